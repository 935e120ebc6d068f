//! Per-topic counts and rates, and recent-latency percentiles: what `topic hz`, `replay` and
//! the live view report. Pure: times are handed in (monotonic or log-time ns).

use std::collections::VecDeque;

use bus_schema::names::Topic;
use serde::Serialize;

/// Counts and times of one topic.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct TopicCount {
    /// Messages seen.
    pub count: u64,
    /// Time of the first one, ns (0 before any).
    pub first_ns: u64,
    /// Time of the last one, ns (0 before any).
    pub last_ns: u64,
}

impl TopicCount {
    /// Counts one message at time `t_ns`.
    pub fn add(&mut self, t_ns: u64) {
        if self.count == 0 {
            self.first_ns = t_ns;
        }
        self.count += 1;
        self.last_ns = self.last_ns.max(t_ns);
    }

    /// Mean rate between the first and the last message, messages/s (0 with fewer than two).
    pub fn mean_rate(&self) -> f64 {
        let span = self.last_ns.saturating_sub(self.first_ns);
        if self.count < 2 || span == 0 {
            return 0.0;
        }
        (self.count - 1) as f64 * 1e9 / span as f64
    }
}

/// One [`TopicCount`] per topic, in `Topic::ALL` order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TopicCounts(pub [TopicCount; Topic::ALL.len()]);

/// Position of `t` in `Topic::ALL`.
pub fn topic_index(t: Topic) -> usize {
    Topic::ALL.iter().position(|x| *x == t).unwrap_or(0)
}

impl TopicCounts {
    /// Counts one message of `topic` at `t_ns`.
    pub fn add(&mut self, topic: Topic, t_ns: u64) {
        self.0[topic_index(topic)].add(t_ns);
    }

    /// The counts of `topic`.
    pub fn get(&self, topic: Topic) -> TopicCount {
        self.0[topic_index(topic)]
    }

    /// Messages of all topics.
    pub fn total(&self) -> u64 {
        self.0.iter().map(|c| c.count).sum()
    }
}

/// Messages per second over a sliding window (for `topic hz` and the live view).
#[derive(Debug, Clone)]
pub struct Rate {
    window_ns: u64,
    times: VecDeque<u64>,
}

impl Rate {
    /// A rate over the last `window_ns` nanoseconds.
    pub fn new(window_ns: u64) -> Self {
        Self {
            window_ns: window_ns.max(1),
            times: VecDeque::new(),
        }
    }

    /// Notes `n` events at `t_ns`.
    pub fn add(&mut self, t_ns: u64, n: u64) {
        for _ in 0..n.min(1 << 20) {
            self.times.push_back(t_ns);
        }
        self.expire(t_ns);
    }

    fn expire(&mut self, now_ns: u64) {
        while let Some(&t) = self.times.front() {
            if now_ns.saturating_sub(t) > self.window_ns {
                self.times.pop_front();
            } else {
                break;
            }
        }
    }

    /// Events per second over the window ending at `now_ns`.
    pub fn per_s(&mut self, now_ns: u64) -> f64 {
        self.expire(now_ns);
        self.times.len() as f64 * 1e9 / self.window_ns as f64
    }
}

/// The most recent latency samples (bounded) and their percentiles.
#[derive(Debug, Clone)]
pub struct RecentLatency {
    cap: usize,
    samples: VecDeque<u64>,
    total: u64,
}

/// Percentiles of [`RecentLatency`], ns.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Percentiles {
    /// Samples the percentiles are taken over.
    pub count: usize,
    /// Median.
    pub p50: u64,
    /// 90th percentile.
    pub p90: u64,
    /// 99th percentile.
    pub p99: u64,
    /// Largest.
    pub max: u64,
}

impl RecentLatency {
    /// Keeps the last `cap` samples.
    pub fn new(cap: usize) -> Self {
        Self {
            cap: cap.max(1),
            samples: VecDeque::new(),
            total: 0,
        }
    }

    /// Adds a sample.
    pub fn add(&mut self, ns: u64) {
        if self.samples.len() == self.cap {
            self.samples.pop_front();
        }
        self.samples.push_back(ns);
        self.total += 1;
    }

    /// Samples ever added.
    pub fn total(&self) -> u64 {
        self.total
    }

