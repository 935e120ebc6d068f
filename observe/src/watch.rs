//! `--live` and `--record` for a launcher: one thread that joins the run as an outside reader
//! once its services exist, feeds every message to the live view and/or the MCAP recorder, and
//! leaves when the launcher says the run is over ([`Watch::finish`]).
//!
//! The launcher calls [`start`] before starting the run's processes (the thread only reads
//! iceoryx2's bookkeeping until the services exist, so the run id stays free),
//! [`Watch::wait_joined`] after the coordinator and before the robots (so nothing a robot sends
//! is missed), and [`Watch::finish`] after they all exited and **before** it removes the run's files: the
//! observer's node must be gone by then.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use planner::grid::Cell;
use planner::task::Task;

use crate::ObserveError;
use crate::attach::Observer;
use crate::record::{BackgroundRecorder, Recorder, RunInfo};
use crate::stats::TopicCounts;
use crate::tui::{self, Exit, Feed};
use crate::view::ViewModel;

/// What to do while a run goes on.
#[derive(Debug, Clone, Default)]
pub struct WatchOptions {
    /// Show the terminal live view.
    pub live: bool,
    /// Record every message into this MCAP file.
    pub record: Option<PathBuf>,
}

impl WatchOptions {
    /// Whether anything is asked for at all.
    pub fn any(&self) -> bool {
        self.live || self.record.is_some()
    }
}

/// What the watch thread saw.
#[derive(Debug, Clone, Default)]
pub struct WatchReport {
    /// The user pressed `q` in the live view.
    pub quit: bool,
    /// Messages seen per topic.
    pub counts: TopicCounts,
    /// Messages written into the recording.
    pub recorded: u64,
}

/// A running watch thread.
pub struct Watch {
    done: Arc<AtomicBool>,
    /// [`PENDING`], [`JOINED`] or [`GAVE_UP`]: whether the thread has joined the run yet.
    joined: Arc<AtomicU8>,
    handle: Option<JoinHandle<Result<WatchReport, ObserveError>>>,
}

/// [`Watch`]'s join state: still waiting for the run's services.
const PENDING: u8 = 0;
/// Joined: a subscriber is open on every topic.
const JOINED: u8 = 1;
/// The thread will not join (the run ended first, or the attach failed).
const GAVE_UP: u8 = 2;

impl Watch {
    /// Waits (up to `timeout`) until the thread has joined the run with a subscriber on every
    /// topic, so that it sees every message sent from then on; false when it gave up or the
    /// time ran out. The launcher calls it between starting the coordinator (whose services
    /// the thread joins) and starting the robots, so a recording holds the run from its first
    /// registration: a robot's publisher connects to a subscriber that exists at its first send.
    pub fn wait_joined(&self, timeout: Duration) -> bool {
        let t0 = Instant::now();
        loop {
            match self.joined.load(Ordering::SeqCst) {
                JOINED => return true,
                GAVE_UP => return false,
                _ if t0.elapsed() >= timeout => return false,
                _ => std::thread::sleep(Duration::from_millis(1)),
            }
        }
    }

    /// Tells the thread the run is over, waits for it to drain, close the recording and
    /// leave the run, and returns what it saw.
    pub fn finish(mut self) -> Result<WatchReport, ObserveError> {
        self.done.store(true, Ordering::SeqCst);
        match self.handle.take().map(JoinHandle::join) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(ObserveError::Bus("the watch thread panicked".into())),
            None => Ok(WatchReport::default()),
        }
    }
}

