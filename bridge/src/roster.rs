//! Which of the joining host's robots are gone: the decision behind the `gone` list of its
//! heartbeats, without IO.
//!
//! Two sources say a robot's process is gone, and either is enough:
//! - **its process ended**: `qfleet join` started it and reaped it ([`Roster::exited`]). This is
//!   the authority: it does not depend on the robot's iceoryx2 node ever having been seen.
//! - **a node listing** ([`Roster::listed`]): a robot listed dead, or once listed alive and
//!   missing from a later listing; what a joining side that did not start its robots has.
//!
//! Listings alone are not enough. A full listing comes at most every second
//! ([`bus::lister::FULL_EVERY`]; the re-checks between look only at the processes the last full
//! one found), and the listing thread cleans dead nodes up: a robot that started after one full
//! listing and was killed before the next was never listed alive, and once its dead node was
//! cleaned it was in no listing at all, so its death was never reported. The hub then kept its
//! proxy, the coordinator took the robot for hung instead of lost, and it stayed on a shared
//! grid as an obstacle until the tick limit (`tests/multihost.rs`, robot 6 killed on host B).
//! A robot once gone stays gone: a process of the same id started later is not this host's to
//! run (`qfleet join` restarts nothing).

/// How a node listing shows one robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Listed {
    /// Its node is alive.
    Alive,
    /// Its node is there and dead (the process died without cleaning up).
    Dead,
    /// No node of it (never made, cleaned up, or unreadable).
    Absent,
}

/// The joining host's robots: which were seen alive, which are gone.
#[derive(Debug, Clone)]
pub struct Roster {
    /// This host's robot ids (from the plan).
    ids: Vec<u32>,
    /// Per robot of `ids`: seen alive in a listing.
    seen: Vec<bool>,
    /// The gone robots, in the order they went; each once, only ids of `ids`.
    gone: Vec<u32>,
}

impl Roster {
    /// A roster of `ids`, none seen, none gone.
    pub fn new(ids: &[u32]) -> Self {
        Roster {
            ids: ids.to_vec(),
            seen: vec![false; ids.len()],
            gone: Vec::with_capacity(ids.len()),
        }
    }

    fn index(&self, id: u32) -> Option<usize> {
        self.ids.iter().position(|&i| i == id)
    }

    fn go(&mut self, i: usize) -> bool {
        let id = self.ids[i];
        if self.gone.contains(&id) {
            return false;
        }
        self.gone.push(id);
        true
    }

    /// The robot's process ended (whatever its exit status): it is gone. True when this is
    /// new. An id not of this host is ignored.
    pub fn exited(&mut self, id: u32) -> bool {
        match self.index(id) {
            Some(i) => self.go(i),
            None => false,
        }
    }

    /// Takes a node listing: `state(id)` is how it shows robot `id` of this host. A robot listed
    /// dead is gone; so is one seen alive before and absent now (its node cleaned up, or not
    /// readable). Returns how many went.
    pub fn listed(&mut self, state: impl Fn(u32) -> Listed) -> usize {
        let mut went = 0;
        for i in 0..self.ids.len() {
            match state(self.ids[i]) {
                Listed::Alive => self.seen[i] = true,
                Listed::Dead => went += usize::from(self.go(i)),
                Listed::Absent if self.seen[i] => went += usize::from(self.go(i)),
                Listed::Absent => {}
            }
        }
        went
    }

    /// The gone robots, each once, in the order they went.
    pub fn gone(&self) -> &[u32] {
        &self.gone
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A listing that shows `ids` alive and nothing else.
    fn alive(ids: &[u32]) -> impl Fn(u32) -> Listed + '_ {
        move |id| {
            if ids.contains(&id) {
                Listed::Alive
            } else {
                Listed::Absent
            }
        }
    }

    #[test]
    fn a_robot_seen_alive_then_missing_from_a_listing_is_gone() {
        let mut r = Roster::new(&[4, 5, 6, 7]);
        assert_eq!(r.listed(alive(&[4, 5, 6, 7])), 0);
        assert!(r.gone().is_empty());
        assert_eq!(r.listed(alive(&[4, 5, 7])), 1);
        assert_eq!(r.gone(), [6]);
        // reported once, however often the listings miss it
        assert_eq!(r.listed(alive(&[4, 5, 7])), 0);
        assert_eq!(r.gone(), [6]);
    }

    #[test]
    fn a_robot_no_listing_ever_showed_alive_is_gone_when_its_process_ends() {
        // the failure of the shared-grid kill test: robot 6 started after host B's first full
        // listing ({4}) and was killed before the next; its dead node was cleaned up, so no
        // listing ever named it and its death never reached the hub
        let mut r = Roster::new(&[4, 5, 6, 7]);
        r.listed(alive(&[4]));
        for _ in 0..10 {
            r.listed(alive(&[4, 5, 7]));
        }
        assert!(r.gone().is_empty(), "never seen: an absence proves nothing");
        assert!(r.exited(6));
        assert_eq!(r.gone(), [6]);
        assert!(!r.exited(6), "once");
        r.listed(alive(&[4, 5, 7]));
        assert_eq!(r.gone(), [6]);
    }

    #[test]
    fn a_robot_listed_dead_is_gone_even_if_never_listed_alive() {
        let mut r = Roster::new(&[4, 5, 6, 7]);
        r.listed(alive(&[4]));
        let went = r.listed(|id| match id {
            6 => Listed::Dead,
            4 | 5 | 7 => Listed::Alive,
            _ => Listed::Absent,
        });
        assert_eq!((went, r.gone()), (1, &[6][..]));
    }

    #[test]
    fn an_exit_and_a_listing_of_the_same_death_report_it_once() {
        let mut r = Roster::new(&[0, 1]);
        r.listed(alive(&[0, 1]));
        assert!(r.exited(1));
        assert_eq!(r.listed(alive(&[0])), 0);
        let mut r2 = Roster::new(&[0, 1]);
        r2.listed(alive(&[0, 1]));
        assert_eq!(r2.listed(alive(&[0])), 1);
        assert!(!r2.exited(1));
        assert_eq!((r.gone(), r2.gone()), (&[1][..], &[1][..]));
    }

    #[test]
    fn other_hosts_ids_and_a_robot_back_in_a_listing_change_nothing() {
        let mut r = Roster::new(&[2, 3]);
        assert!(!r.exited(9), "not this host's");
        r.listed(alive(&[2, 3, 9]));
        r.listed(alive(&[2]));
        assert_eq!(r.gone(), [3]);
        // a node of the same id listed again does not bring a gone robot back
        r.listed(alive(&[2, 3]));
        assert_eq!(r.gone(), [3]);
    }

    #[test]
    fn a_robot_that_exits_before_any_listing_is_gone() {
        let mut r = Roster::new(&[4, 5]);
        assert!(r.exited(5));
        r.listed(alive(&[4]));
        assert_eq!(r.gone(), [5]);
    }
}
