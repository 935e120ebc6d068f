//! Which port carries each topic on each side of the link, so the bridge loops are written once
//! per direction instead of once per topic.
//!
//! Every topic crosses, the shared grid's included (`robot/intent`, `robot/horizon`,
//! `coord/grant`); how each travels on the link is [`crate::wire::link_kind`]'s choice.

use bus::bus_schema::{
    Control, DiscoveryAck, DiscoveryRelay, FinalReport, Grant, Intent, IntentHorizon,
    MergedHintBatch, PseudoTargetDiscovery, QHintBatch, Register, RobotState,
};
use bus::{CoordinatorBus, Inbox, Outbox, RobotBus};

use crate::wire::{Checked, Stamped};

/// A robot→coordinator message: read from the joining host's coordinator stand-in, written by
/// the hub's proxy of the sending robot.
pub trait FromRobot: Stamped + Checked + Default {
    /// The robot that sent it.
    fn robot_id(&self) -> u32;
    /// Its send time (0 = none).
    fn send_ns(&self) -> u64;
    /// Where the joining host reads it.
    fn inbox(bus: &CoordinatorBus) -> &Inbox<Self>;
    /// Where the hub writes it.
    fn outbox(bus: &RobotBus) -> &Outbox<Self>;
}

/// A coordinator→robot message: read by the hub's proxies, written by the joining host's
/// coordinator stand-in.
pub trait ToRobot: Stamped + Checked + Default {
    /// Its send time (0 = none).
    fn send_ns(&self) -> u64;
    /// Where the hub reads it.
    fn inbox(bus: &RobotBus) -> &Inbox<Self>;
    /// Where the joining host writes it.
    fn outbox(bus: &CoordinatorBus) -> &Outbox<Self>;
}

macro_rules! from_robot {
    ($($ty:ty => $port:ident, $time:ident;)*) => {$(
        impl FromRobot for $ty {
            fn robot_id(&self) -> u32 { self.robot_id }
            fn send_ns(&self) -> u64 { self.$time }
            fn inbox(bus: &CoordinatorBus) -> &Inbox<Self> { &bus.$port }
            fn outbox(bus: &RobotBus) -> &Outbox<Self> { &bus.$port }
        }
    )*};
}

macro_rules! to_robot {
    ($($ty:ty => $port:ident, $time:ident;)*) => {$(
        impl ToRobot for $ty {
            fn send_ns(&self) -> u64 { self.$time }
            fn inbox(bus: &RobotBus) -> &Inbox<Self> { &bus.$port }
            fn outbox(bus: &CoordinatorBus) -> &Outbox<Self> { &bus.$port }
        }
    )*};
}

from_robot! {
    Register => register, send_time_ns;
    RobotState => state, send_time_ns;
    PseudoTargetDiscovery => discovery, send_time_ns;
    QHintBatch => hints, send_time_ns;
    FinalReport => report, send_time_ns;
    Intent => intent, send_time_ns;
    IntentHorizon => horizon, send_time_ns;
}

to_robot! {
    Control => control, time_ns;
    MergedHintBatch => merged, send_time_ns;
    DiscoveryAck => ack, time_ns;
    DiscoveryRelay => relay, send_time_ns;
    Grant => grant, send_time_ns;
}
