//! `--pace STEPS_PER_S`: the robot slows to that many environment steps per second so that a
//! person can follow it in the live view. [`Pacer`] decides, without IO, when to pause and for
//! how long; the learning loop counts steps with it and sleeps what it says.
//!
//! - Coarse: the robot pauses once per chunk of steps worth [`Pacer::CHUNK`] of wall time
//!   (one step per pause only below 20 steps per second), not after every step.
//! - Free when off: [`Pacer::step`] is a decrement and a compare; an unpaced robot's countdown
//!   starts at `u64::MAX` and never runs out.
//! - No bursts: a robot that fell behind (a slow machine, a wait between phases) is not let
//!   run fast to catch up; the schedule restarts from where it is.

use std::time::Duration;

/// One robot's pace: a step countdown to the next pause and the schedule the pauses keep.
#[derive(Debug, Clone)]
pub struct Pacer {
    /// Steps until the next pause.
    left: u64,
    /// Steps between pauses.
    every: u64,
    /// The time one step should take, ns (0 when off).
    ns_per_step: f64,
    /// Clock (ns) at which the schedule started, once it has.
    origin_ns: Option<u64>,
    /// Steps counted since `origin_ns`.
    since: u64,
}

impl Pacer {
    /// The wall time a chunk of steps between two pauses is worth.
    pub const CHUNK: Duration = Duration::from_millis(50);

    /// A pacer that never pauses.
    pub fn off() -> Self {
        Pacer {
            left: u64::MAX,
            every: u64::MAX,
            ns_per_step: 0.0,
            origin_ns: None,
            since: 0,
        }
    }

    /// A pacer for `steps_per_s` steps per second; `None`, zero, negative or not finite is off
    /// (the command line has already refused those: `qfleet_args::parse_pace`).
    pub fn new(steps_per_s: Option<f64>) -> Self {
        match steps_per_s {
            Some(r) if r.is_finite() && r > 0.0 => {
                let every = (r * Self::CHUNK.as_secs_f64()).ceil().max(1.0) as u64;
                Pacer {
                    left: every,
                    every,
                    ns_per_step: 1e9 / r,
                    origin_ns: None,
                    since: 0,
                }
            }
            _ => Self::off(),
        }
    }

    /// Whether this pacer ever pauses.
    pub fn is_on(&self) -> bool {
        self.every != u64::MAX
    }

    /// Steps between two pauses.
    pub fn every(&self) -> u64 {
        self.every
    }

    /// Counts one step; true when it is time to pause (then call [`Pacer::pause`]).
    #[inline(always)]
    pub fn step(&mut self) -> bool {
        self.left -= 1;
        if self.left == 0 {
            self.left = self.every;
            true
        } else {
            false
        }
    }

