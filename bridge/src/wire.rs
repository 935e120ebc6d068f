//! The bytes on the Zenoh link: a 16-byte frame header, then either a bus-schema message as its
//! `#[repr(C)]` bytes or a JSON heartbeat.
//!
//! | bytes | field |
//! |---|---|
//! | 0 | [`Kind`]: 0 lossless data, 1 latest-wins data, 2 heartbeat, 3 goodbye |
//! | 1 | topic index in [`Topic::ALL`] (data frames; 0 otherwise) |
//! | 2 | flags: bit 0 [`FLAG_WAKE`] (the sender's bus woke the message's readers); other bits zero |
//! | 3..8 | zero |
//! | 8..16 | link sequence number, little-endian (lossless frames; 0 otherwise) |
//! | 16.. | payload: the message's bytes with their zero runs left out (below), or the JSON [`Heartbeat`] |
//!
//! Messages travel as their in-memory bytes: the join checks that both hosts speak the same
//! schema version and byte order, so the layouts of `bus-schema/README.md` hold on both ends.
//! A message's bytes go as runs ([`encode_zero_runs`]): `u16` zeros to skip, `u16` bytes that
//! follow, those bytes; again, up to the last non-zero byte (the rest are zeros). Batches are
//! fixed-size and mostly zeros past their `count` (a `MergedHintBatch` is 6 176 bytes): sealing
//! and sending only what they hold took the sealed cross-host loop from 1.21–1.23× the plain
//! one's p50 to BENCHMARKS.md's figure.
//! Every monotonic time in a message is moved onto the receiving host's clock on arrival
//! ([`Stamped::shift`]), so the coordinator's and the robots' latency figures stay meaningful.
//!
//! Which topics travel lossless on the link is the bridge's choice ([`link_kind`]), not always
//! the bus's: the shared grid's topics are latest-wins on a bus and lossless on the link. What a
//! decoded message may hold is checked before it reaches a bus ([`Checked`]).

use bus::Message;
use bus::bus_schema::{
    Control, Delivery, DiscoveryAck, DiscoveryRelay, FinalReport, GRANT_CAP, Grant, GridState,
    HORIZON_CELLS, HORIZON_RADIUS_CAP, Intent, IntentHorizon, MergedHintBatch,
    PseudoTargetDiscovery, QHintBatch, Register, RobotState, Topic,
};
use serde::{Deserialize, Serialize};

/// Bytes before the payload of every frame.
pub const HEADER: usize = 16;

/// What a frame carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A message of a lossless topic, numbered on the link and acknowledged by heartbeats.
    Lossless = 0,
    /// A message of a latest-wins topic: sent once, may be dropped.
    Latest = 1,
    /// Link state: acks, clock echo, robots gone (JSON [`Heartbeat`]).
    Heartbeat = 2,
    /// The sender is leaving (the run is over).
    Goodbye = 3,
}

/// Header flag: the sender's bus woke the readers of this message (a notified grant), so the
/// receiving host wakes its readers too; unflagged messages are read when they look.
pub const FLAG_WAKE: u8 = 1;

/// A frame header, decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// What follows.
    pub kind: Kind,
    /// The topic of a data frame.
    pub topic: Topic,
    /// The link sequence number of a lossless frame.
    pub seq: u64,
    /// [`FLAG_WAKE`] was set: wake the message's readers on this host.
    pub wake: bool,
}

/// How a topic's messages cross the link: as its bus delivers them, except the shared grid's.
///
/// `robot/intent`, `robot/horizon` and `coord/grant` are latest-wins on a bus (only the newest
/// matters, and a bus never drops the newest: a full buffer drops the oldest), but on the link
/// they travel **lossless** ([`crate::reliable`]). A latest-wins frame may be dropped whole —
/// the newest included — while the link is down or Zenoh's queue is full, and nothing in the
/// tick protocol asks again: a robot answers each grant once, the coordinator publishes each
/// tick once. A dropped grant or intent would hold the whole grid until the coordinator's
/// per-tick deadline (`--hang-ms`, raised past the host deadline with remote robots: 12 s)
/// made the robot hung; resent, it costs a resend period (300 ms) at worst. A late copy is
/// harmless on both ends: a robot answers only a grant newer than the last it answered, and
/// the coordinator drops an answer to an older tick as late.
pub const fn link_kind(topic: Topic) -> Kind {
    match topic {
        Topic::Intent | Topic::Horizon | Topic::Grant => Kind::Lossless,
        t => match t.delivery() {
            Delivery::Lossless => Kind::Lossless,
            Delivery::LatestWins => Kind::Latest,
        },
    }
}

