//! A recording played back at its recorded pace over a `speed` factor (`qfleet replay --live`,
//! `--foxglove`), read one message at a time (a recording is never held whole): into the live
//! view ([`live`]) or into a Foxglove server once a client connected ([`to_foxglove`]).

use std::time::{Duration, Instant};

use planner::grid::Cell;

use crate::ObserveError;
use crate::foxglove::{RunStart, Server};
use crate::replay::{Messages, Owned, Recording, from_json};
use crate::tui::{self, Feed};
use crate::view::ViewModel;

/// The next message of a recording, typed, with its log time.
pub fn next_owned(msgs: &mut Messages) -> Result<Option<(u64, Owned)>, ObserveError> {
    Ok(msgs
        .next_message()?
        .map(|m| (m.log_time, from_json(m.topic, &m.json))))
}

/// Plays `msgs` (whose first message, already read, is `first`) of `rec` into `server` once a
/// first client has connected (`note` says it waits), at the recorded pace over `speed`,
/// until the end or until `stopped()`; the map and run come from `vm`, the recording's view.
#[allow(clippy::too_many_arguments)]
pub fn to_foxglove(
    rec: &Recording,
    vm: &ViewModel,
    msgs: &mut Messages,
    mut first: Option<(u64, Owned)>,
    server: &Server,
    speed: f64,
    stopped: &dyn Fn() -> bool,
    note: &dyn Fn(&str),
) -> Result<(), ObserveError> {
    let t0 = first.as_ref().map_or_else(crate::record::wall_ns, |m| m.0);
    let cell = |k: &str| rec.cell(k).map(|(x, y)| Cell::new(x, y));
    let start = cell("start").unwrap_or(Cell::new(0, 0));
    server.begin_run(
        RunStart {
            run_id: rec.meta.get("run_id").cloned().unwrap_or_default(),
            map_name: vm.map_name.clone(),
            grid: vm.grid.clone(),
            start,
            goal: cell("goal").unwrap_or(start),
        },
        t0,
    );
    note("foxglove: playing once a client connects (Ctrl-C stops)");
    while server.clients() == 0 && !stopped() {
        std::thread::sleep(Duration::from_millis(50));
    }
    // the client subscribes after it read the advertisement
    std::thread::sleep(Duration::from_millis(500));
    let begin = Instant::now();
    while let Some((t, m)) = match first.take() {
        Some(m) => Some(m),
        None => next_owned(msgs)?,
    } {
        if stopped() {
            break;
        }
        let due = Duration::from_secs_f64(t.saturating_sub(t0) as f64 / 1e9 / speed);
        if let Some(wait) = due.checked_sub(begin.elapsed()) {
            std::thread::sleep(wait);
        }
        server.offer_wait(t, rec.mono_of(t), m);
    }
    Ok(())
}

/// Shows `msgs` of `rec` (whose first message, already read, is `first`) in the live view
/// `vm` titled `source`, at the recorded pace over `speed`; a damaged record ends the view
/// with its error.
pub fn live(
    rec: &Recording,
    vm: &mut ViewModel,
    mut msgs: Messages,
    first: Option<(u64, Owned)>,
    speed: f64,
    source: &str,
) -> Result<(), ObserveError> {
    let mut next = first.map(|(t, m)| (rec.mono_of(t), m));
    let t0 = next.as_ref().map_or(0, |m| m.0);
    let start = Instant::now();
    let feed = |vm: &mut ViewModel| -> Result<Feed, ObserveError> {
        let played = (start.elapsed().as_secs_f64() * speed * 1e9) as u64;
        while let Some((t, m)) = next.take_if(|m| m.0.saturating_sub(t0) <= played) {
            vm.apply(t, m.as_msg());
            next = next_owned(&mut msgs)?.map(|(t, m)| (rec.mono_of(t), m));
        }
        if next.is_none() {
            return Ok(Feed::Ended);
        }
        std::thread::sleep(Duration::from_millis(2));
        Ok(Feed::More)
    };
    tui::run(vm, source, feed, &|| {}, true, true)?;
    Ok(())
}
