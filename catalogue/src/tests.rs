#![allow(clippy::float_cmp)]
use super::*;

#[test]
fn the_built_in_catalogue_reads_and_finds_by_number() {
    let c = Catalogue::micromaster4();
    assert_eq!(c.family, "MICROMASTER 4 / SINAMICS G110");
    let r0021 = c.param(21).unwrap();
    assert_eq!(r0021.id.to_string(), "r0021");
    assert!(!r0021.is_writable());
    let r0947 = c.param(947).unwrap();
    assert_eq!((r0947.array, r0947.data_type), (8, DataType::U16));
    assert_eq!(c.param(9999), None);
    assert_eq!(c.fault(72), Some("USS (COM link) setpoint fault"));
    assert_eq!(c.warning(501), Some("Current limit"));
    assert_eq!(c.fault(9999), None);
}

#[test]
fn an_array_names_its_elements() {
    let c = Catalogue::micromaster4();
    let p2014 = c.param(2014).unwrap();
    assert!(p2014.is_array());
    assert_eq!(
        p2014.elements_named(),
        "P2014[0] (COM link, RS485) or P2014[1] (BOP link, RS232)"
    );
    assert_eq!(
        c.param(947).unwrap().elements_named(),
        "r0947[0] .. r0947[7]"
    );
    assert!(!c.param(1082).unwrap().is_array());
    let wrong = "family = \"x\"\nparam = [{ id = \"P0001\", name = \"a\", type = \"U16\", array = 2, elements = [\"one\"], level = 1, change = \"always\" }]";
    let e = Catalogue::parse(wrong, "wrong.toml").unwrap_err();
    assert_eq!(
        e.to_string(),
        "wrong.toml: P0001: 1 elements named for an array of 2"
    );
}

#[test]
fn values_show_in_their_type_and_unit() {
    let c = Catalogue::micromaster4();
    assert_eq!(
        c.param(1082).unwrap().show(Value::Dword(0x4248_0000)),
        "50.00 Hz"
    );
    assert_eq!(c.param(700).unwrap().show(Value::Word(5)), "5");
    assert_eq!(c.param(52).unwrap().show(Value::Word(0xFB31)), "0xFB31");
    assert_eq!(c.param(2014).unwrap().show(Value::Word(100)), "100 ms");
    assert_eq!(DataType::I16.decode(Value::Word(0xFFFF)), Typed::I16(-1));
    assert_eq!(DataType::I32.decode(Value::Dword(u32::MAX)), Typed::I32(-1));
}

