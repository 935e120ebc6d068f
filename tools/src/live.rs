//! The launcher side of `--live`, `--record FILE.mcap`, `--pace` and `--foxglove` (`qfleet
//! run`, `qfleet experiment`: one [`WatchArgs`] flattened into both): start an
//! `observe::watch` thread before the run's processes, finish it after they exited and before
//! the run's files are removed. Everything else lives in the `observe` crate.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result};
use clap::Args;
use observe::foxglove::Server;
use observe::watch::{Watch, WatchOptions, run_info, start as start_watch};
use planner::task::Task;

/// How a run is watched: the options `qfleet run` and `qfleet experiment` share.
#[derive(Debug, Clone, Args)]
pub struct WatchArgs {
    /// Show the live terminal view (`q` stops the run gracefully, `space` pauses the view).
    #[arg(long)]
    pub live: bool,
    /// Record every message of every topic into this MCAP file, with the map, robots and paths
    /// in Foxglove's schemas (an experiment with several seeds writes `FILE.seed-S.mcap`).
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
    /// Slow every robot to this many environment steps per second (1 to 10 000 000), so that
    /// a person can follow them with `--live` or `--foxglove`; a paced robot also shows its
    /// cell at every pause.
    #[arg(long, value_name = "STEPS_PER_S", value_parser = qfleet_args::parse_pace)]
    pub pace: Option<f64>,
    /// Serve the run to Foxglove (WebSocket, `foxglove.websocket.v1`) on ADDR:PORT while it
    /// goes on [default: 127.0.0.1:8765]; an address other than loopback lets any machine
    /// that reaches it watch (no TLS, no authentication).
    #[arg(long, value_name = "ADDR:PORT", num_args = 0..=1,
          default_missing_value = observe::foxglove::DEFAULT_ADDR, value_parser = observe::foxglove::parse_addr)]
    pub foxglove: Option<SocketAddr>,
}

impl WatchArgs {
    /// Starts the Foxglove server if `--foxglove` asked for one: a port in use or an address
    /// not of this host is bad input (exit 2), before anything of the run starts. Says where
    /// it listens, and warns when that is not loopback.
    pub fn serve(&self) -> Result<Option<Arc<Server>>> {
        let Some(addr) = self.foxglove else {
            return Ok(None);
        };
        serve_at(addr).map(Some)
    }
}

/// Binds a Foxglove server on `addr` (see [`WatchArgs::serve`]).
pub fn serve_at(addr: SocketAddr) -> Result<Arc<Server>> {
    let server = Server::bind(addr)
        .context("--foxglove")
        .context(launcher::Exit::BadInput)?;
    let at = server.local_addr();
    if !observe::foxglove::is_loopback(&at) {
        crate::term::warn(&format!(
            "warning: --foxglove {at} is not a loopback address: anyone who can reach this \
             machine on that port can watch the run (no TLS, no authentication)"
        ));
    }
    crate::term::warn(&format!(
        "foxglove: serving on ws://{at} (Foxglove: Open connection, Foxglove WebSocket)"
    ));
    Ok(server)
}

/// Stops a Foxglove server and says what it did.
pub fn stop_foxglove(server: Option<Arc<Server>>) {
    let Some(s) = server else {
        return;
    };
    crate::term::warn(&s.shutdown().to_string());
}

/// A watch thread, if `--live`, `--record` or `--foxglove` asked for one.
pub struct Hook {
    watch: Option<Watch>,
    record: Option<PathBuf>,
}

/// Starts watching run `run_id` on `task` as `watch` asks (recording into `record`, serving
/// on `foxglove`); `config` goes into the recording's metadata; `on_quit` is the launcher's
/// graceful stop (what Ctrl-C does). A recording file that cannot be created is bad input:
/// nothing of the run has started yet.
pub fn start(
    run_id: &str,
    task: &Task,
    config: Vec<(String, String)>,
    watch: &WatchArgs,
    record: Option<PathBuf>,
    foxglove: Option<Arc<Server>>,
    on_quit: Box<dyn Fn() + Send>,
) -> Result<Hook> {
    // the run's own processes only: a stray process in the prefix is counted, not drawn
    let own_fleet = config
        .iter()
        .find(|(k, _)| k == "robots")
        .and_then(|(_, v)| v.parse().ok());
    let opts = WatchOptions {
        live: watch.live,
        record: record.clone(),
        foxglove,
        own_fleet,
    };
    let watch = match opts.any() {
        true => Some(
            start_watch(run_id, task, run_info(run_id, task, config), opts, on_quit)
                .context("starting the recording")
                .context(launcher::Exit::BadInput)?,
        ),
        false => None,
    };
    Ok(Hook { watch, record })
}

impl Hook {
    /// Waits (up to `timeout_s` seconds, the run's start-up budget; 30 s if that is not a
    /// valid duration) until the watch thread has joined the run, so a recording or the live
    /// view misses nothing the robots send; the launcher calls it once the coordinator runs and
    /// before it starts the robots ([`launcher::Fleet::before_robots`]). A watch that could not
    /// join in time is a warning: the run goes on unobserved so far.
    pub fn wait_joined(&self, timeout_s: f64) {
        let timeout = std::time::Duration::try_from_secs_f64(timeout_s)
            .unwrap_or(std::time::Duration::from_secs(30));
        if let Some(w) = &self.watch
            && !w.wait_joined(timeout)
        {
            crate::term::warn(&format!(
                "warning: the live view / recorder did not join the run within {} s; it may miss its first messages",
                timeout.as_secs()
            ));
        }
    }
}

/// Ends the watch: returns whether the user pressed `q` in the live view, and says on stderr
/// where the recording went.
pub fn finish(hook: Hook) -> Result<bool> {
    let Some(w) = hook.watch else {
        return Ok(false);
    };
    let r = match &hook.record {
        Some(p) => w
            .finish()
            .with_context(|| format!("watching the run (recording to {})", p.display()))?,
        None => w.finish().context("watching the run")?,
    };
    if let Some(p) = &hook.record {
        crate::term::warn(&format!(
            "recorded {} messages to {}",
            r.recorded,
            p.display()
        ));
    }
    if let Some(w) = r.others_warning() {
        crate::term::warn(&w);
    }
    Ok(r.quit)
}
