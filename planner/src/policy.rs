//! Action-selection policies: the traditional ε-greedy and the paper's dynamic softmax.
//!
//! The paper is ambiguous in two places, and each reading is a named option:
//! - ε-greedy's ε = 0.8 is called the probability of a *random* action, but the paper's
//!   average-step figures only fit ε as the probability of the *greedy* action
//!   ([`EpsilonReading::Greedy`], the default).
//! - The dynamic factor ε(k) = 1 − 0.49·2^(k/N) falls from 0.51 to 0.02. Used literally as the
//!   softmax's inverse temperature β ([`Schedule::Literal`]) the policy becomes *more* random as
//!   learning goes on, against the paper's own text; read as a temperature, β = 1/ε(k)
//!   ([`Schedule::Temperature`], the default) it moves from exploring to exploiting.
//!
//! A third choice is ours: the scale of Q the softmax sees ([`QScale`]). With γ = 0.6, Q-values
//! 20 moves from the goal are ~1e-5 of the goal reward, so a softmax over raw Q is uniform far
//! from the goal. [`QScale::Log`] (the default) turns each Q into the number of moves it is
//! behind the best action of its state, log_{1/γ}(max Q / Q), which is what a discounted value
//! encodes and does not depend on how far the state is from the goal.

use crate::fastmath::{exp_neg, log2_pos};
use crate::qtable::{max4, min4};
use crate::rng::LearnRng;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// What the traditional learner's ε means.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum EpsilonReading {
    /// ε is the probability of the greedy action (fits the paper's figures; default).
    Greedy,
    /// ε is the probability of a uniformly random action (the paper's words).
    Random,
}

/// How the dynamic factor ε(k) enters the softmax.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Schedule {
    /// β = ε(k): the literal reading; the policy gets more random over time.
    Literal,
    /// β = 1/ε(k): ε(k) as a temperature; the policy gets greedier over time (default).
    Temperature,
    /// ε(k) as the probability of exploring, by a softmax with β = 1; greedy otherwise.
    Explore,
}

/// The scale on which the softmax compares the four Q-values of a state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum QScale {
    /// β·Q as written in the paper: depends on the magnitude of Q.
    Raw,
    /// β·(Q − max Q)/(max Q − min Q): per-state min–max normalised.
    Range,
    /// β·log_{1/γ}(Q / max Q): moves behind the best action; scale-free (default).
    Log,
}

/// Which policy a learner uses, with its parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum PolicyConfig {
    /// The traditional learner's ε-greedy policy.
    EpsilonGreedy {
        /// ε, read as [`EpsilonReading`] says.
        epsilon: f32,
        /// Whether ε is the greedy or the random probability.
        reading: EpsilonReading,
    },
    /// The improved learner's dynamic softmax.
    Softmax {
        /// How ε(k) becomes the inverse temperature.
        schedule: Schedule,
        /// How Q-values are scaled before the softmax.
        scale: QScale,
        /// Under [`QScale::Log`], how many moves behind a zero or negative Q counts as.
        horizon: f32,
    },
}

impl PolicyConfig {
    /// The paper's traditional ε-greedy with ε = 0.8 as the greedy probability.
    pub const TRADITIONAL: PolicyConfig = PolicyConfig::EpsilonGreedy {
        epsilon: 0.8,
        reading: EpsilonReading::Greedy,
    };
    /// The improved learner's default: ε(k) as the exploration probability, softmax exploration
    /// over raw Q (chosen by measurement: see BENCHMARKS.md and `qfleet replicate --ablation`).
    pub const IMPROVED: PolicyConfig = PolicyConfig::Softmax {
        schedule: Schedule::Explore,
        scale: QScale::Raw,
        horizon: 8.0,
    };
}

/// The paper's dynamic factor ε(k) = 1 − 0.49·2^(k/N): 0.51 at k = 0, 0.02 at k = N (and
/// after: a learner that runs on past N keeps the final value instead of going negative).
pub fn dynamic_epsilon(k: u32, n: u32) -> f32 {
    let n = n.max(1);
    (1.0 - 0.49 * (k.min(n) as f64 / n as f64).exp2()) as f32
}

/// A policy ready to act: the configuration plus the per-episode inverse temperature.
#[derive(Debug, Clone)]
pub struct Policy {
    config: PolicyConfig,
    /// Probability of a uniformly random action (ε-greedy only).
    p_random: f32,
    /// Inverse temperature of the current episode (softmax only).
    beta: f32,
    /// β / log2(1/γ), so that `beta_log * log2(q / max)` counts moves behind the best.
    beta_log: f32,
    inv_log2_inv_gamma: f32,
}

