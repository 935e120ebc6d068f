//! The front door's admission decision, without IO: which TCP connection to the `--listen`
//! address may go on to the hub's Zenoh listener (issue 27: "connection and session limits per
//! source, with unauthenticated connections dropped quickly enough that a flood cannot lock out
//! a real host").
//!
//! Zenoh's own limits are global (`accept_pending`, `max_sessions`): one address dialing in a
//! loop takes the slots every other host needs. The [`Gate`] counts per source: at most
//! [`Limits::per_source`] connections open at once, new ones paced by a token bucket
//! ([`Limits::burst`], one more every [`Limits::refill_every`]), all sources together at most
//! [`Limits::global`], and the table of sources itself bounded ([`Limits::tracked`]). What it
//! refuses is counted per reason and, for the first [`SOURCES_KEPT`] sources, per source
//! ([`DoorReport`]). The IO around it is [`crate::relay::FrontDoor`].
//!
//! Not this: [`crate::join::Door`], which checks the join secret of a query inside a session.

use std::collections::HashMap;
use std::net::IpAddr;
use std::time::{Duration, Instant};

use serde::Serialize;

/// The door's limits; [`Limits::default`] says why each default is what it is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Connections one source may hold open at once (waiting for its first byte or relayed).
    pub per_source: u32,
    /// New connections one source may open at once after a quiet while (the bucket's size).
    pub burst: u32,
    /// One more new connection per source is allowed each this long (the bucket's refill).
    pub refill_every: Duration,
    /// Connections open at once from all sources together.
    pub global: u32,
    /// Sources the door remembers at most; past that an idle one is forgotten or evicted.
    /// Always more than [`global`](Self::global), so a source with an open connection is
    /// never evicted (see [`Gate::new`]).
    pub tracked: usize,
    /// A connection that has sent no byte this long after it was accepted is closed by the
    /// door, without ever reaching Zenoh.
    pub first_byte_within: Duration,
}

impl Default for Limits {
    /// - `per_source` 8: a joining host holds one connection (the session has `max_links` 1)
    ///   and, after its link drops, dials a new one while the door may still relay the old one
    ///   for a moment; 8 leaves room for that and for a few hosts behind one NAT address.
    /// - `burst` 16, one more each 250 ms (4/s): a host dials once per join and Zenoh re-dials
    ///   about once a second while the link is down, so a real host never waits on the bucket;
    ///   a source dialing in a loop gets 16 connections, then 4 a second.
    /// - `global` 512: Zenoh's `max_sessions` of the hub (one connection per session).
    /// - `tracked` 4096 sources: ~50 bytes each (~200 KiB), well past `global`.
    /// - `first_byte_within` 1 s: a Zenoh peer sends its handshake as soon as it is connected;
    ///   the same time Zenoh gives a connection to finish its handshake (`accept_timeout`).
    fn default() -> Self {
        Limits {
            per_source: 8,
            burst: 16,
            refill_every: Duration::from_millis(250),
            global: 512,
            tracked: 4096,
            first_byte_within: Duration::from_secs(1),
        }
    }
}

/// Why a connection was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Refusal {
    /// Its source already holds [`Limits::per_source`] connections.
    SourceBusy,
    /// Its source's bucket is empty: it opened too many connections too fast.
    SourceRate,
    /// [`Limits::global`] connections are open.
    Full,
}

/// The door's decision on one new connection.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Let it in: the caller tells [`Gate::closed`] when it ends.
    Admit,
    /// Close it at once, unread.
    Refuse(Refusal),
}

/// Sources whose refusals the report names one by one; the rest are counted together.
pub const SOURCES_KEPT: usize = 32;

/// Refusals of one source.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct SourceRefusals {
    /// The source: an IPv4 address, or an IPv6 /64 prefix.
    pub source: String,
    /// Connections of it refused, for any reason.
    pub refused: u64,
}

