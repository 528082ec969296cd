//! `ussctl capture` against a real ussd: a known parameter read is captured, decoded at the
//! application level, written to pcapng, and the shipped Wireshark dissector reads the file.

use pcap_file::DataLink;
use pcap_file::pcapng::{Block, PcapNgReader};
use serde_json::Value as Json;
use std::process::Command;
use std::time::Duration;
use uss_integration_tests::{BusSpec, Ussd};
use uss_integration_tests::{addr, param};
use uss_protocol::bcc;
use uss_shm_types::Hex;

/// A request to drive 1 reading P1082 (AK 1, PNU 0x43A) with the safe command OFF1 that a drive
/// without a controller gets (STW1 0x047E) and setpoint 0.
fn read_p1082_request() -> Vec<u8> {
    let mut t = vec![
        0x02, 0x0E, 0x01, 0x14, 0x3A, 0, 0, 0, 0, 0, 0, 0x04, 0x7E, 0, 0,
    ];
    t.push(bcc(&t));
    t
}

#[test]
fn capture_decodes_a_parameter_read_and_writes_pcapng_for_wireshark() {
    let ussd = Ussd::start("", &[(1, ""), (2, "")]);
    let bus = ussd.bus();
    let file = std::env::temp_dir().join(format!("uss-capture-{}.pcapng", std::process::id()));
    let path = file.to_str().unwrap();
    let mut capture = ussd.ussctl(&[
        "--json", "capture", "--drive", "1", "--for", "3", "-o", path,
    ]);
    // Subscribed once it shows a telegram.
    capture.says("\"sequence\"");
    let value = bus.read(addr(1), param(1082)).unwrap();
    assert_eq!(value.as_u32(), 0x4248_0000, "P1082 reads 50.0 Hz");
    let (status, rest, stderr) = capture.finish();
    assert!(status.success(), "{stderr}");
    let lines: Vec<Json> = rest
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert!(lines.len() > 20, "{} telegrams in 3 s", lines.len());
    assert!(lines.iter().all(|l| l["drive"] == 1), "only drive 1");
    // On the wire, every request of those 3 s carries STW1 with bit 10 (control by PLC) set.
    let requests: Vec<&Json> = lines
        .iter()
        .filter(|l| l["direction"] == "request")
        .collect();
    assert!(requests.len() > 10, "{rest}");
    for r in &requests {
        let stw1 = r["frame"]["pzd"][0].as_u64().unwrap();
        assert_ne!(stw1 & 0x0400, 0, "a telegram without STW1 bit 10: {r}");
    }

    let request = lines
        .iter()
        .position(|l| l["app"]["pkw"] == "read P1082")
        .unwrap_or_else(|| panic!("no read of P1082 in {rest}"));
    let r = &lines[request];
    assert_eq!(r["direction"], "request");
    assert_eq!(r["outcome"], "sent");
    assert_eq!(r["bytes"], Hex(&read_p1082_request()).to_string());
    assert_eq!(r["frame"]["pkw"], serde_json::json!([0x143A, 0, 0, 0]));
    assert_eq!(r["frame"]["pzd"], serde_json::json!([0x047E, 0]));
    assert_eq!(r["app"]["word1_name"], "STW1");
    assert_eq!(r["app"]["hz"], 0.0);
    let reply = &lines[request + 1];
    assert_eq!(reply["direction"], "reply");
    assert_eq!(reply["outcome"], "good");
    assert_eq!(reply["app"]["pkw"], "P1082 = 50.00 Hz");
    assert_eq!(
        reply["frame"]["pkw"],
        serde_json::json!([0x243A, 0, 0x4248, 0])
    );
    assert_eq!(reply["frame"]["bcc"], reply["frame"]["bcc_expected"]);

    // The pcapng file: one interface of link type USER0, then every telegram shown (and the
    // one the first line consumed), each an 8-byte header and the telegram.
    let data = std::fs::read(&file).unwrap();
    let mut reader = PcapNgReader::new(data.as_slice()).unwrap();
    let mut packets = Vec::new();
    let mut linktype = None;
    while let Some(block) = reader.next_block() {
        match block.unwrap() {
            Block::InterfaceDescription(i) => linktype = Some(i.linktype),
            Block::EnhancedPacket(p) => {
                let flags = p.options.iter().find_map(|o| match o {
                    pcap_file::pcapng::blocks::enhanced_packet::EnhancedPacketOption::Flags(f) => {
                        Some(*f)
                    }
                    _ => None,
                });
                packets.push((p.data.to_vec(), flags));
            }
            _ => {}
        }
    }
    assert_eq!(linktype, Some(DataLink::USER0));
    assert_eq!(packets.len(), lines.len() + 1);
    let mut expected = vec![1, 0, 0, 1, 4, 2, 2, 0];
    expected.extend(read_p1082_request());
    let (data, flags) = &packets[request + 1];
    assert_eq!(
        *data, expected,
        "header (v1, request, good, drive 1, PKW 4, PZD 2, task) + telegram"
    );
    assert_eq!(*flags, Some(2), "outbound");
    assert_eq!(packets[request + 2].1, Some(1), "inbound");

    dissect(path);
    let _ = std::fs::remove_file(&file);
}