#[test]
fn text_becomes_the_parameters_own_type_or_is_refused_before_the_bus() {
    assert_eq!(DataType::Float.parse("45"), Ok(Value::from_f32(45.0)));
    assert_eq!(DataType::Float.parse(" 2.5 "), Ok(Value::from_f32(2.5)));
    assert_eq!(DataType::U16.parse("5"), Ok(Value::Word(5)));
    assert_eq!(DataType::U16.parse("0x1F"), Ok(Value::Word(0x1F)));
    assert_eq!(DataType::I16.parse("-3"), Ok(Value::Word(0xFFFD)));
    assert_eq!(DataType::I32.parse("-1"), Ok(Value::Dword(u32::MAX)));
    assert_eq!(DataType::U32.parse("70000"), Ok(Value::Dword(70000)));
    assert_eq!(
        DataType::U16.parse("70000").unwrap_err().to_string(),
        "70000 does not fit U16 (0..=65535)"
    );
    assert_eq!(
        DataType::U16.parse("4.5").unwrap_err().to_string(),
        "4.5 is not a whole number, and U16 holds only whole numbers"
    );
    assert_eq!(
        DataType::Float.parse("fast").unwrap_err().to_string(),
        "\"fast\" is not a number"
    );
    assert!(DataType::Float.parse("inf").is_err());
    assert!(DataType::I16.parse("40000").is_err());
    // A whole number however written; hex is the type's bits.
    assert_eq!(DataType::U16.parse("300.0"), Ok(Value::Word(300)));
    assert_eq!(DataType::U16.parse("1e3"), Ok(Value::Word(1000)));
    assert_eq!(
        DataType::I32.parse("-2e3"),
        Ok(Value::Dword(-2000i32 as u32))
    );
    assert!(DataType::U16.parse("-1").is_err());
    assert!(DataType::U16.parse("1e5").is_err());
    assert!(DataType::U16.parse("1e300").is_err());
    assert_eq!(DataType::I16.parse("0xFFFF"), Ok(Value::Word(0xFFFF)));
    assert!(DataType::U16.parse("0x10000").is_err());
    assert_eq!(
        DataType::Float.parse("0x41200000"),
        Ok(Value::from_f32(10.0))
    );
    assert!(DataType::Float.parse("0x7F800000").is_err());
    // Too small for a float: the drive would hold 0, so it is refused like too large.
    assert_eq!(
        DataType::Float.parse("1e-50").unwrap_err().to_string(),
        "1e-50 does not fit float (a single-precision number: 0, or 1.4e-45 to 3.4e38 in size)"
    );
    assert!(DataType::Float.parse("-1e-50").is_err());
    assert!(DataType::Float.parse("1e40").is_err());
    assert_eq!(DataType::Float.parse("1e-45"), Ok(Value::Dword(1)));
    assert_eq!(DataType::Float.parse("0e-50"), Ok(Value::Dword(0)));
    assert_eq!(DataType::Float.parse("-0.0"), Ok(Value::Dword(0x8000_0000)));
}

#[test]
fn a_float_shows_the_very_value_the_drive_holds() {
    let shown = |f: f32| Typed::Float(f).to_string();
    assert_eq!(shown(50.0), "50.00");
    assert_eq!(shown(0.1), "0.10");
    assert_eq!(shown(0.001), "0.001");
    assert_eq!(shown(12.345_678), "12.345678");
    assert_eq!(shown(-0.0), "-0.00");
    let c = Catalogue::micromaster4();
    assert_eq!(
        c.param(1120).unwrap().show(Value::from_f32(0.001)),
        "0.001 s"
    );
}

#[test]
fn a_fixed_point_parameter_is_shown_written_and_bounded_in_its_unit() {
    // SIMOREG P303 counts 0.01 s (OI 6RX1700-0AD76): 1000 is 10.00 s.
    let p303 = Catalogue::simoreg().param(303).unwrap();
    assert_eq!(p303.show(Value::Word(1000)), "10.00 s");
    assert_eq!(p303.show(Value::Word(7)), "0.07 s");
    assert_eq!(p303.parse("5.5"), Ok(Value::Word(550)));
    assert_eq!(p303.parse(" 0.07 "), Ok(Value::Word(7)));
    assert_eq!(p303.parse("650"), Ok(Value::Word(65000)));
    // Hex is the word itself.
    assert_eq!(p303.parse("0x3E8"), Ok(Value::Word(1000)));
    assert!(matches!(
        p303.parse("5.555"),
        Err(ValueError::NotAStep { ref step, .. }) if step == "0.01"
    ));
    let too_long = p303.parse("700").unwrap_err().to_string();
    assert!(too_long.contains("does not fit U16"), "{too_long}");
    assert!(matches!(
        p303.parse("ten"),
        Err(ValueError::NotANumber { .. })
    ));
    assert!(p303.within_limits(Value::Word(65000)) && !p303.within_limits(Value::Word(0)));
    assert_eq!(p303.quantity(Typed::U16(550)), Quantity::Real(5.5));
    assert_eq!(p303.quantity(Typed::U16(7)), Quantity::Real(0.07));
    // A parameter without a scale is as its type holds it.
    let p1120 = Catalogue::micromaster4().param(1120).unwrap();
    assert_eq!(p1120.quantity(Typed::Float(2.5)), Quantity::Real(2.5));
    let p0003 = Catalogue::micromaster4().param(3).unwrap();
    assert_eq!(p0003.quantity(Typed::U16(3)), Quantity::Whole(3));
    assert_eq!(p1120.parse("2.5"), Ok(Value::from_f32(2.5)));
    let bad = "family = \"x\"\nparam = [ { id = \"P0001\", name = \"n\", type = \"Float\", scale = 0.1, level = 1, change = \"always\" } ]\n";
    let e = Catalogue::parse(bad, "f").unwrap_err().to_string();
    assert!(e.contains("scale 0.1"), "{e}");
}

