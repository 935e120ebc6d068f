//! The words results and command lines share: every setting a result names (the wait strategy,
//! the merge rule, the share mode) is one lower-case word, the same in `result.json`, in
//! manifests and on the command line. The command line reads them through [`Word`]
//! (`qfleet_args::choice`), so this crate needs no command-line library.

use serde::{Deserialize, Serialize};

/// A setting written as one of a fixed set of words.
pub trait Word: Sized + Copy + PartialEq + 'static {
    /// Every value, in the order of the docs.
    const ALL: &'static [Self];

    /// Its word (`hybrid`, `max`, `both`, …).
    fn word(self) -> &'static str;

    /// One line on what it means, for `--help`.
    fn help(self) -> &'static str;

    /// The value a word names (exact, lower case).
    fn from_word(word: &str) -> Option<Self> {
        Self::ALL.iter().copied().find(|v| v.word() == word)
    }
}

/// `Display` as the word.
#[macro_export]
macro_rules! display_word {
    ($t:ty) => {
        impl std::fmt::Display for $t {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str($crate::Word::word(*self))
            }
        }
    };
}

/// Whether and what a robot shares with the fleet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ShareMode {
    /// Learn alone: no hints sent or applied (states, discoveries and the report still flow).
    None,
    /// Use other robots' relayed discoveries (the improved learner: as pseudo targets; the
    /// planning learner: as known returns of goal paths); no hints.
    Discoveries,
    /// Send Q-hint batches and apply the fleet's merged hints.
    Hints,
    /// Both: hints and relayed discoveries.
    Both,
}

impl ShareMode {
    /// Every mode, in the order of the docs.
    pub const ALL: [ShareMode; 4] = [
        ShareMode::None,
        ShareMode::Discoveries,
        ShareMode::Hints,
        ShareMode::Both,
    ];

    /// Whether Q hints are sent and merged hints applied.
    pub fn hints(self) -> bool {
        matches!(self, ShareMode::Hints | ShareMode::Both)
    }

    /// Whether relayed discoveries of other robots are used (pseudo targets of the improved
    /// learner, known returns of the planning learner).
    pub fn discoveries(self) -> bool {
        matches!(self, ShareMode::Discoveries | ShareMode::Both)
    }

    /// The word for it: the robot-agent's `--share` value, the manifest's and the result's.
    pub const fn as_cli(self) -> &'static str {
        match self {
            ShareMode::None => "none",
            ShareMode::Discoveries => "discoveries",
            ShareMode::Hints => "hints",
            ShareMode::Both => "both",
        }
    }

    /// The mode a word names (`none`, `discoveries`, `hints`, `both`).
    pub fn parse(s: &str) -> Option<ShareMode> {
        ShareMode::ALL.into_iter().find(|m| m.as_cli() == s)
    }
}

impl Word for ShareMode {
    const ALL: &'static [Self] = &ShareMode::ALL;

    fn word(self) -> &'static str {
        self.as_cli()
    }

    fn help(self) -> &'static str {
        match self {
            ShareMode::None => {
                "Learn alone: no hints sent or applied (states, discoveries and the report still flow)"
            }
            ShareMode::Discoveries => {
                "Use other robots' relayed discoveries (improved: as pseudo targets, planning: as known goal-path returns); no hints"
            }
            ShareMode::Hints => "Send Q-hint batches and apply the fleet's merged hints",
            ShareMode::Both => "Both: hints and relayed discoveries",
        }
    }
}

display_word!(ShareMode);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run::{MergeRule, WaitStrategy};

    #[test]
    fn cli_manifest_and_json_use_the_same_four_words() {
        for m in ShareMode::ALL {
            let word = m.as_cli();
            assert_eq!(ShareMode::parse(word), Some(m));
            assert_eq!(m.to_string(), word);
            assert_eq!(ShareMode::from_word(word), Some(m));
            assert_eq!(serde_json::to_string(&m).unwrap(), format!("\"{word}\""));
        }
        assert_eq!(ShareMode::parse("Hints"), None);
        assert!(ShareMode::Both.hints() && ShareMode::Both.discoveries());
        assert!(!ShareMode::None.hints() && !ShareMode::Hints.discoveries());
    }

    fn every_word_reads_back<T: Word + std::fmt::Display + std::fmt::Debug + Serialize>() {
        for &v in T::ALL {
            assert_eq!(T::from_word(v.word()), Some(v));
            assert_eq!(v.to_string(), v.word());
            assert_eq!(
                serde_json::to_string(&v).unwrap(),
                format!("\"{}\"", v.word())
            );
            assert!(!v.help().is_empty());
        }
    }

    #[test]
    fn results_and_command_lines_read_the_same_words() {
        every_word_reads_back::<WaitStrategy>();
        every_word_reads_back::<MergeRule>();
        every_word_reads_back::<ShareMode>();
        assert_eq!(MergeRule::from_word("Max"), None);
    }
}
