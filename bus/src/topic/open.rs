//! Opening a topic's services: port names, who creates and who only opens (`Role`), and
//! iceoryx2's open errors translated into the bus's.

use bus_schema::SCHEMA_VERSION;
use bus_schema::names::Topic;
use iceoryx2::prelude::*;
use iceoryx2::service::builder::event::{EventOpenError, EventOpenOrCreateError};
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::port_factory::{event, publish_subscribe};

use super::{EVENT_ID_MAX, EVENT_PEER_DEAD, Message, limits};
use crate::{BusConfig, BusError};

/// Port name of the fleet's own subscribers (the coordinator's and the robots'); an outside
/// reader's subscriber has another name, and a lossless publisher discards for it when its
/// buffer is full instead of waiting (see [`Outbox`](crate::Outbox)).
pub const FLEET_PORT_NAME: &str = "qfleet-fleet";

/// Port name of an outside reader's subscriber ([`Inbox::open`](crate::Inbox::open)).
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
        // coordinator still creates the last services), or a dead coordinator's service is
        // being removed right now (a restarted coordinator cleans up its predecessor while a
        // robot reopens: seen in a reliability test): not there yet, retried like a missing one
        E::DoesNotExist | E::HangsInCreation | E::IsMarkedForDestruction => {
            BusError::ServiceMissing {
                service: service.to_string(),
            }
        }
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
        // as for a publish-subscribe service
        E::DoesNotExist | E::HangsInCreation | E::IsMarkedForDestruction => {
            BusError::ServiceMissing {
                service: service.to_string(),
            }
        }
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
