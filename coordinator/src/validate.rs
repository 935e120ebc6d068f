//! Field-by-field checks of every message a robot sends, before the coordinator uses it.
//!
//! Everything here is pure: a message and what the coordinator knows of the run in, a verdict
//! out. A message that fails is counted as `rejected` by the caller and never used; in
//! particular a [`FinalReport`] is trusted only when its schema version, goal, status, counts
//! and every float are plausible (issue 10 item 1: a forged report with NaN `avg_steps` once
//! made the whole result unreadable).

use bus::bus_schema::{
    FinalReport, HINT_BATCH_CAP, PseudoTargetDiscovery, QHint, QHintBatch, RobotState, RobotStatus,
    SCHEMA_VERSION,
};

/// The shape of the run the messages must fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shape {
    /// Map width in cells.
    pub width: u16,
    /// Map height in cells.
    pub height: u16,
    /// Goals of the run: goal ids are `0..goals` (1 for a plain run).
    pub goals: u32,
}

impl Shape {
    /// Cells of the map (the fleet tables' size).
    pub fn cells(&self) -> usize {
        usize::from(self.width) * usize::from(self.height)
    }
}

/// Why a message was rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Invalid {
    /// Goal id outside the run's goals, or not the goal the robot was assigned.
    #[error("goal id {got} (expected {expected})")]
    Goal {
        /// What the message said.
        got: u32,
        /// What the coordinator expected.
        expected: String,
    },
    /// A cell outside the map.
    #[error("cell outside the map")]
    Cell,
    /// An action outside 0..4.
    #[error("action {0} outside 0..4")]
    Action(u8),
    /// A NaN or infinite value, or a negative one where only non-negative ones make sense.
    #[error("{0} is not a finite, plausible number")]
    Value(&'static str),
    /// A hint batch's count above its capacity.
    #[error("count {0} above {HINT_BATCH_CAP}")]
    Count(u32),
    /// A report written by another schema version.
    #[error("schema v{0} != coordinator v{SCHEMA_VERSION}")]
    Schema(u32),
    /// A status byte that is not a status, or not one a report can carry.
    #[error("status {0} is not a final status")]
    Status(u8),
    /// A count or length that contradicts another field or the run.
    #[error("{0}")]
    Inconsistent(&'static str),
    /// Path lengths no honest robot on this task can report (see [`PathVerdict`]).
    #[error(transparent)]
    Forged(#[from] Forgery),
}

/// What a report's two path lengths say, judged against the coordinator's own BFS optimum of
/// the robot's task: forged, or one of three honest endings. Issue 36: a robot that stopped
/// before its greedy policy reached the goal reports `final_path_len` −1 (and a robot that
/// computes no optimum, `optimal_path_len` −1); both are honest, only a path *shorter* than
/// the optimum (no path beats BFS) or another optimum than the coordinator's is a forgery.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PathVerdict {
    /// `final_path_len` −1: no greedy path to the goal yet (it loops, or the robot stopped
    /// early); honest, and the result lists the robot in `without_path`.
    NoPathYet,
    /// A path exactly as long as the optimum.
    Optimal,
    /// A path `extra` moves longer than the optimum: honest, suboptimal.
    Longer {
        /// Moves beyond the optimum (≥ 1).
        extra: u32,
    },
    /// A path the coordinator cannot judge: it knows no optimum for this task.
    Unjudged,
    /// Lengths that cannot come from an honest robot on this task.
    Forged(Forgery),
}

/// Why a report's path lengths are a forgery (or garbage), see [`PathVerdict::Forged`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Forgery {
    /// A greedy path shorter than the BFS optimum: no path beats BFS.
    #[error(
        "final_path_len {got} against the BFS optimum {optimum} of the robot's task on this \
         map: no path is shorter"
    )]
    Shorter {
        /// The claimed path length.
        got: u32,
        /// The coordinator's optimum.
        optimum: u32,
    },
    /// An optimum other than the coordinator's (−1, "not computed", is honest).
    #[error(
        "optimal_path_len {got} against the BFS optimum {optimum} of the robot's task on this \
         map"
    )]
    OtherOptimum {
        /// The claimed optimum.
        got: i32,
        /// The coordinator's optimum.
        optimum: u32,
    },
    /// A length below −1, or above the map's cell count (a path that loops is reported as −1).
    #[error("{what} {got} is no path length on a map of {cells} cells")]
    NotALength {
        /// Which length (`final_path_len` or `optimal_path_len`).
        what: &'static str,
        /// The claimed length.
        got: i32,
        /// Cells of the map.
        cells: u64,
    },
}

