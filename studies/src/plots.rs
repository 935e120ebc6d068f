//! SVG figures: steps per episode (like the paper's learning curves), paths drawn on the grid
//! and latency distributions.

use planner::{Cell, Grid};
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// A figure that could not be drawn or written.
#[derive(Debug, thiserror::Error)]
#[error("writing {}", path.display())]
pub struct PlotError {
    /// The SVG file.
    pub path: PathBuf,
    /// What plotters reported.
    #[source]
    pub source: DrawingAreaErrorKind<std::io::Error>,
}

/// The result of drawing one figure.
pub type Result<T> = std::result::Result<T, PlotError>;

/// Names the file a plotters error was about.
pub fn at(path: &Path) -> impl Fn(DrawingAreaErrorKind<std::io::Error>) -> PlotError + '_ {
    move |source| PlotError {
        path: path.to_path_buf(),
        source,
    }
}

/// The legend's mark for a series drawn in `color` with lines `width` pixels wide.
pub fn legend_mark(color: RGBColor, width: u32) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(width))
}

/// Draws the legend box at `pos` (every figure's: white, half-transparent, framed) and writes
/// the figure to `path`.
pub fn finish<'a, CT: plotters::coord::CoordTranslate>(
    root: &DrawingArea<SVGBackend<'a>, plotters::coord::Shift>,
    chart: &mut ChartContext<'a, SVGBackend<'a>, CT>,
    pos: SeriesLabelPosition,
    path: &Path,
) -> Result<()> {
    chart
        .configure_series_labels()
        .position(pos)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(at(path))?;
    root.present().map_err(at(path))
}

/// Colours of successive series.
pub const PALETTE: [RGBColor; 12] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
    RGBColor(188, 189, 34),
    RGBColor(127, 127, 127),
    RGBColor(0, 0, 128),
    RGBColor(128, 0, 0),
];

/// A named series of y-values over x = 0, 1, 2, ….
pub struct Series<'a> {
    /// Legend label.
    pub label: &'a str,
    /// y-values.
    pub values: &'a [f64],
}

/// Draws line series on a log-scaled y axis (steps span several decades) into an SVG file.
pub fn line_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series<'_>],
) -> Result<()> {
    let n = series
        .iter()
        .map(|s| s.values.len())
        .max()
        .unwrap_or(1)
        .max(2);
    let ymax = series
        .iter()
        .flat_map(|s| s.values.iter().copied())
        .fold(1.0f64, f64::max)
        * 1.5;
    let ymin = series
        .iter()
        .flat_map(|s| s.values.iter().copied())
        .filter(|v| *v > 0.0)
        .fold(ymax, f64::min)
        .max(0.5)
        * 0.7;
    let root = SVGBackend::new(path, (900, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(at(path))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..(n - 1) as f64, (ymin..ymax).log_scale())
        .map_err(at(path))?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .draw()
        .map_err(at(path))?;
    for (i, s) in series.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        chart
            .draw_series(LineSeries::new(
                s.values
                    .iter()
                    .enumerate()
                    .filter(|(_, v)| **v > 0.0)
                    .map(|(x, v)| (x as f64, *v)),
                color.stroke_width(2),
            ))
            .map_err(at(path))?
            .label(s.label)
            .legend(legend_mark(color, 2));
    }
    finish(&root, &mut chart, SeriesLabelPosition::MiddleRight, path)
}

