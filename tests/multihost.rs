//! A run across two hosts, for real: two network namespaces joined by a veth pair, each "host"
//! with its own mount namespace holding a private tmpfs on `/dev/shm` and on iceoryx2's root
//! (`/tmp/iceoryx2`), so the only path between the coordinator's host (A, 10.77.0.1) and the
//! joining host (B, 10.77.0.2) is the network. Addresses exist only inside those namespaces.
//!
//! Needs root, `ip` (iproute2) and `unshare` (util-linux); without them every test says
//! `SKIPPED` and why, and passes. Every namespace, link and mount is removed when a test ends,
//! failed or not (the mounts die with their mount namespaces; the namespaces are deleted by
//! [`TwoHosts`]'s `Drop`, after every process in them is killed), and each test checks that its
//! run left nothing in the outer system's `/dev/shm` or `/tmp/iceoryx2`.
//!
//! The tests take turns (a lock): each runs a fleet on both "hosts", and several at once on
//! two cores would turn the link-down test's 2 s outage into noise.
//!
//! Both hosts get the run's join secret from a file (`--secret-file`), as a user copies it;
//! [`a_stranger_on_the_network_reads_nothing_forges_nothing_and_takes_no_slot`] adds a third
//! party on the network: this test binary itself, re-run inside host B's namespace as a plain
//! Zenoh session ([`stranger_role`]).

use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use qfleet_suite::{Scratch, bin, describe, leftovers, run_id, scratch, skip, wait_bounded};
use serde_json::Value;

/// One test at a time (see the module doc); a failed test does not poison the others.
static TURN: Mutex<()> = Mutex::new(());

const ENDPOINT: &str = "tcp/10.77.0.1:7447";
const LIMIT: Duration = Duration::from_secs(150);

/// One host of the pair.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Host {
    A,
    B,
}

/// Two network namespaces joined by a veth pair; deleted on drop.
struct TwoHosts {
    ns: [String; 2],
    veth: [String; 2],
}

fn sh(args: &[&str]) -> Result<(), String> {
    let out = Command::new(args[0])
        .args(&args[1..])
        .stdin(Stdio::null())
        .output()
        .map_err(|e| format!("{}: {e}", args[0]))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "`{}` failed: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

impl TwoHosts {
    /// The pair, or `None` after printing why this machine cannot make it.
    fn new(test: &str) -> Option<TwoHosts> {
        static N: AtomicU32 = AtomicU32::new(0);
        let skip = |why: String| {
            skip(&format!("multihost::{test}"), &why);
            None
        };
        // SAFETY: geteuid has no preconditions
        if unsafe { libc::geteuid() } != 0 {
            return skip("needs root (network and mount namespaces)".into());
        }
        for tool in ["ip", "unshare", "mount"] {
            if Command::new(tool).arg("--version").output().is_err() {
                return skip(format!("`{tool}` is not installed"));
            }
        }
        let n = N.fetch_add(1, Ordering::Relaxed);
        let tag = format!("{}{n}", std::process::id() % 100_000);
        let hosts = TwoHosts {
            ns: [format!("qfa{tag}"), format!("qfb{tag}")],
            veth: [format!("qva{tag}"), format!("qvb{tag}")],
        };
        let [na, nb] = &hosts.ns;
        let [va, vb] = &hosts.veth;
        let setup = (|| -> Result<(), String> {
            sh(&["ip", "netns", "add", na])?;
            sh(&["ip", "netns", "add", nb])?;
            sh(&["ip", "link", "add", va, "type", "veth", "peer", "name", vb])?;
            sh(&["ip", "link", "set", va, "netns", na])?;
            sh(&["ip", "link", "set", vb, "netns", nb])?;
            for (ns, v, addr) in [(na, va, "10.77.0.1/24"), (nb, vb, "10.77.0.2/24")] {
                sh(&["ip", "-n", ns, "addr", "add", addr, "dev", v])?;
                sh(&["ip", "-n", ns, "link", "set", v, "up"])?;
                sh(&["ip", "-n", ns, "link", "set", "lo", "up"])?;
            }
            Ok(())
        })();
        match setup {
            Ok(()) => Some(hosts),
            // dropping `hosts` removes whatever part was made
            Err(e) => skip(format!("network namespaces unsupported here: {e}")),
        }
    }

    fn ns(&self, host: Host) -> &str {
        &self.ns[host as usize]
    }

    /// `program args…` on `host`: in its network namespace, in a new mount namespace with a
    /// private tmpfs on /dev/shm and /tmp/iceoryx2.
    fn command(&self, host: Host, program: &Path, args: &[&str]) -> Command {
        let mut c = Command::new("ip");
        c.args([
            "netns",
            "exec",
            self.ns(host),
            "unshare",
            "-m",
            "--propagation",
            "private",
        ])
        .args([
            "sh",
            "-c",
            "mount -t tmpfs qfleet-shm /dev/shm && mkdir -p /tmp/iceoryx2 && \
                 mount -t tmpfs qfleet-iox /tmp/iceoryx2 && exec \"$0\" \"$@\"",
        ])
        .arg(program)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
        c
    }

    /// Gives `host`'s end of the link one more address (`10.77.0.N/24`): a third party's
    /// sockets bound to it come from another source than the host's own.
    fn add_address(&self, host: Host, cidr: &str) {
        let i = host as usize;
        sh(&[
            "ip",
            "-n",
            &self.ns[i],
            "addr",
            "add",
            cidr,
            "dev",
            &self.veth[i],
        ])
        .unwrap_or_else(|e| panic!("{e}"));
    }

    /// Sets host A's end of the link down or up.
    fn link(&self, up: bool) {
        let state = if up { "up" } else { "down" };
        sh(&["ip", "-n", &self.ns[0], "link", "set", &self.veth[0], state])
            .unwrap_or_else(|e| panic!("{e}"));
    }

    /// SIGKILLs every process on `host`.
    fn kill_all(&self, host: Host) {
        let out = Command::new("ip")
            .args(["netns", "pids", self.ns(host)])
            .output()
            .map(|o| String::from_utf8_lossy(&o.stdout).into_owned())
            .unwrap_or_default();
        for pid in out.split_whitespace().filter_map(|p| p.parse::<i32>().ok()) {
            // SAFETY: kill(2) with a pid read from the namespace's process list
            unsafe { libc::kill(pid, libc::SIGKILL) };
        }
    }
}

impl Drop for TwoHosts {
    fn drop(&mut self) {
        for host in [Host::A, Host::B] {
            self.kill_all(host);
        }
        std::thread::sleep(Duration::from_millis(100));
        for ns in &self.ns {
            let _ = sh(&["ip", "netns", "del", ns]); // takes its end of the veth pair with it
        }
        for v in &self.veth {
            let _ = sh(&["ip", "link", "del", v]); // only if it never moved into a namespace
        }
    }
}

/// A join secret for run `id` (or an experiment's run-id prefix) in a file of its own, mode
/// 0600, outside both hosts' `--out`.
fn secret_file(id: &str) -> (Scratch, String) {
    secret_file_in(id, "secret")
}

/// A fresh join secret for run `id` in a scratch directory of its own (`{id}-{tag}`): another
/// call gives the same run id with other key bytes, a wrong secret.
fn secret_file_in(id: &str, tag: &str) -> (Scratch, String) {
    use std::os::unix::fs::PermissionsExt;
    let dir = scratch(&format!("{id}-{tag}"));
    let path = dir.join("join.secret");
    let secret = bridge::Secret::generate(id).expect("randomness");
    std::fs::write(&path, secret.text()).expect("write the secret");
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).expect("chmod");
    let p = path.display().to_string();
    (dir, p)
}