impl PathVerdict {
    /// Judges a report's `final_path_len` and `optimal_path_len` (−1 = none / not computed)
    /// on a map of `cells` cells against the coordinator's BFS optimum of the robot's task
    /// (`None`: unknown, only the ranges are checked).
    pub fn judge(final_len: i32, claimed_optimum: i32, optimum: Option<u32>, cells: u64) -> Self {
        let length = |what: &'static str, got: i32| -> Result<Option<u32>, Forgery> {
            match got {
                -1 => Ok(None),
                v if v < -1 || v as u64 > cells => Err(Forgery::NotALength { what, got, cells }),
                v => Ok(Some(v as u32)),
            }
        };
        let (path, claimed) = match (
            length("final_path_len", final_len),
            length("optimal_path_len", claimed_optimum),
        ) {
            (Ok(p), Ok(c)) => (p, c),
            (Err(f), _) | (_, Err(f)) => return PathVerdict::Forged(f),
        };
        let Some(optimum) = optimum else {
            return match path {
                None => PathVerdict::NoPathYet,
                Some(_) => PathVerdict::Unjudged,
            };
        };
        if let Some(got) = claimed
            && got != optimum
        {
            return PathVerdict::Forged(Forgery::OtherOptimum {
                got: claimed_optimum,
                optimum,
            });
        }
        match path {
            None => PathVerdict::NoPathYet,
            Some(got) if got < optimum => PathVerdict::Forged(Forgery::Shorter { got, optimum }),
            Some(got) if got == optimum => PathVerdict::Optimal,
            Some(got) => PathVerdict::Longer {
                extra: got - optimum,
            },
        }
    }
}

fn goal(got: u32, shape: &Shape, assigned: Option<u32>) -> Result<(), Invalid> {
    let ok = match assigned {
        Some(g) => got == g,
        None => got < shape.goals,
    };
    if ok {
        Ok(())
    } else {
        Err(Invalid::Goal {
            got,
            expected: assigned.map_or(format!("0..{}", shape.goals), |g| g.to_string()),
        })
    }
}

/// A discovery: its goal, cell and value; returns the cell's row-major index (the one
/// discovery dedup key, with the goal id).
pub fn discovery(
    d: &PseudoTargetDiscovery,
    shape: &Shape,
    assigned: Option<u32>,
) -> Result<u32, Invalid> {
    goal(d.goal_id, shape, assigned)?;
    if d.cell_x >= shape.width || d.cell_y >= shape.height {
        return Err(Invalid::Cell);
    }
    if !d.value.is_finite() {
        return Err(Invalid::Value("value"));
    }
    Ok(u32::from(d.cell_y) * u32::from(shape.width) + u32::from(d.cell_x))
}

/// A hint batch's header: goal and count; returns the entries to look at.
pub fn hint_batch<'b>(
    b: &'b QHintBatch,
    shape: &Shape,
    assigned: Option<u32>,
) -> Result<&'b [QHint], Invalid> {
    goal(b.goal_id, shape, assigned)?;
    let n = b.count as usize;
    if n > HINT_BATCH_CAP {
        return Err(Invalid::Count(b.count));
    }
    Ok(&b.entries[..n])
}

/// One hint entry: cell, action, finite q (each entry of a batch is judged on its own).
#[inline]
pub fn hint(h: &QHint, cells: usize) -> Result<(), Invalid> {
    if h.cell as usize >= cells {
        return Err(Invalid::Cell);
    }
    if h.action >= 4 {
        return Err(Invalid::Action(h.action));
    }
    if !h.q.is_finite() {
        return Err(Invalid::Value("q"));
    }
    Ok(())
}

/// A state heartbeat: goal, cell and status byte.
pub fn state(s: &RobotState, shape: &Shape, assigned: Option<u32>) -> Result<(), Invalid> {
    goal(s.goal_id, shape, assigned)?;
    if s.cell_x >= shape.width || s.cell_y >= shape.height {
        return Err(Invalid::Cell);
    }
    RobotStatus::try_from(s.status).map_err(Invalid::Status)?;
    Ok(())
}

/// A final report the coordinator accepted: its status and what its path lengths say.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Accepted {
    /// `Finished` or `Failed`.
    pub status: RobotStatus,
    /// The path verdict: never [`PathVerdict::Forged`].
    pub path: PathVerdict,
}

