//! `qfleet replay FILE.mcap [--live] [--json]`: a recording read back — per-topic counts,
//! rates and first/last times as a table or JSON, or the live view driven by the recording at
//! its own pace (`--speed` to go faster or slower).

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
    /// Playback speed of `--live` (2 = twice as fast as recorded).
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
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
