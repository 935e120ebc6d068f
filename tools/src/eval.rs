//! `qfleet eval`: learner configurations × the map suite × seeds, on every core
//! ([`studies::eval`]), with one Markdown table per family and size and a JSON file of every
//! run.

use anyhow::Result;
use clap::Args;
use planner::suite::{self, Family};
use std::path::PathBuf;
use studies::eval::{EvalOptions, Half, eval, named};

use crate::term::{out, write_out};

/// Which half of the suite to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SplitArg {
    /// The half defaults are chosen on.
    Tuning,
    /// The half figures are reported on.
    Heldout,
    /// Both halves.
    All,
}

/// Options of `qfleet eval`.
#[derive(Debug, Args)]
pub struct EvalCmd {
    /// Configurations to compare, by name (`--list` shows them all).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "traditional,improved,planning"
    )]
    configs: Vec<String>,
    /// Which half of the suite.
    #[arg(long, value_enum, default_value = "heldout")]
    split: SplitArg,
    /// Map sizes (square side) of the generated maps, 4 to 4096.
    #[arg(long, value_delimiter = ',', default_value = "10,20,30,32,64,128")]
    sizes: Vec<usize>,
    /// Families to run: random, rooms, maze, walls, movingai (default: all).
    #[arg(long, value_delimiter = ',')]
    families: Vec<Family>,
    /// Generated maps per family and size (both halves together).
    #[arg(long, default_value_t = suite::MAPS_PER_FAMILY as u32, value_parser = clap::value_parser!(u32).range(1..=1000))]
    maps: u32,
    /// Seed of the map generator.
    #[arg(long, default_value_t = suite::DEFAULT_SUITE_SEED)]
    suite_seed: u64,
    /// Learner seeds per map and configuration.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    seeds: u32,
    /// Episodes per run (N).
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(1..))]
    episodes: u32,
    /// Directory of MovingAI `.map`/`.scen` files to add to the suite (skipped, with a message,
    /// when absent).
    #[arg(long, default_value = "../shared/data/movingai")]
    movingai: PathBuf,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Directory for results.json and table.md.
    #[arg(long, default_value = "results/eval")]
    out: PathBuf,
    /// List the named configurations and exit.
    #[arg(long)]
    list: bool,
}

impl From<SplitArg> for Half {
    fn from(s: SplitArg) -> Half {
        match s {
            SplitArg::Tuning => Half::Tuning,
            SplitArg::Heldout => Half::Heldout,
            SplitArg::All => Half::All,
        }
    }
}

impl EvalCmd {
    /// Runs the command.
    pub fn run(self) -> Result<()> {
        if self.list {
            for c in &named() {
                out!(
                    "{:28} {}  [{}]",
                    c.name,
                    c.what,
                    (c.cfg)(self.episodes).policy_label()
                )?;
            }
            return Ok(());
        }
        let opts = EvalOptions {
            configs: self.configs,
            split: self.split.into(),
            sizes: self.sizes,
            families: self.families,
            maps: self.maps,
            suite_seed: self.suite_seed,
            seeds: self.seeds,
            episodes: self.episodes,
            movingai: self.movingai,
            threads: self.threads,
            out: self.out,
        };
        let done = eval(&opts, &mut crate::bar::Bar::new("eval"))
            .map_err(|e| crate::classify(e, |e| e.is_bad_input()))?;
        write_out(format_args!("{}", done.table))?;
        out!(
            "\nwrote {} and {}",
            done.table_md.display(),
            done.results_json.display()
        )?;
        Ok(())
    }
}
