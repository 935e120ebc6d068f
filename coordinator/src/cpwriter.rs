//! Checkpoints written off the serving loop: the loop hands the newest checkpoint over and
//! goes on; a thread of its own writes it. A slow or stalled `--out` disk used to stall the
//! loop inside its checkpoint write (issue 27): no message was read meanwhile, and healthy
//! robots were reported `hung` or `missing`.
//!
//! [`Writer`] holds one slot (a bounded channel of one, latest-wins): a checkpoint handed over
//! while an older one still waits replaces it (counted in [`Written::superseded`]) — only the
//! newest matters to a coordinator that takes over. [`Writer::finish`] waits until the last
//! one handed over is written (the run's end: its `complete` checkpoint must reach the disk).
//! The disk is behind [`Sink`], so a test can make it as slow as it likes.

use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::thread::JoinHandle;

/// Where checkpoints go.
pub trait Sink<T>: Send + 'static {
    /// Writes `cp` (it may take long: it runs on the writer's thread).
    fn write(&mut self, cp: &T) -> Result<(), String>;
}

/// What a writer did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Written {
    /// Checkpoints written.
    pub written: u64,
    /// Checkpoints replaced by a newer one before they were written.
    pub superseded: u64,
    /// Writes that failed.
    pub failed: u64,
}

struct Slot<T> {
    next: Option<T>,
    /// The thread is writing one now.
    busy: bool,
    closed: bool,
    done: Written,
    /// The first failure, said once.
    first_error: Option<String>,
}

struct Shared<T> {
    slot: Mutex<Slot<T>>,
    changed: Condvar,
}

/// Hands checkpoints to a writer thread (see the module documentation).
pub struct Writer<T: Send + 'static> {
    shared: Arc<Shared<T>>,
    thread: Option<JoinHandle<()>>,
}

impl<T: Send + 'static> Writer<T> {
    /// Starts the writer thread over `sink`; `on_error` is called once, on the writer's
    /// thread, with the first failure (a checkpoint not written does not stop a run: it only
    /// helps a restarted coordinator).
    pub fn start(
        mut sink: impl Sink<T>,
        on_error: impl Fn(&str) + Send + 'static,
    ) -> std::io::Result<Self> {
        let shared = Arc::new(Shared {
            slot: Mutex::new(Slot {
                next: None,
                busy: false,
                closed: false,
                done: Written::default(),
                first_error: None,
            }),
            changed: Condvar::new(),
        });
        let s = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("qfleet-checkpoint".into())
            .spawn(move || {
                loop {
                    let cp = {
                        let mut slot = s.slot.lock().unwrap_or_else(PoisonError::into_inner);
                        loop {
                            if let Some(cp) = slot.next.take() {
                                slot.busy = true;
                                break cp;
                            }
                            if slot.closed {
                                return;
                            }
                            slot = s.changed.wait(slot).unwrap_or_else(PoisonError::into_inner);
                        }
                    };
                    let r = sink.write(&cp);
                    let mut slot = s.slot.lock().unwrap_or_else(PoisonError::into_inner);
                    slot.busy = false;
                    match r {
                        Ok(()) => slot.done.written += 1,
                        Err(e) => {
                            slot.done.failed += 1;
                            if slot.first_error.is_none() {
                                on_error(&e);
                                slot.first_error = Some(e);
                            }
                        }
                    }
                    s.changed.notify_all();
                }
            })?;
        Ok(Self {
            shared,
            thread: Some(thread),
        })
    }

    /// Hands `cp` over and returns at once, whatever the disk does; an older checkpoint not
    /// yet written is replaced.
    pub fn offer(&self, cp: T) {
        let mut slot = self
            .shared
            .slot
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if slot.next.replace(cp).is_some() {
            slot.done.superseded += 1;
        }
        self.shared.changed.notify_all();
    }

    /// Waits until every checkpoint handed over is written (or failed), stops the thread and
    /// says what it did.
    pub fn finish(mut self) -> Written {
        self.close()
    }

    fn close(&mut self) -> Written {
        {
            let mut slot = self
                .shared
                .slot
                .lock()
                .unwrap_or_else(PoisonError::into_inner);
            slot.closed = true;
            self.shared.changed.notify_all();
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.shared
            .slot
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .done
    }
}

impl<T: Send + 'static> Drop for Writer<T> {
    fn drop(&mut self) {
        self.close();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;
    use std::time::Duration;

    /// A disk that blocks every write until the test lets it go, and keeps what it wrote.
    struct Stalled {
        go: mpsc::Receiver<()>,
        wrote: Arc<Mutex<Vec<u32>>>,
        entered: mpsc::Sender<u32>,
    }

    impl Sink<u32> for Stalled {
        fn write(&mut self, cp: &u32) -> Result<(), String> {
            let _ = self.entered.send(*cp);
            self.go.recv().map_err(|e| e.to_string())?;
            self.wrote.lock().unwrap().push(*cp);
            Ok(())
        }
    }

    #[test]
    fn a_stalled_disk_never_blocks_the_hand_over_and_the_newest_checkpoint_is_written() {
        let (go_tx, go) = mpsc::channel();
        let (entered, entered_rx) = mpsc::channel();
        let wrote = Arc::new(Mutex::new(Vec::new()));
        let w = Writer::start(
            Stalled {
                go,
                wrote: Arc::clone(&wrote),
                entered,
            },
            |_| {},
        )
        .unwrap();
        w.offer(1);
        // the writer is inside a write that will not end until the test says so
        assert_eq!(entered_rx.recv_timeout(Duration::from_secs(60)), Ok(1));
        // the serving loop hands over 100 more while the disk is stalled: none blocks (a
        // blocking offer would never return, and the test would hang here rather than pass)
        for cp in 2..=101 {
            w.offer(cp);
        }
        // the disk comes back: the stalled write ends, then only the newest is written
        go_tx.send(()).unwrap();
        assert_eq!(entered_rx.recv_timeout(Duration::from_secs(60)), Ok(101));
        go_tx.send(()).unwrap();
        let done = w.finish();
        assert_eq!(*wrote.lock().unwrap(), vec![1, 101]);
        assert_eq!(
            done,
            Written {
                written: 2,
                superseded: 99,
                failed: 0
            }
        );
    }

    struct Full;

    impl Sink<u32> for Full {
        fn write(&mut self, _: &u32) -> Result<(), String> {
            Err("No space left on device".into())
        }
    }

    #[test]
    fn a_failing_disk_is_said_once_and_counted() {
        let said = Arc::new(Mutex::new(Vec::new()));
        let s = Arc::clone(&said);
        let w = Writer::start(Full, move |e| s.lock().unwrap().push(e.to_string())).unwrap();
        w.offer(1);
        // finish waits for what was handed over
        let first = w.finish();
        assert_eq!(first.failed, 1);
        let w = Writer::start(Full, |_| {}).unwrap();
        for cp in 0..3 {
            w.offer(cp);
        }
        assert!(w.finish().failed >= 1);
        assert_eq!(
            *said.lock().unwrap(),
            vec!["No space left on device".to_string()]
        );
    }
}
