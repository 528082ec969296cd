//! `ussctl trace` against a real ussd with simulated drives: the CSV of a ramp from a trigger
//! on, and the picture rendered from it (PNG decoded and looked at; SVG read), and a fault
//! trigger on a drive that trips.

#![allow(clippy::unwrap_used, clippy::float_cmp)]

use std::collections::HashMap;
use std::path::PathBuf;
use uss_integration_tests::Ussd;

/// One CSV row by column name.
type Row = HashMap<String, String>;

fn read_csv(path: &PathBuf) -> Vec<Row> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_owned)
        .collect();
    lines
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            assert_eq!(cells.len(), header.len(), "{l}");
            header
                .iter()
                .cloned()
                .zip(cells.into_iter().map(str::to_owned))
                .collect()
        })
        .collect()
}

fn num(row: &Row, column: &str) -> f64 {
    row[column].parse().unwrap()
}

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("uss-trace-{}-{name}", std::process::id()))
}

/// The pixels of `png` close to `color`, as (x, y).
fn pixels_of(png: &PathBuf, color: [u8; 3]) -> (Vec<(u32, u32)>, (u32, u32)) {
    let decoder = png::Decoder::new(std::fs::File::open(png).unwrap());
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    let channels = info.color_type.samples();
    let mut found = Vec::new();
    for y in 0..info.height {
        for x in 0..info.width {
            let at = ((y * info.width + x) as usize) * channels;
            let px = &buf[at..at + 3];
            if px.iter().zip(color).all(|(&a, b)| a.abs_diff(b) <= 12) {
                found.push((x, y));
            }
        }
    }
    (found, (info.width, info.height))
}

#[test]
fn a_triggered_trace_records_the_ramp_and_plots_it() {
    let ussd = Ussd::start("", &[(1, ""), (2, "")]);
    let (csv, png, svg) = (temp("ramp.csv"), temp("ramp.png"), temp("ramp.svg"));
    let mut trace = ussd.ussctl(&[
        "trace",
        "1",
        "2",
        "--trigger",
        "hz>2",
        "--pre",
        "0.5s",
        "--for",
        "1.5s",
        "--wait",
        "20",
        "-o",
        csv.to_str().unwrap(),
        "--plot",
        png.to_str().unwrap(),
    ]);
    trace.says("waiting for the trigger hz>2");
    std::thread::sleep(std::time::Duration::from_millis(600));
    // Drive 1 runs up its ramp (P1120 10 s for 50 Hz: 5 Hz/s) towards 25 Hz.
    let mut run = ussd.ussctl(&["run", "1", "--hz", "25", "--for", "4"]);
    let (status, stdout, stderr) = trace.finish();
    assert!(status.success(), "{stdout}{stderr}");
    assert!(stdout.contains("from trigger hz>2 (time 0)"), "{stdout}");
    let rows = read_csv(&csv);
    let drive = |d: &'static str| rows.iter().filter(move |r| r["drive"] == d);
    // Time 0 is the first image of drive 1 above 2 Hz; the one before was not.
    let d1: Vec<&Row> = drive("1").collect();
    let at0 = d1.iter().position(|r| num(r, "t_s") == 0.0).unwrap();
    assert!(num(d1[at0], "actual_hz") > 2.0, "{:?}", d1[at0]);
    assert!(num(d1[at0 - 1], "actual_hz") <= 2.0, "{:?}", d1[at0 - 1]);
    // Half a second before it, 1.5 s after it; every image of the bus (none missed, or the
    // misses counted: the rows plus the misses account for every good reply).
    let first = num(d1[0], "t_s");
    let last = num(d1[d1.len() - 1], "t_s");
    assert!((-0.55..-0.4).contains(&first), "first row at {first}");
    assert!((1.4..1.55).contains(&last), "last row at {last}");
    let seen = d1.len() as f64 + d1.iter().map(|r| num(r, "missed")).sum::<f64>();
    let replies = num(d1[d1.len() - 1], "sequence") - num(d1[0], "sequence") + 1.0;
    assert_eq!(seen, replies);
    // The ramp: running (S4, live, setpoint 25 Hz), never slower than before, 5 Hz/s.
    for pair in d1[at0..].windows(2) {
        assert_eq!(pair[1]["state"], "S4");
        assert_eq!(pair[1]["control"], "live");
        assert_eq!(num(pair[1], "setpoint_hz"), 25.0);
        assert!(num(pair[1], "actual_hz") >= num(pair[0], "actual_hz") - 0.01);
    }
    let slope = (num(d1[d1.len() - 1], "actual_hz") - num(d1[at0], "actual_hz")) / last;
    assert!((4.0..6.0).contains(&slope), "ramp of {slope} Hz/s");
    // Drive 2, not run, stays in S2 at 0 Hz, and is recorded as often as drive 1.
    let d2: Vec<&Row> = drive("2").collect();
    assert!(
        d2.iter()
            .all(|r| r["state"] == "S2" && num(r, "actual_hz") == 0.0)
    );
    assert!(
        d2.len().abs_diff(d1.len()) <= 2 + d1.len() / 50,
        "{} {}",
        d1.len(),
        d2.len()
    );
    for r in &rows {
        assert!(
            u16::from_str_radix(&r["stw1"][2..], 16).unwrap() & 0x0400 != 0,
            "{r:?}"
        );
    }

    // The picture: 1200 x 800, drive 1's colour drawn, rising from left to right.
    let size = std::fs::metadata(&png).unwrap().len();
    assert!((20_000..2_000_000).contains(&size), "{size} bytes");
    let (red, dims) = pixels_of(&png, [230, 25, 75]);
    assert_eq!(dims, (1200, 800));
    // Drive 1's actual frequency (solid) in the upper chart: left third lower than right third.
    let upper: Vec<(u32, u32)> = red.iter().copied().filter(|&(_, y)| y < 520).collect();
    assert!(upper.len() > 1000, "{} pixels of drive 1", upper.len());
    let mean_y = |from: u32, to: u32| {
        let ys: Vec<f64> = upper
            .iter()
            .filter(|&&(x, _)| (from..to).contains(&x))
            .map(|&(_, y)| f64::from(y))
            .collect();
        ys.iter().sum::<f64>() / ys.len() as f64
    };
    // (The setpoint line at 25 Hz is at the same height everywhere; the ramp moves the mean.)
    assert!(mean_y(800, 1150) < mean_y(100, 400) - 20.0);
    let _ = run.finish();

    // The same recording as SVG: text, the legend, the trigger mark.
    let status = std::process::Command::new(uss_integration_tests::binary("ussctl", "ussctl"))
        .args(["--bus", &ussd.bus, "trace", "2", "--for", "0.3"])
        .args(["-o", csv.to_str().unwrap(), "--plot", svg.to_str().unwrap()])
        .status()
        .unwrap();
    assert!(status.success());
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(text.starts_with("<svg"), "{}", &text[..100]);
    for wanted in ["drive 2 actual", "drive 2 set", "time [s]", "S2"] {
        assert!(text.contains(wanted), "no {wanted:?} in the SVG");
    }
    for f in [csv, png, svg] {
        let _ = std::fs::remove_file(f);
    }
}