/// `qfleet run` on host A with `local` robots and `remote` robots to come from host B.
fn start_a(
    hosts: &TwoHosts,
    id: &str,
    out: &Path,
    local: u32,
    remote: u32,
    secret: &str,
    extra: &[&str],
) -> Child {
    let (l, r) = (local.to_string(), remote.to_string());
    let out = out.display().to_string();
    let mut args = vec![
        "run",
        "--run-id",
        id,
        "--robots",
        &l,
        "--remote-robots",
        &r,
        "--listen",
        ENDPOINT,
        "--secret-file",
        secret,
        "--out",
        &out,
    ];
    args.extend_from_slice(extra);
    hosts
        .command(Host::A, &bin("qfleet"), &args)
        .spawn()
        .expect("spawn qfleet run")
}

/// `qfleet join` on host B.
fn start_b(hosts: &TwoHosts, robots: u32, out: &Path, secret: &str, extra: &[&str]) -> Child {
    let n = robots.to_string();
    let out = out.display().to_string();
    let mut args = vec![
        "join",
        ENDPOINT,
        "--robots",
        &n,
        "--name",
        "host-b",
        "--secret-file",
        secret,
        "--out",
        &out,
    ];
    args.extend_from_slice(extra);
    hosts
        .command(Host::B, &bin("qfleet"), &args)
        .spawn()
        .expect("spawn qfleet join")
}

/// Runs `qfleet experiment manifest` on host A with `remote` of its robots joined from host B
/// (`qfleet join` writing into `db`), both waited for; asserts both succeeded and returns host
/// A's output.
fn experiment_across(
    hosts: &TwoHosts,
    id: &str,
    manifest: &Path,
    out: &Path,
    remote: u32,
    db: &Path,
    secret: &str,
) -> Output {
    let (m, o, r) = (
        manifest.display().to_string(),
        out.display().to_string(),
        remote.to_string(),
    );
    let a = hosts
        .command(
            Host::A,
            &bin("qfleet"),
            &[
                "experiment",
                &m,
                "--run-id",
                id,
                "--remote-robots",
                &r,
                "--listen",
                ENDPOINT,
                "--secret-file",
                secret,
                "--out",
                &o,
                "--json",
            ],
        )
        .spawn()
        .expect("spawn qfleet experiment");
    let b = start_b(hosts, remote, db, secret, &[]);
    let out_b = wait_bounded(b, LIMIT);
    let out_a = wait_bounded(a, LIMIT);
    assert!(out_a.status.success(), "host A: {}", describe(&out_a));
    assert!(out_b.status.success(), "host B: {}", describe(&out_b));
    out_a
}

fn result(dir: &Path, out: &Output) -> Value {
    let text = std::fs::read_to_string(dir.join("result.json"))
        .unwrap_or_else(|e| panic!("no result.json ({e}): {}", describe(out)));
    serde_json::from_str(&text).expect("result.json is JSON")
}

fn robot(r: &Value, id: u64) -> &Value {
    r["robots"]
        .as_array()
        .and_then(|a| a.iter().find(|x| x["robot_id"] == id))
        .unwrap_or_else(|| panic!("robot {id} missing: {r}"))
}

/// Every robot finished and every discovery made was received (none lost across the link).
fn assert_complete(r: &Value, robots: u64) {
    for id in 0..robots {
        assert_eq!(robot(r, id)["status"], "finished", "robot {id}: {r}");
        let x = robot(r, id);
        assert_eq!(x["discoveries_acked"], x["discoveries_sent"], "{x}");
    }
    assert_eq!(r["discoveries_received"], r["discoveries_sent"], "{r}");
    assert!(
        r["discoveries_sent"].as_u64().unwrap_or(0) > 0,
        "nothing crossed: {r}"
    );
}

/// The `hosts` of a result: the same in the `--json` stdout as in `result.json`, read back into
/// the typed entries, the coordinator's host first with its local robots.
fn assert_hosts_typed(file: &Value, out: &Output, local: &[u32]) {
    let stdout = String::from_utf8_lossy(&out.stdout);
    let printed: Value = serde_json::from_str(stdout.trim())
        .unwrap_or_else(|e| panic!("--json printed no JSON ({e}): {}", describe(out)));
    // `qfleet experiment --json` prints one result per seed
    let printed = match printed {
        Value::Array(mut a) if a.len() == 1 => a.remove(0),
        v => v,
    };
    assert_eq!(
        printed["hosts"], file["hosts"],
        "stdout and result.json disagree"
    );
    let hosts: Vec<report::HostEntry> =
        serde_json::from_value(file["hosts"].clone()).expect("hosts read back typed");
    assert_eq!(hosts.len(), 2, "{hosts:?}");
    assert_eq!(hosts[0].state, report::HostState::Local, "{hosts:?}");
    assert_eq!(hosts[0].robots, local, "{hosts:?}");
    assert!(hosts[0].link.is_none(), "{hosts:?}");
    assert!(hosts[1].link.is_some(), "{hosts:?}");
}

fn host_b(r: &Value) -> &Value {
    r["hosts"]
        .as_array()
        .and_then(|a| a.iter().find(|h| h["host"] == "host-b"))
        .unwrap_or_else(|| panic!("no host-b in the result's hosts: {r}"))
}

/// Waits until host A's run directory shows the remote robots learning (their logs on B are
/// not visible from A, so: the coordinator's stdout is not ours either — wait for B's robot
/// logs to exist and a little learning time).
fn wait_joined(dir_b: &Path, ids: &[u32]) {
    let deadline = Instant::now() + Duration::from_secs(60);
    while ids
        .iter()
        .any(|id| !dir_b.join(format!("robot-{id}.log")).exists())
    {
        assert!(Instant::now() < deadline, "host B never started its robots");
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(1500));
}

fn scratch_pair(id: &str) -> (Scratch, Scratch) {
    (scratch(&format!("{id}-a")), scratch(&format!("{id}-b")))
}

/// Nothing of run `id` in the outer system's shared memory (each host had its own).
fn assert_no_leftovers(id: &str) {
    let left = leftovers(id);
    assert!(
        left.is_empty(),
        "files of {id} in the outer system: {left:?}"
    );
}

