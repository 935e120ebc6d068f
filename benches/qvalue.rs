//! What it costs to keep Q-values from underflowing on long paths (issue 9, item 4): the same
//! Q-learning kernels with four representations of a value, side by side.
//!
//! `cargo bench --bench qvalue`. With γ = 0.6 a value n moves from the goal is 0.6^n: below
//! f32's smallest positive number past ~170 moves, so Q is 0 there and the greedy walk loops.
//! The ways out the issue names, each implemented here in the two kernels that make up the
//! planning learner's work:
//! - `f32-g0.99`: f32 with γ = 0.99, the chosen default (0.99^1000 ≈ 4e-5; f32 holds ~8 000 moves);
//! - `f32-g0.6`: the paper's γ in f32, the baseline that underflows;
//! - `f64-g0.6`: the paper's γ in f64 (0.6^n stays normal to ~1 390 moves), twice the memory;
//! - `slog-g0.6`: a signed log-domain value (sign + ln|Q| in f32; never underflows), where a
//!   Bellman backup needs an `exp` and a `ln_1p` (collisions make values negative, so the
//!   log domain must carry a sign).
//!
//! Kernels: `step` — an ε-greedy step (ε = 0.05) with its Q update on the real environment of
//! `planner` (paper-30, episodes restart at the goal); `sweep` — one full Dyna-style backup of
//! every (cell, action) from the known model, on paper-30 and on a 511×511 serpentine corridor
//! (131 k free cells, where the table no longer fits in cache). Before timing, every
//! representation learns the 1 090-move serpentine corridor by sweeps and prints whether its
//! greedy walk is the optimum: the check that the representation actually holds the path.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use planner::env::{Env, Rewards, Transition};
use planner::map::builtin;
use planner::task::{Task, resolve_task};
use std::hint::black_box;

/// Learning constants in the forms the representations need.
#[derive(Clone, Copy)]
struct K {
    alpha: f64,
    gamma: f64,
}

/// One way to store a Q-value.
trait Repr: Copy {
    /// A value from a plain number.
    fn from_f64(v: f64) -> Self;
    /// The plain number (may underflow to 0 for the narrow representations).
    fn to_f64(self) -> f64;
    /// `q + α (r + γ·next_max − q)` (next_max ignored when `terminal`).
    fn backup(q: Self, r: f32, terminal: bool, next_max: Self, k: &K) -> Self;
    /// The full backup `r + γ·next_max` (a sweep over a deterministic model).
    fn target(r: f32, terminal: bool, next_max: Self, k: &K) -> Self;
    /// Whether `self` is larger than `o`.
    fn gt(self, o: Self) -> bool;
}

#[inline(always)]
fn max4<T: Repr>(r: &[T; 4]) -> T {
    let a = if r[1].gt(r[0]) { r[1] } else { r[0] };
    let b = if r[3].gt(r[2]) { r[3] } else { r[2] };
    if b.gt(a) { b } else { a }
}

#[inline(always)]
fn argmax4<T: Repr>(r: &[T; 4]) -> usize {
    let mut best = 0;
    for a in 1..4 {
        if r[a].gt(r[best]) {
            best = a;
        }
    }
    best
}

impl Repr for f32 {
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    fn to_f64(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn backup(q: Self, r: f32, terminal: bool, m: Self, k: &K) -> Self {
        let t = Self::target(r, terminal, m, k);
        q + k.alpha as f32 * (t - q)
    }
    #[inline(always)]
    fn target(r: f32, terminal: bool, m: Self, k: &K) -> Self {
        if terminal { r } else { r + k.gamma as f32 * m }
    }
    #[inline(always)]
    fn gt(self, o: Self) -> bool {
        self > o
    }
}

impl Repr for f64 {
    fn from_f64(v: f64) -> Self {
        v
    }
    fn to_f64(self) -> f64 {
        self
    }
    #[inline(always)]
    fn backup(q: Self, r: f32, terminal: bool, m: Self, k: &K) -> Self {
        let t = Self::target(r, terminal, m, k);
        q + k.alpha * (t - q)
    }
    #[inline(always)]
    fn target(r: f32, terminal: bool, m: Self, k: &K) -> Self {
        if terminal {
            r as f64
        } else {
            r as f64 + k.gamma * m
        }
    }
    #[inline(always)]
    fn gt(self, o: Self) -> bool {
        self > o
    }
}

/// A signed log-domain value: `sign · e^l` (sign 0 is the value 0).
#[derive(Clone, Copy, Debug)]
struct SLog {
    l: f32,
    sign: f32,
}

impl SLog {
    const ZERO: SLog = SLog { l: 0.0, sign: 0.0 };

