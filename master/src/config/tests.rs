#![allow(
    clippy::float_cmp,
    reason = "a value parsed from the same decimal text is the same float, bit for bit"
)]
use super::*;
use std::path::PathBuf;
use std::time::Duration;
use uss_drive_sim::{DriveConfig, Fault};
use uss_protocol::{PkwMode, PzdCount};

fn parse(text: &str) -> Config {
    match Config::parse(text, "bus.toml") {
        Ok(config) => config,
        Err(e) => panic!("{e}"),
    }
}

fn error(text: &str) -> ConfigError {
    Config::parse(text, "bus.toml").unwrap_err()
}

/// The message and field path of the error `text` gets.
fn refused(text: &str) -> (String, Option<String>) {
    let e = error(text);
    (e.to_string(), e.path)
}

/// A simulated bus with `line` as its line 4 and one drive at address 3.
fn bus_key(line: &str) -> String {
    format!("[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n{line}\n\n[[bus.drive]]\naddress = 3\n")
}

/// A simulated bus with one drive at address 3 that has `line` as line 7.
fn drive_key(line: &str) -> String {
    format!("[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n\n[[bus.drive]]\naddress = 3\n{line}\n")
}

/// A serial bus on /dev/ptmx (a tty every Linux with ptys has) with `bus_line` as line 4 and a drive at address 3 with
/// `drive_line` as line 7.
fn serial(bus_line: &str, drive_line: &str) -> String {
    format!(
        "[[bus]]\nname = \"bus1\"\ndevice = \"/dev/ptmx\"\n{bus_line}\n\n[[bus.drive]]\n\
         address = 3\n{drive_line}\n"
    )
}

fn ms(ms: u64) -> Duration {
    Duration::from_millis(ms)
}

const PKW4_PZD2: Layout = Layout::new(
    PkwMode::Four,
    match PzdCount::new(2) {
        Ok(p) => p,
        Err(_) => panic!("2 PZD words"),
    },
);

const FULL: &str = r#"# two buses, every key set
[[bus]]
name = "line-A_1"
device = "sim"
baud = 19200
rs485 = "auto"
echo = true
response_timeout_ms = 25.5
timeout_margin_ms = 5
retries = 3
offline_after = 4
offline_probe_ms = 1000.0
cycle_time_ms = 12.25
param_timeout_ms = 3000.0
param_priority = true
cpu = 0
priority = 70
seed = 42

[[bus.drive]]
address = 0x1F
pkw = 127
pzd = 6
weight = 3
reference_hz = 60.1
watchdog_ms = 250
safe_command = "off3"
params_writable = false
sim = { delay = 2.5, jitter = 0.5, drop = 0.05, bcc = 0.1, unplug = "1000..1500" }

[[bus.drive]]
address = 2
pkw = 0
pzd = 0

[[bus]]
name = "serial"
device = "/dev/ptmx"
baud = 250000
nonstandard_baud = true
rs485 = "auto"

[[bus.drive]]
address = 7
pkw = 3
pzd = 16
family = "generic"
safe_command = "off2"
"#;

#[test]
fn embedded_default_is_one_simulated_bus_with_four_drives() {
    let c = Config::embedded_default();
    assert_eq!(c.buses.len(), 1);
    let bus = &c.buses[0];
    assert_eq!(bus.name, "bus0");
    assert_eq!(bus.device, Device::Sim);
    assert_eq!(bus.baud.get(), 115_200);
    let shape: Vec<_> = bus
        .drives
        .iter()
        .map(|d| {
            (
                d.address.get(),
                d.layout().pkw.p2013(),
                d.layout().pzd.get(),
            )
        })
        .collect();
    assert_eq!(shape, [(1, 4, 2), (2, 4, 2), (3, 127, 2), (4, 4, 2)]);
    for d in &bus.drives {
        let sim = d.sim_spec().expect("a simulated bus has simulated drives");
        let recommended = DriveConfig {
            telegram_off_time_ms: 100,
            ..DriveConfig::new(d.address, d.layout())
        };
        assert_eq!(sim.config, recommended, "P2014.0 = 100 ms");
        assert_eq!(sim.faults.probability(Fault::DropReply), 0.0);
    }
}

#[test]
fn missing_keys_get_their_documented_defaults() {
    let c = parse(&bus_key(""));
    let bus = &c.buses[0];
    assert_eq!(bus.baud.get(), 115_200);
    assert_eq!(bus.rs485, Rs485Mode::None);
    assert!(!bus.echo);
    assert_eq!(bus.response_timeout_ms.get(), ms(20));
    assert_eq!(bus.timeout_margin_ms.get(), Duration::ZERO);
    assert_eq!((bus.retries.get(), bus.offline_after.get()), (2, 1));
    assert_eq!(bus.offline_probe_ms.get(), ms(500));
    assert_eq!(bus.cycle_time_ms.period(), None);
    assert_eq!(bus.param_timeout_ms.get(), ms(2000));
    assert!(!bus.param_priority);
    assert_eq!((bus.cpu, bus.priority.get(), bus.seed()), (None, 80, 1));
    let d = &bus.drives[0];
    assert_eq!(d.address.get(), 3);
    assert_eq!(d.layout(), PKW4_PZD2);
    assert_eq!(d.weight.get(), 1);
    assert_eq!(d.reference_hz.get(), 50.0);
    assert_eq!(d.watchdog_ms.get(), ms(100));
    assert_eq!(d.safe_command, SafeCommand::Off1);
    assert!(d.params_writable);
    assert_eq!(
        d.monitoring_param().param().map(|p| p.to_string()),
        Some("P2014[0]".into())
    );
    assert_eq!(
        (d.monitoring_max_ms.get(), d.require_monitoring),
        (ms(1000), false)
    );
    // Without `sim`, the simulator's own defaults at the entry's address and layout.
    let sim = d.sim_spec().expect("a simulated bus has simulated drives");
    assert_eq!(sim.config, DriveConfig::new(d.address, PKW4_PZD2));
}

#[test]
fn every_key_is_read_as_written() {
    let c = parse(FULL);
    let [sim, serial] = &c.buses[..] else {
        panic!("two buses expected");
    };
    assert_eq!(sim.name, "line-A_1");
    assert_eq!(sim.baud.get(), 19200);
    assert_eq!(sim.rs485, Rs485Mode::Auto);
    assert!(sim.echo);
    assert_eq!(sim.response_timeout_ms.get(), Duration::from_micros(25_500));
    assert_eq!(sim.timeout_margin_ms.get(), ms(5));
    assert_eq!((sim.retries.get(), sim.offline_after.get()), (3, 4));
    assert_eq!(sim.offline_probe_ms.get(), ms(1000));
    assert_eq!(
        sim.cycle_time_ms.period(),
        Some(Duration::from_micros(12_250))
    );
    assert_eq!(sim.param_timeout_ms.get(), ms(3000));
    assert!(sim.param_priority);
    assert_eq!(
        (sim.cpu, sim.priority.get(), sim.seed()),
        (Some(Cpu(0)), 70, 42)
    );
    let d = &sim.drives[0];
    assert_eq!(d.address.get(), 31);
    assert_eq!(
        (d.layout().pkw, d.layout().pzd.get()),
        (PkwMode::Variable, 6)
    );
    assert_eq!(d.weight.get(), 3);
    assert_eq!(d.reference_hz.get(), 60.1_f32);
    assert_eq!(d.watchdog_ms.get(), ms(250));
    assert_eq!(d.safe_command, SafeCommand::Off3);
    assert!(!d.params_writable);
    let d = &sim.drives[1];
    assert_eq!((d.layout().pkw, d.layout().pzd.get()), (PkwMode::None, 0));

    assert_eq!(serial.device, Device::Serial(PathBuf::from("/dev/ptmx")));
    assert_eq!(
        (serial.baud.get(), serial.rs485),
        (250_000, Rs485Mode::Auto)
    );
    let d = &serial.drives[0];
    assert_eq!((d.layout().pkw, d.layout().pzd.get()), (PkwMode::Three, 16));
    assert_eq!(d.safe_command, SafeCommand::Off2);
    assert!(d.sim.is_none());
}

