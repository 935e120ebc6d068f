//! The tabular Q-learner: one type for the traditional and the improved learner, which differ
//! only in their [`PolicyConfig`] and whether the multi-target search is on.
//!
//! The step loop allocates nothing: a step is one table lookup for the move, one policy draw,
//! one Q update. The learner can be driven an episode at a time ([`Learner::run_episode`]) or a
//! step at a time ([`Learner::step`]) so that a fleet process can exchange Q-values between
//! steps without this crate knowing anything of the bus.

use crate::env::{CellKind, Env, Rewards, Transition};
use crate::grid::{Action, Cell};
use crate::known::{KnownReturns, PathPublisher, path_return};
use crate::metrics::{EpisodeRecord, Outcome, Summary};
use crate::policy::{EpsilonReading, Policy, PolicyConfig};
use crate::pseudo::PseudoConfig;
use crate::qtable::{QTable, max4};
use crate::rng::LearnRng;
use crate::task::Task;
use serde::{Deserialize, Serialize};

/// Which of the paper's two learners.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LearnerKind {
    /// ε-greedy, no pseudo targets.
    Traditional,
    /// Dynamic softmax with multi-target search.
    Improved,
    /// Ours (issue 9): ε-greedy with optimistic untried actions and Dyna-style sweeps over the
    /// transitions seen so far; `qfleet learn`'s default, chosen on the suite's tuning half.
    Planning,
}

impl std::str::FromStr for LearnerKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "traditional" => Ok(LearnerKind::Traditional),
            "improved" => Ok(LearnerKind::Improved),
            "planning" => Ok(LearnerKind::Planning),
            _ => Err(format!(
                "unknown learner '{s}' (expected traditional, improved or planning)"
            )),
        }
    }
}

impl std::fmt::Display for LearnerKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            LearnerKind::Traditional => "traditional",
            LearnerKind::Improved => "improved",
            LearnerKind::Planning => "planning",
        })
    }
}

/// What the paper's learners do not have: each is off (zero, `None`, false) in them, and each is
/// a named option with an ablation row in `qfleet eval`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Extras {
    /// Initial value of every action not tried yet (`None`: 0). Above every reachable value it
    /// makes the greedy policy try each action once, and, through the sweeps, walk to the
    /// nearest untried action: directed exploration without a random walk.
    pub optimistic: Option<f32>,
    /// Sweeps over every (state, action) seen so far after each episode, each a full backup
    /// Q(s,a) = r + γ·max Q(s') on the (deterministic) transition seen: Dyna-style planning.
    /// Sweeps alternate direction and stop early when one changes nothing.
    pub sweeps: u32,
    /// Replays the episode backwards after it ends (full backups along the moves taken), so the
    /// goal's value reaches the start in one episode however long the path.
    pub replay: bool,
    /// Also runs the sweeps every this many steps inside an episode when the model changed
    /// since the last sweep (0: after episodes only): the long exploring episodes at the start
    /// then act on what they have found so far (and, in a fleet, on the moves other robots
    /// made) instead of only after they end.
    pub sweep_every: u32,
}

impl Extras {
    /// Whether the learner must remember which transitions it has seen.
    pub fn needs_model(&self) -> bool {
        self.sweeps > 0 || self.replay
    }
}

/// Everything that defines a learning run; all parameters are settable.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LearnerConfig {
    /// α, the learning rate, in (0, 1].
    pub alpha: f32,
    /// γ, the discount, in [0, 1).
    pub gamma: f32,
    /// N, the number of episodes (> 0); also the horizon of the dynamic schedule.
    pub episodes: u32,
    /// Step cap per episode; 0 picks 50 × the free cells (at least 10 000).
    pub max_steps: u32,
    /// Rewards of goal, collision and plain moves.
    pub rewards: Rewards,
    /// Action selection.
    pub policy: PolicyConfig,
    /// Multi-target search; `None` turns it off.
    pub pseudo: Option<PseudoConfig>,
    /// Seed of the learner's random source.
    pub seed: u64,
    /// Optimism, planning sweeps and replay (all off in the paper's learners).
    #[serde(default)]
    pub extras: Extras,
}

/// A learner parameter out of range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    /// α must lie in (0, 1].
    #[error("alpha must be in (0, 1], got {0}")]
    Alpha(f32),
    /// γ must lie in [0, 1).
    #[error("gamma must be in [0, 1), got {0}")]
    Gamma(f32),
    /// At least one episode.
    #[error("episodes must be at least 1")]
    Episodes,
    /// ε must lie in [0, 1].
    #[error("epsilon must be in [0, 1], got {0}")]
    Epsilon(f32),
    /// The log-scale horizon must be positive and finite.
    #[error("horizon must be positive, got {0}")]
    Horizon(f32),
    /// Pseudo-target parameters: δ in (0, 1], removal fraction in [0, 1], radius ≥ 1.
    #[error(
        "pseudo targets need radius >= 1, delta in (0, 1] and remove-at in [0, 1]; got radius {radius}, delta {delta}, remove-at {remove_at}"
    )]
    Pseudo {
        /// R given.
        radius: u32,
        /// δ given.
        delta: f32,
        /// Removal fraction given.
        remove_at: f32,
    },
    /// Rewards must be finite.
    #[error("rewards must be finite numbers")]
    Rewards,
    /// The optimistic initial value must be finite.
    #[error("the optimistic initial value must be a finite number, got {0}")]
    Optimistic(f32),
}

