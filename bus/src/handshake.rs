//! Registration checks and `Control` message helpers used by the start handshake.

use bus_schema::{Command, Control, REASON_LEN, Register, SCHEMA_VERSION};

use crate::clock::monotonic_ns;

/// What the coordinator expects of every robot that registers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Expected {
    /// Fleet size: robot ids must be `0..robots`.
    pub robots: u32,
    /// Fingerprint of the coordinator's map.
    pub map_hash: u64,
    /// Map width in cells.
    pub width: u16,
    /// Map height in cells.
    pub height: u16,
}

/// Checks a registration against the coordinator's expectations; `Err` holds the reason to put
/// in the `Refuse` control (readable, at most `REASON_LEN` bytes once truncated).
///
/// The schema version is checked first: iceoryx2 only compares type names and sizes, so a robot
/// built from a bus-schema with reordered fields of the same size would otherwise be accepted
/// and send garbage.
pub fn check_register(reg: &Register, expected: &Expected) -> Result<(), String> {
    if reg.schema_version != SCHEMA_VERSION {
        return Err(format!(
            "schema v{} != coordinator v{SCHEMA_VERSION}; rebuild",
            reg.schema_version
        ));
    }
    if reg.robot_id >= expected.robots {
        return Err(format!(
            "robot id {} outside 0..{}",
            reg.robot_id, expected.robots
        ));
    }
    if (reg.width, reg.height) != (expected.width, expected.height) {
        return Err(format!(
            "map {}x{} != coordinator's {}x{}",
            reg.width, reg.height, expected.width, expected.height
        ));
    }
    if reg.map_hash != expected.map_hash {
        return Err(format!(
            "map hash {:016x} != coordinator's {:016x}",
            reg.map_hash, expected.map_hash
        ));
    }
    Ok(())
}

/// A `Control` with `command` for `robot_id` (or `ROBOT_ID_ALL`), stamped with this crate's
/// schema version and the current time; `seq` is filled in when the coordinator sends it.
pub fn control(command: Command, robot_id: u32) -> Control {
    Control {
        command: command.as_u8(),
        robot_id,
        schema_version: SCHEMA_VERSION,
        time_ns: monotonic_ns(),
        ..Control::ZEROED
    }
}

/// Writes `reason` into `ctl.reason`, cut at a character boundary to fit `REASON_LEN` bytes.
pub fn set_reason(ctl: &mut Control, reason: &str) {
    let mut end = reason.len().min(REASON_LEN);
    while !reason.is_char_boundary(end) {
        end -= 1;
    }
    ctl.reason = [0; REASON_LEN];
    ctl.reason[..end].copy_from_slice(&reason.as_bytes()[..end]);
    ctl.reason_len = end as u32;
}

/// The reason text of a `Control` (invalid UTF-8 is replaced, an oversized length clamped).
pub fn reason(ctl: &Control) -> String {
    let len = (ctl.reason_len as usize).min(REASON_LEN);
    String::from_utf8_lossy(&ctl.reason[..len]).into_owned()
}

/// What the coordinator decided about one registration.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Admission {
    /// New robot, acknowledged.
    Accepted,
    /// Same robot (same id and pid) registering again, acknowledged again.
    Reaccepted,
    /// Refused with this reason (also sent to the robot).
    Refused(String),
    /// Acceptable, but no robot was listening for the answer any more; not recorded.
    Gone,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reg() -> Register {
        Register {
            schema_version: SCHEMA_VERSION,
            robot_id: 1,
            width: 10,
            height: 8,
            map_hash: 42,
            ..Register::ZEROED
        }
    }

    const EXPECTED: Expected = Expected {
        robots: 2,
        map_hash: 42,
        width: 10,
        height: 8,
    };

    #[test]
    fn accepts_a_matching_robot() {
        assert_eq!(check_register(&reg(), &EXPECTED), Ok(()));
    }

    #[test]
    fn refuses_other_schema_map_or_id_readably() {
        let r = Register {
            schema_version: SCHEMA_VERSION + 1,
            ..reg()
        };
        let why = check_register(&r, &EXPECTED).unwrap_err();
        assert!(
            why.contains("schema v2") && why.len() <= REASON_LEN,
            "{why}"
        );
        let r = Register {
            map_hash: 7,
            ..reg()
        };
        assert!(
            check_register(&r, &EXPECTED)
                .unwrap_err()
                .contains("map hash")
        );
        let r = Register { width: 11, ..reg() };
        assert!(check_register(&r, &EXPECTED).unwrap_err().contains("11x8"));
        let r = Register {
            robot_id: 2,
            ..reg()
        };
        assert!(check_register(&r, &EXPECTED).unwrap_err().contains("0..2"));
    }

    #[test]
    fn reason_is_cut_at_a_char_boundary() {
        let mut c = control(Command::Refuse, 3);
        set_reason(&mut c, &"é".repeat(40));
        assert_eq!(c.reason_len, 64);
        assert_eq!(reason(&c), "é".repeat(32));
        set_reason(&mut c, "short");
        assert_eq!(reason(&c), "short");
        assert!(c.reason[5..].iter().all(|b| *b == 0));
    }
}
