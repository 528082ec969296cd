//! How late a serial device delivers what it receives, read from sysfs (issue 22): an FTDI
//! adapter holds received bytes up to its `latency_timer` (16 ms by default, 1 ms at best),
//! and the host picks its packet up at the next USB frame (1 ms) after that; an
//! 8250/16550 UART raises its interrupt at its FIFO trigger level, or after four character
//! times of silence; other USB-serial chips (CH340, `cp210x`, PL2303) send a packet per USB
//! frame (1 ms); a pseudo-terminal delivers at once. ussd widens its timing allowances by this
//! much (`rx_latency_ms`, `uss_engine::EngineConfig::rx_latency`).

use core::fmt;
use core::time::Duration;
use std::path::Path;
use uss_protocol::Timing;

/// Where a line's receive latency came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Source {
    /// `rx_latency_ms` in the configuration.
    Configured,
    /// An FTDI adapter's `latency_timer`, in ms.
    LatencyTimer { tty: String, ms: u32 },
    /// An 8250-family UART's receive FIFO trigger level, in bytes.
    FifoTrigger { tty: String, bytes: u32 },
    /// Another USB-serial adapter (its driver): one USB frame.
    UsbFrame { tty: String, driver: String },
    /// A pseudo-terminal, or a device sysfs says nothing about: no latency assumed.
    None,
}

/// A line's receive latency and where it came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RxLatency {
    pub latency: Duration,
    pub source: Source,
}

/// How often a USB host picks up a full-speed adapter's packets.
pub const USB_FRAME: Duration = Duration::from_millis(1);

/// Above this, an FTDI latency timer costs most of the throughput at fast rates: ussd warns.
pub const LATENCY_TIMER_WARN_MS: u32 = 2;

impl RxLatency {
    /// What to tell the user at start, if anything: a latency timer above
    /// [`LATENCY_TIMER_WARN_MS`], and how to lower it.
    pub fn warning(&self) -> Option<String> {
        match &self.source {
            Source::LatencyTimer { tty, ms } if *ms > LATENCY_TIMER_WARN_MS => Some(format!(
                "{tty}'s FTDI latency_timer is {ms} ms: every reply reaches ussd up to {ms} ms \
                 late and each exchange waits for it (at 187500 baud a fifth of the line's \
                 throughput at 16 ms); set it to 1 ms: `echo 1 > \
                 /sys/bus/usb-serial/devices/{tty}/latency_timer`, or for good with \
                 deploy/99-uss-rs485.rules"
            )),
            _ => None,
        }
    }
}

impl fmt::Display for RxLatency {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:.2} ms ", self.latency.as_secs_f64() * 1e3)?;
        match &self.source {
            Source::Configured => f.write_str("(rx_latency_ms)"),
            Source::LatencyTimer { tty, ms } => {
                write!(f, "({tty} latency_timer {ms} ms and a USB frame)")
            }
            Source::FifoTrigger { tty, bytes } => {
                write!(f, "({tty} receive FIFO trigger at {bytes} bytes)")
            }
            Source::UsbFrame { tty, driver } => write!(f, "({tty}: {driver}, one USB frame)"),
            Source::None => f.write_str("(none known)"),
        }
    }
}

