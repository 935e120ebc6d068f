//! `--live` and `--record` for a launcher: one thread that joins the run as an outside reader
//! once its services exist, feeds every message to the live view and/or the MCAP recorder, and
//! leaves when the launcher says the run is over ([`Watch::finish`]). It reads the latest-wins
//! topics itself (at the lowest priority when it only records) and takes the lossless ones
//! from a second reader on a thread of normal priority that a wakeup runs (`LosslessReader`):
//! a starved reader would lose the samples of robots that exit before it first reads.
//!
//! The launcher calls [`start`] before starting the run's processes (the thread only reads
//! iceoryx2's bookkeeping until the services exist, so the run id stays free),
//! [`Watch::wait_joined`] after the coordinator and before the robots (so nothing a robot sends
//! is missed), and [`Watch::finish`] after they all exited and **before** it removes the run's files: the
//! observer's node must be gone by then.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::{Arc, mpsc};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use planner::grid::Cell;
use planner::task::Task;

use crate::ObserveError;
use bus::iceoryx2::prelude::{CallbackProgression, SignalHandlingMode, WaitSetBuilder, ipc};

use crate::attach::{Observer, Topics};
use crate::decode::{Msg, Owned};
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
    /// Serve the run to Foxglove clients on this (already bound) server.
    pub foxglove: Option<Arc<crate::foxglove::Server>>,
    /// Show and record only the run's own processes — children of this process (the
    /// launcher) — and of a robot's messages only those naming one of this many robots; the
    /// others are counted ([`WatchReport::others`]). `None`: everything in the prefix.
    pub own_fleet: Option<u32>,
}