/// What the front door did, for the hub's report (`bridge.json`, `door`).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct DoorReport {
    /// The address it listened on (the user's `--listen`).
    pub listen: String,
    /// Connections let in.
    pub admitted: u64,
    /// Refused: the source held [`Limits::per_source`] connections.
    pub refused_source_busy: u64,
    /// Refused: the source opened connections faster than its bucket allows.
    pub refused_source_rate: u64,
    /// Refused: [`Limits::global`] connections were open.
    pub refused_full: u64,
    /// Admitted, then closed by the door: no byte within [`Limits::first_byte_within`].
    pub silent: u64,
    /// Admitted and sent a byte, but the hub's Zenoh listener could not be reached.
    pub upstream_failed: u64,
    /// Sources forgotten while still pacing (their bucket not full) to make room in the table.
    pub evicted_sources: u64,
    /// Most sources tracked at once.
    pub peak_sources: u64,
    /// Refusals per source, the first [`SOURCES_KEPT`] sources refused.
    pub refused_by_source: Vec<SourceRefusals>,
    /// Refusals of sources past those.
    pub refused_other_sources: u64,
    /// Refused credentials: a probe with a wrong join secret ([`crate::probe`]), or a Zenoh
    /// handshake the hub's session ended at once ([`handshake_refused`]).
    pub refused_credentials: u64,
    /// Refused credentials per source, the first [`SOURCES_KEPT`] sources.
    pub refused_credentials_by_source: Vec<SourceRefusals>,
    /// Refused credentials of sources past those.
    pub refused_credentials_other_sources: u64,
    /// The hub's direct listener ([`crate::admit`]), empty when it has none.
    pub direct: String,
    /// Sources that proved the join secret and were let through to the direct listener.
    pub direct_sources: u64,
}

impl DoorReport {
    /// Every refusal, whatever its reason.
    pub fn refused(&self) -> u64 {
        self.refused_source_busy + self.refused_source_rate + self.refused_full
    }
}

/// A relayed connection the hub's Zenoh session ended within this long of its start is
/// counted as a refused handshake: Zenoh refuses a wrong password (or none) in its first
/// exchange, while a session it accepts lives for the whole join.
pub const HANDSHAKE_WITHIN: Duration = Duration::from_secs(2);

/// Whether a relayed connection was a handshake Zenoh refused: the hub's side ended it first,
/// `lasted` after it was relayed.
pub fn handshake_refused(upstream_ended_first: bool, lasted: Duration) -> bool {
    upstream_ended_first && lasted < HANDSHAKE_WITHIN
}

/// Counts per source, the first [`SOURCES_KEPT`] sources one by one and the rest together, so
/// a flood of addresses cannot grow it.
#[derive(Debug, Default)]
struct BySource {
    kept: Vec<(IpAddr, u64)>,
    other: u64,
}

impl BySource {
    /// Counts one for `key`; true the first time a kept source is counted (worth a log line).
    fn count(&mut self, key: IpAddr) -> bool {
        if let Some((_, n)) = self.kept.iter_mut().find(|(k, _)| *k == key) {
            *n += 1;
            false
        } else if self.kept.len() < SOURCES_KEPT {
            self.kept.push((key, 1));
            true
        } else {
            self.other += 1;
            false
        }
    }

    fn list(&self) -> Vec<SourceRefusals> {
        self.kept
            .iter()
            .map(|(k, n)| SourceRefusals {
                source: source_name(*k),
                refused: *n,
            })
            .collect()
    }
}

/// A source as the report names it: an IPv4 address, or an IPv6 /64 prefix.
pub fn source_name(key: IpAddr) -> String {
    match key {
        IpAddr::V4(a) => a.to_string(),
        IpAddr::V6(a) => format!("{a}/64"),
    }
}

/// What the door knows of one source.
#[derive(Debug, Clone, Copy)]
struct Source {
    /// Connections open now.
    open: u32,
    /// The bucket as a "theoretical arrival time" (GCRA): a new connection is allowed while
    /// `tat - now <= (burst - 1) * refill_every`; each allowed one moves `tat` on by
    /// `refill_every`. `tat <= now` is a full bucket: the same as a source never seen.
    tat: Instant,
}

/// The admission decision: per-source concurrency and pacing, a global cap, a bounded table.
#[derive(Debug)]
pub struct Gate {
    limits: Limits,
    sources: HashMap<IpAddr, Source>,
    open: u32,
    refused_by: BySource,
    credentials: BySource,
    report: DoorReport,
}

/// The source a connection counts against: an IPv4 address (an IPv4-mapped IPv6 one too), or
/// the /64 prefix of an IPv6 address (one host usually holds a whole /64).
pub fn source_of(ip: IpAddr) -> IpAddr {
    match ip {
        IpAddr::V4(_) => ip,
        IpAddr::V6(v6) => match v6.to_ipv4_mapped() {
            Some(v4) => IpAddr::V4(v4),
            None => {
                let s = v6.segments();
                IpAddr::V6(std::net::Ipv6Addr::new(s[0], s[1], s[2], s[3], 0, 0, 0, 0))
            }
        },
    }
}

