//! `qfleet replay FILE.mcap [--live] [--json] [--foxglove [ADDR:PORT]]`: a recording read back —
//! per-topic counts, rates and first/last times as a table or JSON, the live view driven by the
//! recording at its own pace (`--speed` to go faster or slower), or the recording served to
//! Foxglove over WebSocket at its own pace.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow};
use clap::Args;
use observe::replay::{Recording, from_json};
use observe::tui::{self, Feed};
use observe::watch::view_of_recording;

use crate::table::TextTable;

/// Options of `qfleet replay`.
#[derive(Debug, Args)]
pub struct ReplayCmd {
    /// A recording made with `qfleet run … --record FILE.mcap`.
    file: PathBuf,
    /// Show the recording in the live view instead of the summary.
    #[arg(long)]
    live: bool,
    /// Print the summary as JSON.
    #[arg(long, conflicts_with = "live")]
    json: bool,
    /// Playback speed of `--live` and `--foxglove` (2 = twice as fast as recorded).
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    /// Serve the recording to Foxglove (WebSocket, `foxglove.websocket.v1`) on ADDR:PORT at
    /// its own pace [default: 127.0.0.1:8765]: plays once a client has connected, then exits.
    #[arg(long, value_name = "ADDR:PORT", num_args = 0..=1,
          default_missing_value = observe::foxglove::DEFAULT_ADDR,
          value_parser = crate::live::parse_addr, conflicts_with_all = ["live", "json"])]
    foxglove: Option<SocketAddr>,
}

impl ReplayCmd {
    /// Runs the command.
    pub fn run(self) -> Result<()> {
        if !(self.speed.is_finite() && self.speed > 0.0) {
            return Err(
                anyhow!("--speed must be a positive number, got {}", self.speed)
                    .context(launcher::Exit::BadInput),
            );
        }
        // a file that is missing or not a qfleet recording is bad input (exit code 2)
        let rec = Recording::open(&self.file)
            .with_context(|| format!("reading {}", self.file.display()))
            .context(launcher::Exit::BadInput)?;
        if let Some(c) = rec.cut_short {
            crate::term::warn(&format!(
                "warning: {} was not finished (its recorder was killed or its disk filled): read \
                 the messages in its first {} of {} bytes, the rest is lost",
                self.file.display(),
                c.read_bytes,
                c.file_bytes
            ));
        }
        if self.live {
            return self.live(&rec);
        }
        if let Some(addr) = self.foxglove {
            return self.serve(&rec, addr);
        }
        // a recording whose records or messages do not decode is bad input too
        let s = rec.summary().context(launcher::Exit::BadInput)?;
        if let (Some(c), 0) = (rec.cut_short, s.messages) {
            // damaged before its first message: nothing to replay is an error, not "0 messages"
            return Err(anyhow::anyhow!(
                "{} is damaged at byte offset {} of {}: no message before that point",
                self.file.display(),
                c.read_bytes,
                c.file_bytes
            ))
            .context(launcher::Exit::BadInput);
        }
        if self.json {
            crate::term::out!("{}", serde_json::to_string(&s)?)?;
            return Ok(());
        }
        // text from the file is escaped; one message (or none) spans no time worth printing
        let span = match s.messages {
            0 => "no messages".to_string(),
            1 => "1 message".to_string(),
            n => format!("{n} messages over {:.3} s", s.duration_s),
        };
        crate::term::out!(
            "recording {}: run {} on {}, {span}",
            self.file.display(),
            report::escape(&s.run_id),
            report::escape(&s.map),
        )?;
        let mut t = TextTable::new(&["topic", ">messages", ">first s", ">last s", ">rate /s"]);
        let f = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
        for x in &s.topics {
            t.row(vec![
                x.topic.clone(),
                x.count.to_string(),
                f(x.first_s),
                f(x.last_s),
                format!("{:.1}", x.rate_per_s),
            ]);
        }
        crate::term::write_out(format_args!("{}", t.render("  ")))?;
        Ok(())
    }

    /// `--foxglove`: the recording's messages into a Foxglove server at their recorded pace
    /// (over `--speed`), once a first client has connected.
    fn serve(&self, rec: &Recording, addr: SocketAddr) -> Result<()> {
        let vm = view_of_recording(rec).context(launcher::Exit::BadInput)?;
        let mut msgs = Vec::new();
        rec.for_each(|t, topic, v| {
            msgs.push((t, from_json(topic, v)));
            Ok(())
        })
        .context(launcher::Exit::BadInput)?;
        let server = crate::live::serve_at(addr)?;
        crate::catch_interrupts()?;
        let t0 = msgs.first().map_or_else(observe::record::wall_ns, |m| m.0);
        let cell = |k: &str| rec.cell(k).map(|(x, y)| planner::grid::Cell::new(x, y));
        let start = cell("start").unwrap_or(planner::grid::Cell::new(0, 0));
        server.begin_run(
            observe::foxglove::RunStart {
                run_id: rec.meta.get("run_id").cloned().unwrap_or_default(),
                map_name: vm.map_name.clone(),
                grid: vm.grid.clone(),
                start,
                goal: cell("goal").unwrap_or(start),
            },
            t0,
        );
        crate::term::warn("foxglove: playing once a client connects (Ctrl-C stops)");
        let stopped = || crate::STOP.load(std::sync::atomic::Ordering::SeqCst);
        while server.clients() == 0 && !stopped() {
            std::thread::sleep(Duration::from_millis(50));
        }
        // the client subscribes after it read the advertisement
        std::thread::sleep(Duration::from_millis(500));
        let begin = Instant::now();
        for (t, m) in msgs {
            if stopped() {
                break;
            }
            let due = Duration::from_secs_f64(t.saturating_sub(t0) as f64 / 1e9 / self.speed);
            if let Some(wait) = due.checked_sub(begin.elapsed()) {
                std::thread::sleep(wait);
            }
            server.offer_wait(t, rec.mono_of(t), m);
        }
        crate::live::stop_foxglove(Some(server));
        if stopped() {
            return Err(anyhow!("interrupted").context(launcher::Exit::Interrupted));
        }
        Ok(())
    }

    fn live(&self, rec: &Recording) -> Result<()> {
        let mut vm = view_of_recording(rec).context(launcher::Exit::BadInput)?;
        // decode everything first (typed, with receive times), then play it at its pace
        let mut msgs = Vec::new();
        rec.for_each(|t, topic, v| {
            msgs.push((rec.mono_of(t), from_json(topic, v)));
            Ok(())
        })
        .context(launcher::Exit::BadInput)?;
        let t0 = msgs.first().map_or(0, |m| m.0);
        let start = Instant::now();
        let speed = self.speed;
        let mut next = 0;
        let feed = |vm: &mut observe::view::ViewModel| -> Result<Feed, observe::ObserveError> {
            let played = (start.elapsed().as_secs_f64() * speed * 1e9) as u64;
            while next < msgs.len() && msgs[next].0.saturating_sub(t0) <= played {
                let (t, m) = &msgs[next];
                vm.apply(*t, m.as_msg());
                next += 1;
            }
            if next == msgs.len() {
                return Ok(Feed::Ended);
            }
            std::thread::sleep(Duration::from_millis(2));
            Ok(Feed::More)
        };
        let src = format!("replay {}", self.file.display());
        tui::run(&mut vm, &src, feed, &|| {}, true, true)?;
        Ok(())
    }
}
