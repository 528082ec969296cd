//! `ussd --qualify`: whether this machine holds USS's timing, measured as the bus threads would
//! run. For each bus of the configuration a thread takes that bus's scheduling (its CPU, its
//! `SCHED_FIFO` priority, memory locked: [`uss_realtime::apply_to_current_thread`], as the bus
//! thread does) and wakes every millisecond with an absolute `clock_nanosleep` on
//! `CLOCK_MONOTONIC`, recording how late each wake-up came: the method of rt-tests'
//! `cyclictest -m -p PRIO -a CPU -i 1000`, so the figures can be compared with it
//! (`cargo bench -p uss-benches --bench qualify` runs both in one run).
//!
//! The latency is then held against USS's timing at each baud rate (USS.md section 4):
//! - the **start pause** (2 tz): a bus thread that wakes later than that sends each request
//!   late, and the line no longer runs at its wire floor;
//! - the **residual time** slack of a reply (0.5 x (n + 3) tz for a 16-byte telegram, the
//!   tolerance between the compressed and the monitored residual time): a thread that reads a
//!   reply later than that misjudges its end;
//! - a **31-drive cycle**: each exchange wakes the thread at least once, so a full line's cycle
//!   grows by 31 late wake-ups; it holds while that is at most a tenth of the cycle.
//!
//! And it checks what usually breaks a deployment, saying how to fix each: the real-time limits
//! (`RLIMIT_RTPRIO`, `RLIMIT_MEMLOCK`), `isolcpus`/`nohz_full` for a pinned bus's CPU, the
//! adapter's `latency_timer`, `ModemManager` on the port, and the device being a serial tty.

use crate::config::{BusConfig, Config, Device, SerialPath};
use core::fmt::Write as _;
use core::time::Duration;
use hdrhistogram::Histogram;
use nix::sys::time::TimeSpec;
use nix::time::{ClockId, ClockNanosleepFlags, clock_gettime, clock_nanosleep};
use std::path::{Path, PathBuf};
use std::time::Instant;
use uss_protocol::{Baud, Timing};
use uss_realtime::{RtReport, RtRequest, apply_to_current_thread, may_lock_memory};

/// How often the measuring thread wakes: cyclictest's default interval (`-i 1000`).
pub const INTERVAL: Duration = Duration::from_millis(1);
/// Stack the measuring thread faults in, as a bus thread does.
const PREFAULT_STACK: usize = 256 * 1024;
/// Net bytes of the telegram the verdict is worked out for: PKW 4 + PZD 2 (USS.md section 4).
const NET: usize = 12;
/// Drives on a full line (USS.md section 5).
const FULL_LINE: u32 = 31;
/// The share a full line's cycle may grow by through late wake-ups and still hold.
const CYCLE_GROWTH_HOLDS: f64 = 0.10;
/// The USS rates the verdict is given for (the fast ones, where it matters).
const RATES: [u32; 7] = [9600, 19_200, 38_400, 57_600, 93_750, 115_200, 187_500];

/// What `ussd --qualify` is asked.
#[derive(Debug, Clone)]
pub struct QualifyOptions {
    pub duration: Duration,
    /// An SVG picture of the histogram.
    pub plot: Option<PathBuf>,
}

/// One bus's measurement.
#[derive(Debug)]
pub struct Measured {
    pub bus: String,
    pub baud: Baud,
    pub request: RtRequest,
    pub report: RtReport,
    /// How late each wake-up came, ns.
    pub latency: Histogram<u64>,
}

impl Measured {
    fn us(&self, quantile: f64) -> f64 {
        self.latency.value_at_quantile(quantile) as f64 / 1e3
    }

    fn max_us(&self) -> f64 {
        self.latency.max() as f64 / 1e3
    }

    /// USS's timing at the bus's own rate against the worst wake-up: the verdict.
    pub fn at_own_rate(&self) -> Option<AtRate> {
        AtRate::of(self.baud.get(), self.max_us())
    }
}

