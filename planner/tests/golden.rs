//! The paper's two learners stay exactly reproducible: episode by episode (steps, collisions,
//! outcome, greedy path length) on paper-10/20/30, seeds 1 and 2, N = 1000, as recorded in
//! `tests/golden/paper-learners.txt` from the code before the learner work of issue 9.
//!
//! Regenerate only on purpose (a deliberate change to the paper's learners) with
//! `QFLEET_BLESS=1 cargo test -p planner --test golden`, and say why in the commit.

use planner::map::builtin;
use planner::task::resolve_task;
use planner::{Learner, LearnerConfig, Outcome};
use std::fmt::Write as _;

const GOLDEN: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/golden/paper-learners.txt"
);

/// One line per run: `map learner seed` then one `steps:collisions:outcome:greedy` word per
/// episode (outcome g/p/c; greedy `-` when the greedy path loops).
fn record() -> String {
    let mut out = String::new();
    for map in ["paper-10", "paper-20", "paper-30"] {
        let task = resolve_task(&builtin(map).expect("built-in map"), None, None).expect("task");
        for (name, of) in [
            (
                "traditional",
                LearnerConfig::traditional as fn(u32, u64) -> LearnerConfig,
            ),
            ("improved-2026-11", LearnerConfig::paper_improved),
        ] {
            for seed in [1u64, 2] {
                let mut l = Learner::new(&task, of(1000, seed)).expect("valid config");
                let (records, _) = l.run(|_| {});
                write!(out, "{map} {name} {seed}").unwrap();
                for r in records {
                    let o = match r.outcome {
                        Outcome::Goal => 'g',
                        Outcome::Pseudo => 'p',
                        Outcome::Cap => 'c',
                    };
                    write!(out, " {}:{}:{o}:", r.steps, r.collisions).unwrap();
                    match r.greedy_path_len {
                        Some(g) => write!(out, "{g}").unwrap(),
                        None => out.push('-'),
                    }
                }
                out.push('\n');
            }
        }
    }
    out
}

#[test]
fn paper_learners_match_the_golden_file() {
    let now = record();
    if std::env::var_os("QFLEET_BLESS").is_some() {
        std::fs::write(GOLDEN, &now).expect("write golden file");
        eprintln!("blessed {GOLDEN}");
        return;
    }
    let golden = std::fs::read_to_string(GOLDEN).expect("golden file present");
    assert_eq!(golden.lines().count(), 12, "12 runs recorded");
    for (g, n) in golden.lines().zip(now.lines()) {
        let head: String = g.split(' ').take(3).collect::<Vec<_>>().join(" ");
        if g != n {
            let ep = g
                .split(' ')
                .skip(3)
                .zip(n.split(' ').skip(3))
                .position(|(a, b)| a != b);
            panic!("{head}: first difference at episode {ep:?}");
        }
    }
    assert_eq!(golden, now);
}
