//! The sum-of-costs / lower-bound table of `mapf/README.md`: the tuning instance
//! (random-32-32-10, first N agents of random-1) and held-out maps with random start/goal
//! pairs drawn from fixed seeds. Ignored by default (it takes a while in a dev build):
//!
//! ```sh
//! cargo test -p mapf --release --test ratios -- --ignored --nocapture
//! ```

mod common;

use common::{checked, movingai, run};
use mapf::{Instance, WorldConfig};
use planner::Cell;
use planner::map::{GridMap, load_map, load_scen};
use std::time::Instant;

/// xorshift64*: a tiny fixed generator so the held-out instances never change.
struct Rng(u64);

impl Rng {
    fn below(&mut self, n: usize) -> usize {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 33) as usize % n
    }
}

/// `n` agents with distinct random free starts and distinct random goals reachable from them.
fn random_instance(map: &GridMap, n: usize, seed: u64) -> Instance {
    let g = &map.grid;
    let free: Vec<Cell> = (0..g.len())
        .map(|i| g.cell(i))
        .filter(|c| g.is_free(*c))
        .collect();
    let mut rng = Rng(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1);
    let mut used_s = vec![false; g.len()];
    let mut used_g = vec![false; g.len()];
    let (mut starts, mut goals) = (Vec::new(), Vec::new());
    while starts.len() < n {
        let s = free[rng.below(free.len())];
        let t = free[rng.below(free.len())];
        if s == t || used_s[g.index(s)] || used_g[g.index(t)] {
            continue;
        }
        if planner::path::shortest_moves(g, s, t).is_none() {
            continue;
        }
        used_s[g.index(s)] = true;
        used_g[g.index(t)] = true;
        starts.push(s);
        goals.push(t);
    }
    Instance::new(g.clone(), starts, goals).expect("valid by construction")
}

/// (SoC / LB, ms) of one run, asserting every agent arrives without conflict.
fn measure(inst: &Instance, config: WorldConfig) -> (f64, f64) {
    let t0 = Instant::now();
    let r = run(inst, config, 5000);
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    assert!(
        r.world.all_arrived(),
        "{:?} after {} ticks",
        r.last,
        r.ticks
    );
    (checked(inst, &r.world).ratio, ms)
}

#[test]
#[ignore = "the README's ratio table; run with --release --ignored --nocapture"]
fn ratios() {
    let Some(dir) = movingai("ratios") else {
        return;
    };
    let plan = WorldConfig::default();
    // the baseline: this crate's PIBT alone, ties broken as PIBT's reference implementation does
    let pibt = WorldConfig {
        plan_ahead: false,
        free_first: true,
        ..WorldConfig::default()
    };
    let load = |f: &str| load_map(dir.join(f).to_str().unwrap()).unwrap();
    println!("tuning: random-32-32-10, first N agents of random-1");
    println!("| N | LB | mapf SoC/LB | ms | plain PIBT, same intents |");
    println!("|---:|---:|---:|---:|---:|");
    let map = load("random-32-32-10.map");
    let scen = load_scen(&dir.join("random-32-32-10-random-1.scen")).unwrap();
    for n in [8, 16, 32, 64, 128] {
        let inst = Instance::from_scen(&map, &scen, n).unwrap();
        let (r, ms) = measure(&inst, plan);
        let (p, _) = measure(&inst, pibt);
        println!(
            "| {n} | {} | {r:.3} | {ms:.0} | {p:.3} |",
            inst.lower_bound()
        );
    }
    println!();
    println!("held out: random start/goal pairs, seeds 1, 2, 3 (mean and worst of the three)");
    println!("| map | N | mapf SoC/LB mean (worst) | ms mean | plain PIBT mean (worst) |");
    println!("|---|---:|---:|---:|---:|");
    for file in [
        "random-64-64-10.map",
        "room-32-32-4.map",
        "maze-32-32-2.map",
        "warehouse-10-20-10-2-1.map",
        "den312d.map",
    ] {
        let map = load(file);
        for n in [16, 48] {
            let (mut rs, mut ps, mut msum) = (Vec::new(), Vec::new(), 0.0);
            for seed in 1..=3u64 {
                let inst = random_instance(&map, n, seed);
                let (r, ms) = measure(&inst, plan);
                rs.push(r);
                msum += ms;
                ps.push(measure(&inst, pibt).0);
            }
            let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
            let worst = |v: &[f64]| v.iter().cloned().fold(0.0, f64::max);
            println!(
                "| {} | {n} | {:.3} ({:.3}) | {:.0} | {:.3} ({:.3}) |",
                file.trim_end_matches(".map"),
                mean(&rs),
                worst(&rs),
                msum / 3.0,
                mean(&ps),
                worst(&ps)
            );
        }
    }
}
