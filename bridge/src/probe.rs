//! The front door's probe (issue 36, item 3): before a joining host opens its Zenoh session it
//! proves the join secret to the front door, so that a wrong secret is told apart from a dead
//! host. Zenoh's user–password check refuses a wrong password by closing the link, which the
//! joining side cannot tell from a host that is not there; the door can answer plainly.
//!
//! The exchange, on a TCP connection of its own to the `--listen` address: the joining host
//! sends [`MAGIC`]; the door answers a random nonce of [`NONCE_BYTES`]; the joining host sends
//! [`Secret::door_proof`] of it; the door answers one byte, [`ACCEPTED`] or [`REFUSED`], and
//! closes. The secret never crosses the wire. [`MAGIC`] cannot start a Zenoh TCP stream (its
//! first two bytes would announce an 18 001-byte first batch; a Zenoh handshake is a few
//! dozen bytes), so the door tells a probe from a session by its first bytes. A door that does
//! not know probes relays it to Zenoh, which closes it: that is [`Probe::NoAnswer`], and the
//! join goes on as before.
//!
//! After [`ACCEPTED`] the door may add two bytes, big-endian: the port of the hub's **direct**
//! listener on the same address, which the door has just opened to this host's source
//! ([`crate::admit`]). The joining host then opens its Zenoh session there, without the door's
//! relay hop. A door without a direct listener (or an older one) sends the verdict alone, and
//! an older joining host reads the verdict alone: both go through the relay, as before.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::Duration;

use crate::seal::Secret;

/// What a probe starts with.
pub const MAGIC: [u8; 8] = *b"QFPROBE1";

/// The door's nonce, in bytes.
pub const NONCE_BYTES: usize = 32;

/// The proof's length, in bytes.
pub const PROOF_BYTES: usize = 32;

/// The door's answer to a proof of the run's secret.
pub const ACCEPTED: u8 = b'Y';

/// The door's answer to a proof of another secret.
pub const REFUSED: u8 = b'N';

/// How long a joining host gives the probe in all (the door is one round trip away).
pub const PROBE_WITHIN: Duration = Duration::from_secs(3);

/// What a probe learned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Probe {
    /// The door checked the proof: this host holds the run's secret.
    Accepted,
    /// The door checked the proof: this host's secret is not the run's.
    Refused,
    /// No answer (the host is unreachable, or its door knows no probes): the Zenoh connection
    /// says what it can, as before probes.
    NoAnswer,
    /// The host refused the connection: nothing listens there, or not yet (a `qfleet join`
    /// started before the run's hub is up). Worth asking again while the join may wait.
    NotListening,
}

impl Probe {
    /// The probe's outcome from the door's one-byte answer (`None`: none came).
    pub fn of_answer(answer: Option<u8>) -> Probe {
        match answer {
            Some(ACCEPTED) => Probe::Accepted,
            Some(REFUSED) => Probe::Refused,
            _ => Probe::NoAnswer,
        }
    }
}

/// Where the first bytes of a connection to the door stand: enough of them to tell a probe.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Opening {
    /// They are [`MAGIC`]: answer the probe.
    Probe,
    /// They cannot start [`MAGIC`]: relay to Zenoh.
    Session,
    /// A prefix of [`MAGIC`] so far: wait for more.
    Undecided,
}

/// Tells a probe from a Zenoh session by the bytes `first` seen so far.
pub fn opening(first: &[u8]) -> Opening {
    let n = first.len().min(MAGIC.len());
    if first[..n] != MAGIC[..n] {
        Opening::Session
    } else if n == MAGIC.len() {
        Opening::Probe
    } else {
        Opening::Undecided
    }
}

/// Probes the door at `door` with `secret`, giving up after `within` per step; never fails:
/// whatever goes wrong is [`Probe::NoAnswer`].
pub fn knock(door: SocketAddr, secret: &Secret, within: Duration) -> Probe {
    knock_direct(door, secret, within).0
}