#[test]
fn limits_and_type_codes() {
    let p2000 = Catalogue::micromaster4().param(2000).unwrap();
    assert!(p2000.within_limits(Value::from_f32(50.0)));
    assert!(!p2000.within_limits(Value::from_f32(0.5)));
    for t in [
        DataType::I16,
        DataType::I32,
        DataType::U16,
        DataType::U32,
        DataType::Float,
    ] {
        assert_eq!(DataType::from_code(t.code()), Some(t));
    }
    assert_eq!(DataType::from_code(5), None);
}

#[test]
fn a_broken_catalogue_file_is_refused_naming_what_is_wrong() {
    let unsorted = "family = \"x\"\nfault = []\nwarning = []\nparam = [\n\
        { id = \"P0010\", name = \"a\", type = \"U16\", level = 1, change = \"always\" },\n\
        { id = \"P0003\", name = \"b\", type = \"U16\", level = 1, change = \"always\" },\n]\n";
    let e = Catalogue::parse(unsorted, "x.toml").unwrap_err();
    assert!(e.to_string().contains("parameter 3 follows 10"), "{e}");
    let r_writable = "family = \"x\"\nfault = []\nwarning = []\nparam = [\n\
        { id = \"r0021\", name = \"a\", type = \"Float\", level = 1, change = \"always\" },\n]\n";
    let e = Catalogue::parse(r_writable, "x.toml").unwrap_err();
    assert!(
        e.to_string().contains("r0021: an r parameter is read-only"),
        "{e}"
    );
    let typo = "family = \"x\"\nfault = []\nwarning = []\nparam = [\n\
        { id = \"P0003\", name = \"a\", type = \"U61\", level = 1, change = \"always\" },\n]\n";
    let e = Catalogue::parse(typo, "x.toml").unwrap_err();
    assert!(e.to_string().contains("U61"), "{e}");
    let no_max = "family = \"x\"\npzd_length = \"P2012[0]\"\nparam = [\n\
        { id = \"P2012\", name = \"a\", type = \"U16\", array = 2, level = 3, change = \"always\" },\n]\n";
    let e = Catalogue::parse(no_max, "x.toml").unwrap_err();
    assert!(e.to_string().contains("pzd_length names P2012[0]"), "{e}");
    // The built-in profiles say how many PZD words their drives take.
    let max = |c: &Catalogue| c.max_pzd().map(|(p, n)| (p.to_string(), n));
    assert_eq!(max(Catalogue::micromaster4()), Some(("P2012[0]".into(), 8)));
    assert_eq!(max(Catalogue::g120()), Some(("p2022".into(), 8)));
    assert_eq!(max(Catalogue::simoreg()), None);
}

mod properties {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn every_value_of_a_type_written_as_text_reads_back(
            i16v in any::<i16>(), u16v in any::<u16>(), i32v in any::<i32>(),
            u32v in any::<u32>(), f in any::<f32>().prop_filter("finite", |f| f.is_finite()),
        ) {
            let back = |t: DataType, text: String| t.decode(t.parse(&text).unwrap());
            prop_assert_eq!(back(DataType::I16, i16v.to_string()), Typed::I16(i16v));
            prop_assert_eq!(back(DataType::U16, u16v.to_string()), Typed::U16(u16v));
            prop_assert_eq!(back(DataType::U16, format!("{u16v:#X}")), Typed::U16(u16v));
            prop_assert_eq!(back(DataType::I32, i32v.to_string()), Typed::I32(i32v));
            prop_assert_eq!(back(DataType::U32, u32v.to_string()), Typed::U32(u32v));
            prop_assert_eq!(back(DataType::Float, f.to_string()), Typed::Float(f));
            // What is shown is what the drive holds: it reads back to the same bits.
            let shown = Typed::Float(f).to_string();
            prop_assert_eq!(shown.parse::<f32>().map(f32::to_bits), Ok(f.to_bits()));
            prop_assert_eq!(
                DataType::Float.parse(&format!("{:#010x}", f.to_bits())),
                Ok(Value::Dword(f.to_bits()))
            );
        }

