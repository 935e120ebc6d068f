//! The listening run's decisions around the hub (`qfleet run … --remote-robots K --listen E`
//! and `qfleet experiment`): how many robots the fleet counts ([`fleet_total`]), when a remote
//! robot may count as hung ([`hang_ms`]), what to say before listening ([`listen_warning`]),
//! the plan the hub offers with the files its options name ([`remote_plan`]), the run's join
//! secret on disk ([`read_secret`], [`write_secret`]), and what a finished hub's report says to
//! a person ([`HubReport::warnings`], [`HubReport::summary`]).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::join::{FILE_PLACEHOLDER, endpoint_host, every_interface, join_hint};
use crate::{HubReport, RemotePlan, Secret};

/// The environment variable a join secret may come in (instead of `--secret-file`).
pub const SECRET_ENV: &str = "QFLEET_JOIN_SECRET";

/// The file a listening run writes its join secret into, in its out directory.
pub const SECRET_FILE: &str = "join.secret";

/// How long after a host's deadline its silent robots may first count as hung: the hub's
/// drop of their nodes and the coordinator's next node listings (every few hundred ms) fit
/// well inside it.
pub const LOSS_MARGIN_MS: u64 = 2000;

/// Why the listening side could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum ListenError {
    /// The join secret file could not be read.
    #[error("reading the join secret {}", path.display())]
    ReadSecret {
        /// The file.
        path: PathBuf,
        /// The system's error.
        source: std::io::Error,
    },
    /// The join secret (from a file or the environment) is not one.
    #[error("reading the join secret from {what}")]
    ParseSecret {
        /// The file or [`SECRET_ENV`].
        what: String,
        /// Why it is not a secret.
        source: crate::seal::AuthError,
    },
    /// A file could not be written (the secret, a file the plan names).
    #[error("writing {}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// The system's error.
        source: std::io::Error,
    },
    /// A file a robot's options name could not be read to ship it.
    #[error("reading {} to send it to joining hosts", path.display())]
    Ship {
        /// The file.
        path: PathBuf,
        /// The system's error.
        source: std::io::Error,
    },
    /// Local and remote robots exceed the fleet limit.
    #[error(
        "--robots {local} + --remote-robots {remote} = {total} exceeds the fleet limit {}",
        bus::MAX_ROBOTS
    )]
    TooMany {
        /// Robots of this host.
        local: u32,
        /// Robots of other hosts.
        remote: u32,
        /// Their sum.
        total: u64,
    },
}

/// A duration option of the bridge's sides (`--host-deadline`, `--join-within`, `qfleet join
/// --timeout` …) given in seconds: `flag` names it in the refusal of a negative or non-finite
/// value.
pub fn seconds(flag: &str, v: f64) -> Result<std::time::Duration, String> {
    std::time::Duration::try_from_secs_f64(v)
        .map_err(|_| format!("{flag} must be seconds >= 0, got {v}"))
}

/// Local plus remote robots, checked against the fleet limit.
pub fn fleet_total(local: u32, remote: u32) -> Result<u32, ListenError> {
    let total = u64::from(local) + u64::from(remote);
    match u32::try_from(total) {
        Ok(t) if t <= bus::MAX_ROBOTS => Ok(t),
        _ => Err(ListenError::TooMany {
            local,
            remote,
            total,
        }),
    }
}

/// The coordinator's `--hang-ms` for a run with `remote_robots`: past the host deadline by
/// [`LOSS_MARGIN_MS`], so a link that is down (robots on the other host learning alone) is not
/// mistaken for hung robots, and a host given up on has its robots reported lost (the hub
/// drops their nodes, the coordinator's next listing sees them gone) before their silence
/// could make them hung. At exactly the deadline the two raced: a killed host's robots came
/// out `hung` in one CI-clone run of `tests/multihost.rs`.
pub fn hang_ms(remote_robots: u32, host_deadline_s: f64, hang_ms: u64) -> u64 {
    if remote_robots == 0 {
        return hang_ms;
    }
    hang_ms.max((host_deadline_s.max(0.0) * 1000.0) as u64 + LOSS_MARGIN_MS)
}

