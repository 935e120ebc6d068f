//! # bus — qfleet's iceoryx2 plumbing
//!
//! Everything between the wire contract ([`bus_schema`]) and the two kinds of processes: the
//! iceoryx2 configuration of a run, services sized for the fleet, typed sending and receiving
//! halves, the start handshake, wakeups for a sleeping coordinator, node liveness and cleanup.
//! Not here: message layouts (`bus-schema`), learning (`planner`), wait strategies and merging
//! (`coordinator`), the robot's loop (`robot-agent`).
//!
//! ```no_run
//! use std::time::Duration;
//! use bus::bus_schema::{ROBOT_ID_ALL, Register, SCHEMA_VERSION};
//! use bus::{BusConfig, CoordinatorBus, Expected, RobotBus};
//! # fn main() -> Result<(), bus::BusError> {
//! let cfg = BusConfig::new("run-42", 4)?; // same in every process of the run
//!
//! // coordinator process
//! let coord = CoordinatorBus::create(&cfg)?;
//! let expected = Expected { robots: 4, map_hash: 0x1234, width: 20, height: 20 };
//! let fleet = coord.accept_fleet(&expected, Duration::from_secs(30))?;
//! coord.start(ROBOT_ID_ALL, 500)?;
//! while let Some(d) = coord.discovery.receive()? { /* merge, ack … */ }
//! coord.close()?; // removes the run's files once nobody is left
//!
//! // robot process
//! let robot = RobotBus::open(&cfg, 3, Duration::from_secs(30))?;
//! let reg = Register { schema_version: SCHEMA_VERSION, robot_id: 3, map_hash: 0x1234,
//!                      width: 20, height: 20, ..Register::ZEROED };
//! robot.register(&reg, Duration::from_secs(30))?;          // Ok(Ack) or Err(Refused{reason})
//! let start = robot.wait_start(Duration::from_secs(60), |goal| { /* AssignGoal … */ })?;
//! robot.discovery.send_with(|d| { d.robot_id = 3; d.seq = 0; })?; // in place, lossless
//! robot.discovery.notify()?;
//! robot.close()?;
//! # Ok(()) }
//! ```
//!
//! ## One run, one iceoryx2 domain
//!
//! A [`BusConfig`] names a run (`run_id`: 1–48 of `A-Z a-z 0-9 _ -`) and sizes it (`robots`:
//! `1..=`[`MAX_ROBOTS`] = 256). The iceoryx2 `Config` is built in code from iceoryx2's defaults —
//! no config file is read, so a stray `~/.config/iceoryx2/iceoryx2.toml` cannot change a run —
//! with `global.prefix = "qfleet.<run-id>."`. Every file of the run (shared memory in
//! `/dev/shm`, bookkeeping under `/tmp/iceoryx2/`) starts with that prefix, runs with different
//! ids cannot see each other, and tests running in parallel never collide
//! ([`unique_run_id`]). Service names are `qfleet/<run-id>/robot/…` and `…/coord/…`.
//!
//! ## Topics: lossless or latest-wins, and why
//!
//! The coordinator creates every service (`open_or_create` with the limits below); robots only
//! open them, demanding just the payload type and the overflow mode, so a robot never needs to
//! know the fleet size and never trips over "service supports fewer publishers than requested".
//!
//! | topic | type | delivery | buffer per connection | history | why |
//! |---|---|---|---|---|---|
//! | `robot/register` | `Register` | lossless | 4 | 0 | a lost registration stalls the handshake |
//! | `robot/state` | `RobotState` | latest-wins | `state_buffer` (4) | 1 | only the newest state matters; never stall a learner |
//! | `robot/discovery` | `PseudoTargetDiscovery` | lossless | `discovery_buffer` (256) | 0 | rare and valuable: each must arrive exactly once (and is acked) |
//! | `robot/hints` | `QHintBatch` | latest-wins | `hint_buffer` (8) | 0 | newer Q-values supersede older; a slow coordinator must not block robots |
//! | `robot/report` | `FinalReport` | lossless | 4 | 0 | the results of the run |
//! | `coord/control` | `Control` | lossless | 2·robots + 16 ([`control_buffer`]) | 0 | Start/Stop/goals must never be missed; the whole start burst (an Ack and a goal per robot) fits, so a robot that is not scheduled during it never blocks the coordinator |
//! | `coord/merged` | `MergedHintBatch` | latest-wins | `merged_buffer` (4; runs: [`merged_buffer_for`], 16–512) | 1 | one slow robot must not block the fleet; deep, because a batch is a delta and one overwritten is lost to that robot |
//! | `coord/ack` | `DiscoveryAck` | latest-wins | 2·robots + 8 | 0 | cumulative: a newer ack carries all older ones; room for a full round of acks |
//! | `coord/discovery` | `DiscoveryRelay` | lossless | `discovery_buffer` (256) | 0 | each distinct discovery is relayed once and must reach every robot on its goal; rare (a few dozen per goal) |
//!
//! Lossless = safe overflow off + `RetryUntilDelivered` with a backpressure handler that gives
//! up after `send_timeout` (5 s) and reports [`SendError::DeliveryTimeout`], and a send that
//! reached no subscriber is [`SendError::NoSubscriber`] — a lossless send never drops silently
//! and never hangs forever on a dead peer. Lossless is lossless *to the fleet*: the handler
//! retries only for the fleet's own subscribers (port name [`FLEET_PORT_NAME`]); a full buffer
//! of an outside reader ([`Inbox::open`], [`Observer`]) drops that sample for it alone and the
//! send goes on ([`Outbox::outsider_drops`] counts them), so a stalled monitor never blocks or
//! aborts a run. The handler runs only when a buffer is full: a send into free buffers costs
//! the same as before. Latest-wins = safe overflow on: a full buffer drops its oldest sample;
//! sequence gaps show it. A sample stays receivable after its publisher's process exited: every
//! subscriber keeps the unread samples of up to [`BusConfig::max_nodes`] departed publishers
//! (iceoryx2's own default, 128, discarded the final reports of 256 robots stopping together).
//!
//! Limits, from `robots` = R, `spare_ports` = S (2: a restarted process whose dead
//! predecessor is not cleaned yet) and [`OBSERVER_SLOTS`] = O (4: outside readers, see
//! [`Observer`]): robot→coordinator topics admit R+S+O publishers and 1+S+O subscribers,
//! coordinator→robot topics 1+S+O publishers and R+S+O subscribers, every service R+1+S+O
//! nodes; each topic's wake event service admits as many notifiers/listeners as the topic has
//! publishers/subscribers. See [`limits()`]. Shared memory is allocated up front from these;
//! [`shm_estimate`] computes the run's need from them and [`preflight`] compares it with the
//! free space of `/dev/shm` before a run starts.
//!
//! ## Files and permissions
//!
//! Every file of a run (its shared memory in `/dev/shm`, its files under iceoryx2's root) is
//! narrowed to 0600 (directories 0700) as soon as a process has created its node and ports —
//! iceoryx2 itself leaves the per-prefix management segment 0666 — and a prefix holding a file
//! of another user is refused ([`BusError::ForeignFile`]); see `files.rs` for what iceoryx2
//! does and the one window that remains.