impl LearnerConfig {
    /// The paper's traditional learner: ε-greedy, ε = 0.8 as the greedy probability.
    pub fn traditional(episodes: u32, seed: u64) -> Self {
        LearnerConfig {
            alpha: 0.1,
            gamma: 0.6,
            episodes,
            max_steps: 0,
            rewards: Rewards::default(),
            policy: PolicyConfig::TRADITIONAL,
            pseudo: None,
            seed,
            extras: Extras::default(),
        }
    }

    /// The paper's improved learner as replicated here: ε(k) as the exploration probability with
    /// a softmax over raw Q, pseudo targets R = 3, δ = 0.5, removed after N/10.
    pub fn paper_improved(episodes: u32, seed: u64) -> Self {
        Self::improved(episodes, seed)
    }

    /// The improved learner with this crate's defaults (explore schedule, raw-scale softmax,
    /// pseudo targets R = 3, δ = 0.5, removed after N/10).
    pub fn improved(episodes: u32, seed: u64) -> Self {
        LearnerConfig {
            policy: PolicyConfig::IMPROVED,
            pseudo: Some(PseudoConfig::default()),
            ..Self::traditional(episodes, seed)
        }
    }

    /// The planning learner (`qfleet learn`'s default): γ = 0.99 so values 1 000+ moves from the goal stay
    /// far above f32's smallest normal, ε-greedy with ε = 0.05 as the random-action
    /// probability, untried actions worth the goal reward, three sweeps over the seen
    /// transitions and a backward replay after every episode, the sweeps also every 1 024 steps
    /// inside an episode while the model grows, no pseudo targets. Chosen on the suite's tuning
    /// half (README "Map suite and held-out evaluation").
    pub fn planning(episodes: u32, seed: u64) -> Self {
        LearnerConfig {
            gamma: 0.99,
            policy: PolicyConfig::EpsilonGreedy {
                epsilon: 0.05,
                reading: EpsilonReading::Random,
            },
            extras: Extras {
                optimistic: Some(1.0),
                sweeps: 3,
                replay: true,
                sweep_every: 1024,
            },
            ..Self::traditional(episodes, seed)
        }
    }

    /// The default configuration of a learner kind.
    pub fn of_kind(kind: LearnerKind, episodes: u32, seed: u64) -> Self {
        match kind {
            LearnerKind::Traditional => Self::traditional(episodes, seed),
            LearnerKind::Improved => Self::improved(episodes, seed),
            LearnerKind::Planning => Self::planning(episodes, seed),
        }
    }

    /// Checks every parameter's range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if !(self.alpha > 0.0 && self.alpha <= 1.0) {
            return Err(ConfigError::Alpha(self.alpha));
        }
        if !(self.gamma >= 0.0 && self.gamma < 1.0) {
            return Err(ConfigError::Gamma(self.gamma));
        }
        if self.episodes == 0 {
            return Err(ConfigError::Episodes);
        }
        let r = self.rewards;
        if !(r.goal.is_finite() && r.collision.is_finite() && r.step.is_finite()) {
            return Err(ConfigError::Rewards);
        }
        match self.policy {
            PolicyConfig::EpsilonGreedy { epsilon, .. } if !(0.0..=1.0).contains(&epsilon) => {
                return Err(ConfigError::Epsilon(epsilon));
            }
            PolicyConfig::Softmax { horizon, .. } if !(horizon > 0.0 && horizon.is_finite()) => {
                return Err(ConfigError::Horizon(horizon));
            }
            _ => {}
        }
        if let Some(v) = self.extras.optimistic
            && !v.is_finite()
        {
            return Err(ConfigError::Optimistic(v));
        }
        if let Some(p) = self.pseudo
            && (p.radius == 0
                || !(p.delta > 0.0 && p.delta <= 1.0)
                || !(0.0..=1.0).contains(&p.remove_at))
        {
            return Err(ConfigError::Pseudo {
                radius: p.radius,
                delta: p.delta,
                remove_at: p.remove_at,
            });
        }
        Ok(())
    }

    /// Whether this learner's values are upper bounds of Q* (an optimistic start at least the
    /// goal reward, moves and collisions costing nothing or less, no pseudo targets: the
    /// planning learner), so that it publishes goal-path discoveries and ends an episode where
    /// another robot's discovered return shows its value exact (see [`crate::known`]). The same
    /// test as `qfleet_args::ValueBound::of`.
    pub fn path_discoveries(&self) -> bool {
        let r = self.rewards;
        self.extras.optimistic.is_some_and(|v| v >= r.goal.max(0.0))
            && r.step <= 0.0
            && r.collision <= 0.0
            && self.pseudo.is_none()
    }

    /// A short human-readable name of the policy, e.g. for tables.
    pub fn policy_label(&self) -> String {
        let base = self.policy_base_label();
        let x = self.extras;
        let mut extra = Vec::new();
        if let Some(v) = x.optimistic {
            extra.push(format!("optimistic {v}"));
        }
        if x.sweeps > 0 {
            extra.push(format!("{} sweeps", x.sweeps));
        }
        if x.replay {
            extra.push("replay".to_string());
        }
        if extra.is_empty() {
            base
        } else {
            format!("{base} + {}", extra.join(" + "))
        }
    }

    fn policy_base_label(&self) -> String {
        match self.policy {
            PolicyConfig::EpsilonGreedy { epsilon, reading } => {
                let r = if reading == EpsilonReading::Greedy {
                    "greedy"
                } else {
                    "random"
                };
                format!("eps-greedy(eps={epsilon} as {r} prob)")
            }
            PolicyConfig::Softmax {
                schedule, scale, ..
            } => format!("softmax({schedule}, {scale} Q)"),
        }
    }
}

