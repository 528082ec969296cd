//! `uss-exporter` against a real ussd: scraped over HTTP, parsed, checked with `promtool check
//! metrics` (CI installs it and sets `USS_REQUIRE_PROMTOOL`), and still serving while ussd is
//! killed and restarted, which its metrics say; the safety events of a drive (releases, operator
//! stops, refused samples) counted.

#![allow(clippy::unwrap_used, clippy::float_cmp)]

use std::collections::HashMap;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use uss_client::{ControlOptions, StopCommand};
use uss_integration_tests::{ChildProc, Ussd, binary};

/// One scrape: the body, sent as `OpenMetrics` when `openmetrics`, else the classic format.
fn scrape(addr: &str, openmetrics: bool) -> String {
    let mut s = TcpStream::connect(addr).unwrap();
    let accept = if openmetrics {
        "Accept: application/openmetrics-text; version=1.0.0\r\n"
    } else {
        ""
    };
    write!(s, "GET /metrics HTTP/1.0\r\nHost: {addr}\r\n{accept}\r\n").unwrap();
    let mut response = String::new();
    s.read_to_string(&mut response).unwrap();
    let (head, body) = response.split_once("\r\n\r\n").unwrap();
    assert!(
        head.starts_with("HTTP/1.0 200") || head.starts_with("HTTP/1.1 200"),
        "{head}"
    );
    let expected = if openmetrics {
        "application/openmetrics-text"
    } else {
        "text/plain; version=0.0.4"
    };
    assert!(head.contains(expected), "{head}");
    body.to_owned()
}

/// Samples by name with labels as written (`uss_drive_online{bus="b",drive="1"}`).
fn samples(body: &str) -> HashMap<String, f64> {
    body.lines()
        .filter(|l| !l.starts_with('#') && !l.is_empty())
        .map(|l| {
            let (name, value) = l.rsplit_once(' ').unwrap();
            (name.to_owned(), value.parse().unwrap())
        })
        .collect()
}

