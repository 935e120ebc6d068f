//! The terminal live view: draws a [`ViewModel`] with ratatui (map with walls, robots, their
//! greedy paths and discovered cells; a per-robot table; latency, throughput and topic counts)
//! and runs the key loop (`q` quit, `space` pause).
//!
//! [`map_glyphs`] (the scaled map as characters) and [`draw`] (one frame) are pure functions of
//! the model, so they are tested with ratatui's `TestBackend`; [`run`] is the thin IO loop.

use std::time::{Duration, Instant};

use planner::grid::Cell;
use ratatui::Frame;
use ratatui::crossterm::event::{self, Event, KeyCode, KeyEventKind};
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::style::{Color, Modifier, Style};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Borders, Paragraph, Row, Table};

use crate::ObserveError;
use crate::view::ViewModel;
use bus_schema::names::Topic;

/// Glyph of a wall block.
pub const WALL: char = '█';
/// Glyph of a free block.
pub const FREE: char = ' ';
/// Glyph of a block on some robot's greedy path.
pub const PATH: char = '·';
/// Glyph of a block holding a relayed pseudo-target discovery.
pub const DISCOVERY: char = '*';
/// Glyph of the goal.
pub const GOAL: char = 'G';
/// Glyph of the start.
pub const START: char = 'S';

/// The character a robot is drawn with: `0`–`9`, then `a`–`z`, then `@`.
pub fn robot_glyph(id: u32) -> char {
    match id {
        0..=9 => char::from(b'0' + id as u8),
        10..=35 => char::from(b'a' + (id - 10) as u8),
        _ => '@',
    }
}

/// Cells per character side so that the map fits `cols` × `rows` characters (at least 1).
pub fn scale(width: usize, height: usize, cols: usize, rows: usize) -> usize {
    let k = |n: usize, room: usize| n.div_ceil(room.max(1));
    k(width, cols).max(k(height, rows)).max(1)
}

/// The map scaled into at most `cols` × `rows` characters: each character stands for a k × k
/// block of cells ([`scale`]), drawn by priority robot > goal > start > greedy path >
/// discovery > wall (more than half the block blocked) > free.
pub fn map_glyphs(vm: &ViewModel, cols: usize, rows: usize) -> Vec<Vec<(char, Option<u32>)>> {
    let (w, h) = (vm.grid.width(), vm.grid.height());
    let k = scale(w, h, cols, rows);
    let (cw, ch) = (w.div_ceil(k), h.div_ceil(k));
    let mut out = vec![vec![(FREE, None); cw]; ch];
    for (y, row) in out.iter_mut().enumerate() {
        for (x, g) in row.iter_mut().enumerate() {
            let (mut blocked, mut all) = (0, 0);
            for yy in y * k..((y + 1) * k).min(h) {
                for xx in x * k..((x + 1) * k).min(w) {
                    all += 1;
                    if !vm.grid.is_free(Cell::new(xx as u16, yy as u16)) {
                        blocked += 1;
                    }
                }
            }
            if blocked * 2 > all {
                *g = (WALL, None);
            }
        }
    }
    let mut put = |c: Cell, glyph: char, who: Option<u32>, over: &[char]| {
        let (x, y) = (c.x as usize / k, c.y as usize / k);
        if let Some(slot) = out.get_mut(y).and_then(|r| r.get_mut(x))
            && (over.contains(&slot.0))
        {
            *slot = (glyph, who);
        }
    };
    let base = [FREE, WALL];
    for cells in vm.discovered.values() {
        for &c in cells {
            put(c, DISCOVERY, None, &base);
        }
    }
    let under_path = [FREE, WALL, DISCOVERY];
    for r in vm.robots.iter().filter(|r| r.seen) {
        for c in vm.greedy_path(r.id) {
            put(c, PATH, Some(r.id), &under_path);
        }
    }
    let under_marks = [FREE, WALL, DISCOVERY, PATH];
    for r in vm.robots.iter().filter(|r| r.seen) {
        if let Some(s) = r.start {
            put(s, START, None, &under_marks);
        }
    }
    for &g in vm.goals.values() {
        put(g, GOAL, None, &[FREE, WALL, DISCOVERY, PATH, START]);
    }
    let any = [FREE, WALL, DISCOVERY, PATH, START, GOAL];
    for r in vm.robots.iter().filter(|r| r.seen) {
        if let Some(c) = r.cell {
            put(c, robot_glyph(r.id), Some(r.id), &any);
        }
    }
    out
}

const PALETTE: [Color; 6] = [
    Color::Cyan,
    Color::Yellow,
    Color::Magenta,
    Color::Green,
    Color::LightBlue,
    Color::LightRed,
];