/// Why a frame could not be read (a peer of another build, or garbage): dropped and counted.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// Shorter than the header.
    #[error("frame of {0} bytes is shorter than the {HEADER}-byte header")]
    Short(usize),
    /// Unknown kind byte.
    #[error("unknown frame kind {0}")]
    Kind(u8),
    /// Unknown topic byte.
    #[error("unknown topic index {0}")]
    Topic(u8),
    /// Flag bits this version does not know.
    #[error("unknown frame flags {0:#04x}")]
    Flags(u8),
    /// A decoded message holds a value it never holds when a qfleet process writes it.
    #[error("{topic:?} message with {what}")]
    Field {
        /// Topic of the message.
        topic: Topic,
        /// What is wrong.
        what: &'static str,
    },
    /// A heartbeat larger than [`MAX_HEARTBEAT`] or not a heartbeat.
    #[error("heartbeat of {0} bytes is too large or unreadable")]
    Heartbeat(usize),
    /// The payload does not decode into the topic's message (cut short, or past its end).
    #[error("{topic:?} payload of {got} bytes does not decode into its {want}-byte message")]
    Size {
        /// Topic of the frame.
        topic: Topic,
        /// Payload bytes received.
        got: usize,
        /// The message's size.
        want: usize,
    },
}

/// Index of `topic` in [`Topic::ALL`].
pub fn topic_index(topic: Topic) -> u8 {
    Topic::ALL.iter().position(|t| *t == topic).unwrap_or(0) as u8
}

/// Appends a frame header to `out` (which should be empty).
pub fn put_header(out: &mut Vec<u8>, kind: Kind, topic: Topic, seq: u64) {
    put_header_flagged(out, kind, topic, seq, false);
}

/// [`put_header`] with [`FLAG_WAKE`] set when `wake`.
pub fn put_header_flagged(out: &mut Vec<u8>, kind: Kind, topic: Topic, seq: u64, wake: bool) {
    out.push(kind as u8);
    out.push(topic_index(topic));
    out.push(if wake { FLAG_WAKE } else { 0 });
    out.extend_from_slice(&[0; 5]);
    out.extend_from_slice(&seq.to_le_bytes());
}

/// Reads a frame header; the payload is `&frame[HEADER..]`.
pub fn header(frame: &[u8]) -> Result<Header, FrameError> {
    if frame.len() < HEADER {
        return Err(FrameError::Short(frame.len()));
    }
    let kind = match frame[0] {
        0 => Kind::Lossless,
        1 => Kind::Latest,
        2 => Kind::Heartbeat,
        3 => Kind::Goodbye,
        k => return Err(FrameError::Kind(k)),
    };
    let topic = *Topic::ALL
        .get(frame[1] as usize)
        .ok_or(FrameError::Topic(frame[1]))?;
    if frame[2] & !FLAG_WAKE != 0 {
        return Err(FrameError::Flags(frame[2]));
    }
    let mut seq = [0u8; 8];
    seq.copy_from_slice(&frame[8..16]);
    Ok(Header {
        kind,
        topic,
        seq: u64::from_le_bytes(seq),
        wake: frame[2] & FLAG_WAKE != 0,
    })
}

/// A data frame for `msg`: header, then the message's bytes.
pub fn data_frame<T: Message>(msg: &T, seq: u64) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER + size_of::<T>());
    write_data_frame(&mut out, msg, seq);
    out
}

/// Writes [`data_frame`]`(msg, seq)` into `out` (cleared first; no allocation once `out` has
/// grown to the largest message), of the kind [`link_kind`] says.
pub fn write_data_frame<T: Message>(out: &mut Vec<u8>, msg: &T, seq: u64) {
    write_data_frame_as(out, link_kind(T::TOPIC), msg, seq, false);
}

/// Writes a data frame of `kind` for `msg` into `out` (cleared first), flagged [`FLAG_WAKE`]
/// when `wake`.
pub fn write_data_frame_as<T: Message>(
    out: &mut Vec<u8>,
    kind: Kind,
    msg: &T,
    seq: u64,
    wake: bool,
) {
    out.clear();
    put_header_flagged(out, kind, T::TOPIC, seq, wake);
    // SAFETY: `T: Message` is a `#[repr(C)]` bus-schema type whose padding is spelled out as
    // zeroed fields (checked by bus-schema's layout test), so all `size_of::<T>()` bytes are
    // initialised and may be read as `u8`.
    let bytes =
        unsafe { std::slice::from_raw_parts((msg as *const T).cast::<u8>(), size_of::<T>()) };
    encode_zero_runs(bytes, out);
}

