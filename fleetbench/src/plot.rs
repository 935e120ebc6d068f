//! SVG plots: a percentile plot of all latency rows (HdrHistogram style: log x of
//! 1/(1−percentile), log y of latency) and the scale section's throughput and latency.

use std::path::Path;

use plotters::prelude::*;

use crate::BenchError;
use crate::report::{Row, ScaleRow};

/// Colours of successive series.
const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

fn err(path: &Path) -> impl Fn(String) -> BenchError + '_ {
    move |detail| BenchError::Plot {
        path: path.display().to_string(),
        detail,
    }
}

fn percentile_label(x: &f64) -> String {
    let p = 100.0 * (1.0 - 1.0 / x);
    if p < 1.0 {
        "0%".into()
    } else {
        let s = format!("{p:.4}");
        format!("{}%", s.trim_end_matches('0').trim_end_matches('.'))
    }
}

/// Points (1/(1−q), latency µs) of a histogram, up to its max.
fn curve(r: &Row) -> Vec<(f64, f64)> {
    let mut pts = Vec::new();
    for v in r.hist.iter_quantiles(2) {
        let q = v.quantile_iterated_to();
        if q >= 1.0 {
            break;
        }
        pts.push((
            1.0 / (1.0 - q),
            (v.value_iterated_to() as f64 / 1e3).max(0.01),
        ));
    }
    if r.count > 0 {
        // the max, placed at the resolution the sample count allows
        let x = pts.last().map_or(1.0, |p| p.0).max(r.count as f64);
        pts.push((x, (r.max_ns as f64 / 1e3).max(0.01)));
    }
    pts
}

/// Draws every row's latency by percentile into one SVG.
pub fn percentiles(path: &Path, rows: &[Row]) -> Result<(), BenchError> {
    let e = err(path);
    let curves: Vec<(&str, Vec<(f64, f64)>)> =
        rows.iter().map(|r| (r.label.as_str(), curve(r))).collect();
    let all = curves.iter().flat_map(|(_, c)| c.iter());
    let xmax = all.clone().map(|p| p.0).fold(10.0, f64::max) * 1.5;
    let ymax = all.clone().map(|p| p.1).fold(1.0, f64::max) * 2.0;
    let ymin = all.map(|p| p.1).fold(ymax, f64::min).max(0.01) / 1.5;
    let root = SVGBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(x.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Round-trip / update-loop latency by percentile",
            ("sans-serif", 20),
        )
        .margin(14)
        .x_label_area_size(40)
        .y_label_area_size(64)
        .build_cartesian_2d((1.0f64..xmax).log_scale(), (ymin..ymax).log_scale())
        .map_err(|x| e(x.to_string()))?;
    chart
        .configure_mesh()
        .x_desc("percentile")
        .y_desc("latency (µs)")
        .x_label_formatter(&percentile_label)
        .y_label_formatter(&|y| format!("{y}"))
        .draw()
        .map_err(|x| e(x.to_string()))?;
    for (i, (label, pts)) in curves.into_iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        chart
            .draw_series(LineSeries::new(pts, color.stroke_width(2)))
            .map_err(|x| e(x.to_string()))?
            .label(label)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
            });
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|x| e(x.to_string()))?;
    root.present().map_err(|x| e(x.to_string()))
}

/// Draws the scale section: merged Q-updates/s and loop p50/p99 against the fleet size, one
/// line per batch size that has more than one fleet size.
pub fn scale(path: &Path, rows: &[ScaleRow]) -> Result<(), BenchError> {
    let e = err(path);
    let ok: Vec<&ScaleRow> = rows.iter().filter(|r| r.completed).collect();
    let mut batches: Vec<u32> = ok.iter().map(|r| r.batch).collect();
    batches.sort_unstable();
    batches.dedup();
    let series: Vec<(u32, Vec<&ScaleRow>)> = batches
        .into_iter()
        .map(|b| {
            (
                b,
                ok.iter()
                    .copied()
                    .filter(|r| r.batch == b)
                    .collect::<Vec<_>>(),
            )
        })
        .filter(|(_, v)| v.len() > 1)
        .collect();
    let nmax = ok.iter().map(|r| r.robots).max().unwrap_or(2).max(2) as f64 * 1.3;
    let rmax = ok.iter().map(|r| r.merged_per_s / 1e6).fold(1.0, f64::max) * 1.2;
    let lmax = ok
        .iter()
        .map(|r| r.loop_p99_ns as f64 / 1e3)
        .fold(1.0, f64::max)
        * 2.0;
    let lmin = ok
        .iter()
        .map(|r| r.loop_p50_ns as f64 / 1e3)
        .filter(|v| *v > 0.0)
        .fold(lmax, f64::min)
        .max(0.1)
        / 2.0;
    let root = SVGBackend::new(path, (1100, 460)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(x.to_string()))?;
    let (left, right) = root.split_horizontally(550);
    let mut a = ChartBuilder::on(&left)
        .caption("Q-updates merged / s (M)", ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(50)
        .build_cartesian_2d((0.8f64..nmax).log_scale(), 0.0f64..rmax)
        .map_err(|x| e(x.to_string()))?;
    a.configure_mesh()
        .x_desc("robot processes")
        .x_label_formatter(&|x| format!("{x:.0}"))
        .draw()
        .map_err(|x| e(x.to_string()))?;
    let mut b = ChartBuilder::on(&right)
        .caption("update loop latency (µs)", ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(60)
        .build_cartesian_2d((0.8f64..nmax).log_scale(), (lmin..lmax).log_scale())
        .map_err(|x| e(x.to_string()))?;
    b.configure_mesh()
        .x_desc("robot processes")
        .x_label_formatter(&|x| format!("{x:.0}"))
        .y_label_formatter(&|y| format!("{y}"))
        .draw()
        .map_err(|x| e(x.to_string()))?;
    for (i, (batch, pts)) in series.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        let thr: Vec<(f64, f64)> = pts
            .iter()
            .map(|r| (f64::from(r.robots), r.merged_per_s / 1e6))
            .collect();
        a.draw_series(LineSeries::new(thr.clone(), color.stroke_width(2)))
            .map_err(|x| e(x.to_string()))?
            .label(format!("batch {batch}"))
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
            });
        a.draw_series(thr.into_iter().map(|p| Circle::new(p, 3, color.filled())))
            .map_err(|x| e(x.to_string()))?;
        for (k, dash) in [(0.5, false), (0.99, true)] {
            let lat: Vec<(f64, f64)> = pts
                .iter()
                .filter(|r| r.loop_count > 0)
                .map(|r| {
                    let ns = if dash { r.loop_p99_ns } else { r.loop_p50_ns };
                    (f64::from(r.robots), (ns as f64 / 1e3).max(lmin))
                })
                .collect();
            let style = if dash {
                color.mix(0.5).stroke_width(2)
            } else {
                color.stroke_width(2)
            };
            b.draw_series(LineSeries::new(lat, style))
                .map_err(|x| e(x.to_string()))?
                .label(format!(
                    "batch {batch} p{}",
                    if k < 0.9 { "50" } else { "99" }
                ))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], style));
        }
    }
    a.configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|x| e(x.to_string()))?;
    b.configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(|x| e(x.to_string()))?;
    root.present().map_err(|x| e(x.to_string()))
}

#[cfg(test)]
mod tests {
    use super::percentile_label;

    #[test]
    fn percentile_axis_labels() {
        assert_eq!(percentile_label(&1.0), "0%");
        assert_eq!(percentile_label(&10.0), "90%");
        assert_eq!(percentile_label(&1000.0), "99.9%");
    }
}
