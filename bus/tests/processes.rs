//! Real processes: this test binary re-executes itself as robot (or whole-run) processes.
//!
//! `child_process_entry` is the child's entry point; in a normal test run, without the
//! environment variable, it does nothing and passes.

mod common;

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use bus::bus_schema::{
    FinalReport, MergedHintBatch, PseudoTargetDiscovery, ROBOT_ID_ALL, RobotState, RobotStatus,
};
use bus::{
    BusConfig, CoordinatorBus, Liveness, RobotBus, check_nodes, clean_stale, find_run_prefixes,
    leftover_files, monotonic_ns,
};
use common::{PATIENCE, assert_no_leftovers, config, expected, recv, registration};

const CHILD_ENV: &str = "QFLEET_BUS_TEST_CHILD";
const DISCOVERIES: u64 = 2_000;

fn spawn(mode: &str, cfg: &BusConfig, robot_id: u32) -> Child {
    let spec = format!("{mode}:{}:{}:{robot_id}", cfg.run_id, cfg.robots);
    Command::new(std::env::current_exe().expect("test binary path"))
        .args([
            "--exact",
            "child_process_entry",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD_ENV, spec)
        .stdout(Stdio::null())
        .spawn()
        .expect("re-exec the test binary")
}

#[test]
fn child_process_entry() {
    let Ok(spec) = std::env::var(CHILD_ENV) else {
        return;
    };
    let parts: Vec<&str> = spec.split(':').collect();
    let [mode, run_id, robots, robot_id] = parts[..] else {
        panic!("bad child spec {spec:?}");
    };
    let cfg = BusConfig::new(run_id, robots.parse().unwrap()).unwrap();
    let robot_id: u32 = robot_id.parse().unwrap();
    match mode {
        "robot" => run_robot(&cfg, robot_id),
        "hang" => {
            let bus = RobotBus::open(&cfg, robot_id, PATIENCE).unwrap();
            bus.register(&registration(robot_id), PATIENCE).unwrap();
            std::thread::sleep(Duration::from_secs(600));
        }
        "whole-run" => {
            let _c = CoordinatorBus::create(&cfg).unwrap();
            let _r = RobotBus::open(&cfg, robot_id, PATIENCE).unwrap();
            std::thread::sleep(Duration::from_secs(600));
        }
        other => panic!("unknown child mode {other}"),
    }
}

fn run_robot(cfg: &BusConfig, id: u32) {
    let bus = RobotBus::open(cfg, id, PATIENCE).unwrap();
    bus.register(&registration(id), PATIENCE).unwrap();
    bus.wait_start(PATIENCE, |_| {}).unwrap();
    for seq in 0..DISCOVERIES {
        bus.discovery
            .send_with(|d| {
                d.robot_id = id;
                d.seq = seq;
                d.time_ns = monotonic_ns();
                d.send_time_ns = monotonic_ns();
            })
            .unwrap();
    }
    bus.discovery.notify().unwrap();
    bus.state
        .send_and_notify(&RobotState {
            robot_id: id,
            status: RobotStatus::Finished.as_u8(),
            send_time_ns: monotonic_ns(),
            ..RobotState::ZEROED
        })
        .unwrap();
    let merged = recv(&bus.merged);
    let latency = monotonic_ns() - merged.origin_ns[0];
    let deadline = Instant::now() + PATIENCE;
    let acked = loop {
        let ack = recv(&bus.ack);
        if ack.robot_id == id && ack.up_to_seq == DISCOVERIES - 1 {
            break ack.up_to_seq + 1;
        }
        assert!(Instant::now() < deadline);
    };
    bus.report
        .send_and_notify(&FinalReport {
            robot_id: id,
            discoveries_sent: DISCOVERIES,
            discoveries_acked: acked,
            hints_received: 1,
            merged_latency: bus::bus_schema::LatencySummary {
                count: 1,
                max_ns: latency,
                ..Default::default()
            },
            send_time_ns: monotonic_ns(),
            ..FinalReport::ZEROED
        })
        .unwrap();
    bus.close().unwrap();
}

fn wait_success(mut child: Child) {
    let deadline = Instant::now() + PATIENCE;
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            assert!(status.success(), "child failed: {status}");
            return;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("child did not finish");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn a_coordinator_and_two_robot_processes_run_the_whole_protocol() {
    let cfg = config("procs", 2);
    let bus = CoordinatorBus::create(&cfg).unwrap();
    let children = [spawn("robot", &cfg, 0), spawn("robot", &cfg, 1)];
    let fleet = bus.accept_fleet(&expected(2), PATIENCE).unwrap();
    assert_eq!(fleet.len(), 2);
    assert!(
        fleet.values().all(|r| r.pid != std::process::id()),
        "real processes"
    );
    bus.start(ROBOT_ID_ALL, 0).unwrap();

    let mut next = [0u64; 2];
    let deadline = Instant::now() + PATIENCE;
    while next.iter().any(|n| *n < DISCOVERIES) {
        let got = bus
            .discovery
            .drain(usize::MAX, |d: &PseudoTargetDiscovery| {
                let r = d.robot_id as usize;
                assert_eq!(d.seq, next[r], "robot {r}: in order, none lost");
                next[r] += 1;
            })
            .unwrap();
        if got == 0 {
            assert!(Instant::now() < deadline, "discoveries so far {next:?}");
            bus.discovery.wait(Duration::from_millis(10)).unwrap();
        }
    }
    bus.merged
        .send_with(|m: &mut MergedHintBatch| {
            m.count = 1;
            m.origin_ns[0] = monotonic_ns();
            m.oldest_origin_ns = m.origin_ns[0];
        })
        .unwrap();
    bus.merged.notify().unwrap();
    for robot_id in 0..2 {
        bus.ack
            .send(&bus::bus_schema::DiscoveryAck {
                robot_id,
                up_to_seq: DISCOVERIES - 1,
                time_ns: monotonic_ns(),
                ..Default::default()
            })
            .unwrap();
    }
    bus.ack.notify().unwrap();
    let mut reports: Vec<FinalReport> = (0..2).map(|_| recv(&bus.report)).collect();
    reports.sort_by_key(|r| r.robot_id);
    for (i, r) in reports.iter().enumerate() {
        assert_eq!((r.robot_id, r.discoveries_acked), (i as u32, DISCOVERIES));
        assert!(r.merged_latency.max_ns > 0 && r.merged_latency.max_ns < 10_000_000_000);
    }
    for c in children {
        wait_success(c);
    }
    let report = bus.close().unwrap();
    assert!(report.alive.is_empty());
    assert_no_leftovers(&cfg);
}

#[test]
fn a_killed_robot_is_reported_dead_and_its_resources_are_cleaned() {
    let cfg = config("killed", 1);
    let bus = CoordinatorBus::create(&cfg).unwrap();
    let mut child = spawn("hang", &cfg, 0);
    let fleet = bus.accept_fleet(&expected(1), PATIENCE).unwrap();
    let pid = fleet[&0].pid as i32;

    child.kill().unwrap(); // SIGKILL: no chance to clean up
    child.wait().unwrap();

    let nodes = check_nodes(&cfg, false).unwrap();
    let dead: Vec<_> = nodes.dead().collect();
    assert_eq!(dead.len(), 1, "{nodes:#?}");
    assert_eq!(
        (dead[0].name.as_str(), dead[0].pid),
        ("qfleet-robot-0", Some(pid))
    );
    assert_eq!(nodes.alive().count(), 1, "the coordinator");

    let cleaned = check_nodes(&cfg, true).unwrap();
    assert_eq!((cleaned.cleaned, cleaned.cleanup_failed), (1, 0));
    let after = check_nodes(&cfg, false).unwrap();
    assert_eq!(after.dead().count(), 0);
    assert!(after.nodes.iter().all(|n| n.liveness == Liveness::Alive));

    // listeners on the dead robot's wake services were told about it
    let deadline = Instant::now() + PATIENCE;
    while !bus.state.clear_wakeups().unwrap().peer_dead {
        assert!(Instant::now() < deadline, "no peer-dead event");
        std::thread::sleep(Duration::from_millis(5));
    }

    bus.close().unwrap();
    assert_no_leftovers(&cfg);
}

#[test]
fn clean_stale_removes_everything_a_killed_run_left_behind() {
    let cfg = config("stale", 1);
    let mut child = spawn("whole-run", &cfg, 0);
    let deadline = Instant::now() + PATIENCE;
    while check_nodes(&cfg, false).unwrap().alive().count() < 2 {
        assert!(Instant::now() < deadline, "child run did not come up");
        std::thread::sleep(Duration::from_millis(10));
    }
    // while the run is alive, clean_stale touches nothing
    let report = clean_stale(&cfg.prefix()).unwrap();
    assert_eq!((report.alive.len(), report.removed.len()), (2, 0));

    child.kill().unwrap();
    child.wait().unwrap();
    assert!(
        !leftover_files(&cfg.prefix()).is_empty(),
        "SIGKILL leaves files"
    );
    assert!(find_run_prefixes().contains(&cfg.prefix()));

    let report = clean_stale(&cfg.prefix()).unwrap();
    assert!(report.alive.is_empty());
    assert_eq!(report.dead_cleaned, 2);
    assert!(!report.removed.is_empty(), "the management file at least");
    assert_no_leftovers(&cfg);
    assert!(!find_run_prefixes().contains(&cfg.prefix()));
}