//! ## The start handshake (lossless only after connecting)
//!
//! iceoryx2 keeps the lossless promise only once a subscriber has *connected* to a publisher;
//! before that a full buffer drops silently. The handshake makes sure nothing lossless is sent
//! into an unconnected buffer:
//!
//! 1. The coordinator creates all services and its subscribers ([`CoordinatorBus::create`]).
//! 2. A robot opens its subscribers, then its publishers ([`RobotBus::open`]), and sends one
//!    `Register` ([`RobotBus::register`], re-sent every 250 ms until answered, so start order
//!    does not matter).
//! 3. The coordinator checks it ([`check_register`]: schema version first — iceoryx2 only
//!    compares type names and sizes — then id range and map), connects all its subscribers to
//!    the robot's publishers, and answers `Ack` or `Refuse` with a reason
//!    ([`CoordinatorBus::admit`], looped by [`CoordinatorBus::accept_fleet`]).
//! 4. After all robots are in, the coordinator sends goals, then `Start`
//!    ([`CoordinatorBus::start`]); robots publish learning traffic only after
//!    [`RobotBus::wait_start`] returned `Start`.
//!
//! Sending a lossless message before this is reported as [`SendError::NoSubscriber`] once the
//! unconnected buffer is full, never dropped silently (tested).
//!
//! ## Sending and waking
//!
//! [`Outbox::send`] copies a message into a loaned shared-memory slot; [`Outbox::send_with`]
//! zeroes the slot and lets a closure write the message in place — the way to send the 3–6 KiB
//! hint batches without building them on the stack; [`Outbox::send_batch`] does the same for
//! the batch types but zeroes only what the slot's previous batch used (its header and
//! `count` entries), not the whole slot. None of them allocates per message. Publish-subscribe has no
//! wakeup of its own, so each topic has a companion event service `…/wake`: call
//! [`Outbox::notify`] after a burst (not after every message: a cross-CPU wakeup costs tens of
//! µs). For the coordinator's wait strategies:
//!
//! - **spin**: poll [`CoordinatorBus::has_samples`] / [`Inbox::receive`];
//! - **event**: attach all inbox listeners to one iceoryx2 `WaitSet`
//!   ([`CoordinatorBus::attach_all`]), `wait_and_process_once_with_timeout`, then
//!   [`CoordinatorBus::clear_wakeups`] and drain; or block on one inbox with [`Inbox::wait`];
//! - **hybrid**: spin a bounded time, then block — see `examples/waitset.rs`.
//!
//! Wake event id [`EVENT_DATA`] means data; [`EVENT_PEER_DEAD`] is sent by iceoryx2 when a
//! cleanup found a dead notifier ([`Wakeups::peer_dead`]).
//!
//! ## Threads
//!
//! Endpoints use iceoryx2's `ipc::Service` (single-threaded ports, the fastest): create a
//! [`CoordinatorBus`] or [`RobotBus`] on the thread that uses it. Several in one process (tests,
//! an in-process fleet) are fine, each on its own thread.
//!
//! ## Liveness and cleanup
//!
//! [`check_nodes`] lists the run's nodes (alive, dead after e.g. SIGKILL) and optionally removes
//! dead ones' resources, so a restarted process can take their place. A listing is expensive
//! (hundreds of µs); a process that watches its peers runs a [`Lister`], which lists on a
//! thread of its own, fully once a second and by one `/proc` read per process in between
//! ([`lister`]). [`clean_stale`] (for
//! `qfleet clean`) additionally removes every leftover file of a prefix once no node of it is
//! alive — a clean exit still leaves one small management file, which
//! [`CoordinatorBus::close`]/[`RobotBus::close`] remove when the last process leaves.
//! [`find_run_prefixes`] finds runs that left files behind; [`clean::clean_runs`] is `qfleet
//! clean` over them.
//!
//! ## Errors
//!
//! [`BusError`] for every operation but a send; each variant says what to do. A send on an
//! [`Outbox`] (`send`, `send_with`, `send_batch`) returns [`SendError`], whose outcomes its
//! callers act on apart: [`SendError::NoSubscriber`] and [`SendError::DeliveryTimeout`] (a
//! peer gone, stuck or not connected yet: log, skip or retry) versus [`SendError::Loan`] and
//! [`SendError::Failed`] (the bus is broken). `?` turns it into [`BusError::Send`], which shows
//! the same text, so [`Outbox::send_and_notify`], [`CoordinatorBus::send_control`] and the
//! handshake return `BusError` with the send's outcome inside. Why the other operations share
//! one enum is in `error.rs`. A peer built from another schema (different payload type name,
//! size or alignment) gets [`BusError::SchemaMismatch`] naming the service, the type and both
//! schema facts, instead of iceoryx2's bare `IncompatibleTypes`.