/// What one step did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepInfo {
    /// Cell index the step started in.
    pub state: u32,
    /// Action taken (Q-table column).
    pub action: u8,
    /// Cell index after the step.
    pub next: u32,
    /// Q(state, action) after the update.
    pub q: f32,
    /// How the move ended.
    pub transition: Transition,
    /// Whether the episode is over (terminal cell or step cap).
    pub done: bool,
}

/// Rounds of sweeps [`Learner::settle`] runs at most (each round is up to `sweeps` sweeps).
pub const SETTLE_SWEEPS: u32 = 64;

/// The largest return a path of `cfg`'s task can have: the goal reward when moves cost
/// nothing or less (what [`KnownReturns`] refuses anything above).
fn return_ceiling(cfg: &LearnerConfig) -> f32 {
    cfg.rewards.goal.max(0.0)
}

/// A Q-learner on one task, with its table, policy, random source and episode counters.
#[derive(Debug, Clone)]
pub struct Learner {
    cfg: LearnerConfig,
    env: Env,
    q: QTable,
    policy: Policy,
    rng: LearnRng,
    optimal_len: u32,
    max_steps: u32,
    // Episode state.
    episode: u32,
    state: u32,
    steps: u32,
    collisions: u32,
    ret: f32,
    // Multi-target search.
    goal_found: bool,
    visited: Vec<bool>,
    pseudo_targets: Vec<(u32, f32)>,
    new_targets: Vec<(u32, f32)>,
    pseudo_removed: bool,
    // Scratch for greedy path extraction.
    stamp: Vec<u32>,
    stamp_gen: u32,
    // The model of sweeps and replay: per cell a bit per action tried, the (state·4 + action)
    // pairs in the order first tried, this episode's pairs, whether anything new was tried,
    // whether the last planning changed a value.
    tried: Vec<u8>,
    seen: Vec<u32>,
    trail: Vec<u32>,
    model_dirty: bool,
    planned: bool,
    swept_within: bool,
    // Updates never raise a value (see `keep_values_falling`).
    monotone: bool,
    // Moves of other robots joined the model since the last `settle_grid_moves`.
    grid_moves_pending: bool,
    // Goal-path discoveries (planning learner, see `crate::known`): what this learner
    // publishes of its own found paths, the returns others found, and the scratch of the path
    // walk (reused: no allocation once grown).
    path_pub: Option<PathPublisher>,
    known: Option<KnownReturns>,
    path_cells: Vec<u32>,
    path_returns: Vec<f32>,
    pred_at: Vec<u32>,
    pred: Vec<u32>,
    dist: Vec<u32>,
    // Model size at the last search for a known path (none: 0).
    path_searched_at: usize,
}

