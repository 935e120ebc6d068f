//! The live view in a real terminal: `qfleet run --live --pace …` in a detached tmux session of
//! a fixed size. The screen shows the header, the map with its walls where the map has them and
//! the robots on it; `space` freezes the view and unfreezes it; `q` stops the run gracefully:
//! exit code 0, the result written, nothing of the run left in shared memory.
//!
//! Needs tmux (`apt-get install tmux`); without it the test says `SKIPPED …` and passes.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::Duration;

use qfleet_suite::{bin, leftovers, run_id, scratch, skip, wait_until};

const COLS: u16 = 120;
const ROWS: u16 = 40;

/// A tmux server of our own (its socket in the test's scratch directory), killed on drop.
struct Tmux {
    socket: PathBuf,
}

impl Tmux {
    fn cmd(&self) -> Command {
        let mut c = Command::new("tmux");
        // -u: the pane is UTF-8 whatever the test's locale (walls are `█`)
        c.arg("-u").arg("-S").arg(&self.socket);
        c
    }

    fn run(&self, args: &[&str]) -> Output {
        let out = self.cmd().args(args).output().expect("running tmux");
        assert!(
            out.status.success(),
            "tmux {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        out
    }

    /// The pane's text, one string per screen row.
    fn screen(&self) -> Vec<String> {
        let out = self
            .cmd()
            .args(["capture-pane", "-p", "-t", "tui"])
            .output()
            .expect("running tmux");
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .map(str::to_string)
            .collect()
    }

    fn keys(&self, key: &str) {
        self.run(&["send-keys", "-t", "tui", key]);
    }
}

impl Drop for Tmux {
    fn drop(&mut self) {
        let _ = self.cmd().arg("kill-server").output();
        let _ = std::fs::remove_file(&self.socket);
    }
}

fn tmux_missing() -> bool {
    Command::new("tmux")
        .arg("-V")
        .output()
        .map_or(true, |o| !o.status.success())
}

/// The character at column `x` of a screen row (rows hold multi-byte glyphs).
fn char_at(row: &str, x: usize) -> Option<char> {
    row.chars().nth(x)
}

/// The map as drawn: screen row 2 + y, column 1 + x (inside the map block's border, under the
/// header line) for a map small enough to be drawn one character per cell.
fn drawn_cell(screen: &[String], x: usize, y: usize) -> Option<char> {
    screen.get(2 + y).and_then(|r| char_at(r, 1 + x))
}

#[test]
fn the_live_view_draws_the_fleet_pauses_and_q_stops_the_run_cleanly() {
    if tmux_missing() {
        skip(
            "the_live_view_draws_the_fleet_pauses_and_q_stops_the_run_cleanly",
            "tmux is not installed (apt-get install tmux)",
        );
        return;
    }
    let dir = scratch("tui");
    let id = run_id("tui");
    let out_dir = dir.join("out");
    let exit_file = dir.join("exit");
    let qfleet = bin("qfleet");
    let map = planner::map::load_map("builtin:paper-10").unwrap();
    let (w, h) = (map.grid.width(), map.grid.height());
    // a paced run that cannot end on its own in the test's time: only `q` ends it
    let shell = format!(
        "{} run --robots 2 --map builtin:paper-10 --live --pace 40 --run-id {id} --out {}; echo $? > {}",
        sh_quote(&qfleet),
        sh_quote(&out_dir),
        sh_quote(&exit_file)
    );
    let tmux = Tmux {
        socket: dir.join("tmux.sock"),
    };
    tmux.run(&[
        "new-session",
        "-d",
        "-s",
        "tui",
        "-x",
        &COLS.to_string(),
        "-y",
        &ROWS.to_string(),
        &shell,
    ]);
    let ok = Duration::from_secs(60);

    // header, map and both robots on it
    let mut screen = Vec::new();
    let drawn = wait_until(ok, || {
        screen = tmux.screen();
        let robots_on_map = ['0', '1']
            .iter()
            .all(|r| (0..h).any(|y| (0..w).any(|x| drawn_cell(&screen, x, y) == Some(*r))));
        screen.first().is_some_and(|t| t.contains(&id)) && robots_on_map
    });
    assert!(
        drawn,
        "no header with both robots on the map:\n{}",
        screen.join("\n")
    );
    let header = &screen[0];
    assert!(header.contains("map paper-10 10×10"), "{header}");
    assert!(header.contains("live"), "{header}");
    assert!(
        screen[1].contains(" map "),
        "map block title: {}",
        screen[1]
    );
    for y in 0..h {
        for x in 0..w {
            let c = planner::grid::Cell::new(x as u16, y as u16);
            let wall = drawn_cell(&screen, x, y) == Some('█');
            assert_eq!(
                wall,
                !map.grid.is_free(c),
                "map cell ({x},{y}) drawn wrong:\n{}",
                screen.join("\n")
            );
        }
    }
    let text = screen.join("\n");
    assert!(
        text.contains("robots") && text.contains("running"),
        "{text}"
    );
    assert!(text.contains("G"), "the goal: {text}");

    // the view moves while live (so that a frozen one means something) …
    let first = tmux.screen();
    assert!(
        wait_until(ok, || tmux.screen() != first),
        "the live view never changed"
    );
    // … and stands still while paused
    tmux.keys("Space");
    assert!(
        wait_until(ok, || tmux.screen()[0].contains("PAUSED")),
        "space did not pause: {}",
        tmux.screen().join("\n")
    );
    let frozen = tmux.screen();
    std::thread::sleep(Duration::from_millis(1500));
    assert_eq!(tmux.screen(), frozen, "the paused view changed");
    tmux.keys("Space");
    assert!(
        wait_until(ok, || {
            let s = tmux.screen();
            s[0].contains("live") && s != frozen
        }),
        "space did not resume the view"
    );

    // q: a graceful stop that exits 0 with the result written and nothing left behind
    tmux.keys("q");
    assert!(
        wait_until(Duration::from_secs(90), || exit_file.exists()
            && std::fs::read_to_string(&exit_file)
                .is_ok_and(|s| s.ends_with('\n'))),
        "the run did not end after q"
    );
    let code = std::fs::read_to_string(&exit_file).unwrap();
    let log = inventory(&out_dir);
    assert_eq!(code.trim(), "0", "exit code after q; {log}");
    let result: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("result.json")).unwrap())
            .unwrap();
    assert_eq!(
        result["robots"].as_array().map(Vec::len),
        Some(2),
        "{result}"
    );
    let left = leftovers(&id);
    assert!(left.is_empty(), "files of the run left behind: {left:?}");
    drop(tmux);
    let _ = std::fs::remove_dir_all(&dir);
}

fn sh_quote(p: &Path) -> String {
    format!("'{}'", p.display().to_string().replace('\'', r"'\''"))
}

/// The files of a run's output directory and the tail of its logs, for failure messages.
fn inventory(dir: &Path) -> String {
    let mut s = String::new();
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        s.push_str(&format!("{} ", e.file_name().to_string_lossy()));
        if e.path().extension().is_some_and(|x| x == "log") {
            let t = std::fs::read_to_string(e.path()).unwrap_or_default();
            let tail: Vec<&str> = t.lines().rev().take(5).collect();
            s.push_str(&format!("[{}] ", tail.join(" | ")));
        }
    }
    s
}