/// A robot status in at most 7 characters, for the table.
pub fn short_status(status: u8) -> &'static str {
    match bus_schema::RobotStatus::try_from(status) {
        Ok(bus_schema::RobotStatus::Waiting) => "waiting",
        Ok(bus_schema::RobotStatus::Running) => "running",
        Ok(bus_schema::RobotStatus::EpisodeDone) => "ep-done",
        Ok(bus_schema::RobotStatus::Finished) => "done",
        Ok(bus_schema::RobotStatus::Failed) => "failed",
        Err(_) => "?",
    }
}

fn us(ns: u64) -> String {
    format!("{:.1}", ns as f64 / 1e3)
}

/// What the view shows besides the model: paused, stopping, ended, where the data comes from.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Banner {
    /// The view is frozen (`space`).
    pub paused: bool,
    /// `q` was pressed: the run is being stopped.
    pub stopping: bool,
    /// The run (or the recording) is over.
    pub ended: bool,
    /// `live run <id>` or `replay <file>`.
    pub source: String,
}

/// Draws one frame of the view.
pub fn draw(f: &mut Frame<'_>, vm: &mut ViewModel, banner: &Banner) {
    let area = f.area();
    let [top, body, help] = Layout::vertical([
        Constraint::Length(1),
        Constraint::Min(3),
        Constraint::Length(1),
    ])
    .areas(area);
    let state = if banner.ended {
        "ended"
    } else if banner.stopping {
        "stopping…"
    } else if banner.paused {
        "PAUSED"
    } else {
        "live"
    };
    let phase = if vm.phase > 0 {
        format!(", phase {}", vm.phase)
    } else {
        String::new()
    };
    f.render_widget(
        Paragraph::new(format!(
            " qfleet — {} — map {} {}×{}{phase} — {state}",
            banner.source,
            vm.map_name,
            vm.grid.width(),
            vm.grid.height()
        ))
        .style(Style::new().add_modifier(Modifier::REVERSED)),
        top,
    );
    let side = 58.min(body.width / 2);
    let [map_area, right] =
        Layout::horizontal([Constraint::Min(10), Constraint::Length(side)]).areas(body);
    draw_map(f, vm, map_area);
    draw_side(f, vm, right);
    f.render_widget(
        Paragraph::new(" q quit (stops the run gracefully)   space pause/resume the view"),
        help,
    );
}

fn draw_map(f: &mut Frame<'_>, vm: &ViewModel, area: Rect) {
    let k = scale(
        vm.grid.width(),
        vm.grid.height(),
        area.width.saturating_sub(2) as usize,
        area.height.saturating_sub(2) as usize,
    );
    let title = if k > 1 {
        format!(" map (1 char = {k}×{k} cells) ")
    } else {
        " map ".to_string()
    };
    let glyphs = map_glyphs(
        vm,
        area.width.saturating_sub(2) as usize,
        area.height.saturating_sub(2) as usize,
    );
    let lines: Vec<Line> = glyphs
        .into_iter()
        .map(|row| {
            Line::from(
                row.into_iter()
                    .map(|(c, who)| {
                        let style = match (c, who) {
                            (WALL, _) => Style::new().fg(Color::DarkGray),
                            (GOAL | START, _) => {
                                Style::new().fg(Color::White).add_modifier(Modifier::BOLD)
                            }
                            (DISCOVERY, _) => Style::new().fg(Color::Red),
                            (PATH, Some(id)) => {
                                Style::new().fg(PALETTE[id as usize % PALETTE.len()])
                            }
                            (_, Some(id)) => Style::new()
                                .fg(Color::Black)
                                .bg(PALETTE[id as usize % PALETTE.len()]),
                            _ => Style::new(),
                        };
                        Span::styled(c.to_string(), style)
                    })
                    .collect::<Vec<_>>(),
            )
        })
        .collect();
    f.render_widget(
        Paragraph::new(lines).block(Block::new().borders(Borders::ALL).title(title)),
        area,
    );
}