    #[inline(always)]
    fn scale(self, ln_c: f32) -> SLog {
        SLog {
            l: self.l + ln_c,
            sign: self.sign,
        }
    }

    /// `a + b` in the log domain: one `exp` and one `ln_1p`.
    #[inline(always)]
    fn add(a: SLog, b: SLog) -> SLog {
        if a.sign == 0.0 {
            return b;
        }
        if b.sign == 0.0 {
            return a;
        }
        let (hi, lo) = if a.l >= b.l { (a, b) } else { (b, a) };
        let d = (lo.l - hi.l).exp();
        if hi.sign == lo.sign {
            SLog {
                l: hi.l + d.ln_1p(),
                sign: hi.sign,
            }
        } else if d >= 1.0 {
            SLog::ZERO
        } else {
            SLog {
                l: hi.l + (-d).ln_1p(),
                sign: hi.sign,
            }
        }
    }
}

impl Repr for SLog {
    fn from_f64(v: f64) -> Self {
        if v == 0.0 {
            SLog::ZERO
        } else {
            SLog {
                l: v.abs().ln() as f32,
                sign: v.signum() as f32,
            }
        }
    }
    fn to_f64(self) -> f64 {
        self.sign as f64 * (self.l as f64).exp()
    }
    #[inline(always)]
    fn backup(q: Self, r: f32, terminal: bool, m: Self, k: &K) -> Self {
        let t = Self::target(r, terminal, m, k);
        // (1 − α) q + α t
        SLog::add(
            q.scale((1.0 - k.alpha).ln() as f32),
            t.scale(k.alpha.ln() as f32),
        )
    }
    #[inline(always)]
    fn target(r: f32, terminal: bool, m: Self, k: &K) -> Self {
        let r = SLog::from_f64(r as f64);
        if terminal {
            r
        } else {
            SLog::add(r, m.scale(k.gamma.ln() as f32))
        }
    }
    #[inline(always)]
    fn gt(self, o: Self) -> bool {
        // order: negative (larger magnitude is smaller) < zero < positive
        if self.sign != o.sign {
            return self.sign > o.sign;
        }
        if self.sign > 0.0 {
            self.l > o.l
        } else if self.sign < 0.0 {
            self.l < o.l
        } else {
            false
        }
    }
}

/// A Q-table of one representation over one environment.
struct Table<T: Repr> {
    q: Vec<[T; 4]>,
    k: K,
}

impl<T: Repr> Table<T> {
    fn new(env: &Env, gamma: f64, init: f64) -> Self {
        Table {
            q: vec![[T::from_f64(init); 4]; env.grid().len()],
            k: K { alpha: 0.1, gamma },
        }
    }

    /// One full backup of every (cell, action) from the model: `Q(s,a) = r + γ max Q(s')`.
    fn sweep(&mut self, env: &Env, free: &[u32]) {
        for &s in free {
            for a in 0..4 {
                let (n, r, t) = env.step(s, a);
                let terminal = t == Transition::Goal;
                let m = max4(&self.q[n as usize]);
                self.q[s as usize][a] = T::target(r, terminal, m, &self.k);
            }
        }
    }

    /// `n` ε-greedy steps (ε = 0.05, xorshift draws) with their Q updates; restarts at the goal.
    fn steps(&mut self, env: &Env, n: u64, rng: &mut u64) -> u64 {
        let mut s = env.start();
        let mut goals = 0;
        for _ in 0..n {
            *rng ^= *rng << 13;
            *rng ^= *rng >> 7;
            *rng ^= *rng << 17;
            let a = if (*rng & 0xffff) < 3277 {
                ((*rng >> 16) & 3) as usize
            } else {
                argmax4(&self.q[s as usize])
            };
            let (next, r, t) = env.step(s, a);
            let terminal = t == Transition::Goal;
            let m = max4(&self.q[next as usize]);
            let q = &mut self.q[s as usize][a];
            *q = T::backup(*q, r, terminal, m, &self.k);
            if terminal {
                goals += 1;
                s = env.start();
            } else {
                s = next;
            }
        }
        goals
    }

