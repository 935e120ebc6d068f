//! Fuzzes the ASCII map parser: it must never panic, and a map it accepts must write out to
//! text that reads back as the same map.
#![no_main]

use libfuzzer_sys::fuzz_target;
use planner::map::parse_ascii;

fuzz_target!(|data: &[u8]| {
    match parse_ascii("fuzz.txt", data) {
        Ok(map) => {
            let again = parse_ascii("fuzz.txt", map.to_ascii().as_bytes())
                .expect("a parsed map's ASCII form parses");
            assert_eq!(again, map);
        }
        Err(e) => {
            // Rendering the message must not panic either.
            let _ = e.to_string();
        }
    }
});