        #[test]
        fn whole_numbers_outside_a_type_are_refused_and_any_text_gets_an_answer(
            n in any::<i64>(), text in ".{0,12}",
        ) {
            for t in [DataType::I16, DataType::U16, DataType::I32, DataType::U32] {
                let fits = match t {
                    DataType::I16 => i16::try_from(n).is_ok(),
                    DataType::U16 => u16::try_from(n).is_ok(),
                    DataType::I32 => i32::try_from(n).is_ok(),
                    _ => u32::try_from(n).is_ok(),
                };
                prop_assert_eq!(t.parse(&n.to_string()).is_ok(), fits);
                // Never a panic, whatever the text.
                let _ = t.parse(&text);
            }
            let _ = DataType::Float.parse(&text);
        }
    }
}

#[test]
fn guarded_parameters_are_marked_per_family_and_monitoring_only_when_switched_off() {
    let mm4 = Catalogue::of(DriveFamily::Micromaster4).unwrap();
    assert!(core::ptr::eq(
        mm4,
        Catalogue::of(DriveFamily::G110).unwrap()
    ));
    assert!(
        mm4.guard(700, Value::Word(2))
            .unwrap()
            .starts_with("command source")
    );
    assert_eq!(
        mm4.guard(1120, Value::Word(0)),
        None,
        "a ramp time is not guarded"
    );
    assert_eq!(
        mm4.guard(2014, Value::Word(100)),
        None,
        "monitoring set is fine"
    );
    assert!(
        mm4.guard(2014, Value::Word(0))
            .unwrap()
            .contains("monitoring off")
    );
    let g120 = Catalogue::of(DriveFamily::G120).unwrap();
    assert!(
        g120.guard(2021, Value::Word(5))
            .unwrap()
            .contains("address")
    );
    assert!(
        g120.guard(2040, Value::Word(0)).is_some()
            && g120.guard(2040, Value::Dword(100.0f32.to_bits())).is_none()
    );
    assert!(Catalogue::of(DriveFamily::Generic).is_none());
    let simoreg = Catalogue::of(DriveFamily::Simoreg).unwrap();
    assert!(
        simoreg.guard(782, Value::Word(3)).is_some()
            && simoreg.guard(303, Value::Word(100)).is_none()
    );
    // Guarded by number: the BICO sources need no typed entry.
    assert!(mm4.param(840).is_none() && mm4.guard(840, Value::Word(0)).is_some());
}