/// What to say before listening on `endpoint`: frames sent unencrypted (`plain`), and that the
/// other hosts join with this host's own address when it listens on every interface.
pub fn listen_warning(endpoint: &str, plain: bool) -> Option<String> {
    if plain {
        return Some(format!(
            "warning: --insecure-plain: after the join, frames to and from {} cross the network \
             unencrypted and unauthenticated: anyone on the path can read them and forge acks, \
             goodbyes and messages (README \"Threat model, network side\"); for measuring only",
            report::escape(endpoint)
        ));
    }
    if every_interface(endpoint_host(endpoint)) {
        return Some(format!(
            "listening on every interface ({}): the other hosts join with this host's own \
             address, e.g. `qfleet join {} --secret-file join.secret`",
            report::escape(endpoint),
            join_hint(endpoint)
        ));
    }
    None
}

/// The plan the hub offers: remote robots get ids `local..total` and `robot(id)`, the
/// robot-agent options a local robot of that id would get, less `--out DIR` (a joining host
/// writes into its own directory), with the paths after `--map` (unless built-in or generated)
/// and `--scen` replaced by `{file:NAME}` and their content shipped in the plan, so the
/// joining host needs no copy of them.
pub fn remote_plan(
    run_id: &str,
    local: u32,
    total: u32,
    hint_buffer: usize,
    merged_buffer: usize,
    robot: &dyn Fn(u32) -> Vec<String>,
) -> Result<RemotePlan, ListenError> {
    let mut files = BTreeMap::new();
    let mut robot_args = vec![Vec::new(); local as usize];
    for id in local..total {
        robot_args.push(ship_files(without_out(robot(id)), &mut files)?);
    }
    Ok(RemotePlan {
        run_id: run_id.to_string(),
        robots_total: total,
        first_remote: local,
        robot_args,
        files,
        hint_buffer,
        merged_buffer,
    })
}

/// A robot-agent command line without `--out DIR`.
fn without_out(words: Vec<String>) -> Vec<String> {
    let mut out = Vec::new();
    let mut it = words.into_iter();
    while let Some(a) = it.next() {
        if a == "--out" {
            it.next();
            continue;
        }
        out.push(a);
    }
    out
}

/// Replaces the paths after `--map` (unless built-in or generated) and `--scen` with
/// `{file:NAME}` and keeps their content in `files`.
fn ship_files(
    cli: Vec<String>,
    files: &mut BTreeMap<String, String>,
) -> Result<Vec<String>, ListenError> {
    let mut out = Vec::with_capacity(cli.len());
    let mut it = cli.into_iter();
    while let Some(a) = it.next() {
        let is_file_opt = a == "--map" || a == "--scen";
        out.push(a);
        let Some(v) = (if is_file_opt { it.next() } else { None }) else {
            continue;
        };
        if v.starts_with("builtin:") || v.starts_with("suite:") {
            out.push(v);
            continue;
        }
        let path = PathBuf::from(&v);
        let text = std::fs::read_to_string(&path).map_err(|source| ListenError::Ship {
            path: path.clone(),
            source,
        })?;
        let base = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "map".into());
        // two different files of the same name (robots of an experiment) keep both
        let mut name = base.clone();
        let mut n = 1;
        while files.get(&name).is_some_and(|t| *t != text) {
            n += 1;
            name = format!("{n}-{base}");
        }
        out.push(format!("{FILE_PLACEHOLDER}{name}}}"));
        files.insert(name, text);
    }
    Ok(out)
}

/// Reads a join secret from `file`, else from [`SECRET_ENV`]; None when neither is given. A
/// file others may read is used, and `warn` is told so.
pub fn read_secret(
    file: Option<&Path>,
    warn: &dyn Fn(&str),
) -> Result<Option<Secret>, ListenError> {
    use std::os::unix::fs::PermissionsExt;
    let read_err = |f: &Path| {
        let path = f.to_path_buf();
        move |source| ListenError::ReadSecret { path, source }
    };
    let text = match file {
        Some(f) => {
            let meta = std::fs::metadata(f).map_err(read_err(f))?;
            if meta.permissions().mode() & 0o077 != 0 {
                warn(&format!(
                    "warning: the join secret {} can be read by other users (chmod 600 it)",
                    f.display()
                ));
            }
            std::fs::read_to_string(f).map_err(read_err(f))?
        }
        None => match std::env::var(SECRET_ENV) {
            Ok(t) => t,
            Err(_) => return Ok(None),
        },
    };
    let what = file.map_or(SECRET_ENV.to_string(), |f| f.display().to_string());
    Secret::parse(&text)
        .map(Some)
        .map_err(|source| ListenError::ParseSecret { what, source })
}

