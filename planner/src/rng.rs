//! The learner's random source: a seeded xoshiro256++ with the few draws the policies need.

use rand_core::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// Seeded, portable random source: the same seed gives the same draws on every machine.
#[derive(Debug, Clone)]
pub struct LearnRng(Xoshiro256PlusPlus);

impl LearnRng {
    /// A generator seeded from a 64-bit seed (SplitMix64 expansion, as rand_xoshiro does).
    pub fn new(seed: u64) -> Self {
        LearnRng(Xoshiro256PlusPlus::seed_from_u64(seed))
    }

    /// 64 random bits.
    #[inline(always)]
    pub fn bits(&mut self) -> u64 {
        self.0.next_u64()
    }

    /// A uniform float in [0, 1) from the top 24 bits of `bits`.
    #[inline(always)]
    pub fn unit_from(bits: u64) -> f32 {
        (bits >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    /// A uniform float in [0, 1).
    #[inline(always)]
    pub fn unit(&mut self) -> f32 {
        Self::unit_from(self.bits())
    }
}
