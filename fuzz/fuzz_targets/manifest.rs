//! Fuzzes the experiment-manifest parser: it must never panic, errors must name a field, and an
//! accepted manifest must be internally consistent.
#![no_main]

use libfuzzer_sys::fuzz_target;
use qfleet_args::parse_manifest;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match parse_manifest("fuzz.toml", text) {
        Ok(m) => {
            assert!(m.robots >= 1 && m.starts.len() == m.robots as usize);
            assert!(!m.phases.is_empty() && !m.goals.is_empty() && !m.seeds.is_empty());
            for p in &m.phases {
                assert!(p.episodes >= 1);
                assert!(p.goals.iter().all(|g| *g < m.goals.len()));
            }
        }
        Err(e) => assert!(!e.path.is_empty() && !e.reason.is_empty()),
    }
});