/// The receive latency of `device` (a path, perhaps a by-id link) as sysfs under `sysfs`
/// (normally `/sys`) describes it, at `timing`'s character rate.
pub fn detect(sysfs: &Path, device: &Path, timing: Timing) -> RxLatency {
    let none = RxLatency {
        latency: Duration::ZERO,
        source: Source::None,
    };
    let Some(tty) = std::fs::canonicalize(device)
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
    else {
        return none;
    };
    let class = sysfs.join("class/tty").join(&tty);
    let read_number =
        |path: &Path| -> Option<u32> { std::fs::read_to_string(path).ok()?.trim().parse().ok() };
    if let Some(ms) = read_number(&class.join("device/latency_timer")) {
        return RxLatency {
            latency: Duration::from_millis(u64::from(ms)) + USB_FRAME,
            source: Source::LatencyTimer { tty, ms },
        };
    }
    if let Some(bytes) = read_number(&class.join("rx_trig_bytes")) {
        // The trigger's worth of characters, or the character timeout (four character times)
        // for a tail shorter than that.
        let chars = u64::from(bytes.saturating_sub(1)).max(4);
        return RxLatency {
            latency: timing.chars(chars),
            source: Source::FifoTrigger { tty, bytes },
        };
    }
    let link_name = |path: &Path| -> Option<String> {
        std::fs::read_link(path)
            .ok()?
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
    };
    if link_name(&class.join("device/subsystem")).as_deref() == Some("usb-serial") {
        let driver = link_name(&class.join("device/driver")).unwrap_or_else(|| "usb-serial".into());
        return RxLatency {
            latency: USB_FRAME,
            source: Source::UsbFrame { tty, driver },
        };
    }
    none
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;
    use uss_protocol::Baud;

    /// A fake `/sys` and `/dev` in a directory of their own.
    struct Root {
        dir: PathBuf,
    }

    impl Root {
        fn new(name: &str) -> Self {
            let dir =
                std::env::temp_dir().join(format!("uss-latency-{}-{name}", std::process::id()));
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(dir.join("dev/serial/by-id")).unwrap();
            Self { dir }
        }

        /// `/dev/<tty>` and a by-id link to it; returns the link.
        fn device(&self, tty: &str) -> PathBuf {
            let dev = self.dir.join("dev").join(tty);
            std::fs::write(&dev, "").unwrap();
            let link = self.dir.join("dev/serial/by-id/usb-adapter-if00-port0");
            std::os::unix::fs::symlink(&dev, &link).unwrap();
            link
        }

        fn file(&self, path: &str, text: &str) {
            let p = self.dir.join("sys").join(path);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            std::fs::write(p, text).unwrap();
        }

        fn link(&self, path: &str, target: &str) {
            let p = self.dir.join("sys").join(path);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            std::os::unix::fs::symlink(target, p).unwrap();
        }

        fn sys(&self) -> PathBuf {
            self.dir.join("sys")
        }
    }

    impl Drop for Root {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }

    fn timing(baud: u32) -> Timing {
        Timing::new(Baud::new(baud).unwrap())
    }

    #[test]
    fn an_ftdi_adapter_reached_by_id_gives_its_latency_timer_and_a_warning_above_2_ms() {
        let root = Root::new("ftdi");
        let device = root.device("ttyUSB0");
        root.file("class/tty/ttyUSB0/device/latency_timer", "16\n");
        let got = detect(&root.sys(), &device, timing(187_500));
        assert_eq!(got.latency, Duration::from_millis(17));
        assert_eq!(
            got.source,
            Source::LatencyTimer {
                tty: "ttyUSB0".into(),
                ms: 16
            }
        );
        assert_eq!(
            got.to_string(),
            "17.00 ms (ttyUSB0 latency_timer 16 ms and a USB frame)"
        );
        let warning = got.warning().unwrap();
        assert!(
            warning.contains("echo 1 > /sys/bus/usb-serial/devices/ttyUSB0/latency_timer"),
            "{warning}"
        );
        root.file("class/tty/ttyUSB0/device/latency_timer", "1\n");
        let low = detect(&root.sys(), &device, timing(187_500));
        assert_eq!(low.latency, Duration::from_millis(2));
        assert_eq!(low.warning(), None);
    }

    #[test]
    fn a_16550_waits_for_its_fifo_trigger_or_four_characters() {
        let root = Root::new("uart");
        let device = root.device("ttyS0");
        root.file("class/tty/ttyS0/rx_trig_bytes", "8\n");
        let t = timing(9600);
        let got = detect(&root.sys(), &device, t);
        // The start byte is seen seven characters late.
        assert_eq!(got.latency, t.chars(7));
        assert_eq!(got.warning(), None);
        root.file("class/tty/ttyS0/rx_trig_bytes", "1\n");
        assert_eq!(detect(&root.sys(), &device, t).latency, t.chars(4));
    }

    #[test]
    fn other_usb_serial_chips_get_a_usb_frame_and_unknown_devices_nothing() {
        let root = Root::new("ch341");
        let device = root.device("ttyUSB1");
        root.link(
            "class/tty/ttyUSB1/device/subsystem",
            "../../../../bus/usb-serial",
        );
        root.link(
            "class/tty/ttyUSB1/device/driver",
            "../../../../bus/usb-serial/drivers/ch341-uart",
        );
        let got = detect(&root.sys(), &device, timing(19200));
        assert_eq!(got.latency, Duration::from_millis(1));
        assert_eq!(
            got.to_string(),
            "1.00 ms (ttyUSB1: ch341-uart, one USB frame)"
        );

        let bare = Root::new("bare");
        let device = bare.device("ttyAMA0");
        let got = detect(&bare.sys(), &device, timing(19200));
        assert_eq!(got.source, Source::None);
        assert_eq!(got.latency, Duration::ZERO);
        assert_eq!(
            detect(&bare.sys(), Path::new("/nonexistent/tty"), timing(19200)).source,
            Source::None
        );
    }
}
