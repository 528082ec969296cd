//! `uss-exporter`: the buses a ussd runs as Prometheus metrics, at `http://ADDR:PORT/metrics` in
//! the `OpenMetrics` text format. A separate, non-real-time process: it reads ussd's status and
//! diagnostics services like any client, keeps serving while ussd is gone or restarts (and says
//! so in `uss_ussd_up` and `uss_ussd_restarts_total`), and never touches the bus threads.

use clap::Parser;
use prometheus_client::encoding::{EncodeLabelSet, EncodeMetric, MetricEncoder, text::encode};
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::{MetricType, TypedMetric};
use prometheus_client::registry::{Registry, Unit};
use std::io::Write as _;
use std::process::ExitCode;
use std::sync::atomic::AtomicU64;
use uss_client::uss_shm_types::{BusStatus, DriveDiag, EXCHANGE_BUCKETS_NS};
use uss_client::{Bus, ControlState, DriveState, Health, Monitoring, Zsw1};

#[derive(Debug, Parser)]
#[command(
    name = "uss-exporter",
    version,
    about = "Serve the metrics of the buses a ussd runs for Prometheus (GET /metrics)"
)]
struct Cli {
    /// A bus to export, as named in ussd's configuration; repeat for more.
    #[arg(long = "bus", value_name = "NAME", default_value = "bus0")]
    buses: Vec<String>,
    /// Where to listen; loopback unless you mean otherwise.
    #[arg(long, value_name = "ADDR:PORT", default_value = "127.0.0.1:9781")]
    listen: String,
    /// Print the man page (roff) and exit.
    #[arg(long)]
    man: bool,
}

/// What the exporter remembers of a bus between scrapes.
struct Exported {
    name: String,
    bus: Option<Bus>,
    /// The process of the ussd seen last, to count restarts.
    pid: Option<u32>,
    restarts: u64,
}

