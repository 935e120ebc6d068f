//! `--pace STEPS_PER_S`: slow every robot to that many environment steps per second, so that a
//! person can follow the robots in the live view. `qfleet run` and `qfleet experiment` take the
//! option and forward it to the robot-agents, which pace themselves (`robot_agent::pace`).

/// The slowest pace: a paced robot publishes its state at every pause, and one step per second
/// keeps those pauses well inside the coordinator's default hang deadline (`--hang-ms 2000`).
pub const MIN_PACE: f64 = 1.0;
/// The fastest pace; an unpaced robot is about this fast already.
pub const MAX_PACE: f64 = 10_000_000.0;

/// Parses and checks a `--pace` value: a number of steps per second in
/// [`MIN_PACE`]`..=`[`MAX_PACE`] (clap value parser).
pub fn parse_pace(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a number of steps per second"))?;
    if !(MIN_PACE..=MAX_PACE).contains(&v) {
        return Err(format!(
            "the pace must be between {MIN_PACE} and {MAX_PACE} steps per second, got {s}"
        ));
    }
    Ok(v)
}

/// `--pace V` as command-line words to forward, or nothing when unpaced.
pub fn pace_cli(pace: Option<f64>) -> Vec<String> {
    pace.map_or_else(Vec::new, |v| vec!["--pace".into(), v.to_string()])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pace_is_a_bounded_positive_number() {
        assert_eq!(parse_pace("20"), Ok(20.0));
        assert_eq!(parse_pace("1"), Ok(MIN_PACE));
        assert_eq!(parse_pace("2.5e3"), Ok(2500.0));
        for bad in ["0", "-5", "0.5", "nan", "inf", "1e8", "fast", ""] {
            let e = parse_pace(bad).unwrap_err();
            assert!(e.contains("steps per second"), "{bad}: {e}");
        }
    }

    #[test]
    fn the_forwarded_words_parse_back_to_the_same_pace() {
        assert!(pace_cli(None).is_empty());
        let w = pace_cli(Some(12.5));
        assert_eq!(w[0], "--pace");
        assert_eq!(parse_pace(&w[1]), Ok(12.5));
    }
}