/// Zero runs shorter than this stay inside the literal bytes (a token costs 4 bytes).
const MIN_ZERO_RUN: usize = 8;

/// Appends `bytes` to `out` as tokens: `u16` zeros to skip, `u16` literal length, the literal
/// bytes; trailing zeros are left out. Allocates nothing once `out` has grown.
pub fn encode_zero_runs(bytes: &[u8], out: &mut Vec<u8>) {
    let end = bytes.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
    let mut i = 0;
    while i < end {
        // zeros to skip (at most a token's worth)
        let mut z = 0;
        while i + z < end && bytes[i + z] == 0 && z < usize::from(u16::MAX) {
            z += 1;
        }
        // literal: up to a zero run long enough to be worth a token, or the end
        let start = i + z;
        let mut j = start;
        while j < end && j - start < usize::from(u16::MAX) {
            if bytes[j] == 0 {
                let run = bytes[j..end].iter().take_while(|&&b| b == 0).count();
                if run >= MIN_ZERO_RUN {
                    break;
                }
                j += run;
            } else {
                j += 1;
            }
        }
        let j = j.min(start + usize::from(u16::MAX)).min(end);
        out.extend_from_slice(&(z as u16).to_le_bytes());
        out.extend_from_slice(&((j - start) as u16).to_le_bytes());
        out.extend_from_slice(&bytes[start..j]);
        i = j;
    }
}

/// Decodes [`encode_zero_runs`]'s tokens into `dst` (every byte not named is zero); `None`
/// when the tokens are cut short or name bytes past its end.
pub fn decode_zero_runs(mut tokens: &[u8], dst: &mut [u8]) -> Option<()> {
    dst.fill(0);
    let mut at = 0usize;
    while !tokens.is_empty() {
        let (head, rest) = tokens.split_at_checked(4)?;
        let zeros = usize::from(u16::from_le_bytes([head[0], head[1]]));
        let lit = usize::from(u16::from_le_bytes([head[2], head[3]]));
        let (bytes, rest) = rest.split_at_checked(lit)?;
        at = at.checked_add(zeros)?;
        dst.get_mut(at..at.checked_add(lit)?)?
            .copy_from_slice(bytes);
        at += lit;
        tokens = rest;
    }
    Some(())
}

/// Decodes a payload into `dst` (e.g. a loaned shared-memory slot); tokens that do not fit the
/// message are an error.
pub fn read_into<T: Message>(payload: &[u8], dst: &mut T) -> Result<(), FrameError> {
    // SAFETY: `T: Message` guarantees every bit pattern of its integer/float fields is a valid
    // value (bus-schema types hold only integers, floats and arrays of them), so its bytes may
    // be written as `u8` through this exclusive reference.
    let bytes =
        unsafe { std::slice::from_raw_parts_mut((dst as *mut T).cast::<u8>(), size_of::<T>()) };
    decode_zero_runs(payload, bytes).ok_or(FrameError::Size {
        topic: T::TOPIC,
        got: payload.len(),
        want: size_of::<T>(),
    })
}

/// Moves one monotonic time by `delta` ns; 0 ("no time") stays 0.
fn shift_ns(t: &mut u64, delta: i64) {
    if *t != 0 {
        *t = t.saturating_add_signed(delta).max(1);
    }
}

/// A message whose monotonic times can be moved onto another host's clock.
pub trait Stamped: Message {
    /// Adds `delta` ns to every non-zero monotonic time the message carries.
    fn shift(&mut self, delta: i64);
}

macro_rules! stamped {
    ($($ty:ty => [$($field:ident),*]),* $(,)?) => {$(
        impl Stamped for $ty {
            fn shift(&mut self, delta: i64) {
                $(shift_ns(&mut self.$field, delta);)*
            }
        }
    )*};
}

stamped!(
    Register => [send_time_ns],
    RobotState => [send_time_ns],
    PseudoTargetDiscovery => [time_ns, send_time_ns],
    QHintBatch => [oldest_update_ns, send_time_ns],
    FinalReport => [send_time_ns],
    Control => [time_ns],
    DiscoveryAck => [time_ns],
    DiscoveryRelay => [origin_ns, send_time_ns],
    Intent => [send_time_ns],
    IntentHorizon => [send_time_ns],
    Grant => [send_time_ns],
);