/// Issue 32: a guard compares what the drive would hold, not the raw bits.
#[test]
fn a_guard_compares_the_value_as_its_type_reads_it() {
    let g120 = Catalogue::g120();
    // p2040 is a float: -0.0 (0x8000_0000) switches monitoring off like 0 does, and a
    // subnormal float reads as 0 too; 100 ms does not.
    for off in [
        0.0f32,
        -0.0,
        f32::from_bits(1),
        f32::from_bits(0x8000_0001),
        -1.0,
    ] {
        assert!(
            g120.guard(2040, Value::Dword(off.to_bits())).is_some(),
            "{off:e}"
        );
    }
    assert_eq!(g120.guard(2040, Value::Dword(100.0f32.to_bits())), None);
    // Only the listed values: p0010 = 30 (parameter reset mode), not 1 (quick commissioning).
    assert!(g120.guard(10, Value::Word(30)).is_some());
    assert_eq!(g120.guard(10, Value::Word(1)), None);
    assert!(
        Catalogue::micromaster4()
            .guard(10, Value::Word(30))
            .is_some()
    );
    assert_eq!(Catalogue::micromaster4().guard(10, Value::Word(0)), None);
    // NaN and infinities are no setting of a float parameter; a word parameter has no NaN.
    for bits in [
        f32::NAN.to_bits(),
        f32::INFINITY.to_bits(),
        f32::NEG_INFINITY.to_bits(),
    ] {
        assert!(
            g120.judge_write(2040, Value::Dword(bits)).impossible,
            "{bits:#x}"
        );
    }
    assert!(
        !g120
            .judge_write(2040, Value::Dword(100.0f32.to_bits()))
            .impossible
    );
    assert!(
        !Catalogue::micromaster4()
            .judge_write(2014, Value::Word(0xFFFF))
            .impossible
    );
    // One look: the entry comes with the judgement (ussd shows the value by it in its audit).
    let judged = g120.judge_write(2040, Value::Dword(0));
    assert!(judged.guard.is_some() && !judged.impossible);
    assert_eq!(judged.entry.map(|p| p.id.to_string()), Some("p2040".into()));
    let unlisted = Catalogue::micromaster4().judge_write(840, Value::Word(0));
    assert!(unlisted.entry.is_none() && unlisted.guard.is_some());
}

/// Issue 32: every family's guarded list names the parameters that take a drive out of reach
/// or reset its monitoring, each with the manual it comes from.
#[test]
fn each_guard_cites_its_source_and_the_lists_are_complete() {
    let pnus = |c: &Catalogue| c.guard.iter().map(|g| g.id.pnu.get()).collect::<Vec<_>>();
    for c in [
        Catalogue::micromaster4(),
        Catalogue::g120(),
        Catalogue::simoreg(),
    ] {
        for g in &c.guard {
            assert!(
                g.source.len() > 10,
                "{}: {} cites no source",
                c.family,
                g.id
            );
        }
    }
    let mm4 = pnus(Catalogue::micromaster4());
    for pnu in [
        10, 700, 719, 810, 811, 840, 844, 848, 927, 970, 1000, 1070, 2010, 2011, 2012, 2013, 2014,
        3900,
    ] {
        assert!(mm4.contains(&pnu), "MM4 P{pnu:04} unguarded");
    }
    let g120 = pnus(Catalogue::g120());
    for pnu in [
        10, 15, 700, 810, 811, 840, 844, 848, 854, 927, 970, 1000, 1070, 2020, 2021, 2030, 2040,
        3900,
    ] {
        assert!(g120.contains(&pnu), "G120 p{pnu:04} unguarded");
    }
}

#[test]
fn each_family_says_where_its_faults_and_its_link_are() {
    let faults = |family: &str| {
        let f = Catalogue::of(Catalogue::family_named(family).unwrap())
            .unwrap()
            .faults
            .clone()
            .unwrap();
        (f.codes.to_string(), f.values.map(|v| v.to_string()), f.len)
    };
    assert_eq!(
        faults("micromaster4"),
        ("r0947".into(), Some("r0949".into()), 8)
    );
    assert_eq!(faults("g120"), ("r0945".into(), Some("r0949".into()), 8));
    assert_eq!(faults("simoreg"), ("r0947".into(), Some("r0949".into()), 8));
    let mm4 = Catalogue::micromaster4();
    let at = |s: &str| s.parse::<uss_protocol::ParamRef>().unwrap();
    assert!(mm4.is_link(at("P2011[0]")) && !mm4.is_link(at("P2011[1]")));
    assert!(Catalogue::g120().is_link(at("p2021")));
    assert_eq!(mm4.access_level.map(|p| p.pnu.get()), Some(3));
    assert_eq!(Catalogue::simoreg().access_level, None);
}

