//! Decodes 0 to 5 arbitrary PKW words as a task and as a reply (USS.md section 6). Decoding must
//! never panic; whatever decodes must encode again in a width that fits it and decode back to the
//! same value, the re-encoding being canonical.
//!
//! Input: one byte whose value mod 6 is the word count, then the words high byte first.
#![no_main]

use libfuzzer_sys::fuzz_target;
use uss_protocol::{ParamReply, ParamTask, PkwError, PkwMode};

fn check_task(words: &[u16]) -> Option<ParamTask> {
    let task = ParamTask::decode(words).ok()?;
    // Only 3 or 4 words decode, and a task that decodes from them fits that width again.
    let modes: &[PkwMode] = if words.len() == 3 {
        &[PkwMode::Three]
    } else {
        &[PkwMode::Four, PkwMode::Variable]
    };
    for &mode in modes {
        let mut out = [0u16; 4];
        let n = task
            .encode(mode, &mut out)
            .expect("a decoded task encodes in its own width");
        assert_eq!(n, words.len(), "{task:?} in {mode:?}");
        assert_eq!(ParamTask::decode(&out[..n]), Ok(task), "{mode:?}");
        assert_eq!(u16::from(task.id()), out[0] >> 12);
    }
    Some(task)
}

fn check_reply(words: &[u16]) -> Option<ParamReply> {
    let reply = ParamReply::decode(words).ok()?;
    assert_eq!(u16::from(reply.kind.id()), words[0] >> 12);
    let _ = reply.kind.value().map(|v| (v.as_f32(), v.as_u32()));
    for mode in [PkwMode::Three, PkwMode::Four, PkwMode::Variable] {
        let mut out = [0u16; 4];
        match reply.encode(mode, &mut out) {
            Ok(n) => assert_eq!(ParamReply::decode(&out[..n]), Ok(reply), "{mode:?}"),
            // Only a double word can fail to fit, and only the 3-word channel.
            Err(e) => {
                assert_eq!(e, PkwError::DwordOverThreeWords, "{reply:?} in {mode:?}");
                assert_eq!(mode, PkwMode::Three);
            }
        }
    }
    Some(reply)
}

fuzz_target!(|input: &[u8]| {
    let Some((&count, rest)) = input.split_first() else {
        return;
    };
    let mut buf = [0u16; 5];
    for (word, pair) in buf.iter_mut().zip(rest.chunks(2)) {
        *word = u16::from_be_bytes([pair[0], pair.get(1).copied().unwrap_or(0)]);
    }
    let words = &buf[..usize::from(count % 6)];
    let task = check_task(words);
    let reply = check_reply(words);
    if let (Some(task), Some(reply)) = (task, reply) {
        // A request read back as a reply: matching must not panic, and no reply completes AK 0.
        let answered = reply.answers(&task);
        assert!(!answered || task != ParamTask::None);
    }
});