impl Stamped for MergedHintBatch {
    fn shift(&mut self, delta: i64) {
        shift_ns(&mut self.oldest_origin_ns, delta);
        shift_ns(&mut self.send_time_ns, delta);
        let n = (self.count as usize).min(self.origin_ns.len());
        for t in &mut self.origin_ns[..n] {
            shift_ns(t, delta);
        }
    }
}

/// What a message decoded from the network may hold, checked before it is written into a bus
/// (a peer that holds the link's keys can still send anything; its messages are taken only in
/// the shapes a qfleet process writes them). Which host may speak for which robot is checked
/// where the message lands (the hub takes a robot's messages only from the host that runs it).
pub trait Checked {
    /// `Ok` when every field is one a qfleet process of a fleet of `fleet` robots writes.
    fn check(&self, fleet: u32) -> Result<(), FrameError>;
}

/// The coordinator validates these itself on arrival (admission, sequence numbers, counts
/// clamped to their arrays); the bridge checks only that their bytes fit the message.
macro_rules! checked_by_the_coordinator {
    ($($ty:ty),* $(,)?) => {$(
        impl Checked for $ty {
            fn check(&self, _fleet: u32) -> Result<(), FrameError> {
                Ok(())
            }
        }
    )*};
}

checked_by_the_coordinator!(
    Register,
    RobotState,
    PseudoTargetDiscovery,
    QHintBatch,
    FinalReport,
    Control,
    MergedHintBatch,
    DiscoveryAck,
    DiscoveryRelay,
);

fn field(topic: Topic, what: &'static str) -> Result<(), FrameError> {
    Err(FrameError::Field { topic, what })
}

impl Checked for Intent {
    /// A robot of the fleet, 1 to 5 distinct move codes and nothing after them.
    fn check(&self, fleet: u32) -> Result<(), FrameError> {
        let n = usize::from(self.count);
        if self.robot_id >= fleet {
            return field(Topic::Intent, "a robot id outside the fleet");
        }
        if !(1..=self.ranked.len()).contains(&n) {
            return field(Topic::Intent, "a move count outside 1..=5");
        }
        if mapf::Intent::from_bytes(&self.ranked[..n]).is_err() {
            return field(Topic::Intent, "a move code past 4 or named twice");
        }
        if self.ranked[n..].iter().any(|&b| b != 0) || self._pad0 != [0; 6] {
            return field(Topic::Intent, "bytes past its moves");
        }
        Ok(())
    }
}

/// Whether a packed horizon ranking is one a robot writes (`mapf::horizon::unpack`, the
/// coordinator's own reading): move codes only, each at most once, nothing after the end.
pub fn packed_ranking_ok(bits: u16) -> bool {
    mapf::horizon::unpack(bits).is_ok()
}

impl Checked for IntentHorizon {
    /// A robot of the fleet, a radius ≤ [`HORIZON_RADIUS_CAP`], a ranking a robot writes at
    /// every cell of its diamond and nothing past it.
    fn check(&self, fleet: u32) -> Result<(), FrameError> {
        if self.robot_id >= fleet {
            return field(Topic::Horizon, "a robot id outside the fleet");
        }
        if self.radius > HORIZON_RADIUS_CAP {
            return field(Topic::Horizon, "a radius past 8");
        }
        let r = usize::from(self.radius);
        let cells = (2 * r * r + 2 * r + 1).min(HORIZON_CELLS);
        if !self.ranked[..cells].iter().all(|&b| packed_ranking_ok(b)) {
            return field(
                Topic::Horizon,
                "a ranking that is no list of distinct moves",
            );
        }
        if self.ranked[cells..].iter().any(|&b| b != 0)
            || self._pad0 != [0; 3]
            || self._pad1 != [0; 6]
        {
            return field(Topic::Horizon, "bytes past its diamond");
        }
        Ok(())
    }
}

impl Checked for Grant {
    /// At most the fleet's robots, a known state, presence 0 or 1, nothing past its robots.
    fn check(&self, fleet: u32) -> Result<(), FrameError> {
        let n = self.robots as usize;
        if self.robots > fleet || n > GRANT_CAP {
            return field(Topic::Grant, "more robots than the fleet");
        }
        if GridState::try_from(self.state).is_err() {
            return field(Topic::Grant, "an unknown grid state");
        }
        if self.present[..n].iter().any(|&p| p > 1) {
            return field(Topic::Grant, "a presence other than 0 or 1");
        }
        let past = self.present[n..].iter().any(|&p| p != 0)
            || self.cell_x[n..].iter().any(|&c| c != 0)
            || self.cell_y[n..].iter().any(|&c| c != 0)
            || self._pad0 != [0; 7];
        if past {
            return field(Topic::Grant, "bytes past its robots");
        }
        Ok(())
    }
}