// the improved learner explicitly: its discoveries are what the link must carry (the fleet's
// default learner may change)
const SHORT: [&str; 6] = [
    "--map",
    "builtin:paper-20",
    "--learner",
    "improved",
    "--episodes",
    "3000",
];
/// A run that lasts about 6 s on any machine (20 000 episodes of ~62 steps at 200 000 steps/s):
/// long enough to take a link down or kill a host while it learns. Unpaced, 150 000 episodes
/// ended within a second on an idle machine, before the kill or the outage.
const LONG: [&str; 8] = [
    "--map",
    "builtin:paper-20",
    "--learner",
    "improved",
    "--episodes",
    "20000",
    "--pace",
    "200000",
];

#[test]
fn a_run_across_two_hosts_completes_with_every_discovery_delivered() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    let Some(hosts) = TwoHosts::new("run") else {
        return;
    };
    let _ = bin("qfleet");
    let id = run_id("mh-run");
    let (da, db) = scratch_pair(&id);
    let (_s, secret) = secret_file(&id);
    let a = start_a(
        &hosts,
        &id,
        &da,
        1,
        2,
        &secret,
        &[&SHORT[..], &["--json"]].concat(),
    );
    let b = start_b(&hosts, 2, &db, &secret, &[]);
    let out_b = wait_bounded(b, LIMIT);
    let out_a = wait_bounded(a, LIMIT);
    assert!(out_a.status.success(), "host A: {}", describe(&out_a));
    assert!(out_b.status.success(), "host B: {}", describe(&out_b));
    let r = result(&da, &out_a);
    assert_complete(&r, 3);
    assert_hosts_typed(&r, &out_a, &[0]);
    let b = host_b(&r);
    assert_eq!(b["robots"], serde_json::json!([1, 2]), "{b}");
    assert_eq!(r["hosts"][0]["robots"], serde_json::json!([0]), "{r}");
    assert!(b["rtt_ns"]["count"].as_u64() > Some(0), "{b}");
    // the two namespaces share one kernel clock: the estimated offset must be within the
    // estimate's own error bound (half the best round trip) of zero
    let off = b["clock_offset_ns"].as_i64().unwrap().unsigned_abs();
    assert!(off <= b["best_rtt_ns"].as_u64().unwrap() / 2 + 1, "{b}");
    eprintln!("cross-host: {b}");
    drop(hosts);
    assert_no_leftovers(&id);
}

#[test]
fn the_link_down_for_two_seconds_loses_nothing_and_counts_a_reconnect() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    let Some(hosts) = TwoHosts::new("link-down") else {
        return;
    };
    let _ = bin("qfleet");
    let id = run_id("mh-down");
    let (da, db) = scratch_pair(&id);
    let (_s, secret) = secret_file(&id);
    let a = start_a(&hosts, &id, &da, 1, 2, &secret, &LONG);
    let b = start_b(&hosts, 2, &db, &secret, &[]);
    wait_joined(&db, &[1, 2]);
    hosts.link(false);
    std::thread::sleep(Duration::from_secs(2));
    hosts.link(true);
    let out_b = wait_bounded(b, LIMIT);
    let out_a = wait_bounded(a, LIMIT);
    assert!(out_a.status.success(), "host A: {}", describe(&out_a));
    assert!(out_b.status.success(), "host B: {}", describe(&out_b));
    let r = result(&da, &out_a);
    assert_complete(&r, 3);
    let b = host_b(&r);
    assert!(
        b["reconnects"].as_u64() >= Some(1),
        "no reconnect counted: {b}"
    );
    assert!(b["down_ms"].as_u64() >= Some(1000), "{b}");
    eprintln!("after 2 s down: {b}");
    drop(hosts);
    assert_no_leftovers(&id);
}

#[test]
fn a_killed_joining_host_has_its_robots_reported_lost_and_the_run_completes() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    let Some(hosts) = TwoHosts::new("host-killed") else {
        return;
    };
    let _ = bin("qfleet");
    let id = run_id("mh-kill");
    let (da, db) = scratch_pair(&id);
    let (_s, secret) = secret_file(&id);
    let a = start_a(
        &hosts,
        &id,
        &da,
        1,
        2,
        &secret,
        &[&LONG[..], &["--host-deadline", "3"]].concat(),
    );
    let b = start_b(&hosts, 2, &db, &secret, &[]);
    wait_joined(&db, &[1, 2]);
    hosts.kill_all(Host::B);
    let _ = wait_bounded(b, LIMIT);
    let out_a = wait_bounded(a, LIMIT);
    let r = result(&da, &out_a);
    assert_eq!(robot(&r, 0)["status"], "finished", "{r}");
    for id in [1, 2] {
        assert_eq!(robot(&r, id)["status"], "lost", "robot {id}: {r}");
    }
    assert_eq!(host_b(&r)["state"], "lost", "{r}");
    let stderr = String::from_utf8_lossy(&out_a.stderr);
    assert!(stderr.contains("host host-b silent"), "{stderr}");
    drop(hosts);
    assert_no_leftovers(&id);
}

/// The warehouse instance of `examples/grid/`, as `qfleet run --world shared` takes it.
fn warehouse() -> (std::path::PathBuf, std::path::PathBuf) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/grid");
    (dir.join("warehouse.map"), dir.join("warehouse.scen"))
}

#[test]
fn a_shared_grid_across_two_hosts_arrives_without_a_conflict() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    let Some(hosts) = TwoHosts::new("shared-grid") else {
        return;
    };
    let _ = bin("qfleet");
    let id = run_id("mh-grid");
    let (da, db) = scratch_pair(&id);
    let (_s, secret) = secret_file(&id);
    let (map, scen) = warehouse();
    let (m, s) = (map.display().to_string(), scen.display().to_string());
    // 8 agents: robots 0..4 on host A beside the coordinator, 4..8 on host B; every tick's
    // grant crosses to B and B's intents (horizons) cross back
    let grid = [
        "--world",
        "shared",
        "--map",
        &m,
        "--scen",
        &s,
        "--agents",
        "8",
        "--episodes",
        "300",
        "--json",
    ];
    let a = start_a(&hosts, &id, &da, 4, 4, &secret, &grid);
    let b = start_b(&hosts, 4, &db, &secret, &[]);
    let out_b = wait_bounded(b, LIMIT);
    let out_a = wait_bounded(a, LIMIT);
    assert!(out_a.status.success(), "host A: {}", describe(&out_a));
    assert!(out_b.status.success(), "host B: {}", describe(&out_b));
    let r = result(&da, &out_a);
    let g = &r["grid"];
    assert_eq!(g["ended"], "arrived", "{g}");
    assert_eq!(g["all_arrived"], true, "{g}");
    assert_eq!(g["agents"], 8, "{g}");
    assert_eq!(g["conflicts"], 0, "{g}");
    assert_eq!(g["intents_rejected"], 0, "{g}");
    // the coordinator's paths, checked by the tests' own validator from the map and scenario
    qfleet_suite::mapf_check::validate(&da, &map, &scen, 8, g);
    for id in 0..8 {
        assert_eq!(robot(&r, id)["status"], "finished", "robot {id}: {r}");
    }
    assert_hosts_typed(&r, &out_a, &[0, 1, 2, 3]);
    let b = host_b(&r);
    assert_eq!(b["robots"], serde_json::json!([4, 5, 6, 7]), "{b}");
    assert_eq!(b["state"], "up", "{b}");
    // nothing the robots or the coordinator wrote was refused on either side of the link
    assert_eq!(
        (b["rejected"].as_u64(), b["forged"].as_u64()),
        (Some(0), Some(0)),
        "{b}"
    );
    let joined: Value = serde_json::from_str(
        &std::fs::read_to_string(db.join("join.json"))
            .unwrap_or_else(|e| panic!("no join.json on host B ({e}): {}", describe(&out_b))),
    )
    .expect("join.json is JSON");
    assert_eq!(
        (joined["rejected"].as_u64(), joined["forged"].as_u64()),
        (Some(0), Some(0)),
        "host B: {joined}"
    );
    eprintln!("shared grid across hosts: {g}\nhost B: {joined}");
    drop(hosts);
    assert_no_leftovers(&id);
}