/// A final report, fully: schema version, the goal the robot was assigned, a final status,
/// path lengths judged by [`PathVerdict::judge`] against the coordinator's BFS optimum of the
/// robot's task (`optimum`, when it knows one), episodes within what was asked
/// (`max_episodes`, 0 = unknown), finite non-negative `avg_steps`, acked ≤ sent, and a
/// latency summary that is ordered.
pub fn report(
    r: &FinalReport,
    shape: &Shape,
    assigned: Option<u32>,
    max_episodes: u32,
    optimum: Option<u32>,
) -> Result<Accepted, Invalid> {
    if r.schema_version != SCHEMA_VERSION {
        return Err(Invalid::Schema(r.schema_version));
    }
    goal(r.goal_id, shape, assigned)?;
    let status = match RobotStatus::try_from(r.status) {
        Ok(s @ (RobotStatus::Finished | RobotStatus::Failed)) => s,
        _ => return Err(Invalid::Status(r.status)),
    };
    if !(r.avg_steps.is_finite() && r.avg_steps >= 0.0) {
        return Err(Invalid::Value("avg_steps"));
    }
    let path = match PathVerdict::judge(
        r.final_path_len,
        r.optimal_path_len,
        optimum,
        shape.cells() as u64,
    ) {
        PathVerdict::Forged(f) => return Err(f.into()),
        v => v,
    };
    if r.first_optimal_episode < -1 {
        return Err(Invalid::Value("first_optimal_episode"));
    }
    if max_episodes > 0 && r.episodes > max_episodes {
        return Err(Invalid::Inconsistent(
            "more episodes than the robot was asked for",
        ));
    }
    if r.first_optimal_episode >= 0 && r.first_optimal_episode as u32 > r.episodes {
        return Err(Invalid::Inconsistent(
            "first optimal episode after the last episode",
        ));
    }
    if r.discoveries_acked > r.discoveries_sent {
        return Err(Invalid::Inconsistent("more discoveries acked than sent"));
    }
    let l = &r.merged_latency;
    if l.count > 0 && !(l.min_ns <= l.p50_ns && l.p50_ns <= l.p99_ns && l.p99_ns <= l.max_ns) {
        return Err(Invalid::Inconsistent("latency percentiles out of order"));
    }
    Ok(Accepted { status, path })
}

#[cfg(test)]
mod tests {
    use super::*;

    const SHAPE: Shape = Shape {
        width: 10,
        height: 8,
        goals: 2,
    };

    fn good_report() -> FinalReport {
        FinalReport {
            robot_id: 1,
            schema_version: SCHEMA_VERSION,
            goal_id: 1,
            episodes: 100,
            final_path_len: 12,
            optimal_path_len: 12,
            first_optimal_episode: 40,
            status: RobotStatus::Finished.as_u8(),
            avg_steps: 30.5,
            discoveries_sent: 3,
            discoveries_acked: 3,
            ..FinalReport::ZEROED
        }
    }

    #[test]
    fn a_plausible_report_is_accepted_with_its_status() {
        assert_eq!(
            report(&good_report(), &SHAPE, Some(1), 100, None),
            Ok(Accepted {
                status: RobotStatus::Finished,
                path: PathVerdict::Unjudged
            })
        );
        let failed = FinalReport {
            status: RobotStatus::Failed.as_u8(),
            final_path_len: -1,
            first_optimal_episode: -1,
            ..good_report()
        };
        assert_eq!(
            report(&failed, &SHAPE, Some(1), 0, None),
            Ok(Accepted {
                status: RobotStatus::Failed,
                path: PathVerdict::NoPathYet
            })
        );
    }

    #[test]
    fn the_forged_reports_of_issue_10_are_each_rejected() {
        let cases = [
            (
                FinalReport {
                    schema_version: 77,
                    ..good_report()
                },
                "schema",
            ),
            (
                FinalReport {
                    goal_id: 3,
                    ..good_report()
                },
                "goal",
            ),
            (
                FinalReport {
                    goal_id: 0,
                    ..good_report()
                },
                "goal",
            ), // not its assignment
            (
                FinalReport {
                    status: 250,
                    ..good_report()
                },
                "status",
            ),
            (
                FinalReport {
                    status: RobotStatus::Running.as_u8(),
                    ..good_report()
                },
                "status",
            ),
            (
                FinalReport {
                    avg_steps: f64::NAN,
                    ..good_report()
                },
                "avg_steps",
            ),
            (
                FinalReport {
                    avg_steps: f64::INFINITY,
                    ..good_report()
                },
                "avg_steps",
            ),
            (
                FinalReport {
                    avg_steps: -1.0,
                    ..good_report()
                },
                "avg_steps",
            ),
            (
                FinalReport {
                    final_path_len: -5,
                    ..good_report()
                },
                "final_path_len",
            ),
            (
                FinalReport {
                    optimal_path_len: 1_000,
                    ..good_report()
                },
                "optimal_path_len",
            ),
            (
                FinalReport {
                    episodes: 101,
                    ..good_report()
                },
                "more episodes",
            ),
            (
                FinalReport {
                    first_optimal_episode: 200,
                    ..good_report()
                },
                "first optimal",
            ),
            (
                FinalReport {
                    discoveries_acked: 4,
                    ..good_report()
                },
                "acked",
            ),
        ];
        for (r, what) in cases {
            let e = report(&r, &SHAPE, Some(1), 100, None).expect_err(what);
            assert!(e.to_string().contains(what), "{what}: {e}");
        }
    }

