//! A coordinator thread and a robot thread run the start handshake and exchange every message
//! type once, byte for byte; afterwards nothing of the run is left on disk.

mod common;

use std::sync::mpsc;

use bus::bus_schema::{
    Command, Control, DiscoveryAck, FinalReport, HINT_BATCH_CAP, LatencySummary, MergedHintBatch,
    PseudoTargetDiscovery, QHint, ROBOT_ID_ALL, RobotState, RobotStatus, SCHEMA_VERSION,
};
use bus::{CoordinatorBus, RobotBus, monotonic_ns};
use common::{PATIENCE, assert_no_leftovers, config, expected, recv, registration};

fn state() -> RobotState {
    RobotState {
        robot_id: 0,
        goal_id: 3,
        episode: 17,
        step: 42,
        last_episode_steps: 99,
        cell_x: 5,
        cell_y: 6,
        status: RobotStatus::Running.as_u8(),
        seq: 0,
        send_time_ns: monotonic_ns(),
        ..RobotState::ZEROED
    }
}

fn discovery() -> PseudoTargetDiscovery {
    PseudoTargetDiscovery {
        robot_id: 0,
        goal_id: 3,
        cell_x: 7,
        cell_y: 8,
        value: 0.875,
        seq: 0,
        time_ns: monotonic_ns(),
        episode: 17,
        send_time_ns: monotonic_ns(),
        ..PseudoTargetDiscovery::ZEROED
    }
}

fn hint(i: usize) -> QHint {
    QHint {
        cell: i as u32 * 3,
        action: (i % 4) as u8,
        visits: i as u16 + 1,
        q: i as f32 * 0.5,
        ..QHint::ZEROED
    }
}

fn report() -> FinalReport {
    FinalReport {
        robot_id: 0,
        schema_version: SCHEMA_VERSION,
        goal_id: 3,
        episodes: 100,
        final_path_len: 19,
        optimal_path_len: 17,
        first_optimal_episode: -1,
        max_steps: 4000,
        status: RobotStatus::Finished.as_u8(),
        avg_steps: 123.25,
        env_steps: 12_325,
        elapsed_ns: 1_000_000,
        discoveries_sent: 1,
        discoveries_acked: 1,
        hints_sent: 1,
        hints_received: 1,
        hints_applied: HINT_BATCH_CAP as u64,
        merged_latency: LatencySummary {
            count: 256,
            min_ns: 1,
            mean_ns: 5,
            p50_ns: 4,
            p90_ns: 8,
            p99_ns: 9,
            p999_ns: 10,
            max_ns: 11,
        },
        send_time_ns: monotonic_ns(),
        ..FinalReport::ZEROED
    }
}

fn merged() -> MergedHintBatch {
    let mut m = MergedHintBatch {
        coordinator_seq: 0,
        goal_id: 3,
        count: HINT_BATCH_CAP as u32,
        oldest_origin_ns: 1,
        send_time_ns: 12_345,
        ..MergedHintBatch::ZEROED
    };
    for i in 0..HINT_BATCH_CAP {
        m.entries[i] = hint(i);
        m.origin_ns[i] = 1 + i as u64;
        m.origin_robot[i] = (i % 3) as u32;
    }
    m
}

#[test]
fn every_message_type_crosses_between_two_threads() {
    let cfg = config("exchange", 1);
    let cfg = &cfg;
    let (robot_result, coord_result) = std::thread::scope(|s| {
        let (sent_tx, sent_rx) =
            mpsc::channel::<(RobotState, PseudoTargetDiscovery, FinalReport)>();
        let coordinator = s.spawn(move || {
            let bus = CoordinatorBus::create(cfg).unwrap();
            let fleet = bus.accept_fleet(&expected(1), PATIENCE).unwrap();
            assert_eq!(fleet.keys().copied().collect::<Vec<_>>(), vec![0]);
            let reg = fleet[&0];
            let want = registration(0);
            assert_eq!(
                (reg.robot_id, reg.pid, reg.seed, reg.map_hash),
                (0, want.pid, 7, 0xC0FFEE)
            );
            assert!(reg.send_time_ns > 0);

            bus.send_control(Control {
                goal_id: 3,
                goal_x: 10,
                goal_y: 7,
                ..bus::control(Command::AssignGoal, ROBOT_ID_ALL)
            })
            .unwrap();
            assert_eq!(bus.start(ROBOT_ID_ALL, 100).unwrap(), 1);

            let (state, disc, rep) = sent_rx.recv().unwrap();
            assert_eq!(recv(&bus.state), state);
            assert_eq!(recv(&bus.discovery), disc);
            let batch = recv(&bus.hints);
            assert_eq!(batch.count, 200);
            assert!((0..200).all(|i| batch.entries[i] == hint(i)));
            assert!(batch.entries[200..].iter().all(|e| *e == QHint::ZEROED));

            let m = merged();
            bus.merged.send_with(|slot| *slot = m).unwrap();
            bus.merged.notify().unwrap();
            let ack = DiscoveryAck {
                robot_id: 0,
                up_to_seq: 0,
                time_ns: monotonic_ns(),
                ..DiscoveryAck::ZEROED
            };
            bus.ack.send_and_notify(&ack).unwrap();
            assert_eq!(recv(&bus.report), rep);
            bus.close().unwrap()
        });
        let robot = s.spawn(move || {
            let bus = RobotBus::open(cfg, 0, PATIENCE).unwrap();
            let ack = bus.register(&registration(0), PATIENCE).unwrap();
            assert_eq!(ack.command, Command::Ack.as_u8());
            let mut goal = None;
            let start = bus.wait_start(PATIENCE, |c| goal = Some(*c)).unwrap();
            assert_eq!(start.command, Command::Start.as_u8());
            assert_eq!(start.episodes, 100);
            let goal = goal.expect("AssignGoal arrives before Start");
            assert_eq!(
                (goal.command, goal.goal_id, goal.goal_x, goal.goal_y),
                (3, 3, 10, 7)
            );
            assert!(goal.seq < start.seq, "control seq grows");

            let (st, disc, rep) = (state(), discovery(), report());
            bus.state.send_and_notify(&st).unwrap();
            assert_eq!(bus.discovery.send_and_notify(&disc).unwrap(), 1);
            bus.hints
                .send_with(|b| {
                    b.robot_id = 0;
                    b.goal_id = 3;
                    b.count = 200;
                    for i in 0..200 {
                        b.entries[i] = hint(i);
                    }
                })
                .unwrap();
            bus.hints.notify().unwrap();
            sent_tx.send((st, disc, rep)).unwrap();

            assert_eq!(recv(&bus.merged), merged());
            let ack = recv(&bus.ack);
            assert_eq!((ack.robot_id, ack.up_to_seq), (0, 0));
            bus.report.send_and_notify(&rep).unwrap();
            bus.close().unwrap()
        });
        (robot.join(), coordinator.join())
    });
    robot_result.expect("robot thread");
    coord_result.expect("coordinator thread");
    assert_no_leftovers(cfg);
}
