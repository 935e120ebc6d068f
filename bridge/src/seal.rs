//! Who may speak on a link, and what a stranger sees of it: the run's join secret, the join's
//! challenge–response, the keys of each joined host, and the sealing of every frame. No IO.
//!
//! - **The join secret** ([`Secret`]): 32 random bytes made when a run listens, shown as text
//!   `qfleet-join-v1:<run-id>:<64 hex digits>` (so the joining host also knows which run it
//!   asks for). It never crosses the wire.
//! - **The join** is a challenge–response. B sends a random nonce; A answers a *cookie*
//!   ([`Challenges`]: issue time, random bytes and A's own MAC over them, so A keeps no state per
//!   unanswered challenge and a flood of hellos fills nothing); B proves it holds the secret with
//!   an HMAC over the run id, the cookie, its nonce and its whole request ([`proof`]). A checks
//!   the cookie (its MAC, at most [`CHALLENGE_TTL`] old, never spent before) and the proof before
//!   anything else; only then may a slot be given. A's answer (the plan) is sealed with a key
//!   derived from the secret and both nonces, so B also knows it speaks to a holder of the secret.
//! - **Keys per host and direction** ([`HostKeys`]): HKDF-SHA256 over the secret, salted with the
//!   cookie and B's nonce, expanded with the run id, the host index and the direction. Every frame
//!   after the join is sealed with ChaCha20-Poly1305 ([`Seal`]): the nonce is the direction and a
//!   per-direction counter carried in clear before the ciphertext; the receiver drops a frame whose
//!   tag does not verify (tampered, forged, another host's or another direction's key) and one
//!   whose counter it has seen or that is older than its window ([`WINDOW`]) — a replay. Zenoh's
//!   key expressions are derived from the same keys ([`HostKeys::down_key`]), so they name neither
//!   the run nor the host.

use chacha20poly1305::aead::AeadInPlace;
use chacha20poly1305::{ChaCha20Poly1305, KeyInit, Nonce, Tag};
use hkdf::Hkdf;
use hmac::{Hmac, Mac};
use sha2::Sha256;
use std::time::Duration;

type HmacSha256 = Hmac<Sha256>;

/// Bytes of a join secret.
pub const SECRET_BYTES: usize = 32;

/// How a join secret's text starts.
pub const SECRET_PREFIX: &str = "qfleet-join-v1:";

/// How long a challenge may be answered.
pub const CHALLENGE_TTL: Duration = Duration::from_secs(10);

/// Bytes of B's nonce.
pub const NONCE_BYTES: usize = 16;

/// Bytes of a cookie: issue time (8), random (8), MAC (16).
pub const COOKIE_BYTES: usize = 32;

/// Bytes a sealed frame adds: the counter before, the tag after.
pub const OVERHEAD: usize = 8 + 16;

/// Counters a receiver remembers below the highest it accepted: an older frame is a replay.
pub const WINDOW: u64 = 128;

/// Spent cookies remembered (each from a valid proof, so only secret holders add any).
pub const MAX_SPENT: usize = 4096;

/// Direction of a frame: from the hub (host A) to a joined host.
pub const DOWN: u32 = 1;
/// Direction of a frame: from a joined host to the hub.
pub const UP: u32 = 2;

/// What is wrong with a secret, a challenge or a proof.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AuthError {
    /// The secret's text is not `qfleet-join-v1:<run-id>:<64 hex digits>`.
    #[error(
        "not a join secret (expected {SECRET_PREFIX}<run-id>:<64 hex digits>, as `qfleet run --listen` prints and writes into its out directory as join.secret)"
    )]
    SecretText,
    /// The system's random source failed.
    #[error("no randomness from the system: {0}")]
    Random(String),
    /// A cookie A did not issue, or garbled.
    #[error("not a challenge of this run")]
    Cookie,
    /// A cookie older than [`CHALLENGE_TTL`].
    #[error("the challenge expired")]
    Expired,
    /// A cookie already answered.
    #[error("the challenge was already answered")]
    Spent,
    /// The proof does not verify: another secret, or another run.
    #[error("the join secret does not match this run")]
    Proof,
    /// A sealed message that does not open.
    #[error("a sealed answer that does not open with this secret")]
    Sealed,
}

