//! The line protocol between a run's coordinator and its launcher: the coordinator writes
//! these lines with [`progress_line`], [`event_line`] and [`result_line`], the launcher reads
//! them with [`parse_line`].
//!
//! Coordinator → launcher (its stdout, one line each, space separated; other lines are ignored):
//! - `progress <episodes done> <episodes total> <p50 ns> <p99 ns>`
//! - `event <kind> <robot id> <ns since start>`, kind `hung` (silent past `--hang-ms`: the
//!   launcher kills it to restart it under the policy), or any other (lost, joined, …);
//! - `result <json>`: the run's result, sent only when `result.json` could not be written (a
//!   full disk), so the launcher can still print it.
//!
//! Launcher → coordinator (the file `robot-<id>.exited` in the run directory, see
//! `coordinator::exited_file`): `exited <robot id> <code or -signal>` when the launcher reaped a
//! robot process for good, so the coordinator can mark a robot that never registered lost at
//! once instead of waiting for it (see [`exited_line`]).

/// One line the coordinator prints on stdout.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CoordLine {
    /// `progress <episodes done> <total> <p50 ns> <p99 ns>`.
    Progress(u64, u64, u64, u64),
    /// `event hung <robot id> <ns>`.
    Hung(u32),
    /// Any other `event <kind> <robot id> <ns>` (lost, restarted, resumed …).
    Event(u32),
    /// `result <json>`: the result the coordinator could not write into `result.json`.
    Result(String),
}

/// The `progress` line: episodes done of `total`, loop latency p50 and p99 in ns.
pub fn progress_line(done: u64, total: u64, p50_ns: u64, p99_ns: u64) -> String {
    format!("progress {done} {total} {p50_ns} {p99_ns}")
}

/// An `event` line: liveness event `kind` (`hung`, `lost`, …) of robot `id` at `at_ns` since
/// the start.
pub fn event_line(kind: impl std::fmt::Display, id: u32, at_ns: u64) -> String {
    format!("event {kind} {id} {at_ns}")
}

/// The `result` line: the run's result as one line of JSON.
pub fn result_line(json: &str) -> String {
    format!("result {json}")
}

/// Parses one stdout line of the coordinator (`None`: not a line for the launcher).
pub fn parse_line(line: &str) -> Option<CoordLine> {
    if let Some(json) = line.strip_prefix("result ") {
        return Some(CoordLine::Result(json.to_string()));
    }
    if let Some(rest) = line.strip_prefix("progress ") {
        let v: Vec<u64> = rest.split(' ').filter_map(|x| x.parse().ok()).collect();
        return (v.len() == 4).then(|| CoordLine::Progress(v[0], v[1], v[2], v[3]));
    }
    let mut words = line.strip_prefix("event ")?.split(' ');
    let kind = words.next()?;
    let id: u32 = words.next()?.parse().ok()?;
    Some(if kind == "hung" {
        CoordLine::Hung(id)
    } else {
        CoordLine::Event(id)
    })
}

/// The line telling the coordinator that robot `id`'s process ended: `code` if it exited,
/// `-signal` if a signal killed it.
pub fn exited_line(id: u32, code: Option<i32>, signal: Option<i32>) -> String {
    match (code, signal) {
        (Some(c), _) => format!("exited {id} {c}\n"),
        (None, Some(s)) => format!("exited {id} -{s}\n"),
        (None, None) => format!("exited {id} -0\n"),
    }
}

/// Parses a launcher → coordinator line: the robot id and its code (negative: a signal).
pub fn parse_exited(line: &str) -> Option<(u32, i32)> {
    let mut w = line.trim_end().strip_prefix("exited ")?.split(' ');
    let id = w.next()?.parse().ok()?;
    let code = w.next()?.parse().ok()?;
    w.next().is_none().then_some((id, code))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn what_the_coordinator_writes_the_launcher_reads() {
        assert_eq!(
            parse_line(&progress_line(1, 2, 3, 4)),
            Some(CoordLine::Progress(1, 2, 3, 4))
        );
        assert_eq!(
            parse_line(&event_line("hung", 3, 9)),
            Some(CoordLine::Hung(3))
        );
        assert_eq!(
            parse_line(&event_line("lost", 7, 9)),
            Some(CoordLine::Event(7))
        );
        assert_eq!(
            parse_line(&result_line("{}")),
            Some(CoordLine::Result("{}".into()))
        );
    }

    #[test]
    fn parses_progress_and_events() {
        assert_eq!(
            parse_line("progress 1 2 3 4"),
            Some(CoordLine::Progress(1, 2, 3, 4))
        );
        assert_eq!(parse_line("event hung 3 99"), Some(CoordLine::Hung(3)));
        assert_eq!(parse_line("event lost 7 99"), Some(CoordLine::Event(7)));
        assert_eq!(
            parse_line(r#"result {"run_id":"r"}"#),
            Some(CoordLine::Result(r#"{"run_id":"r"}"#.into()))
        );
        for junk in ["", "progress 1 2", "event hung x 1", "hello", "event"] {
            assert_eq!(parse_line(junk), None, "{junk:?}");
        }
    }

    #[test]
    fn exited_lines_round_trip() {
        assert_eq!(parse_exited(&exited_line(3, Some(1), None)), Some((3, 1)));
        assert_eq!(parse_exited(&exited_line(0, None, Some(9))), Some((0, -9)));
        for junk in ["", "exited", "exited x 1", "exited 1", "exited 1 2 3"] {
            assert_eq!(parse_exited(junk), None, "{junk:?}");
        }
    }
}