#![deny(missing_docs)]

pub mod clean;
mod clock;
mod commit;
mod config;
mod endpoints;
mod error;
mod files;
mod handshake;
pub mod limits;
pub mod lister;
mod liveness;
mod observer;
mod topic;
mod wake;

pub use bus_schema;
pub use iceoryx2;

pub use clock::monotonic_ns;
pub use commit::{Committed, Committer, commit_run_shm};
pub use config::{
    BusConfig, MAX_BUFFER, MAX_ROBOTS, MERGED_SEGMENT_BUDGET, OBSERVER_SLOTS,
    iceoryx_config_for_prefix, merged_buffer_for, quiet_library_logs, unique_run_id,
    validate_run_id,
};
pub use endpoints::{CoordinatorBus, Origin, RobotBus};
pub use error::{BusError, SendError};
pub use files::{
    DIR_MODE, FILE_MODE, check_iceoryx_root, check_run_files, check_shm_space, free_bytes,
    preflight, restrict_run_files, shm_estimate,
};
pub use handshake::{Admission, Expected, check_register, control, reason, set_reason};
pub use lister::{Lister, Listing, ProcessState, process_state};
pub use liveness::{
    CleanReport, EMPTY_NODE_DIR_AGE, Liveness, NodeInfo, NodeReport, check_nodes, clean_run,
    clean_stale, empty_node_dirs, find_run_prefixes, iceoryx_root, leftover_files,
    remove_empty_node_dirs, stale_empty_node_dirs, sweep_empty_node_dirs,
};
pub use observer::{OBSERVER_NODE_PREFIX, Observer};
pub use topic::{
    Batch, EVENT_DATA, EVENT_PEER_DEAD, FLEET_PORT_NAME, Inbox, Message, OBSERVER_PORT_NAME,
    Outbox, TopicLimits, Wakeups, control_buffer, limits,
};
pub use wake::{WakeListener, Waker, wake_pair};
