//! The join: what a joining host asks, what the coordinator's host answers, and who decides.
//!
//! A joining host sends a [`JoinRequest`] (its schema version, byte order, name, robot count and
//! clock) as a Zenoh query; the hub answers [`JoinReply::Accepted`] with everything the host
//! needs to run its robots — run id, fleet size, robot ids, each robot's command-line options
//! and the content of every file they name (map, scenario) — or [`JoinReply::Refused`] with a
//! reason that both sides print. [`Admission`] decides, without IO.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// Zenoh key of the hub's join queryable.
pub const JOIN_KEY: &str = "qfleet/join";

/// Placeholder prefix in [`JoinPlan::robot_args`]: `{file:NAME}` stands for the path where the
/// joining host wrote `files[NAME]`.
pub const FILE_PLACEHOLDER: &str = "{file:";

/// What a joining host asks for.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct JoinRequest {
    /// The joining host's `bus_schema::SCHEMA_VERSION`.
    pub schema_version: u32,
    /// Whether the joining host is little-endian (messages travel as their memory bytes).
    pub little_endian: bool,
    /// A name for the joining host (shown in the result).
    pub host: String,
    /// How many robots it will run.
    pub robots: u32,
    /// Its monotonic clock when it sent the request.
    pub t_ns: u64,
}

impl JoinRequest {
    /// A request from this build and host.
    pub fn new(host: String, robots: u32, t_ns: u64) -> Self {
        JoinRequest {
            schema_version: bus::bus_schema::SCHEMA_VERSION,
            little_endian: cfg!(target_endian = "little"),
            host,
            robots,
            t_ns,
        }
    }
}

/// What a joining host sends (each a Zenoh query on [`JOIN_KEY`], JSON).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum JoinAsk {
    /// First: a random nonce (hex); the hub answers a challenge.
    Hello {
        /// B's nonce, [`crate::seal::NONCE_BYTES`] as hex.
        nonce: String,
    },
    /// Then: the request with the proof that B holds the run's secret.
    Join {
        /// The hub's challenge, as received.
        cookie: String,
        /// B's nonce of the hello.
        nonce: String,
        /// What B asks for.
        request: JoinRequest,
        /// [`crate::seal::proof`] over the run id, the cookie, the nonce and the request's
        /// JSON, hex.
        proof: String,
    },
}

/// What the coordinator's host answers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum JoinReply {
    /// Prove you hold the secret: answer this cookie (hex).
    Challenge {
        /// The hub's stateless challenge ([`crate::seal::Challenges`]).
        cookie: String,
    },
    /// Come in: the [`JoinPlan`]'s JSON, sealed with the join's plan key, hex.
    Accepted {
        /// Sealed plan.
        plan: String,
    },
    /// Not this host: why.
    Refused {
        /// Readable reason, printed on both hosts.
        reason: String,
    },
}

/// Largest join query read: a real one is a few hundred bytes; anything larger is dropped
/// before it is parsed.
pub const MAX_ASK: usize = 4096;

/// What the door makes of one join query.
#[derive(Debug)]
pub enum Knock {
    /// Answer this (a challenge, or a refusal of an unauthenticated query).
    Answer(JoinReply),
    /// The asker proved it holds the secret: decide on `request` ([`Admission`]); seal the
    /// plan and the link with `keys`.
    Proven {
        /// What it asks for.
        request: JoinRequest,
        /// The keys of this join.
        keys: crate::seal::HostKeys,
    },
}

/// The hub's door: answers hellos with challenges and lets through only joins that prove they
/// hold the run's secret, each challenge once. Nothing is kept per asker; what fails is only
/// counted. No IO.
pub struct Door {
    secret: crate::seal::Secret,
    challenges: crate::seal::Challenges,
    /// Join queries dropped because they were unreadable, too large, answered a challenge that
    /// is not ours, expired or spent, or carried a proof that does not verify.
    pub unauthenticated: u64,
}

impl Door {
    /// The door of the run `secret` is for.
    pub fn new(secret: crate::seal::Secret) -> Result<Door, crate::seal::AuthError> {
        Ok(Door {
            secret,
            challenges: crate::seal::Challenges::new()?,
            unauthenticated: 0,
        })
    }

    /// One join query's payload, at `now_ms` on the hub's clock.
    pub fn knock(&mut self, payload: &[u8], now_ms: u64) -> Knock {
        use crate::seal::{self, COOKIE_BYTES, NONCE_BYTES, unhex_n};
        let refuse = |door: &mut Door| {
            door.unauthenticated += 1;
            Knock::Answer(JoinReply::Refused {
                reason: "not authenticated: the join secret does not match this run (or the \
                         challenge expired)"
                    .into(),
            })
        };
        if payload.len() > MAX_ASK {
            return refuse(self);
        }
        match serde_json::from_slice::<JoinAsk>(payload) {
            Ok(JoinAsk::Hello { nonce }) if unhex_n::<NONCE_BYTES>(&nonce).is_some() => {
                match self.challenges.issue(now_ms) {
                    Ok(c) => Knock::Answer(JoinReply::Challenge {
                        cookie: seal::hex(&c),
                    }),
                    Err(e) => Knock::Answer(JoinReply::Refused {
                        reason: e.to_string(),
                    }),
                }
            }
            Ok(JoinAsk::Join {
                cookie,
                nonce,
                request,
                proof,
            }) => {
                let (Some(cookie), Some(nonce), Some(proof)) = (
                    unhex_n::<COOKIE_BYTES>(&cookie),
                    unhex_n::<NONCE_BYTES>(&nonce),
                    seal::unhex(&proof),
                ) else {
                    return refuse(self);
                };
                let body = serde_json::to_vec(&request).unwrap_or_default();
                let ok = self.challenges.check(&cookie, now_ms).is_ok()
                    && seal::check_proof(&self.secret, &cookie, &nonce, &body, &proof).is_ok();
                if !ok {
                    return refuse(self);
                }
                self.challenges.spend(&cookie, now_ms);
                Knock::Proven {
                    request,
                    keys: seal::HostKeys::new(&self.secret, &cookie, &nonce),
                }
            }
            _ => refuse(self),
        }
    }
}