impl Exported {
    /// The bus, opened on first need (ussd may start after the exporter).
    fn bus(&mut self) -> Option<&Bus> {
        if self.bus.is_none() {
            self.bus = Bus::open_as(&self.name, "uss-exporter").ok();
        }
        self.bus.as_ref()
    }
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct BuildLabels {
    version: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct BusLabels {
    bus: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct DriveLabels {
    bus: String,
    drive: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct StateLabels {
    bus: String,
    drive: String,
    state: &'static str,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct TelegramLabels {
    bus: String,
    drive: String,
    result: &'static str,
}

/// A histogram ussd already counted (its buckets are cumulative counts at fixed bounds).
#[derive(Debug)]
struct CountedHistogram {
    sum_seconds: f64,
    count: u64,
    /// (upper bound in seconds, cumulative count), ascending.
    le: Vec<(f64, u64)>,
}

impl TypedMetric for CountedHistogram {
    const TYPE: MetricType = MetricType::Histogram;
}

impl EncodeMetric for CountedHistogram {
    fn encode(&self, mut encoder: MetricEncoder) -> Result<(), std::fmt::Error> {
        // The encoder takes each bucket's own count and adds them up.
        let mut buckets = Vec::with_capacity(self.le.len() + 1);
        let mut below = 0;
        for &(bound, cumulative) in &self.le {
            buckets.push((bound, cumulative.saturating_sub(below)));
            below = cumulative;
        }
        buckets.push((f64::MAX, self.count.saturating_sub(below)));
        encoder.encode_histogram::<prometheus_client::encoding::NoLabelSet>(
            self.sum_seconds,
            self.count,
            &buckets,
            None,
        )
    }

    fn metric_type(&self) -> MetricType {
        Self::TYPE
    }
}

/// What each drive's status word ZSW1 says: its state, fault and warning.
fn register_state(
    r: &mut Registry,
    state: Family<StateLabels, Gauge>,
    fault: Family<DriveLabels, Gauge>,
    warning: Family<DriveLabels, Gauge>,
) {
    r.register(
        "uss_drive_state",
        "1 for the PROFIdrive state the drive's status word ZSW1 shows (S1..S4, fault, not ready); unknown while it is offline, its reply stale or it has no process data",
        state,
    );
    r.register(
        "uss_drive_fault",
        "1 while the drive's ZSW1 shows a fault (bit 3: `ussctl faults` names it), 0 without; -1 while not known (offline, stale, no process data)",
        fault,
    );
    r.register(
        "uss_drive_warning",
        "1 while the drive's ZSW1 shows a warning (bit 7: `ussctl faults` names it), 0 without; -1 while not known (offline, stale, no process data)",
        warning,
    );
}

/// The metric families of one scrape.
struct Metrics {
    ussd_up: Family<BusLabels, Gauge>,
    restarts: Family<BusLabels, Counter>,
    line_up: Family<BusLabels, Gauge>,
    exchanges: Family<BusLabels, Counter>,
    cycles: Family<BusLabels, Counter>,
    efficiency: Family<BusLabels, Gauge<f64, AtomicU64>>,
    online: Family<DriveLabels, Gauge>,
    stale: Family<DriveLabels, Gauge>,
    period: Family<DriveLabels, Gauge<f64, AtomicU64>>,
    latched: Family<DriveLabels, Gauge>,
    monitoring_ok: Family<DriveLabels, Gauge>,
    monitoring_seconds: Family<DriveLabels, Gauge<f64, AtomicU64>>,
    state: Family<StateLabels, Gauge>,
    fault: Family<DriveLabels, Gauge>,
    warning: Family<DriveLabels, Gauge>,
    telegrams: Family<TelegramLabels, Counter>,
    retries: Family<DriveLabels, Counter>,
    watchdog_trips: Family<DriveLabels, Counter>,
    replacements: Family<DriveLabels, Counter>,
    latches: Family<DriveLabels, Counter>,
    refused_samples: Family<DriveLabels, Counter>,
    overrides: Family<DriveLabels, Counter>,
    releases: Family<DriveLabels, Counter>,
}

impl Metrics {
    fn new() -> Self {
        Self {
            ussd_up: Family::default(),
            restarts: Family::default(),
            line_up: Family::default(),
            exchanges: Family::default(),
            cycles: Family::default(),
            efficiency: Family::default(),
            online: Family::default(),
            stale: Family::default(),
            period: Family::default(),
            latched: Family::default(),
            monitoring_ok: Family::default(),
            monitoring_seconds: Family::default(),
            state: Family::default(),
            fault: Family::default(),
            warning: Family::default(),
            telegrams: Family::default(),
            retries: Family::default(),
            watchdog_trips: Family::default(),
            replacements: Family::default(),
            latches: Family::default(),
            refused_samples: Family::default(),
            overrides: Family::default(),
            releases: Family::default(),
        }
    }

    fn register(self, registry: &mut Registry) {
        let r = registry;
        r.register(
            "uss_ussd_up",
            "1 while a ussd serves the bus (its heartbeat is fresh)",
            self.ussd_up,
        );
        r.register(
            "uss_ussd_restarts",
            "Restarts of ussd seen by this exporter",
            self.restarts,
        );
        r.register("uss_line_up", "1 while the bus line is up", self.line_up);
        r.register(
            "uss_exchanges",
            "Exchanges (request and reply) on the bus",
            self.exchanges,
        );
        r.register(
            "uss_cycles",
            "Passes through the circulating list",
            self.cycles,
        );
        r.register(
            "uss_efficiency_ratio",
            "Wire-time floor over achieved exchange time (1 = the master adds nothing)",
            self.efficiency,
        );
        r.register(
            "uss_drive_online",
            "1 while the drive answers and its poll is not overdue",
            self.online,
        );
        r.register(
            "uss_drive_stale",
            "1 while the drive's last reply is older than ussd's limit for it (a stalled bus thread)",
            self.stale,
        );
        r.register(
            "uss_drive_poll_period_seconds",
            "How often ussd polls the drive now (0: not known yet)",
            self.period,
        );
        r.register(
            "uss_drive_latched",
            "1 while the drive gets its safe command until its controller re-arms",
            self.latched,
        );
        r.register(
            "uss_drive_monitoring_ok",
            "1 while the drive's own telegram monitoring (P2014[0], p2040) is on within its limits, 0 while it is off, too long, too short or unreadable (nothing stops the drive when ussd or its line dies), -1 not read yet or not checked",
            self.monitoring_ok,
        );
        r.register(
            "uss_drive_monitoring_seconds",
            "The drive's telegram-off time as ussd read it (0: off or not read)",
            self.monitoring_seconds,
        );
        register_state(r, self.state, self.fault, self.warning);
        r.register(
            "uss_telegrams",
            "Replies by result: good, or why the attempt failed",
            self.telegrams,
        );
        r.register(
            "uss_retries",
            "Attempts repeated after a failure",
            self.retries,
        );
        r.register(
            "uss_watchdog_trips",
            "Times the controller did not refresh within its watchdog time",
            self.watchdog_trips,
        );
        r.register(
            "uss_controller_replacements",
            "Times another controller took the place of the one a live drive ran under, without a release (a trip)",
            self.replacements,
        );
        r.register(
            "uss_latches",
            "Times the drive latched its safe command",
            self.latches,
        );
        r.register(
            "uss_refused_samples",
            "Controller samples refused before the wire (each latches the drive)",
            self.refused_samples,
        );
        r.register(
            "uss_overrides",
            "Operator stops (OFF1, OFF2, OFF3) applied to the drive",
            self.overrides,
        );
        r.register(
            "uss_releases",
            "Clean hand-backs of the drive by its controller",
            self.releases,
        );
    }

    fn bus(&self, labels: &BusLabels, s: &BusStatus) {
        self.line_up
            .get_or_create(labels)
            .set(i64::from(!s.is_line_down()));
        self.exchanges.get_or_create(labels).inc_by(s.exchanges);
        self.cycles.get_or_create(labels).inc_by(s.cycles);
        if let Some(efficiency) = s.efficiency() {
            self.efficiency.get_or_create(labels).set(efficiency);
        }
    }

    fn drive(&self, bus: &str, d: &DriveDiag, pzd_words: u8) {
        let labels = DriveLabels {
            bus: bus.to_owned(),
            drive: d.address.to_string(),
        };
        let c = &d.counters;
        let now = uss_client::monotonic_ns();
        // What ZSW1 says, only while it is the drive's word of now: a stale or offline drive's
        // last word is no picture of it.
        let zsw1 = (pzd_words > 0 && d.is_online_at(now) && !d.is_overdue(now))
            .then(|| Zsw1::from_bits_retain(d.last_zsw1));
        let shown = zsw1.map(DriveState::from_zsw1);
        let states = DriveState::ALL
            .into_iter()
            .map(|s| (s.short_name(), shown == Some(s)))
            .chain([("unknown", shown.is_none())]);
        for (state, is) in states {
            self.state
                .get_or_create(&StateLabels {
                    bus: bus.to_owned(),
                    drive: labels.drive.clone(),
                    state,
                })
                .set(i64::from(is));
        }
        let bit = |b: Zsw1| zsw1.map_or(-1, |z| i64::from(z.contains(b)));
        let monitoring = match d.monitoring() {
            Ok(Monitoring::On) => 1,
            Ok(Monitoring::Unknown | Monitoring::NotChecked) | Err(_) => -1,
            Ok(_) => 0,
        };
        self.monitoring_ok.get_or_create(&labels).set(monitoring);
        self.monitoring_seconds
            .get_or_create(&labels)
            .set(f64::from(d.monitoring_ms) / 1000.0);
        self.fault.get_or_create(&labels).set(bit(Zsw1::FAULT));
        self.warning.get_or_create(&labels).set(bit(Zsw1::WARNING));
        self.online
            .get_or_create(&labels)
            .set(i64::from(d.is_online_at(now)));
        self.stale
            .get_or_create(&labels)
            .set(i64::from(d.is_overdue(now)));
        self.period
            .get_or_create(&labels)
            .set(d.period_ns as f64 / 1e9);
        self.latched
            .get_or_create(&labels)
            .set(i64::from(d.control == ControlState::Latched.code()));
        for (result, n) in [
            ("good", c.good),
            ("no_response", c.timeouts),
            ("missing_stx", c.missing_stx),
            ("start_pause", c.start_pause),
            ("bad_lge", c.bad_lge),
            ("bcc", c.bcc),
            ("residual", c.residual),
            ("length", c.length),
            ("wrong_address", c.wrong_address),
            ("parity", c.parity),
            ("framing", c.framing),
            ("overrun", c.overrun),
            ("echo", c.echo),
        ] {
            self.telegrams
                .get_or_create(&TelegramLabels {
                    bus: bus.to_owned(),
                    drive: labels.drive.clone(),
                    result,
                })
                .inc_by(n);
        }
        self.retries.get_or_create(&labels).inc_by(c.retries);
        self.watchdog_trips
            .get_or_create(&labels)
            .inc_by(c.watchdog_trips);
        self.replacements
            .get_or_create(&labels)
            .inc_by(c.replacements);
        self.latches.get_or_create(&labels).inc_by(c.latches);
        self.refused_samples
            .get_or_create(&labels)
            .inc_by(c.rejected_outputs);
        self.overrides.get_or_create(&labels).inc_by(c.overrides);
        self.releases.get_or_create(&labels).inc_by(c.releases);
    }
}

/// One scrape: every bus as it is now.
fn scrape(buses: &mut [Exported]) -> String {
    let mut registry = Registry::default();
    // An OpenMetrics info metric as a gauge of 1: `promtool check metrics` reads the classic
    // text format, which has no info type.
    let build: Family<BuildLabels, Gauge> = Family::default();
    build
        .get_or_create(&BuildLabels {
            version: env!("CARGO_PKG_VERSION"),
        })
        .set(1);
    registry.register("uss_build_info", "The exporter's version", build);
    let metrics = Metrics::new();
    let mut histograms = Vec::new();
    for e in buses.iter_mut() {
        let labels = BusLabels {
            bus: e.name.clone(),
        };
        let name = e.name.clone();
        let Some(bus) = e.bus() else {
            metrics.ussd_up.get_or_create(&labels).set(0);
            metrics.restarts.get_or_create(&labels).inc_by(e.restarts);
            continue;
        };
        let pid = match bus.health() {
            Health::Running { pid } | Health::LineDown { pid, .. } => Some(pid),
            Health::Stopped { .. } | Health::Gone { .. } => None,
        };
        let status = pid.and_then(|_| bus.status().ok());
        // Each drive's diagnostics, with its PZD length (whether its ZSW1 says anything).
        let diags: Vec<(DriveDiag, u8)> = bus
            .drives()
            .into_iter()
            .filter_map(|a| {
                let pzd_words = bus.watch(a).map_or(0, |w| w.info().pzd_words);
                bus.diag(a).ok().map(|d| (d, pzd_words))
            })
            .collect();
        if let (Some(pid), Some(before)) = (pid, e.pid)
            && pid != before
        {
            e.restarts += 1;
        }
        if pid.is_some() {
            e.pid = pid;
        }
        metrics
            .ussd_up
            .get_or_create(&labels)
            .set(i64::from(status.is_some()));
        metrics.restarts.get_or_create(&labels).inc_by(e.restarts);
        let Some(status) = status else {
            continue;
        };
        metrics.bus(&labels, &status);
        for (d, pzd_words) in &diags {
            metrics.drive(&name, d, *pzd_words);
        }
        histograms.push((name, exchange_histogram(&status)));
    }
    metrics.register(&mut registry);
    for (bus, h) in histograms {
        registry
            .sub_registry_with_label(("bus".into(), bus.into()))
            .register_with_unit(
                "uss_exchange_duration",
                "Exchange time: line free to reply complete",
                Unit::Seconds,
                h,
            );
    }
    let mut text = String::new();
    // Writing into a String cannot fail.
    let _ = encode(&mut text, &registry);
    text
}

fn exchange_histogram(s: &BusStatus) -> CountedHistogram {
    CountedHistogram {
        sum_seconds: s.exchange_sum_ns as f64 / 1e9,
        count: s.exchange_count,
        le: EXCHANGE_BUCKETS_NS
            .iter()
            .zip(s.exchange_le)
            .map(|(&ns, n)| (ns as f64 / 1e9, n))
            .collect(),
    }
}

const OPENMETRICS: &[u8] = b"application/openmetrics-text; version=1.0.0; charset=utf-8";
const CLASSIC: &[u8] = b"text/plain; version=0.0.4; charset=utf-8";

/// The classic Prometheus text format (0.0.4) of an `OpenMetrics` exposition: a counter's family
/// takes its samples' `_total` name, and there are no `# UNIT` and `# EOF` lines.
fn classic(openmetrics: &str) -> String {
    let lines: Vec<&str> = openmetrics.lines().collect();
    let counters: Vec<&str> = lines
        .iter()
        .filter_map(|l| l.strip_prefix("# TYPE ")?.strip_suffix(" counter"))
        .collect();
    let mut out = String::with_capacity(openmetrics.len() + 64 * counters.len());
    for line in lines {
        if line.starts_with("# UNIT ") || line == "# EOF" {
            continue;
        }
        let renamed = ["# HELP ", "# TYPE "].iter().find_map(|prefix| {
            let rest = line.strip_prefix(prefix)?;
            let (name, tail) = rest.split_once(' ')?;
            counters
                .contains(&name)
                .then(|| format!("{prefix}{name}_total {tail}"))
        });
        match renamed {
            Some(l) => out.push_str(&l),
            None => out.push_str(line),
        }
        out.push('\n');
    }
    out
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if cli.man {
        let mut page = Vec::new();
        let rendered = clap_mangen::Man::new(<Cli as clap::CommandFactory>::command())
            .render(&mut page)
            .and_then(|()| std::io::stdout().write_all(&page));
        return match rendered {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("uss-exporter: {e}");
                ExitCode::FAILURE
            }
        };
    }
    let server = match tiny_http::Server::http(&cli.listen) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("uss-exporter: cannot listen on {}: {e}", cli.listen);
            return ExitCode::FAILURE;
        }
    };
    let mut buses: Vec<Exported> = cli
        .buses
        .iter()
        .map(|name| Exported {
            name: name.clone(),
            bus: None,
            pid: None,
            restarts: 0,
        })
        .collect();
    // The address as bound (port 0 picks a free one), for whoever started us; a reader of
    // stdout that went away is no reason not to serve.
    let _ = match server.server_addr().to_ip() {
        Some(addr) => writeln!(
            std::io::stdout(),
            "uss-exporter: serving http://{addr}/metrics"
        ),
        None => writeln!(std::io::stdout(), "uss-exporter: serving /metrics"),
    };
    for request in server.incoming_requests() {
        let response = if request.url() == "/metrics" {
            // Prometheus asks for OpenMetrics; anything else (curl, promtool) gets the classic
            // text format.
            let openmetrics = request.headers().iter().any(|h| {
                h.field.equiv("Accept") && h.value.as_str().contains("application/openmetrics-text")
            });
            let text = scrape(&mut buses);
            let (body, content_type) = if openmetrics {
                (text, OPENMETRICS)
            } else {
                (classic(&text), CLASSIC)
            };
            let mut r = tiny_http::Response::from_string(body);
            if let Ok(h) = tiny_http::Header::from_bytes(&b"Content-Type"[..], content_type) {
                r.add_header(h);
            }
            r
        } else {
            tiny_http::Response::from_string("uss-exporter: GET /metrics\n").with_status_code(404)
        };
        let _ = request.respond(response);
    }
    ExitCode::SUCCESS
}
