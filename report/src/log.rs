//! A process's log lines. `eprintln!` panics when stderr cannot be written, and a qfleet
//! process's stderr is its log file in the run's out directory: on a full disk every process
//! of the run died of a panic (exit 101, an empty log) instead of finishing its run.
//! [`log_line!`](crate::log_line) writes the line or, when that fails, drops it: there is
//! then nowhere to say so.

/// `eprintln!` that never panics (see the [module doc](crate::log)).
#[macro_export]
macro_rules! log_line {
    ($($arg:tt)*) => {{
        use ::std::io::Write as _;
        let _ = ::std::writeln!(::std::io::stderr().lock(), $($arg)*);
    }};
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_log_line_is_written_without_panicking() {
        crate::log_line!("log test {}", 1);
    }
}
