//! Shared-grid multi-agent path finding (MAPF): everything the coordinator decides when it is
//! the authority of one grid shared by a fleet. Pure: no IO, no bus, no clocks.
//!
//! - [`instance`]: a validated instance (grid, starts, goals, BFS distance tables).
//! - [`horizon`]: a robot's rankings for the cells it may reach within a few ticks.
//! - [`moves`]: the five moves and a robot's [`Intent`] (its moves ranked best first).
//! - [`world`]: the per-tick resolver that grants every robot one collision-free move.
//! - [`check`](mod@check): an independent checker of finished paths and their costs.
//! - [`paths`]: the mapf-visualizer path format, written and parsed.
//! - [`lifelong`]: lifelong runs (a new goal on arrival): League of Robot Runners problems and
//!   the resolver that deals goals as robots reach them.
//!
//! The coordinator's loop, with robots that rank moves by distance to their goals:
//!
//! ```
//! use mapf::{Instance, Intent, Status, World, WorldConfig, check, write_paths};
//! use planner::{Cell, map::parse_ascii};
//!
//! // two robots swap ends of a corridor with one side pocket
//! let grid = parse_ascii("doc", b"###.###\n.......\n").unwrap().grid;
//! let (a, b) = (Cell::new(0, 1), Cell::new(6, 1));
//! let inst = Instance::new(grid, vec![a, b], vec![b, a]).unwrap();
//! let mut world = World::new(&inst, WorldConfig::default());
//! let mut intents = vec![None; inst.agents()];
//! while !world.all_arrived() && world.tick() < 100 {
//!     // each robot's intent (here: what a robot with converged values would send)
//!     for (i, p) in world.positions().iter().enumerate() {
//!         intents[i] = p.map(|c| Intent::toward(inst.grid(), inst.dist(i).unwrap(), c));
//!     }
//!     let tick = world.step(&intents).unwrap();
//!     assert_ne!(tick.status, Status::Unsolvable);
//! }
//! let costs = check(inst.grid(), inst.starts(), inst.goals(), &world.paths()).unwrap();
//! assert!(costs.all_arrived);
//! assert!(write_paths(&world.paths()).starts_with("0:(0,1),(6,1),"));
//! ```
#![deny(missing_docs)]

pub mod check;
pub mod horizon;
pub mod instance;
pub mod lifelong;
pub mod moves;
pub mod paths;

pub use check::{Costs, Violation, check};
pub use horizon::Coverage;
pub use instance::{Instance, InstanceError, MAX_AGENTS};
pub use moves::{Intent, IntentError, Move};
pub use paths::{PathsError, parse_paths, write_paths};
pub mod world;

mod pibt;
mod plan;
mod search;

pub use world::{AgentStats, Status, Tick, World, WorldConfig, WorldError};