impl Policy {
    /// A policy for a learner with discount `gamma`.
    pub fn new(config: PolicyConfig, gamma: f32) -> Policy {
        let p_random = match config {
            PolicyConfig::EpsilonGreedy {
                epsilon,
                reading: EpsilonReading::Greedy,
            } => 1.0 - epsilon,
            PolicyConfig::EpsilonGreedy {
                epsilon,
                reading: EpsilonReading::Random,
            } => epsilon,
            PolicyConfig::Softmax { .. } => 0.0,
        };
        // γ in (0, 1): log2(1/γ) > 0. γ = 0 makes every non-terminal Q equal; any slope works.
        let l = if gamma > 0.0 && gamma < 1.0 {
            (1.0 / gamma).log2()
        } else {
            1.0
        };
        let mut p = Policy {
            config,
            p_random,
            beta: 0.0,
            beta_log: 0.0,
            inv_log2_inv_gamma: 1.0 / l,
        };
        p.begin_episode(0, 1);
        p
    }

    /// The configuration.
    pub fn config(&self) -> PolicyConfig {
        self.config
    }

    /// The inverse temperature in force (0 for ε-greedy).
    pub fn beta(&self) -> f32 {
        self.beta
    }

    /// Sets the episode-dependent factor for episode `k` of `n`.
    pub fn begin_episode(&mut self, k: u32, n: u32) {
        if let PolicyConfig::Softmax { schedule, .. } = self.config {
            let e = dynamic_epsilon(k, n);
            self.beta = match schedule {
                Schedule::Literal => e,
                Schedule::Temperature => 1.0 / e,
                Schedule::Explore => 1.0,
            };
            if schedule == Schedule::Explore {
                self.p_random = e;
            }
            self.beta_log = self.beta * self.inv_log2_inv_gamma;
        }
    }

    /// Chooses an action for a state with action values `q`.
    #[inline(always)]
    pub fn choose(&self, q: &[f32; 4], rng: &mut LearnRng) -> usize {
        match self.config {
            PolicyConfig::EpsilonGreedy { .. } => {
                let bits = rng.bits();
                if LearnRng::unit_from(bits) < self.p_random {
                    (bits & 3) as usize
                } else {
                    greedy_random_ties(q, bits)
                }
            }
            PolicyConfig::Softmax { schedule, .. } => {
                // One draw serves every decision: bits 40..64 the explore coin, bits 2..18 the
                // greedy tie-break, bits 16..40 the softmax sample (the last two never both).
                let bits = rng.bits();
                if schedule == Schedule::Explore && LearnRng::unit_from(bits) >= self.p_random {
                    return greedy_random_ties(q, bits);
                }
                let w = self.weights(q);
                let u = ((bits >> 16) & 0xff_ffff) as f32
                    * (1.0 / (1u32 << 24) as f32)
                    * (w[0] + w[1] + w[2] + w[3]);
                let c0 = w[0];
                let c1 = c0 + w[1];
                let c2 = c1 + w[2];
                // Branch-free inverse-CDF lookup: the outcome is random, a branch would mispredict.
                (u >= c0) as usize + (u >= c1) as usize + (u >= c2) as usize
            }
        }
    }

    /// Unnormalised softmax weights of the four actions; the largest is 1.
    #[inline(always)]
    fn weights(&self, q: &[f32; 4]) -> [f32; 4] {
        let PolicyConfig::Softmax { scale, horizon, .. } = self.config else {
            return [1.0; 4];
        };
        let max = max4(q);
        match scale {
            QScale::Raw => map4(q, |v| exp_neg(self.beta * (v - max))),
            QScale::Log if max > 0.0 => {
                let lm = log2_pos(max);
                let floor = -horizon;
                map4(q, |v| {
                    let behind = if v > 0.0 {
                        crate::qtable::fmax((log2_pos(v) - lm) * self.inv_log2_inv_gamma, floor)
                    } else {
                        floor
                    };
                    exp_neg(self.beta * behind)
                })
            }
            // Range, and Log for states that have seen no positive value yet.
            QScale::Range | QScale::Log => {
                let min = min4(q);
                let span = max - min;
                if span > 0.0 {
                    // (v - max) / span lies in [-1, 0] even when span is subnormal.
                    map4(q, |v| exp_neg(self.beta * ((v - max) / span)))
                } else {
                    [1.0; 4]
                }
            }
        }
    }