fn draw_side(f: &mut Frame<'_>, vm: &mut ViewModel, area: Rect) {
    let rows_needed = vm.robots.iter().filter(|r| r.seen).count() as u16 + 3;
    let [table_area, stats_area] = Layout::vertical([
        Constraint::Length(rows_needed.min(area.height / 2).max(4)),
        Constraint::Min(4),
    ])
    .areas(area);
    let rows: Vec<Row> = vm
        .robots
        .iter()
        .filter(|r| r.seen)
        .map(|r| {
            let path = vm.greedy_path(r.id);
            let goal = vm.goals.get(&r.goal_id).copied();
            let len = if path.last().copied() == goal && goal.is_some() {
                (path.len() - 1).to_string()
            } else {
                "-".to_string()
            };
            let opt = match vm.path_optimal(r.id) {
                Some(true) => "yes",
                Some(false) => "no",
                None => "-",
            };
            Row::new(vec![
                robot_glyph(r.id).to_string(),
                short_status(r.status).to_string(),
                r.episode.to_string(),
                r.step.to_string(),
                r.avg_steps.map_or("-".into(), |a| format!("{a:.1}")),
                len,
                opt.to_string(),
                r.discoveries.to_string(),
            ])
            .style(Style::new().fg(PALETTE[r.id as usize % PALETTE.len()]))
        })
        .collect();
    let widths = [
        Constraint::Length(2),
        Constraint::Length(7),
        Constraint::Length(6),
        Constraint::Length(5),
        Constraint::Length(6),
        Constraint::Length(4),
        Constraint::Length(3),
        Constraint::Length(4),
    ];
    f.render_widget(
        Table::new(rows, widths)
            .header(
                Row::new(["id", "status", "ep", "step", "avg", "path", "opt", "disc"])
                    .style(Style::new().add_modifier(Modifier::BOLD)),
            )
            .block(Block::new().borders(Borders::ALL).title(" robots ")),
        table_area,
    );
    let lat = vm.latency();
    let hint = vm.hint_latency.percentiles();
    let mut lines = vec![
        Line::from(format!(
            "throughput  {:.0} msg/s   {:.0} merged Q/s",
            vm.message_rate(),
            vm.merged_rate()
        )),
        Line::from(format!(
            "discoveries sent {}   relayed {}   finished {}/{}",
            vm.discoveries_sent,
            vm.relayed,
            vm.finished(),
            vm.robots.iter().filter(|r| r.seen).count()
        )),
        Line::from("latency µs        p50     p90     p99     max   (n)"),
        Line::from(format!(
            "update→merged→us {:>7} {:>7} {:>7} {:>7} ({})",
            us(lat.p50),
            us(lat.p90),
            us(lat.p99),
            us(lat.max),
            lat.count
        )),
        Line::from(format!(
            "update→hints→us  {:>7} {:>7} {:>7} {:>7} ({})",
            us(hint.p50),
            us(hint.p90),
            us(hint.p99),
            us(hint.max),
            hint.count
        )),
        Line::from("messages per topic"),
    ];
    for t in Topic::ALL {
        lines.push(Line::from(format!("  {:16} {:>9}", t.path(), vm.count(t))));
    }
    f.render_widget(
        Paragraph::new(lines).block(Block::new().borders(Borders::ALL).title(" fleet ")),
        stats_area,
    );
}

/// What the feed said in one call of [`run`]'s loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Feed {
    /// More may come.
    More,
    /// The source is exhausted (the run ended, the recording is over).
    Ended,
}

/// How [`run`] ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Exit {
    /// The user pressed `q`.
    Quit,
    /// The source ended.
    Ended,
}

