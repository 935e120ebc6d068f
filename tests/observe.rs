//! End-to-end: a run recorded with `--record` reads back (through `qfleet replay --json`, which
//! uses the `mcap` crate) with one channel per topic and message counts equal to the run's own
//! counters (from the first registration on: the launcher starts the robots only once the
//! recorder has joined), and leaves nothing of the run in shared memory.

use std::process::Command;

use qfleet_suite::bin_dir;

#[test]
fn a_recorded_run_reads_back_with_the_runs_own_counts() {
    use qfleet_suite::{leftovers, run_id, scratch};
    let run_id = run_id("obs");
    let dir = scratch(&run_id);
    let file = dir.join("run.mcap");
    let out_dir = dir.join("out");
    let out = Command::new(bin_dir().join("qfleet"))
        .args([
            "run",
            "--robots",
            "2",
            "--map",
            "builtin:paper-10",
            // the paper's learner: it makes pseudo-target discoveries to count
            "--learner",
            "improved",
            "--json",
            "--run-id",
            &run_id,
        ])
        .arg("--record")
        .arg(&file)
        .arg("--out")
        .arg(&out_dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let result: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let replay = Command::new(bin_dir().join("qfleet"))
        .args(["replay", "--json"])
        .arg(&file)
        .output()
        .unwrap();
    assert!(
        replay.status.success(),
        "{}",
        String::from_utf8_lossy(&replay.stderr)
    );
    let s: serde_json::Value = serde_json::from_slice(&replay.stdout).unwrap();
    let topics = s["topics"].as_array().unwrap();
    assert_eq!(
        topics.len(),
        bus_schema::names::Topic::ALL.len(),
        "one channel per topic"
    );
    let count = |path: &str| {
        topics
            .iter()
            .find(|t| t["topic"].as_str().unwrap().ends_with(path))
            .unwrap()["count"]
            .as_u64()
            .unwrap()
    };
    // what the robots themselves counted sending
    let sent = |field: &str| -> u64 {
        (0..2)
            .map(|r| {
                let text = std::fs::read_to_string(out_dir.join(format!("robot-{r}.json")))
                    .expect("robot result");
                let v: serde_json::Value = serde_json::from_str(&text).unwrap();
                v["counters"][field].as_u64().unwrap()
            })
            .sum()
    };
    // The recorder joined before the robots started (the launcher waits for it), so every
    // message of a lossless topic is in the file, from the first registration to the last
    // report: each discovery as often as it went out (resends after a late ack included).
    let discoveries = sent("discoveries_sent");
    assert!(discoveries > 0, "the run made discoveries to record");
    assert_eq!(discoveries, result["discoveries_sent"].as_u64().unwrap());
    assert_eq!(
        count("/robot/discovery"),
        discoveries + sent("discoveries_resent"),
        "every discovery send"
    );
    assert_eq!(count("/robot/report"), 2, "one report per robot");
    assert!(count("/robot/register") >= 2, "every robot's registration");
    // latest-wins topics: at most what was sent (a reader that falls behind loses the older
    // samples, as the fleet's own subscribers do), and at least the robots' last ones (the
    // recorder connects to every robot before its thread goes idle, so a run that starves it
    // still leaves them readable after it)
    let hints = count("/robot/hints");
    assert!(
        (1..=sent("hint_batches_sent")).contains(&hints),
        "{hints} hint batches recorded of {} sent",
        sent("hint_batches_sent")
    );
    assert_eq!(s["metadata"]["run_id"], run_id.as_str());
    assert_eq!(s["map"], "paper-10");
    let left = leftovers(&run_id);
    assert!(left.is_empty(), "files of the run left: {left:?}");
}

/// `qfleet topic list`, `echo` and `hz` attached to a live (paced, so that it lasts) run: the
/// list says the run is live, echo prints one decodable JSON line per message and sees both
/// final reports, hz prints JSON rate objects; the run's own result is untouched (every robot
/// finished, every discovery received) and nothing of the run is left behind.
#[test]
fn topic_tools_read_a_live_run_without_changing_it() {
    use qfleet_suite::{describe, leftovers, run_id, scratch, spawn, wait_bounded, wait_until};
    use std::process::Stdio;
    use std::time::Duration;
    let id = run_id("topic");
    let dir = scratch(&id);
    let qfleet = bin_dir().join("qfleet");
    let timeout = Duration::from_secs(180);
    let run = spawn(Command::new(&qfleet).args([
        "run",
        "--robots",
        "2",
        "--map",
        "builtin:paper-10",
        "--episodes",
        "300",
        "--pace",
        "4000",
        "--json",
        "--run-id",
        &id,
    ]));
    let topic = |args: &[&str]| {
        let mut c = Command::new(&qfleet);
        c.arg("topic")
            .args(args)
            .args(["--run-id", &id, "--wait", "60"]);
        c
    };
    // into files: a pipe nobody reads while the run goes on would stall the reader
    let to_file = |args: &[&str], name: &str| {
        let f = std::fs::File::create(dir.join(name)).unwrap();
        topic(args)
            .stdin(Stdio::null())
            .stdout(f)
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let echo = to_file(&["echo"], "echo.jsonl");
    let hz = to_file(&["hz", "--json"], "hz.jsonl");
    // while the run goes on, `list` sees it live
    let mut listed = serde_json::Value::Null;
    let live = wait_until(Duration::from_secs(60), || {
        let out = topic(&["list", "--json"]).output().unwrap();
        listed = serde_json::from_slice(&out.stdout).unwrap_or_default();
        listed[0]["live"] == true
    });
    assert!(live, "topic list never saw the run live: {listed}");
    assert_eq!(
        listed.as_array().map(Vec::len),
        Some(bus_schema::names::Topic::ALL.len()),
        "{listed}"
    );
    assert_eq!(
        listed[0]["topic"].as_str().map(|t| t.contains(&id)),
        Some(true),
        "{listed}"
    );

    let run = wait_bounded(run, timeout);
    assert!(run.status.success(), "{}", describe(&run));
    let echo = wait_bounded(echo, timeout);
    assert!(echo.status.success(), "{}", describe(&echo));
    let hz = wait_bounded(hz, timeout);
    assert!(hz.status.success(), "{}", describe(&hz));

    // the run's result is what an unobserved run gives
    let result: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    let robots = result["robots"].as_array().unwrap();
    assert_eq!(robots.len(), 2, "{result}");
    for r in robots {
        assert_eq!(r["status"], "finished", "{result}");
    }
    assert_eq!(
        result["discoveries_sent"], result["discoveries_received"],
        "{result}"
    );

    // echo: every line is a JSON object naming its topic, with the decoded message
    let text = std::fs::read_to_string(dir.join("echo.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    let of = |t: &str| lines.iter().filter(|l| l["topic"] == t).count();
    assert!(of("robot/state") > 0, "no robot/state line:\n{text}");
    assert_eq!(of("robot/report"), 2, "one final report per robot");
    let discoveries = of("robot/discovery") as u64;
    assert!(discoveries <= result["discoveries_sent"].as_u64().unwrap());
    for l in &lines {
        assert!(
            l["recv_ns"].as_u64().is_some() && l["msg"].is_object(),
            "{l}"
        );
    }
    let report = lines.iter().find(|l| l["topic"] == "robot/report").unwrap();
    assert_eq!(report["msg"]["episodes"], 300, "{report}");

    // hz: JSON objects of rates, the state topic counted
    let hz_text = std::fs::read_to_string(dir.join("hz.jsonl")).unwrap();
    let rates: Vec<serde_json::Value> = hz_text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    assert!(!rates.is_empty(), "hz printed nothing: {}", describe(&hz));
    let _ = std::fs::remove_dir_all(&dir);
    assert!(
        rates
            .iter()
            .any(|r| r["robot/state"]["total"].as_u64() > Some(0)),
        "{hz_text}"
    );
    for r in &rates {
        assert!(r["robot/state"]["per_s"].as_f64().is_some(), "{r}");
    }

    let left = leftovers(&id);
    assert!(left.is_empty(), "files of the run left behind: {left:?}");
}

/// `qfleet experiment --record`: the recording holds every robot's registration and every
/// phase report, the watch leaves before the launcher removes the run's files (so no "left
/// behind" warning), and nothing of the run stays.
#[test]
fn a_recorded_experiment_holds_every_phase_and_leaves_nothing() {
    use qfleet_suite::{leftovers, run_id, scratch};
    let id = run_id("obsx");
    let dir = scratch(&id);
    let file = dir.join("exp.mcap");
    let manifest = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("examples/three-goals-six-robots.toml");
    let out = Command::new(bin_dir().join("qfleet"))
        .arg("experiment")
        .arg(&manifest)
        .args(["--run-id", &id, "--record"])
        .arg(&file)
        .arg("--out")
        .arg(dir.join("out"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("left behind"), "{stderr}");
    let replay = Command::new(bin_dir().join("qfleet"))
        .args(["replay", "--json"])
        .arg(&file)
        .output()
        .unwrap();
    assert!(replay.status.success());
    let s: serde_json::Value = serde_json::from_slice(&replay.stdout).unwrap();
    let count = |path: &str| {
        s["topics"]
            .as_array()
            .unwrap()
            .iter()
            .find(|t| t["topic"].as_str().unwrap().ends_with(path))
            .map_or(0, |t| t["count"].as_u64().unwrap())
    };
    // six robots, three phases: a report per robot and phase
    assert!(count("/robot/register") >= 6);
    assert_eq!(count("/robot/report"), 18);
    let left: Vec<_> = std::fs::read_dir("/dev/shm")
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains(&id))
        .collect();
    assert!(left.is_empty(), "{left:?}");
    assert!(leftovers(&id).is_empty());
}

/// A run whose launcher (recorder thread and all) is killed mid-run leaves a recording without
/// an end; `qfleet replay` still reads the messages before the kill, exit 0, and says the file
/// was cut short (text and JSON). `qfleet clean` then removes what the killed run left.
#[test]
fn a_recording_whose_launcher_was_killed_is_read_up_to_the_kill() {
    use qfleet_suite::{describe, leftovers, run_bounded, run_id, scratch, spawn, wait_until};
    use std::os::unix::process::CommandExt;
    let id = run_id("killrec");
    let dir = scratch(&id);
    let file = dir.join("run.mcap");
    let qfleet = bin_dir().join("qfleet");
    // paced so it lasts; its own process group, so one kill ends every process of the run
    let mut run = spawn(
        Command::new(&qfleet)
            .args([
                "run",
                "--robots",
                "2",
                "--map",
                "builtin:paper-10",
                "--pace",
                "200",
                "--json",
                "--run-id",
                &id,
                "--record",
            ])
            .arg(&file)
            .process_group(0),
    );
    // the file holds messages once it grew well past its header, schemas and map
    let grew = wait_until(qfleet_suite::PROCESS_TIMEOUT, || {
        std::fs::metadata(&file).is_ok_and(|m| m.len() > 64 << 10)
    });
    // SAFETY: kill(2) on the process group this test started.
    unsafe { libc::kill(-(run.id() as i32), libc::SIGKILL) };
    let _ = run.wait();
    assert!(grew, "the recording never grew");
    let out = run_bounded(Command::new(&qfleet).args(["replay", "--json"]).arg(&file));
    assert!(out.status.success(), "{}", describe(&out));
    let s: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(s["messages"].as_u64() > Some(0), "{s}");
    let cut = &s["cut_short"];
    assert!(cut["read_bytes"].as_u64() > Some(0), "{s}");
    assert_eq!(
        cut["file_bytes"].as_u64(),
        Some(std::fs::metadata(&file).unwrap().len())
    );
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("was not finished"),
        "{}",
        describe(&out)
    );
    let text = run_bounded(Command::new(&qfleet).arg("replay").arg(&file));
    assert!(text.status.success(), "{}", describe(&text));
    let clean = run_bounded(Command::new(&qfleet).args(["clean", "--run-id", &id]));
    assert!(clean.status.success(), "{}", describe(&clean));
    let left = leftovers(&id);
    assert!(left.is_empty(), "files of the run left: {left:?}");
    drop(dir);
}

/// MCAP records written by hand (what `qfleet run --record` writes, in little): a recording
/// of run `run` with `n` `robot/state` messages in one uncompressed chunk, not yet ended (see
/// [`hand_end`]), and the offsets of the message records.
fn hand_recording(run: &str, n: u32) -> (Vec<u8>, Vec<usize>) {
    fn s(x: &[u8]) -> Vec<u8> {
        let mut v = (x.len() as u32).to_le_bytes().to_vec();
        v.extend_from_slice(x);
        v
    }
    fn rec(op: u8, body: &[u8]) -> Vec<u8> {
        let mut v = vec![op];
        v.extend_from_slice(&(body.len() as u64).to_le_bytes());
        v.extend_from_slice(body);
        v
    }
    const MAGIC: &[u8] = b"\x89MCAP0\r\n";
    let mut f = MAGIC.to_vec();
    f.extend(rec(1, &[s(b""), s(b"test")].concat()));
    f.extend(rec(
        3,
        &[
            &1u16.to_le_bytes()[..],
            &s(b"t"),
            &s(b"jsonschema"),
            &s(b"{}"),
        ]
        .concat(),
    ));
    let topic = format!("qfleet/{run}/robot/state");
    let channel = [
        &1u16.to_le_bytes()[..],
        &1u16.to_le_bytes(),
        &s(topic.as_bytes()),
        &s(b"json"),
        &0u32.to_le_bytes(),
    ]
    .concat();
    f.extend(rec(4, &channel));
    let mut records = Vec::new();
    let mut offsets = Vec::new();
    let records_at = f.len() + 9 + 8 + 8 + 8 + 4 + 4 + 8;
    for i in 0..n {
        let data = format!("{{\"robot_id\": {i}, \"step\": {}}}", i * 10);
        let t = 1_000_000_000 + u64::from(i) * 1_000_000;
        let body = [
            &1u16.to_le_bytes()[..],
            &i.to_le_bytes(),
            &t.to_le_bytes(),
            &t.to_le_bytes(),
            data.as_bytes(),
        ]
        .concat();
        offsets.push(records_at + records.len());
        records.extend(rec(5, &body));
    }
    let chunk = [
        &0u64.to_le_bytes()[..],
        &0u64.to_le_bytes(),
        &(records.len() as u64).to_le_bytes(),
        &0u32.to_le_bytes(),
        &s(b""),
        &(records.len() as u64).to_le_bytes(),
        &records,
    ]
    .concat();
    f.extend(rec(6, &chunk));
    assert_eq!(offsets[0], records_at);
    (f, offsets)
}

/// The end of a finished hand-made recording: data end, an empty footer, the magic.
fn hand_end(f: &mut Vec<u8>) {
    f.push(0x0F);
    f.extend_from_slice(&4u64.to_le_bytes());
    f.extend_from_slice(&0u32.to_le_bytes());
    f.push(0x02);
    f.extend_from_slice(&20u64.to_le_bytes());
    f.extend_from_slice(&[0u8; 20]);
    f.extend_from_slice(b"\x89MCAP0\r\n");
}

/// Runs `cmd` to its end (bounded) and returns its output and its peak resident set, KiB
/// (`wait4`'s `ru_maxrss`). The child is reaped by `wait4`, not `Child::wait` (which cannot
/// give its resource usage).
#[allow(clippy::zombie_processes)]
fn run_measured(cmd: &mut Command) -> (std::process::Output, i64) {
    use std::io::Read;
    use std::time::Instant;
    let mut child = qfleet_suite::spawn(cmd);
    let pid = child.id() as i32;
    let deadline = Instant::now() + qfleet_suite::PROCESS_TIMEOUT;
    let mut status = 0;
    // SAFETY: an all-zero rusage is a valid value to be overwritten.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    loop {
        // SAFETY: wait4 on this test's own child, with valid pointers.
        let r = unsafe { libc::wait4(pid, &mut status, libc::WNOHANG, &mut usage) };
        if r == pid {
            break;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{cmd:?} did not finish in time");
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let (mut out, mut err) = (Vec::new(), Vec::new());
    let _ = child.stdout.take().map(|mut p| p.read_to_end(&mut out));
    let _ = child.stderr.take().map(|mut p| p.read_to_end(&mut err));
    use std::os::unix::process::ExitStatusExt;
    let output = std::process::Output {
        status: std::process::ExitStatus::from_raw(status),
        stdout: out,
        stderr: err,
    };
    (output, usage.ru_maxrss)
}

/// Issue 27: a damaged recording is bad input (exit 2) that says at which byte it broke, a
/// message far bigger than any qfleet message is refused without being read, and memory stays
/// bounded however large the file or the message (a 240 MB message took 3.2 GB; a damaged
/// 1 GB file 2.1 GB and exited 0 with 0 messages).
#[test]
fn a_damaged_recording_or_a_huge_message_is_exit_2_naming_the_byte_in_bounded_memory() {
    use qfleet_suite::{describe, run_bounded, scratch};
    let dir = scratch("replay-damaged");
    let qfleet = bin_dir().join("qfleet");
    // whole: reads back (the baseline)
    let (mut whole, at) = hand_recording("hand", 5);
    hand_end(&mut whole);
    let file = dir.join("whole.mcap");
    std::fs::write(&file, &whole).unwrap();
    let out = run_bounded(Command::new(&qfleet).args(["replay", "--json"]).arg(&file));
    assert!(out.status.success(), "{}", describe(&out));
    let s: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(s["messages"], 5, "{s}");
    // the third message's bytes zeroed: damaged there, after two messages
    let mut damaged = whole.clone();
    damaged[at[2] + 9 + 22..at[3]].fill(0);
    let file = dir.join("damaged.mcap");
    std::fs::write(&file, &damaged).unwrap();
    let out = run_bounded(Command::new(&qfleet).arg("replay").arg(&file));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains(&format!("damaged at byte {} of {}", at[2], damaged.len()))
            && err.contains("2 message(s) read before it"),
        "{}",
        describe(&out)
    );
    // its chunk's framing broken right at its start: damaged before any message
    let mut damaged = whole.clone();
    damaged[at[0]] = 0x00;
    std::fs::write(&file, &damaged).unwrap();
    let out = run_bounded(Command::new(&qfleet).arg("replay").arg(&file));
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains(&format!(
            "damaged at byte {} of {}: unknown record opcode 0x00",
            at[0],
            damaged.len()
        )),
        "{}",
        describe(&out)
    );
    // a message claiming 240 MB (a sparse file, as long as the claim): refused unread
    let (mut huge, _) = hand_recording("hand", 2);
    let huge_at = huge.len();
    let claim: u64 = 240 << 20;
    huge.push(0x05);
    huge.extend_from_slice(&(claim + 22).to_le_bytes());
    huge.extend_from_slice(&1u16.to_le_bytes());
    huge.extend_from_slice(&[0u8; 20]);
    let file = dir.join("huge.mcap");
    std::fs::write(&file, &huge).unwrap();
    let f = std::fs::OpenOptions::new().write(true).open(&file).unwrap();
    f.set_len(huge.len() as u64 + claim).unwrap();
    drop(f);
    let (out, max_rss_kib) = run_measured(Command::new(&qfleet).arg("replay").arg(&file));
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains(&format!(
            "damaged at byte {huge_at} of {}: a message of {claim} bytes",
            huge.len() as u64 + claim
        )),
        "{}",
        describe(&out)
    );
    eprintln!("replay of a 240 MB message: peak RSS {max_rss_kib} KiB");
    assert!(max_rss_kib < 64 << 10, "peak RSS {max_rss_kib} KiB");
    // a large damaged file: its end is not read into memory either (a sparse 1 GB tail
    // behind a broken record)
    let mut big = whole.clone();
    big[at[0]] = 0x00;
    std::fs::write(&file, &big).unwrap();
    let f = std::fs::OpenOptions::new().write(true).open(&file).unwrap();
    f.set_len(1 << 30).unwrap();
    drop(f);
    let (out, max_rss_kib) = run_measured(Command::new(&qfleet).arg("replay").arg(&file));
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    eprintln!("replay of a damaged 1 GB file: peak RSS {max_rss_kib} KiB");
    assert!(max_rss_kib < 64 << 10, "peak RSS {max_rss_kib} KiB");
}

/// Issue 27: an observer showed a stray process in the run's prefix as the run's own (a
/// phantom robot). A process that is not the launcher's publishes states for a robot the
/// fleet does not have (7) and for one it has (1), marked with episode 777 777, while a run
/// is recorded: neither is in the recording, the run's own states are, and the launcher says
/// how many it left out.
#[test]
fn a_stray_process_in_the_prefix_is_neither_recorded_nor_shown_and_is_counted() {
    use bus::bus_schema::RobotState;
    use bus::{BusConfig, Observer, Outbox};
    use qfleet_suite::{PROCESS_TIMEOUT, describe, leftovers, run_id, scratch, spawn};
    use std::os::unix::process::CommandExt;
    const MARK: u32 = 777_777;
    let id = run_id("phantom");
    let dir = scratch(&id);
    let file = dir.join("run.mcap");
    let child = spawn(
        Command::new(bin_dir().join("qfleet"))
            .args(["run", "--json", "--run-id", &id, "--out"])
            .arg(dir.join("out"))
            .args(["--map", "builtin:paper-20", "--episodes", "20000"])
            .args(["--pace", "300000", "--learner", "improved", "--robots", "2"])
            .arg("--record")
            .arg(&file)
            .process_group(0),
    );
    let cfg = BusConfig::new(id.as_str(), 2).expect("config");
    let stray = Observer::join(&cfg, "stray", PROCESS_TIMEOUT).expect("join the run");
    let state = stray.inbox::<RobotState>().expect("state inbox");
    // the robots are learning: the recorder joined before they started
    let deadline = std::time::Instant::now() + PROCESS_TIMEOUT;
    while state.receive().expect("receive").is_none() {
        assert!(std::time::Instant::now() < deadline, "no robot state");
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let out = Outbox::<RobotState>::open(stray.node(), stray.config()).expect("state outbox");
    for _ in 0..100 {
        for robot_id in [7, 1] {
            let _ = out.send(&RobotState {
                robot_id,
                episode: MARK,
                ..RobotState::ZEROED
            });
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    drop((out, state));
    qfleet_suite::leave_run(stray, &id);
    let run = qfleet_suite::wait_bounded(child, PROCESS_TIMEOUT);
    assert!(run.status.success(), "{}", describe(&run));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        err.contains("from processes outside the run") && err.contains("robot/state"),
        "{}",
        describe(&run)
    );
    let rec = observe::replay::Recording::open(&file).expect("the recording");
    let mut own = 0;
    rec.for_each(|_, topic, v| {
        if topic == bus::bus_schema::names::Topic::RobotState {
            assert!(v["robot_id"].as_u64() < Some(2), "a phantom robot: {v}");
            assert_ne!(
                v["episode"].as_u64(),
                Some(u64::from(MARK)),
                "a stray's state: {v}"
            );
            own += 1;
        }
        Ok(())
    })
    .expect("reads");
    assert!(own > 0, "the run's own states are recorded");
    assert!(leftovers(&id).is_empty(), "{:?}", leftovers(&id));
}