/// Fills `buf` with random bytes from the system.
pub fn random(buf: &mut [u8]) -> Result<(), AuthError> {
    getrandom::fill(buf).map_err(|e| AuthError::Random(e.to_string()))
}

/// Lower-case hex of `bytes`.
pub fn hex(bytes: &[u8]) -> String {
    const D: &[u8; 16] = b"0123456789abcdef";
    let mut s = String::with_capacity(bytes.len() * 2);
    for b in bytes {
        s.push(D[(b >> 4) as usize] as char);
        s.push(D[(b & 15) as usize] as char);
    }
    s
}

/// Bytes of a hex text (either case), or None.
pub fn unhex(text: &str) -> Option<Vec<u8>> {
    let t = text.as_bytes();
    if !t.len().is_multiple_of(2) {
        return None;
    }
    let d = |c: u8| (c as char).to_digit(16).map(|v| v as u8);
    t.chunks(2)
        .map(|p| Some(d(p[0])? << 4 | d(p[1])?))
        .collect()
}

/// Bytes of a hex text of exactly `N` bytes.
pub fn unhex_n<const N: usize>(text: &str) -> Option<[u8; N]> {
    unhex(text)?.try_into().ok()
}

/// A run's join secret: the run id it is for and 32 random bytes.
#[derive(Clone, PartialEq, Eq)]
pub struct Secret {
    run_id: String,
    key: [u8; SECRET_BYTES],
}

impl std::fmt::Debug for Secret {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Secret({}, <hidden>)", self.run_id)
    }
}

impl Secret {
    /// A fresh secret for `run_id`.
    pub fn generate(run_id: &str) -> Result<Secret, AuthError> {
        let mut key = [0; SECRET_BYTES];
        random(&mut key)?;
        Ok(Secret::new(run_id, key))
    }

    /// The secret of `run_id` with these bytes.
    pub fn new(run_id: &str, key: [u8; SECRET_BYTES]) -> Secret {
        Secret {
            run_id: run_id.to_string(),
            key,
        }
    }

    /// Reads the text form (surrounding white space ignored); the run id must follow the
    /// launcher's rule.
    pub fn parse(text: &str) -> Result<Secret, AuthError> {
        let rest = text
            .trim()
            .strip_prefix(SECRET_PREFIX)
            .ok_or(AuthError::SecretText)?;
        let (run_id, key) = rest.rsplit_once(':').ok_or(AuthError::SecretText)?;
        crate::join::check_run_id(run_id).map_err(|_| AuthError::SecretText)?;
        let key = unhex_n::<SECRET_BYTES>(key).ok_or(AuthError::SecretText)?;
        Ok(Secret::new(run_id, key))
    }

    /// The text form, `qfleet-join-v1:<run-id>:<64 hex digits>`.
    pub fn text(&self) -> String {
        format!("{SECRET_PREFIX}{}:{}", self.run_id, hex(&self.key))
    }

    /// The run this secret is for.
    pub fn run_id(&self) -> &str {
        &self.run_id
    }

    /// Whether this secret is for the run `run_id`: that run, or one of the seeds of an
    /// experiment whose run-id prefix it names (`<prefix>-…`).
    pub fn names(&self, run_id: &str) -> bool {
        run_id == self.run_id
            || run_id
                .strip_prefix(self.run_id.as_str())
                .is_some_and(|rest| rest.starts_with('-'))
    }

