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

/// An error and its causes (`causes`, outermost first) as the one line a command prints: each
/// cause once (library errors often name their cause in their own message too, and `{:#}`
/// would then print it twice), and no [`Exit`] class marker (context that only sets the code).
pub fn one_line<I: IntoIterator<Item = String>>(causes: I) -> String {
    let markers = [Exit::BadInput, Exit::Interrupted, Exit::Failure].map(|e| e.to_string());
    let mut out = String::new();
    for msg in causes {
        if out.contains(&msg) || markers.contains(&msg) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&msg);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::{Exit, one_line};

    #[test]
    fn each_cause_is_printed_once_and_no_class_marker() {
        let chain = [
            "loading the task",
            "reading map.txt: disk on fire",
            "disk on fire",
        ];
        assert_eq!(
            one_line(chain.map(String::from)),
            "loading the task: reading map.txt: disk on fire"
        );
        let chain = ["checking the command line", "bad input", "--robots 0"];
        assert_eq!(
            one_line(chain.map(String::from)),
            "checking the command line: --robots 0"
        );
    }

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
