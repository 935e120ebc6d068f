//! A wake socket: lets any thread end an iceoryx2 `WaitSet` wait, so one loop can block on its
//! inboxes' wake listeners and on something outside iceoryx2 (a network callback) at once.
//!
//! [`wake_pair`] makes a connected stream socket pair: the [`WakeListener`] end attaches to a
//! `WaitSet` beside the listeners, the [`Waker`] end (cheap to clone, `Send + Sync`) writes one
//! byte when woken. Wakes coalesce: while one is pending (not yet [`WakeListener::clear`]ed) the
//! next ones write nothing, so a burst costs one syscall, not one per item.
//!
//! The protocol: producers push their item somewhere the loop reads (a channel), then call
//! [`Waker::wake`]; after a wait the loop calls [`WakeListener::clear`] *before* it drains that
//! channel. An item pushed after the clear wakes the loop again; one pushed before it is
//! drained now.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use iceoryx2::prelude::{WaitSet, WaitSetGuard, ipc};
use iceoryx2_bb_posix::socket_pair::StreamingSocket;

use crate::BusError;

fn err(what: &str, e: impl std::fmt::Debug) -> BusError {
    BusError::Event {
        service: "wake socket".into(),
        detail: format!("{what}: {e:?}"),
    }
}

/// The writing end: ends the listener's `WaitSet` wait (see the module doc).
#[derive(Debug, Clone)]
pub struct Waker {
    socket: Arc<StreamingSocket>,
    pending: Arc<AtomicBool>,
}

/// The reading end: attach it to a `WaitSet`; [`clear`](Self::clear) it after every wakeup.
#[derive(Debug)]
pub struct WakeListener {
    socket: StreamingSocket,
    pending: Arc<AtomicBool>,
}

/// A connected waker and listener.
pub fn wake_pair() -> Result<(Waker, WakeListener), BusError> {
    let (a, b) = StreamingSocket::create_pair().map_err(|e| err("socketpair", e))?;
    let pending = Arc::new(AtomicBool::new(false));
    Ok((
        Waker {
            socket: Arc::new(a),
            pending: Arc::clone(&pending),
        },
        WakeListener { socket: b, pending },
    ))
}

impl Waker {
    /// Wakes the listener's loop (one byte, unless a wake is already pending). Never blocks; a
    /// failed write is ignored (the loop still wakes at its next timeout).
    pub fn wake(&self) {
        if !self.pending.swap(true, Ordering::SeqCst) {
            let _ = self.socket.try_send(&[1]);
        }
    }
}

impl WakeListener {
    /// Attaches this end to `waitset`; keep the guard as long as the attachment should last.
    pub fn attach<'w, 'a>(
        &'a self,
        waitset: &'w WaitSet<ipc::Service>,
    ) -> Result<WaitSetGuard<'w, 'a, ipc::Service>, BusError> {
        waitset
            .attach_notification(&self.socket)
            .map_err(|e| err("cannot attach to the WaitSet", e))
    }

    /// Consumes the pending wake (reads every byte written); returns whether one was pending.
    /// Call it after a `WaitSet` wait, before draining what the wakers pushed; between waits
    /// it is not needed (a wake still pending keeps the next wait from blocking).
    pub fn clear(&self) -> bool {
        let was = self.pending.swap(false, Ordering::SeqCst);
        // also a byte whose writer set `pending` before the swap but wrote after the last clear
        let mut buf = [0u8; 64];
        while matches!(self.socket.try_receive(&mut buf), Ok(n) if n > 0) {}
        was
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use iceoryx2::prelude::*;

    use super::*;

    fn waitset() -> WaitSet<ipc::Service> {
        WaitSetBuilder::new()
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .unwrap()
    }

    #[test]
    fn a_wake_from_another_thread_ends_a_waitset_wait_and_clear_rearms_it() {
        let (waker, listener) = wake_pair().unwrap();
        let ws = waitset();
        let guard = listener.attach(&ws).unwrap();
        let long = Duration::from_secs(20);
        let w = waker.clone();
        let t = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(20));
            w.wake();
            w.wake();
        });
        let mut fired = false;
        ws.wait_and_process_once_with_timeout(
            |id| {
                fired |= id.has_event_from(&guard);
                CallbackProgression::Continue
            },
            long,
        )
        .unwrap();
        t.join().unwrap();
        assert!(fired, "the wait ended without the wake socket's event");
        // both wakes collapsed into one, and clearing leaves nothing to wake on
        assert!(listener.clear());
        assert!(!listener.clear());
        let mut again = false;
        ws.wait_and_process_once_with_timeout(
            |id| {
                again |= id.has_event_from(&guard);
                CallbackProgression::Continue
            },
            Duration::from_millis(10),
        )
        .unwrap();
        assert!(!again, "a cleared wake fired again");
        // and the next wake fires again
        waker.wake();
        let t0 = Instant::now();
        let mut third = false;
        ws.wait_and_process_once_with_timeout(
            |id| {
                third |= id.has_event_from(&guard);
                CallbackProgression::Continue
            },
            long,
        )
        .unwrap();
        assert!(
            third && t0.elapsed() < long,
            "a wake after a clear was lost"
        );
    }
}
