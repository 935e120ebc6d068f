//! `Outbox::send_batch` zeroes only what a reused slot's last batch used: batches of falling
//! and rising sizes through the same slots still arrive with every byte beyond `count` zero
//! and no stale header field.

mod common;

use std::sync::mpsc;

use bus::bus_schema::{Command, HINT_BATCH_CAP, MergedHintBatch, QHint, QHintBatch, ROBOT_ID_ALL};
use bus::{CoordinatorBus, RobotBus};
use common::{PATIENCE, assert_no_leftovers, config, expected, recv, registration};

/// Sizes that shrink after large batches (the case that would leave stale entries behind).
const COUNTS: [usize; 12] = [HINT_BATCH_CAP, 3, 0, 200, 1, 255, 2, 0, 128, 64, 1, 0];
const ROUNDS: usize = 8;

fn hint(k: usize, i: usize) -> QHint {
    QHint {
        cell: (k * 1000 + i) as u32,
        action: (i % 4) as u8,
        visits: 1 + i as u16,
        q: 0.25 + i as f32,
        ..QHint::ZEROED
    }
}

fn hints(k: usize) -> QHintBatch {
    let n = COUNTS[k % COUNTS.len()];
    let mut b = QHintBatch {
        robot_id: 0,
        goal_id: (k % 3) as u32,
        count: n as u32,
        seq: k as u64,
        // a header field some batches leave unset: must not survive from the slot's last use
        oldest_update_ns: if k.is_multiple_of(2) {
            10 + k as u64
        } else {
            0
        },
        ..QHintBatch::ZEROED
    };
    for i in 0..n {
        b.entries[i] = hint(k, i);
    }
    b
}

fn merged(k: usize) -> MergedHintBatch {
    let n = COUNTS[(k + 5) % COUNTS.len()];
    let mut m = MergedHintBatch {
        coordinator_seq: k as u64,
        count: n as u32,
        oldest_origin_ns: if k.is_multiple_of(2) { 1 } else { 0 },
        ..MergedHintBatch::ZEROED
    };
    for i in 0..n {
        m.entries[i] = hint(k, i);
        m.origin_ns[i] = 1 + i as u64;
        m.origin_robot[i] = (i % 3) as u32;
    }
    m
}

/// Writes what `fill` of the robot-agent / coordinator writes: header fields and `[..count]`.
fn write_hints(b: &mut QHintBatch, want: &QHintBatch) {
    assert!(
        *b == QHintBatch::ZEROED,
        "send_batch hands out an all-zero slot"
    );
    let n = want.count as usize;
    b.robot_id = want.robot_id;
    b.goal_id = want.goal_id;
    b.count = want.count;
    b.seq = want.seq;
    if want.oldest_update_ns != 0 {
        b.oldest_update_ns = want.oldest_update_ns;
    }
    b.entries[..n].copy_from_slice(&want.entries[..n]);
}

fn write_merged(m: &mut MergedHintBatch, want: &MergedHintBatch) {
    assert!(
        *m == MergedHintBatch::ZEROED,
        "send_batch hands out an all-zero slot"
    );
    let n = want.count as usize;
    m.coordinator_seq = want.coordinator_seq;
    m.count = want.count;
    if want.oldest_origin_ns != 0 {
        m.oldest_origin_ns = want.oldest_origin_ns;
    }
    m.entries[..n].copy_from_slice(&want.entries[..n]);
    m.origin_ns[..n].copy_from_slice(&want.origin_ns[..n]);
    m.origin_robot[..n].copy_from_slice(&want.origin_robot[..n]);
}

#[test]
fn reused_slots_arrive_zero_beyond_count_in_both_directions() {
    let cfg = config("sendbatch", 1);
    let cfg = &cfg;
    let total = ROUNDS * COUNTS.len();
    let (robot_result, coord_result) = std::thread::scope(|s| {
        // lockstep: the robot sends batch k+1 only after the coordinator checked batch k, so
        // the latest-wins buffers never drop one and the same few slots are reused
        let (got_tx, got_rx) = mpsc::channel::<usize>();
        let coordinator = s.spawn(move || {
            let bus = CoordinatorBus::create(cfg).unwrap();
            bus.accept_fleet(&expected(1), PATIENCE).unwrap();
            bus.start(ROBOT_ID_ALL, 1).unwrap();
            for k in 0..total {
                assert_eq!(recv(&bus.hints), hints(k), "hint batch {k}");
                let want = merged(k);
                bus.merged.send_batch(|m| write_merged(m, &want)).unwrap();
                got_tx.send(k).unwrap();
            }
            bus.close().unwrap()
        });
        let robot = s.spawn(move || {
            let bus = RobotBus::open(cfg, 0, PATIENCE).unwrap();
            let ack = bus.register(&registration(0), PATIENCE).unwrap();
            assert_eq!(ack.command, Command::Ack.as_u8());
            bus.wait_start(PATIENCE, |_| {}).unwrap();
            for k in 0..total {
                let want = hints(k);
                bus.hints.send_batch(|b| write_hints(b, &want)).unwrap();
                assert_eq!(got_rx.recv_timeout(PATIENCE).unwrap(), k);
                assert_eq!(recv(&bus.merged), merged(k), "merged batch {k}");
            }
            bus.close().unwrap()
        });
        (robot.join(), coordinator.join())
    });
    robot_result.expect("robot thread");
    coord_result.expect("coordinator thread");
    assert_no_leftovers(cfg);
}