    /// How long to sleep now, at clock reading `now_ns` (monotonic), so that the steps since
    /// the schedule started took at least their share of time. The first pause starts the
    /// schedule (its chunk is taken to have cost nothing, so the whole chunk is slept); a
    /// robot more than one chunk behind starts it again instead of racing to catch up.
    pub fn pause(&mut self, now_ns: u64) -> Duration {
        if !self.is_on() {
            return Duration::ZERO;
        }
        let chunk_ns = self.every as f64 * self.ns_per_step;
        let Some(origin) = self.origin_ns else {
            // the schedule starts where the chunk just done should have ended
            self.origin_ns = Some(now_ns.saturating_add(chunk_ns as u64));
            self.since = 0;
            return Duration::from_nanos(chunk_ns as u64);
        };
        self.since += self.every;
        let target = origin.saturating_add((self.since as f64 * self.ns_per_step) as u64);
        if now_ns < target {
            return Duration::from_nanos(target - now_ns);
        }
        if (now_ns - target) as f64 > chunk_ns.max(Self::CHUNK.as_nanos() as f64) {
            self.origin_ns = Some(now_ns);
            self.since = 0;
        }
        Duration::ZERO
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: u64 = 1_000_000_000;

    /// Runs `steps` steps that cost `step_ns` each, sleeping what the pacer says; returns the
    /// simulated time taken and the number of pauses.
    fn simulate(p: &mut Pacer, clock: &mut u64, steps: u64, step_ns: u64) -> (u64, u64) {
        let t0 = *clock;
        let mut pauses = 0;
        for _ in 0..steps {
            *clock += step_ns;
            if p.step() {
                pauses += 1;
                *clock += p.pause(*clock).as_nanos() as u64;
            }
        }
        (*clock - t0, pauses)
    }

    #[test]
    fn off_never_pauses() {
        let mut p = Pacer::new(None);
        assert!(!p.is_on());
        let mut clock = 0;
        assert_eq!(simulate(&mut p, &mut clock, 1_000_000, 0), (0, 0));
        assert_eq!(p.pause(5), Duration::ZERO);
        for bad in [Some(0.0), Some(-3.0), Some(f64::NAN), Some(f64::INFINITY)] {
            assert!(!Pacer::new(bad).is_on(), "{bad:?}");
        }
    }

    #[test]
    fn pauses_come_in_chunks_of_fifty_milliseconds_of_steps() {
        assert_eq!(
            Pacer::new(Some(10.0)).every(),
            1,
            "slow: one step per pause"
        );
        assert_eq!(Pacer::new(Some(20.0)).every(), 1);
        assert_eq!(Pacer::new(Some(100.0)).every(), 5);
        assert_eq!(Pacer::new(Some(100_000.0)).every(), 5_000);
        let mut p = Pacer::new(Some(100_000.0));
        let mut clock = 0;
        let (_, pauses) = simulate(&mut p, &mut clock, 1_000_000, 0);
        assert_eq!(pauses, 200, "a million steps, one pause per 5 000");
    }

    #[test]
    fn free_steps_are_slowed_to_the_pace() {
        for rate in [1.0, 7.0, 50.0, 1234.0, 1e6] {
            let mut p = Pacer::new(Some(rate));
            let mut clock = 42;
            // about ten seconds' worth, ending on a pause
            let steps = ((rate * 10.0) as u64).div_ceil(p.every()) * p.every();
            let (took, _) = simulate(&mut p, &mut clock, steps, 0);
            let want = steps as f64 / rate * S as f64;
            assert!(
                (took as f64 - want).abs() <= want * 1e-6 + 1e3,
                "{rate}/s: {took} ns for {steps} steps, want {want}"
            );
        }
    }

    #[test]
    fn steps_slower_than_the_pace_are_not_slowed_further() {
        // 100 steps/s asked, each step takes 20 ms (50/s): no sleep at all after the first
        let mut p = Pacer::new(Some(100.0));
        let mut clock = 0;
        let (took, _) = simulate(&mut p, &mut clock, 500, 20_000_000);
        assert!(took <= 500 * 20_000_000 + 50_000_000, "{took}");
    }

    #[test]
    fn a_stall_is_not_caught_up_with_a_burst() {
        let mut p = Pacer::new(Some(100.0));
        let mut clock = 0;
        simulate(&mut p, &mut clock, 1_000, 0);
        clock += 30 * S; // waiting for the next phase
        // the next ten seconds of steps still take ten seconds, not zero
        let (took, _) = simulate(&mut p, &mut clock, 1_000, 0);
        let want = 10 * S;
        assert!(
            took + 50_000_000 >= want && took <= want + 50_000_000,
            "{took}"
        );
    }

    #[test]
    fn a_pause_is_at_most_one_chunk_once_the_schedule_runs() {
        let mut p = Pacer::new(Some(1000.0));
        let mut clock = 0;
        for _ in 0..10_000 {
            if p.step() {
                let d = p.pause(clock);
                assert!(d <= Pacer::CHUNK, "{d:?}");
                clock += d.as_nanos() as u64;
            }
        }
    }
}
