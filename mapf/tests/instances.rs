//! Instances from the real MovingAI files: the first N lines, and every refusal before a run.

mod common;

use common::movingai;
use mapf::{Instance, InstanceError, MAX_AGENTS};
use planner::map::{load_map, load_scen};

#[test]
fn the_first_n_scenario_lines_in_file_order() {
    let Some(dir) = movingai("the_first_n_scenario_lines_in_file_order") else {
        return;
    };
    let map = load_map(dir.join("random-32-32-10.map").to_str().unwrap()).unwrap();
    let scen = load_scen(&dir.join("random-32-32-10-random-1.scen")).unwrap();
    let inst = Instance::from_scen(&map, &scen, 3).unwrap();
    // line 1: 3 random-32-32-10.map 32 32 11 6 7 18 ... (x = column, y = row)
    assert_eq!(inst.starts()[0], planner::Cell::new(11, 6));
    assert_eq!(inst.goals()[0], planner::Cell::new(7, 18));
    assert_eq!(inst.starts()[2], planner::Cell::new(9, 0));
    // the lower bounds the anchors README lists for the reference planners' runs
    for (n, lb) in [(8, 208), (16, 407), (32, 769), (64, 1403), (128, 2934)] {
        assert_eq!(
            Instance::from_scen(&map, &scen, n).unwrap().lower_bound(),
            lb
        );
    }
    // more agents than lines, more than the wire carries, a scenario of another map
    let e = Instance::from_scen(&map, &scen[..10], 11).unwrap_err();
    assert_eq!(
        e,
        InstanceError::NotEnoughScenarios {
            agents: 11,
            available: 10
        }
    );
    let e = Instance::from_scen(&map, &scen, MAX_AGENTS + 1).unwrap_err();
    assert_eq!(e, InstanceError::TooManyAgents { agents: 257 });
    let big = load_map(dir.join("random-64-64-10.map").to_str().unwrap()).unwrap();
    let e = Instance::from_scen(&big, &scen, 4).unwrap_err();
    assert_eq!(
        e.to_string(),
        "agent 0: its scenario line is for a 32x32 map (random-32-32-10.map), but the map is 64x64"
    );
    assert!(Instance::from_scen(&map, &scen, MAX_AGENTS).is_ok());
}