    /// The password both hosts give Zenoh's user–password authentication (see
    /// [`crate::link::SessionAuth`]): derived from the secret, so only a holder of the secret
    /// completes a Zenoh session with the run's host at all; the secret itself never leaves
    /// this process (Zenoh sends only an HMAC of this password keyed by the acceptor's nonce).
    pub fn session_password(&self) -> String {
        hex(&self.mac(b"qfleet zenoh session v1").finalize().into_bytes())
    }

    /// The answer to the front door's probe `nonce` ([`crate::probe`]): proves the secret to
    /// the door before any Zenoh session, so a wrong secret is told apart from a dead host.
    pub fn door_proof(&self, nonce: &[u8]) -> [u8; 32] {
        let mut m = self.mac(b"qfleet door probe v1");
        m.update(nonce);
        m.finalize().into_bytes().into()
    }

    /// Whether `proof` answers the door's probe `nonce` (compared in constant time).
    pub fn check_door_proof(&self, nonce: &[u8], proof: &[u8]) -> bool {
        let mut m = self.mac(b"qfleet door probe v1");
        m.update(nonce);
        m.verify_slice(proof).is_ok()
    }

    fn mac(&self, label: &[u8]) -> HmacSha256 {
        let mut m = <HmacSha256 as Mac>::new_from_slice(&self.key).expect("HMAC takes any key");
        m.update(label);
        put_str(&mut m, &self.run_id);
        m
    }
}

/// Feeds a length-prefixed string (so fields cannot slide into each other).
fn put_str(m: &mut HmacSha256, s: &str) {
    m.update(&(s.len() as u64).to_le_bytes());
    m.update(s.as_bytes());
}

/// B's proof that it holds `secret`: an HMAC over the run id, A's cookie, B's nonce and the
/// bytes of B's request.
pub fn proof(
    secret: &Secret,
    cookie: &[u8; COOKIE_BYTES],
    nonce: &[u8; NONCE_BYTES],
    request: &[u8],
) -> [u8; 32] {
    proof_mac(secret, cookie, nonce, request)
        .finalize()
        .into_bytes()
        .into()
}

fn proof_mac(
    secret: &Secret,
    cookie: &[u8; COOKIE_BYTES],
    nonce: &[u8; NONCE_BYTES],
    request: &[u8],
) -> HmacSha256 {
    let mut m = secret.mac(b"qfleet join proof v1");
    m.update(cookie);
    m.update(nonce);
    m.update(&(request.len() as u64).to_le_bytes());
    m.update(request);
    m
}

/// Checks B's proof in constant time.
pub fn check_proof(
    secret: &Secret,
    cookie: &[u8; COOKIE_BYTES],
    nonce: &[u8; NONCE_BYTES],
    request: &[u8],
    proof: &[u8],
) -> Result<(), AuthError> {
    proof_mac(secret, cookie, nonce, request)
        .verify_slice(proof)
        .map_err(|_| AuthError::Proof)
}

/// A's challenges: stateless cookies (issue time, random, MAC under a key of this hub's own),
/// and the bounded set of those already answered with a valid proof.
pub struct Challenges {
    key: [u8; 32],
    spent: std::collections::VecDeque<(u64, [u8; COOKIE_BYTES])>,
}

impl Challenges {
    /// A fresh cookie key.
    pub fn new() -> Result<Challenges, AuthError> {
        let mut key = [0; 32];
        random(&mut key)?;
        Ok(Challenges {
            key,
            spent: Default::default(),
        })
    }

    fn tag(&self, head: &[u8]) -> [u8; 16] {
        let mut m = <HmacSha256 as Mac>::new_from_slice(&self.key).expect("HMAC takes any key");
        m.update(head);
        let full: [u8; 32] = m.finalize().into_bytes().into();
        full[..16].try_into().expect("16 of 32")
    }

    /// A cookie issued at `now_ms` (the hub's clock, ms).
    pub fn issue(&self, now_ms: u64) -> Result<[u8; COOKIE_BYTES], AuthError> {
        let mut c = [0u8; COOKIE_BYTES];
        c[..8].copy_from_slice(&now_ms.to_le_bytes());
        random(&mut c[8..16])?;
        let t = self.tag(&c[..16]);
        c[16..].copy_from_slice(&t);
        Ok(c)
    }

