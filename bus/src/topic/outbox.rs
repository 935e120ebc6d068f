//! The sending half of a topic (`Outbox`) and the backpressure handler's tell of the fleet's
//! subscribers from outside readers (`FleetPorts`).

use core::fmt::Debug;
use std::cell::RefCell;
use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use bus_schema::names::Delivery;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::port::{BackpressureAction, BackpressureInfo, SendError as IoxSendError};
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe;

use super::open::{FLEET_PORT_NAME, Role, open_pubsub, open_wake};
use super::{Batch, EVENT_DATA, Message, limits};
use crate::{BusConfig, BusError, SendError};

/// Slots an [`Outbox`] remembers for [`Outbox::send_batch`]; more than any topic's data
/// segment has (a bound against an unexpected allocator, not a tuning knob).
const DIRTY_SLOTS_MAX: usize = 1 << 16;

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
    /// Lossless topics report [`SendError::NoSubscriber`] when nobody received it and
    /// [`SendError::DeliveryTimeout`] when a subscriber stayed full for the send timeout.
    pub fn send(&self, msg: &T) -> Result<usize, SendError> {
        let sample = self.publisher.loan_uninit().map_err(|e| self.loan_err(e))?;
        self.finish(sample.write_payload(*msg).send())
    }

    /// Loans a slot, zeroes it, lets `fill` write the message in place, and sends it.
    ///
    /// The zero-copy way to send the 3–6 KiB hint batches: nothing is built on the stack and
    /// copied. Same results as [`send`](Self::send).
    pub fn send_with(&self, fill: impl FnOnce(&mut T)) -> Result<usize, SendError> {
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

    /// Sends `msg` and then wakes the subscribers; a failed send is [`BusError::Send`].
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
        self.publisher.update_connections().map_err(|e| {
            BusError::from(SendError::Failed {
                service: self.service.clone(),
                detail: format!("cannot update connections: {e:?}"),
            })
        })
    }

    fn loan_err(&self, e: impl Debug) -> SendError {
        SendError::Loan {
            service: self.service.clone(),
            detail: format!("{e:?}"),
        }
    }

    fn finish(&self, sent: Result<usize, IoxSendError>) -> Result<usize, SendError> {
        match sent {
            Ok(0) if self.delivery == Delivery::Lossless => Err(SendError::NoSubscriber {
                service: self.service.clone(),
            }),
            Ok(n) => Ok(n),
            Err(IoxSendError::UnableToDeliver) => Err(SendError::DeliveryTimeout {
                service: self.service.clone(),
                timeout: self.send_timeout,
            }),
            Err(e) => Err(SendError::Failed {
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
    pub fn send_batch(&self, fill: impl FnOnce(&mut T)) -> Result<usize, SendError> {
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
