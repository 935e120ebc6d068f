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

/// What the coordinator's host answers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum JoinReply {
    /// Come in: run these robots.
    Accepted(JoinPlan),
    /// Not this host: why.
    Refused {
        /// Readable reason, printed on both hosts.
        reason: String,
    },
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

/// Who gets which robot ids; refuses what cannot work.
#[derive(Debug, Clone)]
pub struct Admission {
    next: u32,
    end: u32,
    /// Names of the hosts admitted, by host index.
    pub hosts: Vec<String>,
}

impl Admission {
    /// Hands out ids `first..end`.
    pub fn new(first: u32, end: u32) -> Self {
        Admission {
            next: first,
            end,
            hosts: Vec::new(),
        }
    }

    /// Remote robots not yet taken by a host.
    pub fn open_slots(&self) -> u32 {
        self.end - self.next
    }

    /// Admits a request: `(host index, robot ids)`, or the reason it is refused.
    pub fn admit(&mut self, req: &JoinRequest) -> Result<(u32, std::ops::Range<u32>), String> {
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
        let open = self.open_slots();
        if req.robots > open {
            return Err(format!(
                "host {} offers {} robots but the run waits for {open} more",
                req.host, req.robots
            ));
        }
        let ids = self.next..self.next + req.robots;
        self.next += req.robots;
        self.hosts.push(req.host.clone());
        Ok((self.hosts.len() as u32 - 1, ids))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn req(robots: u32) -> JoinRequest {
        JoinRequest::new("b".into(), robots, 1)
    }

    #[test]
    fn hosts_get_consecutive_ids_until_the_run_is_full() {
        let mut a = Admission::new(2, 6);
        assert_eq!(a.admit(&req(3)), Ok((0, 2..5)));
        assert_eq!(a.open_slots(), 1);
        let e = a.admit(&req(2)).unwrap_err();
        assert!(
            e.contains("offers 2 robots but the run waits for 1 more"),
            "{e}"
        );
        assert_eq!(a.admit(&req(1)), Ok((1, 5..6)));
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

    #[test]
    fn a_reply_round_trips_through_json() {
        let r = JoinReply::Refused { reason: "x".into() };
        let back: JoinReply = serde_json::from_str(&serde_json::to_string(&r).unwrap()).unwrap();
        assert_eq!(back, r);
    }
}