/// Robot 6, on host B, SIGKILLed while an 8-robot shared grid (4 robots per host, 150 ms ticks)
/// executes: host B reports it gone (its process ended: `qfleet join` reaped it), the hub drops
/// its stand-in, the coordinator declares it lost and it leaves the grid ("robot 6 left the
/// shared grid"); the seven others arrive with no conflict and host A exits 1 with the result
/// (a robot lost). Robot 6 is killed about 0.3 s into the execution, often before host B's
/// second full node listing: a robot that no listing ever showed alive was never reported gone,
/// so it turned hung at the per-tick deadline and the run ended at the tick limit (3 of 8 runs
/// before `bridge::roster` took the process's end as the authority).
#[test]
fn a_remote_robot_killed_on_a_shared_grid_leaves_it_and_the_others_arrive() {
    remote_robot_dies_on_a_shared_grid("mh-gkill", false);
}

/// Robot 6, on host B, SIGSTOPped while the shared grid executes (as in
/// [`a_remote_robot_killed_on_a_shared_grid_leaves_it_and_the_others_arrive`]): its process
/// lives, so host B reports nothing and it turns hung at the per-tick deadline (12 s with
/// remote robots): an obstacle the others are not held up by, still on the grid. Then it is
/// SIGKILLed: host B reports it gone, it is declared lost and leaves the grid, and the seven
/// others arrive.
#[test]
fn a_remote_robot_stopped_on_a_shared_grid_is_an_obstacle_until_killed_then_leaves_it() {
    remote_robot_dies_on_a_shared_grid("mh-gstop", true);
}

/// Robot 6 of an 8-robot shared grid across two hosts dies on host B mid-execution (first
/// stopped until the coordinator finds it hung, with `stop_first`): it must leave the grid.
fn remote_robot_dies_on_a_shared_grid(tag: &str, stop_first: bool) {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    let Some(hosts) = TwoHosts::new(tag) else {
        return;
    };
    let _ = bin("qfleet");
    let id = run_id(tag);
    let (da, db) = scratch_pair(&id);
    let (_s, secret) = secret_file(&id);
    let (map, scen) = warehouse();
    let (m, s) = (map.display().to_string(), scen.display().to_string());
    // 150 ms a tick: the execution lasts seconds, time to kill robot 6 (on host B) in it
    let grid = [
        "--world",
        "shared",
        "--map",
        &m,
        "--scen",
        &s,
        "--agents",
        "8",
        "--episodes",
        "300",
        "--tick-ms",
        "150",
        "--json",
    ];
    let a = start_a(&hosts, &id, &da, 4, 4, &secret, &grid);
    let b = start_b(&hosts, 4, &db, &secret, &[]);
    let log = da.join("coordinator.log");
    let deadline = Instant::now() + Duration::from_secs(90);
    while !std::fs::read_to_string(&log).is_ok_and(|l| l.contains("shared grid:")) {
        assert!(Instant::now() < deadline, "the execution never started");
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(300));
    let pid = qfleet_suite::pid_with_arg(&id, "--robot-id", "6").expect("robot 6 alive on B");
    if stop_first {
        // SAFETY: a plain kill(2) of a process of this test's run.
        unsafe { libc::kill(pid, libc::SIGSTOP) };
        let hung = "robot 6 sent no intent";
        let deadline = Instant::now() + Duration::from_secs(60);
        while !std::fs::read_to_string(&log).is_ok_and(|l| l.contains(hung)) {
            assert!(Instant::now() < deadline, "robot 6 never turned hung");
            std::thread::sleep(Duration::from_millis(100));
        }
        std::thread::sleep(Duration::from_secs(2));
        let l = std::fs::read_to_string(&log).unwrap_or_default();
        assert!(
            !l.contains("robot 6 left") && !l.contains("robot 6 is gone"),
            "a stopped robot is an obstacle, not lost: {l}"
        );
    }
    // SAFETY: a plain kill(2) of a process of this test's run.
    unsafe { libc::kill(pid, libc::SIGKILL) };
    let out_b = wait_bounded(b, LIMIT);
    let out_a = wait_bounded(a, LIMIT);
    // a lost robot is a run that completed without all its robots: exit 1 with the result
    assert_eq!(out_a.status.code(), Some(1), "host A: {}", describe(&out_a));
    let r = result(&da, &out_a);
    let g = &r["grid"];
    assert_eq!(
        g["robots"][6]["left"],
        true,
        "{g}\nhost A: {}\nhost B: {}",
        describe(&out_a),
        describe(&out_b)
    );
    assert_eq!(g["all_arrived"], false, "{g}");
    for i in [0, 1, 2, 3, 4, 5, 7] {
        assert!(
            g["robots"][i]["arrived_at"].as_u64().is_some(),
            "robot {i}: {g}"
        );
    }
    assert_eq!(g["conflicts"], 0, "{g}");
    assert_eq!(robot(&r, 6)["status"], "lost", "{r}");
    let stderr = String::from_utf8_lossy(&out_a.stderr);
    let coordinator = std::fs::read_to_string(&log).unwrap_or_default();
    assert!(
        coordinator.contains("robot 6 left the shared grid"),
        "{coordinator}\n{stderr}"
    );
    let eb = String::from_utf8_lossy(&out_b.stderr);
    assert!(
        eb.contains("robot 6 is gone (its process ended)"),
        "host B: {}",
        describe(&out_b)
    );
    drop(hosts);
    assert_no_leftovers(&id);
}