/// Measures every bus of `config` at once, each in a thread of its bus's scheduling, for
/// `duration`; a bus whose thread could not run is missing from the result (the caller says so).
pub fn measure(config: &Config, duration: Duration) -> Vec<Measured> {
    let threads: Vec<_> = config
        .buses
        .iter()
        .map(|bus| {
            let request = RtRequest {
                cpu: bus.cpu.map(crate::config::Cpu::get),
                priority: bus.priority.get(),
                lock_memory: true,
                prefault_stack_bytes: PREFAULT_STACK,
            };
            let (name, baud) = (bus.name.clone(), bus.baud);
            std::thread::Builder::new()
                .name(format!("qualify-{name}"))
                .spawn(move || {
                    let report = apply_to_current_thread(&request);
                    let latency = wake_ups(duration);
                    Measured {
                        bus: name,
                        baud,
                        request,
                        report,
                        latency,
                    }
                })
        })
        .collect();
    threads
        .into_iter()
        .filter_map(|t| t.ok()?.join().ok())
        .collect()
}

/// Wakes every [`INTERVAL`] for `duration` and records how late each wake-up came (ns).
fn wake_ups(duration: Duration) -> Histogram<u64> {
    // 1 ns .. 10 s at 3 significant figures; allocated before the loop, which records only.
    let mut h = Histogram::new_with_bounds(1, 10_000_000_000, 3)
        .unwrap_or_else(|e| unreachable!("valid bounds: {e}"));
    let now = || clock_gettime(ClockId::CLOCK_MONOTONIC).map_or(0, |t| ns_of(&t));
    let interval = INTERVAL.as_nanos() as u64;
    let end = Instant::now() + duration;
    let mut next = now() + interval;
    while Instant::now() < end {
        let at = TimeSpec::from_duration(Duration::from_nanos(next));
        let _ = clock_nanosleep(
            ClockId::CLOCK_MONOTONIC,
            ClockNanosleepFlags::TIMER_ABSTIME,
            &at,
        );
        let late = now().saturating_sub(next);
        let _ = h.record(late.max(1));
        next += interval;
        // A wake-up so late that the next ones are past already: step over them on the same
        // grid, as cyclictest does, rather than firing a burst.
        let current = now();
        while next <= current {
            next += interval;
        }
    }
    h
}

fn ns_of(t: &TimeSpec) -> u64 {
    (t.tv_sec() as u64).saturating_mul(1_000_000_000) + t.tv_nsec() as u64
}

/// How one USS rule fares at one rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rule {
    /// The allowance, µs.
    pub allowed_us: f64,
    /// The allowance minus the worst latency, µs (negative: it does not hold).
    pub margin_us: f64,
}

impl Rule {
    pub fn holds(&self) -> bool {
        self.margin_us >= 0.0
    }
}

/// USS's timing at `baud` against a worst wake-up latency of `max_us`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AtRate {
    pub baud: u32,
    pub start_pause: Rule,
    pub residual: Rule,
    /// A full line's cycle at the wire floor, ms, and how much late wake-ups add to it.
    pub cycle_ms: f64,
    pub cycle_growth: f64,
}

impl AtRate {
    pub fn of(baud: u32, max_us: f64) -> Option<Self> {
        let timing = Timing::new(Baud::new(baud).ok()?);
        let us = |d: Duration| d.as_secs_f64() * 1e6;
        let start_pause = us(timing.start_pause());
        let slack = us(timing.max_residual(NET)) - us(timing.residual(NET));
        // The slave answers no sooner than a start pause (USS.md section 4).
        let exchange = us(timing.wire_floor(NET, NET, timing.start_pause()));
        let cycle_us = f64::from(FULL_LINE) * exchange;
        Some(Self {
            baud,
            start_pause: Rule {
                allowed_us: start_pause,
                margin_us: start_pause - max_us,
            },
            residual: Rule {
                allowed_us: slack,
                margin_us: slack - max_us,
            },
            cycle_ms: cycle_us / 1e3,
            cycle_growth: f64::from(FULL_LINE) * max_us / cycle_us,
        })
    }

    pub fn cycle_holds(&self) -> bool {
        self.cycle_growth <= CYCLE_GROWTH_HOLDS
    }

    pub fn holds(&self) -> bool {
        self.start_pause.holds() && self.residual.holds() && self.cycle_holds()
    }
}

/// One thing that usually breaks a deployment, checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Check {
    pub ok: bool,
    pub what: String,
}

fn ok(what: String) -> Check {
    Check { ok: true, what }
}

fn fix(what: String) -> Check {
    Check { ok: false, what }
}

