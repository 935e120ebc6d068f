//! Writing messages into loaned shared-memory samples, and one whole update-loop round trip
//! in one thread (no wakeups, no second process): the software cost under the IPC floor.
//!
//! `cargo bench --bench bus`. Uses a private run id and removes its files at the end.

use std::hint::black_box;
use std::time::Duration;

use bus::bus_schema::{HINT_BATCH_CAP, MergedHintBatch, QHint, QHintBatch};
use bus::{BusConfig, CoordinatorBus, RobotBus, monotonic_ns, unique_run_id};
use contract::coordinator::MergeRule;
use criterion::{Criterion, criterion_group, criterion_main};
use sharing::FleetTable;

fn bench(c: &mut Criterion) {
    let cfg = match BusConfig::new(unique_run_id("bench-bus"), 2) {
        Ok(c) => c,
        Err(e) => panic!("{e}"),
    };
    let (coord, robot) = match CoordinatorBus::create(&cfg)
        .and_then(|c| RobotBus::open(&cfg, 0, Duration::from_secs(5)).map(|r| (c, r)))
    {
        Ok(p) => p,
        Err(e) => panic!("bus: {e}"),
    };
    if let Err(e) = coord.connect_all() {
        panic!("{e}");
    }
    let mut entries = Box::new([QHint::ZEROED; HINT_BATCH_CAP]);
    for (i, e) in entries.iter_mut().enumerate() {
        e.cell = i as u32;
        e.q = 0.5;
    }
    let mut g = c.benchmark_group("loaned-sample");
    for n in [1usize, 256] {
        g.bench_function(format!("send_with-QHintBatch-{n}-entries+receive"), |b| {
            b.iter(|| {
                let sent = robot.hints.send_with(|m| {
                    m.count = n as u32;
                    m.entries[..n].copy_from_slice(&entries[..n]);
                    m.send_time_ns = monotonic_ns();
                });
                let s = coord.hints.receive_sample();
                black_box((sent.is_ok(), s.map(|s| s.is_some()).ok()))
            })
        });
    }
    let whole = Box::new(QHintBatch {
        count: 1,
        ..QHintBatch::ZEROED
    });
    g.bench_function("send-copy-QHintBatch+receive", |b| {
        b.iter(|| {
            let sent = robot.hints.send(&whole);
            let s = coord.hints.receive_sample();
            black_box((sent.is_ok(), s.map(|s| s.is_some()).ok()))
        })
    });
    g.bench_function("send_with-MergedHintBatch-1-entry+receive", |b| {
        b.iter(|| {
            let sent = coord.merged.send_with(|m: &mut MergedHintBatch| {
                m.count = 1;
                m.entries[0] = entries[0];
                m.send_time_ns = monotonic_ns();
            });
            let s = robot.merged.receive_sample();
            black_box((sent.is_ok(), s.map(|s| s.is_some()).ok()))
        })
    });
    g.bench_function("notify", |b| {
        b.iter(|| {
            let n = robot.hints.notify();
            let w = coord.hints.clear_wakeups();
            black_box((n.is_ok(), w.is_ok()))
        })
    });
    let mut table = FleetTable::new(900, MergeRule::Max);
    let mut k = 0u32;
    g.bench_function("loop-round-trip-in-one-thread", |b| {
        b.iter(|| {
            k = k.wrapping_add(1);
            let q = if k.is_multiple_of(2) { 0.5 } else { 0.75 };
            let _ = robot.hints.send_with(|m| {
                m.count = 1;
                m.entries[0] = QHint {
                    cell: k % 256,
                    q,
                    ..QHint::ZEROED
                };
                m.oldest_update_ns = monotonic_ns();
            });
            if let Ok(Some(s)) = coord.hints.receive_sample() {
                let m = s.payload();
                table.merge(m.robot_id, &m.entries[0], m.oldest_update_ns);
            }
            let _ = coord.merged.send_with(|m| {
                table.take_into(m);
            });
            let got = robot.merged.receive_sample();
            black_box(got.map(|s| s.map(|s| s.payload().count)).ok())
        })
    });
    g.finish();
    // what a liveness check costs: a full listing (the coordinator's and a joining host's
    // lister make one at most every second) against a re-check (every 100-200 ms)
    let mut g = c.benchmark_group("liveness");
    g.bench_function("check_nodes-2-nodes", |b| {
        b.iter(|| black_box(bus::check_nodes(&cfg, false).map(|r| r.nodes.len()).ok()))
    });
    g.bench_function("check_nodes-2-nodes-clean-dead", |b| {
        b.iter(|| black_box(bus::check_nodes(&cfg, true).map(|r| r.nodes.len()).ok()))
    });
    // what the lister does between full listings: one /proc read per node
    if let Ok(listed) = bus::check_nodes(&cfg, false) {
        g.bench_function("recheck-2-nodes", |b| {
            b.iter(|| black_box(bus::lister::recheck(&listed, bus::process_state).1))
        });
    }
    g.finish();
    drop(robot);
    if let Err(e) = coord.close() {
        eprintln!("cleanup: {e}");
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