#[test]
fn a_fault_trigger_catches_the_trip_and_what_led_to_it() {
    // Drive 3 watches its telegrams (P2014 = 100 ms) and is unplugged for half a second: it
    // goes offline, then answers again in fault F0072 (3 s after ussd started: the trace is
    // armed by then).
    let ussd = Ussd::start("", &[(3, "sim = { p2014 = 100, unplug = \"3000..3500\" }")]);
    let (csv, svg) = (temp("fault.csv"), temp("fault.svg"));
    let mut trace = ussd.ussctl(&[
        "trace",
        "3",
        "--trigger",
        "fault",
        "--pre",
        "1s",
        "--for",
        "0.5",
        "--wait",
        "20",
        "-o",
        csv.to_str().unwrap(),
        "--plot",
        svg.to_str().unwrap(),
    ]);
    // (Armed well before the unplug, 3 s after ussd started.)
    trace.says("waiting for the trigger fault");
    let (status, stdout, stderr) = trace.finish();
    assert!(status.success(), "{stdout}{stderr}");
    let rows = read_csv(&csv);
    let at0 = rows.iter().position(|r| num(r, "t_s") == 0.0).unwrap();
    assert_eq!(rows[at0]["fault"], "1");
    assert_eq!(rows[at0]["state"], "fault");
    assert_eq!(rows[at0]["online"], "1");
    // Before it: the drive answered, then went offline (unplugged), all within the second kept.
    let before = &rows[..at0];
    assert!(
        before
            .iter()
            .any(|r| r["online"] == "1" && r["fault"] == "0")
    );
    assert!(before.iter().any(|r| r["online"] == "0"), "{before:?}");
    assert!(before.iter().all(|r| num(r, "t_s") >= -1.05));
    let text = std::fs::read_to_string(&svg).unwrap();
    for wanted in ["3: fault", "3: offline", "trigger"] {
        assert!(text.contains(wanted), "no {wanted:?} in the SVG");
    }

    // A trigger that never fires: a clear error after --wait, and nothing written.
    let _ = std::fs::remove_file(&csv);
    let mut never = ussd.ussctl(&[
        "trace",
        "3",
        "--trigger",
        "hz>100",
        "--wait",
        "0.5",
        "-o",
        csv.to_str().unwrap(),
    ]);
    let (status, _, stderr) = never.finish();
    assert_eq!(status.code(), Some(1));
    assert!(
        stderr.contains("the trigger hz>100 did not fire within 0.5 s; nothing was written"),
        "{stderr}"
    );
    assert!(!csv.exists());
    let _ = std::fs::remove_file(svg);
}