/// A CPU list as the kernel writes it (`1-3,5`).
fn cpu_list(text: &str) -> Vec<usize> {
    text.trim()
        .split(',')
        .filter(|p| !p.is_empty())
        .flat_map(|part| match part.split_once('-') {
            Some((a, b)) => match (a.parse::<usize>(), b.parse::<usize>()) {
                (Ok(a), Ok(b)) => (a..=b).collect(),
                _ => Vec::new(),
            },
            None => part.parse().into_iter().collect(),
        })
        .collect()
}

/// Whether a process named `ModemManager` runs.
fn modem_manager_runs() -> bool {
    std::fs::read_dir("/proc").is_ok_and(|entries| {
        entries.filter_map(Result::ok).any(|e| {
            std::fs::read_to_string(e.path().join("comm")).is_ok_and(|c| c.trim() == "ModemManager")
        })
    })
}

/// Whether udev marked `device` for `ModemManager` to leave alone (`ID_MM_DEVICE_IGNORE=1`).
fn modem_manager_ignores(device: &Path) -> bool {
    use std::os::unix::fs::MetadataExt as _;
    std::fs::metadata(device).is_ok_and(|m| {
        let (major, minor) = (
            nix::sys::stat::major(m.rdev()),
            nix::sys::stat::minor(m.rdev()),
        );
        std::fs::read_to_string(format!("/run/udev/data/c{major}:{minor}"))
            .is_ok_and(|db| db.lines().any(|l| l == "E:ID_MM_DEVICE_IGNORE=1"))
    })
}

/// What usually breaks a deployment of `bus`, each with how to fix it.
pub fn checks(bus: &BusConfig) -> Vec<Check> {
    let mut out = vec![rtprio(bus.priority.get()), memlock(), isolation(bus)];
    match &bus.device {
        Device::Serial(path) => out.extend(adapter(path, bus.baud)),
        Device::Tcp(_) => out.push(ok(format!(
            "bus {} runs over a serial device server ({}): no adapter here to check; its port's \
             8E1 and rate are set on the server",
            bus.name, bus.device
        ))),
        Device::Sim => out.push(ok(format!(
            "bus {} is the built-in simulated bus: no adapter to check",
            bus.name
        ))),
    }
    out
}

/// The real-time priority limit.
fn rtprio(priority: u8) -> Check {
    // SAFETY: geteuid has no preconditions and cannot fail.
    let root = unsafe { nix::libc::geteuid() } == 0;
    match nix::sys::resource::getrlimit(nix::sys::resource::Resource::RLIMIT_RTPRIO) {
        Ok(_) if root => ok(format!(
            "running as root: SCHED_FIFO priority {priority} needs no RLIMIT_RTPRIO (ussd's user \
             uss needs LimitRTPRIO=95, as the packaged unit sets)"
        )),
        Ok((soft, _)) if soft >= u64::from(priority) => ok(format!(
            "RLIMIT_RTPRIO {} allows SCHED_FIFO priority {priority}",
            if soft == u64::MAX {
                "unlimited".to_owned()
            } else {
                soft.to_string()
            }
        )),
        Ok((soft, _)) => fix(format!(
            "RLIMIT_RTPRIO is {soft}, below priority {priority}: the bus thread runs without \
             real time; LimitRTPRIO=95 in ussd's unit (as packaged), or `@uss - rtprio 95` in \
             /etc/security/limits.d/uss.conf for a login"
        )),
        Err(e) => fix(format!("RLIMIT_RTPRIO unreadable ({e})")),
    }
}

/// The memory-lock limit.
fn memlock() -> Check {
    if may_lock_memory() {
        ok("memory can be locked (RLIMIT_MEMLOCK unlimited or CAP_IPC_LOCK)".into())
    } else {
        fix(
            "RLIMIT_MEMLOCK is finite and there is no CAP_IPC_LOCK: the bus thread may take page \
             faults; LimitMEMLOCK=infinity in ussd's unit (as packaged), or `@uss - memlock \
             unlimited` in /etc/security/limits.d/uss.conf"
                .into(),
        )
    }
}

