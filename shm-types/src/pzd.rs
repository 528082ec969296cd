//! Process images (USS.md section 7): what a controller wants sent to one drive, and what the
//! drive last replied. PZD word 1 is STW1 / ZSW1, word 2 the main setpoint HSW / actual value
//! HIW, words 3.. follow in `extra`.

use crate::{ContractError, LAYOUT_VERSION, check_version};
use iceoryx2::prelude::ZeroCopySend;

/// Most PZD words a drive exchanges (USS.md section 3: 0..16, fixed per slave).
pub const MAX_PZD_WORDS: usize = 16;
/// PZD words after the first two.
pub const EXTRA_PZD_WORDS: usize = MAX_PZD_WORDS - 2;

/// The controller's output image of one drive, published on `uss/<bus>/drive/<addr>/out`.
///
/// Exactly one controller publishes it (the service admits one publisher). ussd sends the
/// latest words in every telegram to the drive (USS.md section 7: the current STW1 goes in
/// every telegram). A controller must publish a new `sequence` within the drive's watchdog
/// time; when it stops, or no controller ever published, the drive gets its configured safe
/// command (OFF1 by default), never a stale "run".
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, ZeroCopySend)]
#[type_name("UssPzdOutputV1")]
pub struct PzdOutput {
    /// [`LAYOUT_VERSION`].
    pub version: u32,
    /// The writing controller's process id (for diagnostics).
    pub controller_pid: u32,
    /// Incremented by the controller with every write; 0 = never written.
    pub sequence: u64,
    /// When the controller wrote, `CLOCK_MONOTONIC` ns.
    pub timestamp_ns: u64,
    /// PZD1: control word STW1.
    pub stw1: u16,
    /// PZD2: main setpoint HSW (0x4000 = 100 % of the reference, USS.md section 7).
    pub setpoint: u16,
    /// PZD3..PZD16.
    pub extra: [u16; EXTRA_PZD_WORDS],
    /// PZD words in use, counting STW1 and setpoint (0..=16); must equal the drive's configured
    /// PZD length (P2012).
    pub word_count: u8,
    pub reserved: [u8; 7],
}

/// The drive's input image, on `uss/<bus>/drive/<addr>/in`, written by ussd after every good
/// reply.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, ZeroCopySend)]
#[type_name("UssPzdInputV1")]
pub struct PzdInput {
    /// [`LAYOUT_VERSION`].
    pub version: u32,
    /// 1 while the drive answers, 0 after it went offline (USS.md section 4: "slave x does
    /// not respond").
    pub online: u8,
    /// 1 while the drive gets its safe command because its controller is stale or absent.
    pub watchdog_tripped: u8,
    /// PZD words in use, counting ZSW1 and HIW (0..=16).
    pub word_count: u8,
    pub reserved: u8,
    /// Good replies so far (the exchange count); 0 = no reply yet.
    pub sequence: u64,
    /// When the reply arrived, `CLOCK_MONOTONIC` ns.
    pub timestamp_ns: u64,
    /// Time since the previous good reply (the drive's update period), ns; 0 for the first.
    pub age_ns: u64,
    /// PZD1: status word ZSW1.
    pub zsw1: u16,
    /// PZD2: main actual value HIW.
    pub hiw: u16,
    /// PZD3..PZD16.
    pub extra: [u16; EXTRA_PZD_WORDS],
}

/// Puts up to 16 PZD words into the named word fields.
fn split(words: &[u16]) -> Result<(u16, u16, [u16; EXTRA_PZD_WORDS], u8), ContractError> {
    if words.len() > MAX_PZD_WORDS {
        return Err(ContractError::PzdWords(words.len()));
    }
    let mut all = [0u16; MAX_PZD_WORDS];
    all[..words.len()].copy_from_slice(words);
    let mut extra = [0u16; EXTRA_PZD_WORDS];
    extra.copy_from_slice(&all[2..]);
    Ok((all[0], all[1], extra, words.len() as u8))
}

/// The named word fields as one array, and the count in use (checked against 16).
fn join(
    first: u16,
    second: u16,
    extra: &[u16; EXTRA_PZD_WORDS],
    count: u8,
) -> Result<([u16; MAX_PZD_WORDS], usize), ContractError> {
    let count = usize::from(count);
    if count > MAX_PZD_WORDS {
        return Err(ContractError::PzdWords(count));
    }
    let mut all = [0u16; MAX_PZD_WORDS];
    all[0] = first;
    all[1] = second;
    all[2..].copy_from_slice(extra);
    Ok((all, count))
}