/// Takes over the terminal and shows `vm`, fed by `feed` (called in a tight loop, also while
/// the view is paused: an observer must keep draining), until the source ends or the user quits.
/// `on_quit` is called once when `q` is pressed; after that the view keeps feeding until the
/// source ends (the run stopping) unless `leave_on_quit`. With `hold_at_end` the last frame
/// stays until a key is pressed. The terminal is restored on every path out.
pub fn run(
    vm: &mut ViewModel,
    source: &str,
    mut feed: impl FnMut(&mut ViewModel) -> Result<Feed, ObserveError>,
    on_quit: &dyn Fn(),
    leave_on_quit: bool,
    hold_at_end: bool,
) -> Result<Exit, ObserveError> {
    let mut term = ratatui::try_init().map_err(ObserveError::Terminal)?;
    let result = (|| -> Result<Exit, ObserveError> {
        let mut banner = Banner {
            source: source.to_string(),
            ..Banner::default()
        };
        let frame = Duration::from_millis(100);
        let mut last_draw: Option<Instant> = None;
        let mut quit = false;
        loop {
            if !banner.ended && feed(vm)? == Feed::Ended {
                banner.ended = true;
                last_draw = None;
            }
            if last_draw.is_none_or(|t| t.elapsed() >= frame) && !banner.paused {
                term.draw(|f| draw(f, vm, &banner))
                    .map_err(ObserveError::Terminal)?;
                last_draw = Some(Instant::now());
            }
            if banner.ended && (!hold_at_end || quit) {
                return Ok(if quit { Exit::Quit } else { Exit::Ended });
            }
            let wait = if banner.ended {
                frame
            } else {
                Duration::from_millis(2)
            };
            if event::poll(wait).map_err(ObserveError::Terminal)?
                && let Event::Key(k) = event::read().map_err(ObserveError::Terminal)?
                && k.kind == KeyEventKind::Press
            {
                match k.code {
                    KeyCode::Char('q') | KeyCode::Esc if !quit => {
                        quit = true;
                        banner.stopping = true;
                        banner.paused = false;
                        last_draw = None;
                        on_quit();
                        if leave_on_quit {
                            return Ok(Exit::Quit);
                        }
                    }
                    KeyCode::Char(' ') => {
                        banner.paused = !banner.paused;
                        if banner.paused {
                            // one frame that says so, then frozen
                            term.draw(|f| draw(f, vm, &banner))
                                .map_err(ObserveError::Terminal)?;
                        }
                        last_draw = None;
                    }
                    _ if banner.ended => return Ok(if quit { Exit::Quit } else { Exit::Ended }),
                    _ => {}
                }
            }
        }
    })();
    let restored = ratatui::try_restore().map_err(ObserveError::Terminal);
    let exit = result?;
    restored?;
    Ok(exit)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decode::Msg;
    use bus_schema::{QHint, QHintBatch, RobotState};
    use planner::grid::Grid;
    use ratatui::Terminal;
    use ratatui::backend::TestBackend;

    /// 6×4 map with a wall column at x = 3 (rows 0–2), start (0,0), goal (5,0).
    fn model() -> ViewModel {
        let mut free = vec![true; 24];
        for y in 0..3 {
            free[y * 6 + 3] = false;
        }
        let g = Grid::new(6, 4, free).unwrap();
        ViewModel::new("walls", g, Cell::new(0, 0), Cell::new(5, 0))
    }

    #[test]
    fn glyphs_show_walls_robots_goal_and_the_greedy_path() {
        let mut vm = model();
        vm.apply(
            1,
            Msg::State(&RobotState {
                robot_id: 1,
                cell_x: 2,
                cell_y: 3,
                ..RobotState::ZEROED
            }),
        );
        // robot 1's greedy path: right, right (0,0)→(2,0), then down … only two steps shared
        let mut h = QHintBatch {
            robot_id: 1,
            count: 2,
            ..QHintBatch::ZEROED
        };
        h.entries[0] = QHint {
            cell: 0,
            action: 1,
            q: 0.1,
            ..QHint::ZEROED
        };
        h.entries[1] = QHint {
            cell: 1,
            action: 1,
            q: 0.1,
            ..QHint::ZEROED
        };
        vm.apply(2, Msg::Hints(&h));
        let g = map_glyphs(&vm, 80, 40);
        assert_eq!(g.len(), 4);
        assert_eq!(g[0].len(), 6);
        for (y, row) in g.iter().take(3).enumerate() {
            assert_eq!(row[3].0, WALL, "row {y}");
        }
        assert_eq!(g[3][3].0, FREE);
        assert_eq!(g[3][2], ('1', Some(1)));
        assert_eq!(g[0][5].0, GOAL);
        assert_eq!(g[0][0].0, START);
        assert_eq!(g[0][1], (PATH, Some(1)));
        assert_eq!(g[0][2], (PATH, Some(1)));
    }

    #[test]
    fn big_maps_scale_down_to_fit() {
        let g = Grid::new(300, 100, vec![true; 30_000]).unwrap();
        let vm = ViewModel::new("big", g, Cell::new(0, 0), Cell::new(299, 99));
        assert_eq!(scale(300, 100, 60, 30), 5);
        let glyphs = map_glyphs(&vm, 60, 30);
        assert!(glyphs.len() <= 30 && glyphs[0].len() <= 60);
        assert_eq!(glyphs[glyphs.len() - 1][glyphs[0].len() - 1].0, GOAL);
    }

    #[test]
    fn a_frame_draws_the_grid_and_the_robots_where_they_are() {
        let mut vm = model();
        vm.apply(
            1,
            Msg::State(&RobotState {
                robot_id: 0,
                cell_x: 4,
                cell_y: 2,
                episode: 7,
                status: 1,
                ..RobotState::ZEROED
            }),
        );
        let mut term = Terminal::new(TestBackend::new(100, 30)).unwrap();
        let banner = Banner {
            source: "test".into(),
            ..Banner::default()
        };
        term.draw(|f| draw(f, &mut vm, &banner)).unwrap();
        let buf = term.backend().buffer().clone();
        // the map block starts inside the border at (1, 2): row 0 of the map is screen row 2
        let at = |x: u16, y: u16| buf[(x, y)].symbol().to_string();
        for y in 0..3 {
            assert_eq!(at(1 + 3, 2 + y), WALL.to_string(), "wall at map (3,{y})");
        }
        assert_eq!(at(1 + 4, 2 + 2), "0", "robot 0 at map (4,2)");
        assert_eq!(at(1 + 5, 2), "G");
        assert_eq!(at(1, 2), "S");
        let text: String = (0..30)
            .map(|y| (0..100).map(|x| at(x, y)).collect::<String>() + "\n")
            .collect();
        assert!(text.contains("running"), "{text}");
        assert!(text.contains("walls 6×4"), "{text}");
        assert!(text.contains("robot/state"), "{text}");
    }
}