/// Whether the bus is pinned to a CPU the kernel keeps other work and its tick off.
fn isolation(bus: &BusConfig) -> Check {
    let listed = |file: &str| {
        std::fs::read_to_string(format!("/sys/devices/system/cpu/{file}"))
            .map(|t| cpu_list(&t))
            .unwrap_or_default()
    };
    match bus.cpu.map(crate::config::Cpu::get) {
        None => fix(format!(
            "bus {} is not pinned: other work shares its CPU; set `cpu = N` in its [[bus]] table \
             and CPUAffinity=N in ussd's unit (`systemctl edit ussd`)",
            bus.name
        )),
        Some(cpu) if listed("isolated").contains(&cpu) && listed("nohz_full").contains(&cpu) => ok(
            format!("CPU {cpu} is isolated (isolcpus) and tickless (nohz_full)"),
        ),
        Some(cpu) => fix(format!(
            "CPU {cpu} is not isolated and tickless: the scheduler puts other work or the timer \
             tick on it; add `isolcpus={cpu} nohz_full={cpu}` to the kernel command line \
             (GRUB_CMDLINE_LINUX in /etc/default/grub, then update-grub and reboot)"
        )),
    }
}

/// The adapter: a serial tty, how late it delivers, and `ModemManager`.
fn adapter(path: &Path, baud: Baud) -> [Check; 3] {
    let shown = path.display();
    let tty = match SerialPath::of(path) {
        SerialPath::Tty => ok(format!("{shown} is a serial tty")),
        SerialPath::Absent => fix(format!(
            "{shown} does not exist now: plug the adapter in (a udev name such as \
             /dev/uss-line1 appears with it)"
        )),
        SerialPath::Unknown => fix(format!("{shown}: this machine does not say what it is")),
        SerialPath::NotATty(what) => fix(format!("{shown} is {what}, not a serial device")),
    };
    let latency = uss_serial::latency::detect(Path::new("/sys"), path, Timing::new(baud));
    let delivery = match latency.warning() {
        Some(w) => fix(w),
        None => ok(format!("{shown} delivers received bytes within {latency}")),
    };
    let modems = if !modem_manager_runs() {
        ok("ModemManager does not run".into())
    } else if modem_manager_ignores(path) {
        ok(format!(
            "ModemManager runs and leaves {shown} alone (ID_MM_DEVICE_IGNORE)"
        ))
    } else {
        fix(format!(
            "ModemManager runs and may probe {shown} with AT commands, onto the bus: install \
             deploy/99-uss-rs485.rules (ENV{{ID_MM_DEVICE_IGNORE}}=\"1\"), or `systemctl disable \
             --now ModemManager`"
        ))
    };
    [tty, delivery, modems]
}

/// Histogram rows for the terminal: upper bounds in µs.
const ROWS_US: [u64; 12] = [
    5,
    10,
    20,
    50,
    100,
    200,
    500,
    1000,
    2000,
    5000,
    10_000,
    u64::MAX,
];

/// The report `ussd --qualify` prints for one bus.
pub fn report(m: &Measured, checks: &[Check], seconds: f64) -> String {
    let mut t = String::new();
    let pinned = m
        .request
        .cpu
        .map_or_else(|| "not pinned".to_owned(), |c| format!("CPU {c}"));
    let _ = writeln!(
        t,
        "bus {} ({} baud): {seconds:.0} s of wake-ups every {} us at SCHED_FIFO {}, {pinned}, \
         as its bus thread runs",
        m.bus,
        m.baud.get(),
        INTERVAL.as_micros(),
        m.request.priority
    );
    let _ = writeln!(t, "  scheduling: {}", m.report.summary());
    let _ = writeln!(
        t,
        "  wake-up latency: p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us ({} wake-ups)",
        m.us(0.5),
        m.us(0.99),
        m.us(0.999),
        m.max_us(),
        m.latency.len()
    );
    histogram(&mut t, m);
    rates(&mut t, m);
    verdict(&mut t, m);
    for c in checks {
        let _ = writeln!(t, "  {} {}", if c.ok { "ok  " } else { "FIX " }, c.what);
    }
    t
}

/// The histogram in rows of [`ROWS_US`], bars on a log scale.
fn histogram(t: &mut String, m: &Measured) {
    let total = m.latency.len().max(1);
    let mut below = 0;
    for upper in ROWS_US {
        let upper_ns = upper.saturating_mul(1000);
        let count = m.latency.count_between(below, upper_ns.saturating_sub(1));
        below = upper_ns;
        if count == 0 && upper > 100 {
            continue;
        }
        let bar = if count == 0 {
            0
        } else {
            // Log scale: one mark per decade and a half, at least one.
            ((count as f64).log10() * 6.0).ceil().max(1.0) as usize
        };
        let label = if upper == u64::MAX {
            "10000+ us".to_owned()
        } else {
            format!("< {upper} us")
        };
        let _ = writeln!(
            t,
            "    {label:>10} {count:>9} {:>6.2} % {}",
            100.0 * count as f64 / total as f64,
            "#".repeat(bar)
        );
    }
}

