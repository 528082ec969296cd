//! Drive families (issue 23): a USS slave that is not a MICROMASTER 4, on a pty served by
//! `uss-sim`, here a generic slave (a pump controller, say: three parameters of its own, PKW 4,
//! PZD 6, 19200 baud) whose firmware stops answering after a task on a parameter it does not
//! know. ussd must leave it alone: nothing but what clients ask.
#![allow(clippy::unwrap_used)]

use std::time::Duration;
use uss_integration_tests::{BusSpec, SimProcess, Ussd};

fn fragile_pump() -> SimProcess {
    SimProcess::start(&[
        "--baud",
        "19200",
        "--drive",
        "1:family=generic,fragile=true,pzd=6",
    ])
}

/// Whether drive 1 stays online and polled for `secs` seconds.
fn stays_online(bus: &uss_client::Bus, secs: u64) -> Result<(), String> {
    let watch = bus.watch(1).unwrap();
    watch
        .wait_for(Duration::from_secs(5), "online", |i| i.online == 1)
        .map_err(|e| format!("went offline (or never online): {e:?}"))?;
    for _ in 0..secs * 10 {
        std::thread::sleep(Duration::from_millis(100));
        let i = watch.latest();
        if i.online != 1 {
            return Err(format!("went offline: {i:?}"));
        }
    }
    Ok(())
}

#[test]
#[should_panic(expected = "went offline")]
fn a_generic_slave_that_dies_of_unknown_parameters_stays_online() {
    let sim = fragile_pump();
    let mut ussd = Ussd::launch(
        &[BusSpec {
            suffix: "",
            device: &sim.path,
            keys: "baud = 19200",
            drives: &[(1, "pzd = 6")],
        }],
        &[],
    );
    let bus = ussd.open_when_running("");
    stays_online(&bus, 3).unwrap();
}

#[test]
#[should_panic(expected = "went offline")]
fn a_generic_slave_is_read_by_value_alone_and_stays_online() {
    let sim = fragile_pump();
    let mut ussd = Ussd::launch(
        &[BusSpec {
            suffix: "",
            device: &sim.path,
            keys: "baud = 19200",
            drives: &[(
                1,
                "pzd = 6\nmonitoring_param = \"\"\nreference_param = \"\"",
            )],
        }],
        &[],
    );
    let bus = ussd.open_when_running("");
    stays_online(&bus, 1).unwrap();
    // Its own parameter P1, a word: read as the reply types it.
    let p1 = bus.read_param(1, "P1".parse().unwrap());
    println!("families: P1 of the generic slave: {p1:?}");
    stays_online(&bus, 1).unwrap();
    assert_eq!(p1.unwrap().raw, uss_protocol::Value::Word(0x0A51));
}
