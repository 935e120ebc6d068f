//! Joining a live run from outside: a monitor, a recorder, a test.
//!
//! An outside reader must neither disturb the run nor take a slot the run needs:
//!
//! 1. **Wait for the services, then create the node.** A node in a run's prefix before the
//!    coordinator has created the services makes `qfleet run` see a live process of that run
//!    and refuse the run id. [`Observer::join`] polls for every topic's service without a node
//!    of its own, and creates its node only once they all exist.
//! 2. **Its own slots.** Every service admits [`OBSERVER_SLOTS`] nodes and ports beyond the
//!    fleet and its restart spares; `join` counts the live observers (nodes named
//!    `qfleet-observer-…`) and refuses when they are all taken, so a restarted robot or
//!    coordinator always finds its slot. (A process that ignores this can still take spares:
//!    it runs as the same user, who can do anything to the run — see the threat model.)
//! 3. **Never stalls the run.** Its subscribers are named `qfleet-observer`: when one of them
//!    lags on a lossless topic, the publishers drop samples for it alone ([`crate::Outbox`]).
//!    Latest-wins topics drop the oldest sample anyway.

use std::time::{Duration, Instant};

use bus_schema::names::Topic;
use iceoryx2::prelude::*;
use iceoryx2::service::messaging_pattern::MessagingPattern;

use crate::config::OBSERVER_SLOTS;
use crate::liveness::check_nodes;
use crate::topic::{Inbox, Message};
use crate::{BusConfig, BusError};

/// Node name prefix of outside readers.
pub const OBSERVER_NODE_PREFIX: &str = "qfleet-observer-";

/// An outside reader's node in a live run (see the module docs for the rules it follows).
pub struct Observer {
    config: BusConfig,
    node: Node<ipc::Service>,
}

impl Observer {
    /// Waits up to `wait` for the run's services, checks that an observer slot is free, and
    /// creates the node `qfleet-observer-<name>`.
    ///
    /// `cfg` must describe the run (same run id and fleet size as its launcher used).
    pub fn join(cfg: &BusConfig, name: &str, wait: Duration) -> Result<Self, BusError> {
        let config = cfg.iceoryx_config()?;
        let deadline = Instant::now() + wait;
        for topic in Topic::ALL {
            let service = topic.service_name(&cfg.run_id);
            let sname = ServiceName::new(&service).map_err(|e| BusError::Service {
                service: service.clone(),
                detail: format!("invalid service name: {e:?}"),
            })?;
            loop {
                let exists =
                    ipc::Service::does_exist(&sname, &config, MessagingPattern::PublishSubscribe)
                        .map_err(|e| BusError::Service {
                        service: service.clone(),
                        detail: format!("{e:?}"),
                    })?;
                if exists {
                    break;
                }
                if Instant::now() >= deadline {
                    return Err(BusError::Timeout {
                        what: format!("run {} to create {service:?}", cfg.run_id),
                        timeout: wait,
                    });
                }
                std::thread::sleep(Duration::from_millis(20));
            }
        }
        let observers = check_nodes(cfg, false)?
            .alive()
            .filter(|n| n.name.starts_with(OBSERVER_NODE_PREFIX))
            .count();
        if observers >= OBSERVER_SLOTS as usize {
            return Err(BusError::NoObserverSlot {
                run_id: cfg.run_id.clone(),
                slots: OBSERVER_SLOTS,
            });
        }
        let node = cfg.create_node(&format!("{OBSERVER_NODE_PREFIX}{name}"))?;
        Ok(Self {
            config: cfg.clone(),
            node,
        })
    }

    /// A subscriber on `T`'s topic (an observer port: dropped for when it lags).
    pub fn inbox<T: Message>(&self) -> Result<Inbox<T>, BusError> {
        Inbox::open(&self.node, &self.config)
    }

    /// The observer's iceoryx2 node.
    pub fn node(&self) -> &Node<ipc::Service> {
        &self.node
    }

    /// The run's configuration.
    pub fn config(&self) -> &BusConfig {
        &self.config
    }
}