    /// Nearest-rank percentiles of the kept samples.
    pub fn percentiles(&self) -> Percentiles {
        let mut v: Vec<u64> = self.samples.iter().copied().collect();
        if v.is_empty() {
            return Percentiles::default();
        }
        v.sort_unstable();
        let at = |p: f64| v[((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1];
        Percentiles {
            count: v.len(),
            p50: at(0.50),
            p90: at(0.90),
            p99: at(0.99),
            max: v[v.len() - 1],
        }
    }
}

/// One report of `qfleet topic hz`: per topic (all, or `only`) its rate now and its total, as
/// one JSON object or as text lines, followed by a blank line in text or a newline in JSON.
pub fn rates_report(
    rates: &mut [Rate],
    counts: &TopicCounts,
    only: Option<Topic>,
    now_ns: u64,
    json: bool,
) -> String {
    let mut v = serde_json::Map::new();
    let mut text = String::new();
    for x in Topic::ALL
        .into_iter()
        .filter(|x| only.is_none_or(|o| o == *x))
    {
        let rate = rates[topic_index(x)].per_s(now_ns);
        let total = counts.get(x).count;
        v.insert(
            x.path().into(),
            serde_json::json!({"per_s": rate, "total": total}),
        );
        text.push_str(&format!(
            "{:18} {rate:>10.1} msg/s  {total:>9} total\n",
            x.path()
        ));
    }
    if json {
        serde_json::Value::Object(v).to_string() + "\n"
    } else {
        text + "\n"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rates_report_has_a_line_or_a_key_per_topic() {
        let t = Topic::ALL[0];
        let mut rates: Vec<Rate> = Topic::ALL
            .iter()
            .map(|_| Rate::new(1_000_000_000))
            .collect();
        let mut counts = TopicCounts::default();
        for i in 0..5 {
            counts.add(t, i * 1000);
            rates[topic_index(t)].add(i * 1000, 1);
        }
        let text = rates_report(&mut rates, &counts, Some(t), 10_000, false);
        assert_eq!(
            text,
            format!("{:18} {:>10.1} msg/s  {:>9} total\n\n", t.path(), 5.0, 5)
        );
        let all = rates_report(&mut rates, &counts, None, 10_000, false);
        assert_eq!(all.lines().count(), Topic::ALL.len() + 1);
        let json = rates_report(&mut rates, &counts, Some(t), 10_000, true);
        let v: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(v[t.path()]["total"], 5);
    }

    #[test]
    fn counts_and_mean_rate() {
        let mut c = TopicCount::default();
        assert_eq!(c.mean_rate(), 0.0);
        for i in 0..11 {
            c.add(1_000 + i * 100_000_000);
        }
        assert_eq!(c.count, 11);
        assert_eq!(c.first_ns, 1_000);
        assert!((c.mean_rate() - 10.0).abs() < 1e-9);
    }

    #[test]
    fn sliding_rate_forgets_old_events() {
        let mut r = Rate::new(1_000_000_000);
        r.add(0, 5);
        assert_eq!(r.per_s(500_000_000), 5.0);
        r.add(1_500_000_000, 2);
        assert_eq!(r.per_s(1_500_000_000), 2.0);
        assert_eq!(r.per_s(10_000_000_000), 0.0);
    }

    #[test]
    fn percentiles_are_nearest_rank_over_the_kept_samples() {
        let mut l = RecentLatency::new(100);
        assert_eq!(l.percentiles(), Percentiles::default());
        for i in 1..=200 {
            l.add(i);
        }
        let p = l.percentiles();
        assert_eq!(
            (p.count, p.p50, p.p90, p.p99, p.max),
            (100, 150, 190, 199, 200)
        );
        assert_eq!(l.total(), 200);
    }

    #[test]
    fn topic_counts_go_to_their_topic() {
        let mut t = TopicCounts::default();
        t.add(Topic::Relay, 5);
        t.add(Topic::Relay, 9);
        t.add(Topic::Register, 1);
        assert_eq!(t.get(Topic::Relay).count, 2);
        assert_eq!(t.get(Topic::Relay).last_ns, 9);
        assert_eq!(t.total(), 3);
    }
}