#[test]
fn a_shared_grid_experiment_across_two_hosts_arrives_in_both_phases_without_a_conflict() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    let Some(hosts) = TwoHosts::new("shared-grid-experiment") else {
        return;
    };
    let _ = bin("qfleet");
    // a short prefix: the experiment adds the seed, its pid and the time (48 characters at most)
    let id = format!("mhgx{}", std::process::id());
    let (da, db) = scratch_pair(&id);
    let (_s, secret) = secret_file(&id);
    let (map, scen) = warehouse();
    // the repository's two-phase example on the warehouse, its robots 3-5 on host B: each
    // phase's Execute, grants and intents cross the link, and phase 1's goals too
    let manifest = map.with_file_name("warehouse-two-phases.toml");
    let out = da.join("out");
    let out_a = experiment_across(&hosts, &id, &manifest, &out, 3, &db, &secret);
    let seed = out.join("seed-1");
    let r = result(&seed, &out_a);
    let phases = r["phases"].as_array().expect("phases");
    assert_eq!(phases.len(), 2, "{r}");
    // every phase from the scenario's starts; phase 1 to the next robot's goal
    let lines = qfleet_suite::mapf_check::scen_pairs(
        &std::fs::read_to_string(&scen).expect("the scenario"),
        6,
    );
    for (p, phase) in phases.iter().enumerate() {
        let g = &phase["grid"];
        assert_eq!(g["ended"], "arrived", "phase {p}: {g}");
        assert_eq!(g["all_arrived"], true, "phase {p}: {g}");
        assert_eq!(g["agents"], 6, "phase {p}: {g}");
        assert_eq!(g["intents_rejected"], 0, "phase {p}: {g}");
        assert_eq!(g["paths_file"], format!("paths-phase-{p}.txt"), "{g}");
        let pairs: Vec<_> = (0..6).map(|i| (lines[i].0, lines[(i + p) % 6].1)).collect();
        // the coordinator's paths, checked by the tests' own validator
        qfleet_suite::mapf_check::validate_pairs(
            &seed.join(format!("paths-phase-{p}.txt")),
            &map,
            &pairs,
            g,
        );
        let robots = phase["robots"].as_array().expect("robots");
        assert_eq!(robots.len(), 6, "phase {p}: {phase}");
        for (i, x) in robots.iter().enumerate() {
            assert_eq!(x["status"], "finished", "phase {p}: {x}");
            // goal ids are per robot, rotated by one in phase 1: the remote robots got
            // their new goal across the link
            assert_eq!(x["goal"].as_u64(), Some(((i + p) % 6) as u64), "{x}");
        }
    }
    assert_hosts_typed(&r, &out_a, &[0, 1, 2]);
    let b = host_b(&r);
    assert_eq!(b["robots"], serde_json::json!([3, 4, 5]), "{b}");
    assert_eq!(b["state"], "up", "{b}");
    assert_eq!(
        (b["rejected"].as_u64(), b["forged"].as_u64()),
        (Some(0), Some(0)),
        "{b}"
    );
    eprintln!("shared-grid experiment across hosts: {}", phases[1]["grid"]);
    drop(hosts);
    assert_no_leftovers(&id);
}

#[test]
fn a_join_with_another_schema_version_is_refused_clearly_on_both_hosts() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    let Some(hosts) = TwoHosts::new("schema") else {
        return;
    };
    let _ = bin("qfleet");
    let id = run_id("mh-schema");
    let (da, db) = scratch_pair(&id);
    let (_s, secret) = secret_file(&id);
    let a = start_a(&hosts, &id, &da, 1, 1, &secret, &SHORT);
    let b = start_b(
        &hosts,
        1,
        &db,
        &secret,
        &["--schema-version-override", "999"],
    );
    let out_b = wait_bounded(b, LIMIT);
    assert!(
        !out_b.status.success(),
        "host B joined: {}",
        describe(&out_b)
    );
    let eb = String::from_utf8_lossy(&out_b.stderr);
    let ours = format!("v{}", bus_schema::SCHEMA_VERSION);
    assert!(
        eb.contains("join refused")
            && eb.contains("schema version mismatch")
            && eb.contains("v999")
            && eb.contains(&ours),
        "{eb}"
    );
    // host A goes on waiting for a robot that can join: stop it as a user would
    // SAFETY: kill(2) on our child (`ip netns exec` execs down to qfleet)
    unsafe { libc::kill(a.id() as i32, libc::SIGINT) };
    let out_a = wait_bounded(a, LIMIT);
    let ea = String::from_utf8_lossy(&out_a.stderr);
    assert!(
        ea.contains("refused the join of host host-b") && ea.contains("v999"),
        "{ea}"
    );
    drop(hosts);
    assert_no_leftovers(&id);
}

#[test]
fn an_experiment_across_two_hosts_runs_every_phase_with_the_remote_robots() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    let Some(hosts) = TwoHosts::new("experiment") else {
        return;
    };
    let _ = bin("qfleet");
    // a short prefix: the experiment adds the seed, its pid and the time (48 characters at most)
    let id = format!("mhx{}", std::process::id());
    let (da, db) = scratch_pair(&id);
    // one secret for the experiment: it names the seeds' run-id prefix
    let (_s, secret) = secret_file(&id);
    // two goals, two phases: the phase change (a control message) must cross the link too
    let manifest = da.join("m.toml");
    std::fs::write(
        &manifest,
        r#"
name = "across hosts"
sharing = "both"
episodes = 300
seeds = [5]
[map]
source = "builtin:paper-10"
[[goals]]
cell = [9, 9]
[[goals]]
cell = [9, 0]
[robots]
count = 3
start = [0, 0]
[learner]
kind = "improved"
[[phases]]
[[phases]]
rotate = 1
episodes = 200
"#,
    )
    .expect("write the manifest");
    let out = da.join("out");
    let out_a = experiment_across(&hosts, &id, &manifest, &out, 2, &db, &secret);
    let seed = out.join("seed-5");
    let r = result(&seed, &out_a);
    let phases = r["phases"].as_array().expect("phases");
    assert_eq!(phases.len(), 2, "{r}");
    for (p, phase) in phases.iter().enumerate() {
        let robots = phase["robots"].as_array().expect("robots");
        assert_eq!(robots.len(), 3, "phase {p}: {phase}");
        for x in robots {
            assert_eq!(x["status"], "finished", "phase {p}: {x}");
            // round-robin over the two goals, shifted by one in phase 1: the remote robots
            // got their new goal across the link
            let rid = x["robot_id"].as_u64().unwrap();
            assert_eq!(x["goal"].as_u64().unwrap(), (rid + p as u64) % 2, "{x}");
        }
    }
    assert!(r["discoveries_received"].as_u64() > Some(0), "{r}");
    assert_hosts_typed(&r, &out_a, &[0]);
    let b = host_b(&r);
    assert_eq!(b["robots"], serde_json::json!([1, 2]), "{b}");
    assert_eq!(b["state"], "up", "{b}");
    drop(hosts);
    assert_no_leftovers(&id);
}

/// What the stranger saw and got (printed by [`stranger_role`] as one JSON line).
#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
struct Stranger {
    /// Samples its `**` subscription received.
    samples: u64,
    /// Of those, keys or payloads holding the run id or a heartbeat's JSON (plaintext).
    plaintext: u64,
    /// Answers to its forged joins: each `Refused` or `Challenge`, never `Accepted`.
    join_answers: Vec<String>,
    /// Replies of other peers' admin spaces (`@/**`).
    admin_replies: u64,
    /// Frames it replayed or forged onto the keys it saw.
    forged: u64,
    /// TCP connections it dialed that never start Zenoh's handshake (a flood of
    /// [`FLOOD_CONNECTIONS`] kept open, each re-dialed as soon as host A closed it, for the
    /// first 4 s of the stranger's life, through host B's join), how many of them host A closed (the last ones within 5 s of the
    /// flood's end), and how many were re-dials.
    idle_opened: u64,
    idle_closed: u64,
    redials: u64,
    /// Zenoh sessions it opened to host A (its own and a flood of more), and how many of them
    /// host A admitted as peers; of those, how many of the flood were admitted at once.
    sessions_opened: u64,
    sessions_admitted: u64,
    flood_admitted: u64,
}