#[test]
fn simulated_drive_takes_address_and_layout_from_the_entry_and_faults_from_sim() {
    let c = parse(FULL);
    let d = &c.buses[0].drives[0];
    let sim = d.sim_spec().expect("a simulated bus has simulated drives");
    assert_eq!(sim.config.address.get(), 31);
    assert_eq!(sim.config.layout, d.layout());
    assert_eq!(sim.config.response_delay, Duration::from_micros(2500));
    assert_eq!(sim.config.response_jitter, Duration::from_micros(500));
    assert_eq!(sim.faults.probability(Fault::DropReply), 0.05);
    assert_eq!(sim.faults.probability(Fault::CorruptBcc), 0.1);
    assert_eq!(sim.faults.probability(Fault::Late), 0.0);
    assert!(sim.faults.is_unplugged(ms(1200)));
    assert!(!sim.faults.is_unplugged(ms(1500)));
    // Without `sim`, the simulator's defaults at the entry's layout.
    let d = &c.buses[0].drives[1];
    let sim = d.sim_spec().expect("a simulated bus has simulated drives");
    let pzd0 = Layout::new(PkwMode::None, PzdCount::new(0).unwrap());
    assert_eq!(sim.config, DriveConfig::new(d.address, pzd0));
    // Dotted keys and a header table read the same.
    let dotted = parse(&drive_key("sim.delay = 2.5\nsim.drop = 0.05"));
    let header = parse(&drive_key("[bus.drive.sim]\ndelay = 2.5\ndrop = 0.05"));
    assert_eq!(dotted, header);
    let sim = dotted.buses[0].drives[0].sim_spec().unwrap();
    assert_eq!(sim.config.response_delay, Duration::from_micros(2500));
}

/// A simulated drive is of its entry's family unless its `sim` options name another: a G120
/// entry on a simulated bus is a simulated G120 (it used to be a MICROMASTER 4 unless
/// `sim = { family = "g120" }` said so too).
#[test]
fn a_simulated_drive_is_of_its_entrys_family() {
    use uss_drive_sim::drive::Personality;
    let personality = |keys: &str| {
        let c = parse(&drive_key(keys));
        c.buses[0].drives[0].sim_spec().unwrap().config.personality
    };
    assert_eq!(personality(""), Personality::MICROMASTER4);
    assert_eq!(personality("family = \"g110\""), Personality::G110);
    assert_eq!(personality("family = \"g120\""), Personality::G120);
    assert_eq!(personality("family = \"simoreg\""), Personality::SIMOREG);
    let generic = |fragile| Personality::Generic { fragile };
    assert_eq!(personality("family = \"generic\""), generic(false));
    assert_eq!(
        personality("family = \"generic\"\nsim.fragile = true"),
        generic(true)
    );
    // Named otherwise in `sim`, the simulator plays that (a test bench of a mismatch).
    assert_eq!(
        personality("family = \"g120\"\nsim.family = \"micromaster4\""),
        Personality::MICROMASTER4
    );
}

#[test]
fn embedded_default_round_trips_through_to_toml() {
    let c = Config::embedded_default();
    assert_eq!(Config::parse(&c.to_toml(), "default").unwrap(), c);
}

#[test]
fn full_example_round_trips_through_to_toml() {
    let c = parse(FULL);
    let text = c.to_toml();
    assert_eq!(Config::parse(&text, "check").unwrap(), c);
    // And the second trip writes the same text.
    assert_eq!(parse(&text).to_toml(), text);
    // Times are written as the exact milliseconds they were read as.
    assert!(text.contains("response_timeout_ms = 25.5\n"), "{text}");
    assert!(text.contains("timeout_margin_ms = 5.0\n"), "{text}");
    assert!(text.contains("reference_hz = 60.1\n"), "{text}");
}

#[test]
fn to_toml_writes_every_default_and_what_a_serial_device_is() {
    assert_eq!(
        parse(&serial("", "")).to_toml(),
        r#"# ussd configuration: the effective settings, every default filled in
# bus bus1: /dev/ptmx is a serial device (a tty)

[[bus]]
name = "bus1"
device = "/dev/ptmx"
baud = 115200
nonstandard_baud = false
rs485 = "none"
echo = false
response_timeout_ms = 20.0
timeout_margin_ms = 0.0
retries = 2
offline_after = 1
offline_probe_ms = 500.0
cycle_time_ms = 0.0
param_timeout_ms = 2000.0
param_priority = false
line_down_limit_ms = 30000.0
priority = 80

[[bus.drive]]
address = 3
pkw = 4
pzd = 2
weight = 1
reference_hz = 50.0
family = "micromaster4"
reference_param = "P2000"
watchdog_ms = 100.0
safe_command = "off1"
params_writable = true
monitoring_param = "P2014[0]"
monitoring_max_ms = 1000.0
require_monitoring = false
broadcast = true
"#
    );
    let later = serial("", "").replace("/dev/ptmx", "/dev/uss-nothing-here");
    let later = parse(&later);
    assert!(later.to_toml().contains(
        "# bus bus1: warning: /dev/uss-nothing-here does not exist now: ussd starts this bus \
         line down and opens it when it appears\n"
    ));
    assert_eq!(
        later.warnings(),
        [
            "bus bus1: device /dev/uss-nothing-here does not exist now: ussd starts this bus line \
          down and opens it when it appears"
        ]
    );
    assert!(parse(&serial("", "")).warnings().is_empty());
    // The simulated bus gets its seed written.
    assert!(parse(&bus_key("")).to_toml().contains("\nseed = 1\n"));
}

#[test]
fn times_read_to_the_nanosecond() {
    let c = parse(&bus_key("response_timeout_ms = 1.0955"));
    assert_eq!(
        c.buses[0].response_timeout_ms.get(),
        Duration::from_nanos(1_095_500)
    );
}

#[test]
fn a_zero_cycle_time_means_as_fast_as_the_wire_allows() {
    assert_eq!(
        parse(&bus_key("cycle_time_ms = 0")).buses[0]
            .cycle_time_ms
            .period(),
        None
    );
    assert_eq!(
        parse(&bus_key("cycle_time_ms = 10")).buses[0]
            .cycle_time_ms
            .period(),
        Some(ms(10))
    );
}

#[test]
fn safe_commands_send_the_stw1_of_uss_md_section_7() {
    assert_eq!(SafeCommand::Off1.command().stw1(), 0x047E);
    assert_eq!(SafeCommand::Off2.command().stw1(), 0x047C);
    assert_eq!(SafeCommand::Off3.command().stw1(), 0x047A);
}

