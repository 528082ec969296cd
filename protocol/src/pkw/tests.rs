use super::*;

fn pnu(n: u16) -> Pnu {
    Pnu::from_u16(n)
}

fn encoded(task: ParamTask, mode: PkwMode) -> Vec<u16> {
    let mut out = [0u16; 4];
    let n = task.encode(mode, &mut out).unwrap();
    out[..n].to_vec()
}

#[test]
fn page_bits_follow_uss_md_section_6() {
    assert_eq!(pnu(1999).ind_high(), 0x00);
    assert_eq!(pnu(2000).ind_high(), 0x80);
    assert_eq!(pnu(3999).ind_high(), 0x80);
    assert_eq!(pnu(4000).ind_high(), 0x10);
    assert_eq!(pnu(6000).ind_high(), 0x90);
    assert_eq!(pnu(8000).ind_high(), 0x20);
    assert_eq!(pnu(60000).ind_high(), 0x74);
    assert_eq!(pnu(61999).ind_high(), 0x74);
    assert_eq!(pnu(2000).low(), 0);
}

#[test]
fn every_pnu_round_trips_through_pke_and_ind() {
    for n in 0..=u16::MAX {
        let p = pnu(n);
        assert_eq!(Pnu::from_parts(p.low(), p.ind_high()), Some(p), "PNU {n}");
    }
}

#[test]
fn read_p2000_is_pke_1000_ind_8000() {
    // Checked on a real MM440 (USS.md section 6).
    let task = ParamTask::Read { pnu: pnu(2000) };
    assert_eq!(encoded(task, PkwMode::Four), vec![0x1000, 0x8000, 0, 0]);
    assert_eq!(encoded(task, PkwMode::Three), vec![0x1000, 0x8000, 0]);
}

#[test]
fn read_p1082_reply_decodes_to_50_hz() {
    let reply = ParamReply::decode(&[0x2000 | 1082, 0, 0x4248, 0x0000]).unwrap();
    assert_eq!(reply.pnu, pnu(1082));
    assert_eq!(reply.kind, ReplyKind::Dword(0x4248_0000));
    assert_eq!(reply.kind.value().unwrap().as_f32(), 50.0);
    assert_eq!(Value::from_f32(50.0), Value::Dword(0x4248_0000));
    assert!(reply.answers(&ParamTask::Read { pnu: pnu(1082) }));
}

#[test]
fn task_ids_match_the_table() {
    let p = pnu(700);
    let i = Subindex::new(2).unwrap();
    let w = Value::Word(5);
    let d = Value::Dword(0x0001_0002);
    let cases = [
        (ParamTask::None, 0),
        (ParamTask::Read { pnu: p }, 1),
        (
            ParamTask::Write {
                pnu: p,
                value: w,
                storage: Storage::Ram,
            },
            2,
        ),
        (
            ParamTask::Write {
                pnu: p,
                value: d,
                storage: Storage::Ram,
            },
            3,
        ),
        (ParamTask::ReadDescription { pnu: p, element: i }, 4),
        (ParamTask::ReadArray { pnu: p, index: i }, 6),
        (
            ParamTask::WriteArray {
                pnu: p,
                index: i,
                value: w,
                storage: Storage::Ram,
            },
            7,
        ),
        (
            ParamTask::WriteArray {
                pnu: p,
                index: i,
                value: d,
                storage: Storage::Ram,
            },
            8,
        ),
        (ParamTask::ReadArrayLen { pnu: p }, 9),
        (
            ParamTask::WriteArray {
                pnu: p,
                index: i,
                value: d,
                storage: Storage::RamAndEeprom,
            },
            11,
        ),
        (
            ParamTask::WriteArray {
                pnu: p,
                index: i,
                value: w,
                storage: Storage::RamAndEeprom,
            },
            12,
        ),
        (
            ParamTask::Write {
                pnu: p,
                value: d,
                storage: Storage::RamAndEeprom,
            },
            13,
        ),
        (
            ParamTask::Write {
                pnu: p,
                value: w,
                storage: Storage::RamAndEeprom,
            },
            14,
        ),
    ];
    for (task, id) in cases {
        assert_eq!(task.id(), id, "{task:?}");
        let words = encoded(task, PkwMode::Four);
        assert_eq!(words[0] >> 12, u16::from(id));
        assert_eq!(ParamTask::decode(&words), Ok(task), "{task:?}");
    }
}

#[test]
fn values_sit_where_uss_md_puts_them() {
    let p = pnu(1120);
    let w = ParamTask::Write {
        pnu: p,
        value: Value::Word(0x1234),
        storage: Storage::Ram,
    };
    assert_eq!(encoded(w, PkwMode::Four), vec![0x2000 | 1120, 0, 0, 0x1234]);
    assert_eq!(encoded(w, PkwMode::Three), vec![0x2000 | 1120, 0, 0x1234]);
    let d = ParamTask::Write {
        pnu: p,
        value: Value::from_f32(10.0),
        storage: Storage::Ram,
    };
    assert_eq!(
        encoded(d, PkwMode::Four),
        vec![0x3000 | 1120, 0, 0x4120, 0x0000]
    );
    assert_eq!(
        encoded(d, PkwMode::Variable),
        vec![0x3000 | 1120, 0, 0x4120, 0x0000]
    );
    let mut out = [0u16; 4];
    assert_eq!(
        d.encode(PkwMode::Three, &mut out),
        Err(PkwError::DwordOverThreeWords)
    );
    assert_eq!(d.encode(PkwMode::None, &mut out), Err(PkwError::NoChannel));
    let a = ParamTask::ReadArray {
        pnu: pnu(947),
        index: Subindex::new(3).unwrap(),
    };
    assert_eq!(encoded(a, PkwMode::Four), vec![0x6000 | 947, 0x0003, 0, 0]);
}

