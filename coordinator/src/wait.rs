//! The receive loop both drivers run a phase with: drain, take the newest node listing, and
//! wait by the chosen [`WaitStrategy`] (see [`options`](crate::options) for the three).
//!
//! All strategies also wake every 50 ms for the periodic work the driver asks for (progress
//! lines, its end-of-phase check). Liveness (iceoryx2 node states) is listed on a thread of its
//! own ([`Lister`]); the loop only takes the newest listing from a channel, so no node listing
//! ever runs on this loop.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use bus::iceoryx2::prelude::*;
use bus::{BusError, CoordinatorBus, Lister};

use crate::engine::Engine;
use crate::options::{CoordError, WaitStrategy};

/// How the loop waits.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Waiting {
    /// The strategy.
    pub(crate) strategy: WaitStrategy,
    /// Hybrid: how long to keep spinning after the last message.
    pub(crate) spin: Duration,
}

fn waitset_error(e: impl std::fmt::Debug) -> BusError {
    BusError::Event {
        service: "WaitSet".into(),
        detail: format!("{e:?}"),
    }
}

/// What a phase is served over: the bus, the liveness thread, the wait strategy and the stop
/// flag a signal sets.
pub(crate) struct Serving<'a> {
    pub(crate) bus: &'a CoordinatorBus,
    pub(crate) lister: &'a Lister,
    pub(crate) how: Waiting,
    pub(crate) stop: &'a AtomicBool,
}

/// Serves the bus until `periodic` says the phase is over (true) or `stop` is set; returns
/// whether it was stopped by a signal. `after_drain` runs after every drain that took
/// something (the experiment watches its merged tables there).
pub(crate) fn serve(
    engine: &mut Engine,
    with: &Serving<'_>,
    mut after_drain: impl FnMut(&mut Engine),
    mut periodic: impl FnMut(&mut Engine) -> bool,
) -> Result<bool, CoordError> {
    let Serving {
        bus,
        lister,
        how,
        stop,
    } = *with;
    let strategy = how.strategy;
    let waitset = match strategy {
        WaitStrategy::Spin => None,
        // iceoryx2's own SIGINT/SIGTERM handler would replace the process's (ctrlc) one and
        // swallow the stop request: keep it off
        _ => Some(
            WaitSetBuilder::new()
                .signal_handling_mode(SignalHandlingMode::Disabled)
                .create::<ipc::Service>()
                .map_err(waitset_error)?,
        ),
    };
    let guards = match &waitset {
        Some(ws) => bus.attach_all(ws)?,
        None => Vec::new(),
    };
    let clear = |i: usize| -> Result<bus::Wakeups, BusError> {
        match i {
            0 => bus.register.clear_wakeups(),
            1 => bus.state.clear_wakeups(),
            2 => bus.discovery.clear_wakeups(),
            3 => bus.hints.clear_wakeups(),
            _ => bus.report.clear_wakeups(),
        }
    };
    let mut last_activity = Instant::now();
    let mut last_periodic = Instant::now();
    let mut peer_dead = false;
    let mut iter: u32 = 0;
    loop {
        let n = engine.drain(bus)?;
        if n > 0 {
            after_drain(engine);
        }
        iter = iter.wrapping_add(1);
        let check_clock = n > 0 || strategy != WaitStrategy::Spin || iter.is_multiple_of(64);
        if !check_clock {
            std::hint::spin_loop();
            continue;
        }
        if let Some(listing) = lister.poll() {
            engine.liveness(bus, listing)?;
        }
        let now = Instant::now();
        if n > 0 {
            last_activity = now;
        }
        if now.duration_since(last_periodic) >= Duration::from_millis(50) || peer_dead {
            last_periodic = now;
            if std::mem::take(&mut peer_dead) {
                lister.now();
            }
            if stop.load(Ordering::Relaxed) || engine.halted() {
                return Ok(true);
            }
            if periodic(engine) {
                // take in whatever arrived meanwhile
                if engine.drain(bus)? > 0 {
                    after_drain(engine);
                }
                return Ok(false);
            }
        }
        if n > 0 {
            continue;
        }
        let block = match strategy {
            WaitStrategy::Spin => false,
            WaitStrategy::Event => true,
            WaitStrategy::Hybrid => now.duration_since(last_activity) >= how.spin,
        };
        let Some(ws) = waitset.as_ref().filter(|_| block) else {
            std::hint::spin_loop();
            continue;
        };
        let mut err = None;
        ws.wait_and_process_once_with_timeout(
            |id| {
                for (i, g) in guards.iter().enumerate() {
                    if id.has_event_from(g) {
                        match clear(i) {
                            Ok(w) => peer_dead |= w.peer_dead,
                            Err(e) => err = Some(e),
                        }
                    }
                }
                CallbackProgression::Continue
            },
            Duration::from_millis(50),
        )
        .map_err(waitset_error)?;
        if let Some(e) = err {
            return Err(e.into());
        }
    }
}