#[test]
fn load_reads_a_file_and_names_it_in_errors() {
    let dir = std::env::temp_dir().join(format!("uss-config-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let good = dir.join("good.toml");
    std::fs::write(&good, bus_key("")).unwrap();
    assert_eq!(Config::load(&good).unwrap(), parse(&bus_key("")));
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, bus_key("retries = 11")).unwrap();
    let e = Config::load(&bad).unwrap_err();
    assert_eq!(
        e.to_string(),
        format!(
            "{}:4:11: bus \"bus0\": retries = 11 is out of range: retries after a failed \
             exchange are 0..=10",
            bad.display()
        )
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn unreadable_file_is_an_error_without_a_line() {
    let e = Config::load(Path::new("/nonexistent/ussd.toml")).unwrap_err();
    assert_eq!(
        e.to_string(),
        "/nonexistent/ussd.toml: cannot read the configuration: No such file or directory \
         (os error 2)"
    );
    assert_eq!((e.line, e.column, e.path), (None, None, None));
}

#[test]
fn toml_syntax_error_keeps_tomls_message_and_position() {
    let e = error(&drive_key("pzd = 3 x"));
    assert_eq!(
        e.to_string(),
        "bus.toml:7:7: invalid TOML: string values must be quoted, expected literal string"
    );
    assert_eq!((e.line, e.column, e.path), (Some(7), Some(7), None));
    assert_eq!(
        error(&drive_key("address = 4")).to_string(),
        "bus.toml:7:1: invalid TOML: duplicate key"
    );
}

#[test]
fn telegram_monitoring_is_checked_as_configured() {
    let d = |line: &str| parse(&drive_key(line)).buses[0].drives[0].clone();
    let g120 =
        d("monitoring_param = \"p2040\"\nmonitoring_max_ms = 200\nrequire_monitoring = true");
    assert_eq!(
        g120.monitoring_param().param().map(|p| p.to_string()),
        Some("p2040".into())
    );
    assert_eq!(
        (g120.monitoring_max_ms.get(), g120.require_monitoring),
        (ms(200), true)
    );
    assert_eq!(
        d("monitoring_param = \"\"").monitoring_param().param(),
        None
    );
}

#[test]
fn a_g120_reference_speed_is_read_only_with_its_pole_pairs() {
    use uss_engine::reference::ReferenceUnit;
    let d = |line: &str| parse(&drive_key(line)).buses[0].drives[0].clone();
    let unverified = d("family = \"g120\"");
    assert_eq!(unverified.reference_param().param(), None);
    let g120 = d("family = \"g120\"\npole_pairs = 2");
    assert_eq!(
        g120.reference_param().param().map(|p| p.to_string()),
        Some("p2000".into())
    );
    assert_eq!(g120.reference_unit(), ReferenceUnit::Rpm { pole_pairs: 2 });
    assert_eq!(d("").reference_unit(), ReferenceUnit::Hz);
    let (message, path) = refused(&drive_key("pole_pairs = 2"));
    assert!(
        message.contains("pole_pairs = 2 is only for a drive whose reference is a speed"),
        "{message}"
    );
    assert_eq!(path.as_deref(), Some("bus[0].drive[0].pole_pairs"));
    let (message, _) = refused(&drive_key("family = \"g120\"\npole_pairs = 0"));
    assert!(message.contains("pole_pairs = 0 is 1..=32"), "{message}");
}

#[test]
fn the_reference_frequency_parameter_is_p2000_unless_told() {
    let d = |line: &str| parse(&drive_key(line)).buses[0].drives[0].clone();
    assert_eq!(
        d("").reference_param().param().map(|p| p.to_string()),
        Some("P2000".into())
    );
    assert_eq!(d("reference_param = \"\"").reference_param().param(), None);
    assert_eq!(
        refused(&drive_key("reference_param = \"rpm\"")),
        (
            "bus.toml:7:19: bus \"bus0\" drive 3: reference_param = \"rpm\" is not a \
             parameter: write a parameter as P1082, p1082, r0021 or 1082, an element as P0947[3] \
             or r0947.3; name the drive's reference frequency in Hz as the manual writes it, \
             e.g. \"P2000\" (MICROMASTER 4, G110), or \"\" for no check (G120: p2000 is a \
             speed in rpm)"
                .to_owned(),
            Some("bus[0].drive[0].reference_param".to_owned())
        )
    );
}

#[test]
fn a_monitoring_that_cannot_be_verified_cannot_be_required() {
    assert_eq!(
        refused(&drive_key("monitoring_param = \"P20x4\"")),
        (
            "bus.toml:7:20: bus \"bus0\" drive 3: monitoring_param = \"P20x4\" is not a \
             parameter: write a parameter as P1082, p1082, r0021 or 1082, an element as P0947[3] \
             or r0947.3; name the drive's telegram-off time as the manual writes it, e.g. \
             \"P2014.0\" (MICROMASTER 4, COM link) or \"p2040\" (G120), or \"\" for no check"
                .to_owned(),
            Some("bus[0].drive[0].monitoring_param".to_owned())
        )
    );
    assert_eq!(
        refused(&drive_key(
            "monitoring_param = \"\"\nrequire_monitoring = true"
        )),
        (
            "bus.toml:8:22: bus \"bus0\" drive 3: require_monitoring = true needs \
             monitoring_param (e.g. \"P2014.0\"): ussd cannot verify a monitoring it does not read"
                .to_owned(),
            Some("bus[0].drive[0].require_monitoring".to_owned())
        )
    );
    let (message, _) = refused(&drive_key("pkw = 0\nrequire_monitoring = true"));
    assert!(
        message.contains("require_monitoring = true needs a parameter channel"),
        "{message}"
    );
}

#[test]
fn unknown_keys_are_named_with_their_table_in_every_table() {
    assert_eq!(
        refused(&drive_key("colour = \"red\"")),
        (
            "bus.toml:7:1: bus \"bus0\" drive 3: unknown key `colour`: a [[bus.drive]] table \
             takes address, pkw, pzd, weight, reference_hz, family, reference_param, \
             pole_pairs, watchdog_ms, safe_command, params_writable, monitoring_param, monitoring_max_ms, \
             require_monitoring, broadcast, writable, sim"
                .to_owned(),
            Some("bus[0].drive[0].colour".to_owned())
        )
    );
    // A typo of a required key is the typo, not "address is missing".
    let (message, path) =
        refused("[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n\n[[bus.drive]]\nadress = 3\n");
    assert!(message.starts_with("bus.toml:6:1: bus \"bus0\" drive[0]: unknown key `adress`"));
    assert_eq!(path.as_deref(), Some("bus[0].drive[0].adress"));
    let (message, path) = refused(&bus_key("baudrate = 9600"));
    assert!(
        message.starts_with(
            "bus.toml:4:1: bus \"bus0\": unknown key `baudrate`: a [[bus]] table takes name, \
             device, baud,"
        ),
        "{message}"
    );
    assert_eq!(path.as_deref(), Some("bus[0].baudrate"));
    assert_eq!(
        refused(&format!("version = 2\n{}", bus_key(""))),
        (
            "bus.toml:1:1: unknown key `version`: the file takes access_group or bus".to_owned(),
            Some("version".to_owned())
        )
    );
    let (message, path) = refused(&drive_key("sim = { pzd = 4 }"));
    assert!(
        message.starts_with(
            "bus.toml:7:9: bus \"bus0\" drive 3: unknown key `pzd`: a [bus.drive.sim] table \
             takes delay, jitter,"
        ),
        "{message}"
    );
    assert_eq!(path.as_deref(), Some("bus[0].drive[0].sim.pzd"));
    // A date-time where a table belongs (toml hands it over as a table with a private key).
    assert_eq!(
        refused(&drive_key("sim = 1979-05-27")),
        (
            "bus.toml:7:7: bus \"bus0\" drive 3: sim = 1979-05-27: a date-time where a table \
             belongs"
                .to_owned(),
            Some("bus[0].drive[0].sim".to_owned())
        )
    );
    // A key with a backtick in it is named whole, and the keys allowed are listed as usual.
    assert!(
        error(&drive_key("\"a`b\" = 1"))
            .to_string()
            .contains("unknown key `a`b`: a [[bus.drive]] table takes address, pkw,"),
    );
    // A table header of its own after a [[bus]] belongs to the file, not to that bus.
    assert_eq!(
        refused(&format!("{}[other]\nx = 1\n", bus_key(""))),
        (
            "bus.toml:8:2: unknown key `other`: the file takes access_group or bus".to_owned(),
            Some("other".to_owned())
        )
    );
}

#[test]
fn wrong_types_say_what_is_expected() {
    assert_eq!(
        refused(&drive_key("pzd = \"two\"")),
        (
            "bus.toml:7:7: bus \"bus0\" drive 3: pzd = \"two\" is not an integer: PZD words \
             (P2012) are 0..=16"
                .to_owned(),
            Some("bus[0].drive[0].pzd".to_owned())
        )
    );
    assert_eq!(
        error(&drive_key("pzd = 2.0")).to_string(),
        "bus.toml:7:7: bus \"bus0\" drive 3: pzd = 2.0 is not an integer: PZD words (P2012) are \
         0..=16"
    );
    assert_eq!(
        error(&bus_key("echo = \"yes\"")).to_string(),
        "bus.toml:4:8: bus \"bus0\": echo = \"yes\" is not a boolean: write true or false"
    );
    assert_eq!(
        error(&bus_key("response_timeout_ms = \"20\"")).to_string(),
        "bus.toml:4:23: bus \"bus0\": response_timeout_ms = \"20\" is not a number: the \
         response timeout is 1..=1000 ms (USS.md section 4: a slave answers within 20 ms)"
    );
    assert_eq!(
        error("[[bus]]\nname = 7\ndevice = \"sim\"\n[[bus.drive]]\naddress = 1\n").to_string(),
        "bus.toml:2:8: bus[0]: name = 7 is not a string: a bus name is 1..=32 characters from \
         A-Z, a-z, 0-9, _ and - (it becomes part of shared-memory service names)"
    );
    assert_eq!(
        refused("[bus]\nname = \"bus0\"\n"),
        (
            "bus.toml:1:1: bus is a table, not [[bus]] tables: write a [[bus]] table for each"
                .to_owned(),
            Some("bus".to_owned())
        )
    );
    assert_eq!(
        error("[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\ndrive = 3\n").to_string(),
        "bus.toml:4:9: bus \"bus0\": drive = 3 is not [[bus.drive]] tables: write a \
         [[bus.drive]] table for each"
    );
    // A table written as an array would be read field by field (extra items unread): refused.
    assert_eq!(
        refused("[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\ndrive = [[3], { address = 4 }]\n"),
        (
            "bus.toml:4:10: bus \"bus0\": drive = [[3], { address = 4 }] is not [[bus.drive]] \
             tables: write a [[bus.drive]] table for each"
                .to_owned(),
            Some("bus[0].drive".to_owned())
        )
    );
    assert!(
        error("bus = [[\"bus0\", \"sim\"]]\n")
            .to_string()
            .starts_with("bus.toml:1:8: bus = [[\"bus0\", \"sim\"]] is not [[bus]] tables"),
    );
    assert_eq!(
        refused(&drive_key("sim = [1.0, 0.5]")),
        (
            "bus.toml:7:7: bus \"bus0\" drive 3: sim = [1.0, 0.5] is not a table of uss-sim's \
             drive keys, e.g. sim = { delay = 1, drop = 0.01 }"
                .to_owned(),
            Some("bus[0].drive[0].sim".to_owned())
        )
    );
    // An item of the array that is not a table: the array is named, as written.
    assert_eq!(
        refused("[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\ndrive = [{ address = 1 }, 2]\n"),
        (
            "bus.toml:4:27: bus \"bus0\": drive = [{ address = 1 }, 2] is not [[bus.drive]] \
             tables: write a [[bus.drive]] table for each"
                .to_owned(),
            Some("bus[0].drive".to_owned())
        )
    );
    assert_eq!(
        error(&drive_key("sim = 1")).to_string(),
        "bus.toml:7:7: bus \"bus0\" drive 3: sim = 1 is not a table of uss-sim's drive keys, \
         e.g. sim = { delay = 1, drop = 0.01 }"
    );
    assert_eq!(
        refused(&drive_key("[bus.drive.sim]\ndelay = \"x\"")),
        (
            "bus.toml:8:9: bus \"bus0\" drive 3: delay = \"x\" is not a number".to_owned(),
            Some("bus[0].drive[0].sim.delay".to_owned())
        )
    );
}

#[test]
fn address_must_be_0_to_31_and_is_required() {
    let drive = |line: &str| {
        format!("[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n\n[[bus.drive]]\n{line}\n")
    };
    assert_eq!(
        refused(&drive("address = 32")),
        (
            "bus.toml:6:11: bus \"bus0\" drive[0]: address = 32 is out of range: USS addresses \
             are 0..=31"
                .to_owned(),
            Some("bus[0].drive[0].address".to_owned())
        )
    );
    assert_eq!(
        error(&drive("address = -1")).to_string(),
        "bus.toml:6:11: bus \"bus0\" drive[0]: address = -1 is out of range: USS addresses are \
         0..=31"
    );
    assert_eq!(
        refused(&drive("pzd = 4")),
        (
            "bus.toml:5:1: bus \"bus0\" drive[0]: address is missing: USS addresses are 0..=31"
                .to_owned(),
            Some("bus[0].drive[0].address".to_owned())
        )
    );
}

#[test]
fn an_address_or_bus_name_used_twice_names_the_first_line() {
    let text = "[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n\n[[bus.drive]]\naddress = 3\n\n\
                [[bus.drive]]\naddress = 3\n";
    assert_eq!(
        refused(text),
        (
            "bus.toml:9:11: bus \"bus0\" drive 3: address = 3 is used twice (first at line 6): \
             every drive on a bus needs its own address"
                .to_owned(),
            Some("bus[0].drive[1].address".to_owned())
        )
    );
    // The same address on two buses is fine.
    let two_buses = "[[bus]]\nname = \"a\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 3\n\
                     [[bus]]\nname = \"b\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 3\n";
    assert_eq!(parse(two_buses).buses.len(), 2);
    let text = "[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 1\n\n\
                [[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 1\n";
    assert_eq!(
        refused(text),
        (
            "bus.toml:8:8: bus \"bus0\": name = \"bus0\" is used twice (first at line 2): every \
             bus needs its own name"
                .to_owned(),
            Some("bus[1].name".to_owned())
        )
    );
}

#[test]
fn two_buses_on_one_device_are_refused_even_under_two_names() {
    let dir = std::env::temp_dir().join(format!("uss-config-dev-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let link = dir.join("usb-FTDI_FT1ABCDE-if00-port0");
    std::os::unix::fs::symlink("/dev/ptmx", &link).unwrap();
    let text = format!(
        "[[bus]]\nname = \"a\"\ndevice = \"/dev/ptmx\"\n[[bus.drive]]\naddress = 1\n\n\
         [[bus]]\nname = \"b\"\ndevice = \"{}\"\n[[bus.drive]]\naddress = 2\n",
        link.display()
    );
    let (message, path) = refused(&text);
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(path.as_deref(), Some("bus[1].device"));
    assert!(
        message.starts_with("bus.toml:9:10: bus \"b\": device = \""),
        "{message}"
    );
    assert!(
        message.ends_with(
            "is the device of bus \"a\" too (line 3): two buses cannot share one line (each \
             would take the other's replies, and the second cannot open it)"
        ),
        "{message}"
    );
    // Two simulated buses are two lines.
    let sims = "[[bus]]\nname = \"a\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 3\n\
                [[bus]]\nname = \"b\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 3\n";
    assert_eq!(parse(sims).buses.len(), 2);
}

#[test]
fn rs485_settings_need_the_kernels_mode_which_hears_no_echo() {
    assert_eq!(
        refused(&serial("rs485_rts = \"low-while-sending\"", "")).0,
        "bus.toml:4:13: bus \"bus1\": rs485_rts = \"low-while-sending\" applies to the \
         kernel's RS485 mode only: set rs485 = \"kernel\""
    );
    assert_eq!(
        refused(&serial("rs485 = \"kernel\"\necho = true", "")).0,
        "bus.toml:5:8: bus \"bus1\": echo = true cannot be heard with rs485 = \"kernel\": the \
         kernel turns the receiver off while sending (set echo = false)"
    );
    assert_eq!(
        refused(&serial(
            "rs485 = \"kernel\"\nrs485_delay_after_ms = 101",
            ""
        ))
        .0,
        "bus.toml:5:24: bus \"bus1\": rs485_delay_after_ms = 101 is out of range: RS485 \
         delays are 0..=100 ms (whole ms)"
    );
    let bus = parse(&serial(
        "rs485 = \"kernel\"\nrs485_rts = \"high-while-sending\"\nrs485_delay_after_ms = 1",
        "",
    ))
    .buses
    .remove(0);
    assert_eq!(bus.rs485_rts, Some(super::Rs485Rts::HighWhileSending));
    assert_eq!(bus.rs485_delay_after_ms.map(Rs485Delay::get), Some(1));
    assert_eq!(bus.rs485_delay_before_ms, None, "the port's own kept");
}

#[test]
fn a_family_decides_what_ussd_reads_unasked_and_an_unknown_one_is_refused_with_the_list() {
    let d = |line: &str| parse(&drive_key(line)).buses.remove(0).drives.remove(0);
    let read = |e: &DriveEntry| {
        (
            e.monitoring_param().param().map(|p| p.to_string()),
            e.reference_param().param().map(|p| p.to_string()),
        )
    };
    assert_eq!(
        read(&d("")),
        (Some("P2014[0]".into()), Some("P2000".into()))
    );
    assert_eq!(read(&d("family = \"generic\"")), (None, None));
    assert_eq!(read(&d("family = \"g120\"")), (Some("p2040".into()), None));
    assert_eq!(
        read(&d("family = \"g110\"")),
        (Some("P2014[0]".into()), Some("P2000".into()))
    );
    assert_eq!(read(&d("family = \"simoreg\"")), (None, None));
    // What is written wins over the family's.
    assert_eq!(
        read(&d("family = \"simoreg\"\nmonitoring_param = \"P2014.0\"")).0,
        Some("P2014[0]".into())
    );
    assert_eq!(
        refused(&drive_key("family = \"g150\"")).0,
        "bus.toml:7:10: bus \"bus0\" drive 3: family = \"g150\" is not allowed: use \
         \"micromaster4\", \"g110\", \"g120\", \"simoreg\", \"generic\""
    );
}

#[test]
fn bus_names_are_1_to_32_of_letters_digits_underscore_and_dash() {
    let named = |name: &str| {
        format!("[[bus]]\nname = {name}\ndevice = \"sim\"\n[[bus.drive]]\naddress = 1\n")
    };
    let allowed = "a bus name is 1..=32 characters from A-Z, a-z, 0-9, _ and - (it becomes part \
                   of shared-memory service names)";
    assert_eq!(
        refused(&named("\"bus 0\"")),
        (
            format!("bus.toml:2:8: bus[0]: name = \"bus 0\" is not allowed: {allowed}"),
            Some("bus[0].name".to_owned())
        )
    );
    assert_eq!(
        error(&named("\"\"")).to_string(),
        format!("bus.toml:2:8: bus[0]: name = \"\" is not allowed: {allowed}")
    );
    let long = "b".repeat(33);
    assert_eq!(
        error(&named(&format!("\"{long}\""))).to_string(),
        format!("bus.toml:2:8: bus[0]: name = \"{long}\" is not allowed: {allowed}")
    );
    assert_eq!(
        parse(&named(&format!("\"{}\"", "b".repeat(32)))).buses[0]
            .name
            .len(),
        32
    );
    assert_eq!(
        error("[[bus]]\ndevice = \"sim\"\n[[bus.drive]]\naddress = 1\n").to_string(),
        format!("bus.toml:1:1: bus[0]: name is missing: {allowed}")
    );
}

#[test]
fn layout_keys_are_checked_by_their_types() {
    assert_eq!(
        refused(&drive_key("pzd = 17")),
        (
            "bus.toml:7:7: bus \"bus0\" drive 3: pzd = 17 is out of range: PZD words (P2012) \
             are 0..=16"
                .to_owned(),
            Some("bus[0].drive[0].pzd".to_owned())
        )
    );
    assert_eq!(
        parse(&drive_key("family = \"generic\"\npzd = 16")).buses[0].drives[0]
            .layout()
            .pzd
            .get(),
        16
    );
    assert_eq!(
        refused(&drive_key("pkw = 5")),
        (
            "bus.toml:7:7: bus \"bus0\" drive 3: pkw = 5 is not allowed: the PKW length (P2013) \
             is 0, 3, 4 or 127 (variable)"
                .to_owned(),
            Some("bus[0].drive[0].pkw".to_owned())
        )
    );
    assert_eq!(error(&drive_key("pkw = -4")).line, Some(7));
    let message = |w: &str| {
        format!(
            "bus.toml:7:10: bus \"bus0\" drive 3: weight = {w} is out of range: poll weights \
             (entries in the circulating list) are 1..=16"
        )
    };
    assert_eq!(error(&drive_key("weight = 0")).to_string(), message("0"));
    assert_eq!(error(&drive_key("weight = 17")).to_string(), message("17"));
    assert_eq!(
        parse(&drive_key("weight = 16")).buses[0].drives[0].weight,
        Weight(16)
    );
}

#[test]
fn baud_rates_are_the_ones_uss_names_unless_another_is_meant() {
    let message = |b: &str| {
        format!(
            "bus.toml:4:8: bus \"bus0\": baud = {b} is out of range: baud rates are \
             300..=12000000 (USS.md section 2 names 300 to 187500)"
        )
    };
    assert_eq!(error(&bus_key("baud = 299")).to_string(), message("299"));
    assert_eq!(
        error(&bus_key("baud = 99999999999")).to_string(),
        message("99999999999")
    );
    assert_eq!(
        refused(&bus_key("baud = 100000")),
        (
            "bus.toml:4:8: bus \"bus0\": baud = 100000 is not a USS baud rate (USS.md section 2: \
             300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 76800, 93750, 115200, \
             187500): set nonstandard_baud = true for a drive and adapter that take it"
                .to_owned(),
            Some("bus[0].baud".to_owned())
        )
    );
    let c = parse(&bus_key("baud = 1000000\nnonstandard_baud = true"));
    assert_eq!(c.buses[0].baud.get(), 1_000_000);
    assert_eq!(parse(&bus_key("baud = 93750")).buses[0].baud.get(), 93750);
}

#[test]
fn unknown_rs485_mode_and_safe_command_list_the_choices() {
    assert_eq!(
        refused(&bus_key("rs485 = \"rts\"")),
        (
            "bus.toml:4:9: bus \"bus0\": rs485 = \"rts\" is not allowed: use \"kernel\", \"auto\", \
             \"none\""
                .to_owned(),
            Some("bus[0].rs485".to_owned())
        )
    );
    assert_eq!(
        error(&drive_key("safe_command = \"stop\"")).to_string(),
        "bus.toml:7:16: bus \"bus0\" drive 3: safe_command = \"stop\" is not allowed: use \
         \"off1\", \"off2\", \"off3\""
    );
    // A table where a choice belongs is quoted as written, not by the key inside it.
    assert!(
        error(&bus_key("rs485 = { a = 1 }"))
            .to_string()
            .contains("rs485 = { a = 1 } is not allowed: use \"kernel\""),
    );
}

#[test]
fn a_relative_serial_device_must_exist_an_absolute_one_may_come_later() {
    let text = "[[bus]]\nname = \"bus0\"\ndevice = \"ttyXYZ\"\n[[bus.drive]]\naddress = 1\n";
    let later = text.replace("ttyXYZ", "/dev/ttyXYZ");
    assert_eq!(
        parse(&later).buses[0].device,
        Device::Serial(PathBuf::from("/dev/ttyXYZ"))
    );
    assert_eq!(
        refused(text),
        (
            "bus.toml:3:10: bus \"bus0\": device = \"ttyXYZ\" does not exist (a device that may \
             be absent when ussd starts needs its absolute path): device is \"sim\" (the \
             built-in simulated bus), the path of a serial device, or tcp://host:port (a \
             serial device server's port)"
                .to_owned(),
            Some("bus[0].device".to_owned())
        )
    );
    assert_eq!(
        error("[[bus]]\nname = \"bus0\"\n[[bus.drive]]\naddress = 1\n").to_string(),
        "bus.toml:1:1: bus \"bus0\": device is missing: device is \"sim\" (the built-in \
         simulated bus), the path of a serial device, or tcp://host:port (a serial device \
         server's port)"
    );
}

#[test]
fn sim_and_seed_are_refused_on_a_serial_bus() {
    assert_eq!(
        refused(&serial("", "sim = { delay = 1 }")),
        (
            "bus.toml:8:7: bus \"bus1\" drive 3: sim is only allowed with device = \"sim\": the \
             drives on a serial bus are real"
                .to_owned(),
            Some("bus[0].drive[0].sim".to_owned())
        )
    );
    assert_eq!(
        refused(&serial("seed = 7", "")),
        (
            "bus.toml:4:8: bus \"bus1\": seed = 7 is only allowed with device = \"sim\": the \
             drives on a serial bus are real"
                .to_owned(),
            Some("bus[0].seed".to_owned())
        )
    );
    // Also when the serial device is absent (it may appear later).
    let text = serial("", "sim.delay = 1").replace("/dev/ptmx", "/dev/ttyXYZ");
    assert!(
        error(&text)
            .to_string()
            .contains("only allowed with device = \"sim\"")
    );
    assert!(parse(&serial("", "")).buses[0].drives[0].sim.is_none());
}

#[test]
fn a_bad_sim_option_carries_the_simulators_message() {
    assert_eq!(
        refused(&drive_key("sim = { delay = -1 }")),
        (
            "bus.toml:7:7: bus \"bus0\" drive 3: sim: delay=-1: a time in milliseconds, \
             0..=3600000"
                .to_owned(),
            Some("bus[0].drive[0].sim".to_owned())
        )
    );
    assert_eq!(
        error(&drive_key("sim = { drop = 2 }")).to_string(),
        "bus.toml:7:7: bus \"bus0\" drive 3: sim: drop=2: a probability is 0..=1"
    );
}

#[test]
fn values_out_of_range_name_their_limits() {
    let cases = [
        (
            "response_timeout_ms = 0.5",
            "response_timeout_ms = 0.5 is out of range: the response timeout is 1..=1000 ms \
             (USS.md section 4: a slave answers within 20 ms)",
        ),
        (
            "timeout_margin_ms = -1",
            "timeout_margin_ms = -1 is out of range: the timeout margin is 0..=1000 ms",
        ),
        (
            "offline_probe_ms = 5",
            "offline_probe_ms = 5 is out of range: the poll interval of an offline drive is \
             10..=60000 ms",
        ),
        (
            "cycle_time_ms = 60001",
            "cycle_time_ms = 60001 is out of range: the cycle time (0 = as fast as the wire \
             allows) is 0..=60000 ms",
        ),
        (
            "rx_latency_ms = 101",
            "rx_latency_ms = 101 is out of range: the receive latency is 0..=100 ms",
        ),
        (
            "line_down_limit_ms = -1",
            "line_down_limit_ms = -1 is out of range: the line-down limit (0 = never) is 0..=86400000 ms",
        ),
        (
            "param_timeout_ms = 1e9",
            "param_timeout_ms = 1e9 is out of range: the parameter job timeout is 10..=600000 ms",
        ),
        (
            "response_timeout_ms = nan",
            "response_timeout_ms = nan is out of range: the response timeout is 1..=1000 ms \
             (USS.md section 4: a slave answers within 20 ms)",
        ),
        (
            "offline_after = 0",
            "offline_after = 0 is out of range: failed polls before a drive is marked offline \
             are 1..=100",
        ),
        (
            "priority = 100",
            "priority = 100 is out of range: SCHED_FIFO priorities are 1..=99",
        ),
    ];
    for (line, problem) in cases {
        let (key, _) = line.split_once(" = ").unwrap();
        let column = key.len() + 4;
        assert_eq!(
            refused(&bus_key(line)),
            (
                format!("bus.toml:4:{column}: bus \"bus0\": {problem}"),
                Some(format!("bus[0].{key}"))
            )
        );
    }
    assert_eq!(
        refused(&drive_key("watchdog_ms = 0")),
        (
            "bus.toml:7:15: bus \"bus0\" drive 3: watchdog_ms = 0 is out of range: the \
             controller watchdog is 1..=60000 ms"
                .to_owned(),
            Some("bus[0].drive[0].watchdog_ms".to_owned())
        )
    );
    assert_eq!(
        error(&drive_key("reference_hz = 0")).to_string(),
        "bus.toml:7:16: bus \"bus0\" drive 3: reference_hz = 0 is out of range: the reference \
         frequency (P2000) is above 0 and at most 650 Hz"
    );
    assert_eq!(error(&drive_key("reference_hz = 650.5")).line, Some(7));
    // Checked as written, before it becomes an f32 (which would round this to 650).
    assert_eq!(error(&drive_key("reference_hz = 650.00003")).line, Some(7));
    assert_eq!(
        parse(&drive_key("reference_hz = 650")).buses[0].drives[0].reference_hz,
        ReferenceHz(650.0)
    );
    assert_eq!(
        parse(&bus_key("priority = 99")).buses[0].priority,
        Priority(99)
    );
}

#[test]
fn cpu_must_be_online() {
    let online = std::thread::available_parallelism().unwrap().get();
    let plural = if online == 1 { "" } else { "s" };
    assert_eq!(
        refused(&bus_key(&format!("cpu = {online}"))),
        (
            format!(
                "bus.toml:4:7: bus \"bus0\": cpu = {online} is out of range: this machine has \
                 {online} online CPU{plural}: cpu is 0..={}",
                online - 1
            ),
            Some("bus[0].cpu".to_owned())
        )
    );
    assert_eq!(error(&bus_key("cpu = -1")).line, Some(4));
    assert_eq!(parse(&bus_key("cpu = 0")).buses[0].cpu, Some(Cpu(0)));
    assert_eq!(
        error(&bus_key("cpu = \"x\"")).to_string(),
        "bus.toml:4:7: bus \"bus0\": cpu = \"x\" is not an integer"
    );
}

#[test]
fn the_broken_rule_nearest_the_start_is_reported_whatever_the_kinds() {
    // A bad name (line 2) before a CPU this machine lacks and a monitoring parameter that is
    // none (both checked as rules, not as the file is read).
    let text = "[[bus]]\nname = \"b a d\"\ndevice = \"sim\"\ncpu = 4096\n\n[[bus.drive]]\n\
                address = 3\nmonitoring_param = \"Q1\"\n";
    assert_eq!(error(text).path.as_deref(), Some("bus[0].name"));
    let text = text.replace("b a d", "bus0");
    assert_eq!(error(&text).path.as_deref(), Some("bus[0].cpu"));
    let text = text.replace("cpu = 4096", "cpu = 0");
    assert_eq!(
        error(&text).path.as_deref(),
        Some("bus[0].drive[0].monitoring_param")
    );
}

#[test]
fn a_configuration_needs_a_bus_and_a_bus_needs_a_drive() {
    for text in ["# nothing here\n", "bus = []\n"] {
        let e = error(text);
        assert_eq!(
            e.to_string(),
            "bus.toml: no [[bus]] table: a configuration needs at least one bus"
        );
        assert_eq!((e.line, e.path.as_deref()), (None, Some("bus")));
    }
    assert_eq!(
        refused("# a bus\n[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n"),
        (
            "bus.toml:2:1: bus \"bus0\": no [[bus.drive]] table: every bus needs at least one \
             drive"
                .to_owned(),
            Some("bus[0].drive".to_owned())
        )
    );
    // Also at the [[bus]] table when it writes an empty drive array.
    assert_eq!(
        error("# a bus\n[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\ndrive = []\n").line,
        Some(2)
    );
}

#[test]
fn one_error_at_a_time_each_at_its_own_place() {
    // serde stops at the first value it refuses (the tables in file order, a table's keys in
    // name order): each error is reported where it is, and fixing it shows the next.
    let text = "[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\nretries = 11\n\n[[bus.drive]]\n\
                address = 3\npzd = 17\n";
    assert_eq!(error(text).path.as_deref(), Some("bus[0].drive[0].pzd"));
    let fixed = text.replace("pzd = 17", "pzd = 2");
    assert_eq!(error(&fixed).line, Some(4));
    // A later bus with a bad name does not hide an earlier bus's error.
    let text = "[[bus]]\nname = \"a\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 3\npzd = 99\n\
                [[bus]]\nname = \"b b\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 3\n";
    assert_eq!(error(text).line, Some(6));
    // Of several broken rules, the first in the file.
    let text = "[[bus]]\nname = \"a a\"\ndevice = \"ttyXYZ\"\n[[bus.drive]]\naddress = 3\n";
    assert_eq!(error(text).path.as_deref(), Some("bus[0].name"));
}

#[test]
fn inline_tables_are_checked_like_headers() {
    let text = "bus = [{ name = \"bus0\", device = \"sim\", drive = [{ address = 1 }, \
                { address = 2, pzd = 17 }] }]\n";
    assert_eq!(
        refused(text),
        (
            "bus.toml:1:88: bus \"bus0\" drive 2: pzd = 17 is out of range: PZD words (P2012) \
             are 0..=16"
                .to_owned(),
            Some("bus[0].drive[1].pzd".to_owned())
        )
    );
    let ok = text.replace("pzd = 17", "pzd = 4");
    assert_eq!(parse(&ok).buses[0].drives[1].layout().pzd.get(), 4);
}

#[test]
fn integers_may_be_written_in_hex_and_times_as_integers() {
    let c = parse(&drive_key("watchdog_ms = 0x10"));
    assert_eq!(c.buses[0].drives[0].watchdog_ms.get(), ms(16));
    let c = parse("[[bus]]\nname = \"b\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 0x1f\n");
    assert_eq!(c.buses[0].drives[0].address.get(), 31);
}

#[test]
fn columns_count_characters_not_bytes() {
    assert_eq!(errors::position("aé\nxéy", 7), (2, 3));
    assert_eq!(errors::position("abc", 0), (1, 1));
    assert_eq!(errors::position("abc", 99), (1, 4));
    // A serial device whose path has a two-byte character before the error on the same line.
    let device = std::env::temp_dir().join(format!("uss-config-é-{}", std::process::id()));
    std::fs::write(&device, "").unwrap();
    let text = format!(
        "bus = [{{ name = \"b\", device = \"{}\", drive = [{{ address = 3, pzd = 17 }}] }}]\n",
        device.display()
    );
    let e = error(&text);
    std::fs::remove_file(&device).unwrap();
    // Search for the whole key: the process id in the path may contain "17" too.
    let at = text.find("pzd = 17").unwrap() + "pzd = ".len();
    let column = text[..at].chars().count() + 1;
    assert_eq!((e.line, e.column), (Some(1), Some(column)));
    assert_eq!(at + 1, column + 1, "the path holds one two-byte character");
}

/// Lines a configuration is made of: valid keys, out-of-range and wrongly typed values, typos,
/// headers, broken TOML.
const PIECES: &[&str] = &[
    "[[bus]]",
    "[[bus.drive]]",
    "[bus.drive.sim]",
    "name = \"bus0\"",
    "name = \"bus0\"",
    "name = \"b a d\"",
    "device = \"sim\"",
    "device = \"/dev/ptmx\"",
    "device = \"relative/tty\"",
    "address = 3",
    "address = 3",
    "address = 40",
    "adress = 3",
    "baud = 19200",
    "baud = 250000",
    "baud = \"fast\"",
    "nonstandard_baud = true",
    "pkw = 127",
    "pkw = 5",
    "pzd = 17",
    "response_timeout_ms = 25.5",
    "response_timeout_ms = nan",
    "cycle_time_ms = -1",
    "retries = 300",
    "cpu = -1",
    "cpu = 0",
    "seed = 7",
    "weight = 0",
    "reference_hz = 60",
    "safe_command = \"off3\"",
    "safe_command = \"stop\"",
    "monitoring_param = \"P2014.0\"",
    "monitoring_param = \"Q1\"",
    "monitoring_param = \"\"",
    "require_monitoring = true",
    "sim = { delay = 1, drop = 0.5 }",
    "sim = { drop = 2 }",
    "delay = 1",
    "sim = \"delay=1\"",
    "bus = 1",
    "drive = []",
    "= broken",
    "\"é\" = 1",
    "",
];

/// Keys of a `[[bus]]` table with values that are allowed (mostly) on the simulated bus.
const BUS_KEYS: &[&str] = &[
    "baud = 19200",
    "baud = 250000\nnonstandard_baud = true",
    "rs485 = \"auto\"",
    "echo = true",
    "response_timeout_ms = 25.5",
    "timeout_margin_ms = 3",
    "rx_latency_ms = 16",
    "rs485 = \"kernel\"\nrs485_rts = \"low-while-sending\"\nrs485_delay_before_ms = 2",
    "retries = 0",
    "offline_after = 5",
    "cycle_time_ms = 12.25",
    "param_priority = true",
    "line_down_limit_ms = 0",
    "priority = 99",
    "seed = 7",
    "cpu = 0",
];

/// Keys of a `[[bus.drive]]` table with values that are allowed (mostly).
const DRIVE_KEYS: &[&str] = &[
    "pkw = 127",
    "pkw = 0",
    "pzd = 6",
    "weight = 16",
    "reference_hz = 60.1",
    "watchdog_ms = 250",
    "safe_command = \"off2\"",
    "params_writable = false",
    "monitoring_param = \"p2040\"",
    "monitoring_param = \"\"",
    "monitoring_max_ms = 5000",
    "require_monitoring = true",
    "sim = { delay = 1.5, drop = 0.1, unplug = \"10..20\" }",
    "sim.p2014 = 100",
];

/// Picked keys of a bus, and its drives: address and picked keys.
type BusPicks = (Vec<usize>, Vec<(u8, Vec<usize>)>);

/// A file of buses and drives with keys from [`BUS_KEYS`] and [`DRIVE_KEYS`], or sometimes one
/// of [`PIECES`] instead: `(bus keys, [(address, drive keys)])` per bus.
fn file_text(buses: &[BusPicks], noise: &[(usize, usize)]) -> String {
    let mut lines = Vec::new();
    for (n, (keys, drives)) in buses.iter().enumerate() {
        lines.push(format!("[[bus]]\nname = \"bus{n}\"\ndevice = \"sim\""));
        lines.extend(keys.iter().map(|&k| BUS_KEYS[k].to_owned()));
        for (address, keys) in drives {
            lines.push(format!("[[bus.drive]]\naddress = {address}"));
            lines.extend(keys.iter().map(|&k| DRIVE_KEYS[k].to_owned()));
        }
    }
    for &(at, piece) in noise {
        let at = at % (lines.len() + 1);
        lines.insert(at, PIECES[piece].to_owned());
    }
    lines.join("\n") + "\n"
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(1000))]

    /// Whatever the file, parsing never panics; a refusal names a place inside the text and
    /// what is allowed, and an accepted configuration reads back the same from what
    /// `--check-config` writes.
    #[test]
    fn any_file_is_accepted_and_round_trips_or_refused_with_its_place(
        buses in proptest::collection::vec(
            (
                proptest::collection::vec(0..BUS_KEYS.len(), 0..3),
                proptest::collection::vec(
                    (0u8..4, proptest::collection::vec(0..DRIVE_KEYS.len(), 0..3)),
                    1..4,
                ),
            ),
            0..3,
        ),
        noise in proptest::collection::vec((0usize..64, 0..PIECES.len()), 0..2),
        cut in 0usize..4000,
    ) {
        let text = file_text(&buses, &noise);
        // Sometimes a file cut short, in the middle of a line.
        let text = if cut < text.len() && text.is_char_boundary(cut) && cut % 4 == 0 {
            text[..cut].to_owned()
        } else {
            text
        };
        match Config::parse(&text, "p.toml") {
            Ok(config) => {
                let written = config.to_toml();
                let again = Config::parse(&written, "written");
                proptest::prop_assert_eq!(again.as_ref().ok(), Some(&config), "{}", written);
            }
            Err(e) => {
                proptest::prop_assert!(!e.message.is_empty());
                if let (Some(line), Some(column)) = (e.line, e.column) {
                    let lines: Vec<&str> = text.split('\n').collect();
                    proptest::prop_assert!(line <= lines.len(), "{e} in {text:?}");
                    proptest::prop_assert!(
                        column <= lines[line - 1].chars().count() + 1,
                        "{e} in {text:?}"
                    );
                }
            }
        }
    }
}

/// A device that exists but no serial line runs over (a directory, a file, /dev/null) is refused
/// with the file, line and field, at `--check-config` and at start alike (issue 35).
#[test]
fn a_device_that_is_no_tty_is_refused_naming_file_line_and_field() {
    let regular = std::env::temp_dir().join(format!("uss-config-file-{}", std::process::id()));
    std::fs::write(&regular, "").unwrap();
    let cases = [
        ("/tmp", "is a directory".to_owned()),
        (
            "/dev/null",
            "is a character device of the kernel's mem class".to_owned(),
        ),
        (regular.to_str().unwrap(), "is a regular file".to_owned()),
    ];
    for (device, what) in &cases {
        let (message, path) = refused(&serial("", "").replace("/dev/ptmx", device));
        assert_eq!(
            message,
            format!(
                "bus.toml:3:10: bus \"bus1\": device = \"{device}\" {what}, not a serial device \
                 (a serial adapter's tty such as /dev/ttyUSB0, or a pty): {}",
                allowed::DEVICES
            )
        );
        assert_eq!(path.as_deref(), Some("bus[0].device"));
    }
    std::fs::remove_file(&regular).unwrap();
}

/// A configuration written for the old profile (this guide said `P2014.1` until the parameter
/// lists were read: index 1 is the BOP link, RS232) names the telegram monitoring of another
/// interface than the COM link ussd talks over: refused, naming both elements, so ussd never
/// verifies the wrong one.
#[test]
fn a_monitoring_param_naming_another_link_of_the_family_is_refused() {
    assert_eq!(
        refused(&drive_key("monitoring_param = \"P2014.1\"")),
        (
            "bus.toml:7:20: bus \"bus0\" drive 3: monitoring_param = \"P2014.1\" names \
             P2014[1] (BOP link, RS232), not the telegram-off time of the link ussd talks \
             over: P2014[0] (COM link, RS485); write \"P2014[0]\", or leave the key out"
                .to_owned(),
            Some("bus[0].drive[0].monitoring_param".to_owned())
        )
    );
    // The family's own element, written out, is taken.
    assert_eq!(
        parse(&drive_key("monitoring_param = \"P2014.0\"")).buses[0].drives[0]
            .monitoring_param()
            .param()
            .map(|p| p.to_string()),
        Some("P2014[0]".into())
    );
}

/// A drive of a family is configured for no more PZD words than the family's USS PZD length
/// parameter allows (MM4 P2012[0]: at most 8, PL440 p.196; G120 p2022: at most 8): a drive told
/// otherwise answers no telegram of ussd's length. The protocol's 16 stay open to a `generic`
/// slave.
#[test]
fn more_pzd_words_than_the_family_takes_are_refused() {
    assert_eq!(
        refused(&drive_key("pzd = 9")),
        (
            "bus.toml:7:7: bus \"bus0\" drive 3: pzd = 9 is more than a MICROMASTER 4 / \
             SINAMICS G110 takes: its USS PZD length P2012[0] is at most 8; give family = \
             \"generic\" for another slave"
                .to_owned(),
            Some("bus[0].drive[0].pzd".to_owned())
        )
    );
    let g120 = refused(&drive_key("family = \"g120\"\npzd = 12")).0;
    assert!(g120.contains("pzd = 12 is more than") && g120.contains("p2022 is at most 8"));
    for ok in [
        "pzd = 8",
        "family = \"generic\"\npzd = 16",
        "family = \"simoreg\"\npzd = 16",
    ] {
        parse(&drive_key(ok));
    }
}
