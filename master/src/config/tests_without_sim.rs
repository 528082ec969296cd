//! A build without the simulator (`--no-default-features`): `device = "sim"` is refused in
//! plain words, a serial bus is read as in every build.

use super::*;
use std::path::PathBuf;

#[test]
fn the_simulated_bus_is_refused_with_the_reason() {
    let e = Config::parse(
        "[[bus]]\nname = \"b\"\ndevice = \"sim\"\n\n[[bus.drive]]\naddress = 1\n",
        "f.toml",
    )
    .unwrap_err();
    assert_eq!((e.line, e.column), (Some(3), Some(10)), "{e}");
    assert_eq!(e.path.as_deref(), Some("bus[0].device"));
    assert!(
        e.message
            .contains("built without the simulated bus (the `sim` feature of uss-master)"),
        "{e}"
    );
}

#[test]
fn a_serial_bus_is_read_and_a_sim_table_there_is_refused() {
    let text = "[[bus]]\nname = \"b\"\ndevice = \"/dev/ttyUSB9\"\n\n[[bus.drive]]\naddress = 1\n";
    let c = Config::parse(text, "f.toml").unwrap();
    assert_eq!(
        c.buses[0].device,
        Device::Serial(PathBuf::from("/dev/ttyUSB9"))
    );
    let e = Config::parse(&format!("{text}sim = {{ delay = 1 }}\n"), "f.toml").unwrap_err();
    assert_eq!(e.path.as_deref(), Some("bus[0].drive[0].sim"), "{e}");
    assert!(
        e.message.contains("only allowed with device = \"sim\""),
        "{e}"
    );
}
