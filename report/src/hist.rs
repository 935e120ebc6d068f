//! Latency histograms of every qfleet process: one bounded hdrhistogram shape, its summary on
//! the wire and in JSON, `.hgrm` percentile files, and a binary file format so a robot can hand
//! its full histogram to the coordinator. Files are written with [`write_atomic`].

use std::path::Path;

use bus_schema::LatencySummary;
use hdrhistogram::Histogram;
use hdrhistogram::serialization::{Deserializer, Serializer, V2Serializer};
use serde::{Deserialize, Serialize};

use crate::atomic::{WriteError, write_atomic};

/// Largest latency a histogram records exactly (60 s); larger samples are clamped to it.
pub const MAX_TRACKED_NS: u64 = 60_000_000_000;

/// Why a histogram file could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum HistError {
    /// The file could not be written (full disk, missing directory, …).
    #[error(transparent)]
    Write(#[from] WriteError),
    /// The file could not be read.
    #[error("reading {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The file is not a serialized histogram.
    #[error("{path}: not an hdrhistogram V2 file: {detail}")]
    Format {
        /// The file.
        path: String,
        /// The decoder's complaint.
        detail: String,
    },
}

/// A fresh latency histogram: 1 ns .. 60 s, 3 significant digits (what every qfleet process
/// records, so histograms of different processes can be added).
pub fn new_hist() -> Histogram<u64> {
    // 1..=60e9 with 3 significant figures is always a valid bound set.
    match Histogram::new_with_bounds(1, MAX_TRACKED_NS, 3) {
        Ok(h) => h,
        Err(_) => unreachable!("constant histogram bounds are valid"),
    }
}

/// Records one sample, clamped into the tracked range (never fails, never panics).
#[inline]
pub fn record(h: &mut Histogram<u64>, ns: u64) {
    h.saturating_record(ns.clamp(1, MAX_TRACKED_NS));
}

/// The percentiles of a latency distribution as they appear in result JSON.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct LatencyStats {
    /// Number of samples.
    pub count: u64,
    /// Median, ns.
    pub p50: u64,
    /// 90th percentile, ns.
    pub p90: u64,
    /// 99th percentile, ns.
    pub p99: u64,
    /// 99.9th percentile, ns.
    pub p999: u64,
    /// 99.99th percentile, ns.
    pub p9999: u64,
    /// Largest sample, ns.
    pub max: u64,
    /// Smallest sample, ns.
    pub min: u64,
    /// Mean, ns.
    pub mean: f64,
}

impl LatencyStats {
    /// Percentiles of a histogram (all zero when it is empty).
    pub fn of(h: &Histogram<u64>) -> Self {
        if h.is_empty() {
            return Self::default();
        }
        LatencyStats {
            count: h.len(),
            p50: h.value_at_quantile(0.5),
            p90: h.value_at_quantile(0.9),
            p99: h.value_at_quantile(0.99),
            p999: h.value_at_quantile(0.999),
            p9999: h.value_at_quantile(0.9999),
            max: h.max(),
            min: h.min(),
            mean: h.mean(),
        }
    }

    /// The stats carried by a wire summary (p99.99 is not on the wire: reported as the max).
    pub fn from_summary(s: &LatencySummary) -> Self {
        LatencyStats {
            count: s.count,
            p50: s.p50_ns,
            p90: s.p90_ns,
            p99: s.p99_ns,
            p999: s.p999_ns,
            p9999: s.max_ns,
            max: s.max_ns,
            min: s.min_ns,
            mean: s.mean_ns as f64,
        }
    }
}

/// The fixed-size wire summary of a histogram, for a `FinalReport`.
pub fn summary(h: &Histogram<u64>) -> LatencySummary {
    let s = LatencyStats::of(h);
    LatencySummary {
        count: s.count,
        min_ns: s.min,
        mean_ns: s.mean as u64,
        p50_ns: s.p50,
        p90_ns: s.p90,
        p99_ns: s.p99,
        p999_ns: s.p999,
        max_ns: s.max,
    }
}

/// Writes the histogram as an HdrHistogram percentile-distribution (`.hgrm`) file, values in
/// microseconds, readable by HdrHistogram's plotter and `hdr-plot`.
pub fn write_hgrm(h: &Histogram<u64>, path: &Path) -> Result<(), HistError> {
    let mut out = String::new();
    out.push_str("       Value     Percentile TotalCount 1/(1-Percentile)\n\n");
    if !h.is_empty() {
        let mut total = 0u64;
        for v in h.iter_quantiles(5) {
            let q = v.quantile_iterated_to();
            let value_us = v.value_iterated_to() as f64 / 1000.0;
            total += v.count_since_last_iteration();
            if q < 1.0 {
                out.push_str(&format!(
                    "{value_us:12.3} {q:2.12} {total:10} {:14.2}\n",
                    1.0 / (1.0 - q)
                ));
            } else {
                out.push_str(&format!("{value_us:12.3} {q:2.12} {total:10}\n"));
            }
        }
    }
    out.push_str(&format!(
        "#[Mean    = {:12.3}, StdDeviation   = {:12.3}]\n",
        h.mean() / 1000.0,
        h.stdev() / 1000.0
    ));
    out.push_str(&format!(
        "#[Max     = {:12.3}, Total count    = {:12}]\n",
        h.max() as f64 / 1000.0,
        h.len()
    ));
    out.push_str(&format!(
        "#[Buckets = {:12}, SubBuckets     = {:12}]\n",
        h.buckets(),
        h.distinct_values()
    ));
    Ok(write_atomic(path, out.as_bytes())?)
}

/// Writes the histogram in HdrHistogram's V2 binary encoding (lossless, to be added up later).
pub fn write_binary(h: &Histogram<u64>, path: &Path) -> Result<(), HistError> {
    let mut buf = Vec::new();
    V2Serializer::new()
        .serialize(h, &mut buf)
        .map_err(|e| HistError::Format {
            path: path.display().to_string(),
            detail: format!("{e:?}"),
        })?;
    Ok(write_atomic(path, &buf)?)
}

/// Reads a histogram written by [`write_binary`].
pub fn read_binary(path: &Path) -> Result<Histogram<u64>, HistError> {
    let bytes = std::fs::read(path).map_err(|source| HistError::Read {
        path: path.display().to_string(),
        source,
    })?;
    Deserializer::new()
        .deserialize(&mut bytes.as_slice())
        .map_err(|e| HistError::Format {
            path: path.display().to_string(),
            detail: format!("{e:?}"),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_files_and_round_trip() {
        let mut h = new_hist();
        for v in 1..=1000u64 {
            record(&mut h, v * 1000);
        }
        record(&mut h, u64::MAX);
        let s = LatencyStats::of(&h);
        assert_eq!(s.count, 1001);
        assert!(s.p50 >= 499_000 && s.p50 <= 502_000, "{s:?}");
        assert!(s.max >= MAX_TRACKED_NS);
        let dir = std::env::temp_dir().join(format!("qfleet-hist-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        write_hgrm(&h, &dir.join("x.hgrm")).unwrap();
        let text = std::fs::read_to_string(dir.join("x.hgrm")).unwrap();
        assert!(text.contains("Percentile") && text.contains("Total count"));
        write_binary(&h, &dir.join("x.hdr")).unwrap();
        let back = read_binary(&dir.join("x.hdr")).unwrap();
        assert_eq!(back.len(), h.len());
        assert_eq!(back.value_at_quantile(0.5), h.value_at_quantile(0.5));
        assert!(read_binary(&dir.join("x.hgrm")).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(LatencyStats::of(&new_hist()), LatencyStats::default());
    }
}
