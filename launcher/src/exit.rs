//! Exit codes of every qfleet command (the README's "Exit codes" table is this module).
//!
//! | code | meaning |
//! |---|---|
//! | 0 | the command did what it was asked |
//! | 1 | runtime failure (a process failed for good, a full disk, a write to stdout failed) |
//! | 2 | bad input (a CLI value, a file, a manifest, a run id in use, an `--out` not empty) |
//! | 130 | interrupted (Ctrl-C/SIGTERM), also when the stop that followed was not clean |
//!
//! A command marks an error with its class by adding an [`Exit`] as anyhow context; the binary
//! finds it with `downcast_ref::<Exit>()` (anyhow searches every context layer) and exits with
//! [`Exit::code`]; an unmarked error is a runtime failure.

/// The class of a command's outcome, and its exit code.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Exit {
    /// 0: success.
    Ok,
    /// 1: runtime failure.
    Failure,
    /// 2: bad input; nothing was started, or a child refused its input.
    BadInput,
    /// 130: interrupted by the user (SIGINT/SIGTERM).
    Interrupted,
}

impl Exit {
    /// The process exit code.
    pub fn code(self) -> i32 {
        match self {
            Exit::Ok => 0,
            Exit::Failure => 1,
            Exit::BadInput => 2,
            Exit::Interrupted => 130,
        }
    }

    /// The class of a child's exit code (qfleet processes use the same table; 3, a refused
    /// registration, is bad input too; any other non-zero code is a failure).
    pub fn of_child(code: i32) -> Exit {
        match code {
            0 => Exit::Ok,
            2 | 3 => Exit::BadInput,
            130 => Exit::Interrupted,
            _ => Exit::Failure,
        }
    }

    /// The more important of two outcomes: interrupted over bad input over failure over ok.
    pub fn worst(self, other: Exit) -> Exit {
        let rank = |e: Exit| match e {
            Exit::Ok => 0,
            Exit::Failure => 1,
            Exit::BadInput => 2,
            Exit::Interrupted => 3,
        };
        if rank(other) > rank(self) {
            other
        } else {
            self
        }
    }
}

impl std::fmt::Display for Exit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Exit::Ok => "ok",
            Exit::Failure => "failed",
            Exit::BadInput => "bad input",
            Exit::Interrupted => "interrupted",
        })
    }
}

#[cfg(test)]
mod tests {
    use super::Exit;

    #[test]
    fn codes_are_the_documented_ones() {
        assert_eq!(
            [Exit::Ok, Exit::Failure, Exit::BadInput, Exit::Interrupted].map(Exit::code),
            [0, 1, 2, 130]
        );
    }

    #[test]
    fn children_codes_map_onto_the_classes() {
        assert_eq!(Exit::of_child(0), Exit::Ok);
        assert_eq!(Exit::of_child(2), Exit::BadInput);
        assert_eq!(Exit::of_child(3), Exit::BadInput);
        assert_eq!(Exit::of_child(130), Exit::Interrupted);
        for c in [1, 4, 101, 255] {
            assert_eq!(Exit::of_child(c), Exit::Failure, "{c}");
        }
    }

    #[test]
    fn interrupted_wins_over_everything() {
        assert_eq!(Exit::Failure.worst(Exit::Interrupted), Exit::Interrupted);
        assert_eq!(Exit::Interrupted.worst(Exit::BadInput), Exit::Interrupted);
        assert_eq!(Exit::Ok.worst(Exit::Failure), Exit::Failure);
        assert_eq!(Exit::BadInput.worst(Exit::Failure), Exit::BadInput);
    }
}