    /// The probability of each action in a state with values `q` (for tests and plots).
    pub fn probabilities(&self, q: &[f32; 4]) -> [f32; 4] {
        match self.config {
            PolicyConfig::EpsilonGreedy { .. } => {
                let max = max4(q);
                let ties = q.iter().filter(|v| **v == max).count() as f32;
                q.map(|v| {
                    self.p_random / 4.0
                        + if v == max {
                            (1.0 - self.p_random) / ties
                        } else {
                            0.0
                        }
                })
            }
            PolicyConfig::Softmax { schedule, .. } => {
                let w = self.weights(q);
                let s: f32 = w.iter().sum();
                if schedule == Schedule::Explore {
                    let max = max4(q);
                    let ties = q.iter().filter(|v| **v == max).count() as f32;
                    let mut p = [0.0; 4];
                    for a in 0..4 {
                        p[a] = self.p_random * w[a] / s
                            + if q[a] == max {
                                (1.0 - self.p_random) / ties
                            } else {
                                0.0
                            };
                    }
                    p
                } else {
                    w.map(|x| x / s)
                }
            }
        }
    }
}

/// `[f(q0), f(q1), f(q2), f(q3)]`, written out: `<[T; 4]>::map` goes through a generic
/// `try_map` that the optimiser does not always flatten in this loop (measured with callgrind).
#[inline(always)]
fn map4(q: &[f32; 4], f: impl Fn(f32) -> f32) -> [f32; 4] {
    [f(q[0]), f(q[1]), f(q[2]), f(q[3])]
}

/// The greedy action, with ties broken uniformly by spare random bits.
#[inline(always)]
fn greedy_random_ties(q: &[f32; 4], bits: u64) -> usize {
    let max = max4(q);
    let mask = (q[0] == max) as u32
        | ((q[1] == max) as u32) << 1
        | ((q[2] == max) as u32) << 2
        | ((q[3] == max) as u32) << 3;
    if mask.is_power_of_two() {
        return mask.trailing_zeros() as usize;
    }
    // Pick the j-th set bit, j uniform in 0..ties (16 spare bits; bias < 1e-4).
    let ties = mask.count_ones();
    let mut j = ((((bits >> 2) & 0xffff) * ties as u64) >> 16) as u32;
    let mut m = mask;
    while j > 0 {
        m &= m - 1;
        j -= 1;
    }
    m.trailing_zeros() as usize
}

macro_rules! kebab_enum {
    ($t:ty, $($name:literal => $v:expr),+) => {
        impl FromStr for $t {
            type Err = String;
            fn from_str(s: &str) -> Result<Self, String> {
                match s {
                    $($name => Ok($v),)+
                    _ => Err(format!("unknown value '{s}' (expected one of: {})", [$($name),+].join(", "))),
                }
            }
        }
        impl fmt::Display for $t {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                $(if *self == $v { return f.write_str($name); })+
                Ok(())
            }
        }
    };
}
kebab_enum!(EpsilonReading, "greedy" => EpsilonReading::Greedy, "random" => EpsilonReading::Random);
kebab_enum!(Schedule, "literal" => Schedule::Literal, "temperature" => Schedule::Temperature, "explore" => Schedule::Explore);
kebab_enum!(QScale, "raw" => QScale::Raw, "range" => QScale::Range, "log" => QScale::Log);

#[cfg(test)]
mod tests {
    use super::*;

    const TEMP_LOG: PolicyConfig = PolicyConfig::Softmax {
        schedule: Schedule::Temperature,
        scale: QScale::Log,
        horizon: 8.0,
    };

    #[test]
    fn schedule_values() {
        assert!((dynamic_epsilon(0, 100) - 0.51).abs() < 1e-6);
        assert!((dynamic_epsilon(100, 100) - 0.02).abs() < 1e-6);
        assert!(dynamic_epsilon(99, 100) > 0.02 && dynamic_epsilon(99, 100) < 0.04);
        assert!(
            (dynamic_epsilon(500, 100) - 0.02).abs() < 1e-6,
            "clamped past N"
        );
        let mut p = Policy::new(TEMP_LOG, 0.6);
        p.begin_episode(0, 10);
        assert!((p.beta() - 1.0 / 0.51).abs() < 1e-5);
        let mut lit = Policy::new(
            PolicyConfig::Softmax {
                schedule: Schedule::Literal,
                scale: QScale::Raw,
                horizon: 8.0,
            },
            0.6,
        );
        lit.begin_episode(10, 10);
        assert!((lit.beta() - 0.02).abs() < 1e-5);
    }