/// B's side of the join, without IO: makes the hello, answers the challenge, opens the plan.
pub struct Knocker {
    secret: crate::seal::Secret,
    nonce: [u8; crate::seal::NONCE_BYTES],
}

impl Knocker {
    /// A fresh nonce for a join with `secret`.
    pub fn new(secret: crate::seal::Secret) -> Result<Knocker, crate::seal::AuthError> {
        let mut nonce = [0; crate::seal::NONCE_BYTES];
        crate::seal::random(&mut nonce)?;
        Ok(Knocker { secret, nonce })
    }

    /// The first query.
    pub fn hello(&self) -> JoinAsk {
        JoinAsk::Hello {
            nonce: crate::seal::hex(&self.nonce),
        }
    }

    /// The second query, answering `cookie`; the keys it will share with the hub.
    pub fn join(
        &self,
        cookie: &str,
        request: JoinRequest,
    ) -> Result<(JoinAsk, crate::seal::HostKeys), crate::seal::AuthError> {
        use crate::seal::{self, COOKIE_BYTES, unhex_n};
        let c = unhex_n::<COOKIE_BYTES>(cookie).ok_or(crate::seal::AuthError::Cookie)?;
        let body = serde_json::to_vec(&request).unwrap_or_default();
        let proof = seal::proof(&self.secret, &c, &self.nonce, &body);
        Ok((
            JoinAsk::Join {
                cookie: cookie.to_string(),
                nonce: seal::hex(&self.nonce),
                request,
                proof: seal::hex(&proof),
            },
            seal::HostKeys::new(&self.secret, &c, &self.nonce),
        ))
    }

    /// Opens the sealed plan of an accepted join (which proves the hub holds the secret too)
    /// and checks it is for the run the secret names.
    pub fn open(&self, keys: &crate::seal::HostKeys, sealed_hex: &str) -> Result<JoinPlan, String> {
        let sealed = crate::seal::unhex(sealed_hex).ok_or("a sealed plan that is not hex")?;
        let bytes = keys
            .open_plan(&sealed)
            .map_err(|e| format!("{e}: the answer is not from a holder of this run's secret"))?;
        let plan: JoinPlan = serde_json::from_slice(&bytes)
            .map_err(|e| format!("unreadable plan ({e}): another qfleet version?"))?;
        if !self.secret.names(&plan.run_id) {
            return Err(format!(
                "the coordinator's host runs {:?}, not the run {:?} that was asked for",
                plan.run_id,
                self.secret.run_id()
            ));
        }
        Ok(plan)
    }
}

/// Everything a joining host needs: no map file or learner option is needed on that host.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JoinPlan {
    /// The run's id (the iceoryx2 prefix on the joining host too).
    pub run_id: String,
    /// Index of this host among the joined ones (names its Zenoh keys).
    pub host_index: u32,
    /// Robots in the whole fleet (sizes the joining host's services).
    pub robots_total: u32,
    /// Robot ids this host runs.
    pub robot_ids: Vec<u32>,
    /// Per robot id of this host: its whole robot-agent command line except `--out` (the
    /// joining host adds its own directory).
    pub robot_args: Vec<Vec<String>>,
    /// Files the options name (`{file:NAME}`), by name, with their content.
    pub files: BTreeMap<String, String>,
    /// The coordinator's hint buffer per connection.
    pub hint_buffer: usize,
    /// The coordinator's merged-hint buffer per connection.
    pub merged_buffer: usize,
    /// Heartbeat silence after which the link counts as down, ms.
    pub down_after_ms: u64,
    /// Silence after which a host is given up on, ms.
    pub deadline_ms: u64,
    /// The hub's monotonic clock when it answered (seeds the clock offset).
    pub t_ns: u64,
    /// Frames travel unsealed (`--insecure-plain` on host A); host B accepts that only with
    /// `--insecure-plain` too.
    #[serde(default)]
    pub plain: bool,
}

/// Most files a plan may ship (a run ships at most a map and a scenario per distinct file).
pub const MAX_PLAN_FILES: usize = 64;

/// Most bytes of one shipped file (the largest suite map is a few MB).
pub const MAX_FILE_BYTES: usize = 64 << 20;

/// Most arguments of one robot's command line.
pub const MAX_ROBOT_ARGS: usize = 256;

/// Longest heartbeat silence and host deadline a plan may ask for, ms (a day).
pub const MAX_PLAN_MS: u64 = 24 * 3600 * 1000;