/// The door's answer after [`ACCEPTED`]: the direct listener's port, if it sent one.
pub fn direct_port(after_verdict: &[u8]) -> Option<u16> {
    match after_verdict {
        [hi, lo, ..] => Some(u16::from_be_bytes([*hi, *lo])).filter(|p| *p != 0),
        _ => None,
    }
}

/// [`knock`], and the port of the hub's direct listener when the door accepted the proof and
/// opened it to this host.
pub fn knock_direct(door: SocketAddr, secret: &Secret, within: Duration) -> (Probe, Option<u16>) {
    let mut port = None;
    let mut answer = || -> std::io::Result<u8> {
        let mut s = TcpStream::connect_timeout(&door, within)?;
        s.set_read_timeout(Some(within))?;
        s.set_write_timeout(Some(within))?;
        s.set_nodelay(true)?;
        s.write_all(&MAGIC)?;
        let mut nonce = [0u8; NONCE_BYTES];
        s.read_exact(&mut nonce)?;
        s.write_all(&secret.door_proof(&nonce))?;
        let mut verdict = [0u8; 1];
        s.read_exact(&mut verdict)?;
        if verdict[0] == ACCEPTED {
            // an older door closes after the verdict: no port, the relay as before
            let mut more = [0u8; 2];
            if s.read_exact(&mut more).is_ok() {
                port = direct_port(&more);
            }
        }
        Ok(verdict[0])
    };
    let probe = match answer() {
        Ok(verdict) => Probe::of_answer(Some(verdict)),
        Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => Probe::NotListening,
        Err(_) => Probe::NoAnswer,
    };
    (probe, port.filter(|_| probe == Probe::Accepted))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_two_answers_decide_and_anything_else_leaves_it_to_zenoh() {
        assert_eq!(Probe::of_answer(Some(ACCEPTED)), Probe::Accepted);
        assert_eq!(Probe::of_answer(Some(REFUSED)), Probe::Refused);
        assert_eq!(Probe::of_answer(Some(0)), Probe::NoAnswer);
        assert_eq!(Probe::of_answer(None), Probe::NoAnswer);
    }

    #[test]
    fn a_direct_port_is_two_bytes_after_the_verdict_and_never_zero() {
        assert_eq!(direct_port(&[0x1c, 0xe8]), Some(7400));
        assert_eq!(direct_port(&[0, 0]), None);
        assert_eq!(direct_port(&[0x1c]), None);
        assert_eq!(direct_port(&[]), None);
    }

    #[test]
    fn a_probe_is_told_from_a_zenoh_stream_by_its_first_bytes() {
        assert_eq!(opening(b""), Opening::Undecided);
        assert_eq!(opening(b"QFPR"), Opening::Undecided);
        assert_eq!(opening(&MAGIC), Opening::Probe);
        assert_eq!(opening(b"QFPROBE1 and more"), Opening::Probe);
        // a Zenoh TCP stream starts with its first batch's length, little-endian, a few dozen
        assert_eq!(opening(&[0x2c, 0x00, 0x01]), Opening::Session);
        assert_eq!(opening(b"QFX"), Opening::Session);
    }

    #[test]
    fn a_proof_holds_for_its_own_secret_and_nonce_only() {
        let ours = Secret::new("run-a", [7; 32]);
        let other = Secret::new("run-a", [8; 32]);
        let nonce = [1u8; NONCE_BYTES];
        let proof = ours.door_proof(&nonce);
        assert!(ours.check_door_proof(&nonce, &proof));
        assert!(!ours.check_door_proof(&[2u8; NONCE_BYTES], &proof));
        assert!(!ours.check_door_proof(&nonce, &other.door_proof(&nonce)));
        assert!(!ours.check_door_proof(&nonce, &proof[..31]));
    }

    #[test]
    fn nothing_listening_is_said_not_an_error() {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let at = l.local_addr().unwrap();
        drop(l);
        let s = Secret::new("run-a", [7; 32]);
        assert_eq!(knock(at, &s, Duration::from_secs(1)), Probe::NotListening);
    }
}
