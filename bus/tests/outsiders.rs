//! What a process outside the fleet can and cannot do to a run (issue 10, items 7, 11, 12, 21):
//! a stalled outside reader never blocks or aborts a lossless send (the fleet still gets every
//! message, and a stalled *fleet* subscriber still fails loudly); every file of a run is
//! owner-only; a re-sent registration that crossed its Ack is not acked again; an observer
//! joins only once the run's services exist and only into its own slots.

mod common;

use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::time::{Duration, Instant};

use bus::bus_schema::{Command, Control, ROBOT_ID_ALL};
use bus::{
    Admission, BusConfig, BusError, CoordinatorBus, DIR_MODE, FILE_MODE, Inbox, OBSERVER_SLOTS,
    Observer, RobotBus, SendError, control_buffer, leftover_files,
};
use common::{PATIENCE, assert_no_leftovers, config, expected, registration};

/// Controls sent in the stalled-reader tests: several times any buffer involved.
fn burst(robots: u32) -> u64 {
    4 * control_buffer(robots as usize) as u64
}

#[test]
fn a_stalled_outside_reader_on_a_lossless_topic_never_blocks_the_fleet() {
    let cfg = BusConfig {
        send_timeout: Duration::from_millis(300),
        ..config("stalled-outsider", 1)
    };
    let cfg = &cfg;
    let n = burst(1);
    std::thread::scope(|s| {
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let (done_tx, done_rx) = std::sync::mpsc::channel::<()>();
        let coordinator = s.spawn(move || {
            let bus = CoordinatorBus::create(cfg).unwrap();
            bus.accept_fleet(&expected(1), PATIENCE).unwrap();
            // the outside reader is connected before anything below is sent
            ready_rx.recv().unwrap();
            bus.connect_all().unwrap();
            bus.start(ROBOT_ID_ALL, 0).unwrap();
            let t0 = Instant::now();
            for _ in 0..n {
                // with a retrying outsider each send past its buffer would wait 300 ms and
                // then fail: DeliveryTimeout
                bus.send_control(bus::control(Command::Phase, ROBOT_ID_ALL))
                    .expect("a lossless send must not fail because an outsider is stalled");
            }
            let per_send = t0.elapsed() / n as u32;
            eprintln!(
                "{n} controls past a stalled outside reader: {per_send:?} per send, {} dropped \
                 for it",
                bus.control.outsider_drops()
            );
            assert!(
                bus.control.outsider_drops() >= n - control_buffer(1) as u64,
                "the outsider's full buffer dropped samples ({} drops)",
                bus.control.outsider_drops()
            );
            bus.stop(ROBOT_ID_ALL).unwrap();
            done_rx.recv().unwrap();
            bus.close().unwrap();
        });
        let robot = s.spawn(move || {
            let bus = RobotBus::open(cfg, 0, PATIENCE).unwrap();
            bus.register(&registration(0), PATIENCE).unwrap();
            bus.wait_start(PATIENCE, |_| {}).unwrap();
            let mut phases = 0;
            let stop = bus
                .wait_control(PATIENCE, |c| {
                    if c.command == Command::Phase.as_u8() {
                        phases += 1;
                    }
                    c.command == Command::Stop.as_u8()
                })
                .unwrap();
            assert_eq!(stop.command, Command::Stop.as_u8());
            assert_eq!(
                phases, n,
                "the fleet got every control: lossless to the fleet"
            );
            bus.close().unwrap();
        });
        // the outside reader: joins, never reads
        let observer = Observer::join(cfg, "stalled", PATIENCE).unwrap();
        let inbox = observer.inbox::<Control>().unwrap();
        inbox.connect().unwrap();
        ready_tx.send(()).unwrap();
        robot.join().expect("robot thread");
        // it kept at most one buffer's worth: the rest was dropped for it alone
        let mut kept = 0;
        while inbox.receive().unwrap().is_some() {
            kept += 1;
        }
        assert!(kept <= control_buffer(1), "{kept}");
        drop(inbox);
        drop(observer);
        done_tx.send(()).unwrap();
        coordinator.join().expect("coordinator thread");
    });
    assert_no_leftovers(cfg);
}

#[test]
fn a_stalled_fleet_subscriber_still_fails_loudly() {
    let cfg = BusConfig {
        send_timeout: Duration::from_millis(200),
        ..config("stalled-fleet", 1)
    };
    let cfg = &cfg;
    std::thread::scope(|s| {
        let (go_tx, go_rx) = std::sync::mpsc::channel::<()>();
        let coordinator = s.spawn(move || {
            let bus = CoordinatorBus::create(cfg).unwrap();
            bus.accept_fleet(&expected(1), PATIENCE).unwrap();
            let mut failure = None;
            for _ in 0..burst(1) {
                if let Err(e) = bus.send_control(bus::control(Command::Phase, ROBOT_ID_ALL)) {
                    failure = Some(e);
                    break;
                }
            }
            assert!(
                matches!(
                    failure,
                    Some(BusError::Send(SendError::DeliveryTimeout { .. }))
                ),
                "a robot that never drains is a delivery failure, not a silent drop: {failure:?}"
            );
            assert_eq!(bus.control.outsider_drops(), 0);
            go_tx.send(()).unwrap();
            bus.close().unwrap();
        });
        let robot = s.spawn(move || {
            let bus = RobotBus::open(cfg, 0, PATIENCE).unwrap();
            bus.register(&registration(0), PATIENCE).unwrap();
            go_rx.recv().unwrap(); // never reads meanwhile
            bus.close().unwrap();
        });
        robot.join().expect("robot thread");
        coordinator.join().expect("coordinator thread");
    });
    assert_no_leftovers(cfg);
}

