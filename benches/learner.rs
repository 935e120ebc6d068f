//! Learner throughput: environment steps per second on paper-30, the paper's two learners and
//! the planning default.
//!
//! `cargo bench --bench learner`. Group `learner-step` times steps alone; group
//! `learner-episode` times whole episodes (`run_episode`: steps, the planning learner's sweeps
//! inside the episode, then its replay and sweeps at the episode's end), the figure that counts
//! for planning; `planning-episode-sweeps` is planning with `--sweep-every 0`, side by side. One iteration runs a fixed number of steps of an already
//! warmed-up learner (episodes restart as they end), so the figure is the steady-state step
//! cost: the policy draw, the move and the Q update. N is set very large so the dynamic
//! schedule stays at its start (ε(k) ≈ 0.51: half the steps explore through the softmax), the
//! improved learner's most expensive phase.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use planner::map::builtin;
use planner::task::resolve_task;
use planner::{Learner, LearnerConfig};
use std::hint::black_box;

const STEPS: u64 = 1_000_000;

fn steps(l: &mut Learner, n: u64) -> u64 {
    let mut done = 0;
    while done < n {
        l.begin_episode();
        loop {
            let s = l.step();
            done += 1;
            if s.done || done >= n {
                black_box(s);
                break;
            }
        }
    }
    done
}

/// The planning learner sweeping after episodes only (`--sweep-every 0`), side by side with
/// the default that also sweeps inside episodes.
fn episode_sweeps(episodes: u32) -> LearnerConfig {
    let mut c = LearnerConfig::planning(episodes, 1);
    c.extras.sweep_every = 0;
    c
}

fn bench(c: &mut Criterion) {
    let task = resolve_task(&builtin("paper-30").expect("paper-30"), None, None).expect("task");
    let mut g = c.benchmark_group("learner-step/paper-30");
    g.throughput(Throughput::Elements(STEPS));
    g.sample_size(20);
    for (name, cfg) in [
        ("traditional", LearnerConfig::traditional(1 << 30, 1)),
        ("improved", LearnerConfig::improved(1 << 30, 1)),
        ("planning", LearnerConfig::planning(1 << 30, 1)),
        ("planning-episode-sweeps", episode_sweeps(1 << 30)),
    ] {
        // Warm up: learn for 100 episodes so Q-values and episode lengths are realistic.
        let mut l = Learner::new(&task, cfg).expect("config");
        for _ in 0..100 {
            l.run_episode();
        }
        g.bench_function(name, |b| b.iter(|| steps(&mut l, STEPS)));
    }
    g.finish();

    // Whole episodes: the planning learner's per-episode replay and sweeps count here. A fresh
    // learner per iteration (its first 20 episodes: exploration, most sweeps), steps counted.
    let mut g = c.benchmark_group("learner-episode/paper-30");
    g.sample_size(10);
    for (name, cfg) in [
        ("traditional", LearnerConfig::traditional(1000, 1)),
        ("improved", LearnerConfig::improved(1000, 1)),
        ("planning", LearnerConfig::planning(1000, 1)),
        ("planning-episode-sweeps", episode_sweeps(1000)),
    ] {
        let mut probe = Learner::new(&task, cfg).expect("config");
        let per_iter: u64 = (0..20).map(|_| probe.run_episode().steps as u64).sum();
        g.throughput(Throughput::Elements(per_iter));
        g.bench_function(name, |b| {
            b.iter(|| {
                let mut l = Learner::new(&task, cfg).expect("config");
                for _ in 0..20 {
                    black_box(l.run_episode());
                }
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