    #[test]
    fn without_an_assignment_any_goal_of_the_run_is_fine() {
        let r = FinalReport {
            goal_id: 0,
            ..good_report()
        };
        assert!(report(&r, &SHAPE, None, 100, None).is_ok());
        let r = FinalReport {
            goal_id: 2,
            ..good_report()
        };
        assert!(report(&r, &SHAPE, None, 100, None).is_err());
    }

    #[test]
    fn discoveries_outside_the_map_or_not_finite_are_rejected() {
        let d = PseudoTargetDiscovery {
            goal_id: 1,
            cell_x: 3,
            cell_y: 2,
            value: 0.5,
            ..PseudoTargetDiscovery::ZEROED
        };
        assert_eq!(discovery(&d, &SHAPE, None), Ok(23));
        let bad = [
            PseudoTargetDiscovery { cell_x: 10, ..d },
            PseudoTargetDiscovery { cell_y: 8, ..d },
            PseudoTargetDiscovery {
                value: f32::NAN,
                ..d
            },
            PseudoTargetDiscovery { goal_id: 2, ..d },
        ];
        for b in bad {
            assert!(discovery(&b, &SHAPE, None).is_err(), "{b:?}");
        }
        assert!(discovery(&d, &SHAPE, Some(0)).is_err());
    }

    #[test]
    fn hint_batches_and_entries_are_checked_separately() {
        let mut b = QHintBatch {
            goal_id: 0,
            count: 2,
            ..QHintBatch::ZEROED
        };
        assert_eq!(hint_batch(&b, &SHAPE, None).map(<[QHint]>::len), Ok(2));
        b.count = HINT_BATCH_CAP as u32 + 1;
        assert_eq!(hint_batch(&b, &SHAPE, None), Err(Invalid::Count(b.count)));
        let ok = QHint {
            cell: 79,
            action: 3,
            q: 0.25,
            ..QHint::ZEROED
        };
        assert_eq!(hint(&ok, SHAPE.cells()), Ok(()));
        assert_eq!(hint(&QHint { cell: 80, ..ok }, 80), Err(Invalid::Cell));
        assert_eq!(
            hint(&QHint { action: 4, ..ok }, 80),
            Err(Invalid::Action(4))
        );
        assert!(hint(&QHint { q: f32::NAN, ..ok }, 80).is_err());
    }

    #[test]
    fn states_with_unknown_status_bytes_are_rejected() {
        let s = RobotState {
            goal_id: 0,
            cell_x: 1,
            cell_y: 1,
            status: RobotStatus::Running.as_u8(),
            ..RobotState::ZEROED
        };
        assert_eq!(state(&s, &SHAPE, Some(0)), Ok(()));
        assert_eq!(
            state(&RobotState { status: 9, ..s }, &SHAPE, Some(0)),
            Err(Invalid::Status(9))
        );
    }

    #[test]
    fn a_path_shorter_than_the_bfs_optimum_or_another_optimum_is_rejected() {
        // the forged report of issue 27: 18 steps where the map's optimum is 19
        let mut r = good_report();
        r.optimal_path_len = 19;
        r.final_path_len = 18;
        let e = report(&r, &SHAPE, Some(1), 100, Some(19)).unwrap_err();
        assert_eq!(
            e,
            Invalid::Forged(Forgery::Shorter {
                got: 18,
                optimum: 19
            })
        );
        assert!(e.to_string().contains("BFS optimum 19"), "{e}");
        // claiming the optimum is 18 does not help: the coordinator's own optimum counts
        r.optimal_path_len = 18;
        assert!(matches!(
            report(&r, &SHAPE, Some(1), 100, Some(19)),
            Err(Invalid::Forged(Forgery::OtherOptimum { got: 18, .. }))
        ));
        // an optimal or longer path, or none at all (-1), is fine
        for (len, verdict) in [
            (19, PathVerdict::Optimal),
            (25, PathVerdict::Longer { extra: 6 }),
            (-1, PathVerdict::NoPathYet),
        ] {
            r.optimal_path_len = 19;
            r.final_path_len = len;
            assert_eq!(
                report(&r, &SHAPE, Some(1), 100, Some(19)).map(|a| a.path),
                Ok(verdict),
                "{len}"
            );
        }
        // no optimum known: the old checks only
        r.final_path_len = 3;
        assert!(report(&r, &SHAPE, Some(1), 100, None).is_ok());
    }

