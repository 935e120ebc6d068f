//! Two runs with different run ids share nothing: not messages, not nodes, not files.

mod common;

use std::time::Duration;

use bus::bus_schema::RobotState;
use bus::{BusError, CoordinatorBus, RobotBus, check_nodes, leftover_files};
use common::{PATIENCE, assert_no_leftovers, config, recv};

#[test]
fn runs_with_different_ids_do_not_see_each_other() {
    let a = config("iso-a", 1);
    let b = config("iso-b", 1);
    let coord_a = CoordinatorBus::create(&a).unwrap();
    let coord_b = CoordinatorBus::create(&b).unwrap();
    let robot_a = RobotBus::open(&a, 0, PATIENCE).unwrap();
    let robot_b = RobotBus::open(&b, 0, PATIENCE).unwrap();
    coord_a.connect_all().unwrap();
    coord_b.connect_all().unwrap();

    let from_a = RobotState {
        episode: 1,
        ..RobotState::ZEROED
    };
    let from_b = RobotState {
        episode: 2,
        ..RobotState::ZEROED
    };
    assert_eq!(
        robot_a.state.send(&from_a).unwrap(),
        1,
        "only run a's coordinator"
    );
    assert_eq!(
        robot_b.state.send(&from_b).unwrap(),
        1,
        "only run b's coordinator"
    );
    assert_eq!(recv(&coord_a.state), from_a);
    assert_eq!(recv(&coord_b.state), from_b);
    assert_eq!(coord_a.state.receive().unwrap(), None);
    assert_eq!(coord_b.state.receive().unwrap(), None);

    // each run lists only its own two nodes
    for cfg in [&a, &b] {
        let nodes = check_nodes(cfg, false).unwrap();
        let mut names: Vec<_> = nodes.alive().map(|n| n.name.clone()).collect();
        names.sort();
        assert_eq!(names, ["qfleet-coordinator", "qfleet-robot-0"]);
    }
    // and its files all carry its own prefix
    assert!(!leftover_files(&a.prefix()).is_empty());
    assert!(
        leftover_files(&a.prefix())
            .iter()
            .all(|p| !p.to_string_lossy().contains(&b.run_id))
    );

    drop((robot_a, robot_b));
    coord_a.close().unwrap();
    // closing run a removed run a's files only
    assert_no_leftovers(&a);
    assert!(!leftover_files(&b.prefix()).is_empty());
    coord_b.close().unwrap();
    assert_no_leftovers(&b);
}

#[test]
fn a_robot_of_a_run_without_coordinator_times_out_clearly() {
    let cfg = config("nocoord", 1);
    let started = std::time::Instant::now();
    let Err(err) = RobotBus::open(&cfg, 0, Duration::from_millis(200)) else {
        panic!("no coordinator, no services");
    };
    assert!(started.elapsed() >= Duration::from_millis(200));
    assert!(matches!(err, BusError::Timeout { .. }), "{err:?}");
    assert!(err.to_string().contains("coordinator"), "{err}");
    bus::clean_run(&cfg).unwrap();
    assert_no_leftovers(&cfg);
}

#[test]
fn config_is_validated() {
    use bus::{BusConfig, MAX_ROBOTS};
    for bad in [
        "",
        "has space",
        "dot.ted",
        "slash/ed",
        "ünï",
        &"x".repeat(49),
    ] {
        let err = BusConfig::new(bad, 1).unwrap_err();
        assert!(
            matches!(err, BusError::InvalidRunId { .. }),
            "{bad:?}: {err}"
        );
    }
    assert!(BusConfig::new("Ok_run-1", 1).is_ok());
    assert!(BusConfig::new("x".repeat(48), MAX_ROBOTS).is_ok());
    assert!(BusConfig::new("r", 0).is_err());
    assert!(BusConfig::new("r", MAX_ROBOTS + 1).is_err());
    let cfg = BusConfig::new("r", 4).unwrap();
    assert_eq!(cfg.prefix(), "qfleet.r.");
    for bad in [
        BusConfig {
            hint_buffer: 0,
            ..cfg.clone()
        },
        BusConfig {
            send_timeout: Duration::ZERO,
            ..cfg.clone()
        },
    ] {
        assert!(matches!(bad.validate(), Err(BusError::InvalidConfig(_))));
    }
    let err = RobotBus::open(&cfg, 4, Duration::ZERO).err().unwrap();
    assert!(err.to_string().contains("outside 0..4"), "{err}");
}
