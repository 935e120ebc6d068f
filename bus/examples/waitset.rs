//! A coordinator loop with the `hybrid` wait strategy: spin a bounded time on `has_samples`,
//! then sleep in a WaitSet on all inbox listeners with a timeout. A robot thread feeds it.
//!
//! `cargo run -p bus --example waitset` — prints one line per wakeup and cleans up after itself.

use std::time::{Duration, Instant};

use bus::bus_schema::{Command, PseudoTargetDiscovery, ROBOT_ID_ALL, Register, SCHEMA_VERSION};
use bus::iceoryx2::prelude::*;
use bus::{BusConfig, CoordinatorBus, Expected, RobotBus, monotonic_ns, unique_run_id};

const SPIN: Duration = Duration::from_micros(50);
const TIMEOUT: Duration = Duration::from_millis(200);

fn main() -> Result<(), Box<dyn core::error::Error>> {
    let cfg = BusConfig::new(unique_run_id("example"), 1)?;
    let coordinator = CoordinatorBus::create(&cfg)?;

    let robot_cfg = cfg.clone();
    let robot = std::thread::spawn(move || -> Result<(), bus::BusError> {
        let bus = RobotBus::open(&robot_cfg, 0, Duration::from_secs(5))?;
        let reg = Register {
            schema_version: SCHEMA_VERSION,
            robot_id: 0,
            pid: std::process::id(),
            width: 4,
            height: 4,
            ..Register::ZEROED
        };
        bus.register(&reg, Duration::from_secs(5))?;
        bus.wait_start(Duration::from_secs(5), |_| {})?;
        for seq in 0..5 {
            std::thread::sleep(Duration::from_millis(30));
            bus.discovery.send_with(|d| {
                d.seq = seq;
                d.send_time_ns = monotonic_ns();
            })?;
            bus.discovery.notify()?;
        }
        bus.wait_control(Duration::from_secs(5), |c| {
            c.command == Command::Stop.as_u8()
        })?;
        bus.close()?;
        Ok(())
    });

    let expected = Expected {
        robots: 1,
        map_hash: 0,
        width: 4,
        height: 4,
    };
    coordinator.accept_fleet(&expected, Duration::from_secs(5))?;
    coordinator.start(ROBOT_ID_ALL, 0)?;

    let waitset = WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()?;
    let guards = coordinator.attach_all(&waitset)?;

    let mut received = 0;
    while received < 5 {
        // 1. spin: cheap while data keeps coming, costs a core while it spins
        let spin_until = Instant::now() + SPIN;
        while !coordinator.has_samples()? && Instant::now() < spin_until {
            std::hint::spin_loop();
        }
        // 2. block: no CPU, but a cross-CPU wakeup costs tens of microseconds
        if !coordinator.has_samples()? {
            let mut woke = false;
            waitset.wait_and_process_once_with_timeout(
                |_| {
                    woke = true;
                    CallbackProgression::Continue
                },
                TIMEOUT,
            )?;
            if !woke {
                println!("timeout after {TIMEOUT:?}, nothing arrived");
                continue;
            }
        }
        // 3. reset the wakeups (or the WaitSet reports them again) and drain
        coordinator.clear_wakeups()?;
        coordinator
            .discovery
            .drain(usize::MAX, |d: &PseudoTargetDiscovery| {
                received += 1;
                let latency_us = (monotonic_ns() - d.send_time_ns) / 1_000;
                println!("discovery seq {} after {latency_us} µs", d.seq);
            })?;
    }
    coordinator.stop(ROBOT_ID_ALL)?;
    drop(guards);
    robot.join().map_err(|_| "robot thread panicked")??;
    let report = coordinator.close()?;
    println!("closed; removed {} leftover files", report.removed.len());
    Ok(())
}