/// Why a joining host refuses the plan the coordinator's host sent (checked before anything
/// is written, started or named after it on the joining host).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PlanError {
    /// The run id is not a run id (`../`, `/`, control characters, too long…).
    #[error("the coordinator's host sent an invalid run id {0:?} (1 to {max} of A-Z a-z 0-9 _ -, starting with a letter or digit)", max = bus::bus_schema::RUN_ID_MAX_LEN)]
    RunId(String),
    /// More robots than this host offered.
    #[error("the coordinator's host asks for {asked} robots but this host offered {offered}")]
    TooManyRobots {
        /// Robots in the plan.
        asked: usize,
        /// `--robots`.
        offered: u32,
    },
    /// A plan with no robot.
    #[error("the coordinator's host sent a plan with no robot")]
    NoRobots,
    /// Fleet size, robot ids or argument lists that do not fit together.
    #[error("the coordinator's host sent an inconsistent plan: {0}")]
    Inconsistent(String),
    /// A file name that is not a plain file name.
    #[error(
        "the coordinator's host sent a file name {name:?} that is not a plain file name: {reason}"
    )]
    FileName {
        /// The name as sent.
        name: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// Too many or too large files.
    #[error("the coordinator's host sent too much: {0}")]
    TooLarge(String),
    /// A robot option this host does not let the other host choose.
    #[error("the coordinator's host sent robot {robot} an option it may not choose: {detail}")]
    Option {
        /// The robot id.
        robot: u32,
        /// Which option and why.
        detail: String,
    },
}

/// The launcher's run-id rule (`launcher::run_id::validate`): 1 to `RUN_ID_MAX_LEN` of
/// `A-Z a-z 0-9 _ -`, starting with a letter or digit.
pub fn check_run_id(id: &str) -> Result<(), PlanError> {
    let ok = bus::validate_run_id(id).is_ok()
        && id.chars().next().is_some_and(|c| c.is_ascii_alphanumeric());
    if ok {
        Ok(())
    } else {
        Err(PlanError::RunId(id.to_string()))
    }
}

/// A file name sent by the other host, accepted only as a plain name: no `/`, not `.` or `..`,
/// not empty, no NUL or other control character, at most 255 bytes.
pub fn plain_file_name(name: &str) -> Result<&str, PlanError> {
    let bad = |reason| {
        Err(PlanError::FileName {
            name: name.to_string(),
            reason,
        })
    };
    if name.is_empty() {
        return bad("it is empty");
    }
    if name.len() > 255 {
        return bad("it is longer than 255 bytes");
    }
    if name.contains('/') {
        return bad("it holds a '/'");
    }
    if name == "." || name == ".." {
        return bad("it names a directory");
    }
    if name.chars().any(char::is_control) {
        return bad("it holds a control character");
    }
    Ok(name)
}

/// The name inside a `{file:NAME}` placeholder, if `arg` is one.
pub fn placeholder(arg: &str) -> Option<&str> {
    arg.strip_prefix(FILE_PLACEHOLDER)?.strip_suffix('}')
}

impl JoinPlan {
    /// Whether the joining host takes this plan as its options say: unsealed frames only with
    /// `insecure_plain` (`qfleet join --insecure-plain`), and only the run `asked` (`--run`),
    /// if any. The refusal is the line the joining host prints.
    pub fn accept(&self, asked: Option<&str>, insecure_plain: bool) -> Result<(), String> {
        if self.plain && !insecure_plain {
            return Err(
                "the coordinator's host sends frames unencrypted (--insecure-plain \
                        there): join with --insecure-plain to accept that"
                    .into(),
            );
        }
        match asked {
            Some(run) if run != self.run_id => Err(format!(
                "the coordinator's host runs {:?}, not the run {run:?} asked for",
                self.run_id
            )),
            _ => Ok(()),
        }
    }

    /// Checks everything the joining host will use before it uses any of it: the run id, the
    /// robot count against `offered` (`--robots`), ids and fleet size, buffer sizes and
    /// deadlines, every shipped file name, and each robot's options (no `--out`, `--run-id`
    /// `--robot-id` `--robots` as the plan says, `--map`/`--scen` only built-in maps or a
    /// shipped file, placeholders nowhere else).
    pub fn check(&self, offered: u32) -> Result<(), PlanError> {
        check_run_id(&self.run_id)?;
        let n = self.robot_ids.len();
        if n == 0 {
            return Err(PlanError::NoRobots);
        }
        if n > offered as usize {
            return Err(PlanError::TooManyRobots { asked: n, offered });
        }
        let incons = |s: String| Err(PlanError::Inconsistent(s));
        if !(1..=bus::MAX_ROBOTS).contains(&self.robots_total) {
            return incons(format!(
                "fleet size {} is not 1..={}",
                self.robots_total,
                bus::MAX_ROBOTS
            ));
        }
        if self.robot_args.len() != n {
            return incons(format!(
                "{} robot ids but {} command lines",
                n,
                self.robot_args.len()
            ));
        }
        let mut ids = std::collections::BTreeSet::new();
        for &id in &self.robot_ids {
            if id >= self.robots_total || !ids.insert(id) {
                return incons(format!(
                    "robot id {id} is repeated or outside the fleet of {}",
                    self.robots_total
                ));
            }
        }
        for (what, v) in [
            ("hint buffer", self.hint_buffer),
            ("merged buffer", self.merged_buffer),
        ] {
            if !(1..=bus::MAX_BUFFER).contains(&v) {
                return incons(format!("{what} {v} is not 1..={}", bus::MAX_BUFFER));
            }
        }
        for (what, v) in [
            ("link-down time", self.down_after_ms),
            ("host deadline", self.deadline_ms),
        ] {
            if !(1..=MAX_PLAN_MS).contains(&v) {
                return incons(format!("{what} {v} ms is not 1..={MAX_PLAN_MS}"));
            }
        }
        if self.files.len() > MAX_PLAN_FILES {
            return Err(PlanError::TooLarge(format!(
                "{} files (at most {MAX_PLAN_FILES})",
                self.files.len()
            )));
        }
        for (name, text) in &self.files {
            plain_file_name(name)?;
            if text.len() > MAX_FILE_BYTES {
                return Err(PlanError::TooLarge(format!(
                    "file {name:?} of {} bytes (at most {MAX_FILE_BYTES})",
                    text.len()
                )));
            }
        }
        for (&id, args) in self.robot_ids.iter().zip(&self.robot_args) {
            self.check_args(id, args)?;
        }
        Ok(())
    }

