//! A peer built from another schema gets a clear error instead of garbage: iceoryx2's type check
//! (name, size, alignment) becomes `SchemaMismatch`, and the schema version in `Register`
//! catches what iceoryx2 cannot see.

mod common;

use bus::bus_schema::names::Topic;
use bus::bus_schema::{Register, SCHEMA_VERSION};
use bus::iceoryx2::prelude::*;
use bus::{BusError, CoordinatorBus, Message, Outbox, RobotBus};
use common::{PATIENCE, assert_no_leftovers, config, expected, registration};

/// A discovery as an older robot might have sent it: same type name, smaller.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("qfleet::v1::PseudoTargetDiscovery")]
struct ShrunkDiscovery {
    robot_id: u32,
    cell: u32,
    seq: u64,
}

// SAFETY: repr(C), no padding, all-zero is valid.
unsafe impl Message for ShrunkDiscovery {
    const TOPIC: Topic = Topic::Discovery;
}

/// The same bytes under the next schema's type name.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("qfleet::v2::PseudoTargetDiscovery")]
struct DiscoveryV2([u64; 6]);

// SAFETY: repr(C), no padding, all-zero is valid.
unsafe impl Message for DiscoveryV2 {
    const TOPIC: Topic = Topic::Discovery;
}

#[test]
fn a_peer_with_another_payload_type_gets_a_schema_error() {
    let cfg = config("schema", 1);
    let coordinator = CoordinatorBus::create(&cfg).unwrap();
    let node = cfg.create_node("old-robot").unwrap();

    let Err(err) = Outbox::<ShrunkDiscovery>::open(&node, &cfg) else {
        panic!("a 16-byte discovery must not connect to the 48-byte service");
    };
    assert!(
        matches!(err, BusError::SchemaMismatch { size: 16, .. }),
        "{err:?}"
    );
    let text = err.to_string();
    assert!(text.contains("robot/discovery"), "{text}");
    assert!(text.contains("qfleet::v1::PseudoTargetDiscovery"), "{text}");
    assert!(
        text.contains(&format!("schema v{SCHEMA_VERSION}")),
        "{text}"
    );
    assert!(text.contains("different bus-schema"), "{text}");

    let Err(err) = Outbox::<DiscoveryV2>::open(&node, &cfg) else {
        panic!("a v2 type name must not connect to a v1 service");
    };
    assert!(matches!(err, BusError::SchemaMismatch { .. }), "{err:?}");
    assert!(
        err.to_string()
            .contains("qfleet::v2::PseudoTargetDiscovery")
    );

    drop(node);
    coordinator.close().unwrap();
    assert_no_leftovers(&cfg);
}

#[test]
fn a_robot_with_another_schema_version_or_map_is_refused_with_a_reason() {
    let cfg = config("refuse", 2);
    let cfg = &cfg;
    std::thread::scope(|s| {
        let coordinator = s.spawn(move || {
            let bus = CoordinatorBus::create(cfg).unwrap();
            // robot 1 registers correctly after the two refusals below, completing the fleet of
            // one accepted robot out of the ids 0..2
            let mut accepted = std::collections::BTreeMap::new();
            let mut verdicts = Vec::new();
            while accepted.is_empty() {
                let reg = common::recv(&bus.register);
                let verdict = bus.admit(&reg, &expected(2), &mut accepted).unwrap();
                // a robot re-sends its registration until answered: keep one verdict per kind
                if verdicts.last() != Some(&verdict) {
                    verdicts.push(verdict);
                }
            }
            // wait for the last robot to be gone before closing, so close removes everything
            while bus::check_nodes(cfg, false).unwrap().alive().count() > 1 {
                std::thread::sleep(std::time::Duration::from_millis(5));
            }
            bus.close().unwrap();
            verdicts
        });
        let robot = s.spawn(move || {
            let bus = RobotBus::open(cfg, 0, PATIENCE).unwrap();
            let newer = Register {
                schema_version: SCHEMA_VERSION + 1,
                ..registration(0)
            };
            let err = bus.register(&newer, PATIENCE).unwrap_err();
            let text = err.to_string();
            assert!(
                matches!(err, BusError::Refused { robot_id: 0, .. }),
                "{text}"
            );
            assert!(text.contains("schema v2 != coordinator v1"), "{text}");

            let other_map = Register {
                map_hash: 1,
                ..registration(0)
            };
            let err = bus.register(&other_map, PATIENCE).unwrap_err();
            assert!(err.to_string().contains("map hash"), "{err}");
            drop(bus);

            let bus = RobotBus::open(cfg, 1, PATIENCE).unwrap();
            bus.register(&registration(1), PATIENCE).unwrap();
            bus.close().unwrap();
        });
        robot.join().expect("robot thread");
        let verdicts = coordinator.join().expect("coordinator thread");
        assert_eq!(verdicts.len(), 3, "{verdicts:?}");
        assert!(matches!(&verdicts[0], bus::Admission::Refused(r) if r.contains("schema")));
        assert!(matches!(&verdicts[1], bus::Admission::Refused(r) if r.contains("map hash")));
        assert_eq!(verdicts[2], bus::Admission::Accepted);
    });
    assert_no_leftovers(cfg);
}