impl WatchOptions {
    /// Whether anything is asked for at all.
    pub fn any(&self) -> bool {
        self.live || self.record.is_some() || self.foxglove.is_some()
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
    /// Messages neither shown nor recorded because a process outside the run sent them (or
    /// they named a robot the fleet does not have), per topic in [`bus_schema::names::Topic::ALL`]'s order.
    pub others: Vec<u64>,
}

impl WatchReport {
    /// The warning to give when messages from outside the run were left out (None if none
    /// were): how many in all, and per topic.
    pub fn others_warning(&self) -> Option<String> {
        let others: u64 = self.others.iter().sum();
        if others == 0 {
            return None;
        }
        let topics: Vec<String> = bus_schema::names::Topic::ALL
            .iter()
            .zip(&self.others)
            .filter(|(_, n)| **n > 0)
            .map(|(t, n)| format!("{} {n}", t.path()))
            .collect();
        Some(format!(
            "warning: {others} message(s) from processes outside the run (or naming a robot it \
             does not have) were neither shown nor recorded: {}",
            topics.join(", ")
        ))
    }
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
    // the Foxglove server's scene of this run starts now: the map is there before any robot
    let clock = (crate::record::wall_ns(), bus::monotonic_ns());
    if let Some(f) = &opts.foxglove {
        f.begin_run(
            crate::foxglove::RunStart {
                run_id: run_id.to_string(),
                map_name: task.map_name.clone(),
                grid: task.grid.clone(),
                start: task.start,
                goal: task.goal,
            },
            clock.0,
        );
    }
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
            let r = watch_thread(&run_id, vm, rec, &opts, clock, &d, &j, &*on_quit);
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

#[allow(clippy::too_many_arguments)]
fn watch_thread(
    run_id: &str,
    mut vm: ViewModel,
    mut rec: Option<BackgroundRecorder>,
    opts: &WatchOptions,
    (wall0, mono0): (u64, u64),
    done: &AtomicBool,
    joined: &AtomicU8,
    on_quit: &dyn Fn(),
) -> Result<WatchReport, ObserveError> {
    let give_up = || done.load(Ordering::SeqCst);
    let own = |o: Observer| match opts.own_fleet {
        Some(robots) => o.only_own(robots, std::process::id() as i32),
        None => Ok(o),
    };
    let joining = Observer::attach(run_id, Topics::LatestWins, ATTACH_TIMEOUT, &give_up)
        .and_then(own)
        .and_then(|o| Ok((o, LosslessReader::start(run_id, opts.own_fleet)?)));
    let (observer, lossless) = match joining {
        Ok(both) => {
            joined.store(JOINED, Ordering::SeqCst);
            both
        }
        Err(e) => {
            if let Some(r) = rec.take() {
                r.finish()?;
            }
            return Err(e);
        }
    };
    let mut lossless = Some(lossless);
    let mut lossless_others = [0u64; bus_schema::names::Topic::ALL.len()];
    // Joined (before the robots started: see `Watch::wait_joined`), a recorder reads the
    // latest-wins topics at the lowest priority, so it takes from a run that fills every core
    // only what the run leaves: their older samples are dropped for us alone. The lossless
    // topics have a thread of their own that a wakeup runs (see `LosslessReader`). The live
    // view keeps its priority: a person is watching it.
    let mut idle = LowerOnceConnected::new(
        !opts.live,
        opts.own_fleet.map_or(0, |r| r as usize),
        Instant::now() + CONNECT_BEFORE_IDLE,
    );
    let mut feed = |vm: &mut ViewModel| -> Result<Feed, ObserveError> {
        let over = done.load(Ordering::SeqCst);
        if idle.due(Instant::now()) {
            // connected and told whose the senders are first: a connected reader keeps the
            // last samples of a publisher that leaves before it reads again, and a sender is
            // told to be the run's own only while it is listed, so even a reader the run
            // starves records each robot's latest state and hints (read after the run)
            observer.connect_all()?;
            observer.learn_senders();
            crate::record::lower_priority();
        }
        let mut take = |t: u64, m: Msg<'_>| {
            idle.saw(m);
            vm.apply(t, m);
            if let Some(r) = rec.as_mut() {
                r.record(t, m);
            }
            if let Some(f) = &opts.foxglove {
                f.offer(
                    wall0.saturating_add(t.saturating_sub(mono0)),
                    t,
                    Owned::of(m),
                );
            }
        };
        let mut n = 0;
        if let Some(l) = &lossless {
            n += l.take(&mut take);
        }
        n += observer.poll(&mut take)?;
        if over {
            // the lossless reader's last drain comes after the run's last process ended
            if let Some(l) = lossless.take() {
                lossless_others = l.finish(&mut take)?;
            }
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
    let others = observer
        .others()
        .iter()
        .zip(lossless_others)
        .map(|(a, b)| a + b)
        .collect();
    drop(observer);
    // the launcher may have cleaned up while we were still attached: finish its job
    crate::attach::leave(run_id)?;
    let mut report = WatchReport {
        quit,
        counts: vm.counts.clone(),
        recorded: 0,
        others,
    };
    if let Some(r) = rec {
        report.recorded = r.finish()?;
    }
    Ok(report)
}

/// How long the watch thread waits at normal priority for every robot's registration before it
/// moves to the idle class anyway (a robot that never starts must not keep it there).
const CONNECT_BEFORE_IDLE: Duration = Duration::from_secs(5);

/// When the watch thread of a recording moves to the idle class: once its latest-wins readers
/// can connect to every robot's publishers (a robot opens them all before it registers, so
/// after the last robot's registration), or at the deadline. A reader that never connected to
/// a publisher loses that publisher's samples when it leaves (see [`crate::attach`]), and an
/// idle-class reader on a machine whose cores are busy may first run after the robots exited.
#[derive(Debug)]
struct LowerOnceConnected {
    /// Whether to lower at all (not for the live view).
    wanted: bool,
    /// Robots whose registration was seen (ids below `robots`).
    seen: Vec<bool>,
    /// How many of them.
    count: usize,
    deadline: Instant,
}

impl LowerOnceConnected {
    fn new(wanted: bool, robots: usize, deadline: Instant) -> Self {
        Self {
            wanted,
            seen: vec![false; robots.min(MAX_WATCHED_ROBOTS)],
            count: 0,
            deadline,
        }
    }

    /// Notes a message (a registration counts its robot).
    fn saw(&mut self, m: Msg<'_>) {
        if let Msg::Register(r) = m
            && let Some(s) = self.seen.get_mut(r.robot_id as usize)
            && !*s
        {
            *s = true;
            self.count += 1;
        }
    }

    /// Whether to connect and lower now; true once.
    fn due(&mut self, now: Instant) -> bool {
        let due = self.wanted && (self.count == self.seen.len() || now >= self.deadline);
        if due {
            self.wanted = false;
        }
        due
    }
}

/// Robots whose registrations [`LowerOnceConnected`] tracks at most (a fleet's size is checked
/// elsewhere; this only bounds the table).
const MAX_WATCHED_ROBOTS: usize = 1 << 16;

/// How long the lossless reader may take to join once the watch thread has joined.
const JOIN_LOSSLESS: Duration = Duration::from_secs(10);

/// How long the lossless reader blocks at most between two looks at the stop flag (a wakeup
/// ends the wait at once).
const LOSSLESS_TICK: Duration = Duration::from_millis(20);

/// The reader of a run's lossless topics (registrations, discoveries, reports, control,
/// relays) for a watch whose own thread may be starved: an [`Observer`] of
/// [`Topics::Lossless`] on a thread of normal priority that blocks on the topics' wake events,
/// so it runs within a wakeup of every lossless send and connects to every publisher before
/// the publisher can leave (a reader that never connected to a publisher that left has lost
/// its samples: see [`crate::attach`]). It copies what it reads into a channel that the watch
/// thread empties; its CPU cost is one wakeup per lossless message, a few hundred in a run.
struct LosslessReader {
    rx: mpsc::Receiver<(u64, Owned)>,
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<Result<Others, ObserveError>>>,
}

/// Messages not shown, per topic (see [`Observer::others`]).
type Others = [u64; bus_schema::names::Topic::ALL.len()];

impl LosslessReader {
    /// Starts the thread and waits until its observer has joined run `run_id` (the run's
    /// services must exist); it reads until [`finish`](Self::finish), then once more.
    fn start(run_id: &str, own_fleet: Option<u32>) -> Result<Self, ObserveError> {
        let (tx, rx) = mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let done = Arc::clone(&stop);
        let (joined_tx, joined_rx) = mpsc::sync_channel(1);
        let run_id = run_id.to_string();
        let handle = std::thread::Builder::new()
            .name("qfleet-watch-lossless".into())
            .spawn(move || {
                // iceoryx2 ports stay on the thread that made them: join here (retrying an
                // open that fails while the coordinator still creates a service)
                let quit = || done.load(Ordering::SeqCst);
                let joined = Observer::attach(&run_id, Topics::Lossless, JOIN_LOSSLESS, &quit)
                    .and_then(|o| match own_fleet {
                        Some(robots) => o.only_own(robots, std::process::id() as i32),
                        None => Ok(o),
                    });
                let observer = match joined {
                    Ok(o) => {
                        let _ = joined_tx.send(Ok(()));
                        o
                    }
                    Err(e) => {
                        let _ = joined_tx.send(Err(e));
                        return Ok([0; bus_schema::names::Topic::ALL.len()]);
                    }
                };
                read_lossless(&observer, &done, &tx)?;
                Ok(observer.others())
            })
            .map_err(|e| ObserveError::Io {
                path: "the lossless reader thread".into(),
                source: e,
            })?;
        match joined_rx.recv() {
            Ok(Ok(())) => Ok(Self {
                rx,
                stop,
                handle: Some(handle),
            }),
            Ok(Err(e)) => Err(e),
            Err(_) => Err(ObserveError::Bus(
                "the lossless reader thread ended before it joined".into(),
            )),
        }
    }

    /// Hands everything read so far to `f`; returns how many messages.
    fn take(&self, f: &mut impl FnMut(u64, Msg<'_>)) -> usize {
        let mut n = 0;
        for (t, m) in self.rx.try_iter() {
            f(t, m.as_msg());
            n += 1;
        }
        n
    }

    /// Stops the thread after one last read (call it once the run's processes all ended),
    /// waits for it to leave the run, and hands the rest to `f`; returns the messages it did
    /// not show.
    fn finish(mut self, f: &mut impl FnMut(u64, Msg<'_>)) -> Result<Others, ObserveError> {
        let r = self.stop_and_join();
        self.take(f);
        r
    }

    fn stop_and_join(&mut self) -> Result<Others, ObserveError> {
        self.stop.store(true, Ordering::SeqCst);
        match self.handle.take().map(JoinHandle::join) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(ObserveError::Bus(
                "the lossless reader thread panicked".into(),
            )),
            None => Ok([0; bus_schema::names::Topic::ALL.len()]),
        }
    }
}

impl Drop for LosslessReader {
    /// A watch thread that ends early (an error) still leaves no node of ours in the run.
    fn drop(&mut self) {
        let _ = self.stop_and_join();
    }
}

/// The lossless reader's loop: read, then block until a wakeup or [`LOSSLESS_TICK`]; after
/// `done` is set, one last read.
fn read_lossless(
    observer: &Observer,
    done: &AtomicBool,
    tx: &mpsc::Sender<(u64, Owned)>,
) -> Result<(), ObserveError> {
    let waitset = WaitSetBuilder::new()
        // iceoryx2's own SIGINT/SIGTERM handler would replace the launcher's
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| ObserveError::Bus(format!("cannot create a WaitSet: {e:?}")))?;
    let _guards = observer.attach_all(&waitset)?;
    loop {
        let over = done.load(Ordering::SeqCst);
        // cleared before the read: a send after it wakes the next wait
        observer.clear_wakeups()?;
        // every topic connected before any is read: a message seen here means its sender's
        // other publishers (a robot opens them all before it registers) are connected too
        observer.connect_all()?;
        observer.poll(|t, m| {
            // the receiving end lives as long as the watch thread, which joins us first
            let _ = tx.send((t, Owned::of(m)));
        })?;
        if over {
            return Ok(());
        }
        waitset
            .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, LOSSLESS_TICK)
            .map_err(|e| ObserveError::Bus(format!("WaitSet: {e:?}")))?;
    }
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

#[cfg(test)]
mod tests {
    use bus::bus_schema::names::Topic;
    use bus::bus_schema::{FinalReport, PseudoTargetDiscovery, Register, RobotState};
    use bus::{BusConfig, CoordinatorBus, Outbox, leftover_files, unique_run_id};

    use super::*;

    /// A robot-like process on a thread of its own: joins run `cfg`, sends a registration,
    /// waits for `go`, then sends two discoveries and a report (each notified, as the robots
    /// do) and leaves at once.
    fn visiting_robot(cfg: &BusConfig, go: mpsc::Receiver<()>) -> JoinHandle<()> {
        let cfg = cfg.clone();
        std::thread::spawn(move || {
            let node = cfg.create_node("visitor").expect("node");
            let reg = Outbox::<Register>::open(&node, &cfg).expect("register outbox");
            let disc = Outbox::<PseudoTargetDiscovery>::open(&node, &cfg).expect("outbox");
            let report = Outbox::<FinalReport>::open(&node, &cfg).expect("report outbox");
            reg.send_with(|m| m.robot_id = 0).expect("send");
            reg.notify().expect("notify");
            go.recv_timeout(Duration::from_secs(20)).expect("go");
            for cell_x in [3, 4] {
                disc.send_with(|m| m.cell_x = cell_x).expect("send");
                disc.notify().expect("notify");
            }
            report.send_with(|m| m.robot_id = 0).expect("send");
            report.notify().expect("notify");
        })
    }

    fn topics_of(msgs: &[(u64, Owned)]) -> Vec<Topic> {
        msgs.iter().map(|(_, m)| m.as_msg().topic()).collect()
    }

    fn register(robot_id: u32) -> Register {
        Register {
            robot_id,
            ..Register::default()
        }
    }

    #[test]
    fn a_recording_reader_lowers_itself_once_every_robot_registered_or_at_the_deadline() {
        let t0 = Instant::now();
        let mut all = LowerOnceConnected::new(true, 2, t0 + Duration::from_secs(5));
        assert!(!all.due(t0), "no robot registered yet");
        all.saw(Msg::Register(&register(1)));
        all.saw(Msg::Register(&register(1)));
        assert!(!all.due(t0), "a robot registering twice counts once");
        // a robot id the fleet does not have counts for nothing
        all.saw(Msg::Register(&register(7)));
        assert!(!all.due(t0));
        all.saw(Msg::Register(&register(0)));
        assert!(all.due(t0), "every robot registered");
        assert!(!all.due(t0), "once only");
        let mut late = LowerOnceConnected::new(true, 2, t0 + Duration::from_secs(5));
        late.saw(Msg::Register(&register(0)));
        assert!(!late.due(t0 + Duration::from_secs(4)));
        assert!(
            late.due(t0 + Duration::from_secs(5)),
            "a robot that never came"
        );
        let mut live = LowerOnceConnected::new(false, 0, t0);
        assert!(
            !live.due(t0 + Duration::from_secs(9)),
            "the live view keeps its priority"
        );
    }

    #[test]
    fn a_connected_latest_wins_reader_keeps_the_last_sample_of_a_publisher_that_left() {
        let cfg = BusConfig::new(unique_run_id("obs-connected"), 1).unwrap();
        let coordinator = CoordinatorBus::create(&cfg).expect("the run's services");
        let connected = Observer::open(&cfg.run_id, Topics::LatestWins).expect("joins");
        let unconnected = Observer::open(&cfg.run_id, Topics::LatestWins).expect("joins");
        let (opened_tx, opened) = mpsc::channel();
        let (go, wait) = mpsc::channel::<()>();
        let c = cfg.clone();
        let robot = std::thread::spawn(move || {
            let node = c.create_node("visitor").expect("node");
            let state = Outbox::<RobotState>::open(&node, &c).expect("state outbox");
            opened_tx.send(()).unwrap();
            wait.recv_timeout(Duration::from_secs(20)).expect("go");
            for episode in [1, 2] {
                state.send_with(|m| m.episode = episode).expect("send");
            }
        });
        opened
            .recv_timeout(Duration::from_secs(20))
            .expect("opened");
        // what `LowerOnceConnected` makes the watch thread do before it goes idle
        connected.connect_all().unwrap();
        go.send(()).unwrap();
        robot.join().expect("robot");
        let episodes = |o: &Observer| {
            let mut seen = Vec::new();
            o.poll(|_, m| {
                if let Msg::State(s) = m {
                    seen.push(s.episode);
                }
            })
            .unwrap();
            seen
        };
        assert_eq!(episodes(&connected).last(), Some(&2), "the latest sample");
        assert_eq!(episodes(&unconnected), Vec::<u32>::new());
        drop((connected, unconnected));
        coordinator.close().unwrap();
        assert!(leftover_files(&cfg.prefix()).is_empty());
    }

    #[test]
    fn the_lossless_reader_keeps_what_a_publisher_sent_before_it_left() {
        let cfg = BusConfig::new(unique_run_id("obs-lossless"), 1).unwrap();
        let coordinator = CoordinatorBus::create(&cfg).expect("the run's services");
        let reader = LosslessReader::start(&cfg.run_id, None).expect("joins");
        // an observer that does not read while the visitor is there: what an idle-class
        // reader on a saturated machine is
        let idle = Observer::open(&cfg.run_id, Topics::Lossless).expect("joins");
        let (go, wait) = mpsc::channel();
        let visitor = visiting_robot(&cfg, wait);
        // the reader wakes on the registration (as on a robot's, whose process then lives on
        // for the run); once it has read it, the visitor sends the rest and leaves at once
        let mut kept = Vec::new();
        let t0 = Instant::now();
        while kept.is_empty() {
            assert!(
                t0.elapsed() < Duration::from_secs(20),
                "no registration read"
            );
            reader.take(&mut |t, m| kept.push((t, Owned::of(m))));
            std::thread::sleep(Duration::from_millis(1));
        }
        go.send(()).unwrap();
        visitor.join().expect("visitor");
        // the visitor's node is gone: its publishers, and their data segments, with it
        let mut late = Vec::new();
        idle.poll(|t, m| late.push((t, Owned::of(m)))).unwrap();
        reader
            .finish(&mut |t, m| kept.push((t, Owned::of(m))))
            .unwrap();
        assert_eq!(
            topics_of(&kept),
            [
                Topic::Register,
                Topic::Discovery,
                Topic::Discovery,
                Topic::Report
            ],
            "the reader woke on each send and connected before the publisher left"
        );
        assert_eq!(
            topics_of(&late),
            [],
            "iceoryx2 drops an unconnected reader's samples of a publisher that left; if this \
             changes, the lossless reader may no longer be needed"
        );
        drop(idle);
        coordinator.close().unwrap();
        assert!(leftover_files(&cfg.prefix()).is_empty());
    }
}