    fn check_args(&self, id: u32, args: &[String]) -> Result<(), PlanError> {
        let refuse = |detail: String| Err(PlanError::Option { robot: id, detail });
        if args.len() > MAX_ROBOT_ARGS {
            return refuse(format!(
                "{} arguments (at most {MAX_ROBOT_ARGS})",
                args.len()
            ));
        }
        let mut it = args.iter();
        let mut seen_run_id = false;
        while let Some(a) = it.next() {
            if a.chars().any(|c| c == '\0') {
                return refuse("an argument holds a NUL".into());
            }
            let name = a.split('=').next().unwrap_or(a);
            if a.starts_with("--") && a.contains('=') && is_checked_option(name) {
                return refuse(format!("{name} given as {name}=VALUE"));
            }
            if a == "--" || a == "--out" {
                return refuse(format!("{a} is this host's to choose"));
            }
            if placeholder(a).is_some() {
                return refuse(format!("a file placeholder outside --map/--scen: {a:?}"));
            }
            let value = match a.as_str() {
                "--map" | "--scen" | "--run-id" | "--robot-id" | "--robots" => match it.next() {
                    Some(v) => v,
                    None => return refuse(format!("{a} without a value")),
                },
                _ => continue,
            };
            match a.as_str() {
                "--map" | "--scen" => {
                    let builtin = a == "--map"
                        && (value.starts_with("builtin:") || value.starts_with("suite:"));
                    match placeholder(value) {
                        Some(name) if self.files.contains_key(plain_file_name(name)?) => {}
                        Some(name) => {
                            return refuse(format!("{a} names file {name:?}, which was not sent"));
                        }
                        None if builtin => {}
                        None => {
                            return refuse(format!(
                                "{a} {value:?} is a path on this host (only a shipped file or a built-in map)"
                            ));
                        }
                    }
                }
                "--run-id" if *value != self.run_id => {
                    return refuse(format!(
                        "--run-id {value:?} is not the run's {:?}",
                        self.run_id
                    ));
                }
                "--run-id" => seen_run_id = true,
                "--robot-id" if *value != id.to_string() => {
                    return refuse(format!("--robot-id {value:?}"));
                }
                "--robots" if *value != self.robots_total.to_string() => {
                    return refuse(format!("--robots {value:?} is not the fleet size"));
                }
                _ => {}
            }
        }
        if !seen_run_id {
            return refuse("no --run-id".into());
        }
        Ok(())
    }

    /// Robot `i`'s command line on this host: each `{file:NAME}` becomes the path of NAME in
    /// `out` (call after [`JoinPlan::check`]; an unchecked name is refused again here).
    pub fn robot_command_line(
        &self,
        i: usize,
        out: &std::path::Path,
    ) -> Result<Vec<String>, PlanError> {
        let args = self.robot_args.get(i).map(Vec::as_slice).unwrap_or(&[]);
        args.iter()
            .map(|a| match placeholder(a) {
                Some(name) => Ok(out.join(plain_file_name(name)?).display().to_string()),
                None => Ok(a.clone()),
            })
            .collect()
    }
}

/// Options whose value [`JoinPlan::check`] looks at, refused in their `--opt=VALUE` form.
fn is_checked_option(name: &str) -> bool {
    matches!(
        name,
        "--map" | "--scen" | "--run-id" | "--robot-id" | "--robots" | "--out"
    )
}

/// What the hub offers to joining hosts (the run's side of [`JoinPlan`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RemotePlan {
    /// The run's id.
    pub run_id: String,
    /// Robots in the whole fleet.
    pub robots_total: u32,
    /// The first robot id served by other hosts (ids `first_remote..robots_total`).
    pub first_remote: u32,
    /// Every robot id's whole robot-agent command line except `--out` (index = robot id;
    /// local ones may be empty).
    pub robot_args: Vec<Vec<String>>,
    /// Files the options name.
    pub files: BTreeMap<String, String>,
    /// The coordinator's hint buffer per connection.
    pub hint_buffer: usize,
    /// The coordinator's merged-hint buffer per connection.
    pub merged_buffer: usize,
}

/// Longest host name a join may carry (it is stored and printed).
pub const MAX_HOST_NAME: usize = 64;

/// Who gets which robot ids; refuses what cannot work. Ids are taken only by a valid join and
/// come back ([`Admission::release`]) when a host does not start its robots in time; once the
/// join window closes ([`Admission::close`]) the ids still free are given up for good.
#[derive(Debug, Clone)]
pub struct Admission {
    free: std::collections::BTreeSet<u32>,
    closed: bool,
    /// Names of the hosts admitted, by host index.
    pub hosts: Vec<String>,
}