/// What each side tells the other every heartbeat period (JSON in a [`Kind::Heartbeat`] frame).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Heartbeat {
    /// The sender's monotonic time when it sent this.
    pub t_ns: u64,
    /// The `t_ns` of the last heartbeat the sender received (0 = none yet): a round trip.
    pub echo_ns: u64,
    /// How long the sender held that heartbeat before echoing it.
    pub hold_ns: u64,
    /// Lossless frames of the receiver's stream the sender has in order: seq `< acked` arrived.
    pub acked: u64,
    /// Lossless frames the sender has numbered so far (its next seq).
    pub sent: u64,
    /// Robots of the joining host whose process is gone (joining side only).
    pub gone: Vec<u32>,
}

impl Heartbeat {
    /// A heartbeat sent at `t_ns` that echoes `echo` (the `t_ns` of the last heartbeat
    /// received and when it arrived, both 0 before the first), with the sender's stream
    /// positions and gone robots.
    pub fn at(t_ns: u64, echo: (u64, u64), acked: u64, sent: u64, gone: Vec<u32>) -> Self {
        Heartbeat {
            t_ns,
            echo_ns: echo.0,
            hold_ns: if echo.0 == 0 {
                0
            } else {
                t_ns.saturating_sub(echo.1)
            },
            acked,
            sent,
            gone,
        }
    }
}

/// Largest heartbeat payload read: a real one is under 100 bytes plus a few per gone robot
/// (at most `bus::MAX_ROBOTS` of them); anything larger is dropped before it is parsed.
pub const MAX_HEARTBEAT: usize = 4096;

/// Reads a heartbeat payload (`&frame[HEADER..]`), refusing one larger than [`MAX_HEARTBEAT`]
/// or with more gone robots than a fleet has.
pub fn read_heartbeat(payload: &[u8]) -> Result<Heartbeat, FrameError> {
    if payload.len() > MAX_HEARTBEAT {
        return Err(FrameError::Heartbeat(payload.len()));
    }
    match serde_json::from_slice::<Heartbeat>(payload) {
        Ok(hb) if hb.gone.len() <= bus::MAX_ROBOTS as usize => Ok(hb),
        _ => Err(FrameError::Heartbeat(payload.len())),
    }
}

/// A heartbeat frame.
pub fn heartbeat_frame(hb: &Heartbeat) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER + 96);
    write_heartbeat(&mut out, hb);
    out
}

/// Writes [`heartbeat_frame`]`(hb)` into `out` (cleared first).
pub fn write_heartbeat(out: &mut Vec<u8>, hb: &Heartbeat) {
    out.clear();
    put_header(out, Kind::Heartbeat, Topic::Register, 0);
    // a plain struct of integers always serialises
    let _ = serde_json::to_writer(&mut *out, hb);
}

