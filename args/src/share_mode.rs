//! What robots share with the fleet: the one `ShareMode` of qfleet, read from the command line
//! (`--share`, `--sharing`), from manifests (`sharing = "both"`) and written in results
//! (`"share": "both"`), always as the same four words.

use serde::{Deserialize, Serialize};

/// Whether and what a robot shares with the fleet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, clap::ValueEnum, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ShareMode {
    /// Learn alone: no hints sent or applied (states, discoveries and the report still flow).
    None,
    /// Take other robots' relayed pseudo-target discoveries as own pseudo targets; no hints.
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

    /// Whether relayed discoveries of other robots become pseudo targets of this one.
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

impl std::fmt::Display for ShareMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_cli())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::ValueEnum;

    #[test]
    fn cli_manifest_and_json_use_the_same_four_words() {
        for m in ShareMode::ALL {
            let word = m.as_cli();
            assert_eq!(ShareMode::parse(word), Some(m));
            assert_eq!(m.to_string(), word);
            assert_eq!(ShareMode::from_str(word, false), Ok(m));
            assert_eq!(serde_json::to_string(&m).unwrap(), format!("\"{word}\""));
        }
        assert_eq!(ShareMode::parse("Hints"), None);
        assert!(ShareMode::Both.hints() && ShareMode::Both.discoveries());
        assert!(!ShareMode::None.hints() && !ShareMode::Hints.discoveries());
    }
}