    /// Whether `cookie` is one of ours, fresh at `now_ms` and not answered yet (nothing kept).
    pub fn check(&self, cookie: &[u8; COOKIE_BYTES], now_ms: u64) -> Result<(), AuthError> {
        let t = self.tag(&cookie[..16]);
        let ok: bool = t
            .iter()
            .zip(&cookie[16..])
            .fold(0u8, |acc, (a, b)| acc | (a ^ b))
            == 0;
        if !ok {
            return Err(AuthError::Cookie);
        }
        let issued = u64::from_le_bytes(cookie[..8].try_into().expect("8 bytes"));
        if issued > now_ms || now_ms - issued > CHALLENGE_TTL.as_millis() as u64 {
            return Err(AuthError::Expired);
        }
        if self.spent.iter().any(|(_, c)| c == cookie) {
            return Err(AuthError::Spent);
        }
        Ok(())
    }

    /// Marks a checked cookie answered (call after its proof verified): it cannot be used again.
    pub fn spend(&mut self, cookie: &[u8; COOKIE_BYTES], now_ms: u64) {
        let ttl = CHALLENGE_TTL.as_millis() as u64;
        while self
            .spent
            .front()
            .is_some_and(|(t, _)| now_ms.saturating_sub(*t) > ttl)
            || self.spent.len() >= MAX_SPENT
        {
            self.spent.pop_front();
        }
        self.spent.push_back((now_ms, *cookie));
    }

    /// Cookies remembered as answered.
    pub fn spent(&self) -> usize {
        self.spent.len()
    }
}

/// Everything both ends of one joined host's link derive from the secret and the join's
/// nonces: the plan's key, the frame keys of both directions and the Zenoh key names.
pub struct HostKeys {
    prk: Hkdf<Sha256>,
    run_id: String,
}

impl std::fmt::Debug for HostKeys {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "HostKeys({}, <hidden>)", self.run_id)
    }
}

impl HostKeys {
    /// Keys of the join that used `cookie` and B's `nonce`.
    pub fn new(secret: &Secret, cookie: &[u8; COOKIE_BYTES], nonce: &[u8; NONCE_BYTES]) -> Self {
        let mut salt = [0u8; COOKIE_BYTES + NONCE_BYTES];
        salt[..COOKIE_BYTES].copy_from_slice(cookie);
        salt[COOKIE_BYTES..].copy_from_slice(nonce);
        HostKeys {
            prk: Hkdf::<Sha256>::new(Some(&salt), &secret.key),
            run_id: secret.run_id.clone(),
        }
    }

    fn expand(&self, what: &str, host: Option<u32>, dir: u32) -> [u8; 32] {
        let mut info = Vec::with_capacity(64);
        info.extend_from_slice(b"qfleet bridge v1\0");
        info.extend_from_slice(what.as_bytes());
        info.push(0);
        info.extend_from_slice(&(self.run_id.len() as u64).to_le_bytes());
        info.extend_from_slice(self.run_id.as_bytes());
        info.extend_from_slice(&host.map_or(u64::MAX, u64::from).to_le_bytes());
        info.extend_from_slice(&dir.to_le_bytes());
        let mut okm = [0u8; 32];
        self.prk
            .expand(&info, &mut okm)
            .expect("32 bytes is a valid HKDF-SHA256 length");
        okm
    }

    /// Seals the plan (A) for this join only.
    pub fn seal_plan(&self, plan: &[u8]) -> Vec<u8> {
        let mut s = Seal::one_way(self.expand("plan", None, DOWN), DOWN);
        s.seal(plan).to_vec()
    }