/// USS's rules at each fast rate (and the bus's own), against the worst wake-up.
fn rates(t: &mut String, m: &Measured) {
    let max = m.max_us();
    let _ = writeln!(
        t,
        "  USS timing against the worst wake-up ({max:.1} us late; USS.md section 4):"
    );
    let _ = writeln!(
        t,
        "    {:>7}  {:<26} {:<26} 31-drive cycle",
        "baud", "start pause (2 tz)", "residual slack (7.5 tz)"
    );
    let rule = |r: Rule| {
        format!(
            "{:>7.1} us: {} {:+.0} us",
            r.allowed_us,
            if r.holds() { "holds" } else { "FAILS" },
            r.margin_us
        )
    };
    let mut rates = RATES.to_vec();
    if !rates.contains(&m.baud.get()) {
        rates.push(m.baud.get());
        rates.sort_unstable();
    }
    for baud in rates {
        let Some(at) = AtRate::of(baud, max) else {
            continue;
        };
        let mark = if baud == m.baud.get() { "*" } else { " " };
        let _ = writeln!(
            t,
            "   {mark}{baud:>7}  {:<26} {:<26} {:.1} ms +{:.1} %: {}",
            rule(at.start_pause),
            rule(at.residual),
            at.cycle_ms,
            100.0 * at.cycle_growth,
            if at.cycle_holds() { "holds" } else { "FAILS" }
        );
    }
}

/// The verdict at the bus's own rate, and what to do when it does not hold.
fn verdict(t: &mut String, m: &Measured) {
    let max = m.max_us();
    let _ = match m.at_own_rate() {
        Some(at) if at.holds() && m.report.is_full_rt() => writeln!(
            t,
            "  verdict: this machine holds bus {}'s timing at {} baud (start pause margin {:.0} us)",
            m.bus,
            m.baud.get(),
            at.start_pause.margin_us
        ),
        Some(at) if at.holds() => writeln!(
            t,
            "  verdict: the timing held, but without full real time ({}): it may not hold under \
             load; fix what is marked below",
            m.report.mode()
        ),
        _ => writeln!(
            t,
            "  verdict: this machine does NOT hold bus {}'s timing at {} baud: wake-ups up to \
             {max:.0} us late; isolate the bus's CPU (isolcpus, nohz_full), run a PREEMPT_RT \
             kernel (Debian's linux-image-rt), keep other real-time work below priority {}, or \
             run the line at a lower rate",
            m.bus,
            m.baud.get(),
            m.request.priority
        ),
    };
}

/// Bins of the plot: each 10 % wider than the one before, from 1 µs (a linear axis of 1 µs bins
/// squeezed the wake-ups, most within tens of µs, against zero beside a start pause of
/// milliseconds). Each item: the bin's upper end (µs) and its wake-ups.
fn log_bins(latency: &Histogram<u64>) -> impl Iterator<Item = (f64, u64)> + '_ {
    latency
        .iter_log(1000, 1.1)
        .filter(|v| v.count_since_last_iteration() > 0)
        .map(|v| {
            (
                (v.value_iterated_to() as f64 / 1e3).max(1.0),
                v.count_since_last_iteration(),
            )
        })
}

