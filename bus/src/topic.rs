//! Per-topic limits, opening services, and the typed sending/receiving halves of a topic.

use core::fmt::Debug;
use core::mem::offset_of;
use std::cell::RefCell;
use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use bus_schema::names::{Delivery, Direction, Topic};
use bus_schema::{
    Control, DiscoveryAck, DiscoveryRelay, FinalReport, Grant, HINT_BATCH_CAP, Intent,
    IntentHorizon, MergedHintBatch, PseudoTargetDiscovery, QHint, QHintBatch, Register, RobotState,
    SCHEMA_VERSION,
};
use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::port::{BackpressureAction, BackpressureInfo, SendError};
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::service::builder::event::{EventOpenError, EventOpenOrCreateError};
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::port_factory::{event, publish_subscribe};

use crate::config::OBSERVER_SLOTS;
use crate::{BusConfig, BusError};

/// Event id a publisher's notifier sends after new data ("look at the topic").
pub const EVENT_DATA: EventId = EventId::new(0);

/// Event id iceoryx2 emits on a wake service when cleanup finds a notifier of a dead process
/// ("a peer died: run a liveness check").
pub const EVENT_PEER_DEAD: EventId = EventId::new(1);

/// Largest event id used on the wake services.
const EVENT_ID_MAX: usize = 1;

/// A payload type that can travel on a qfleet topic.
///
/// # Safety
///
/// The type must be `#[repr(C)]` without implicit padding, and the all-zero byte pattern must
/// be a valid value of it: [`Outbox::send_with`] zeroes the shared-memory slot and hands it out
/// as `&mut Self`. All `bus-schema` messages qualify (checked by their layout test).
pub unsafe trait Message: ZeroCopySend + Copy + Debug + 'static {
    /// The topic this type travels on.
    const TOPIC: Topic;
}

// SAFETY (all impls): bus-schema messages are repr(C) POD structs whose layout test proves they
// have no implicit padding; every field is an integer, float, or array/struct of those.
unsafe impl Message for Register {
    const TOPIC: Topic = Topic::Register;
}
unsafe impl Message for RobotState {
    const TOPIC: Topic = Topic::RobotState;
}
unsafe impl Message for PseudoTargetDiscovery {
    const TOPIC: Topic = Topic::Discovery;
}
unsafe impl Message for QHintBatch {
    const TOPIC: Topic = Topic::Hints;
}
unsafe impl Message for FinalReport {
    const TOPIC: Topic = Topic::Report;
}
unsafe impl Message for Control {
    const TOPIC: Topic = Topic::Control;
}
unsafe impl Message for MergedHintBatch {
    const TOPIC: Topic = Topic::Merged;
}
unsafe impl Message for DiscoveryAck {
    const TOPIC: Topic = Topic::Ack;
}
unsafe impl Message for DiscoveryRelay {
    const TOPIC: Topic = Topic::Relay;
}
unsafe impl Message for Intent {
    const TOPIC: Topic = Topic::Intent;
}
unsafe impl Message for IntentHorizon {
    const TOPIC: Topic = Topic::Horizon;
}
unsafe impl Message for Grant {
    const TOPIC: Topic = Topic::Grant;
}

/// A message with `count` valid entries at the front of its per-entry arrays and zeros after
/// them (the wire contract of `QHintBatch` and `MergedHintBatch`): what
/// [`Outbox::send_batch`] needs to clear a reused slot without zeroing all of it.
pub trait Batch: Message {
    /// Entries the message uses: its `count`, at most [`HINT_BATCH_CAP`].
    fn used(&self) -> usize;
    /// Zeroes the header (every byte before the arrays) and the first `n` entries of every
    /// per-entry array; `n` above the capacity means all of them.
    fn clear_front(&mut self, n: usize);
}

/// Zeroes the first `len` bytes of `msg` (a header made of integers and explicit padding).
fn zero_prefix<T: Message>(msg: &mut T, len: usize) {
    assert!(len <= size_of::<T>());
    // SAFETY: in bounds (checked), and `T: Message` makes zero bytes valid for any field.
    unsafe { core::ptr::write_bytes(core::ptr::from_mut(msg).cast::<u8>(), 0, len) }
}