#[test]
fn decode_refuses_bad_requests() {
    assert_eq!(
        ParamTask::decode(&[0x3000 | 1120, 0, 5]),
        Err(PkwError::DwordOverThreeWords)
    );
    assert_eq!(
        ParamTask::decode(&[0x5000 | 1, 0, 0, 0]),
        Err(PkwError::UnsupportedTask(5))
    );
    assert_eq!(
        ParamTask::decode(&[0x1000 | 2010, 0, 0, 0]),
        Err(PkwError::PnuPart(2010))
    );
    assert_eq!(
        ParamTask::decode(&[0x1000, 0x00FF, 0, 0]),
        Err(PkwError::Subindex(255))
    );
    assert_eq!(ParamTask::decode(&[0x1000, 0]), Err(PkwError::Words(2)));
    assert_eq!(
        ParamTask::decode(&[0x0123, 0x4567, 0, 0]),
        Ok(ParamTask::None)
    );
}

#[test]
fn replies_encode_by_mode_and_decode_by_length() {
    let word = ParamReply {
        pnu: pnu(700),
        subindex: 0,
        kind: ReplyKind::Word(2),
    };
    let dword = ParamReply {
        pnu: pnu(1082),
        subindex: 0,
        kind: ReplyKind::Dword(0x4248_0000),
    };
    let mut out = [0u16; 4];
    assert_eq!(word.encode(PkwMode::Variable, &mut out), Ok(3));
    assert_eq!(out[..3], [0x1000 | 700, 0, 2]);
    assert_eq!(ParamReply::decode(&out[..3]), Ok(word));
    assert_eq!(word.encode(PkwMode::Four, &mut out), Ok(4));
    assert_eq!(out, [0x1000 | 700, 0, 0, 2]);
    assert_eq!(ParamReply::decode(&out), Ok(word));
    assert_eq!(dword.encode(PkwMode::Variable, &mut out), Ok(4));
    assert_eq!(ParamReply::decode(&out), Ok(dword));
    assert_eq!(
        dword.encode(PkwMode::Three, &mut out),
        Err(PkwError::DwordOverThreeWords)
    );
    let err = ParamReply {
        pnu: pnu(9999),
        subindex: 0,
        kind: ReplyKind::Error(ErrorNumber::IllegalPnu),
    };
    assert_eq!(err.encode(PkwMode::Four, &mut out), Ok(4));
    assert_eq!(out, [0x7000 | (9999 % 2000), 0x2000, 0, 0]);
    assert_eq!(ParamReply::decode(&out), Ok(err));
}

#[test]
fn error_numbers_are_named_and_unknown_ones_kept() {
    for (n, e) in ErrorNumber::NAMED {
        assert_eq!(ErrorNumber::from_number(n), e);
        assert_eq!(e.number(), n);
    }
    assert_eq!(ErrorNumber::from_number(42), ErrorNumber::Other(42));
    assert_eq!(ErrorNumber::Other(42).number(), 42);
    assert_eq!(
        ErrorNumber::from_number(204).to_string(),
        "error 204: access level too low"
    );
}

#[test]
fn reply_matching_checks_family_pnu_and_index() {
    let read = ParamTask::Read { pnu: pnu(1082) };
    let r = |id: u16, p: u16, ind: u16| {
        ParamReply::decode(&[(id << 12) | (p % 2000), ind, 0, 1]).unwrap()
    };
    assert!(r(1, 1082, 0).answers(&read));
    assert!(r(2, 1082, 0).answers(&read));
    assert!(r(7, 1082, 0).answers(&read));
    assert!(r(8, 1082, 0).answers(&read));
    assert!(!r(0, 1082, 0).answers(&read), "AK 0 means busy");
    assert!(!r(1, 1083, 0).answers(&read), "another PNU");
    assert!(!r(6, 1082, 0).answers(&read), "another family");
    assert!(!r(1, 3082, 0x8000).answers(&read), "another page");
    let arr = ParamTask::ReadArray {
        pnu: pnu(947),
        index: Subindex::new(2).unwrap(),
    };
    assert!(r(4, 947, 2).answers(&arr));
    assert!(
        !r(4, 947, 1).answers(&arr),
        "a late reply for another index"
    );
    let write = ParamTask::Write {
        pnu: pnu(1120),
        value: Value::Word(10),
        storage: Storage::RamAndEeprom,
    };
    assert!(r(1, 1120, 0).answers(&write));
    assert!(!r(2, 1120, 0).answers(&write));
    let len = ParamTask::ReadArrayLen { pnu: pnu(947) };
    assert!(r(6, 947, 0).answers(&len));
    assert!(!r(4, 947, 0).answers(&len));
    assert!(!ParamReply::NOT_YET.answers(&ParamTask::None));
}

#[test]
fn a_raw_value_is_a_dword_when_asked_and_a_word_only_when_it_fits() {
    assert_eq!(
        Value::from_raw(0x4248_0000, true),
        Some(Value::Dword(0x4248_0000))
    );
    assert_eq!(Value::from_raw(7, true), Some(Value::Dword(7)));
    assert_eq!(Value::from_raw(0xFFFF, false), Some(Value::Word(0xFFFF)));
    assert_eq!(Value::from_raw(0x1_0000, false), None);
}
