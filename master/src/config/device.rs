//! Where a bus lives, one kind of line per variant: the built-in simulated bus, a serial device,
//! or a serial device server's port over TCP. What differs between the kinds as the
//! configuration sees them (how one is written, whether it is usable, whether two buses share
//! one, whether it is a line that can fail and come back) is here; the daemon opens each kind
//! in its own file (`daemon/line/`).

use super::allowed::DEVICES;
use core::time::Duration;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use uss_protocol::Timing;

/// Where a bus lives.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, Serialize)]
#[serde(from = "String", into = "String")]
pub enum Device {
    /// The built-in simulated bus: `uss-drive-sim` drives on an in-process virtual wire.
    Sim,
    /// A serial device (RS485 adapter, embedded UART, or a pseudo-terminal).
    Serial(PathBuf),
    /// A serial device server's RS485 port over raw TCP (ser2net, a Moxa `NPort` or Lantronix
    /// server in TCP-server mode), written `tcp://host:port`: the `host:port`.
    Tcp(String),
}

/// The device name of the built-in simulated bus.
pub const SIM_DEVICE: &str = "sim";

/// How a serial device server's port is written.
pub const TCP_SCHEME: &str = "tcp://";

/// `"sim"`, `tcp://host:port` or a path; whether it is usable is [`Device::problem`]'s.
impl From<String> for Device {
    fn from(written: String) -> Self {
        if written == SIM_DEVICE {
            Device::Sim
        } else if let Some(address) = written.strip_prefix(TCP_SCHEME) {
            Device::Tcp(address.to_owned())
        } else {
            Device::Serial(PathBuf::from(written))
        }
    }
}

impl From<Device> for String {
    fn from(device: Device) -> Self {
        device.to_string()
    }
}

impl core::fmt::Display for Device {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Device::Sim => f.write_str(SIM_DEVICE),
            Device::Serial(path) => write!(f, "{}", path.display()),
            Device::Tcp(address) => write!(f, "{TCP_SCHEME}{address}"),
        }
    }
}

impl Device {
    /// Whether the bus runs over a line that can fail and come back (a serial device, a
    /// connection): not the simulated bus.
    pub const fn is_line(&self) -> bool {
        !matches!(self, Device::Sim)
    }

    /// How long a write may wait for room before the line counts as stuck (a line failure,
    /// reopened); zero where nothing waits (the simulated bus).
    pub fn write_stall(&self, timing: Timing) -> Duration {
        match self {
            Device::Sim => Duration::ZERO,
            Device::Serial(_) | Device::Tcp(_) => uss_serial::write_stall(timing),
        }
    }

    /// Whether two buses' devices are one line: the same path, or two names (a by-id link and
    /// the tty) of one existing device; the same server port.
    pub fn same_line(&self, other: &Device) -> bool {
        match (self, other) {
            (Device::Serial(a), Device::Serial(b)) => {
                a == b
                    || matches!(
                        (std::fs::canonicalize(a), std::fs::canonicalize(b)),
                        (Ok(x), Ok(y)) if x == y
                    )
            }
            (Device::Tcp(a), Device::Tcp(b)) => a.eq_ignore_ascii_case(b),
            _ => false,
        }
    }

    /// What makes the device unusable, in the error's words; `None` when it is usable: "sim"
    /// where the build has the simulator; a serial device that exists, or an absolute path that
    /// may appear later (ussd starts that bus line down and opens the device when it appears);
    /// a server port `tcp://host:port` (the host is looked up when ussd connects).
    pub fn problem(&self) -> Option<String> {
        let problem = match self {
            Device::Sim if cfg!(feature = "sim") => return None,
            Device::Sim => {
                "is not available: this ussd was built without the simulated bus (the `sim` \
                 feature of uss-master)"
            }
            Device::Serial(path) if path.as_os_str().is_empty() => "is not allowed",
            Device::Serial(path) => match SerialPath::of(path) {
                SerialPath::Tty | SerialPath::Unknown => return None,
                SerialPath::Absent if path.is_absolute() => return None,
                SerialPath::Absent => {
                    "does not exist (a device that may be absent when ussd starts needs its \
                     absolute path)"
                }
                SerialPath::NotATty(what) => {
                    return Some(format!(
                        "is {what}, not a serial device (a serial adapter's tty such as \
                         /dev/ttyUSB0, or a pty): {DEVICES}"
                    ));
                }
            },
            Device::Tcp(address) => match tcp_port(address) {
                Ok(_) => return None,
                Err(why) => return Some(format!("is not a server port ({why}): {DEVICES}")),
            },
        };
        Some(format!("{problem}: {DEVICES}"))
    }
}