// the arrays end the messages: nothing after them to clear
const _: () = assert!(
    offset_of!(QHintBatch, entries) + size_of::<[QHint; HINT_BATCH_CAP]>()
        == size_of::<QHintBatch>()
);
const _: () = assert!(
    offset_of!(MergedHintBatch, origin_robot) + size_of::<[u32; HINT_BATCH_CAP]>()
        == size_of::<MergedHintBatch>()
);

impl Batch for QHintBatch {
    #[inline]
    fn used(&self) -> usize {
        (self.count as usize).min(HINT_BATCH_CAP)
    }

    #[inline]
    fn clear_front(&mut self, n: usize) {
        let n = n.min(HINT_BATCH_CAP);
        zero_prefix(self, offset_of!(QHintBatch, entries));
        self.entries[..n].fill(QHint::ZEROED);
    }
}

impl Batch for MergedHintBatch {
    #[inline]
    fn used(&self) -> usize {
        (self.count as usize).min(HINT_BATCH_CAP)
    }

    #[inline]
    fn clear_front(&mut self, n: usize) {
        let n = n.min(HINT_BATCH_CAP);
        zero_prefix(self, offset_of!(MergedHintBatch, entries));
        self.entries[..n].fill(QHint::ZEROED);
        self.origin_ns[..n].fill(0);
        self.origin_robot[..n].fill(0);
    }
}

/// Slots an [`Outbox`] remembers for [`Outbox::send_batch`]; more than any topic's data
/// segment has (a bound against an unexpected allocator, not a tuning knob).
const DIRTY_SLOTS_MAX: usize = 1 << 16;

/// The limits a topic's publish-subscribe service and its wake event service are created with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TopicLimits {
    /// Publishers (and wake notifiers) the service admits.
    pub max_publishers: usize,
    /// Subscribers (and wake listeners) the service admits.
    pub max_subscribers: usize,
    /// Processes (nodes) that may open the service.
    pub max_nodes: usize,
    /// Samples buffered per publisher→subscriber connection.
    pub subscriber_buffer: usize,
    /// Samples a subscriber may hold at once.
    pub subscriber_borrowed: usize,
    /// Samples a publisher may have loaned at once.
    pub publisher_loans: usize,
    /// Last samples replayed to a subscriber that connects late.
    pub history: usize,
    /// Latest-wins (`true`) or lossless (`false`).
    pub safe_overflow: bool,
}

/// The limits of `topic` for the fleet described by `cfg` (see the crate docs for the table).
///
/// Ports and nodes are the fleet's (R robots + 1 coordinator), plus `spare_ports` for a
/// restarted process whose dead predecessor is not cleaned yet, plus [`OBSERVER_SLOTS`] for
/// outside readers: an observer that follows [`crate::Observer`]'s admission never takes a slot
/// a restart needs.
pub fn limits(cfg: &BusConfig, topic: Topic) -> TopicLimits {
    let robots = cfg.robots as usize;
    let spare = cfg.spare_ports as usize + OBSERVER_SLOTS as usize;
    let (max_publishers, max_subscribers, subscriber_borrowed) = match topic.direction() {
        Direction::RobotToCoordinator => (robots + spare, 1 + spare, 4),
        Direction::CoordinatorToRobot => (1 + spare, robots + spare, 2),
    };
    let (subscriber_buffer, history) = match topic {
        // one registration per robot, plus a few re-sends while the coordinator starts
        Topic::Register => (4, 0),
        Topic::RobotState => (cfg.state_buffer, 1),
        Topic::Discovery => (cfg.discovery_buffer, 0),
        Topic::Hints => (cfg.hint_buffer, 0),
        Topic::Report => (4, 0),
        // broadcast: the start burst — one Ack per robot, one AssignGoal per robot, Start and a
        // few Phase/Stop — passes through every robot's buffer. It must fit whole: on a loaded
        // machine a robot that registered early may not run at all while the others register,
        // and a lossless send into its full buffer would block the coordinator (issue 10 #11:
        // 64 slots failed at 256 robots with "not delivered within 1s").
        Topic::Control => (control_buffer(robots), 0),
        Topic::Merged => (cfg.merged_buffer, 1),
        // broadcast and cumulative: room for one ack per robot, twice, so a robot's own latest
        // ack is not pushed out by one round of acks to the others
        Topic::Ack => (2 * robots + 8, 0),
        // one relay per distinct (goal, cell) of the run, a few dozen per goal; as deep as the
        // discovery inbox so a burst of relays never waits for a robot between two polls
        Topic::Relay => (cfg.discovery_buffer, 0),
        // shared grid: one intent per robot per tick, answered by one grant per tick; only the
        // newest matters (an older one is for a tick already resolved), and a robot that
        // connects late reads the current configuration from the history
        Topic::Intent => (4, 0),
        // one horizon per robot per wake of the fleet (every few ticks); only the newest matters
        Topic::Horizon => (4, 0),
        Topic::Grant => (2, 1),
    };
    TopicLimits {
        max_publishers,
        max_subscribers,
        max_nodes: cfg.max_nodes(),
        subscriber_buffer,
        subscriber_borrowed,
        publisher_loans: 2,
        history,
        safe_overflow: topic.delivery() == Delivery::LatestWins,
    }
}

