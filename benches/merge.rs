//! Hot paths of the update loop without IPC: the coordinator's merge of a full hint batch
//! (with the checks `coordinator::run` makes per entry) and the publication of the merged
//! batch, the robot's batching of Q updates, and applying a full merged batch to a Q-table.
//!
//! `cargo bench --bench merge`. Throughput is per Q-hint entry.

use std::hint::black_box;

use bus_schema::{HINT_BATCH_CAP, MergedHintBatch, QHint, QHintBatch};
use contract::coordinator::MergeRule;
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use planner::{Grid, QTable};
use sharing::FleetTable;
use sharing::{ApplyCtx, HintBatcher, MergedApplier};

const CELLS: usize = 900; // paper-30

fn batch(robot: u32, round: u32) -> Box<QHintBatch> {
    let mut b = Box::new(QHintBatch {
        robot_id: robot,
        count: HINT_BATCH_CAP as u32,
        oldest_update_ns: 1,
        ..QHintBatch::ZEROED
    });
    for (i, e) in b.entries.iter_mut().enumerate() {
        *e = QHint {
            cell: (i * 3 % CELLS) as u32,
            action: (i % 4) as u8,
            visits: 3,
            q: 0.5 + 0.01 * (round % 7) as f32 + i as f32 * 1e-4,
            ..QHint::ZEROED
        };
    }
    b
}

/// What `coordinator::run` does per received batch: check each entry, merge it.
fn merge_batch(t: &mut FleetTable, b: &QHintBatch, out: &mut MergedHintBatch) -> usize {
    let mut merged = 0;
    for h in &b.entries[..b.count as usize] {
        if h.cell as usize >= t.cells() || h.action >= 4 || !h.q.is_finite() {
            continue;
        }
        merged += 1;
        if t.merge(b.robot_id, h, b.oldest_update_ns) {
            t.take_into(out);
        }
    }
    merged
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("update-loop-cpu");
    g.throughput(Throughput::Elements(HINT_BATCH_CAP as u64));
    // alternate two batches so every merge changes the table (the worst case: all queued)
    let batches = [batch(0, 0), batch(0, 1)];
    let mut out = Box::new(MergedHintBatch::ZEROED);
    for rule in [MergeRule::Max, MergeRule::Mean] {
        let mut t = FleetTable::new(CELLS, rule);
        let mut k = 0;
        g.bench_function(format!("merge-256+take/{rule}"), |bch| {
            bch.iter(|| {
                k ^= 1;
                let n = merge_batch(&mut t, &batches[k], &mut out);
                t.take_into(&mut out);
                black_box(n)
            })
        });
    }
    // unchanged values: the merge only checks (no queueing, no merged batch)
    let mut t = FleetTable::new(CELLS, MergeRule::Max);
    merge_batch(&mut t, &batches[1], &mut out);
    t.take_into(&mut out);
    let lower = batch(1, 0);
    g.bench_function("merge-256/no-change", |bch| {
        bch.iter(|| black_box(merge_batch(&mut t, &lower, &mut out)))
    });

    let mut batcher = HintBatcher::new(CELLS, HINT_BATCH_CAP, 1e-3);
    let mut hb = Box::new(QHintBatch::ZEROED);
    let mut round = 0u32;
    g.bench_function("batcher-note-256+fill", |bch| {
        bch.iter(|| {
            round = round.wrapping_add(1);
            let q = if round.is_multiple_of(2) { 0.5 } else { 0.75 };
            for i in 0..HINT_BATCH_CAP as u32 {
                batcher.note(i * 3 % CELLS as u32, (i % 4) as u8, q, u64::from(i), || 7);
            }
            black_box(batcher.fill(&mut hb))
        })
    });

    let grid = match Grid::new(30, 30, vec![true; CELLS]) {
        Ok(g) => g,
        Err(e) => panic!("grid: {e}"),
    };
    let mut q = QTable::new(&grid);
    let visits = vec![0u16; CELLS * 4];
    let mut merged = Box::new(MergedHintBatch::ZEROED);
    let mut t = FleetTable::new(CELLS, MergeRule::Max);
    // a full batch: merge_batch hands it over when the 256th entry is queued
    merge_batch(&mut t, &batches[1], &mut merged);
    assert_eq!(merged.count as usize, HINT_BATCH_CAP);
    let mut applier = MergedApplier::new(ApplyCtx::second_of_two());
    g.bench_function("apply-merged-256", |bch| {
        bch.iter(|| {
            applier.apply(&merged, &mut q, &visits, 1_000);
            black_box(applier.counters().entries_seen)
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
