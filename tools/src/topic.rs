//! `qfleet topic list|echo|hz --run-id ID [TOPIC]`: look at a live run from outside — which
//! topics it has, every message as a JSON line, message rates. The reader joins only once the
//! run's services exist and only subscribes (see `observe::attach`).

use std::io::Write;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use clap::{Args, Subcommand};
use observe::attach::{Observer, Topics, leave, run_services_exist};
use observe::decode::topic_by_name;
use observe::stats::{Rate, TopicCounts, topic_index};
use serde_json::json;

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
            Some(t) => topic_by_name(t).map(Some).ok_or_else(|| {
                let all: Vec<&str> = Topic::ALL.iter().map(|t| t.path()).collect();
                anyhow!("unknown topic {t:?}; the topics are {}", all.join(", "))
            }),
        }
    }

    fn wait(&self) -> Result<Duration> {
        Duration::try_from_secs_f64(self.wait)
            .map_err(|_| anyhow!("--wait must be a number of seconds >= 0, got {}", self.wait))
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
            TopicAction::Echo(t) => watch(&t, Mode::Echo),
            TopicAction::Hz(t) => watch(&t, Mode::Hz),
        }
    }
}

fn list(t: &Target) -> Result<()> {
    bus::validate_run_id(&t.run_id).context(launcher::Exit::BadInput)?;
    let only = t.topic().context(launcher::Exit::BadInput)?;
    let live = run_services_exist(&t.run_id)?;
    let mut out = std::io::stdout().lock();
    let topics: Vec<Topic> = Topic::ALL
        .into_iter()
        .filter(|x| only.is_none_or(|o| o == *x))
        .collect();
    if t.json {
        let v: Vec<_> = topics
            .iter()
            .map(|x| {
                json!({
                    "topic": x.service_name(&t.run_id), "type": x.type_name(),
                    "delivery": format!("{:?}", x.delivery()), "direction": format!("{:?}", x.direction()),
                    "payload_bytes": x.payload_size(), "live": live,
                })
            })
            .collect();
        out_ok(writeln!(out, "{}", serde_json::Value::Array(v)))?;
    } else {
        let mut tab = crate::table::TextTable::new(&["topic", "type", "delivery", ">bytes"]);
        for x in &topics {
            tab.row(vec![
                x.service_name(&t.run_id),
                x.type_name().to_string(),
                format!("{:?}", x.delivery()),
                x.payload_size().to_string(),
            ]);
        }
        let state = if live {
            "running"
        } else {
            "not running (no services)"
        };
        out_ok(write!(out, "run {}: {state}\n{}", t.run_id, tab.render("")))?;
    }
    Ok(())
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    Echo,
    Hz,
}

fn watch(t: &Target, mode: Mode) -> Result<()> {
    bus::validate_run_id(&t.run_id).context(launcher::Exit::BadInput)?;
    let only = t.topic().context(launcher::Exit::BadInput)?;
    let wait = t.wait().context(launcher::Exit::BadInput)?;
    let stop = interrupted()?;
    let observer = Observer::attach(&t.run_id, Topics::All, wait, &|| {
        stop.load(Ordering::SeqCst)
    })
    .with_context(|| format!("joining run {}", t.run_id))?;
    let result = watch_loop(&observer, t, only, mode, &stop);
    drop(observer);
    // if the run ended while we were attached, its last files are ours to remove
    if let Err(e) = leave(&t.run_id) {
        crate::term::warn(&format!("warning: leaving run {}: {e}", t.run_id));
    }
    result
}

fn watch_loop(
    observer: &Observer,
    t: &Target,
    only: Option<Topic>,
    mode: Mode,
    stop: &AtomicBool,
) -> Result<()> {
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    let mut counts = TopicCounts::default();
    let mut rates: Vec<Rate> = (0..Topic::ALL.len())
        .map(|_| Rate::new(1_000_000_000))
        .collect();
    let mut printed = 0u64;
    let mut open = true;
    let mut last_check = Instant::now();
    let mut last_hz = Instant::now();
    let mut line = Vec::with_capacity(8192);
    let mut err: Option<anyhow::Error> = None;
    let mut last_round = false;
    loop {
        let n = observer.poll(|recv_ns, m| {
            let topic = m.topic();
            if only.is_some_and(|o| o != topic) || !open || err.is_some() {
                return;
            }
            counts.add(topic, recv_ns);
            rates[topic_index(topic)].add(recv_ns, 1);
            if mode == Mode::Echo {
                line.clear();
                let v = json!({
                    "topic": topic.path(), "recv_ns": recv_ns, "msg": m.to_json(),
                });
                if let Err(e) = serde_json::to_writer(&mut line, &v) {
                    err = Some(e.into());
                    return;
                }
                line.push(b'\n');
                match out_ok(out.write_all(&line)) {
                    Ok(true) => {}
                    Ok(false) => open = false,
                    Err(e) => err = Some(e),
                }
                printed += 1;
                if t.count > 0 && printed >= t.count {
                    open = false;
                }
            }
        })?;
        if let Some(e) = err {
            return Err(e);
        }
        if n > 0 && mode == Mode::Echo && !out_ok(out.flush())? {
            open = false;
        }
        if !open || stop.load(Ordering::SeqCst) || last_round {
            break;
        }
        if mode == Mode::Hz && last_hz.elapsed() >= Duration::from_secs(1) {
            last_hz = Instant::now();
            let now = bus::monotonic_ns();
            let mut v = serde_json::Map::new();
            let mut text = String::new();
            for x in Topic::ALL
                .into_iter()
                .filter(|x| only.is_none_or(|o| o == *x))
            {
                let rate = rates[topic_index(x)].per_s(now);
                let total = counts.get(x).count;
                v.insert(x.path().into(), json!({"per_s": rate, "total": total}));
                text.push_str(&format!(
                    "{:18} {rate:>10.1} msg/s  {total:>9} total\n",
                    x.path()
                ));
            }
            let s = if t.json {
                serde_json::Value::Object(v).to_string() + "\n"
            } else {
                text + "\n"
            };
            if !out_ok(out.write_all(s.as_bytes()).and_then(|()| out.flush()))? {
                break;
            }
            printed += 1;
            if t.count > 0 && printed >= t.count {
                break;
            }
        }
        if last_check.elapsed() >= Duration::from_millis(200) {
            last_check = Instant::now();
            // the run is over: one more drain for what it sent last, then leave
            last_round = !observer.run_alive();
        }
        if n == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    let _ = out.flush();
    if stop.load(Ordering::SeqCst) && printed == 0 && mode == Mode::Echo {
        bail!("interrupted before any message arrived");
    }
    Ok(())
}