/// The roles ussd and its tools read a drive by, typed in from the manuals (not from the
/// profiles): the telegram-off time of the USS link and the fault its expiry records, the
/// reference. MM4: index 0 of the USS parameters is the COM link (RS485), index 1 the BOP link
/// (MM420 Parameter List 6SE6400-5BA00-0BP0 04/02 p.84, P2012: "P2012[0] : Serial interface COM
/// link, P2012[1] : Serial interface BOP link"; MM440 Parameter List 01/06 p.197, P2013 the same;
/// CU240S OI 10/2007 6.6.4 p.183: "Index[0] for USS on RS485, Index[1] for USS on RS232"),
/// F0072 "USS (COM link) setpoint fault", P2000 reference frequency in Hz; G120 (CU240 list manual):
/// p2040 fieldbus monitoring time, F01910 setpoint timeout, p2000 reference speed in rpm;
/// SIMOREG: uss-rt knows none of them (its telegram failure time is not in a stored copy).
#[test]
fn each_family_names_its_monitoring_fault_and_reference_as_its_manual_does() {
    let roles = |family: DriveFamily| {
        let c = Catalogue::of(family).unwrap();
        let name = |p: Option<uss_protocol::ParamRef>| p.map(|p| p.to_string());
        (
            name(c.monitoring),
            c.telegram_off_fault,
            name(c.reference),
            name(c.reference_speed),
        )
    };
    let mm4 = (
        Some("P2014[0]".into()),
        Some(72),
        Some("P2000".into()),
        None,
    );
    assert_eq!(roles(DriveFamily::Micromaster4), mm4);
    assert_eq!(roles(DriveFamily::G110), mm4);
    assert_eq!(
        roles(DriveFamily::G120),
        (Some("p2040".into()), Some(1910), None, Some("p2000".into()))
    );
    assert_eq!(roles(DriveFamily::Simoreg), (None, None, None, None));
    let named = |family| Catalogue::of(family).unwrap().monitoring_name();
    assert_eq!(
        named(DriveFamily::G110).as_deref(),
        Some("P2014[0] (F0072)")
    );
    assert_eq!(named(DriveFamily::G120).as_deref(), Some("p2040 (F01910)"));
    assert_eq!(named(DriveFamily::Simoreg), None);
    let source = |family| Catalogue::of(family).unwrap().command_source_setting();
    assert_eq!(
        source(DriveFamily::Micromaster4).as_deref(),
        Some("P0700 = 5")
    );
    assert_eq!(source(DriveFamily::G120).as_deref(), Some("p0700 = 6"));
    assert_eq!(source(DriveFamily::Simoreg), None);
    assert!(Catalogue::of(DriveFamily::Generic).is_none());
    for family in DriveFamily::ALL {
        assert_eq!(Catalogue::family_named(family.name()), Some(*family));
    }
    assert_eq!(Catalogue::family_named("MICROMASTER"), None);
}

/// An entry as a stored page of a Siemens list shows it: (id, type, unit, elements, level,
/// change, min, max, default, the page).
type PageEntry = (
    &'static str,
    DataType,
    &'static str,
    u16,
    u8,
    Change,
    Option<f64>,
    Option<f64>,
    Option<f64>,
    &'static str,
);

