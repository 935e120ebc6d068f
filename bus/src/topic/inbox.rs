//! The receiving half of a topic (`Inbox`) and what its wake listener received (`Wakeups`).

use core::fmt::Debug;
use std::time::Duration;

use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;

use super::open::{FLEET_PORT_NAME, OBSERVER_PORT_NAME, Role, open_pubsub, open_wake};
use super::{EVENT_PEER_DEAD, Message};
use crate::{BusConfig, BusError};

/// Receiving half of a topic: a subscriber plus a listener on the topic's wake service.
pub struct Inbox<T: Message> {
    service: String,
    subscriber: Subscriber<ipc::Service, T, ()>,
    listener: Listener<ipc::Service>,
}

impl<T: Message> Inbox<T> {
    /// Opens a subscriber on `T`'s topic of an existing run for an outside reader (a monitor,
    /// a recorder); it takes one of the [`OBSERVER_SLOTS`](crate::OBSERVER_SLOTS) ports. Its
    /// port is named [`OBSERVER_PORT_NAME`]: if it does not keep up with a lossless topic, the
    /// publishers drop samples for it alone (never for the fleet) instead of waiting for it.
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