/// Control samples buffered per robot: the whole start burst for `robots` (see [`limits`]).
pub fn control_buffer(robots: usize) -> usize {
    2 * robots + 16
}

/// Port name of the fleet's own subscribers (the coordinator's and the robots'); an outside
/// reader's subscriber has another name, and a lossless publisher discards for it when its
/// buffer is full instead of waiting (see [`Outbox`]).
pub const FLEET_PORT_NAME: &str = "qfleet-fleet";

/// Port name of an outside reader's subscriber ([`Inbox::open`]).
pub const OBSERVER_PORT_NAME: &str = "qfleet-observer";

/// Whether this process creates services (the coordinator) or only opens them (robots).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Role {
    /// Opens or creates with the fleet's limits.
    Creator,
    /// Opens what the creator made; demands only a matching type and overflow mode.
    Opener,
}

fn pubsub_open_error(
    service: &str,
    t: (&'static str, usize, usize),
    e: PublishSubscribeOpenError,
) -> BusError {
    use PublishSubscribeOpenError as E;
    match e {
        E::IncompatibleTypes => BusError::SchemaMismatch {
            service: service.to_string(),
            type_name: t.0,
            size: t.1,
            align: t.2,
            schema_version: SCHEMA_VERSION,
        },
        // the coordinator is creating it right now (a robot of a large fleet opens while the
        // coordinator still creates the last services): not there yet, retried like a missing one
        E::DoesNotExist | E::HangsInCreation => BusError::ServiceMissing {
            service: service.to_string(),
        },
        E::IncompatibleMessagingPattern
        | E::IncompatibleAttributes
        | E::DoesNotSupportRequestedMinBufferSize
        | E::DoesNotSupportRequestedMinHistorySize
        | E::DoesNotSupportRequestedMinSubscriberBorrowedSamples
        | E::DoesNotSupportRequestedAmountOfPublishers
        | E::DoesNotSupportRequestedAmountOfSubscribers
        | E::DoesNotSupportRequestedAmountOfNodes
        | E::IncompatibleOverflowBehavior
        | E::ExceedsMaxNumberOfNodes => BusError::IncompatibleService {
            service: service.to_string(),
            detail: format!("{e:?}"),
        },
        other => BusError::Service {
            service: service.to_string(),
            detail: format!("{other:?}"),
        },
    }
}

fn event_open_error(service: &str, e: EventOpenError) -> BusError {
    use EventOpenError as E;
    match e {
        E::DoesNotExist | E::HangsInCreation => BusError::ServiceMissing {
            service: service.to_string(),
        },
        E::IncompatibleMessagingPattern
        | E::IncompatibleAttributes
        | E::IncompatibleDeadline
        | E::IncompatibleNotifierCreatedEvent
        | E::IncompatibleNotifierDroppedEvent
        | E::IncompatibleNotifierDeadEvent
        | E::DoesNotSupportRequestedAmountOfNotifiers
        | E::DoesNotSupportRequestedAmountOfListeners
        | E::DoesNotSupportRequestedMaxEventId
        | E::DoesNotSupportRequestedAmountOfNodes
        | E::ExceedsMaxNumberOfNodes => BusError::IncompatibleService {
            service: service.to_string(),
            detail: format!("{e:?}"),
        },
        other => BusError::Service {
            service: service.to_string(),
            detail: format!("{other:?}"),
        },
    }
}

fn service_name(name: &str) -> Result<ServiceName, BusError> {
    ServiceName::new(name).map_err(|e| BusError::Service {
        service: name.to_string(),
        detail: format!("invalid service name: {e:?}"),
    })
}

/// Opens (or creates) the publish-subscribe service of `topic` for payload `T`.
pub(crate) fn open_pubsub<T: Message>(
    node: &Node<ipc::Service>,
    cfg: &BusConfig,
    topic: Topic,
    role: Role,
) -> Result<publish_subscribe::PortFactory<ipc::Service, T, ()>, BusError> {
    let name = topic.service_name(&cfg.run_id);
    let service = service_name(&name)?;
    let l = limits(cfg, topic);
    // SAFETY: `type_name` only returns the literal given to `#[type_name]`.
    let t = (
        unsafe { <T as ZeroCopySend>::type_name() },
        size_of::<T>(),
        align_of::<T>(),
    );
    let builder = node
        .service_builder(&service)
        .publish_subscribe::<T>()
        .enable_safe_overflow(l.safe_overflow);
    match role {
        Role::Creator => builder
            .history_size(l.history)
            .subscriber_max_buffer_size(l.subscriber_buffer)
            .subscriber_max_borrowed_samples(l.subscriber_borrowed)
            .max_publishers(l.max_publishers)
            .max_subscribers(l.max_subscribers)
            .max_nodes(l.max_nodes)
            .open_or_create()
            .map_err(|e| match e {
                PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(e) => {
                    pubsub_open_error(&name, t, e)
                }
                other => BusError::Service {
                    service: name.clone(),
                    detail: format!("{other:?}"),
                },
            }),
        Role::Opener => builder.open().map_err(|e| pubsub_open_error(&name, t, e)),
    }
}

/// Opens (or creates) the wake event service of `topic`.
pub(crate) fn open_wake(
    node: &Node<ipc::Service>,
    cfg: &BusConfig,
    topic: Topic,
    role: Role,
) -> Result<event::PortFactory<ipc::Service>, BusError> {
    let name = topic.wake_service_name(&cfg.run_id);
    let service = service_name(&name)?;
    let l = limits(cfg, topic);
    let builder = node.service_builder(&service).event();
    match role {
        Role::Creator => builder
            .max_notifiers(l.max_publishers)
            .max_listeners(l.max_subscribers)
            .max_nodes(l.max_nodes)
            .event_id_max_value(EVENT_ID_MAX)
            .disable_deadline()
            .disable_notifier_created_event()
            .disable_notifier_dropped_event()
            .notifier_dead_event(EVENT_PEER_DEAD)
            .open_or_create()
            .map_err(|e| match e {
                EventOpenOrCreateError::EventOpenError(e) => event_open_error(&name, e),
                other => BusError::Service {
                    service: name.clone(),
                    detail: format!("{other:?}"),
                },
            }),
        Role::Opener => builder.open().map_err(|e| event_open_error(&name, e)),
    }
}

/// Sending half of a topic: a publisher plus the notifier of the topic's wake service.
///
/// Sending never allocates (except [`send_batch`](Self::send_batch)'s slot table while it
/// meets the publisher's slots for the first time): the message is written straight into a
/// loaned shared-memory slot.
pub struct Outbox<T: Message> {
    service: String,
    delivery: Delivery,
    send_timeout: Duration,
    publisher: Publisher<ipc::Service, T, ()>,
    notifier: Notifier<ipc::Service>,
    /// [`send_batch`](Self::send_batch): entries used by the message last written into each
    /// slot (by address), i.e. the only bytes of that slot that are not zero.
    dirty: RefCell<HashMap<usize, u32>>,
    /// Samples dropped for outside readers whose buffer was full (see [`Self::outsider_drops`]).
    outsider_drops: Arc<AtomicU64>,
}

/// Tells the fleet's subscribers from outside readers by port name, for the backpressure
/// handler of a lossless [`Outbox`]; a verdict is cached per subscriber port id (ids are
/// unique and never reused), so the service's port list is read once per subscriber that ever
/// had a full buffer, not per retry.
struct FleetPorts<T: Message> {
    pubsub: Arc<publish_subscribe::PortFactory<ipc::Service, T, ()>>,
    verdicts: RefCell<HashMap<u128, bool>>,
}

impl<T: Message> FleetPorts<T> {
    /// Most cached verdicts (a bound, not a tuning knob: a run has a few hundred subscribers).
    const MAX_CACHED: usize = 1 << 14;

    fn new(pubsub: Arc<publish_subscribe::PortFactory<ipc::Service, T, ()>>) -> Self {
        Self {
            pubsub,
            verdicts: RefCell::new(HashMap::new()),
        }
    }

    /// Whether the subscriber port `id` belongs to the fleet. A port not found in the service's
    /// list counts as the fleet's: when in doubt, keep the lossless promise.
    fn is_fleet(&self, id: u128) -> bool {
        if let Some(v) = self.verdicts.borrow().get(&id) {
            return *v;
        }
        let mut fleet = true;
        self.pubsub.dynamic_config().list_subscribers(|d| {
            if d.subscriber_id.value() == id {
                fleet = d.subscriber_name.as_str() == FLEET_PORT_NAME;
                CallbackProgression::Stop
            } else {
                CallbackProgression::Continue
            }
        });
        let mut verdicts = self.verdicts.borrow_mut();
        if verdicts.len() >= Self::MAX_CACHED {
            verdicts.clear();
        }
        verdicts.insert(id, fleet);
        fleet
    }
}

impl<T: Message> Outbox<T> {
    /// Opens a publisher on `T`'s topic of an existing run, for a process other than the
    /// coordinator and robots (a replayer, a test); it takes one of the spare ports.
    pub fn open(node: &Node<ipc::Service>, cfg: &BusConfig) -> Result<Self, BusError> {
        Self::create(node, cfg, Role::Opener)
    }

    pub(crate) fn create(
        node: &Node<ipc::Service>,
        cfg: &BusConfig,
        role: Role,
    ) -> Result<Self, BusError> {
        let topic = T::TOPIC;
        let service = topic.service_name(&cfg.run_id);
        // shared with the backpressure handler, which looks up who owns a full buffer
        let pubsub = Arc::new(open_pubsub::<T>(node, cfg, topic, role)?);
        let wake = open_wake(node, cfg, topic, role)?;
        let l = limits(cfg, topic);
        let port_err = |port: &'static str, detail: String| BusError::Port {
            port,
            service: service.clone(),
            detail,
        };
        let outsider_drops = Arc::new(AtomicU64::new(0));
        let builder = pubsub
            .publisher_builder()
            .max_loaned_samples(l.publisher_loans);
        let publisher = match topic.delivery() {
            Delivery::LatestWins => {
                builder.backpressure_strategy(BackpressureStrategy::DiscardData)
            }
            Delivery::Lossless => {
                let timeout = cfg.send_timeout;
                let owners = FleetPorts::new(Arc::clone(&pubsub));
                let drops = Arc::clone(&outsider_drops);
                builder
                    .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
                    // Runs only when a subscriber's buffer is full, never on a plain send.
                    // The fleet's own subscribers: retry while they drain, after the timeout
                    // fail loudly. An outside reader's: drop this sample for it alone and go
                    // on — a stalled monitor never blocks or aborts the run.
                    .set_backpressure_handler(move |info: &BackpressureInfo| {
                        if !owners.is_fleet(info.receiver_port_id) {
                            drops.fetch_add(1, Ordering::Relaxed);
                            BackpressureAction::DiscardData
                        } else if info.elapsed_time < timeout {
                            BackpressureAction::Retry
                        } else {
                            BackpressureAction::DiscardDataAndFail
                        }
                    })
            }
        }
        .create()
        .map_err(|e| port_err("publisher", format!("{e:?}")))?;
        let notifier = wake
            .notifier_builder()
            .default_event_id(EVENT_DATA)
            .create()
            .map_err(|e| port_err("notifier", format!("{e:?}")))?;
        Ok(Self {
            service,
            delivery: topic.delivery(),
            send_timeout: cfg.send_timeout,
            publisher,
            notifier,
            dirty: RefCell::new(HashMap::new()),
            outsider_drops,
        })
    }

    /// Samples of this (lossless) outbox that an outside reader's full buffer did not take:
    /// dropped for that reader alone, delivered to the fleet. Always 0 on latest-wins topics.
    pub fn outsider_drops(&self) -> u64 {
        self.outsider_drops.load(Ordering::Relaxed)
    }

    /// The service name this outbox publishes on.
    pub fn service(&self) -> &str {
        &self.service
    }

    /// Copies `msg` into a loaned shared-memory slot and sends it; returns the number of
    /// subscribers reached.
    ///
    /// Lossless topics report [`BusError::NoSubscriber`] when nobody received it and
    /// [`BusError::DeliveryTimeout`] when a subscriber stayed full for the send timeout.
    pub fn send(&self, msg: &T) -> Result<usize, BusError> {
        let sample = self.publisher.loan_uninit().map_err(|e| self.loan_err(e))?;
        self.finish(sample.write_payload(*msg).send())
    }

    /// Loans a slot, zeroes it, lets `fill` write the message in place, and sends it.
    ///
    /// The zero-copy way to send the 3–6 KiB hint batches: nothing is built on the stack and
    /// copied. Same results as [`send`](Self::send).
    pub fn send_with(&self, fill: impl FnOnce(&mut T)) -> Result<usize, BusError> {
        let mut uninit = self.publisher.loan_uninit().map_err(|e| self.loan_err(e))?;
        // SAFETY: `T: Message` guarantees all-zero bytes are a valid `T`; the slot is
        // exclusively ours until sent.
        let mut sample = unsafe {
            uninit.payload_mut().as_mut_ptr().write_bytes(0, 1);
            uninit.assume_init()
        };
        fill(sample.payload_mut());
        self.finish(sample.send())
    }

    /// Sends `msg` and then wakes the subscribers.
    pub fn send_and_notify(&self, msg: &T) -> Result<usize, BusError> {
        let n = self.send(msg)?;
        self.notify()?;
        Ok(n)
    }

    /// Wakes every listener of the topic's wake service; returns how many were notified.
    ///
    /// Call it after a burst of sends rather than after each one: a cross-CPU wakeup costs
    /// tens of microseconds.
    pub fn notify(&self) -> Result<usize, BusError> {
        self.notifier.notify().map_err(|e| BusError::Event {
            service: format!("{}/wake", self.service),
            detail: format!("{e:?}"),
        })
    }

    /// Connects to subscribers that appeared since the last send (sending does this too).
    pub fn connect(&self) -> Result<(), BusError> {
        self.publisher
            .update_connections()
            .map_err(|e| BusError::Send {
                service: self.service.clone(),
                detail: format!("cannot update connections: {e:?}"),
            })
    }

    fn loan_err(&self, e: impl Debug) -> BusError {
        BusError::Loan {
            service: self.service.clone(),
            detail: format!("{e:?}"),
        }
    }

    fn finish(&self, sent: Result<usize, SendError>) -> Result<usize, BusError> {
        match sent {
            Ok(0) if self.delivery == Delivery::Lossless => Err(BusError::NoSubscriber {
                service: self.service.clone(),
            }),
            Ok(n) => Ok(n),
            Err(SendError::UnableToDeliver) => Err(BusError::DeliveryTimeout {
                service: self.service.clone(),
                timeout: self.send_timeout,
            }),
            Err(e) => Err(BusError::Send {
                service: self.service.clone(),
                detail: format!("{e:?}"),
            }),
        }
    }
}