#[test]
fn every_file_of_a_run_is_owner_only() {
    let cfg = config("modes", 1);
    let cfg = &cfg;
    std::thread::scope(|s| {
        let (checked_tx, checked_rx) = std::sync::mpsc::channel::<()>();
        let (up_tx, up_rx) = std::sync::mpsc::channel::<()>();
        let coordinator = s.spawn(move || {
            let bus = CoordinatorBus::create(cfg).unwrap();
            bus.accept_fleet(&expected(1), PATIENCE).unwrap();
            up_tx.send(()).unwrap();
            checked_rx.recv().unwrap();
            bus.close().unwrap();
        });
        let robot = s.spawn(move || {
            let bus = RobotBus::open(cfg, 0, PATIENCE).unwrap();
            bus.register(&registration(0), PATIENCE).unwrap();
            up_rx.recv().unwrap();
            let files = leftover_files(&cfg.prefix());
            assert!(
                files
                    .iter()
                    .any(|f| f.to_string_lossy().ends_with("global_mgmt")),
                "the management segment iceoryx2 makes 0666 is among them: {files:#?}"
            );
            let me = unsafe { libc::geteuid() };
            for f in &files {
                let m = std::fs::symlink_metadata(f).unwrap();
                let want = if m.is_dir() {
                    DIR_MODE
                } else {
                    m.mode() & FILE_MODE
                };
                assert_eq!(m.uid(), me, "{}", f.display());
                assert_eq!(
                    m.permissions().mode() & 0o7777,
                    want,
                    "{} is {:o}",
                    f.display(),
                    m.permissions().mode() & 0o7777
                );
            }
            checked_tx.send(()).unwrap();
            bus.close().unwrap();
        });
        robot.join().expect("robot thread");
        coordinator.join().expect("coordinator thread");
    });
    assert_no_leftovers(cfg);
}

#[test]
fn a_registration_resent_before_its_ack_is_not_acked_twice() {
    let cfg = config("reack", 2);
    let cfg = &cfg;
    std::thread::scope(|s| {
        let coordinator = s.spawn(move || {
            let bus = CoordinatorBus::create(cfg).unwrap();
            // a listener for what goes out on control
            let watch = Inbox::<Control>::open(bus.node(), cfg).unwrap();
            let mut accepted = std::collections::BTreeMap::new();
            let early = registration(1);
            let mut reg = early;
            reg.send_time_ns = bus::monotonic_ns();
            let r = bus.admit(&reg, &expected(2), &mut accepted).unwrap();
            assert_eq!(r, Admission::Accepted);
            // a re-send stamped before the Ack went out crossed it: no second Ack
            let r = bus.admit(&reg, &expected(2), &mut accepted).unwrap();
            assert_eq!(r, Admission::Reaccepted);
            // asked again after the Ack: answered
            let mut again = reg;
            again.send_time_ns = bus::monotonic_ns();
            let r = bus.admit(&again, &expected(2), &mut accepted).unwrap();
            assert_eq!(r, Admission::Reaccepted);
            let mut acks = 0;
            while let Some(c) = watch.receive().unwrap() {
                if c.command == Command::Ack.as_u8() {
                    acks += 1;
                }
            }
            assert_eq!(
                acks, 2,
                "one Ack for the registration, one for the later request"
            );
            drop(watch);
            bus.close().unwrap();
        });
        coordinator.join().expect("coordinator thread");
    });
    assert_no_leftovers(cfg);
}

#[test]
fn an_observer_waits_for_the_services_and_gets_only_its_own_slots() {
    let cfg = config("observer", 1);
    let cfg = &cfg;
    // before the run exists: no node is created, the join times out
    let e = Observer::join(cfg, "early", Duration::from_millis(100))
        .err()
        .expect("no run yet");
    assert!(matches!(e, BusError::Timeout { .. }), "{e}");
    assert!(
        leftover_files(&cfg.prefix()).is_empty(),
        "an early observer left no node"
    );
    std::thread::scope(|s| {
        let (done_tx, done_rx) = std::sync::mpsc::channel::<()>();
        let (up_tx, up_rx) = std::sync::mpsc::channel::<()>();
        let coordinator = s.spawn(move || {
            let bus = CoordinatorBus::create(cfg).unwrap();
            up_tx.send(()).unwrap();
            done_rx.recv().unwrap();
            bus.close().unwrap();
        });
        up_rx.recv().unwrap();
        let observers: Vec<Observer> = (0..OBSERVER_SLOTS)
            .map(|i| Observer::join(cfg, &format!("o{i}"), PATIENCE).unwrap())
            .collect();
        let e = Observer::join(cfg, "one-too-many", PATIENCE)
            .err()
            .expect("all observer slots taken");
        assert!(matches!(e, BusError::NoObserverSlot { .. }), "{e}");
        // the fleet's own slots are untouched: the robot still gets in
        let robot = RobotBus::open(cfg, 0, PATIENCE).unwrap();
        drop(robot);
        drop(observers);
        done_tx.send(()).unwrap();
        coordinator.join().expect("coordinator thread");
    });
    assert_no_leftovers(cfg);
}