    /// Opens the plan (B): fails unless A holds the same secret and saw the same nonces.
    pub fn open_plan(&self, sealed: &[u8]) -> Result<Vec<u8>, AuthError> {
        let mut s = Seal::one_way(self.expand("plan", None, DOWN), DOWN);
        s.open(sealed)
            .map(<[u8]>::to_vec)
            .map_err(|_| AuthError::Sealed)
    }

    /// The hub's end of host `host`'s link: sends down, receives up.
    pub fn hub_end(&self, host: u32) -> Seal {
        Seal::new(
            self.expand("frames", Some(host), DOWN),
            DOWN,
            self.expand("frames", Some(host), UP),
            UP,
        )
    }

    /// Host `host`'s end: sends up, receives down.
    pub fn host_end(&self, host: u32) -> Seal {
        Seal::new(
            self.expand("frames", Some(host), UP),
            UP,
            self.expand("frames", Some(host), DOWN),
            DOWN,
        )
    }

    /// The Zenoh key the hub publishes to host `host` on: names neither run nor host.
    pub fn down_key(&self, host: u32) -> String {
        format!(
            "qfleet/down/{}",
            hex(&self.expand("key", Some(host), DOWN)[..16])
        )
    }

    /// The Zenoh key host `host` publishes to the hub on.
    pub fn up_key(&self, host: u32) -> String {
        format!(
            "qfleet/up/{}",
            hex(&self.expand("key", Some(host), UP)[..16])
        )
    }
}

/// The hub's subscription: every joined host's up key.
pub const UP_KEYS: &str = "qfleet/up/*";

/// Why a received frame was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Reject {
    /// Shorter than counter and tag.
    #[error("too short to be sealed")]
    Short,
    /// The tag does not verify: tampered, forged, or sealed with another key.
    #[error("does not verify")]
    Forged,
    /// A counter already seen, or older than the window.
    #[error("replayed")]
    Replayed,
}

/// Which counters a receiver has accepted: the highest and a bitmap of the [`WINDOW`] below it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReplayWindow {
    top: u64,
    seen: u128,
}

impl Default for ReplayWindow {
    /// Counter 0 is never sent: it counts as seen.
    fn default() -> Self {
        ReplayWindow { top: 0, seen: 1 }
    }
}

impl ReplayWindow {
    /// Whether `ctr` may be accepted (nothing changes: call [`ReplayWindow::mark`] once the
    /// frame verified, so a forgery cannot move the window).
    pub fn fresh(&self, ctr: u64) -> bool {
        ctr > self.top || (self.top - ctr < WINDOW && self.seen & (1u128 << (self.top - ctr)) == 0)
    }

    /// Records `ctr` as accepted.
    pub fn mark(&mut self, ctr: u64) {
        if ctr > self.top {
            let shift = ctr - self.top;
            self.seen = if shift >= WINDOW {
                0
            } else {
                self.seen << shift
            };
            self.seen |= 1;
            self.top = ctr;
        } else if self.top - ctr < WINDOW {
            self.seen |= 1u128 << (self.top - ctr);
        }
    }
}

/// The sending half of a link end's sealing: its key, direction and counter, and a reused
/// buffer (nothing allocated per frame once warm).
pub struct Sealer {
    key: ChaCha20Poly1305,
    dir: u32,
    next: u64,
    out: Vec<u8>,
}

/// The receiving half: the peer's key and direction, the replay window, a reused buffer.
pub struct Opener {
    key: ChaCha20Poly1305,
    dir: u32,
    window: ReplayWindow,
    inp: Vec<u8>,
}

/// Both halves of one link end.
pub struct Seal {
    /// What this end sends.
    pub tx: Sealer,
    /// What this end receives.
    pub rx: Opener,
}

fn nonce(dir: u32, ctr: u64) -> Nonce {
    let mut n = [0u8; 12];
    n[..4].copy_from_slice(&dir.to_le_bytes());
    n[4..].copy_from_slice(&ctr.to_le_bytes());
    n.into()
}

