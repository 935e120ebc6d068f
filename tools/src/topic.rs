//! `qfleet topic list|echo|hz --run-id ID [TOPIC]`: look at a live run from outside — which
//! topics it has, every message as a JSON line, message rates. The reader joins only once the
//! run's services exist and only subscribes (see `observe::attach`).

use std::io::Write;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result, anyhow, bail};
use clap::{Args, Subcommand};
use observe::attach::{Observer, Topics, leave, run_services_exist, topic_list};
use observe::decode::topic_named;
use observe::follow::{Follow, follow};

use bus_schema::names::Topic;

/// Options of `qfleet topic`.
#[derive(Debug, Args)]
pub struct TopicCmd {
    #[command(subcommand)]
    action: TopicAction,
}

/// What `qfleet topic` does.
#[derive(Debug, Subcommand)]
enum TopicAction {
    /// The run's topics: service name, type, delivery, and whether it exists now.
    List(Target),
    /// Print every message (of TOPIC, or of all topics) as one JSON line, until the run ends.
    Echo(Target),
    /// Print message rates per topic every second, until the run ends.
    Hz(Target),
}

#[derive(Debug, Args)]
struct Target {
    /// The run to look at (`qfleet run --run-id ID`).
    #[arg(long)]
    run_id: String,
    /// One topic, by path (`robot/state`) or service name; all topics if omitted.
    topic: Option<String>,
    /// Seconds to wait for the run to appear.
    #[arg(long, default_value_t = 30.0)]
    wait: f64,
    /// Stop after this many messages (echo) or reports (hz); 0 = until the run ends.
    #[arg(long, default_value_t = 0)]
    count: u64,
    /// Print JSON (list, hz); echo always prints JSON lines.
    #[arg(long)]
    json: bool,
}

impl Target {
    fn topic(&self) -> Result<Option<Topic>> {
        match &self.topic {
            None => Ok(None),
            Some(t) => topic_named(t).map(Some).map_err(|e| anyhow!(e)),
        }
    }

    fn wait(&self) -> Result<Duration> {
        qfleet_args::seconds("--wait", self.wait).map_err(|e| anyhow!(e))
    }
}

fn interrupted() -> Result<Arc<AtomicBool>> {
    let f = Arc::new(AtomicBool::new(false));
    let g = Arc::clone(&f);
    ctrlc::set_handler(move || g.store(true, Ordering::SeqCst))
        .context("installing the Ctrl-C handler")?;
    Ok(f)
}

/// A closed stdout (`| head`) ends the command cleanly.
fn out_ok(r: std::io::Result<()>) -> Result<bool> {
    match r {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(false),
        Err(e) => Err(e).context("writing to stdout"),
    }
}

impl TopicCmd {
    /// Runs the command.
    pub fn run(self) -> Result<()> {
        match self.action {
            TopicAction::List(t) => list(&t),
            TopicAction::Echo(t) => watch(&t, false),
            TopicAction::Hz(t) => watch(&t, true),
        }
    }
}

fn list(t: &Target) -> Result<()> {
    bus::validate_run_id(&t.run_id).context(launcher::Exit::BadInput)?;
    let only = t.topic().context(launcher::Exit::BadInput)?;
    let live = run_services_exist(&t.run_id)?;
    let text = topic_list(&t.run_id, only, live, t.json);
    out_ok(std::io::stdout().lock().write_all(text.as_bytes()))?;
    Ok(())
}

fn watch(t: &Target, hz: bool) -> Result<()> {
    bus::validate_run_id(&t.run_id).context(launcher::Exit::BadInput)?;
    let only = t.topic().context(launcher::Exit::BadInput)?;
    let wait = t.wait().context(launcher::Exit::BadInput)?;
    let stop = interrupted()?;
    let observer = Observer::attach(&t.run_id, Topics::All, wait, &|| {
        stop.load(Ordering::SeqCst)
    })
    .with_context(|| format!("joining run {}", t.run_id))?;
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    let mode = match hz {
        false => Follow::Echo,
        true => Follow::Hz { json: t.json },
    };
    let result = follow(&observer, only, mode, t.count, &stop, &mut out);
    drop(observer);
    // if the run ended while we were attached, its last files are ours to remove
    if let Err(e) = leave(&t.run_id) {
        crate::term::warn(&format!("warning: leaving run {}: {e}", t.run_id));
    }
    let printed = result?;
    if stop.load(Ordering::SeqCst) && printed == 0 && mode == Follow::Echo {
        bail!("interrupted before any message arrived");
    }
    Ok(())
}