    /// Moves of the greedy walk from the start, if it reaches the goal.
    fn greedy_len(&self, env: &Env) -> Option<u32> {
        let mut s = env.start();
        for moves in 1..=env.grid().len() as u32 {
            let (n, _, t) = env.step(s, argmax4(&self.q[s as usize]));
            if t == Transition::Goal {
                return Some(moves);
            }
            s = n;
        }
        None
    }
}

fn free_cells(env: &Env) -> Vec<u32> {
    (0..env.grid().len() as u32)
        .filter(|&i| env.grid().free_flags()[i as usize])
        .collect()
}

fn serpentine(w: usize, h: usize) -> Task {
    planner::suite::serpentine(w, h).expect("corridor")
}

fn env_of(task: &Task) -> Env {
    Env::new(&task.grid, task.start, task.goal, Rewards::default())
}

/// Learns the 1 090-move corridor by sweeps until nothing changes and says whether the greedy
/// walk is the optimum (printed: the bench's correctness check).
fn check_long_path<T: Repr>(name: &str, gamma: f64) {
    let task = serpentine(51, 41);
    let env = env_of(&task);
    let free = free_cells(&env);
    let mut t = Table::<T>::new(&env, gamma, 0.0);
    // values spread one move per sweep along the corridor
    for _ in 0..task.optimal_len + 10 {
        t.sweep(&env, &free);
    }
    let start = max4(&t.q[env.start() as usize]).to_f64();
    eprintln!(
        "qvalue check: {name}: {}-move corridor, greedy walk {:?} (optimum {}), Q(start) as f64 = {start:e}",
        task.optimal_len,
        t.greedy_len(&env),
        task.optimal_len
    );
}

fn group<T: Repr>(c: &mut Criterion, name: &str, gamma: f64) {
    check_long_path::<T>(name, gamma);
    let paper = resolve_task(&builtin("paper-30").expect("paper-30"), None, None).expect("task");
    let env = env_of(&paper);
    const STEPS: u64 = 1_000_000;
    let mut t = Table::<T>::new(&env, gamma, 1.0);
    let mut rng = 0x9e37_79b9_7f4a_7c15u64;
    t.steps(&env, STEPS, &mut rng); // warm up: realistic values
    let mut g = c.benchmark_group("qvalue-step/paper-30");
    g.throughput(Throughput::Elements(STEPS));
    g.sample_size(20);
    g.bench_function(name, |b| {
        b.iter(|| black_box(t.steps(&env, STEPS, &mut rng)))
    });
    g.finish();

    let free = free_cells(&env);
    let mut g = c.benchmark_group("qvalue-sweep/paper-30");
    g.throughput(Throughput::Elements(free.len() as u64 * 4));
    g.sample_size(20);
    g.bench_function(name, |b| b.iter(|| t.sweep(&env, &free)));
    g.finish();

    let big = serpentine(511, 511);
    let env = env_of(&big);
    let free = free_cells(&env);
    let mut t = Table::<T>::new(&env, gamma, 1.0);
    let mut g = c.benchmark_group("qvalue-sweep/serpentine-511");
    g.throughput(Throughput::Elements(free.len() as u64 * 4));
    g.sample_size(10);
    g.bench_function(name, |b| b.iter(|| t.sweep(&env, &free)));
    g.finish();
}

fn bench(c: &mut Criterion) {
    group::<f32>(c, "f32-g0.99", 0.99);
    group::<f32>(c, "f32-g0.6", 0.6);
    group::<f64>(c, "f64-g0.6", 0.6);
    group::<SLog>(c, "slog-g0.6", 0.6);
}

criterion_group!(benches, bench);
criterion_main!(benches);