impl<T: Batch> Outbox<T> {
    /// [`send_with`](Self::send_with) for a batch, without zeroing the whole 3–6 KiB slot:
    /// `fill` gets the same all-zero slot and writes the header and `entries[..count]`.
    ///
    /// A publisher's slots are reused, and only this outbox writes into them, so each slot
    /// still holds the batch last sent from it. The outbox remembers that batch's `count` per
    /// slot and zeroes only its header and those entries (a slot seen for the first time, or
    /// whose `fill` panicked, is zeroed whole). Entries beyond `count` thus stay zero on the
    /// wire, as bus-schema promises, for ~100 bytes of stores instead of 3–6 KiB when a batch
    /// is small; `fill` must not write beyond `count` (it would leave non-zero entries behind).
    pub fn send_batch(&self, fill: impl FnOnce(&mut T)) -> Result<usize, BusError> {
        let mut uninit = self.publisher.loan_uninit().map_err(|e| self.loan_err(e))?;
        let slot = uninit.payload_mut().as_mut_ptr();
        let key = slot as usize;
        // taken out while `fill` runs: a panic in it leaves the slot unknown (zeroed next time)
        let last = self.dirty.borrow_mut().remove(&key);
        // SAFETY: a slot in `dirty` holds the complete `T` last written into it by this outbox
        // (nobody else writes a publisher's slots; subscribers map them read-only), so it is
        // initialised; any other slot is zeroed whole, a valid `T` by `T: Message`. The slot
        // is exclusively ours until sent.
        let mut sample = unsafe {
            match last {
                Some(n) => (*slot).clear_front(n as usize),
                None => slot.write_bytes(0, 1),
            }
            uninit.assume_init()
        };
        let msg = sample.payload_mut();
        fill(msg);
        let used = msg.used() as u32;
        {
            let mut dirty = self.dirty.borrow_mut();
            if dirty.len() >= DIRTY_SLOTS_MAX {
                dirty.clear();
            }
            dirty.insert(key, used);
        }
        self.finish(sample.send())
    }
}