/// Entries of the MM4 profile checked against a stored page of a Siemens parameter list, their
/// fields typed in from that page (not from the profile). PL420 = MICROMASTER 420 Parameter
/// List 6SE6400-5BA00-0BP0 04/02, PL440 = MICROMASTER 440 Parameter List 6SE6400-5BB00-0BP0
/// 01/06.
#[rustfmt::skip]
const MM4_PAGES: &[PageEntry] = &[
    // PL420 p.84: "P2012[2] USS PZD length Min: 0 CStat: CUT Datatype: U16 Def: 2 Max: 4 Level 3"
    // (MM420); PL440 p.196: Max 8 (the family's largest).
    ("P2012", DataType::U16, "", 2, 3, Change::Always, Some(0.0), Some(8.0), Some(2.0), "PL440 p.196"),
    // PL440 p.197: "P2013[2] USS PKW length Min: 0 CStat: CUT Datatype: U16 Def: 127 Max: 127 Level 3".
    ("P2013", DataType::U16, "", 2, 3, Change::Always, Some(0.0), Some(127.0), Some(127.0), "PL440 p.197"),
    // PL440 p.201: r2024[2], r2025[2], U16, level 3, index 0 COM link, 1 BOP link.
    ("r2024", DataType::U16, "", 2, 3, Change::ReadOnly, None, None, None, "PL440 p.201"),
    ("r2025", DataType::U16, "", 2, 3, Change::ReadOnly, None, None, None, "PL440 p.201"),
    // PL440 p.107: "r0948[12] CO: Fault time", U16, level 3.
    ("r0948", DataType::U16, "", 12, 3, Change::ReadOnly, None, None, None, "PL440 p.107"),
    // PL440 p.127: "P1080[3] Min. frequency", Float, Hz, 0.00..650.00, level 1, CUT (indexed by
    // drive data set on MM440; uss-rt reads element 0, the first).
    ("P1080", DataType::Float, "Hz", 0, 1, Change::Always, Some(0.0), Some(650.0), None, "PL440 p.127"),
];

/// Each entry of [`MM4_PAGES`] is in the profile as its page shows it, and cites the page.
#[test]
fn mm4_entries_checked_against_a_stored_list_page_match_it_and_cite_it() {
    let c = Catalogue::micromaster4();
    for &(id, ty, unit, array, level, change, min, max, default, page) in MM4_PAGES {
        let p = c
            .param(id.parse::<uss_protocol::ParamRef>().unwrap().pnu.get())
            .unwrap();
        assert_eq!(
            (p.data_type, p.unit.as_str(), p.array, p.level, p.change),
            (ty, unit, array, level, change),
            "{id}"
        );
        assert_eq!((p.min, p.max, p.default), (min, max, default), "{id}");
        let cited = p.source.as_deref().unwrap_or_default();
        assert!(cited.contains(page), "{id} cites {cited:?}, not {page}");
    }
    // Index 0 of the USS parameters is the COM link (PL420 p.84, PL440 p.197 and p.201).
    for id in [2012, 2013, 2024, 2025] {
        assert!(
            c.param(id).unwrap().elements[0].starts_with("COM link"),
            "{id}"
        );
    }
    // Every citation names a document the profile's header lists.
    let cited: Vec<&Param> = c.param.iter().filter(|p| p.source.is_some()).collect();
    for p in &cited {
        let s = p.source.as_deref().unwrap_or_default();
        assert!(
            ["PL420 p.", "PL440 p.", "RM420 p."]
                .iter()
                .any(|d| s.contains(d)),
            "{}: {s}",
            p.id
        );
    }
    println!(
        "{} of {} MM4 entries cite a stored page of their list",
        cited.len(),
        c.param.len()
    );
}

/// A family is one data file: every family of the contract but `generic` has exactly one
/// built-in profile (the file that names it in `families`), every file in `catalogue/data`
/// serves a family, and a file naming a family the contract lacks is refused.
#[test]
fn every_family_has_exactly_one_profile_file_and_every_file_a_family() {
    for &family in DriveFamily::ALL {
        let serving = PROFILES
            .iter()
            .filter(|c| c.families.contains(&family))
            .count();
        let expected = usize::from(family != DriveFamily::Generic);
        assert_eq!(serving, expected, "{}", family.name());
    }
    assert_eq!(PROFILES.len(), PROFILE_FILES.len());
    for (c, (origin, _)) in PROFILES.iter().zip(PROFILE_FILES) {
        assert!(!c.families.is_empty(), "{origin} serves no family");
    }
    let unknown = "family = \"x\"\nfamilies = [\"g130\"]\n";
    let e = Catalogue::parse(unknown, "x.toml").unwrap_err();
    assert!(e.to_string().contains("\"g130\" is no family"), "{e}");
    let generic = "family = \"x\"\nfamilies = [\"generic\"]\n";
    assert!(Catalogue::parse(generic, "x.toml").is_err());
}