/// Draws the grid (obstacles dark), start, goal and any number of labelled paths into an SVG file.
pub fn paths_on_grid(
    path: &Path,
    title: &str,
    grid: &Grid,
    start: Cell,
    goal: Cell,
    paths: &[(&str, &[Cell])],
) -> Result<()> {
    let (w, h) = (grid.width() as i32, grid.height() as i32);
    let cell_px = (720 / w.max(h)).clamp(2, 40);
    let root = SVGBackend::new(path, ((w * cell_px + 40) as u32, (h * cell_px + 90) as u32))
        .into_drawing_area();
    root.fill(&WHITE).map_err(at(path))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(20)
        .build_cartesian_2d(0f64..w as f64, h as f64..0f64)
        .map_err(at(path))?;
    chart
        .draw_series((0..grid.len()).filter_map(|i| {
            let c = grid.cell(i);
            (!grid.is_free(c)).then(|| {
                Rectangle::new(
                    [
                        (c.x as f64, c.y as f64),
                        (c.x as f64 + 1.0, c.y as f64 + 1.0),
                    ],
                    RGBColor(60, 60, 60).filled(),
                )
            })
        }))
        .map_err(at(path))?;
    chart
        .draw_series((0..=w).map(|x| {
            PathElement::new(
                vec![(x as f64, 0.0), (x as f64, h as f64)],
                RGBColor(220, 220, 220),
            )
        }))
        .map_err(at(path))?;
    chart
        .draw_series((0..=h).map(|y| {
            PathElement::new(
                vec![(0.0, y as f64), (w as f64, y as f64)],
                RGBColor(220, 220, 220),
            )
        }))
        .map_err(at(path))?;
    let centre = |c: &Cell| (c.x as f64 + 0.5, c.y as f64 + 0.5);
    for (i, (label, cells)) in paths.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        let off = i as f64 * 0.12;
        chart
            .draw_series(std::iter::once(PathElement::new(
                cells
                    .iter()
                    .map(|c| (centre(c).0 + off, centre(c).1 + off))
                    .collect::<Vec<_>>(),
                color.stroke_width(3),
            )))
            .map_err(at(path))?
            .label(format!("{label} ({} moves)", cells.len().saturating_sub(1)))
            .legend(legend_mark(color, 3));
    }
    let r = (cell_px / 3).max(2);
    chart
        .draw_series(
            [(start, GREEN), (goal, RED)]
                .into_iter()
                .map(|(c, col)| Circle::new(centre(&c), r, col.filled())),
        )
        .map_err(at(path))?;
    if paths.is_empty() {
        return root.present().map_err(at(path));
    }
    finish(&root, &mut chart, SeriesLabelPosition::LowerLeft, path)
}

/// One latency distribution: (percentile in [0, 100), value) points.
pub struct Percentiles<'a> {
    /// Legend label.
    pub label: &'a str,
    /// Points, in increasing percentile.
    pub points: &'a [(f64, f64)],
}

/// Draws latency distributions like HdrHistogram plots: x = percentile on a "number of nines"
/// scale (log of 1/(1 − p)), y = latency on a log scale.
pub fn percentile_chart(
    path: &Path,
    title: &str,
    y_label: &str,
    series: &[Percentiles<'_>],
) -> Result<()> {
    let nines = |p: f64| 1.0 / (1.0 - (p / 100.0).min(0.999_999));
    let all = || series.iter().flat_map(|s| s.points.iter());
    let xmax = all().map(|(p, _)| nines(*p)).fold(10.0f64, f64::max) * 1.2;
    let ymax = all().map(|(_, v)| *v).fold(1.0f64, f64::max) * 1.5;
    let ymin = all()
        .map(|(_, v)| *v)
        .filter(|v| *v > 0.0)
        .fold(ymax, f64::min)
        .max(1e-3)
        * 0.7;
    let root = SVGBackend::new(path, (900, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(at(path))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d((1.0f64..xmax).log_scale(), (ymin..ymax).log_scale())
        .map_err(at(path))?;
    chart
        .configure_mesh()
        .x_desc("percentile")
        .y_desc(y_label)
        .x_label_formatter(&|x| {
            let p = format!("{:.4}", 100.0 * (1.0 - 1.0 / x));
            format!("{}%", p.trim_end_matches('0').trim_end_matches('.'))
        })
        .draw()
        .map_err(at(path))?;
    for (i, s) in series.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        chart
            .draw_series(LineSeries::new(
                s.points
                    .iter()
                    .filter(|(_, v)| *v > 0.0)
                    .map(|(p, v)| (nines(*p), *v)),
                color.stroke_width(2),
            ))
            .map_err(at(path))?
            .label(s.label)
            .legend(legend_mark(color, 2));
    }
    finish(&root, &mut chart, SeriesLabelPosition::UpperLeft, path)
}