impl Learner {
    /// A fresh learner (zero Q-table) for a task.
    pub fn new(task: &Task, cfg: LearnerConfig) -> Result<Learner, ConfigError> {
        cfg.validate()?;
        let env = Env::new(&task.grid, task.start, task.goal, cfg.rewards);
        let free = task.grid.free_count() as u64;
        let max_steps = if cfg.max_steps > 0 {
            cfg.max_steps
        } else {
            (free * 50).clamp(10_000, u32::MAX as u64) as u32
        };
        let n = task.grid.len();
        let mut q = QTable::new(&task.grid);
        if let Some(v) = cfg.extras.optimistic {
            let free = task.grid.free_flags();
            for (idx, row) in q.rows_mut().iter_mut().enumerate() {
                if free[idx] {
                    *row = [v; 4];
                }
            }
        }
        let model = cfg.extras.needs_model();
        Ok(Learner {
            policy: Policy::new(cfg.policy, cfg.gamma),
            rng: LearnRng::new(cfg.seed),
            q,
            tried: if model { vec![0; n] } else { Vec::new() },
            seen: if model {
                Vec::with_capacity(task.grid.free_count() * 4)
            } else {
                Vec::new()
            },
            trail: if cfg.extras.replay {
                Vec::with_capacity((max_steps as usize).min(1 << 16))
            } else {
                Vec::new()
            },
            model_dirty: false,
            planned: false,
            swept_within: false,
            monotone: false,
            grid_moves_pending: false,
            path_pub: cfg.path_discoveries().then(|| PathPublisher::new(n)),
            known: cfg
                .path_discoveries()
                .then(|| KnownReturns::new(n, return_ceiling(&cfg))),
            path_cells: Vec::new(),
            path_returns: Vec::new(),
            pred_at: Vec::new(),
            pred: Vec::new(),
            dist: Vec::new(),
            path_searched_at: 0,
            optimal_len: task.optimal_len,
            max_steps,
            episode: 0,
            state: env.start(),
            steps: 0,
            collisions: 0,
            ret: 0.0,
            goal_found: false,
            visited: if cfg.pseudo.is_some() {
                vec![false; n]
            } else {
                Vec::new()
            },
            pseudo_targets: Vec::new(),
            new_targets: Vec::new(),
            pseudo_removed: false,
            stamp: vec![0; n],
            stamp_gen: 0,
            env,
            cfg,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &LearnerConfig {
        &self.cfg
    }

    /// The environment (grid, start, goal, active pseudo targets).
    pub fn env(&self) -> &Env {
        &self.env
    }

    /// The Q-table.
    pub fn q(&self) -> &QTable {
        &self.q
    }

    /// The Q-table, for applying values learned elsewhere (e.g. a fleet's merged hints); call
    /// [`table_changed`](Self::table_changed) when something was changed.
    pub fn q_mut(&mut self) -> &mut QTable {
        &mut self.q
    }

    /// From now on no update (step, replay, sweep) raises a value: each takes the smaller of
    /// the value held and its new target. For a learner whose values are upper bounds of Q*
    /// (optimistic start, see `qfleet_args::ValueBound`) both are upper bounds, so the smaller
    /// is one too. Alone such a learner never raises a value anyway (from an optimistic start
    /// every backup is at most the value it replaces), so this changes nothing there; in a
    /// fleet it keeps a tighter bound set from outside (a merged hint, `min` rule) from being
    /// raised again by the next backup from this robot's own, looser neighbours.
    pub fn keep_values_falling(&mut self) {
        self.monotone = true;
    }

    /// Adds the move `a` from cell `s` to the model the sweeps back up, as if this learner had
    /// tried it: another robot of the fleet did, and the grid is deterministic, so its
    /// transition is known (a shared model). Returns whether it was new; false for a learner
    /// without a model, a cell out of the grid or not free, or an action out of range.
    pub fn add_known_move(&mut self, s: u32, a: usize) -> bool {
        let i = s as usize;
        if self.tried.is_empty()
            || a >= 4
            || i >= self.tried.len()
            || !self.env.grid().free_flags()[i]
            || self.tried[i] & (1 << a) != 0
        {
            return false;
        }
        self.tried[i] |= 1 << a;
        self.seen.push(s * 4 + a as u32);
        self.model_dirty = true;
        true
    }

    /// Adds what another robot's move `a` from cell `s` tells of the grid this learner shares
    /// with it (a robot of another goal on the same map): the grid is deterministic and
    /// 4-connected and each of its cells free or blocked, so the move reveals two cells — `s`,
    /// free since the robot stood there, and the cell `a` leads to, free or (the move collided)
    /// blocked — and with them the outcome of every move *into* either cell from a free
    /// neighbour, the move itself, its way back and the other moves into a wall it found
    /// included. Each joins the model as [`add_known_move`](Self::add_known_move) would add it;
    /// a move off the grid reveals no second cell. The values are brought up to date by
    /// [`settle_grid_moves`](Self::settle_grid_moves). Returns how many moves were new (0 for a
    /// learner without a model, or `s`/`a` out of range or on a blocked cell).
    pub fn add_grid_move(&mut self, s: u32, a: usize) -> u32 {
        let grid = self.env.grid();
        let i = s as usize;
        if self.tried.is_empty() || a >= 4 || i >= grid.len() || !grid.free_flags()[i] {
            return 0;
        }
        let to = grid
            .adjacent(grid.cell(i), Action::from_index(a))
            .map(|c| grid.index(c) as u32);
        let mut new = u32::from(self.add_known_move(s, a));
        new += self.add_moves_into(s);
        if let Some(t) = to {
            new += self.add_moves_into(t);
        }
        if new > 0 {
            self.grid_moves_pending = true;
        }
        new
    }

    /// Adds every move into cell `c` from a free 4-neighbour (see
    /// [`add_grid_move`](Self::add_grid_move)); returns how many were new.
    fn add_moves_into(&mut self, c: u32) -> u32 {
        let grid = self.env.grid();
        let cell = grid.cell(c as usize);
        // the free neighbour on side `act` moves into `c` by the opposite action, (act + 2) mod 4
        let from = Action::ALL.map(|act| grid.neighbor(cell, act).map(|n| grid.index(n) as u32));
        let mut new = 0;
        for (act, n) in from.into_iter().enumerate() {
            if let Some(n) = n {
                new += u32::from(self.add_known_move(n, (act + 2) & 3));
            }
        }
        new
    }

    /// After moves of other robots joined the model ([`add_grid_move`](Self::add_grid_move)):
    /// sweeps until the values agree with the whole model again ([`settle`](Self::settle));
    /// nothing when none joined since the last call. The per-episode sweeps are budgeted for
    /// a model that grows by this learner's own trajectory, whose backward replay has already
    /// carried the values along it; moves from outside come in bulk, in no useful order and
    /// with no trajectory to replay, and within that budget a learner that was handed the
    /// whole grid kept a looping greedy path for thousands of steps, exploring on optimistic
    /// values the new moves had already refuted. Returns whether a value changed.
    pub fn settle_grid_moves(&mut self) -> bool {
        if !std::mem::take(&mut self.grid_moves_pending) {
            return false;
        }
        self.settle()
    }

    /// Values were set from outside ([`q_mut`](Self::q_mut)): the next episode's sweeps run
    /// even if this learner tried nothing new, so that they reach the pairs leading there.
    pub fn table_changed(&mut self) {
        self.model_dirty = true;
    }

    /// The (state·4 + action) pairs tried so far, in the order first tried (empty for a learner
    /// without replay or sweeps): what a fleet robot offers to share after planning changed
    /// their values.
    pub fn tried_pairs(&self) -> &[u32] {
        &self.seen
    }

    /// Episodes finished so far.
    pub fn episodes_done(&self) -> u32 {
        self.episode
    }

    /// Whether all configured episodes are done.
    pub fn finished(&self) -> bool {
        self.episode >= self.cfg.episodes
    }

    /// The step cap per episode in force.
    pub fn max_steps(&self) -> u32 {
        self.max_steps
    }

    /// The BFS optimum of the task, in moves.
    pub fn optimal_len(&self) -> u32 {
        self.optimal_len
    }

    /// Active pseudo targets as (cell index, value).
    pub fn pseudo_targets(&self) -> &[(u32, f32)] {
        if self.pseudo_removed {
            &[]
        } else {
            &self.pseudo_targets
        }
    }

    /// Discoveries this learner made itself since the last call, to share with others: pseudo
    /// targets (the paper's improved learner) or cells of a found goal path with their return
    /// along it (the planning learner, [`crate::known`]).
    pub fn take_new_pseudo_targets(&mut self) -> Vec<(u32, f32)> {
        std::mem::take(&mut self.new_targets)
    }

    /// Adds a pseudo target found by someone else; false if pseudo targets are off, already
    /// removed, or the cell cannot be one.
    pub fn add_pseudo_target(&mut self, cell: u32, value: f32) -> bool {
        // The robot's own cell never becomes terminal under its feet.
        if self.cfg.pseudo.is_none()
            || self.pseudo_removed
            || cell == self.state
            || self.env.kind(cell.min(self.env.grid().len() as u32 - 1)) != CellKind::Plain
        {
            return false;
        }
        if self.env.set_pseudo(cell, value) {
            self.pseudo_targets.push((cell, value));
            true
        } else {
            false
        }
    }

    /// Takes another robot's discovery of cell `cell` worth `value`, as this learner uses one:
    /// a pseudo target of its own (the paper's improved learner, [`add_pseudo_target`](Self::add_pseudo_target)),
    /// or a known return of a goal path (the planning learner, [`crate::known`]). False if
    /// this learner uses neither, or the discovery adds nothing.
    pub fn add_discovery(&mut self, cell: u32, value: f32) -> bool {
        match self.known.as_mut() {
            Some(k) => {
                let grid = self.env.grid();
                (cell as usize) < grid.len()
                    && grid.free_flags()[cell as usize]
                    && cell != self.env.goal()
                    && k.offer(cell, value)
            }
            None => self.add_pseudo_target(cell, value),
        }
    }

    /// The goal-path returns other robots discovered (planning learner; `None` for the paper's).
    pub fn known_returns(&self) -> Option<&KnownReturns> {
        self.known.as_ref()
    }

    /// Whether entering `next` ends the episode by a known return (see [`crate::known`]):
    /// the cheap test on every step, the walk on only where it passes.
    #[inline(always)]
    fn ends_at_known(&self, next: u32) -> bool {
        match &self.known {
            Some(k) if !k.is_empty() && k.exact_at(next, max4(self.q.row(next as usize))) => {
                k.certifies(next, self.known_walk_return(next))
            }
            _ => false,
        }
    }

    /// The return of the greedy walk from `from` to the goal when every move of it is in the
    /// model (tried here or made known from outside); `None` when it takes an untried action,
    /// collides or loops. Kept out of line: it runs only where a value is exact.
    #[inline(never)]
    fn known_walk_return(&self, from: u32) -> Option<f32> {
        if self.tried.is_empty() {
            return None;
        }
        let goal = self.env.goal();
        let mut s = from;
        let mut moves = 0u32;
        while s != goal {
            let a = self.q.argmax(s as usize);
            if self.tried[s as usize] & (1 << a) == 0 || moves as usize >= self.tried.len() {
                return None;
            }
            s = self.env.peek(s, a)?;
            moves += 1;
        }
        let r = self.cfg.rewards;
        (moves > 0).then(|| path_return(moves, r.goal, r.step, self.cfg.gamma))
    }

    /// After an episode that reached the goal (planning learner): when the shortest path from
    /// the start over the moves this learner knows ([`known_path`](Self::known_path)) is the
    /// first or shorter than any published, hands some of its cells with their returns along
    /// it to [`take_new_pseudo_targets`](Self::take_new_pseudo_targets) (see
    /// [`crate::known`]). Stops once the published path is optimal. The path, its returns and
    /// the search use scratch vectors reused from episode to episode.
    fn discover_goal_path(&mut self) {
        if !self
            .path_pub
            .as_ref()
            .is_some_and(|p| p.published() < PathPublisher::CAP && p.wants(self.optimal_len.max(1)))
        {
            return;
        }
        // the search's answer changes only with the model
        if self.seen.len() == self.path_searched_at {
            return;
        }
        self.path_searched_at = self.seen.len();
        let Some(moves) = self.known_path() else {
            return;
        };
        if !self.path_pub.as_ref().is_some_and(|p| p.wants(moves)) {
            return;
        }
        // returns from the goal back, with the learner's own backup arithmetic (`path_return`)
        let r = self.cfg.rewards;
        let moves = moves as usize;
        self.path_returns.clear();
        self.path_returns.resize(moves, 0.0);
        let mut v = r.goal;
        for i in (0..moves).rev() {
            if i + 1 < moves {
                v = r.step + self.cfg.gamma * v;
            }
            self.path_returns[i] = v;
        }
        if let Some(p) = self.path_pub.as_mut() {
            p.publish(&self.path_cells, &self.path_returns, &mut self.new_targets);
        }
    }

    /// The shortest path from the start to the goal over the moves in this learner's model
    /// (its own and those made known from outside; collisions are no moves), into
    /// `path_cells` (start first, goal last); its moves, or `None` if the model holds no such
    /// path. A breadth-first search back from the goal over the model's moves reversed.
    fn known_path(&mut self) -> Option<u32> {
        let n = self.tried.len();
        if n == 0 {
            return None;
        }
        let (start, goal) = (self.env.start() as usize, self.env.goal() as usize);
        // predecessors of every cell over the known moves, compressed rows in `pred_at`/`pred`
        let at = &mut self.pred_at;
        at.clear();
        at.resize(n + 1, 0);
        for &sa in &self.seen {
            if let Some(t) = self.env.peek(sa >> 2, (sa & 3) as usize)
                && t != sa >> 2
            {
                at[t as usize + 1] += 1;
            }
        }
        for i in 0..n {
            at[i + 1] += at[i];
        }
        let pred = &mut self.pred;
        pred.clear();
        pred.resize(at[n] as usize, 0);
        // the next free place of every row (the distances' scratch until the search)
        let dist = &mut self.dist;
        dist.clear();
        dist.extend_from_slice(&at[..n]);
        for &sa in &self.seen {
            let s = sa >> 2;
            if let Some(t) = self.env.peek(s, (sa & 3) as usize)
                && t != s
            {
                let k = &mut dist[t as usize];
                pred[*k as usize] = s;
                *k += 1;
            }
        }
        // distances to the goal over them
        dist.fill(u32::MAX);
        let queue = &mut self.path_cells;
        queue.clear();
        dist[goal] = 0;
        queue.push(goal as u32);
        let mut head = 0;
        while head < queue.len() && dist[start] == u32::MAX {
            let c = queue[head] as usize;
            head += 1;
            for &p in &pred[at[c] as usize..at[c + 1] as usize] {
                if dist[p as usize] == u32::MAX {
                    dist[p as usize] = dist[c] + 1;
                    queue.push(p);
                }
            }
        }
        let moves = dist[start];
        if moves == u32::MAX {
            return None;
        }
        // and the path down them from the start, by known moves only
        let path = &mut self.path_cells;
        path.clear();
        let mut s = start;
        path.push(s as u32);
        while s != goal {
            let next = (0..4).find_map(|a| {
                let t = self.env.peek(s as u32, a)? as usize;
                (self.tried[s] & (1 << a) != 0 && dist[t] < dist[s] && dist[t] + 1 == dist[s])
                    .then_some(t)
            })?;
            s = next;
            path.push(s as u32);
        }
        Some(moves)
    }

    /// Resets the episode state and applies the schedule for the coming episode.
    pub fn begin_episode(&mut self) {
        self.policy.begin_episode(self.episode, self.cfg.episodes);
        if let Some(p) = self.cfg.pseudo
            && !self.pseudo_removed
            && self.episode >= p.removal_episode(self.cfg.episodes)
        {
            for &(c, _) in &self.pseudo_targets {
                self.env.clear_pseudo(c);
            }
            self.pseudo_removed = true;
        }
        self.state = self.env.start();
        self.steps = 0;
        self.collisions = 0;
        self.ret = 0.0;
        self.trail.clear();
    }

    /// Takes one step of the current episode: choose, move, update Q.
    #[inline]
    pub fn step(&mut self) -> StepInfo {
        let s = self.state;
        let a = self.policy.choose(self.q.row(s as usize), &mut self.rng);
        let (next, r, t) = self.env.step(s, a);
        let terminal = matches!(t, Transition::Goal | Transition::Pseudo);
        let target = if terminal {
            r
        } else {
            r + self.cfg.gamma * max4(self.q.row(next as usize))
        };
        let row = self.q.row_mut(s as usize);
        let mut q = row[a] + self.cfg.alpha * (target - row[a]);
        if self.monotone {
            q = q.min(row[a]);
        }
        row[a] = q;
        self.steps += 1;
        self.collisions += (t == Transition::Collided) as u32;
        self.ret += r;
        self.state = next;
        if !self.goal_found && !self.visited.is_empty() {
            self.visited[next as usize] = true;
        }
        if !self.tried.is_empty() {
            self.record(s, a);
            if self.cfg.extras.sweep_every != 0 {
                self.sweep_within();
            }
        }
        // another robot's goal-path discovery shows the value here exact: the walk on follows
        // exact values and tells nothing new, the episode ends (as at a pseudo target)
        let cut = !terminal && self.ends_at_known(next);
        StepInfo {
            state: s,
            action: a as u8,
            next,
            q,
            transition: if cut { Transition::Pseudo } else { t },
            done: terminal || cut || self.steps >= self.max_steps,
        }
    }

    /// Closes the current episode after `step` reported `done` (or to abandon it).
    pub fn end_episode(&mut self, last: Transition) -> EpisodeRecord {
        let outcome = match last {
            Transition::Goal => Outcome::Goal,
            Transition::Pseudo => Outcome::Pseudo,
            _ => Outcome::Cap,
        };
        if outcome == Outcome::Goal && !self.goal_found {
            self.goal_found = true;
            self.discover_pseudo_targets();
        }
        self.plan();
        if outcome != Outcome::Cap {
            self.discover_goal_path();
        }
        let rec = EpisodeRecord {
            episode: self.episode,
            steps: self.steps,
            collisions: self.collisions,
            outcome,
            ret: self.ret,
            greedy_path_len: self.greedy_path_len(),
        };
        self.episode += 1;
        rec
    }

    /// Runs one whole episode.
    pub fn run_episode(&mut self) -> EpisodeRecord {
        self.begin_episode();
        loop {
            let s = self.step();
            if s.done {
                return self.end_episode(s.transition);
            }
        }
    }

    /// Runs the remaining episodes, calling `on_episode` after each; returns the summary.
    pub fn run(
        &mut self,
        mut on_episode: impl FnMut(&EpisodeRecord),
    ) -> (Vec<EpisodeRecord>, Summary) {
        let mut records =
            Vec::with_capacity(self.cfg.episodes.saturating_sub(self.episode) as usize);
        while !self.finished() {
            let r = self.run_episode();
            on_episode(&r);
            records.push(r);
        }
        let summary = Summary::from_records(&records, self.optimal_len, self.greedy_path_len());
        (records, summary)
    }

    /// Remembers that action `a` was tried in `s` (model of sweeps and replay). Pushes stay
    /// within the capacity reserved at construction, except the episode trail, which grows
    /// geometrically and is then reused: no allocation in steady state. Kept out of line: the
    /// paper's learners never call it and their step stays small.
    #[inline(never)]
    fn record(&mut self, s: u32, a: usize) {
        let bit = 1u8 << a;
        let t = &mut self.tried[s as usize];
        if *t & bit == 0 {
            *t |= bit;
            self.seen.push(s * 4 + a as u32);
            self.model_dirty = true;
        }
        if self.cfg.extras.replay {
            self.trail.push(s * 4 + a as u32);
        }
    }

    /// Full backup of one seen pair: Q(s,a) = r + γ·max Q(s'); returns whether it changed.
    #[inline(always)]
    fn backup(&mut self, sa: u32) -> bool {
        let (s, a) = ((sa >> 2) as usize, (sa & 3) as usize);
        let (next, r, t) = self.env.step(s as u32, a);
        let v = if matches!(t, Transition::Goal | Transition::Pseudo) {
            r
        } else {
            r + self.cfg.gamma * max4(self.q.row(next as usize))
        };
        let row = self.q.row_mut(s);
        let v = if self.monotone { v.min(row[a]) } else { v };
        let changed = row[a] != v;
        row[a] = v;
        changed
    }

    /// After an episode: the backward replay of its moves, then up to `sweeps` sweeps over every
    /// pair seen, alternating direction, stopping once a sweep changes nothing. Skipped when the
    /// model has not changed since a sweep that changed nothing.
    fn plan(&mut self) {
        let x = self.cfg.extras;
        self.planned = false;
        if x.replay {
            for i in (0..self.trail.len()).rev() {
                let sa = self.trail[i];
                self.planned |= self.backup(sa);
            }
        }
        let swept = self.sweep_now();
        self.planned |= swept;
    }

    /// The sweeps inside an episode, every [`Extras::sweep_every`] steps (see there).
    #[inline(never)]
    fn sweep_within(&mut self) {
        if self.steps.is_multiple_of(self.cfg.extras.sweep_every) && self.sweep_now() {
            self.swept_within = true;
        }
    }

    /// Whether sweeps inside the episode changed values since the last call (a fleet robot
    /// then offers its values, as after an episode); clears the flag.
    pub fn take_swept_within(&mut self) -> bool {
        std::mem::take(&mut self.swept_within)
    }

    /// Up to `sweeps` sweeps over every pair seen, alternating direction, stopping once one
    /// changes nothing; skipped when the model (own moves, [`add_known_move`](Self::add_known_move),
    /// [`table_changed`](Self::table_changed)) has not changed since such a sweep. Used after an
    /// episode and inside one ([`Extras::sweep_every`]); returns whether a value changed.
    fn sweep_now(&mut self) -> bool {
        let x = self.cfg.extras;
        if x.sweeps == 0 || !self.model_dirty {
            return false;
        }
        let mut any = false;
        for k in 0..x.sweeps {
            let mut changed = false;
            if k.is_multiple_of(2) {
                for i in (0..self.seen.len()).rev() {
                    changed |= self.backup(self.seen[i]);
                }
            } else {
                for i in 0..self.seen.len() {
                    changed |= self.backup(self.seen[i]);
                }
            }
            any |= changed;
            if !changed {
                self.model_dirty = false;
                break;
            }
        }
        any
    }

    /// Sweeps until the values are consistent with every move in the model again (at most
    /// [`SETTLE_SWEEPS`] rounds of sweeps); returns whether a value changed. For values set from
    /// outside after the last episode (a fleet's merged hints arriving while the robot waits for
    /// the end of the run): without it those values stay unpropagated, and a greedy path read
    /// then can loop through a cell whose bound fell while its neighbours' did not.
    pub fn settle(&mut self) -> bool {
        let mut any = false;
        for _ in 0..SETTLE_SWEEPS {
            if !self.sweep_now() {
                break;
            }
            any = true;
        }
        any
    }

    /// Whether the replay or sweeps after the last episode changed any value (what a fleet
    /// robot then offers to share, see [`tried_pairs`](Self::tried_pairs)).
    pub fn planned(&self) -> bool {
        self.planned
    }

    fn discover_pseudo_targets(&mut self) {
        let Some(p) = self.cfg.pseudo else { return };
        if self.pseudo_removed {
            return;
        }
        let grid = self.env.grid();
        let goal = grid.cell(self.env.goal() as usize);
        let mut found = Vec::new();
        for (idx, seen) in self.visited.iter().enumerate() {
            let d = grid.cell(idx).manhattan(goal);
            if *seen && d >= 1 && d <= p.radius {
                found.push((idx as u32, p.value(d, self.cfg.rewards.goal)));
            }
        }
        for (c, v) in found {
            if self.env.set_pseudo(c, v) {
                self.pseudo_targets.push((c, v));
                self.new_targets.push((c, v));
            }
        }
        self.visited = Vec::new();
    }

    /// Moves of the greedy path from the start to the true goal, or `None` if it loops or collides.
    pub fn greedy_path_len(&mut self) -> Option<u32> {
        self.stamp_gen = self.stamp_gen.wrapping_add(1);
        if self.stamp_gen == 0 {
            self.stamp.fill(0);
            self.stamp_gen = 1;
        }
        let (mut s, goal) = (self.env.start(), self.env.goal());
        let mut len = 0;
        while s != goal {
            if self.stamp[s as usize] == self.stamp_gen {
                return None;
            }
            self.stamp[s as usize] = self.stamp_gen;
            s = self.env.peek(s, self.q.argmax(s as usize))?;
            len += 1;
        }
        Some(len)
    }

    /// The greedy path from the start as cells (start and goal included), or `None` if it loops.
    pub fn greedy_path(&self) -> Option<Vec<Cell>> {
        greedy_path(&self.env, &self.q)
    }
}

/// The greedy path of a Q-table in an environment, or `None` if it loops or collides.
pub fn greedy_path(env: &Env, q: &QTable) -> Option<Vec<Cell>> {
    let grid = env.grid();
    let mut seen = vec![false; grid.len()];
    let mut s = env.start();
    let mut path = vec![grid.cell(s as usize)];
    while s != env.goal() {
        if std::mem::replace(&mut seen[s as usize], true) {
            return None;
        }
        s = env.peek(s, q.argmax(s as usize))?;
        path.push(grid.cell(s as usize));
    }
    Some(path)
}