impl Gate {
    /// A gate with `limits`, made consistent: every count at least 1, the refill between 1 µs
    /// and an hour (so no instant arithmetic can overflow), `tracked` more than `global` (so
    /// the table always has an idle source to drop when it is full).
    pub fn new(limits: Limits) -> Gate {
        let mut l = limits;
        l.per_source = l.per_source.max(1);
        l.burst = l.burst.max(1);
        l.refill_every = l
            .refill_every
            .clamp(Duration::from_micros(1), Duration::from_secs(3600));
        l.global = l.global.max(1);
        l.tracked = l.tracked.max(l.global as usize + 1);
        Gate {
            limits: l,
            sources: HashMap::new(),
            open: 0,
            refused_by: BySource::default(),
            credentials: BySource::default(),
            report: DoorReport::default(),
        }
    }

    /// The limits in force.
    pub fn limits(&self) -> Limits {
        self.limits
    }

    /// A new connection from `src` at `now`: admit it (counted open until [`closed`](Self::closed))
    /// or refuse it, counted by reason and source.
    pub fn admit(&mut self, src: IpAddr, now: Instant) -> Verdict {
        let key = source_of(src);
        let verdict = self.decide(key, now);
        match verdict {
            Verdict::Admit => self.report.admitted += 1,
            Verdict::Refuse(why) => {
                match why {
                    Refusal::SourceBusy => self.report.refused_source_busy += 1,
                    Refusal::SourceRate => self.report.refused_source_rate += 1,
                    Refusal::Full => self.report.refused_full += 1,
                }
                self.count_refused(key);
            }
        }
        verdict
    }

    fn decide(&mut self, key: IpAddr, now: Instant) -> Verdict {
        if self.open >= self.limits.global {
            return Verdict::Refuse(Refusal::Full);
        }
        if !self.sources.contains_key(&key) && !self.make_room(now) {
            return Verdict::Refuse(Refusal::Full);
        }
        let l = self.limits;
        let s = self
            .sources
            .entry(key)
            .or_insert(Source { open: 0, tat: now });
        if s.open >= l.per_source {
            return Verdict::Refuse(Refusal::SourceBusy);
        }
        let tat = s.tat.max(now);
        let tolerance = l.refill_every.saturating_mul(l.burst - 1);
        if tat.duration_since(now) > tolerance {
            return Verdict::Refuse(Refusal::SourceRate);
        }
        s.tat = tat.checked_add(l.refill_every).unwrap_or(tat);
        s.open += 1;
        self.open += 1;
        self.report.peak_sources = self.report.peak_sources.max(self.sources.len() as u64);
        Verdict::Admit
    }

    /// Room for one more source in a full table: first every source that holds nothing (no
    /// open connection, a full bucket: the same as never seen) is forgotten; if none is, the
    /// idle source whose bucket is fullest is evicted (counted: it may burst again). False
    /// only if every tracked source holds a connection, which `tracked > global` rules out.
    fn make_room(&mut self, now: Instant) -> bool {
        if self.sources.len() < self.limits.tracked {
            return true;
        }
        self.sources.retain(|_, s| s.open > 0 || s.tat > now);
        if self.sources.len() < self.limits.tracked {
            return true;
        }
        let victim = self
            .sources
            .iter()
            .filter(|(_, s)| s.open == 0)
            .min_by_key(|(_, s)| s.tat)
            .map(|(k, _)| *k);
        match victim {
            Some(k) => {
                self.sources.remove(&k);
                self.report.evicted_sources += 1;
                true
            }
            None => false,
        }
    }

    fn count_refused(&mut self, key: IpAddr) {
        self.refused_by.count(key);
    }

    /// `src` failed to prove the join secret (a probe, or a Zenoh handshake refused): counted
    /// per source; true the first time a source is (log one line for it, not one per try).
    pub fn refused_credentials(&mut self, src: IpAddr) -> bool {
        self.report.refused_credentials += 1;
        self.credentials.count(source_of(src))
    }

    /// A connection admitted from `src` has ended (whoever closed it).
    pub fn closed(&mut self, src: IpAddr) {
        self.open = self.open.saturating_sub(1);
        if let Some(s) = self.sources.get_mut(&source_of(src)) {
            s.open = s.open.saturating_sub(1);
        }
    }