/// Draws the histograms (wake-ups per bin, bins 10 % wide from 1 µs, both axes logarithmic,
/// up to the worst) and each bus's start pause at its rate into an SVG file.
pub fn plot(path: &Path, measured: &[Measured]) -> Result<(), String> {
    use plotters::prelude::*;
    static FONTS: std::sync::Once = std::sync::Once::new();
    FONTS.call_once(|| {
        // The built-in font is valid; a failure would only leave text out.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            dejavu::sans::regular(),
        );
    });
    let failed = |e: &dyn core::fmt::Display| format!("{}: {e}", path.display());
    let root = SVGBackend::new(path, (1200, 700)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| failed(&e))?;
    let pause_us = |m: &Measured| Timing::new(m.baud).start_pause().as_secs_f64() * 1e6;
    let max_us = measured
        .iter()
        .map(|m| m.max_us().max(pause_us(m)))
        .fold(10.0, f64::max)
        * 1.5;
    // The count axis up to the next power of ten above the fullest bin.
    let fullest = measured
        .iter()
        .flat_map(|m| log_bins(&m.latency).map(|(_, n)| n))
        .max()
        .unwrap_or(1);
    let top = 10u64.pow(fullest.max(1).ilog10() + 1);
    let mut chart = ChartBuilder::on(&root)
        .caption("ussd --qualify: wake-up latency", ("sans-serif", 28))
        .margin(20)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d((1.0..max_us).log_scale(), (1u64..top).log_scale())
        .map_err(|e| failed(&e))?;
    chart
        .configure_mesh()
        .x_desc("wake-up latency (us, log scale)")
        .x_label_formatter(&|us| format!("{us:.0}"))
        .y_desc("wake-ups per bin (bins 10 % wide)")
        .label_style(("sans-serif", 16))
        .draw()
        .map_err(|e| failed(&e))?;
    let colours = [BLUE, RED, GREEN, MAGENTA];
    for (i, m) in measured.iter().enumerate() {
        let colour = colours[i % colours.len()];
        let bins = log_bins(&m.latency);
        chart
            .draw_series(bins.map(|(x, n)| Circle::new((x, n), 2, colour.filled())))
            .map_err(|e| failed(&e))?
            .label(format!(
                "bus {} (p99 {:.1} us, max {:.1} us)",
                m.bus,
                m.us(0.99),
                m.max_us()
            ))
            .legend(move |(x, y)| Circle::new((x, y), 4, colour.filled()));
        let pause = pause_us(m);
        chart
            .draw_series(LineSeries::new(
                [(pause, 1u64), (pause, top)],
                colour.stroke_width(2),
            ))
            .map_err(|e| failed(&e))?
            .label(format!(
                "start pause at {} baud: {pause:.0} us",
                m.baud.get()
            ))
            .legend(move |(x, y)| PathElement::new([(x - 10, y), (x + 10, y)], colour));
    }
    chart
        .configure_series_labels()
        .label_font(("sans-serif", 16))
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| failed(&e))?;
    root.present().map_err(|e| failed(&e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_lists_read_as_the_kernel_writes_them() {
        assert_eq!(cpu_list("1-3,5\n"), [1, 2, 3, 5]);
        assert_eq!(cpu_list("\n"), Vec::<usize>::new());
        assert_eq!(cpu_list("0"), [0]);
    }

    /// At 187500 baud the start pause is 117 us (USS.md section 4): 100 us late holds, 150 us
    /// does not; the residual slack of a 16-byte reply is 7.5 tz (440 us).
    #[test]
    fn the_rules_hold_up_to_their_allowance() {
        let fast = AtRate::of(187_500, 100.0).unwrap();
        assert!(
            (fast.start_pause.allowed_us - 117.3).abs() < 0.1,
            "{fast:?}"
        );
        assert!(fast.start_pause.holds() && fast.residual.holds());
        assert!((fast.residual.allowed_us - 440.0).abs() < 0.1, "{fast:?}");
        let late = AtRate::of(187_500, 150.0).unwrap();
        assert!(!late.start_pause.holds() && late.residual.holds() && !late.holds());
        // A full line at 9600 baud takes over a second: 150 us more per exchange is nothing.
        let slow = AtRate::of(9600, 150.0).unwrap();
        assert!(slow.holds() && slow.cycle_growth < 0.01, "{slow:?}");
    }

    /// Issue 47, item 5: the plot's bins are 10 % wide from 1 µs, so wake-ups of a few µs and a
    /// stall of milliseconds both stand apart (a linear axis of 1 µs bins put them at zero);
    /// every wake-up is in one bin.
    #[test]
    fn the_plot_bins_keep_every_wake_up_apart_on_a_log_axis() {
        let mut h = Histogram::<u64>::new_with_bounds(1, 10_000_000_000, 3).unwrap();
        h.record_n(3_000, 1000).unwrap();
        h.record_n(50_000, 10).unwrap();
        h.record(4_000_000).unwrap();
        let bins: Vec<_> = log_bins(&h).collect();
        assert_eq!(bins.iter().map(|b| b.1).sum::<u64>(), 1011, "{bins:?}");
        assert_eq!(bins.len(), 3, "{bins:?}");
        let ends: Vec<f64> = bins.iter().map(|b| b.0).collect();
        assert!((3.0..3.4).contains(&ends[0]), "{ends:?}");
        assert!((50.0..55.1).contains(&ends[1]), "{ends:?}");
        assert!((4000.0..4400.1).contains(&ends[2]), "{ends:?}");
    }
}
