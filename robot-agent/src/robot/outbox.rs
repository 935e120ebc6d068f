//! What the robot sends: its state (latest-wins, and a heartbeat while not learning), batches
//! of changed Q-values (latest-wins), and its discoveries (lossless, numbered, sent again until
//! acknowledged, held while no coordinator is there). A failed send is counted, never fatal.

use std::time::{Duration, Instant};

use bus::bus_schema::{PseudoTargetDiscovery, RobotStatus};
use bus::monotonic_ns;

use super::{Phase, Robot};

/// How often a robot that is not learning tells the coordinator it is alive.
const HEARTBEAT: Duration = Duration::from_millis(100);

impl Robot<'_> {
    /// Publishes where the robot is and how far it got (latest-wins; a failure is counted).
    pub(super) fn send_state(&mut self, p: &Phase, status: RobotStatus, cell_idx: u32) {
        let cell = p.task.grid.cell(cell_idx as usize);
        let (robot_id, goal_id, episode, step, last, seq) = (
            self.args.robot_id,
            p.a.goal_id,
            p.learner.episodes_done(),
            p.episode_step,
            p.last_episode_steps,
            self.state_seq,
        );
        let sent = self.bus.state.send_with(|m| {
            m.robot_id = robot_id;
            m.goal_id = goal_id;
            m.episode = episode;
            m.step = step;
            m.last_episode_steps = last;
            m.cell_x = cell.x;
            m.cell_y = cell.y;
            m.status = status.as_u8();
            m.seq = seq;
            m.send_time_ns = monotonic_ns();
        });
        self.state_seq += 1;
        match sent {
            Ok(_) => self.c.states_sent += 1,
            Err(_) => self.c.send_errors += 1,
        }
    }

    /// A state now and then while not learning (waiting for acks or for the next phase), so
    /// the coordinator's heartbeat deadline does not take a waiting robot for a hung one.
    pub(super) fn heartbeat(&mut self, p: &Phase, status: RobotStatus, last: &mut Instant) {
        if last.elapsed() >= HEARTBEAT {
            *last = Instant::now();
            let at = p.learner.env().start();
            self.send_state(p, status, at);
            let _ = self.bus.state.notify();
        }
    }

    /// Sends the batcher's pending Q-values of the current goal as one batch and wakes the
    /// coordinator (latest-wins; a failure is counted, the values go again when they change).
    pub(super) fn send_hints(&mut self, p: &mut Phase) {
        let (robot_id, goal_id, seq) = (self.args.robot_id, p.a.goal_id, self.hint_seq);
        let batcher = &mut p.batcher;
        let mut n = 0;
        let sent = self.bus.hints.send_batch(|b| {
            b.robot_id = robot_id;
            b.goal_id = goal_id;
            b.seq = seq;
            n = batcher.fill(b);
            b.send_time_ns = monotonic_ns();
        });
        if n == 0 {
            // the loan failed before `fill`: drop the pending values (latest-wins)
            batcher.clear_shared();
        }
        self.hint_seq += 1;
        match sent {
            Ok(_) => {
                self.c.hint_batches_sent += 1;
                self.c.hint_entries_sent += n as u64;
                // waking the coordinator costs a syscall; once per batch is cheap enough
                let _ = self.bus.hints.notify();
                // and lets it (and the fleet) run: on a host with fewer cores than processes a
                // robot that kept its core would learn its whole task within its time slices,
                // before the coordinator had relayed anything of the others to it or of it to
                // them; which robots learned alone then depended on the scheduler
                // (docs/bench/history.md, "Shared grid: planning with the others' moves").
                // Nothing else runnable: returns at once
                std::thread::yield_now();
            }
            Err(_) => self.c.send_errors += 1,
        }
    }

    /// Records a pseudo target this robot found and sends it now unless no coordinator is
    /// there (kept until acknowledged either way).
    pub(super) fn queue_discovery(&mut self, p: &Phase, cell: u32, value: f32) {
        let c = p.task.grid.cell(cell as usize);
        let d = PseudoTargetDiscovery {
            goal_id: p.a.goal_id,
            cell_x: c.x,
            cell_y: c.y,
            value,
            time_ns: monotonic_ns(),
            episode: p.records.len() as u32,
            ..PseudoTargetDiscovery::ZEROED
        };
        self.c.discoveries_sent += 1;
        // first send happens now (unless no coordinator is there to take it); a failure
        // leaves it for the re-send timer
        let alone = self.link.alone();
        let d = self.disc.record(d, Instant::now(), !alone);
        if alone {
            self.link.counters.discoveries_while_alone += 1;
        } else {
            let sent = self.bus.discovery.send_with(|m| {
                *m = d;
                m.send_time_ns = monotonic_ns();
            });
            if sent.is_err() {
                self.c.discovery_send_errors += 1;
            }
        }
        self.disc_dirty = true;
    }

    /// Sends again the discoveries whose acknowledgement is overdue, and wakes the coordinator
    /// if anything went out.
    pub(super) fn resend_discoveries(&mut self) {
        if self.link.alone() {
            return; // kept until a coordinator is back and acknowledges them
        }
        let (bus, c) = (&self.bus, &mut self.c);
        let n = self.disc.due(Instant::now(), |d| {
            let sent = bus.discovery.send_with(|m| {
                *m = *d;
                m.send_time_ns = monotonic_ns();
            });
            match sent {
                Ok(_) => c.discoveries_resent += 1,
                Err(_) => c.discovery_send_errors += 1,
            }
        });
        if n > 0 || std::mem::take(&mut self.disc_dirty) {
            let _ = self.bus.discovery.notify();
        }
    }
}