    /// An admitted connection was closed for sending nothing within
    /// [`Limits::first_byte_within`] (call [`closed`](Self::closed) too).
    pub fn silent(&mut self) {
        self.report.silent += 1;
    }

    /// An admitted connection could not be forwarded: the hub's listener did not answer (call
    /// [`closed`](Self::closed) too).
    pub fn upstream_failed(&mut self) {
        self.report.upstream_failed += 1;
    }

    /// Connections open now, from all sources.
    pub fn open(&self) -> u32 {
        self.open
    }

    /// Connections open now from `src`'s source.
    pub fn open_from(&self, src: IpAddr) -> u32 {
        self.sources.get(&source_of(src)).map_or(0, |s| s.open)
    }

    /// Sources tracked now.
    pub fn tracked(&self) -> usize {
        self.sources.len()
    }

    /// The figures so far, `listen` filled in.
    pub fn report(&self, listen: &str) -> DoorReport {
        let mut r = self.report.clone();
        r.listen = listen.to_string();
        r.refused_by_source = self.refused_by.list();
        r.refused_other_sources = self.refused_by.other;
        r.refused_credentials_by_source = self.credentials.list();
        r.refused_credentials_other_sources = self.credentials.other;
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::net::{Ipv4Addr, Ipv6Addr};

    fn ip(n: u32) -> IpAddr {
        IpAddr::V4(Ipv4Addr::from(0x0a00_0000 + n))
    }

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    #[test]
    fn a_source_holds_at_most_per_source_connections_and_gets_one_back_when_one_closes() {
        let t = Instant::now();
        let mut g = Gate::new(Limits::default());
        for _ in 0..8 {
            assert_eq!(g.admit(ip(1), t), Verdict::Admit);
        }
        assert_eq!(g.admit(ip(1), t), Verdict::Refuse(Refusal::SourceBusy));
        // another source is not held up by the first
        assert_eq!(g.admit(ip(2), t), Verdict::Admit);
        g.closed(ip(1));
        assert_eq!(g.open_from(ip(1)), 7);
        assert_eq!(g.admit(ip(1), t), Verdict::Admit);
        let r = g.report("x");
        assert_eq!((r.admitted, r.refused_source_busy), (10, 1));
        assert_eq!(
            r.refused_by_source,
            vec![SourceRefusals {
                source: "10.0.0.1".into(),
                refused: 1
            }]
        );
    }

    #[test]
    fn a_source_dialing_in_a_loop_gets_its_burst_then_one_per_refill() {
        let t = Instant::now();
        let mut g = Gate::new(Limits::default());
        // open and close at once: only the bucket limits it
        let dial = |g: &mut Gate, at: Instant| {
            let v = g.admit(ip(1), at);
            if v == Verdict::Admit {
                g.closed(ip(1));
            }
            v
        };
        for _ in 0..16 {
            assert_eq!(dial(&mut g, t), Verdict::Admit);
        }
        assert_eq!(dial(&mut g, t), Verdict::Refuse(Refusal::SourceRate));
        // a refusal takes no token: 250 ms later exactly one more
        assert_eq!(
            dial(&mut g, t + ms(249)),
            Verdict::Refuse(Refusal::SourceRate)
        );
        assert_eq!(dial(&mut g, t + ms(250)), Verdict::Admit);
        assert_eq!(
            dial(&mut g, t + ms(250)),
            Verdict::Refuse(Refusal::SourceRate)
        );
        // over ten seconds of dialing every 10 ms: 4 a second
        let admitted = (1..=1000)
            .filter(|i| dial(&mut g, t + ms(250 + 10 * i)) == Verdict::Admit)
            .count();
        assert_eq!(admitted, 40);
        // quiet for 4 s: the whole burst again, not more
        let later = t + ms(250 + 10_000 + 4_000);
        let burst = (0..100)
            .filter(|_| dial(&mut g, later) == Verdict::Admit)
            .count();
        assert_eq!(burst, 16);
        // the pacing of one source is not another's
        assert_eq!(g.admit(ip(2), t), Verdict::Admit);
    }

    #[test]
    fn all_sources_together_hold_at_most_the_global_cap() {
        let t = Instant::now();
        let mut g = Gate::new(Limits {
            global: 20,
            ..Limits::default()
        });
        let admitted = (0..100)
            .filter(|n| g.admit(ip(*n), t) == Verdict::Admit)
            .count();
        assert_eq!(admitted, 20);
        assert_eq!(g.open(), 20);
        assert_eq!(g.admit(ip(500), t), Verdict::Refuse(Refusal::Full));
        g.closed(ip(3));
        assert_eq!(g.admit(ip(500), t), Verdict::Admit);
        assert_eq!(g.report("x").refused_full, 81);
    }

    #[test]
    fn the_table_of_sources_stays_bounded_forgetting_idle_sources_first() {
        let t = Instant::now();
        let limits = Limits {
            global: 20,
            tracked: 64,
            ..Limits::default()
        };
        let mut g = Gate::new(limits);
        // 10 sources hold a connection each; 10 000 more each dial once and hang up
        for n in 0..10 {
            assert_eq!(g.admit(ip(n), t), Verdict::Admit);
        }
        for n in 10..10_010 {
            let at = t + ms(300 * n as u64);
            assert_eq!(g.admit(ip(n), at), Verdict::Admit, "source {n}");
            g.closed(ip(n));
            assert!(g.tracked() <= 64);
        }
        // the holders were never dropped: their connections still count against them
        for n in 0..10 {
            assert_eq!(g.open_from(ip(n)), 1);
        }
        // sources whose bucket had refilled were forgotten, not evicted
        let r = g.report("x");
        assert_eq!(r.evicted_sources, 0, "{r:?}");
        assert_eq!(r.peak_sources, 64);
    }

    #[test]
    fn a_full_table_of_pacing_sources_evicts_and_counts_the_most_rested_one() {
        let t = Instant::now();
        let mut g = Gate::new(Limits {
            global: 2,
            tracked: 4,
            ..Limits::default()
        });
        // four sources, each still pacing (all at the same instant: no refill yet)
        for n in 0..4 {
            assert_eq!(g.admit(ip(n), t), Verdict::Admit);
            g.closed(ip(n));
        }
        assert_eq!(g.admit(ip(9), t), Verdict::Admit);
        assert_eq!(g.tracked(), 4);
        assert_eq!(g.report("x").evicted_sources, 1);
    }

    #[test]
    fn inconsistent_limits_are_made_safe() {
        let g = Gate::new(Limits {
            per_source: 0,
            burst: 0,
            refill_every: Duration::ZERO,
            global: 0,
            tracked: 0,
            first_byte_within: Duration::ZERO,
        });
        let l = g.limits();
        assert_eq!((l.per_source, l.burst, l.global, l.tracked), (1, 1, 1, 2));
        assert!(!l.refill_every.is_zero());
        // a refill too long to add to an instant is cut to an hour, never a panic
        let mut g = Gate::new(Limits {
            refill_every: Duration::MAX,
            burst: u32::MAX,
            ..Limits::default()
        });
        assert_eq!(g.limits().refill_every, Duration::from_secs(3600));
        let t = Instant::now();
        assert_eq!(g.admit(ip(1), t), Verdict::Admit);
    }

    #[test]
    fn an_ipv6_host_counts_as_its_slash_64_and_a_mapped_ipv4_as_the_ipv4() {
        let a: IpAddr = "2001:db8:1:2::1".parse().unwrap();
        let b: IpAddr = "2001:db8:1:2:ffff::9".parse().unwrap();
        let c: IpAddr = "2001:db8:1:3::1".parse().unwrap();
        assert_eq!(source_of(a), source_of(b));
        assert_ne!(source_of(a), source_of(c));
        let mapped = IpAddr::V6(Ipv4Addr::new(10, 0, 0, 1).to_ipv6_mapped());
        assert_eq!(source_of(mapped), ip(1));
        let t = Instant::now();
        let mut g = Gate::new(Limits::default());
        for i in 0..8u16 {
            let x = IpAddr::V6(Ipv6Addr::new(0x2001, 0xdb8, 1, 2, 0, 0, 0, i));
            assert_eq!(g.admit(x, t), Verdict::Admit);
        }
        assert_eq!(g.admit(a, t), Verdict::Refuse(Refusal::SourceBusy));
        assert_eq!(
            g.report("x").refused_by_source[0].source,
            "2001:db8:1:2::/64"
        );
    }

    #[test]
    fn refusals_are_named_for_the_first_sources_and_counted_for_the_rest() {
        let t = Instant::now();
        let mut g = Gate::new(Limits {
            global: 1,
            ..Limits::default()
        });
        assert_eq!(g.admit(ip(0), t), Verdict::Admit);
        for n in 1..=100 {
            assert_eq!(g.admit(ip(n), t), Verdict::Refuse(Refusal::Full));
        }
        let r = g.report("x");
        assert_eq!(r.refused_by_source.len(), SOURCES_KEPT);
        assert_eq!(r.refused_other_sources, 100 - SOURCES_KEPT as u64);
        assert_eq!(r.refused(), 100);
    }

    mod properties {
        use super::*;
        use proptest::prelude::*;

        proptest! {
            /// Whatever sources dial and hang up in whatever order: no source ever holds more
            /// than `per_source`, all together never more than `global`, the table never more
            /// than `tracked`, and every connection is either admitted or refused with a count.
            #[test]
            fn the_limits_hold_under_any_sequence(
                ops in proptest::collection::vec((0u32..40, any::<bool>(), 0u64..400), 1..600)
            ) {
                let limits = Limits { per_source: 3, burst: 5, global: 12, tracked: 16,
                    ..Limits::default() };
                let mut g = Gate::new(limits);
                let t0 = Instant::now();
                let mut now = t0;
                let mut held: Vec<u32> = Vec::new();
                let mut dials = 0u64;
                for (src, hang_up, step_ms) in ops {
                    now += Duration::from_millis(step_ms);
                    if hang_up {
                        if let Some(i) = held.iter().position(|h| *h == src) {
                            held.swap_remove(i);
                            g.closed(ip(src));
                        }
                        continue;
                    }
                    dials += 1;
                    if g.admit(ip(src), now) == Verdict::Admit {
                        held.push(src);
                    }
                    let from = held.iter().filter(|h| **h == src).count() as u32;
                    prop_assert_eq!(g.open_from(ip(src)), from);
                    prop_assert!(from <= 3);
                    prop_assert!(g.open() as usize == held.len() && held.len() <= 12);
                    prop_assert!(g.tracked() <= 16);
                }
                let r = g.report("x");
                prop_assert_eq!(r.admitted + r.refused(), dials);
                prop_assert_eq!(
                    r.refused_by_source.iter().map(|s| s.refused).sum::<u64>()
                        + r.refused_other_sources,
                    r.refused()
                );
            }
        }
    }

    #[test]
    fn refused_credentials_are_counted_per_source_bounded_and_logged_once_per_source() {
        let mut g = Gate::new(Limits::default());
        // the first refusal of a source is worth a log line, the next ones only a count
        assert!(g.refused_credentials(ip(1)));
        assert!(!g.refused_credentials(ip(1)));
        // an IPv6 host counts as its /64, however many addresses it uses
        let v6 = |last| IpAddr::V6(Ipv6Addr::new(0xfd00, 0, 0, 1, 0, 0, 0, last));
        assert!(g.refused_credentials(v6(1)));
        assert!(!g.refused_credentials(v6(2)));
        // a flood of addresses: the first SOURCES_KEPT are named, the rest counted together
        for n in 2..200 {
            g.refused_credentials(ip(n));
        }
        let r = g.report("x");
        assert_eq!(r.refused_credentials, 4 + 198);
        assert_eq!(r.refused_credentials_by_source.len(), SOURCES_KEPT);
        assert_eq!(r.refused_credentials_by_source[0].refused, 2);
        assert_eq!(r.refused_credentials_by_source[1].source, "fd00:0:0:1::/64");
        assert_eq!(
            r.refused_credentials_other_sources,
            202 - r
                .refused_credentials_by_source
                .iter()
                .map(|s| s.refused)
                .sum::<u64>()
        );
        // it refuses no connection: the connection limits are not touched
        assert_eq!(r.refused(), 0);
        assert_eq!(g.open(), 0);
    }

    #[test]
    fn only_a_session_the_hub_ended_early_is_a_refused_handshake() {
        let early = HANDSHAKE_WITHIN / 4;
        assert!(handshake_refused(true, early));
        // the joining host left: not a refusal
        assert!(!handshake_refused(false, early));
        // a session that lived past the handshake ended for another reason
        assert!(!handshake_refused(true, HANDSHAKE_WITHIN));
        assert!(!handshake_refused(true, HANDSHAKE_WITHIN * 30));
    }
}
