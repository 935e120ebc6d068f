//! Writing to stdout and stderr without panicking (`println!` panics on a closed or full
//! stdout, `eprintln!` on a full stderr).
//!
//! - stdout ([`out!`]): a closed pipe (EPIPE, e.g. `qfleet clean | head -2`) makes every later
//!   write a no-op and the command goes on to its end (a clean must not stop half-way because
//!   its reader left) and exits as it would have; any other error (ENOSPC on `> /dev/full`) is
//!   returned, and the command fails with exit code 1.
//! - stderr ([`warn`], or `report::log_line!` for a line with another prefix): messages for the
//!   user; if stderr cannot be written there is nowhere to say so, so errors are ignored.

use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result};

static STDOUT_CLOSED: AtomicBool = AtomicBool::new(false);

/// Writes formatted text to stdout (see the module doc for errors).
pub fn write_out(args: std::fmt::Arguments) -> Result<()> {
    if STDOUT_CLOSED.load(Ordering::Relaxed) {
        return Ok(());
    }
    let mut out = std::io::stdout().lock();
    match out.write_fmt(args).and_then(|()| out.flush()) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {
            STDOUT_CLOSED.store(true, Ordering::Relaxed);
            Ok(())
        }
        Err(e) => Err(e).context("writing to stdout"),
    }
}

/// `out!("…", args)`: `println!` that returns an error instead of panicking (use with `?`).
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::term::write_out(format_args!("{}\n", format_args!($($arg)*)))
    };
}
pub(crate) use out;

/// `qfleet: <msg>` on stderr; errors writing it are ignored.
pub fn warn(msg: &str) {
    report::log_line!("qfleet: {msg}");
}

#[cfg(test)]
mod tests {
    #[test]
    fn out_writes_without_panicking() {
        super::out!("term test {}", 1).unwrap();
    }
}
