//! `qfleet replay FILE.mcap [--live] [--json] [--foxglove [ADDR:PORT]]`: a recording read back —
//! per-topic counts, rates and first/last times as a table or JSON, the live view driven by the
//! recording at its own pace (`--speed` to go faster or slower), or the recording served to
//! Foxglove over WebSocket at its own pace.

use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::{Context, Result, anyhow};
use clap::Args;
use observe::playback;
use observe::replay::{Messages, Recording};
use observe::watch::view_of_recording;

use report::TextTable;

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
          value_parser = observe::foxglove::parse_addr, conflicts_with_all = ["live", "json"])]
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
        let s = rec
            .summary()
            .with_context(|| format!("reading {}", self.file.display()))
            .context(launcher::Exit::BadInput)?;
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
        let span = s.span();
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
        if s.others > 0 {
            crate::term::warn(&format!(
                "{} message(s) naming a robot the run does not have were left out (another \
                 process's, not the run's)",
                s.others
            ));
        }
        Ok(())
    }

    /// `--foxglove`: the recording's messages into a Foxglove server at their recorded pace
    /// (over `--speed`), once a first client has connected.
    fn serve(&self, rec: &Recording, addr: SocketAddr) -> Result<()> {
        let vm = view_of_recording(rec).context(launcher::Exit::BadInput)?;
        // read as played, one message at a time (a recording is never held whole)
        let mut msgs = rec.messages().context(launcher::Exit::BadInput)?;
        let first = next_owned(&mut msgs)?;
        let server = crate::live::serve_at(addr)?;
        crate::catch_interrupts()?;
        let stopped = || crate::STOP.load(std::sync::atomic::Ordering::SeqCst);
        let note = |l: &str| crate::term::warn(l);
        playback::to_foxglove(
            rec, &vm, &mut msgs, first, &server, self.speed, &stopped, &note,
        )
        .context(launcher::Exit::BadInput)?;
        crate::live::stop_foxglove(Some(server));
        if stopped() {
            return Err(anyhow!("interrupted").context(launcher::Exit::Interrupted));
        }
        Ok(())
    }

    fn live(&self, rec: &Recording) -> Result<()> {
        let mut vm = view_of_recording(rec).context(launcher::Exit::BadInput)?;
        // read as played, one message at a time (a recording is never held whole); a damaged
        // record ends the view with its error
        let mut msgs = rec.messages().context(launcher::Exit::BadInput)?;
        let first = next_owned(&mut msgs)?;
        let src = format!("replay {}", self.file.display());
        playback::live(rec, &mut vm, msgs, first, self.speed, &src)?;
        Ok(())
    }
}

/// The next message of a recording, typed, with its log time; a damaged record is bad input.
fn next_owned(msgs: &mut Messages) -> Result<Option<(u64, observe::replay::Owned)>> {
    playback::next_owned(msgs).context(launcher::Exit::BadInput)
}
