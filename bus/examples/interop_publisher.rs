//! Publishes a few `RobotState`s and one `MergedHintBatch` of a run for a subscriber written in
//! another language (see `interop_subscriber.py`), then cleans up.
//!
//! `cargo run -p bus --example interop_publisher -- <run-id> [seconds]`

use std::time::{Duration, Instant};

use bus::bus_schema::{QHint, RobotState, RobotStatus};
use bus::{BusConfig, CoordinatorBus, RobotBus, monotonic_ns};

fn main() -> Result<(), Box<dyn core::error::Error>> {
    let mut args = std::env::args().skip(1);
    let run_id = args
        .next()
        .ok_or("usage: interop_publisher <run-id> [seconds]")?;
    let seconds: u64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(5);
    let cfg = BusConfig::new(run_id, 1)?;
    let coordinator = CoordinatorBus::create(&cfg)?;
    let robot = RobotBus::open(&cfg, 0, Duration::from_secs(1))?;
    println!("prefix {} — publishing for {seconds} s", cfg.prefix());

    let end = Instant::now() + Duration::from_secs(seconds);
    let mut seq = 0;
    while Instant::now() < end {
        robot.state.send_and_notify(&RobotState {
            robot_id: 0,
            goal_id: 2,
            episode: seq as u32,
            step: 7,
            cell_x: 3,
            cell_y: 4,
            status: RobotStatus::Running.as_u8(),
            seq,
            send_time_ns: monotonic_ns(),
            ..RobotState::ZEROED
        })?;
        coordinator.merged.send_with(|m| {
            m.coordinator_seq = seq;
            m.count = 2;
            m.entries[0] = QHint {
                cell: 5,
                action: 1,
                visits: 3,
                q: 0.25,
                ..QHint::ZEROED
            };
            m.entries[1] = QHint {
                cell: 6,
                action: 2,
                visits: 4,
                q: -1.5,
                ..QHint::ZEROED
            };
            m.origin_ns[..2].copy_from_slice(&[monotonic_ns(), monotonic_ns()]);
            m.origin_robot[..2].copy_from_slice(&[0, 0]);
            m.oldest_origin_ns = m.origin_ns[0];
            m.send_time_ns = monotonic_ns();
        })?;
        coordinator.state.drain(usize::MAX, |_| {})?;
        robot.merged.drain(usize::MAX, |_| {})?;
        seq += 1;
        std::thread::sleep(Duration::from_millis(100));
    }
    drop(robot);
    coordinator.close()?;
    Ok(())
}
