//! A coordinator can sleep in an iceoryx2 WaitSet on all its inboxes at once and is woken by
//! the topic that got data, or by its timeout.

mod common;

use std::time::{Duration, Instant};

use bus::bus_schema::{PseudoTargetDiscovery, RobotState};
use bus::iceoryx2::prelude::*;
use bus::{CoordinatorBus, RobotBus};
use common::{PATIENCE, assert_no_leftovers, config};

#[test]
fn the_waitset_wakes_on_the_notified_topic_and_times_out_otherwise() {
    let cfg = config("waitset", 1);
    let cfg = &cfg;
    std::thread::scope(|s| {
        let (go_tx, go_rx) = std::sync::mpsc::channel::<()>();
        let (ready_tx, ready_rx) = std::sync::mpsc::channel::<()>();
        s.spawn(move || {
            let robot = RobotBus::open(cfg, 0, PATIENCE).unwrap();
            ready_tx.send(()).unwrap();
            go_rx.recv().unwrap();
            std::thread::sleep(Duration::from_millis(50));
            robot.state.send(&RobotState::ZEROED).unwrap();
            robot
                .discovery
                .send(&PseudoTargetDiscovery::ZEROED)
                .unwrap();
            robot.discovery.notify().unwrap();
            go_rx.recv().unwrap();
        });
        let coord = CoordinatorBus::create(cfg).unwrap();
        ready_rx.recv().unwrap();
        coord.connect_all().unwrap();

        let waitset = WaitSetBuilder::new()
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .unwrap();
        let guards = coord.attach_all(&waitset).unwrap();
        assert_eq!(guards.len(), 5);

        // nothing sent: the timeout ends the wait
        let t = Instant::now();
        let mut woken = 0;
        waitset
            .wait_and_process_once_with_timeout(
                |_| {
                    woken += 1;
                    CallbackProgression::Continue
                },
                Duration::from_millis(100),
            )
            .unwrap();
        assert_eq!(woken, 0);
        assert!(t.elapsed() >= Duration::from_millis(90));

        // data + notify on discovery: exactly that attachment fires; state was sent silently
        go_tx.send(()).unwrap();
        let mut fired = Vec::new();
        let deadline = Instant::now() + PATIENCE;
        while fired.is_empty() {
            assert!(Instant::now() < deadline, "no wakeup");
            waitset
                .wait_and_process_once_with_timeout(
                    |id| {
                        for (i, g) in guards.iter().enumerate() {
                            if id.has_event_from(g) {
                                fired.push(coord.listeners()[i].0);
                            }
                        }
                        CallbackProgression::Continue
                    },
                    Duration::from_secs(1),
                )
                .unwrap();
        }
        use bus::bus_schema::names::Topic;
        assert_eq!(fired, [Topic::Discovery]);
        let w = coord.discovery.clear_wakeups().unwrap();
        assert!(w.data >= 1 && !w.peer_dead, "{w:?}");
        assert!(coord.discovery.receive().unwrap().is_some());
        assert!(
            coord.state.receive().unwrap().is_some(),
            "unnotified data is still there"
        );
        go_tx.send(()).unwrap();
        drop(guards);
        drop(waitset);
        // wait for the robot thread to drop its node before closing
        while bus::check_nodes(cfg, false).unwrap().alive().count() > 1 {
            std::thread::sleep(Duration::from_millis(5));
        }
        coord.close().unwrap();
    });
    assert_no_leftovers(cfg);
}