impl Sealer {
    /// Seals with `key` in direction `dir`, counting from 1.
    pub fn new(key: [u8; 32], dir: u32) -> Sealer {
        Sealer {
            key: ChaCha20Poly1305::new(&key.into()),
            dir,
            next: 1,
            out: Vec::new(),
        }
    }

    /// `frame` sealed: counter (8 bytes, little-endian), ciphertext, tag. Each call takes the
    /// next counter (a resend is sealed again, as a new frame).
    pub fn seal(&mut self, frame: &[u8]) -> &[u8] {
        let ctr = self.next;
        self.next += 1;
        self.out.clear();
        self.out.extend_from_slice(&ctr.to_le_bytes());
        self.out.extend_from_slice(frame);
        let tag = self
            .key
            .encrypt_in_place_detached(&nonce(self.dir, ctr), &[], &mut self.out[8..])
            .expect("a frame is far below ChaCha20-Poly1305's length limit");
        self.out.extend_from_slice(&tag);
        &self.out
    }
}

impl Opener {
    /// Opens what was sealed with `key` in direction `dir`.
    pub fn new(key: [u8; 32], dir: u32) -> Opener {
        Opener {
            key: ChaCha20Poly1305::new(&key.into()),
            dir,
            window: ReplayWindow::default(),
            inp: Vec::new(),
        }
    }

    /// The frame inside `sealed`, or why it was dropped.
    pub fn open(&mut self, sealed: &[u8]) -> Result<&[u8], Reject> {
        if sealed.len() < OVERHEAD {
            return Err(Reject::Short);
        }
        let ctr = u64::from_le_bytes(sealed[..8].try_into().expect("8 bytes"));
        if !self.window.fresh(ctr) {
            return Err(Reject::Replayed);
        }
        let (body, tag) = sealed[8..].split_at(sealed.len() - OVERHEAD);
        self.inp.clear();
        self.inp.extend_from_slice(body);
        self.key
            .decrypt_in_place_detached(
                &nonce(self.dir, ctr),
                &[],
                &mut self.inp,
                Tag::from_slice(tag),
            )
            .map_err(|_| Reject::Forged)?;
        self.window.mark(ctr);
        Ok(&self.inp)
    }
}

impl Seal {
    /// Sends with `tx_key` in direction `tx_dir`, receives with `rx_key` in `rx_dir`.
    pub fn new(tx_key: [u8; 32], tx_dir: u32, rx_key: [u8; 32], rx_dir: u32) -> Seal {
        Seal {
            tx: Sealer::new(tx_key, tx_dir),
            rx: Opener::new(rx_key, rx_dir),
        }
    }

    fn one_way(key: [u8; 32], dir: u32) -> Seal {
        Seal::new(key, dir, key, dir)
    }

    /// [`Sealer::seal`].
    pub fn seal(&mut self, frame: &[u8]) -> &[u8] {
        self.tx.seal(frame)
    }