/// A goodbye frame.
pub fn goodbye_frame() -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER);
    put_header(&mut out, Kind::Goodbye, Topic::Register, 0);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Whatever the bytes (mostly zeros, like batches past their count, or dense), they
        /// come back exactly, and never take more than 4 bytes per 8 of message over their size.
        #[test]
        fn zero_runs_round_trip(
            bytes in prop::collection::vec(prop_oneof![4 => Just(0u8), 1 => any::<u8>()], 0..9000)
        ) {
            let mut out = Vec::new();
            encode_zero_runs(&bytes, &mut out);
            prop_assert!(out.len() <= bytes.len() + 4 + bytes.len() / 2);
            let mut back = vec![0xAAu8; bytes.len()];
            prop_assert!(decode_zero_runs(&out, &mut back).is_some());
            prop_assert_eq!(back, bytes);
        }

        /// Any bytes a peer sends decode or are refused: never a panic, never a write past the
        /// message.
        #[test]
        fn any_tokens_decode_or_are_refused(tokens in prop::collection::vec(any::<u8>(), 0..64)) {
            let mut dst = [0u8; 16];
            let _ = decode_zero_runs(&tokens, &mut dst);
        }
    }

    #[test]
    fn a_batch_travels_as_the_entries_it_holds() {
        let mut m = MergedHintBatch::ZEROED;
        m.count = 2;
        for (i, e) in m.entries.iter_mut().take(2).enumerate() {
            e.cell = 10 + i as u32;
            e.q = 0.5;
        }
        m.origin_robot[1] = 3;
        let f = data_frame(&m, 1);
        assert!(
            f.len() < HEADER + 80,
            "{} bytes for a 2-entry batch",
            f.len()
        );
        let mut back = MergedHintBatch::ZEROED;
        read_into(&f[HEADER..], &mut back).unwrap();
        assert_eq!(back, m);
        // tokens naming bytes past the message are refused, not written
        let mut r = Register::ZEROED;
        let past = [0xFF, 0xFF, 1, 0, 7];
        assert!(read_into(&past, &mut r).is_err());
    }

    #[test]
    fn a_heartbeat_echoes_the_last_one_with_how_long_it_was_held() {
        let first = Heartbeat::at(1_000, (0, 0), 3, 5, vec![2]);
        assert_eq!(
            (first.echo_ns, first.hold_ns),
            (0, 0),
            "nothing to echo yet"
        );
        assert_eq!((first.acked, first.sent, first.gone), (3, 5, vec![2]));
        let hb = Heartbeat::at(9_000, (700, 8_250), 0, 0, Vec::new());
        assert_eq!((hb.t_ns, hb.echo_ns, hb.hold_ns), (9_000, 700, 750));
        // a clock read before the arrival (never on one host) holds for 0, not a wrap
        assert_eq!(
            Heartbeat::at(8_000, (700, 8_250), 0, 0, Vec::new()).hold_ns,
            0
        );
    }

    #[test]
    fn a_message_survives_the_frame_round_trip() {
        let d = PseudoTargetDiscovery {
            robot_id: 3,
            goal_id: 1,
            cell_x: 7,
            cell_y: 9,
            value: 0.25,
            seq: 41,
            time_ns: 1000,
            episode: 5,
            send_time_ns: 2000,
            ..PseudoTargetDiscovery::ZEROED
        };
        let f = data_frame(&d, 77);
        let h = header(&f).unwrap();
        assert_eq!(
            (h.kind, h.topic, h.seq),
            (Kind::Lossless, Topic::Discovery, 77)
        );
        let mut back = PseudoTargetDiscovery::ZEROED;
        read_into(&f[HEADER..], &mut back).unwrap();
        assert_eq!(back, d);
    }

    #[test]
    fn latest_wins_topics_travel_as_latest_frames() {
        let f = data_frame(&RobotState::ZEROED, 0);
        assert_eq!(header(&f).unwrap().kind, Kind::Latest);
        assert_eq!(header(&f).unwrap().topic, Topic::RobotState);
    }

    #[test]
    fn bad_frames_are_errors_not_panics() {
        assert_eq!(header(&[0; 3]), Err(FrameError::Short(3)));
        assert_eq!(header(&[9; 16]), Err(FrameError::Kind(9)));
        let mut f = vec![0u8; 16];
        f[1] = 200;
        assert_eq!(header(&f), Err(FrameError::Topic(200)));
        let mut r = Register::ZEROED;
        assert!(matches!(
            read_into(&[1, 2, 3], &mut r),
            Err(FrameError::Size { got: 3, .. })
        ));
    }

    #[test]
    fn shifting_moves_every_time_but_keeps_zero_as_no_time() {
        let mut m = MergedHintBatch::ZEROED;
        m.count = 2;
        m.origin_ns[0] = 100;
        m.origin_ns[1] = 0;
        m.origin_ns[2] = 500; // beyond count: untouched
        m.send_time_ns = 1000;
        m.shift(-50);
        assert_eq!(
            (m.origin_ns[0], m.origin_ns[1], m.origin_ns[2]),
            (50, 0, 500)
        );
        assert_eq!((m.send_time_ns, m.oldest_origin_ns), (950, 0));
        let mut c = Control {
            time_ns: 10,
            ..Control::ZEROED
        };
        c.shift(-100);
        assert_eq!(c.time_ns, 1, "a time never becomes 0 (= no time) or wraps");
    }

    #[test]
    fn a_heartbeat_round_trips_through_json() {
        let hb = Heartbeat {
            t_ns: 5,
            acked: 3,
            gone: vec![4],
            ..Heartbeat::default()
        };
        let f = heartbeat_frame(&hb);
        assert_eq!(header(&f).unwrap().kind, Kind::Heartbeat);
        let back: Heartbeat = serde_json::from_slice(&f[HEADER..]).unwrap();
        assert_eq!(back, hb);
        assert_eq!(read_heartbeat(&f[HEADER..]), Ok(hb));
    }

    #[test]
    fn a_huge_heartbeat_is_refused_before_it_is_parsed() {
        // a `gone` list of a million ids, as a stranger would send to grow host A's memory
        let hb = Heartbeat {
            gone: (0..1_000_000).collect(),
            ..Heartbeat::default()
        };
        let f = heartbeat_frame(&hb);
        assert!(f.len() > MAX_HEARTBEAT);
        assert!(matches!(
            read_heartbeat(&f[HEADER..]),
            Err(FrameError::Heartbeat(_))
        ));
        // small in bytes but more gone robots than any fleet: refused too
        let mut f = Vec::new();
        put_header(&mut f, Kind::Heartbeat, Topic::Register, 0);
        f.extend_from_slice(
            b"{\"t_ns\":1,\"echo_ns\":0,\"hold_ns\":0,\"acked\":0,\"sent\":0,\"gone\":[",
        );
        f.extend_from_slice(b"1");
        for _ in 0..300 {
            f.extend_from_slice(b",1");
        }
        f.extend_from_slice(b"]}");
        assert!(f.len() - HEADER <= MAX_HEARTBEAT);
        assert!(read_heartbeat(&f[HEADER..]).is_err());
        assert!(read_heartbeat(b"not json").is_err());
    }
    #[test]
    fn the_shared_grids_topics_cross_lossless_the_others_as_their_bus_delivers() {
        for t in Topic::ALL {
            let want = match t {
                Topic::Intent | Topic::Horizon | Topic::Grant => Kind::Lossless,
                t if t.delivery() == Delivery::Lossless => Kind::Lossless,
                _ => Kind::Latest,
            };
            assert_eq!(link_kind(t), want, "{t:?}");
        }
        let f = data_frame(&Grant::ZEROED, 3);
        assert_eq!(
            (header(&f).unwrap().kind, header(&f).unwrap().seq),
            (Kind::Lossless, 3)
        );
    }

    #[test]
    fn the_wake_flag_round_trips_and_unknown_flags_are_refused() {
        let mut f = Vec::new();
        write_data_frame_as(&mut f, Kind::Lossless, &Grant::ZEROED, 9, true);
        let h = header(&f).unwrap();
        assert!(h.wake && h.topic == Topic::Grant && h.seq == 9, "{h:?}");
        assert!(!header(&data_frame(&Grant::ZEROED, 9)).unwrap().wake);
        for bad in [2u8, 4, 0x80, 0xFF] {
            f[2] = bad;
            assert_eq!(header(&f), Err(FrameError::Flags(bad)));
        }
    }

    fn intent() -> Intent {
        Intent {
            robot_id: 3,
            tick: 7,
            cell_x: 4,
            cell_y: 5,
            count: 3,
            ranked: [2, 0, 4, 0, 0],
            ..Intent::ZEROED
        }
    }

    /// Decodes `m` as a peer's frame would arrive, then checks it against a fleet of 4.
    fn arrives<T: Message + Checked + Default>(m: &T) -> Result<(), FrameError> {
        let f = data_frame(m, 0);
        let mut back = T::default();
        read_into(&f[HEADER..], &mut back)?;
        back.check(4)
    }

    fn refused<T: Message + Checked + Default>(m: &T) -> bool {
        matches!(arrives(m), Err(FrameError::Field { .. }))
    }

    #[test]
    fn an_intent_is_taken_only_as_a_robot_writes_it() {
        assert_eq!(arrives(&intent()), Ok(()));
        let five = Intent {
            count: 5,
            ranked: [4, 3, 2, 1, 0],
            ..intent()
        };
        assert_eq!(arrives(&five), Ok(()));
        let cases: [(&str, Intent); 7] = [
            (
                "a robot outside the fleet",
                Intent {
                    robot_id: 4,
                    ..intent()
                },
            ),
            (
                "no move",
                Intent {
                    count: 0,
                    ranked: [0; 5],
                    ..intent()
                },
            ),
            (
                "more moves than there are",
                Intent {
                    count: 6,
                    ..intent()
                },
            ),
            (
                "a move code past 4",
                Intent {
                    ranked: [2, 5, 4, 0, 0],
                    ..intent()
                },
            ),
            (
                "a move named twice",
                Intent {
                    ranked: [2, 2, 4, 0, 0],
                    ..intent()
                },
            ),
            (
                "a move past the count",
                Intent {
                    ranked: [2, 0, 4, 1, 0],
                    ..intent()
                },
            ),
            (
                "padding",
                Intent {
                    _pad0: [0, 0, 1, 0, 0, 0],
                    ..intent()
                },
            ),
        ];
        for (what, m) in cases {
            assert!(refused(&m), "{what}: {m:?}");
        }
    }

    fn horizon(radius: u8) -> IntentHorizon {
        let mut h = IntentHorizon {
            robot_id: 2,
            tick: 9,
            radius,
            ..IntentHorizon::ZEROED
        };
        let r = usize::from(radius);
        // wait, then right, then up: (0+1) | (2+1) << 3 | (1+1) << 6
        for x in &mut h.ranked[..2 * r * r + 2 * r + 1] {
            *x = 1 | 3 << 3 | 2 << 6;
        }
        h
    }

    #[test]
    fn packed_rankings_are_move_codes_each_once_with_nothing_after_the_end() {
        assert!(packed_ranking_ok(0), "no preference");
        assert!(packed_ranking_ok(1 | 3 << 3 | 2 << 6));
        assert!(packed_ranking_ok(5 | 4 << 3 | 3 << 6 | 2 << 9 | 1 << 12));
        assert!(!packed_ranking_ok(6), "code 5");
        assert!(!packed_ranking_ok(7 << 3 | 1), "code 6");
        assert!(!packed_ranking_ok(1 | 1 << 3), "wait twice");
        assert!(!packed_ranking_ok(1 | 1 << 9), "a group after the end");
        assert!(!packed_ranking_ok(1 << 15), "the 16th bit");
    }

    #[test]
    fn a_horizon_is_taken_only_as_a_robot_writes_it() {
        for r in [0, 1, 8] {
            assert_eq!(arrives(&horizon(r)), Ok(()), "radius {r}");
        }
        let mut past_diamond = horizon(1);
        past_diamond.ranked[5] = 1;
        let mut bad_ranking = horizon(2);
        bad_ranking.ranked[12] = 6;
        let cases: [(&str, IntentHorizon); 5] = [
            (
                "a robot outside the fleet",
                IntentHorizon {
                    robot_id: 9,
                    ..horizon(1)
                },
            ),
            (
                "a radius past the cap",
                IntentHorizon {
                    radius: 9,
                    ..horizon(1)
                },
            ),
            ("a ranking past the diamond", past_diamond),
            ("a ranking that is no list of moves", bad_ranking),
            (
                "padding",
                IntentHorizon {
                    _pad1: [0, 0, 0, 0, 0, 9],
                    ..horizon(1)
                },
            ),
        ];
        for (what, m) in cases {
            assert!(refused(&m), "{what}");
        }
    }

    fn grant() -> Grant {
        let mut g = Grant {
            tick: 12,
            robots: 3,
            state: GridState::Moving.as_u8(),
            seq: 12,
            ..Grant::ZEROED
        };
        for i in 0..3 {
            g.cell_x[i] = 10 + i as u16;
            g.cell_y[i] = 1;
            g.present[i] = u8::from(i != 1);
        }
        g
    }

    #[test]
    fn a_grant_is_taken_only_as_the_coordinator_writes_it() {
        assert_eq!(arrives(&grant()), Ok(()));
        assert_eq!(
            arrives(&Grant {
                state: GridState::Ended.as_u8(),
                robots: 4,
                ..grant()
            }),
            Ok(())
        );
        let mut present_past = grant();
        present_past.present[3] = 1;
        let mut cell_past = grant();
        cell_past.cell_x[200] = 1;
        let mut two = grant();
        two.present[0] = 2;
        let cases: [(&str, Grant); 6] = [
            (
                "more robots than the fleet",
                Grant {
                    robots: 5,
                    ..grant()
                },
            ),
            (
                "an unknown state",
                Grant {
                    state: 3,
                    ..grant()
                },
            ),
            ("a presence of 2", two),
            ("a robot present past its count", present_past),
            ("a cell past its count", cell_past),
            (
                "padding",
                Grant {
                    _pad0: [1, 0, 0, 0, 0, 0, 0],
                    ..grant()
                },
            ),
        ];
        for (what, m) in cases {
            assert!(refused(&m), "{what}");
        }
        // a fleet of the largest size: every entry may be used, none past it
        let mut full = grant();
        full.robots = GRANT_CAP as u32;
        full.present = [1; GRANT_CAP];
        assert_eq!(full.check(GRANT_CAP as u32), Ok(()));
        assert!(full.check(GRANT_CAP as u32 - 1).is_err());
    }
}
