//! `qfleet topic echo|hz`: following a live run's messages through an attached [`Observer`]
//! until the run ends, a count is reached, the reader left (a closed pipe ends it cleanly) or
//! a stop is asked for: every message as one JSON line ([`Follow::Echo`]), or each topic's
//! rate every second ([`Follow::Hz`], [`rates_report`]).

use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bus_schema::names::Topic;
use serde_json::json;

use crate::ObserveError;
use crate::attach::Observer;
use crate::stats::{Rate, TopicCounts, rates_report, topic_index};

/// What [`follow`] prints.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Follow {
    /// Every message as one JSON line.
    Echo,
    /// Message rates per topic every second (JSON with `json`).
    Hz {
        /// One JSON object a report instead of text lines.
        json: bool,
    },
}

/// A write to the reader: Ok(false) when it left (a closed pipe), an error otherwise.
fn written(r: std::io::Result<()>) -> Result<bool, ObserveError> {
    match r {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(false),
        Err(e) => Err(ObserveError::Stdout(e)),
    }
}

/// Follows `observer`'s run (topic `only`, or all) as `mode` says into `out`, until the run
/// ended (one more drain for what it sent last), `count` lines or reports were printed (0: no
/// limit), `out`'s reader left, or `stop` was set; returns how many were printed.
pub fn follow(
    observer: &Observer,
    only: Option<Topic>,
    mode: Follow,
    count: u64,
    stop: &AtomicBool,
    out: &mut dyn Write,
) -> Result<u64, ObserveError> {
    let mut counts = TopicCounts::default();
    let mut rates: Vec<Rate> = (0..Topic::ALL.len())
        .map(|_| Rate::new(1_000_000_000))
        .collect();
    let mut printed = 0u64;
    let mut open = true;
    let mut last_check = Instant::now();
    let mut last_hz = Instant::now();
    let mut line = Vec::with_capacity(8192);
    let mut err: Option<ObserveError> = None;
    let mut last_round = false;
    loop {
        let n = observer.poll(|recv_ns, m| {
            let topic = m.topic();
            if only.is_some_and(|o| o != topic) || !open || err.is_some() {
                return;
            }
            counts.add(topic, recv_ns);
            rates[topic_index(topic)].add(recv_ns, 1);
            if mode == Follow::Echo {
                line.clear();
                let v = json!({
                    "topic": topic.path(), "recv_ns": recv_ns, "msg": m.to_json(),
                });
                if let Err(e) = serde_json::to_writer(&mut line, &v) {
                    err = Some(e.into());
                    return;
                }
                line.push(b'\n');
                match written(out.write_all(&line)) {
                    Ok(true) => {}
                    Ok(false) => open = false,
                    Err(e) => err = Some(e),
                }
                printed += 1;
                if count > 0 && printed >= count {
                    open = false;
                }
            }
        })?;
        if let Some(e) = err {
            return Err(e);
        }
        if n > 0 && mode == Follow::Echo && !written(out.flush())? {
            open = false;
        }
        if !open || stop.load(Ordering::SeqCst) || last_round {
            break;
        }
        if let Follow::Hz { json } = mode
            && last_hz.elapsed() >= Duration::from_secs(1)
        {
            last_hz = Instant::now();
            let s = rates_report(&mut rates, &counts, only, bus::monotonic_ns(), json);
            if !written(out.write_all(s.as_bytes()).and_then(|()| out.flush()))? {
                break;
            }
            printed += 1;
            if count > 0 && printed >= count {
                break;
            }
        }
        if last_check.elapsed() >= Duration::from_millis(200) {
            last_check = Instant::now();
            // the run is over: one more drain for what it sent last, then leave
            last_round = !observer.run_alive();
        }
        if n == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
    }
    let _ = out.flush();
    Ok(printed)
}