fn wait_for(
    addr: &str,
    what: &str,
    ok: impl Fn(&HashMap<String, f64>) -> bool,
) -> HashMap<String, f64> {
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let s = samples(&scrape(addr, true));
        if ok(&s) {
            return s;
        }
        assert!(Instant::now() < deadline, "no scrape showed {what}: {s:?}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn exporter_serves_metrics_that_promtool_accepts_and_follows_a_restarted_ussd() {
    // Drive 2 loses a tenth of its replies; a poll fails only when three exchanges in a row are
    // lost (1 in 1000), and with offline_after = 5 the drive stays online through one such poll, so
    // "online" below is a fact about the exporter, not a bet on the random drops.
    // Drive 3 watches its telegrams (100 ms) and is unplugged for half a second: it trips
    // (F0072) and answers again in fault.
    let mut ussd = Ussd::start(
        "offline_after = 5",
        &[
            (1, ""),
            (2, "sim = { drop = 0.1 }"),
            (3, "sim = { p2014 = 100, unplug = \"300..800\" }"),
        ],
    );
    let bus = ussd.bus.clone();
    let mut command = Command::new(binary("uss-exporter", "uss-exporter"));
    command.args(["--bus", &bus, "--listen", "127.0.0.1:0"]);
    let mut exporter = ChildProc::spawn("uss-exporter".into(), command);
    let addr = exporter
        .says("serving http://")
        .trim_end_matches("/metrics")
        .to_owned();

    let up = |s: &HashMap<String, f64>| s.get(&format!("uss_ussd_up{{bus=\"{bus}\"}}")).copied();
    let s = wait_for(&addr, "drive 2's lost replies", |s| {
        s.get(&format!(
            "uss_telegrams_total{{bus=\"{bus}\",drive=\"2\",result=\"no_response\"}}"
        ))
        .is_some_and(|&n| n > 0.0)
    });
    assert_eq!(up(&s), Some(1.0));
    assert_eq!(s["uss_build_info{version=\"0.1.0\"}"], 1.0);
    for drive in ["1", "2"] {
        assert_eq!(
            s[&format!("uss_drive_online{{bus=\"{bus}\",drive=\"{drive}\"}}")],
            1.0,
            "drive {drive}: {s:?}"
        );
        assert!(
            s[&format!("uss_telegrams_total{{bus=\"{bus}\",drive=\"{drive}\",result=\"good\"}}")]
                > 0.0
        );
    }
    assert!(s[&format!("uss_retries_total{{bus=\"{bus}\",drive=\"2\"}}")] > 0.0);
    states_and_faults(&addr, &bus, &s);
    // The exchange-time histogram: cumulative buckets, +Inf is the count, the sum plausible.
    let bucket =
        |le: &str| s[&format!("uss_exchange_duration_seconds_bucket{{bus=\"{bus}\",le=\"{le}\"}}")];
    let count = s[&format!("uss_exchange_duration_seconds_count{{bus=\"{bus}\"}}")];
    let sum = s[&format!("uss_exchange_duration_seconds_sum{{bus=\"{bus}\"}}")];
    assert!(count > 0.0);
    assert_eq!(bucket("+Inf"), count);
    let les = [
        "0.0005", "0.001", "0.002", "0.003", "0.005", "0.0075", "0.01", "0.02", "0.05", "0.1",
        "0.25", "1.0",
    ];
    assert!(
        les.windows(2).all(|w| bucket(w[0]) <= bucket(w[1])),
        "{s:?}"
    );
    // At 115200 baud an exchange of PKW 4 + PZD 2 takes about 3 ms, with the 1 ms reply delay.
    let mean = sum / count;
    assert!((0.001..0.02).contains(&mean), "mean exchange {mean} s");

    // The safety events of drive 1: a controller that re-arms it and hands it back cleanly,
    // then an operator's stop; no sample of it was refused.
    let drive1 = |s: &HashMap<String, f64>, name: &str| {
        s.get(&format!("{name}{{bus=\"{bus}\",drive=\"1\"}}"))
            .copied()
    };
    assert_eq!(drive1(&s, "uss_overrides_total"), Some(0.0));
    let client = ussd.bus();
    let c = client
        .control(uss_integration_tests::addr(1), ControlOptions::default())
        .unwrap();
    let refresh = c.spawn_refresher(Duration::from_millis(20));
    c.rearm(uss_client::monotonic_ns()).unwrap();
    drop(refresh);
    c.release().unwrap();
    client
        .stop_drive(uss_integration_tests::addr(1), StopCommand::Off1)
        .unwrap();
    let s = wait_for(&addr, "drive 1's release and operator stop", |s| {
        drive1(s, "uss_overrides_total") == Some(1.0)
            && drive1(s, "uss_releases_total") == Some(1.0)
    });
    assert_eq!(drive1(&s, "uss_refused_samples_total"), Some(0.0));

    let body = scrape(&addr, false);
    promtool(&body);
    shipped_monitoring_names_only_these(&body);
    // Drive 3's own telegram monitoring as ussd read it: 100 ms.
    assert_eq!(
        s[&format!("uss_drive_monitoring_seconds{{bus=\"{bus}\",drive=\"3\"}}")],
        0.1
    );

    // ussd killed: the exporter keeps serving and says so; restarted: it counts the restart.
    ussd.kill();
    wait_for(&addr, "ussd gone", |s| up(s) == Some(0.0));
    ussd.restart();
    let s = wait_for(&addr, "the restarted ussd", |s| up(s) == Some(1.0));
    assert_eq!(s[&format!("uss_ussd_restarts_total{{bus=\"{bus}\"}}")], 1.0);
    exporter.kill();
}

/// Each drive's state from its ZSW1: drive 1 in S2, without fault or warning; drive 3 in the
/// fault its telegram monitoring tripped (issue 46, item 6: no state or fault metrics).
fn states_and_faults(addr: &str, bus: &str, s: &HashMap<String, f64>) {
    let state = |s: &HashMap<String, f64>, drive: &str, state: &str| {
        s.get(&format!(
            "uss_drive_state{{bus=\"{bus}\",drive=\"{drive}\",state=\"{state}\"}}"
        ))
        .copied()
    };
    assert_eq!(state(s, "1", "S2"), Some(1.0), "{s:?}");
    assert_eq!(state(s, "1", "S4"), Some(0.0));
    assert_eq!(state(s, "1", "unknown"), Some(0.0));
    assert_eq!(
        s[&format!("uss_drive_fault{{bus=\"{bus}\",drive=\"1\"}}")],
        0.0
    );
    assert_eq!(
        s[&format!("uss_drive_warning{{bus=\"{bus}\",drive=\"1\"}}")],
        0.0
    );
    let s = wait_for(addr, "drive 3's fault", |s| {
        state(s, "3", "fault") == Some(1.0)
            && s.get(&format!("uss_drive_fault{{bus=\"{bus}\",drive=\"3\"}}")) == Some(&1.0)
    });
    assert_eq!(state(&s, "3", "S2"), Some(0.0));
}

/// Issue 47, item 6: the Prometheus scrape configuration, alert rules and Grafana dashboard
/// uss-rt ships (`deploy/prometheus`, `deploy/grafana`): promtool takes the configuration and
/// passes the rules' own tests, and every metric they name is one this exporter serves (`body`,
/// a real scrape).
fn shipped_monitoring_names_only_these(body: &str) {
    let served: std::collections::BTreeSet<&str> = body
        .lines()
        .filter(|l| !l.starts_with('#') && !l.is_empty())
        .filter_map(|l| l.split(['{', ' ']).next())
        .collect();
    let deploy = uss_integration_tests::root().join("deploy");
    let mut named = std::collections::BTreeMap::new();
    for file in [
        "prometheus/uss-rt-alerts.yml",
        "prometheus/uss-rt-alerts.test.yml",
        "grafana/uss-rt-dashboard.json",
    ] {
        let text = std::fs::read_to_string(deploy.join(file)).unwrap();
        for (at, _) in text.match_indices("uss_") {
            let name: String = text[at..]
                .chars()
                .take_while(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || *c == '_')
                .collect();
            // Words of the texts that are no metric: uss_vfd, the uss-rt names.
            if name.len() > 6 {
                named.entry(name).or_insert(file);
            }
        }
    }
    assert!(named.len() >= 10, "{named:?}");
    let unknown: Vec<String> = named
        .iter()
        .filter(|(name, _)| !served.contains(name.as_str()))
        .map(|(name, file)| format!("{file}: {name}"))
        .collect();
    assert!(
        unknown.is_empty(),
        "named in deploy/, not served by uss-exporter: {unknown:?}\nserved: {served:?}"
    );
    for args in [
        &["check", "config", "prometheus.yml"][..],
        &["test", "rules", "uss-rt-alerts.test.yml"],
    ] {
        let out = match Command::new("promtool")
            .args(args)
            .current_dir(deploy.join("prometheus"))
            .output()
        {
            Ok(out) => out,
            Err(e) if std::env::var_os("USS_REQUIRE_PROMTOOL").is_none() => {
                println!("SKIPPED promtool {args:?}: promtool does not run ({e})");
                return;
            }
            Err(e) => panic!("promtool does not run ({e}) but USS_REQUIRE_PROMTOOL is set"),
        };
        assert!(
            out.status.success(),
            "promtool {args:?}: {}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

/// `promtool check metrics` on the classic text format. Without promtool the check says so;
/// CI installs it and sets `USS_REQUIRE_PROMTOOL`, so there it cannot be skipped.
fn promtool(body: &str) {
    let run = Command::new("promtool")
        .args(["check", "metrics"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn();
    let mut child = match run {
        Ok(child) => child,
        Err(e) if std::env::var_os("USS_REQUIRE_PROMTOOL").is_none() => {
            eprintln!(
                "SKIPPED promtool check metrics: promtool does not run ({e}); install it with `apt-get install prometheus`"
            );
            return;
        }
        Err(e) => panic!("promtool does not run ({e}) but USS_REQUIRE_PROMTOOL is set"),
    };
    child
        .stdin
        .take()
        .unwrap()
        .write_all(body.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "promtool check metrics: {}{}\n{body}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