    #[test]
    fn softmax_sums_to_one_and_prefers_the_best() {
        for scale in [QScale::Raw, QScale::Range, QScale::Log] {
            let mut p = Policy::new(
                PolicyConfig::Softmax {
                    schedule: Schedule::Temperature,
                    scale,
                    horizon: 8.0,
                },
                0.6,
            );
            p.begin_episode(5, 10);
            for q in [
                [0.0; 4],
                [0.5, 0.3, -1.0, 0.0],
                [1e-6, 6e-7, 0.0, -0.1],
                [-0.1, -0.2, -0.3, -0.05],
            ] {
                let pr = p.probabilities(&q);
                assert!(
                    (pr.iter().sum::<f32>() - 1.0).abs() < 1e-5,
                    "{scale:?} {q:?} {pr:?}"
                );
                let best = crate::qtable::argmax4(&q);
                assert!(
                    pr.iter().all(|x| *x <= pr[best] + 1e-6),
                    "{scale:?} {q:?} {pr:?}"
                );
            }
        }
    }

    #[test]
    fn log_scale_is_scale_free() {
        let p = Policy::new(TEMP_LOG, 0.6);
        let near = p.probabilities(&[0.6, 0.36, 0.0, -1.0]);
        let far = p.probabilities(&[0.6f32.powi(20), 0.6f32.powi(21), 0.0, -1.0]);
        for a in 0..4 {
            assert!((near[a] - far[a]).abs() < 1e-4, "{near:?} vs {far:?}");
        }
        // One move behind the best: weight e^-β.
        assert!((near[1] / near[0] - (-p.beta()).exp()).abs() < 1e-4);
    }

    #[test]
    fn raw_scale_is_uniform_far_from_goal() {
        let p = Policy::new(
            PolicyConfig::Softmax {
                schedule: Schedule::Temperature,
                scale: QScale::Raw,
                horizon: 8.0,
            },
            0.6,
        );
        let far = p.probabilities(&[0.6f32.powi(20), 0.6f32.powi(21), 0.0, 0.0]);
        assert!(far.iter().all(|x| (x - 0.25).abs() < 1e-3), "{far:?}");
    }

    #[test]
    fn epsilon_readings() {
        let g = Policy::new(PolicyConfig::TRADITIONAL, 0.6);
        assert!((g.probabilities(&[1.0, 0.0, 0.0, 0.0])[0] - (0.8 + 0.05)).abs() < 1e-6);
        let r = Policy::new(
            PolicyConfig::EpsilonGreedy {
                epsilon: 0.8,
                reading: EpsilonReading::Random,
            },
            0.6,
        );
        assert!((r.probabilities(&[1.0, 0.0, 0.0, 0.0])[0] - (0.2 + 0.2)).abs() < 1e-6);
    }

    #[test]
    fn sampling_follows_probabilities() {
        let mut rng = LearnRng::new(7);
        let q = [0.6, 0.36, 0.0, -1.0];
        for cfg in [PolicyConfig::IMPROVED, TEMP_LOG, PolicyConfig::TRADITIONAL] {
            let p = Policy::new(cfg, 0.6);
            let pr = p.probabilities(&q);
            let mut counts = [0u32; 4];
            let n = 200_000;
            for _ in 0..n {
                counts[p.choose(&q, &mut rng)] += 1;
            }
            for a in 0..4 {
                let f = counts[a] as f32 / n as f32;
                assert!(
                    (f - pr[a]).abs() < 0.005,
                    "{cfg:?} a={a} freq={f} p={}",
                    pr[a]
                );
            }
        }
    }

    #[test]
    fn ties_are_broken_uniformly() {
        let mut counts = [0u32; 4];
        for i in 0..40_000u64 {
            let bits = i.wrapping_mul(0x9E37_79B9_7F4A_7C15);
            counts[greedy_random_ties(&[0.0, 0.0, -1.0, 0.0], bits)] += 1;
        }
        assert_eq!(counts[2], 0);
        for a in [0, 1, 3] {
            assert!(
                (counts[a] as f32 / 40_000.0 - 1.0 / 3.0).abs() < 0.01,
                "{counts:?}"
            );
        }
    }
}
