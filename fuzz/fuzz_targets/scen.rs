//! Fuzzes the MovingAI `.scen` parser: it must never panic, and every scenario it accepts must
//! lie inside the map size written on its own line.
#![no_main]

use libfuzzer_sys::fuzz_target;
use planner::map::parse_scen;

fuzz_target!(|data: &[u8]| {
    match parse_scen("fuzz.scen", data) {
        Ok(scenarios) => {
            for s in scenarios {
                assert!((s.start.x as usize) < s.width && (s.start.y as usize) < s.height);
                assert!((s.goal.x as usize) < s.width && (s.goal.y as usize) < s.height);
                assert!(s.optimal_octile.is_finite() && s.optimal_octile >= 0.0);
            }
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
});