/// The shipped dissector decodes the file: tshark shows the read of P1082 and its reply.
/// Without tshark the check says so; CI installs it and sets `USS_REQUIRE_TSHARK`, so there it
/// cannot be skipped.
fn dissect(path: &str) {
    let lua = concat!(env!("CARGO_MANIFEST_DIR"), "/../tools/wireshark/uss.lua");
    let run = Command::new("tshark")
        .args(["-X", &format!("lua_script:{lua}"), "-r", path])
        .args(["-Y", "uss.pkw.parameter contains \"P1082\""])
        .args(["-T", "fields", "-e", "uss.direction", "-e", "uss.drive"])
        .args(["-e", "uss.pkw.parameter", "-e", "uss.bcc.ok"])
        .output();
    let out = match run {
        Ok(out) => out,
        Err(e) if std::env::var_os("USS_REQUIRE_TSHARK").is_none() => {
            eprintln!(
                "SKIPPED the Wireshark dissector check: tshark does not run ({e}); install it with `apt-get install tshark`"
            );
            return;
        }
        Err(e) => panic!("tshark does not run ({e}) but USS_REQUIRE_TSHARK is set"),
    };
    let shown = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<&str> = shown.lines().collect();
    assert!(lines.contains(&"0\t1\trequest value P1082\t1"), "{shown}");
    assert!(lines.contains(&"1\t1\tvalue (dword) P1082\t1"), "{shown}");
}

/// `RUST_LOG=debug` shows state changes, retries with their reasons and the parameter jobs'
/// life cycle; `trace` every telegram and every job's end. All from ussd's non-real-time
/// threads (the bus thread hands events and telegrams over).
#[test]
fn rust_log_debug_and_trace_show_states_retries_jobs_and_telegrams() {
    let ussd = Ussd::start_buses_with_env(
        &[BusSpec {
            suffix: "",
            device: "sim",
            keys: "",
            drives: &[(1, "sim = { drop = 0.2 }")],
        }],
        &[("RUST_LOG", "uss_master=trace")],
    );
    let bus = ussd.bus();
    // Three tries at 20 % lost replies: a read may still fail; its jobs are logged either way.
    let _ = bus.read(addr(1), param(1082));
    let wait = Duration::from_secs(10);
    for said in [
        "drive 1: unknown -> S",
        "retry 1 of 2",
        "parameter request of 1 item(s) accepted as jobs",
        "answered",
        "ended: Ok(Ok(",
        "-> drive 1 sent: 02 0E 01",
        "<- drive 1 no response",
    ] {
        assert!(
            ussd.log_line(said, wait).is_some(),
            "ussd's log does not say {said:?}:\n{}",
            ussd.log()
        );
    }
}
