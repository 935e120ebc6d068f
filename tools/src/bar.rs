//! The progress bar and notes of a long study (`replicate`, `eval`) on stderr: the CLI's
//! [`studies::Progress`].

use indicatif::{ProgressBar, ProgressStyle};

/// A bar named after its command (`replicate 40/300 runs …`), cleared when the runs are done.
pub struct Bar {
    name: &'static str,
    bar: Option<ProgressBar>,
}

impl Bar {
    /// A bar for command `name`, drawn once the study says how many runs it makes.
    pub fn new(name: &'static str) -> Self {
        Bar { name, bar: None }
    }
}

impl studies::Progress for Bar {
    fn start(&mut self, total: u64) {
        let bar = ProgressBar::new(total);
        bar.set_style(
            ProgressStyle::with_template(&format!(
                "{} {{bar:40}} {{pos}}/{{len}} runs  {{elapsed_precise}} (eta {{eta}})",
                self.name
            ))
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        self.bar = Some(bar);
    }

    fn advance(&mut self) {
        if let Some(b) = &self.bar {
            b.inc(1);
        }
    }

    fn finish(&mut self) {
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
    }

    fn note(&mut self, line: &str) {
        report::log_line!("{line}");
    }
}