    /// [`Opener::open`].
    pub fn open(&mut self, sealed: &[u8]) -> Result<&[u8], Reject> {
        self.rx.open(sealed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn secret(b: u8) -> Secret {
        Secret::new("run-1", [b; SECRET_BYTES])
    }

    fn keys(s: &Secret) -> HostKeys {
        HostKeys::new(s, &[7; COOKIE_BYTES], &[9; NONCE_BYTES])
    }

    #[test]
    fn a_secret_reads_back_from_its_text_and_names_its_run() {
        let s = Secret::generate("run-42").unwrap();
        let t = s.text();
        assert!(t.starts_with("qfleet-join-v1:run-42:"), "{t}");
        assert_eq!(Secret::parse(&format!("  {t}\n")).unwrap(), s);
        assert_eq!(s.run_id(), "run-42");
        assert!(!format!("{s:?}").contains(&t[22..]), "Debug hides the key");
        assert!(s.names("run-42") && s.names("run-42-s1-x7"));
        assert!(!s.names("run-421") && !s.names("run-4") && !s.names("other"));
        for bad in [
            "",
            "qfleet-join-v1:run-42",
            "qfleet-join-v1:run-42:abc",
            "qfleet-join-v1:../x:0000000000000000000000000000000000000000000000000000000000000000",
            &t.replace("qfleet-join-v1", "qfleet-join-v2"),
            &format!("{t}00"),
        ] {
            assert_eq!(Secret::parse(bad), Err(AuthError::SecretText), "{bad:?}");
        }
    }

    #[test]
    fn only_the_holder_of_the_secret_proves_a_join_and_only_for_that_request() {
        let s = secret(1);
        let ch = Challenges::new().unwrap();
        let cookie = ch.issue(1000).unwrap();
        let nonce = [3; NONCE_BYTES];
        let p = proof(&s, &cookie, &nonce, b"robots 2");
        assert_eq!(check_proof(&s, &cookie, &nonce, b"robots 2", &p), Ok(()));
        // another secret, another run id, another request, another nonce or a truncated proof
        let other_run = Secret::new("run-2", [1; SECRET_BYTES]);
        for (sec, req, n, pf) in [
            (&secret(2), &b"robots 2"[..], nonce, &p[..]),
            (&other_run, b"robots 2", nonce, &p[..]),
            (&s, b"robots 9", nonce, &p[..]),
            (&s, b"robots 2", [4; NONCE_BYTES], &p[..]),
            (&s, b"robots 2", nonce, &p[..16]),
        ] {
            assert_eq!(
                check_proof(sec, &cookie, &n, req, pf),
                Err(AuthError::Proof)
            );
        }
    }

    #[test]
    fn a_cookie_is_ours_fresh_and_answered_once() {
        let mut ch = Challenges::new().unwrap();
        let c = ch.issue(1000).unwrap();
        assert_eq!(ch.check(&c, 1500), Ok(()));
        let mut forged = c;
        forged[9] ^= 1;
        assert_eq!(ch.check(&forged, 1500), Err(AuthError::Cookie));
        assert_eq!(
            Challenges::new().unwrap().check(&c, 1500),
            Err(AuthError::Cookie),
            "another hub's cookie"
        );
        let late = 1000 + CHALLENGE_TTL.as_millis() as u64 + 1;
        assert_eq!(ch.check(&c, late), Err(AuthError::Expired));
        ch.spend(&c, 1500);
        assert_eq!(ch.check(&c, 1600), Err(AuthError::Spent), "a replayed join");
        // spent cookies are forgotten once they expired anyway: the set stays bounded
        for i in 0..(MAX_SPENT as u64 + 10) {
            let c = ch.issue(2000).unwrap();
            ch.spend(&c, 2000 + i % 5);
        }
        assert!(ch.spent() <= MAX_SPENT);
        ch.spend(&ch.issue(late + 20_000).unwrap(), late + 20_000);
        assert_eq!(ch.spent(), 1);
    }

    #[test]
    fn the_plan_opens_only_with_the_same_secret_and_nonces() {
        let s = secret(1);
        let sealed = keys(&s).seal_plan(b"the plan");
        assert!(!sealed.windows(8).any(|w| w == b"the plan"));
        assert_eq!(keys(&s).open_plan(&sealed).unwrap(), b"the plan");
        assert_eq!(keys(&secret(2)).open_plan(&sealed), Err(AuthError::Sealed));
        let other_nonce = HostKeys::new(&s, &[7; COOKIE_BYTES], &[8; NONCE_BYTES]);
        assert_eq!(other_nonce.open_plan(&sealed), Err(AuthError::Sealed));
    }

    #[test]
    fn a_sealed_frame_opens_once_at_the_other_end_and_hides_its_bytes() {
        let k = keys(&secret(1));
        let (mut hub, mut host) = (k.hub_end(0), k.host_end(0));
        let f = hub.seal(b"coordinator message").to_vec();
        assert_eq!(f.len(), 19 + OVERHEAD);
        assert!(!f.windows(11).any(|w| w == b"coordinator"));
        assert_eq!(host.open(&f), Ok(&b"coordinator message"[..]));
        assert_eq!(host.open(&f), Err(Reject::Replayed), "a replay");
        let up = host.seal(b"robot message").to_vec();
        assert_eq!(hub.open(&up), Ok(&b"robot message"[..]));
    }

    #[test]
    fn a_tampered_byte_anywhere_drops_the_frame() {
        let k = keys(&secret(1));
        let (mut hub, mut host) = (k.hub_end(0), k.host_end(0));
        let f = hub.seal(b"0123456789").to_vec();
        for i in 0..f.len() {
            let mut t = f.clone();
            t[i] ^= 0x40;
            let r = host.open(&t);
            assert!(
                matches!(r, Err(Reject::Forged | Reject::Replayed)),
                "byte {i}: {r:?}"
            );
        }
        assert_eq!(host.open(&f[..10]), Err(Reject::Short));
        // none of that moved the window: the real frame still opens
        assert!(host.open(&f).is_ok());
    }

    #[test]
    fn a_frame_under_another_key_host_or_direction_is_forged() {
        let k = keys(&secret(1));
        let mut hub0 = k.hub_end(0);
        // host 1's key on host 2's channel
        let mut host1 = k.host_end(1);
        let mut hub2 = k.hub_end(2);
        assert_eq!(hub2.open(host1.seal(b"x")), Err(Reject::Forged));
        // the hub's own frame sent back up to it (a reflection)
        let mut hub0b = k.hub_end(0);
        assert_eq!(hub0b.open(hub0.seal(b"x")), Err(Reject::Forged));
        // a stranger with another secret, or the same secret but other nonces
        let mut stranger = keys(&secret(2)).host_end(0);
        assert_eq!(hub0.open(stranger.seal(b"x")), Err(Reject::Forged));
        let replayed_join = HostKeys::new(&secret(1), &[7; COOKIE_BYTES], &[1; NONCE_BYTES]);
        assert_eq!(
            hub0.open(replayed_join.host_end(0).seal(b"x")),
            Err(Reject::Forged)
        );
        // the key names differ per host and direction and hide the run id
        assert_ne!(k.down_key(0), k.down_key(1));
        assert_ne!(k.down_key(0), k.up_key(0).replace("/up/", "/down/"));
        assert!(!k.down_key(0).contains("run-1"));
    }

    /// What sealing and opening cost per frame of the loop's two messages (a measurement, not
    /// a check: `cargo test -p bridge seal_cost -- --ignored --nocapture`).
    #[test]
    #[ignore]
    fn seal_cost() {
        let k = keys(&secret(1));
        let (mut a, mut b) = (k.hub_end(0), k.host_end(0));
        for bytes in [64, 3112 + 16, 6176 + 16] {
            let frame = vec![7u8; bytes];
            let n = 20_000u32;
            let t = std::time::Instant::now();
            for _ in 0..n {
                let f = a.seal(&frame).to_vec();
                assert!(b.open(&f).is_ok());
            }
            let per = t.elapsed() / n;
            eprintln!("seal + open of a {bytes}-byte frame: {per:?}");
        }
    }

    #[test]
    fn reordering_within_the_window_is_accepted_and_older_frames_are_replays() {
        let mut w = ReplayWindow::default();
        assert!(!w.fresh(0), "counter 0 is never sent");
        for c in [1, 3, 2, 200] {
            assert!(w.fresh(c), "{c}");
            w.mark(c);
            assert!(!w.fresh(c));
        }
        assert!(w.fresh(199) && w.fresh(73));
        assert!(!w.fresh(72), "older than the window");
        assert!(!w.fresh(3));
        w.mark(1_000_000);
        assert!(!w.fresh(199));
    }
}
