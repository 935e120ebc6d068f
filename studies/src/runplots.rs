//! Figures of a fleet run, drawn from the files its processes left in the out directory:
//! the latency distribution of every measured path (`latency-*.hgrm`) and every robot's steps
//! per episode (`robot-<id>-episodes.csv`).

use crate::plots::{self, Percentiles, PlotError, Series};
use std::path::{Path, PathBuf};

/// Why a run's figures were not drawn.
#[derive(Debug, thiserror::Error)]
pub enum RunPlotsError {
    /// The out directory or one of its files could not be read.
    #[error("reading {}", path.display())]
    Read {
        /// The directory or file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// A figure could not be drawn.
    #[error(transparent)]
    Plot(#[from] PlotError),
}

fn read(path: &Path) -> impl FnOnce(std::io::Error) -> RunPlotsError + '_ {
    move |source| RunPlotsError::Read {
        path: path.to_path_buf(),
        source,
    }
}

/// Writes `latency.svg` and `steps.svg` into a run's out directory; returns the files written.
pub fn write(out: &Path) -> Result<Vec<PathBuf>, RunPlotsError> {
    let mut written = Vec::new();
    let mut dists: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    let mut curves: Vec<(u32, Vec<f64>)> = Vec::new();
    let entries = std::fs::read_dir(out).map_err(read(out))?;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if let Some(label) = name
            .strip_prefix("latency-")
            .and_then(|n| n.strip_suffix(".hgrm"))
        {
            let path = e.path();
            let text = std::fs::read_to_string(&path).map_err(read(&path))?;
            let points = parse_hgrm(&text);
            if !points.is_empty() {
                dists.push((label.to_string(), points));
            }
        } else if let Some(id) = name
            .strip_prefix("robot-")
            .and_then(|n| n.strip_suffix("-episodes.csv"))
        {
            let Ok(id) = id.parse::<u32>() else { continue };
            let path = e.path();
            let text = std::fs::read_to_string(&path).map_err(read(&path))?;
            curves.push((id, parse_steps(&text)));
        }
    }
    dists.sort_by(|a, b| a.0.cmp(&b.0));
    curves.sort_by_key(|c| c.0);
    if !dists.is_empty() {
        let path = out.join("latency.svg");
        let series: Vec<Percentiles> = dists
            .iter()
            .map(|(l, p)| Percentiles {
                label: l,
                points: p,
            })
            .collect();
        plots::percentile_chart(&path, "fleet run: latency by path", "latency (µs)", &series)?;
        written.push(path);
    }
    if !curves.is_empty() {
        let path = out.join("steps.svg");
        let labels: Vec<String> = curves.iter().map(|(id, _)| format!("robot {id}")).collect();
        let series: Vec<Series> = curves
            .iter()
            .zip(&labels)
            .map(|((_, v), l)| Series {
                label: l,
                values: v,
            })
            .collect();
        plots::line_chart(
            &path,
            "fleet run: steps per episode",
            "episode",
            "steps",
            &series,
        )?;
        written.push(path);
    }
    Ok(written)
}

/// (percentile, value) points of an HdrHistogram percentile file; malformed lines are skipped.
fn parse_hgrm(text: &str) -> Vec<(f64, f64)> {
    text.lines()
        .filter_map(|l| {
            let mut f = l.split_whitespace();
            let value: f64 = f.next()?.parse().ok()?;
            let pct: f64 = f.next()?.parse().ok()?;
            (pct.is_finite() && (0.0..1.0).contains(&pct)).then_some((pct * 100.0, value))
        })
        .collect()
}

/// The steps column of a per-episode CSV file.
fn parse_steps(text: &str) -> Vec<f64> {
    text.lines()
        .skip(1)
        .filter_map(|l| l.split(',').nth(1)?.parse().ok())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_hgrm_and_csv() {
        let h = "       Value     Percentile TotalCount 1/(1-Percentile)\n\n     103.359 0.000000000000          1           1.00\n    3786.751 0.500000000000      18714           2.00\n#[Mean    =  1.0]\n    9999.0 1.000000000000 1 inf\n";
        assert_eq!(parse_hgrm(h), vec![(0.0, 103.359), (50.0, 3786.751)]);
        assert_eq!(
            parse_steps("episode,steps\n0,12,1\n1,x\n2,7"),
            vec![12.0, 7.0]
        );
    }
}
