//! Fuzzes the MovingAI `.map` parser: it must never panic, and a map it accepts must write out
//! to a `.map` file that reads back as the same grid.
#![no_main]

use libfuzzer_sys::fuzz_target;
use planner::map::parse_movingai_map;

fuzz_target!(|data: &[u8]| {
    match parse_movingai_map("fuzz.map", data) {
        Ok(map) => {
            let again = parse_movingai_map("fuzz.map", map.to_movingai().as_bytes())
                .expect("a parsed map's MovingAI form parses");
            assert_eq!(again.grid, map.grid);
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
});