/// The stranger itself: does nothing unless `QFLEET_STRANGER=ENDPOINT;RUN_ID;SOURCE[;PASSWORD]`
/// is set (then it is the copy of this test binary that the stranger test starts inside host
/// B's namespace; every socket it opens is bound to the address `SOURCE`, so host A sees it as
/// a source of its own, not as host B). A plain Zenoh peer on host A's endpoint, or, with
/// `PASSWORD`, one that holds the run's Zenoh session password (as if it had leaked; the join
/// secret it does not have): it opens a flood of sessions, subscribes to everything, asks the
/// admin space who is there, asks to join without the secret (and floods the join key), and
/// replays every frame it saw and forges goodbyes and heartbeats on the keys it saw; the one
/// without the password also keeps a flood of half-open TCP connections going
/// ([`redial_flood`]).
#[test]
fn stranger_role() {
    use zenoh::Wait;
    let Ok(spec) = std::env::var("QFLEET_STRANGER") else {
        return;
    };
    let mut parts = spec.split(';');
    let (endpoint, run_id, source) = (
        parts.next().expect("ENDPOINT"),
        parts.next().expect("RUN_ID"),
        parts.next().expect("SOURCE"),
    );
    let password = parts.next();
    let mut seen = Stranger::default();
    let addr = endpoint.trim_start_matches("tcp/");
    let source: std::net::IpAddr = source.parse().expect("SOURCE is an address");
    // the connection flood is the stranger's (the insider reads and forges in time for the run)
    let stop_flood = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flood_conns = password.is_none().then(|| {
        let (addr, stop) = (addr.to_string(), stop_flood.clone());
        std::thread::spawn(move || redial_flood(source, &addr, &stop))
    });
    let mut c = zenoh::Config::default();
    for (k, v) in [
        ("mode", "\"peer\"".to_string()),
        ("scouting/multicast/enabled", "false".into()),
        ("listen/endpoints", "[]".into()),
        // Zenoh binds the connecting socket to the stranger's own address
        (
            "connect/endpoints",
            format!("[\"{endpoint}#bind={source}:0\"]"),
        ),
    ] {
        c.insert_json5(k, &v).expect("config");
    }
    if let Some(p) = password {
        c.insert_json5("transport/auth/usrpwd/user", "\"qfleet\"")
            .expect("user");
        c.insert_json5("transport/auth/usrpwd/password", &format!("\"{p}\""))
            .expect("password");
    }
    // a flood of sessions first (Zenoh's own limit is 1000 per host; the run's 512; host A's
    // front door lets one source hold 8 connections), closed before its own session opens
    let admitted = |x: &zenoh::Session| x.info().peers_zid().wait().next().is_some();
    let flood: Vec<zenoh::Session> = (0..20)
        .filter_map(|_| zenoh::open(c.clone()).wait().ok())
        .collect();
    std::thread::sleep(Duration::from_millis(500));
    seen.flood_admitted = flood.iter().filter(|x| admitted(x)).count() as u64;
    for f in flood.iter() {
        let _ = f.close().wait();
    }
    seen.sessions_opened = flood.len() as u64 + 1;
    drop(flood);
    let s = zenoh::open(c).wait().expect("the stranger's session");
    // the insider's own session may find its source's slots still held by the closing flood:
    // Zenoh dials again (about a second later)
    let until = Instant::now() + Duration::from_secs(5);
    while password.is_some() && !admitted(&s) && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(50));
    }
    let sub = s.declare_subscriber("**").wait().expect("subscribe");
    let plain = |b: &[u8]| {
        b.windows(run_id.len()).any(|w| w == run_id.as_bytes())
            || b.windows(7).any(|w| w == b"\"acked\"")
    };
    // ask to join without the secret: a made-up proof, and a flood of hellos
    let ask = |body: String| -> Vec<String> {
        let mut out = Vec::new();
        if let Ok(r) = s
            .get("qfleet/join")
            .payload(body)
            .timeout(Duration::from_secs(1))
            .wait()
        {
            while let Ok(reply) = r.recv() {
                if let Ok(sample) = reply.into_result() {
                    let text = String::from_utf8_lossy(&sample.payload().to_bytes()).into_owned();
                    out.push(text.chars().take(40).collect());
                }
            }
        }
        out
    };
    std::thread::sleep(Duration::from_millis(500));
    let forged_join = serde_json::json!({"Join": {
        "cookie": "00".repeat(32), "nonce": "00".repeat(16),
        "request": {"schema_version": bus_schema::SCHEMA_VERSION, "little_endian": true,
                    "host": "stranger", "robots": 2, "t_ns": 1},
        "proof": "00".repeat(32)}});
    seen.join_answers.extend(ask(forged_join.to_string()));
    seen.join_answers.extend(ask(
        serde_json::json!({"Hello": {"nonce": "11".repeat(16)}}).to_string(),
    ));
    for _ in 0..300 {
        let _ = s
            .get("qfleet/join")
            .payload(forged_join.to_string())
            .timeout(Duration::from_millis(1))
            .wait();
    }
    // (its own session answers for itself: only other peers' answers count)
    let own = s.zid().to_string();
    if let Ok(r) = s.get("@/**").timeout(Duration::from_secs(1)).wait() {
        while let Ok(reply) = r.recv() {
            if let Ok(sample) = reply.result()
                && !sample.key_expr().as_str().contains(&own)
            {
                seen.admin_replies += 1;
            }
        }
    }
    // listen for three seconds, keeping the last frames of every key
    let mut frames: std::collections::BTreeMap<String, Vec<Vec<u8>>> = Default::default();
    let until = Instant::now() + Duration::from_secs(3);
    while Instant::now() < until {
        match sub.recv_timeout(Duration::from_millis(50)) {
            Ok(Some(sample)) => {
                seen.samples += 1;
                let key = sample.key_expr().as_str().to_string();
                let bytes = sample.payload().to_bytes().to_vec();
                if key.contains(run_id) || plain(&bytes) {
                    seen.plaintext += 1;
                }
                let kept = frames.entry(key).or_default();
                if kept.len() < 50 {
                    kept.push(bytes);
                }
            }
            _ => continue,
        }
    }
    // replay everything, then forge: a plain goodbye, a heartbeat acknowledging everything,
    // garbage — on every key seen and on made-up up keys
    let mut goodbye = vec![3u8];
    goodbye.resize(16, 0);
    let mut ack_all = vec![2u8];
    ack_all.resize(16, 0);
    ack_all.extend_from_slice(
        br#"{"t_ns":1,"echo_ns":0,"hold_ns":0,"acked":1000000,"sent":1000000,"gone":[1,2]}"#,
    );
    for (key, kept) in &frames {
        let up = key.replace("/down/", "/up/");
        for f in kept.iter().chain([&goodbye, &ack_all, &vec![0xAA; 64]]) {
            for k in [key.as_str(), up.as_str(), "qfleet/up/0"] {
                if s.put(k, f.clone()).wait().is_ok() {
                    seen.forged += 1;
                }
            }
        }
    }
    seen.sessions_admitted = seen.flood_admitted + u64::from(admitted(&s));
    let _ = s.close().wait();
    stop_flood.store(true, Ordering::Relaxed);
    if let Some(flood) = flood_conns {
        (seen.idle_opened, seen.idle_closed, seen.redials) = flood.join().expect("the flood");
    }
    println!("STRANGER {}", serde_json::to_string(&seen).unwrap());
}

