//! # observe — watching and recording a qfleet run from outside
//!
//! An outside reader of a run: it attaches once the run's services exist
//! ([`attach::Observer`]), decodes every topic to JSON with a JSON schema per type
//! ([`decode`]), counts messages and rates ([`stats`]; `qfleet topic echo|hz` is [`follow`]), records everything into an MCAP file
//! that Foxglove opens ([`record`]), reads recordings back in bounded memory ([`replay`] over
//! [`walk`]; one whose recorder was killed up to where it stopped; [`playback`] at its recorded pace), and keeps an IO-free model of the run ([`view::ViewModel`])
//! that the terminal live view ([`tui`]) draws. [`scene`] turns a run into Foxglove's
//! well-known schemas (map, robots, paths, markers), which recordings carry and a Foxglove
//! WebSocket server ([`foxglove`]) serves live. [`watch`] ties them together for `qfleet
//! run/experiment --live/--record/--foxglove`.
//!
//! Not here: starting or stopping a run's processes (the launcher in `tools/`; the live view
//! only calls the stop callback it is given), publishing anything on a run's topics (an
//! observer only subscribes), the wire contract (`bus-schema`) and iceoryx2 plumbing (`bus`).

#![deny(missing_docs)]

pub mod attach;
pub mod decode;
pub mod follow;
pub mod foxglove;
pub mod members;
pub mod playback;
pub mod record;
pub mod replay;
pub mod scene;
pub mod stats;
pub mod tui;
pub mod view;
pub mod walk;
pub mod watch;

/// Why observing, recording or replaying failed.
#[derive(Debug, thiserror::Error)]
pub enum ObserveError {
    /// The bus refused (bad run id, node or port creation, a receive).
    #[error(transparent)]
    BusError(#[from] bus::BusError),
    /// Another iceoryx2 failure, with what was being done.
    #[error("iceoryx2: {0}")]
    Bus(String),
    /// The run's services did not appear in time.
    #[error("run {run_id} did not appear within {waited:?} (is it running? is the run id right?)")]
    Timeout {
        /// The run id waited for.
        run_id: String,
        /// How long.
        waited: std::time::Duration,
    },
    /// The run ended (or never started) before the observer could join.
    #[error("run {0} is not running")]
    NotRunning(String),
    /// An MCAP file that is not what a qfleet recording holds (too big, a message not JSON).
    #[error("mcap: {0}")]
    Mcap(String),
    /// The `mcap` crate could not read or write a file; its source says why (a full disk, a
    /// truncated file).
    #[error("mcap")]
    McapFile(#[from] mcap::McapError),
    /// A recording that cannot be read on: the byte offset of the record that broke, what
    /// was wrong, and how many messages were read before it.
    #[error(
        "the recording is damaged at byte {at} of {file_bytes}: {what} ({messages} message(s) read before it)"
    )]
    Damaged {
        /// Byte offset of the record that broke.
        at: u64,
        /// The file's size.
        file_bytes: u64,
        /// What was wrong with it.
        what: String,
        /// Messages read before it.
        messages: u64,
    },
    /// Reading a recording failed.
    #[error("reading the recording")]
    Read(#[source] std::io::Error),
    /// JSON encoding.
    #[error("json: {0}")]
    Json(#[from] serde_json::Error),
    /// File IO.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// Writing what a command follows to its stdout (a full disk; a closed pipe is no error).
    #[error("writing to stdout")]
    Stdout(#[source] std::io::Error),
    /// The terminal (raw mode, drawing, reading keys).
    #[error("terminal: {0}")]
    Terminal(#[source] std::io::Error),
    /// A map in a recording that cannot be read.
    #[error("the recording's map: {0}")]
    Map(String),
}
