//! `qfleet replicate`: the paper's Table 1 and learning-curve figures, regenerated
//! ([`studies::replicate`]).

use anyhow::Result;
use clap::Args;
use std::path::PathBuf;
use studies::replicate::{ReplicateOptions, replicate};

use crate::term::{out, write_out};

/// Options of `qfleet replicate`.
#[derive(Debug, Args)]
pub struct ReplicateCmd {
    /// Seeds per map and learner.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    seeds: u32,
    /// Episodes per run (N).
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(1..))]
    episodes: u32,
    /// Also run every named reading of the paper's ambiguous parts (the ablation table).
    #[arg(long)]
    ablation: bool,
    /// Maps to run (comma-separated built-in names or map files).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "paper-10,paper-20,paper-30"
    )]
    maps: Vec<String>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Directory for results.json, table.md and the SVG figures.
    #[arg(long, default_value = "results/replicate")]
    out: PathBuf,
    /// Print the results as JSON on stdout instead of the table.
    #[arg(long)]
    json: bool,
}

impl ReplicateCmd {
    /// Runs the command.
    pub fn run(self) -> Result<()> {
        let opts = ReplicateOptions {
            seeds: self.seeds,
            episodes: self.episodes,
            ablation: self.ablation,
            maps: self.maps,
            threads: self.threads,
            out: self.out,
        };
        let done = replicate(&opts, &mut crate::bar::Bar::new("replicate"))
            .map_err(|e| crate::classify(e, |e| e.is_bad_input()))?;
        if self.json {
            out!("{}", done.json)?;
        } else {
            write_out(format_args!("{}", done.table))?;
            out!(
                "\nwrote {}/{{table.md,results.json,steps-*.svg,path-*.svg}}",
                opts.out.display()
            )?;
        }
        Ok(())
    }
}
