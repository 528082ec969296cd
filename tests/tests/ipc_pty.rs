//! The whole chain over a real pseudo-terminal: `uss-sim --pty` in one process, `ussd` on that
//! pty in another, and this process as a client through shared memory: it reads a drive's
//! inputs, takes control and runs the drive to S4, and reads and writes parameters.
#![allow(clippy::unwrap_used)]

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use uss_client::{Bus, ClientError, ControlOptions, DriveState, Value};
use uss_integration_tests::{SimProcess, binary, terminate};
use uss_integration_tests::{addr, param};

/// ussd on the simulator's pty; stopped with SIGTERM when dropped.
struct Ussd {
    child: Child,
    config: std::path::PathBuf,
}

impl Drop for Ussd {
    fn drop(&mut self) {
        terminate(&mut self.child);
        let _ = std::fs::remove_file(&self.config);
    }
}

fn open_when_ready(bus: &str, ussd: &mut Ussd) -> Bus {
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        match Bus::open(bus) {
            Ok(bus) => return bus,
            Err(ClientError::NotRunning { .. }) if Instant::now() < deadline => {
                assert!(ussd.child.try_wait().unwrap().is_none(), "ussd ended early");
                std::thread::sleep(Duration::from_millis(50));
            }
            Err(e) => panic!("{e}"),
        }
    }
}

#[test]
fn client_controls_and_parameterises_a_drive_through_ussd_over_a_pty() {
    let sim = SimProcess::start(&["--baud", "115200", "--drive", "1", "--drive", "2:pkw=127"]);
    let bus_name = format!("pty{}", std::process::id());
    let config = std::env::temp_dir().join(format!("ussd-{bus_name}.toml"));
    std::fs::write(
        &config,
        format!(
            "[[bus]]\nname = \"{bus_name}\"\ndevice = \"{}\"\nbaud = 115200\n\n\
             [[bus.drive]]\naddress = 1\nwatchdog_ms = 200\n\n[[bus.drive]]\naddress = 2\npkw = 127\n",
            sim.path
        ),
    )
    .unwrap();
    let child = Command::new(binary("uss-master", "ussd"))
        .arg("--config")
        .arg(&config)
        .args(["--summary-every", "3600"])
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    let mut ussd = Ussd { child, config };
    let bus = open_when_ready(&bus_name, &mut ussd);

    // Inputs: the drive answers over the pty; with no controller it got OFF1 and sits in S2.
    let watch = bus.watch(addr(1)).unwrap();
    let first = watch
        .wait_for(Duration::from_secs(10), "a reply", |i| {
            i.online != 0 && i.sequence > 0
        })
        .unwrap();
    assert_eq!(watch.state(), DriveState::ReadyToSwitchOn, "{first:?}");

    // Parameters through the request-response bridge and the drive's PKW channel.
    assert_eq!(
        bus.read(addr(1), param(1082)).unwrap(),
        Value::Dword(0x4248_0000)
    );
    assert_eq!(
        bus.read(addr(2), param(2000)).unwrap(),
        Value::Dword(0x4248_0000),
        "P2000 (page bit)"
    );
    let half_second = Value::from_f32(0.5);
    assert_eq!(
        bus.write(addr(1), param(1120), half_second, false).unwrap(),
        half_second
    );
    assert_eq!(bus.read(addr(1), param(1120)).unwrap(), half_second);

    // Exclusive control: run to S4 at 25 Hz, see the actual value.
    let controller = bus.control(addr(1), ControlOptions::default()).unwrap();
    controller.rearm(uss_client::monotonic_ns()).unwrap();
    controller.run_hz(25.0).unwrap();
    controller
        .wait_for_state(DriveState::OperationEnabled, Duration::from_secs(10))
        .unwrap();
    let running = controller
        .wait_for(Duration::from_secs(10), "25 Hz", |i| i.hiw == 0x2000)
        .unwrap();
    assert_eq!(running.online, 1);
    assert!(
        bus.control(addr(1), ControlOptions::default()).is_err(),
        "one controller per drive"
    );
    controller.stop().unwrap();
    controller
        .wait_for(Duration::from_secs(10), "stopped", |i| i.hiw == 0)
        .unwrap();
    drop(ussd);
    let sim_out = sim.stop();
    assert!(sim_out.contains("drive  1:"), "{sim_out}");
}