/// Writes `secret` into `dir/join.secret`, readable by this user only.
pub fn write_secret(dir: &Path, secret: &Secret) -> Result<PathBuf, ListenError> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let path = dir.join(SECRET_FILE);
    let _ = std::fs::remove_file(&path);
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(&path)
        .and_then(|mut f| writeln!(f, "{}", secret.text()))
        .map_err(|source| ListenError::Write {
            path: path.clone(),
            source,
        })?;
    Ok(path)
}

impl HubReport {
    /// What a person should hear once the hub finished: remote robots that did not join, and
    /// refused joins whose reasons were not all kept.
    pub fn warnings(&self) -> Vec<String> {
        let mut w = Vec::new();
        if self.joined_robots < self.remote_robots {
            w.push(format!(
                "only {} of {} remote robots joined on {} (start `qfleet join {} --robots N` on the other hosts within --join-within of the start)",
                self.joined_robots,
                self.remote_robots,
                self.listen,
                join_hint(&self.listen)
            ));
        }
        if self.refused_total > self.refused.len() as u64 {
            w.push(format!(
                "{} joins refused in all; the first {} reasons are in bridge.json",
                self.refused_total,
                self.refused.len()
            ));
        }
        w
    }

    /// The `hosts` lines of `qfleet run`'s human output (robots `0..local` ran here): where
    /// each robot ran and what the link to each joined host did.
    pub fn summary(&self, local: u32) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "  hosts              local: robots 0..{}; {} of {} remote robots joined on {}",
            local.saturating_sub(1),
            self.joined_robots,
            self.remote_robots,
            self.listen
        );
        for h in &self.hosts {
            let state = h
                .state
                .map(|s| serde_json::to_string(&s).unwrap_or_default())
                .unwrap_or_default();
            let _ = writeln!(
                s,
                "  host {:13} robots {:?}  link {}  reconnects {}  down {} ms  round trip p50 {:.1} µs p99.9 {:.1} µs  one-way in p50 {:.1} µs  resent {}  rejected {}  capped {}  forged {}",
                report::escape(&h.host),
                h.robots,
                state.trim_matches('"'),
                h.link.reconnects,
                h.link.down_ms,
                h.link.rtt_ns.p50 as f64 / 1e3,
                h.link.rtt_ns.p999 as f64 / 1e3,
                h.link.one_way_in_ns.p50 as f64 / 1e3,
                h.link.resent,
                h.link.rejected,
                h.link.capped,
                h.link.forged
            );
        }
        for r in &self.refused {
            let _ = writeln!(s, "  refused join       {}", report::escape(r));
        }
        if self.refused_total > self.refused.len() as u64 {
            let _ = writeln!(
                s,
                "  refused joins      {} in all ({} not kept)",
                self.refused_total,
                self.refused_total - self.refused.len() as u64
            );
        }
        if self.unauthenticated > 0 {
            let _ = writeln!(
                s,
                "  unauthenticated    {} join queries without a valid proof of the join secret (dropped)",
                self.unauthenticated
            );
        }
        if !self.given_up.is_empty() || self.foreign_frames > 0 || self.expired_hosts > 0 {
            let _ = writeln!(
                s,
                "  not joined         robots {:?} given up; {} host(s) did not start in time; {} frame(s) from no joined host",
                self.given_up, self.expired_hosts, self.foreign_frames
            );
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_frames_warn_and_the_hint_names_a_reachable_address() {
        for quiet in [
            "tcp/127.0.0.1:7447",
            "tcp/10.0.0.1:7447",
            "tcp/8.8.8.8:7447",
            "tcp/[::1]:7447",
            "tcp/hub.lan:7447",
        ] {
            // joins are authenticated and frames sealed: no address needs a warning
            assert_eq!(listen_warning(quiet, false), None, "{quiet}");
            assert_eq!(join_hint(quiet), quiet);
            let w = listen_warning(quiet, true).expect("plain frames always warn");
            assert!(w.contains("unencrypted"), "{w}");
        }
        let w = listen_warning("tcp/0.0.0.0:7447", false).expect("a note");
        assert!(
            w.contains("every interface") && w.contains("tcp/<this-host-address>:7447"),
            "{w}"
        );
        assert!(!w.contains("join tcp/0.0.0.0"), "{w}");
        assert_eq!(join_hint("tcp/[::]:9000"), "tcp/<this-host-address>:9000");
    }

    #[test]
    fn a_written_secret_is_private_and_reads_back() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("qfleet-secret-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let s = Secret::generate("run-7").unwrap();
        let path = write_secret(&dir, &s).unwrap();
        let mode = std::fs::metadata(&path).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600);
        let quiet = |w: &str| panic!("a private secret file warns: {w}");
        assert_eq!(read_secret(Some(&path), &quiet).unwrap(), Some(s.clone()));
        // written again (the next seed of an experiment): replaced, still private
        write_secret(&dir, &s).unwrap();
        std::fs::write(dir.join("bad"), "not a secret").unwrap();
        assert!(read_secret(Some(&dir.join("bad")), &|_| {}).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn remote_robots_turn_hung_only_well_after_their_host_is_given_up() {
        // a killed host's robots must come out lost, not hung: the hang deadline is later
        assert_eq!(hang_ms(2, 3.0, 2000), 3000 + LOSS_MARGIN_MS);
        // a longer hang deadline asked for is kept; a local-only run is untouched
        assert_eq!(hang_ms(2, 3.0, 60_000), 60_000);
        assert_eq!(hang_ms(0, 3.0, 2000), 2000);
    }

    #[test]
    fn seconds_are_finite_and_not_negative() {
        assert_eq!(seconds("--grace", 1.5).unwrap().as_millis(), 1500);
        let e = seconds("--grace", -1.0).unwrap_err();
        assert_eq!(e, "--grace must be seconds >= 0, got -1");
        assert!(seconds("--timeout", f64::NAN).is_err());
    }

    #[test]
    fn the_fleet_limit_counts_both_hosts() {
        assert_eq!(fleet_total(3, 2).unwrap(), 5);
        let e = fleet_total(bus::MAX_ROBOTS, 1).unwrap_err().to_string();
        assert!(e.contains("exceeds the fleet limit"), "{e}");
        assert!(fleet_total(u32::MAX, u32::MAX).is_err());
    }

    #[test]
    fn shipped_files_replace_their_paths_and_out_stays_home() {
        let dir = std::env::temp_dir().join(format!("qfleet-ship-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let map = dir.join("w.map");
        std::fs::write(&map, "type octile\n").unwrap();
        let words = |id: u32| -> Vec<String> {
            let mut v: Vec<String> = vec!["--robot-id".into(), id.to_string()];
            v.extend(["--map".into(), map.display().to_string()]);
            v.extend(["--out".into(), "/tmp/a".into(), "--scen".into()]);
            v.push(
                if id == 2 {
                    "builtin:paper-10"
                } else {
                    "suite:x"
                }
                .into(),
            );
            v
        };
        let plan = remote_plan("r", 1, 3, 64, 32, &words).unwrap();
        assert_eq!(plan.robot_args[0], Vec::<String>::new());
        assert_eq!(
            plan.robot_args[1],
            [
                "--robot-id",
                "1",
                "--map",
                "{file:w.map}",
                "--scen",
                "suite:x"
            ]
        );
        assert_eq!(plan.files["w.map"], "type octile\n");
        assert_eq!(plan.robot_args[2][5], "builtin:paper-10");
        let missing = |_| {
            vec![
                "--map".to_string(),
                dir.join("no.map").display().to_string(),
            ]
        };
        assert!(matches!(
            remote_plan("r", 0, 1, 64, 32, &missing),
            Err(ListenError::Ship { .. })
        ));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