/// TCP connections the stranger keeps open to host A's endpoint at once.
const FLOOD_CONNECTIONS: usize = 300;

/// Keeps [`FLOOD_CONNECTIONS`] TCP connections from `source` to `addr` that never send a byte,
/// re-dialing each one host A closes (or refuses), for 4 s (or until `stop`); then waits up to
/// 5 s for host A to close the last ones. Returns (dials, closed by host A, re-dials).
fn redial_flood(
    source: std::net::IpAddr,
    addr: &str,
    stop: &std::sync::atomic::AtomicBool,
) -> (u64, u64, u64) {
    use std::io::{ErrorKind, Read};
    use std::net::{SocketAddr, TcpStream};
    let addr: SocketAddr = addr.parse().expect("a socket address");
    let dial = || -> std::io::Result<TcpStream> {
        let s = socket2::Socket::new(socket2::Domain::IPV4, socket2::Type::STREAM, None)?;
        s.bind(&SocketAddr::new(source, 0).into())?;
        s.connect_timeout(&addr.into(), Duration::from_millis(200))?;
        Ok(s.into())
    };
    let closed = |mut t: &TcpStream| match t.read(&mut [0u8; 64]) {
        Ok(0) => true,
        Ok(_) => false,
        Err(e) => !matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut),
    };
    let (mut dials, mut closes, mut redials) = (0u64, 0u64, 0u64);
    let mut conns: Vec<Option<TcpStream>> = (0..FLOOD_CONNECTIONS).map(|_| None).collect();
    // four seconds cover host B's join (it starts 1.5 s after the stranger); the insider's
    // forgeries come later and must find the CPUs free to reach the run before it ends
    let flood_until = Instant::now() + Duration::from_secs(4);
    while !stop.load(Ordering::Relaxed) && Instant::now() < flood_until {
        for slot in conns.iter_mut() {
            match slot {
                Some(t) if closed(t) => {
                    closes += 1;
                    *slot = None;
                }
                Some(_) => {}
                None => {
                    if let Ok(t) = dial() {
                        let _ = t.set_nonblocking(true);
                        redials += u64::from(dials >= FLOOD_CONNECTIONS as u64);
                        dials += 1;
                        *slot = Some(t);
                    }
                }
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    // host A drops a connection that has not finished the handshake after 1 s
    let until = Instant::now() + Duration::from_secs(5);
    for t in conns.iter_mut().flatten() {
        let _ = t.set_nonblocking(false);
        let left = until.saturating_duration_since(Instant::now());
        let _ = t.set_read_timeout(Some(left.max(Duration::from_millis(1))));
        if closed(t) {
            closes += 1;
        }
    }
    (dials, closes, redials)
}

#[test]
fn a_stranger_on_the_network_reads_nothing_forges_nothing_and_takes_no_slot() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    if std::env::var_os("QFLEET_STRANGER").is_some() {
        return;
    }
    let Some(hosts) = TwoHosts::new("stranger") else {
        return;
    };
    let _ = bin("qfleet");
    let id = run_id("mh-stranger");
    let (da, db) = scratch_pair(&id);
    let (_s, secret) = secret_file(&id);
    let a = start_a(
        &hosts,
        &id,
        &da,
        1,
        2,
        &secret,
        // twice LONG's episodes: the insider replays and forges after ~8 s of probing, and
        // under load LONG's run had ended by then (nothing left to forge against)
        &[
            &LONG[..4],
            &["--episodes", "40000", "--pace", "200000", "--json"],
        ]
        .concat(),
    );
    // the stranger first: its joins, floods and idle connections come before the real host's
    std::thread::sleep(Duration::from_millis(1500));
    // a copy of this test binary in host B's namespace runs [`stranger_role`] with `spec`
    let spawn_stranger = |spec: String| -> Child {
        let me = std::env::current_exe().expect("this test binary");
        let mut c = hosts.command(
            Host::B,
            &me,
            &[
                "stranger_role",
                "--exact",
                "--nocapture",
                "--test-threads",
                "1",
            ],
        );
        c.env("QFLEET_STRANGER", spec);
        c.spawn().expect("spawn the stranger")
    };
    // each from an address of its own on host B's link, so host A's front door sees three
    // sources: host B (10.77.0.2), the stranger (.3) and the insider (.4)
    hosts.add_address(Host::B, "10.77.0.3/24");
    hosts.add_address(Host::B, "10.77.0.4/24");
    let stranger = spawn_stranger(format!("{ENDPOINT};{id};10.77.0.3"));
    // and one that holds the session password (leaked), not the join secret
    let password =
        bridge::Secret::parse(&std::fs::read_to_string(&secret).expect("the secret file"))
            .expect("a secret")
            .session_password();
    let insider = spawn_stranger(format!("{ENDPOINT};{id};10.77.0.4;{password}"));
    std::thread::sleep(Duration::from_millis(1500));
    let b = start_b(&hosts, 2, &db, &secret, &[]);
    let out_s = wait_bounded(stranger, LIMIT);
    let out_i = wait_bounded(insider, LIMIT);
    let out_b = wait_bounded(b, LIMIT);
    let out_a = wait_bounded(a, LIMIT);
    assert!(out_a.status.success(), "host A: {}", describe(&out_a));
    assert!(out_b.status.success(), "host B: {}", describe(&out_b));
    // the run is whole: every robot finished, every discovery crossed
    let r = result(&da, &out_a);
    assert_complete(&r, 3);
    assert_eq!(host_b(&r)["robots"], serde_json::json!([1, 2]), "{r}");
    let seen_by = |out: &Output, who: &str| -> Stranger {
        let text = String::from_utf8_lossy(&out.stdout);
        let line = text
            .lines()
            .find_map(|l| l.split_once("STRANGER ").map(|(_, json)| json))
            .unwrap_or_else(|| panic!("the {who} printed nothing: {}", describe(out)));
        let seen: Stranger = serde_json::from_str(line).expect("the stranger's JSON");
        eprintln!("{who}: {seen:?}");
        seen
    };
    // the stranger without the secret gets no Zenoh session at all: nothing to read, nothing
    // reaches host A, no session slot held, idle connections dropped
    let seen = seen_by(&out_s, "stranger");
    assert_eq!(
        (seen.sessions_admitted, seen.samples, seen.admin_replies),
        (0, 0, 0),
        "{seen:?}"
    );
    assert!(seen.sessions_opened > 1, "{seen:?}");
    assert!(seen.join_answers.is_empty(), "{seen:?}");
    // the re-dialing flood of half-open connections went on through host B's join, and host
    // A kept closing them: it re-dialed, and every one it opened was closed
    assert!(seen.redials > 0, "{seen:?}");
    assert_eq!(seen.idle_closed, seen.idle_opened, "{seen:?}");
    // what the insider (session password, no join secret) got: frames, but no plaintext; no
    // slot; no admin space; of its flood of sessions, no more than one source may hold
    let seen = seen_by(&out_i, "insider");
    assert!(seen.sessions_admitted > 0, "{seen:?}");
    assert!(
        (1..=u64::from(bridge::DoorLimits::default().per_source)).contains(&seen.flood_admitted),
        "{seen:?}"
    );
    assert!(
        seen.samples > 0,
        "the insider saw no frame at all: {seen:?}"
    );
    assert_eq!(seen.plaintext, 0, "{seen:?}");
    assert!(!seen.join_answers.is_empty(), "{seen:?}");
    assert!(
        seen.join_answers
            .iter()
            .all(|a| a.contains("Refused") || a.contains("Challenge")),
        "{seen:?}"
    );
    assert_eq!(seen.admin_replies, 0, "{seen:?}");
    assert!(seen.forged > 0, "{seen:?}");
    // host A counted the stranger's joins, host B dropped its replays and forgeries
    let bridge: Value = serde_json::from_str(
        &std::fs::read_to_string(da.join("bridge.json")).expect("bridge.json"),
    )
    .expect("bridge.json is JSON");
    assert!(bridge["unauthenticated"].as_u64() >= Some(1), "{bridge}");
    // host A's front door refused the stranger's and the insider's floods by their sources,
    // and never host B, which joined from its own address through them
    let refused = |source: &str| -> u64 {
        bridge["door"]["refused_by_source"]
            .as_array()
            .and_then(|a| a.iter().find(|s| s["source"] == source))
            .and_then(|s| s["refused"].as_u64())
            .unwrap_or(0)
    };
    eprintln!("host A's front door: {}", bridge["door"]);
    assert!(refused("10.77.0.3") > 0, "{bridge}");
    assert!(refused("10.77.0.4") > 0, "{bridge}");
    assert_eq!(refused("10.77.0.2"), 0, "{bridge}");
    assert!(bridge["door"]["silent"].as_u64() > Some(0), "{bridge}");
    // host A's memory under the attack stays bounded: the launcher holding the hub (its
    // coordinator and robots are processes of their own) peaked under 256 MiB
    let rss = bridge["peak_rss_kib"].as_u64().expect("peak_rss_kib");
    eprintln!("host A's launcher peaked at {rss} KiB under the attack");
    assert!((1..256 * 1024).contains(&rss), "{bridge}");
    let joined: Value =
        serde_json::from_str(&std::fs::read_to_string(db.join("join.json")).expect("join.json"))
            .expect("join.json is JSON");
    // every replayed or forged frame was dropped and counted where it arrived: by host B
    // (replays of the hub's frames), by the hub for host B, or as foreign at the hub
    let dropped = joined["forged"].as_u64().unwrap_or(0)
        + host_b(&r)["forged"].as_u64().unwrap_or(0)
        + bridge["foreign_frames"].as_u64().unwrap_or(0);
    assert!(dropped > 0, "{joined} {bridge}");
    // the secret stays in the run's own directory, private
    {
        use std::os::unix::fs::PermissionsExt;
        let meta = std::fs::metadata(da.join("join.secret")).expect("join.secret in --out");
        assert_eq!(meta.permissions().mode() & 0o077, 0);
    }
    drop(hosts);
    assert_no_leftovers(&id);
}

#[test]
fn a_wrong_join_secret_is_refused_in_seconds_naming_the_file_and_counted_by_host_a() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    let Some(hosts) = TwoHosts::new("wrong-secret") else {
        return;
    };
    let _ = bin("qfleet");
    let id = run_id("mh-wrong");
    let (da, db) = scratch_pair(&id);
    let (_s, secret) = secret_file(&id);
    let (_w, wrong) = secret_file_in(&id, "wrong");
    let a = start_a(&hosts, &id, &da, 1, 1, &secret, &SHORT);
    // host A's front door is up well within this (its hub starts before its robots)
    std::thread::sleep(Duration::from_secs(5));
    let started = std::time::Instant::now();
    let b = start_b(&hosts, 1, &db, &wrong, &["--timeout", "60"]);
    let out_b = wait_bounded(b, LIMIT);
    let took = started.elapsed();
    let eb = String::from_utf8_lossy(&out_b.stderr);
    assert_eq!(out_b.status.code(), Some(2), "{}", describe(&out_b));
    assert!(took < Duration::from_secs(10), "took {took:?}: {eb}");
    assert!(
        eb.contains("refused this host's credentials") && eb.contains(&wrong),
        "{eb}"
    );
    // the run goes on without host B (its slot stays empty) and ends by itself
    let out_a = wait_bounded(a, LIMIT);
    let ea = String::from_utf8_lossy(&out_a.stderr);
    assert_eq!(
        ea.matches("front door: 10.77.0.2 sent a probe with a wrong join secret")
            .count(),
        1,
        "{ea}"
    );
    let bridge: Value = serde_json::from_str(
        &std::fs::read_to_string(da.join("bridge.json")).expect("bridge.json"),
    )
    .expect("bridge.json is JSON");
    let door = &bridge["door"];
    eprintln!("host A's front door: {door}");
    assert!(door["refused_credentials"].as_u64() >= Some(1), "{door}");
    assert_eq!(
        door["refused_credentials_by_source"][0]["source"], "10.77.0.2",
        "{door}"
    );
    drop(hosts);
    assert_no_leftovers(&id);
}

#[test]
fn a_join_to_a_host_that_is_down_still_says_it_may_not_be_running_or_reachable() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    let Some(hosts) = TwoHosts::new("down") else {
        return;
    };
    let _ = bin("qfleet");
    let id = run_id("mh-nohost");
    let (_da, db) = scratch_pair(&id);
    let (_s, secret) = secret_file(&id);
    // nothing runs on host A
    let b = start_b(&hosts, 1, &db, &secret, &["--timeout", "3"]);
    let out_b = wait_bounded(b, LIMIT);
    let eb = String::from_utf8_lossy(&out_b.stderr);
    assert_eq!(out_b.status.code(), Some(1), "{}", describe(&out_b));
    assert!(
        eb.contains("running there, and reachable?") && !eb.contains("credentials"),
        "{eb}"
    );
    drop(hosts);
    assert_no_leftovers(&id);
}
