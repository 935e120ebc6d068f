//! The process contract of qfleet: what the launcher, `qfleet`, `fleetbench` and the bridge may
//! ask of the two process binaries, and what they answer.
//!
//! - [`CoordArgs`] and [`AgentArgs`]: every option `qfleet-coordinator` and `robot-agent`
//!   accept, as the very structs their `main` parses, each with one [`CoordArgs::to_args`] /
//!   [`CoordArgs::try_parse_args`] pair (round-trip property-tested). A process command line is
//!   built only from these; a new option is one field here plus its use.
//! - [`share`]: the sharing options and the rules that fit each learner (`--apply`, `--merge`).
//! - [`plan`]: the experiment plan (`plan.json`) the coordinator runs with `--plan`.
//! - [`lines`]: the line protocol between the coordinator and its launcher (stdout lines, the
//!   `robot-<id>.exited` file).
//!
//! Nothing here does IO beyond reading a plan file; the types are the contract, the processes
//! implement it.

pub mod coordinator;
pub mod lines;
pub mod plan;
pub mod robot;
pub mod share;

pub use coordinator::{BRIDGED_SPIN_US, CoordArgs, DEFAULT_SPIN_US, spin_us_for};
pub use robot::AgentArgs;
pub use share::{ApplyRule, Resolved, Rules, ShareArgs, ShareOptionError};

use std::ffi::OsString;

/// Command-line words being built: `--name value` pairs and flags, in order.
#[derive(Debug, Default)]
pub(crate) struct Words(Vec<OsString>);

impl Words {
    /// `--name value`.
    pub(crate) fn opt(&mut self, name: &str, value: impl Into<OsString>) -> &mut Self {
        self.0.push(name.into());
        self.0.push(value.into());
        self
    }

    /// `--name path`, a path that begins with `-` written as `./-…` (the same file) so that
    /// it is not read as an option.
    pub(crate) fn path(&mut self, name: &str, path: &std::path::Path) -> &mut Self {
        let mut word = OsString::new();
        if path.as_os_str().as_encoded_bytes().starts_with(b"-") {
            word.push("./");
        }
        word.push(path);
        self.opt(name, word)
    }

    /// `--name value` when there is a value.
    pub(crate) fn maybe<T: ToString>(&mut self, name: &str, value: Option<T>) -> &mut Self {
        if let Some(v) = value {
            self.opt(name, v.to_string());
        }
        self
    }

    /// `--name` when `on`.
    pub(crate) fn flag(&mut self, name: &str, on: bool) -> &mut Self {
        if on {
            self.0.push(name.into());
        }
        self
    }

    /// Words from a `to_cli` of the shared option groups.
    pub(crate) fn extend(&mut self, words: Vec<String>) -> &mut Self {
        self.0.extend(words.into_iter().map(OsString::from));
        self
    }

    pub(crate) fn done(&mut self) -> Vec<OsString> {
        std::mem::take(&mut self.0)
    }
}

/// Parses command-line words (without the program name) with `P`, the program name taken from
/// `P`'s command.
pub(crate) fn parse<P, I, T>(words: I) -> Result<P, clap::Error>
where
    P: clap::Parser,
    I: IntoIterator<Item = T>,
    T: Into<OsString> + Clone,
{
    let name = OsString::from(P::command().get_name());
    P::try_parse_from(std::iter::once(name).chain(words.into_iter().map(Into::into)))
}

/// The long option names a clap command accepts (`--run-id`, …), for the tests that keep
/// `to_args` complete.
#[cfg(test)]
pub(crate) fn long_options(cmd: &clap::Command) -> Vec<String> {
    cmd.get_arguments()
        .filter_map(|a| a.get_long().map(|l| format!("--{l}")))
        .collect()
}