impl Drop for Watch {
    fn drop(&mut self) {
        self.done.store(true, Ordering::SeqCst);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// The recording's description of a run on `task` (the map as a MovingAI file), plus `config`.
pub fn run_info(
    run_id: &str,
    task: &Task,
    config: impl IntoIterator<Item = (String, String)>,
) -> RunInfo {
    let map = planner::map::GridMap {
        name: task.map_name.clone(),
        grid: task.grid.clone(),
        start: Some(task.start),
        goals: vec![task.goal],
    };
    RunInfo {
        run_id: run_id.to_string(),
        map_name: task.map_name.clone(),
        map_text: map.to_movingai(),
        start: (task.start.x, task.start.y),
        goal: (task.goal.x, task.goal.y),
        config: config.into_iter().collect(),
    }
}

/// How long the thread waits for the run's services before it gives up.
const ATTACH_TIMEOUT: Duration = Duration::from_secs(120);

/// Starts watching run `run_id` (of `task`) as `opts` asks; `on_quit` is called once when the
/// user presses `q` in the live view (the launcher's graceful stop, as Ctrl-C). The recording
/// file is created here, before anything of the run starts: a path that cannot be written is
/// an error now, not after the run.
pub fn start(
    run_id: &str,
    task: &Task,
    info: RunInfo,
    opts: WatchOptions,
    on_quit: Box<dyn Fn() + Send>,
) -> Result<Watch, ObserveError> {
    // encoded on a low-priority thread of its own: the watch thread only copies messages
    let rec = match &opts.record {
        Some(p) => Some(BackgroundRecorder::start(Recorder::create(p, &info)?)?),
        None => None,
    };
    let done = Arc::new(AtomicBool::new(false));
    let d = Arc::clone(&done);
    let joined = Arc::new(AtomicU8::new(PENDING));
    let j = Arc::clone(&joined);
    let run_id = run_id.to_string();
    let (grid, start, goal, name) = (
        task.grid.clone(),
        task.start,
        task.goal,
        task.map_name.clone(),
    );
    let handle = std::thread::Builder::new()
        .name("qfleet-watch".into())
        .spawn(move || {
            let vm = ViewModel::new(&name, grid, start, goal);
            let r = watch_thread(&run_id, vm, rec, &opts, &d, &j, &*on_quit);
            // an attach that never happened (an error, the run over first) is final
            let _ = j.compare_exchange(PENDING, GAVE_UP, Ordering::SeqCst, Ordering::SeqCst);
            r
        })
        .ok();
    if handle.is_none() {
        joined.store(GAVE_UP, Ordering::SeqCst);
    }
    Ok(Watch {
        done,
        joined,
        handle,
    })
}

fn watch_thread(
    run_id: &str,
    mut vm: ViewModel,
    mut rec: Option<BackgroundRecorder>,
    opts: &WatchOptions,
    done: &AtomicBool,
    joined: &AtomicU8,
    on_quit: &dyn Fn(),
) -> Result<WatchReport, ObserveError> {
    let observer = match Observer::attach(run_id, ATTACH_TIMEOUT, &|| done.load(Ordering::SeqCst)) {
        Ok(o) => {
            joined.store(JOINED, Ordering::SeqCst);
            // Joined (before the robots started: see `Watch::wait_joined`), a recorder reads at
            // the lowest priority, so it takes from a run that fills every core only what the
            // run leaves: a lossless topic's samples wait in our buffers (256 discoveries per
            // robot), a latest-wins topic's older samples are dropped for us alone. The live
            // view keeps its priority: a person is watching it.
            if !opts.live {
                crate::record::lower_priority();
            }
            o
        }
        Err(e) => {
            if let Some(r) = rec.take() {
                r.finish()?;
            }
            return Err(e);
        }
    };
    let mut feed = |vm: &mut ViewModel| -> Result<Feed, ObserveError> {
        let over = done.load(Ordering::SeqCst);
        let n = observer.poll(|t, m| {
            vm.apply(t, m);
            if let Some(r) = rec.as_mut() {
                r.record(t, m);
            }
        })?;
        if over {
            return Ok(Feed::Ended);
        }
        if n == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
        Ok(Feed::More)
    };
    let mut quit = false;
    if opts.live {
        let src = format!("run {run_id}");
        quit = tui::run(&mut vm, &src, &mut feed, on_quit, false, false)? == Exit::Quit;
    }
    while feed(&mut vm)? == Feed::More {}
    drop(observer);
    // the launcher may have cleaned up while we were still attached: finish its job
    crate::attach::leave(run_id)?;
    let mut report = WatchReport {
        quit,
        counts: vm.counts.clone(),
        recorded: 0,
    };
    if let Some(r) = rec {
        report.recorded = r.finish()?;
    }
    Ok(report)
}

/// A [`ViewModel`] for a recording: its map attachment and start/goal metadata.
pub fn view_of_recording(r: &crate::replay::Recording) -> Result<ViewModel, ObserveError> {
    let text = r
        .map_text
        .as_deref()
        .ok_or_else(|| ObserveError::Map("the recording has no map attachment".into()))?;
    let map = planner::map::parse_movingai_map("map.map", text.as_bytes())
        .map_err(|e| ObserveError::Map(e.to_string()))?;
    let cell = |k: &str| r.cell(k).map(|(x, y)| Cell::new(x, y));
    let start = cell("start").unwrap_or(Cell::new(0, 0));
    let goal = cell("goal").unwrap_or(start);
    let name = r.meta.get("map").cloned().unwrap_or(map.name);
    Ok(ViewModel::new(&name, map.grid, start, goal))
}