impl Admission {
    /// Hands out ids `first..end`.
    pub fn new(first: u32, end: u32) -> Self {
        Admission {
            free: (first..end).collect(),
            closed: false,
            hosts: Vec::new(),
        }
    }

    /// Remote robots not yet taken by a host.
    pub fn open_slots(&self) -> u32 {
        self.free.len() as u32
    }

    /// Admits a request: `(host index, robot ids)`, or the reason it is refused.
    pub fn admit(&mut self, req: &JoinRequest) -> Result<(u32, Vec<u32>), String> {
        if req.host.len() > MAX_HOST_NAME || req.host.chars().any(char::is_control) {
            let shown: String = req.host.chars().take(MAX_HOST_NAME).collect();
            return Err(format!(
                "host name {shown:?}… is longer than {MAX_HOST_NAME} bytes or holds control characters"
            ));
        }
        let ours = bus::bus_schema::SCHEMA_VERSION;
        if req.schema_version != ours {
            return Err(format!(
                "schema version mismatch: host {} speaks bus schema v{}, this run speaks v{ours}; \
                 run the same qfleet build on both hosts",
                req.host, req.schema_version
            ));
        }
        if req.little_endian != cfg!(target_endian = "little") {
            return Err(format!(
                "byte order mismatch: host {} has the other byte order; messages travel as \
                 their in-memory layout",
                req.host
            ));
        }
        if req.robots == 0 {
            return Err("a join must bring at least one robot".into());
        }
        if self.closed {
            return Err(format!(
                "host {} is too late: the run stopped waiting for other hosts",
                req.host
            ));
        }
        let open = self.open_slots();
        if req.robots > open {
            return Err(format!(
                "host {} offers {} robots but the run waits for {open} more",
                req.host, req.robots
            ));
        }
        let ids: Vec<u32> = self
            .free
            .iter()
            .copied()
            .take(req.robots as usize)
            .collect();
        for id in &ids {
            self.free.remove(id);
        }
        self.hosts.push(req.host.clone());
        Ok((self.hosts.len() as u32 - 1, ids))
    }

    /// A host did not start its robots in time: its ids can be taken by another host (or,
    /// after [`Admission::close`], are given up).
    pub fn release(&mut self, ids: &[u32]) {
        self.free.extend(ids);
    }

    /// The join window is over: no more joins; returns the ids no host holds, which the run
    /// goes on without.
    pub fn close(&mut self) -> Vec<u32> {
        self.closed = true;
        std::mem::take(&mut self.free).into_iter().collect()
    }

    /// Whether [`Admission::close`] was called.
    pub fn is_closed(&self) -> bool {
        self.closed
    }
}

/// Refused joins as a bounded log: the first [`RefusedLog::KEEP`] reasons are kept (each cut
/// to [`RefusedLog::REASON_LEN`] characters), the rest only counted.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct RefusedLog {
    /// Reasons kept.
    pub reasons: Vec<String>,
    /// Joins refused in all (kept or not).
    pub total: u64,
}

impl RefusedLog {
    /// Reasons kept at most.
    pub const KEEP: usize = 32;
    /// Characters kept of a reason.
    pub const REASON_LEN: usize = 300;

    /// Counts a refusal, keeping its reason while there is room; whether it was kept (the
    /// caller logs only kept ones, so a flood does not fill the log either).
    pub fn push(&mut self, reason: &str) -> bool {
        self.total += 1;
        if self.reasons.len() >= Self::KEEP {
            return false;
        }
        self.reasons
            .push(reason.chars().take(Self::REASON_LEN).collect());
        true
    }

    /// Refusals counted but not kept.
    pub fn dropped(&self) -> u64 {
        self.total - self.reasons.len() as u64
    }
}

/// Refuses a join secret that names another run than the one `asked` for (`qfleet join
/// --run`), before anything connects.
pub fn secret_for(secret: &crate::seal::Secret, asked: Option<&str>) -> Result<(), String> {
    match asked {
        Some(run) if run != secret.run_id() => Err(format!(
            "the join secret is for run {:?}, not the run {run:?} asked for",
            secret.run_id()
        )),
        _ => Ok(()),
    }
}

/// This host's name as a joining host reports it by default: the kernel's hostname, or
/// `remote` when it cannot be read.
pub fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "remote".into())
}

/// The host part of a Zenoh endpoint `proto/host:port` (brackets of an IPv6 address kept).
pub fn endpoint_host(endpoint: &str) -> &str {
    let addr = endpoint.split_once('/').map_or(endpoint, |(_, a)| a);
    addr.rsplit_once(':').map_or(addr, |(h, _)| h)
}

/// Whether `host` is an unspecified address (every interface).
pub fn every_interface(host: &str) -> bool {
    matches!(host, "0.0.0.0" | "[::]" | "::" | "")
}