    #[test]
    fn the_honest_no_path_yet_report_of_issue_36_is_accepted() {
        // `qfleet bench --scale` at 256 robots: a robot that computes no optimum and stopped
        // without a path reports -1 / -1; the map's optimum is 318
        let shape = Shape {
            width: 64,
            height: 256,
            goals: 1,
        };
        let r = FinalReport {
            goal_id: 0,
            final_path_len: -1,
            optimal_path_len: -1,
            first_optimal_episode: -1,
            episodes: 1,
            ..good_report()
        };
        assert_eq!(
            report(&r, &shape, Some(0), 1, Some(318)),
            Ok(Accepted {
                status: RobotStatus::Finished,
                path: PathVerdict::NoPathYet
            })
        );
    }

    /// The path verdict as a specification: each case one line, `(final_path_len,
    /// optimal_path_len, the coordinator's optimum, verdict)` on a map of 80 cells.
    #[test]
    fn path_verdicts_tell_a_forgery_from_no_path_yet_and_from_a_longer_path() {
        use Forgery::*;
        use PathVerdict::*;
        const CELLS: u64 = 80;
        let cases: &[(i32, i32, Option<u32>, PathVerdict)] = &[
            // honest endings
            (-1, -1, Some(19), NoPathYet),
            (-1, 19, Some(19), NoPathYet),
            (19, 19, Some(19), Optimal),
            (19, -1, Some(19), Optimal), // a robot that computes no optimum
            (20, 19, Some(19), Longer { extra: 1 }),
            (80, -1, Some(19), Longer { extra: 61 }), // as long as the map has cells
            // forgeries: shorter than BFS, or another optimum
            (
                18,
                19,
                Some(19),
                Forged(Shorter {
                    got: 18,
                    optimum: 19,
                }),
            ),
            (
                0,
                -1,
                Some(19),
                Forged(Shorter {
                    got: 0,
                    optimum: 19,
                }),
            ),
            (
                19,
                18,
                Some(19),
                Forged(OtherOptimum {
                    got: 18,
                    optimum: 19,
                }),
            ),
            (
                -1,
                0,
                Some(19),
                Forged(OtherOptimum {
                    got: 0,
                    optimum: 19,
                }),
            ),
            // 0: start on the goal
            (0, 0, Some(0), Optimal),
            (0, -1, Some(0), Optimal),
            (3, 0, Some(0), Longer { extra: 3 }),
            // negative other than -1, and huge: no length at all
            (
                -2,
                19,
                Some(19),
                Forged(NotALength {
                    what: "final_path_len",
                    got: -2,
                    cells: CELLS,
                }),
            ),
            (
                i32::MIN,
                -1,
                None,
                Forged(NotALength {
                    what: "final_path_len",
                    got: i32::MIN,
                    cells: CELLS,
                }),
            ),
            (
                19,
                -7,
                Some(19),
                Forged(NotALength {
                    what: "optimal_path_len",
                    got: -7,
                    cells: CELLS,
                }),
            ),
            (
                81,
                19,
                Some(19),
                Forged(NotALength {
                    what: "final_path_len",
                    got: 81,
                    cells: CELLS,
                }),
            ),
            (
                i32::MAX,
                i32::MAX,
                Some(19),
                Forged(NotALength {
                    what: "final_path_len",
                    got: i32::MAX,
                    cells: CELLS,
                }),
            ),
            // no optimum known to the coordinator: ranges only
            (-1, -1, None, NoPathYet),
            (3, -1, None, Unjudged),
            (3, 40, None, Unjudged),
        ];
        for &(path, claimed, optimum, want) in cases {
            assert_eq!(
                PathVerdict::judge(path, claimed, optimum, CELLS),
                want,
                "final {path}, claimed optimum {claimed}, optimum {optimum:?}"
            );
        }
    }

    #[test]
    fn forgeries_say_what_was_claimed_against_what() {
        let e = Invalid::from(Forgery::OtherOptimum {
            got: -5,
            optimum: 318,
        });
        assert!(e.to_string().contains("against the BFS optimum 318"), "{e}");
        let e = Invalid::from(Forgery::NotALength {
            what: "final_path_len",
            got: -2,
            cells: 80,
        });
        assert_eq!(
            e.to_string(),
            "final_path_len -2 is no path length on a map of 80 cells"
        );
    }
}
