//! A topic of the bus: what may travel on one (`Message`, `Batch`), the wake event ids, and the
//! typed halves that send and receive it.
//!
//! Split by job: `sizes` (the limits a topic's services are created with), `open` (port names,
//! opening or creating the services, iceoryx2's open errors in the bus's terms), `outbox` (the
//! sending half) and `inbox` (the receiving half). The sizes module is not called `limits`:
//! the crate already has a public [`limits`](mod@crate::limits) module (process-wide
//! resources: open files, memory), and the function that sizes a topic is
//! [`limits()`](fn@crate::limits) at the crate root.

use core::fmt::Debug;
use core::mem::offset_of;

use bus_schema::names::Topic;
use bus_schema::{
    Control, DiscoveryAck, DiscoveryRelay, FinalReport, Grant, HINT_BATCH_CAP, Intent,
    IntentHorizon, MergedHintBatch, PseudoTargetDiscovery, QHint, QHintBatch, Register, RobotState,
};
use iceoryx2::prelude::*;

mod inbox;
mod open;
mod outbox;
mod sizes;

pub use inbox::{Inbox, Wakeups};
pub(crate) use open::Role;
pub use open::{FLEET_PORT_NAME, OBSERVER_PORT_NAME};
pub use outbox::Outbox;
pub use sizes::{TopicLimits, control_buffer, limits};

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