impl PzdOutput {
    /// Nothing written yet: no words, sequence 0.
    pub const EMPTY: Self = Self {
        version: LAYOUT_VERSION,
        controller_pid: 0,
        sequence: 0,
        timestamp_ns: 0,
        stw1: 0,
        setpoint: 0,
        extra: [0; EXTRA_PZD_WORDS],
        word_count: 0,
        reserved: [0; 7],
    };

    /// An image carrying `words` (PZD1 = STW1 first, at most 16).
    pub fn from_words(
        words: &[u16],
        sequence: u64,
        timestamp_ns: u64,
        controller_pid: u32,
    ) -> Result<Self, ContractError> {
        let (stw1, setpoint, extra, word_count) = split(words)?;
        Ok(Self {
            controller_pid,
            sequence,
            timestamp_ns,
            stw1,
            setpoint,
            extra,
            word_count,
            ..Self::EMPTY
        })
    }

    /// All 16 word slots and how many are in use, after checking the version and count:
    /// `let (w, n) = out.words()?; &w[..n]`.
    pub fn words(&self) -> Result<([u16; MAX_PZD_WORDS], usize), ContractError> {
        check_version(self.version)?;
        join(self.stw1, self.setpoint, &self.extra, self.word_count)
    }
}

impl Default for PzdOutput {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl PzdInput {
    /// No reply yet.
    pub const EMPTY: Self = Self {
        version: LAYOUT_VERSION,
        online: 0,
        watchdog_tripped: 0,
        word_count: 0,
        reserved: 0,
        sequence: 0,
        timestamp_ns: 0,
        age_ns: 0,
        zsw1: 0,
        hiw: 0,
        extra: [0; EXTRA_PZD_WORDS],
    };

    /// An image carrying the reply's `words` (PZD1 = ZSW1 first, at most 16); `online` set.
    pub fn from_words(
        words: &[u16],
        sequence: u64,
        timestamp_ns: u64,
        age_ns: u64,
    ) -> Result<Self, ContractError> {
        let (zsw1, hiw, extra, word_count) = split(words)?;
        Ok(Self {
            online: 1,
            word_count,
            sequence,
            timestamp_ns,
            age_ns,
            zsw1,
            hiw,
            extra,
            ..Self::EMPTY
        })
    }

    /// All 16 word slots and how many are in use, after checking the version and count.
    pub fn words(&self) -> Result<([u16; MAX_PZD_WORDS], usize), ContractError> {
        check_version(self.version)?;
        join(self.zsw1, self.hiw, &self.extra, self.word_count)
    }
}

impl Default for PzdInput {
    fn default() -> Self {
        Self::EMPTY
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_words_round_trip_in_pzd_order() {
        let out = PzdOutput::from_words(&[0x047F, 0x2000, 7], 3, 99, 1234).unwrap();
        assert_eq!((out.stw1, out.setpoint, out.extra[0]), (0x047F, 0x2000, 7));
        assert_eq!((out.word_count, out.sequence, out.timestamp_ns), (3, 3, 99));
        assert_eq!(out.controller_pid, 1234);
        let (w, n) = out.words().unwrap();
        assert_eq!(&w[..n], &[0x047F, 0x2000, 7]);
    }

    #[test]
    fn input_carries_sixteen_words_and_marks_the_drive_online() {
        let words: Vec<u16> = (1..=16).collect();
        let inp = PzdInput::from_words(&words, 5, 10, 20).unwrap();
        assert_eq!((inp.zsw1, inp.hiw, inp.extra[13]), (1, 2, 16));
        assert_eq!((inp.online, inp.word_count, inp.age_ns), (1, 16, 20));
        let (w, n) = inp.words().unwrap();
        assert_eq!(&w[..n], words.as_slice());
    }

    #[test]
    fn seventeen_words_are_refused() {
        assert_eq!(
            PzdOutput::from_words(&[0; 17], 1, 0, 0),
            Err(ContractError::PzdWords(17))
        );
        assert_eq!(
            PzdInput::from_words(&[0; 17], 1, 0, 0),
            Err(ContractError::PzdWords(17))
        );
    }

    #[test]
    fn foreign_images_with_a_bad_count_or_version_are_refused() {
        let mut out = PzdOutput::EMPTY;
        out.word_count = 17;
        assert_eq!(out.words(), Err(ContractError::PzdWords(17)));
        let mut inp = PzdInput::EMPTY;
        inp.version = 2;
        assert_eq!(
            inp.words(),
            Err(ContractError::Version {
                expected: 1,
                found: 2
            })
        );
    }
}