/// Receiving half of a topic: a subscriber plus a listener on the topic's wake service.
pub struct Inbox<T: Message> {
    service: String,
    subscriber: Subscriber<ipc::Service, T, ()>,
    listener: Listener<ipc::Service>,
}

impl<T: Message> Inbox<T> {
    /// Opens a subscriber on `T`'s topic of an existing run for an outside reader (a monitor,
    /// a recorder); it takes one of the [`OBSERVER_SLOTS`] ports. Its port is named
    /// [`OBSERVER_PORT_NAME`]: if it does not keep up with a lossless topic, the publishers
    /// drop samples for it alone (never for the fleet) instead of waiting for it.
    pub fn open(node: &Node<ipc::Service>, cfg: &BusConfig) -> Result<Self, BusError> {
        Self::build(node, cfg, Role::Opener, OBSERVER_PORT_NAME)
    }

    /// A subscriber of the fleet itself (the coordinator's or a robot's).
    pub(crate) fn create(
        node: &Node<ipc::Service>,
        cfg: &BusConfig,
        role: Role,
    ) -> Result<Self, BusError> {
        Self::build(node, cfg, role, FLEET_PORT_NAME)
    }

    fn build(
        node: &Node<ipc::Service>,
        cfg: &BusConfig,
        role: Role,
        port_name: &str,
    ) -> Result<Self, BusError> {
        let topic = T::TOPIC;
        let service = topic.service_name(&cfg.run_id);
        let pubsub = open_pubsub::<T>(node, cfg, topic, role)?;
        let wake = open_wake(node, cfg, topic, role)?;
        let port_err = |port: &'static str, detail: String| BusError::Port {
            port,
            service: service.clone(),
            detail,
        };
        let name = PortName::new(port_name)
            .map_err(|e| port_err("subscriber", format!("bad port name: {e:?}")))?;
        let subscriber = pubsub
            .subscriber_builder()
            .name(&name)
            .create()
            .map_err(|e| port_err("subscriber", format!("{e:?}")))?;
        let listener = wake
            .listener_builder()
            .create()
            .map_err(|e| port_err("listener", format!("{e:?}")))?;
        Ok(Self {
            service,
            subscriber,
            listener,
        })
    }

    /// The service name this inbox subscribes to.
    pub fn service(&self) -> &str {
        &self.service
    }

    /// Takes the oldest buffered message, copied out of shared memory.
    pub fn receive(&self) -> Result<Option<T>, BusError> {
        Ok(self.receive_sample()?.map(|s| *s.payload()))
    }

    /// Takes the oldest buffered message as a zero-copy sample (released when dropped).
    pub fn receive_sample(&self) -> Result<Option<Sample<ipc::Service, T, ()>>, BusError> {
        self.subscriber.receive().map_err(|e| BusError::Receive {
            service: self.service.clone(),
            detail: format!("{e:?}"),
        })
    }

    /// Calls `f` on up to `max` buffered messages in place (no copy); returns how many.
    pub fn drain(&self, max: usize, mut f: impl FnMut(&T)) -> Result<usize, BusError> {
        let mut n = 0;
        while n < max {
            match self.receive_sample()? {
                Some(sample) => {
                    f(sample.payload());
                    n += 1;
                }
                None => break,
            }
        }
        Ok(n)
    }

    /// As [`Inbox::drain`], with each message's sender: the iceoryx2 node id
    /// (`UniqueNodeId::value`) from the sample's header.
    pub fn drain_from(&self, max: usize, mut f: impl FnMut(u128, &T)) -> Result<usize, BusError> {
        let mut n = 0;
        while n < max {
            match self.receive_sample()? {
                Some(sample) => {
                    f(sample.header().node_id().value(), sample.payload());
                    n += 1;
                }
                None => break,
            }
        }
        Ok(n)
    }

    /// Whether a message is waiting (the cheap check a spinning loop polls).
    pub fn has_samples(&self) -> Result<bool, BusError> {
        self.subscriber
            .has_samples()
            .map_err(|e| BusError::Receive {
                service: self.service.clone(),
                detail: format!("{e:?}"),
            })
    }

    /// Connects to publishers that appeared since the last receive, so that lossless delivery
    /// from them is guaranteed from now on (receiving does this too).
    pub fn connect(&self) -> Result<(), BusError> {
        self.subscriber
            .update_connections()
            .map_err(|e| BusError::Receive {
                service: self.service.clone(),
                detail: format!("cannot update connections: {e:?}"),
            })
    }

    /// The wake listener, to attach to an iceoryx2 `WaitSet` or to block on directly.
    pub fn listener(&self) -> &Listener<ipc::Service> {
        &self.listener
    }

    /// Consumes pending wakeups without blocking; returns the number of notifications and
    /// whether one of them was [`EVENT_PEER_DEAD`].
    ///
    /// Call it when the `WaitSet` reports this listener, or it keeps reporting it.
    pub fn clear_wakeups(&self) -> Result<Wakeups, BusError> {
        let mut w = Wakeups::default();
        self.listener
            .try_wait(|a| w.add(a))
            .map_err(|e| self.event_err(e))?;
        Ok(w)
    }

    /// Blocks until a wakeup arrives or `timeout` passes, consuming the wakeups.
    ///
    /// A signal delivered meanwhile (e.g. SIGTERM, which the qfleet processes turn into a stop
    /// flag) ends the wait early with no wakeups, so the caller re-checks its flags; it is not
    /// an error.
    pub fn wait(&self, timeout: Duration) -> Result<Wakeups, BusError> {
        let mut w = Wakeups::default();
        match self.listener.timed_wait(|a| w.add(a), timeout) {
            Ok(_) | Err(ListenerWaitError::InterruptSignal) => Ok(w),
            Err(e) => Err(self.event_err(e)),
        }
    }

    fn event_err(&self, e: impl Debug) -> BusError {
        BusError::Event {
            service: format!("{}/wake", self.service),
            detail: format!("{e:?}"),
        }
    }
}

/// What a listener received: data notifications and peer-death notices.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Wakeups {
    /// Number of data notifications (several notifies may collapse into one).
    pub data: u64,
    /// A notifier of a dead process was found: run [`crate::check_nodes`].
    pub peer_dead: bool,
}

impl Wakeups {
    fn add(&mut self, a: EventActivation) {
        if a.id == EVENT_PEER_DEAD {
            self.peer_dead = true;
        } else {
            self.data += a.count.max(1);
        }
    }

    /// Whether anything at all arrived.
    pub fn any(&self) -> bool {
        self.data > 0 || self.peer_dead
    }
}