/// The endpoint another host joins: `endpoint` itself, or with `<this-host-address>` in place
/// of an unspecified address (`tcp/0.0.0.0:7447` is not where anyone can connect).
pub fn join_hint(endpoint: &str) -> String {
    let host = endpoint_host(endpoint);
    if !every_interface(host) {
        return endpoint.to_string();
    }
    let (proto, addr) = endpoint.split_once('/').unwrap_or(("tcp", endpoint));
    let port = addr.rsplit_once(':').map_or("7447", |(_, p)| p);
    format!("{proto}/<this-host-address>:{port}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_joining_host_takes_only_the_run_and_sealing_it_asked_for() {
        let plan = |plain: bool| JoinPlan {
            run_id: "r1".into(),
            host_index: 0,
            robots_total: 2,
            robot_ids: vec![1],
            robot_args: vec![vec![]],
            files: BTreeMap::new(),
            hint_buffer: 64,
            merged_buffer: 64,
            down_after_ms: 500,
            deadline_ms: 10_000,
            t_ns: 0,
            plain,
        };
        assert_eq!(plan(false).accept(None, false), Ok(()));
        assert_eq!(plan(false).accept(Some("r1"), false), Ok(()));
        let e = plan(false).accept(Some("r2"), false).unwrap_err();
        assert!(e.contains("runs \"r1\", not the run \"r2\""), "{e}");
        assert!(
            plan(true)
                .accept(None, false)
                .unwrap_err()
                .contains("--insecure-plain")
        );
        assert_eq!(plan(true).accept(None, true), Ok(()));
        let s = crate::seal::Secret::generate("r1").unwrap();
        assert_eq!(secret_for(&s, None), Ok(()));
        assert_eq!(secret_for(&s, Some("r1")), Ok(()));
        assert!(
            secret_for(&s, Some("r2"))
                .unwrap_err()
                .contains("is for run \"r1\"")
        );
        assert!(!hostname().is_empty());
    }

    fn req(robots: u32) -> JoinRequest {
        JoinRequest::new("b".into(), robots, 1)
    }

    #[test]
    fn hosts_get_consecutive_ids_until_the_run_is_full() {
        let mut a = Admission::new(2, 6);
        assert_eq!(a.admit(&req(3)), Ok((0, vec![2, 3, 4])));
        assert_eq!(a.open_slots(), 1);
        let e = a.admit(&req(2)).unwrap_err();
        assert!(
            e.contains("offers 2 robots but the run waits for 1 more"),
            "{e}"
        );
        assert_eq!(a.admit(&req(1)), Ok((1, vec![5])));
        assert_eq!(a.open_slots(), 0);
    }

    #[test]
    fn another_schema_version_is_refused_with_both_versions_named() {
        let mut a = Admission::new(0, 4);
        let mut r = req(4);
        r.schema_version = 99;
        let e = a.admit(&r).unwrap_err();
        let ours = bus::bus_schema::SCHEMA_VERSION;
        assert!(e.contains("v99") && e.contains(&format!("v{ours}")), "{e}");
        assert_eq!(a.open_slots(), 4, "a refused host takes nothing");
    }

    #[test]
    fn zero_robots_and_the_other_byte_order_are_refused() {
        let mut a = Admission::new(0, 4);
        assert!(a.admit(&req(0)).is_err());
        let mut r = req(1);
        r.little_endian = !r.little_endian;
        assert!(a.admit(&r).unwrap_err().contains("byte order"));
    }

    fn plan() -> JoinPlan {
        let args = |id: u32| -> Vec<String> {
            [
                "--run-id",
                "r1",
                "--robot-id",
                &id.to_string(),
                "--robots",
                "4",
                "--map",
                "{file:m.map}",
                "--seed",
                "3",
            ]
            .iter()
            .map(|s| s.to_string())
            .collect()
        };
        JoinPlan {
            run_id: "r1".into(),
            host_index: 0,
            robots_total: 4,
            robot_ids: vec![2, 3],
            robot_args: vec![args(2), args(3)],
            files: BTreeMap::from([("m.map".into(), "map".into())]),
            hint_buffer: 64,
            merged_buffer: 64,
            down_after_ms: 500,
            deadline_ms: 10_000,
            t_ns: 1,
            plain: false,
        }
    }

    #[test]
    fn a_plan_as_the_hub_makes_it_passes_and_places_files_inside_out() {
        let p = plan();
        assert_eq!(p.check(2), Ok(()));
        let line = p.robot_command_line(0, std::path::Path::new("/o")).unwrap();
        assert!(line.contains(&"/o/m.map".to_string()), "{line:?}");
    }

    #[test]
    fn a_run_id_outside_the_launchers_rule_is_refused() {
        for bad in [
            "../x",
            "a/b",
            "..",
            "",
            "-x",
            "a.b",
            "a\u{1b}[2J",
            &"a".repeat(49),
        ] {
            let mut p = plan();
            p.run_id = bad.into();
            assert_eq!(p.check(2), Err(PlanError::RunId(bad.into())), "{bad:?}");
        }
    }

    #[test]
    fn more_robots_than_offered_are_refused() {
        let mut p = plan();
        p.robot_ids = (0..40).collect();
        p.robots_total = 40;
        assert_eq!(
            p.check(1),
            Err(PlanError::TooManyRobots {
                asked: 40,
                offered: 1
            })
        );
        assert!(
            plan()
                .check(1)
                .unwrap_err()
                .to_string()
                .contains("offered 1")
        );
    }

    #[test]
    fn file_names_are_plain_names_only() {
        for bad in [
            "../etc/passwd",
            "/etc/passwd",
            "a/b",
            "..",
            ".",
            "",
            "a\0b",
            "a\u{1b}b",
        ] {
            assert!(plain_file_name(bad).is_err(), "{bad:?}");
            let mut p = plan();
            p.files.insert(bad.into(), "x".into());
            assert!(
                matches!(p.check(2), Err(PlanError::FileName { .. })),
                "{bad:?}"
            );
        }
        assert_eq!(plain_file_name("maze-1.map"), Ok("maze-1.map"));
    }

    #[test]
    fn a_placeholder_cannot_point_outside_out() {
        let mut p = plan();
        p.robot_args[0][7] = "{file:../../etc/shadow}".into();
        assert!(matches!(p.check(2), Err(PlanError::FileName { .. })));
        let err = p
            .robot_command_line(0, std::path::Path::new("/o"))
            .unwrap_err();
        assert!(matches!(err, PlanError::FileName { .. }));
        // a name that was not shipped
        let mut p = plan();
        p.robot_args[0][7] = "{file:other.map}".into();
        assert!(matches!(
            p.check(2),
            Err(PlanError::Option { robot: 2, .. })
        ));
    }

    #[test]
    fn a_path_on_this_host_an_out_or_another_run_is_refused() {
        let cases: [(usize, &str); 6] = [
            (7, "/etc/shadow"),
            (7, "relative/map"),
            (1, "other-run"),
            (3, "7"),
            (5, "99"),
            (8, "{file:m.map}"),
        ];
        for (i, v) in cases {
            let mut p = plan();
            p.robot_args[0][i] = v.into();
            assert!(
                matches!(p.check(2), Err(PlanError::Option { robot: 2, .. })),
                "arg {i} = {v:?}"
            );
        }
        for extra in [
            vec!["--out", "/tmp/x"],
            vec!["--map=/etc/shadow"],
            vec!["--out=/x"],
            vec!["--", "x"],
        ] {
            let mut p = plan();
            p.robot_args[0].extend(extra.iter().map(|s| s.to_string()));
            assert!(
                matches!(p.check(2), Err(PlanError::Option { robot: 2, .. })),
                "{extra:?}"
            );
        }
        let mut p = plan();
        p.robot_args[0][7] = "builtin:paper-20".into();
        assert_eq!(p.check(2), Ok(()), "built-in maps need no file");
    }

    #[test]
    fn inconsistent_plans_are_refused() {
        let mut p = plan();
        p.robot_ids = vec![2, 2];
        assert!(matches!(p.check(2), Err(PlanError::Inconsistent(_))));
        let mut p = plan();
        p.robot_ids = vec![2, 9];
        assert!(matches!(p.check(2), Err(PlanError::Inconsistent(_))));
        let mut p = plan();
        p.robot_args.pop();
        assert!(matches!(p.check(2), Err(PlanError::Inconsistent(_))));
        let mut p = plan();
        p.merged_buffer = usize::MAX;
        assert!(matches!(p.check(2), Err(PlanError::Inconsistent(_))));
        let mut p = plan();
        p.robot_ids.clear();
        p.robot_args.clear();
        assert_eq!(p.check(2), Err(PlanError::NoRobots));
    }

    #[test]
    fn released_slots_go_to_the_next_host_and_close_gives_up_the_rest() {
        let mut a = Admission::new(2, 6);
        let (_, stranger) = a.admit(&req(4)).unwrap();
        assert!(a.admit(&req(1)).is_err(), "all slots taken");
        a.release(&stranger);
        assert_eq!(a.admit(&req(3)), Ok((1, vec![2, 3, 4])));
        assert_eq!(a.close(), vec![5]);
        assert!(a.admit(&req(1)).unwrap_err().contains("too late"));
        assert_eq!(a.open_slots(), 0);
    }

    #[test]
    fn a_long_or_control_character_host_name_is_refused() {
        let mut a = Admission::new(0, 4);
        let mut r = req(1);
        r.host = "x".repeat(10_000);
        let e = a.admit(&r).unwrap_err();
        assert!(
            e.len() < 200,
            "the reason does not carry the whole name: {}",
            e.len()
        );
        r.host = "evil\u{1b}]0;title\u{7}".into();
        assert!(a.admit(&r).is_err());
        assert_eq!(a.open_slots(), 4);
    }

    #[test]
    fn refused_joins_are_counted_but_only_the_first_reasons_kept() {
        let mut log = RefusedLog::default();
        let long = "r".repeat(10_000);
        for _ in 0..10_000 {
            log.push(&long);
        }
        assert_eq!(log.total, 10_000);
        assert_eq!(log.reasons.len(), RefusedLog::KEEP);
        assert_eq!(log.dropped(), 10_000 - RefusedLog::KEEP as u64);
        assert!(
            log.reasons
                .iter()
                .all(|r| r.len() == RefusedLog::REASON_LEN)
        );
    }

    #[test]
    fn a_reply_round_trips_through_json() {
        let r = JoinReply::Refused { reason: "x".into() };
        let back: JoinReply = serde_json::from_str(&serde_json::to_string(&r).unwrap()).unwrap();
        assert_eq!(back, r);
    }

    use crate::seal::{SECRET_BYTES, Secret};

    fn secret(b: u8, run: &str) -> Secret {
        Secret::new(run, [b; SECRET_BYTES])
    }

    fn tiny_plan() -> JoinPlan {
        JoinPlan {
            run_id: "run-1".into(),
            host_index: 0,
            robots_total: 2,
            robot_ids: vec![1],
            robot_args: vec![vec![]],
            files: BTreeMap::new(),
            hint_buffer: 1,
            merged_buffer: 1,
            down_after_ms: 1,
            deadline_ms: 1,
            t_ns: 1,
            plain: false,
        }
    }

    fn ask(a: &JoinAsk) -> Vec<u8> {
        serde_json::to_vec(a).unwrap()
    }

    /// B's full exchange with `door` at `now_ms`: hello, challenge, join.
    fn exchange(door: &mut Door, b: &Knocker, robots: u32, now_ms: u64) -> Knock {
        let Knock::Answer(JoinReply::Challenge { cookie }) = door.knock(&ask(&b.hello()), now_ms)
        else {
            panic!("a hello gets a challenge");
        };
        let (j, _) = b.join(&cookie, req(robots)).unwrap();
        door.knock(&ask(&j), now_ms)
    }

    #[test]
    fn only_a_join_proving_the_secret_gets_through_the_door() {
        let mut door = Door::new(secret(1, "run-1")).unwrap();
        let b = Knocker::new(secret(1, "run-1")).unwrap();
        let Knock::Proven { request, keys } = exchange(&mut door, &b, 2, 1000) else {
            panic!("the secret's holder is let in");
        };
        assert_eq!(request.robots, 2);
        assert_eq!(door.unauthenticated, 0);
        // another secret, or the same bytes for another run: refused, counted, nothing more
        for other in [secret(2, "run-1"), secret(1, "run-2")] {
            let k = Knocker::new(other).unwrap();
            assert!(matches!(
                exchange(&mut door, &k, 2, 1000),
                Knock::Answer(JoinReply::Refused { .. })
            ));
        }
        assert_eq!(door.unauthenticated, 2);
        // B opens the plan the hub sealed with the same join's keys
        let plan = tiny_plan();
        let sealed = crate::seal::hex(&keys.seal_plan(&serde_json::to_vec(&plan).unwrap()));
        let (_, b_keys) = b.join(&crate::seal::hex(&[0; 32]), req(2)).unwrap();
        assert!(b.open(&b_keys, &sealed).is_err(), "another join's keys");
    }

    #[test]
    fn b_refuses_a_plan_for_another_run_even_from_a_holder_of_the_secret() {
        let mut door = Door::new(secret(1, "run-1")).unwrap();
        let b = Knocker::new(secret(1, "run-1")).unwrap();
        let Knock::Answer(JoinReply::Challenge { cookie }) = door.knock(&ask(&b.hello()), 1) else {
            panic!()
        };
        let (j, b_keys) = b.join(&cookie, req(1)).unwrap();
        let Knock::Proven { keys, .. } = door.knock(&ask(&j), 1) else {
            panic!()
        };
        let mut plan = tiny_plan();
        let seal =
            |p: &JoinPlan| crate::seal::hex(&keys.seal_plan(&serde_json::to_vec(p).unwrap()));
        assert_eq!(b.open(&b_keys, &seal(&plan)).unwrap(), plan);
        plan.run_id = "run-9".into();
        let e = b.open(&b_keys, &seal(&plan)).unwrap_err();
        assert!(e.contains("not the run \"run-1\""), "{e}");
        // a plan sealed by someone without the secret does not open
        let stranger = crate::seal::HostKeys::new(&secret(7, "run-1"), &[0; 32], &[0; 16]);
        let forged = crate::seal::hex(&stranger.seal_plan(b"{}"));
        assert!(b.open(&b_keys, &forged).is_err());
    }

    #[test]
    fn a_replayed_forged_or_flooding_join_takes_no_slot() {
        let mut door = Door::new(secret(1, "run-1")).unwrap();
        let mut admission = Admission::new(0, 4);
        let b = Knocker::new(secret(1, "run-1")).unwrap();
        let Knock::Answer(JoinReply::Challenge { cookie }) = door.knock(&ask(&b.hello()), 1) else {
            panic!()
        };
        let (j, _) = b.join(&cookie, req(1)).unwrap();
        let mut admitted = 0;
        let mut try_admit = |k: Knock, admission: &mut Admission| {
            if let Knock::Proven { request, .. } = k {
                admission.admit(&request).unwrap();
                admitted += 1;
            }
        };
        try_admit(door.knock(&ask(&j), 2), &mut admission);
        // the same join replayed by whoever saw it on the wire
        try_admit(door.knock(&ask(&j), 3), &mut admission);
        // a stranger's joins: made-up cookies and proofs, a cookie of ours with a made-up
        // proof, a request for every slot with a proof of a smaller one, garbage, a huge query
        let JoinAsk::Join {
            cookie: c2, nonce, ..
        } = b.join(&cookie, req(1)).unwrap().0
        else {
            panic!()
        };
        let mut flood = vec![
            ask(&JoinAsk::Join {
                cookie: crate::seal::hex(&[1; 32]),
                nonce: nonce.clone(),
                request: req(4),
                proof: crate::seal::hex(&[0; 32]),
            }),
            ask(&JoinAsk::Join {
                cookie: c2,
                nonce,
                request: req(4),
                proof: crate::seal::hex(&[0; 32]),
            }),
            b"not json".to_vec(),
            vec![b' '; MAX_ASK + 1],
        ];
        if let JoinAsk::Join {
            cookie,
            nonce,
            proof,
            ..
        } = b.join(&cookie, req(1)).unwrap().0
        {
            flood.push(ask(&JoinAsk::Join {
                cookie,
                nonce,
                request: req(4),
                proof,
            }));
        }
        for _ in 0..1000 {
            for f in &flood {
                try_admit(door.knock(f, 4), &mut admission);
            }
        }
        assert_eq!(admitted, 1);
        assert_eq!(admission.open_slots(), 3);
        assert_eq!(door.unauthenticated, 1 + 5000);
        // a hello flood answers challenges and keeps nothing
        for _ in 0..10_000 {
            door.knock(&ask(&b.hello()), 5);
        }
        assert_eq!(door.challenges.spent(), 1);
    }
}