/// The port of `host:port` (an IPv6 host in brackets: `[::1]:4001`), or why it is none.
fn tcp_port(address: &str) -> Result<u16, &'static str> {
    let (host, port) = address.rsplit_once(':').ok_or("write it tcp://host:port")?;
    if host.is_empty() || host == "[]" {
        return Err("no host before the port");
    }
    if host.contains(':') && !(host.starts_with('[') && host.ends_with(']')) {
        return Err("an IPv6 address goes in brackets, tcp://[::1]:4001");
    }
    match port.parse::<u16>() {
        Ok(0) | Err(_) => Err("the port is a number 1..=65535"),
        Ok(port) => Ok(port),
    }
}

/// What is at a serial device's path now, told without opening it (opening a serial port can
/// raise its modem lines).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SerialPath {
    /// Nothing: a USB adapter not plugged in yet; ussd starts the line down and opens it when
    /// it appears.
    Absent,
    /// A terminal device: a serial port, a USB adapter's tty or a pseudo-terminal.
    Tty,
    /// Something no serial line runs over: a directory, a file, `/dev/null`.
    NotATty(String),
    /// It exists, but this machine does not say what it is (no access, no sysfs).
    Unknown,
}

/// Unix98 pseudo-terminal slaves, `/dev/pts/N` (Linux devices.txt: char majors 136..143).
const PTY_SLAVE_MAJORS: core::ops::RangeInclusive<u64> = 136..=143;

impl SerialPath {
    /// What `path` is: a character device of the kernel's `tty` class (sysfs
    /// `/sys/dev/char/MAJOR:MINOR/subsystem`), a pty slave, or what else.
    pub fn of(path: &std::path::Path) -> Self {
        use std::os::unix::fs::{FileTypeExt as _, MetadataExt as _};
        let meta = match std::fs::metadata(path) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Self::Absent,
            Err(_) => return Self::Unknown,
        };
        let kind = meta.file_type();
        if kind.is_dir() {
            return Self::NotATty("a directory".into());
        }
        if !kind.is_char_device() {
            return Self::NotATty(if kind.is_file() {
                "a regular file".into()
            } else {
                "not a character device".into()
            });
        }
        let (major, minor) = (
            nix::sys::stat::major(meta.rdev()),
            nix::sys::stat::minor(meta.rdev()),
        );
        if PTY_SLAVE_MAJORS.contains(&major) {
            return Self::Tty;
        }
        let class = std::fs::read_link(format!("/sys/dev/char/{major}:{minor}/subsystem"));
        match class.as_deref().ok().and_then(std::path::Path::file_name) {
            Some(c) if c == "tty" => Self::Tty,
            Some(c) => Self::NotATty(format!(
                "a character device of the kernel's {} class",
                c.to_string_lossy()
            )),
            None => Self::Unknown,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_server_port_is_written_tcp_host_port() {
        for (written, ok) in [
            ("tcp://127.0.0.1:4001", true),
            ("tcp://moxa-3.plant:950", true),
            ("tcp://[::1]:4001", true),
            ("tcp://127.0.0.1", false),
            ("tcp://:4001", false),
            ("tcp://host:0", false),
            ("tcp://host:70000", false),
            ("tcp://::1:4001", false),
        ] {
            let device = Device::from(written.to_owned());
            assert!(matches!(device, Device::Tcp(_)), "{written}");
            assert_eq!(
                device.problem().is_none(),
                ok,
                "{written}: {:?}",
                device.problem()
            );
            assert_eq!(String::from(device), written, "written back as it was");
        }
    }

    proptest::proptest! {
        /// Whatever follows `tcp://` is a server port written back as it was, and judged
        /// without a panic: usable exactly when it is `host:port` with a port 1..=65535.
        #[test]
        fn any_server_port_is_written_back_and_judged(address in "\\PC{0,40}") {
            let written = format!("{TCP_SCHEME}{address}");
            let device = Device::from(written.clone());
            proptest::prop_assert_eq!(&String::from(device.clone()), &written);
            let usable = device.problem().is_none();
            proptest::prop_assert_eq!(usable, tcp_port(&address).is_ok());
            if usable {
                let (_, port) = address.rsplit_once(':').unwrap_or_default();
                proptest::prop_assert!(port.parse::<u16>().is_ok_and(|p| p > 0));
            }
        }
    }

    #[test]
    fn two_buses_on_one_server_port_are_one_line() {
        let a = Device::from("tcp://Server:4001".to_owned());
        assert!(a.same_line(&Device::from("tcp://server:4001".to_owned())));
        assert!(!a.same_line(&Device::from("tcp://server:4002".to_owned())));
        assert!(!a.same_line(&Device::Serial("server:4001".into())));
        assert!(a.is_line() && !Device::Sim.is_line());
    }
}
