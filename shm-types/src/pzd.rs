//! Process images (USS.md section 7): what a controller wants sent to one drive, and what the
//! drive last replied. PZD word 1 is STW1 / ZSW1, word 2 the main setpoint HSW / actual value
//! HIW, words 3.. follow in `extra`.

use crate::control::{ControlState, LatchReason, Rejection, StopCommand};
use crate::{ContractError, LAYOUT_VERSION, check_version};
#[cfg(feature = "ipc")]
use iceoryx2::prelude::ZeroCopySend;
use uss_control::{Body, DriveImage, Received, Sample, Words};

/// Most PZD words a drive exchanges (USS.md section 3: 0..16, fixed per slave).
pub const MAX_PZD_WORDS: usize = 16;
/// PZD words after the first two.
pub const EXTRA_PZD_WORDS: usize = MAX_PZD_WORDS - 2;

/// `flags` bit of a [`PzdOutput`]: the controller hands the drive back (a clean exit, not a
/// crash). The drive gets its safe command, latched, and the status says "released".
pub const OUTPUT_RELEASE: u8 = 0x01;
/// Every `flags` bit this layout defines.
pub const OUTPUT_FLAGS: u8 = OUTPUT_RELEASE;
/// STW1 bit 10, "control by PLC": with it clear a drive ignores the PZD (USS.md section 7).
pub const STW1_CONTROL_BY_PLC: u16 = 0x0400;
/// STW1 bit 0, ON / OFF1.
pub const STW1_ON: u16 = 0x0001;
/// STW1 bits 8 and 9, jog right and jog left: a jog runs the motor, so a word with either set
/// never re-arms a latched drive.
pub const STW1_JOG: u16 = 0x0300;

// The one test of "is a stop" and "how hard", for ussd and the client rules: the domain's.
pub use uss_control::{is_stop, stop_strength};

// The words written out for the C header (cbindgen does not evaluate calls), the codec's bits.
const _: () = assert!(STW1_CONTROL_BY_PLC == uss_protocol::Stw1::CONTROL_BY_PLC.bits());
const _: () = assert!(STW1_ON == uss_protocol::Stw1::ON.bits());
const _: () =
    assert!(STW1_JOG == uss_protocol::Stw1::JOG_RIGHT.bits() | uss_protocol::Stw1::JOG_LEFT.bits());

/// The controller's output image of one drive, published on `uss/<bus>/drive/<addr>/out`.
///
/// Exactly one controller publishes it (the service admits one publisher). ussd sends the
/// latest words in every telegram to the drive (USS.md section 7: the current STW1 goes in
/// every telegram) while the drive is live. A controller must publish a new `sequence` within
/// the drive's watchdog time; when it stops, the drive gets its configured safe command (OFF1
/// by default), latched until the controller re-arms it with OFF1 then ON (see
/// [`crate::control`]): the re-arming stop names the latch it acknowledges (`latch_id`, read from
/// the input image), so only a stop made after the image showed the latch re-arms it. ussd
/// checks every sample with [`PzdOutput::validate`] before it reaches the wire: a sample the
/// drive would misread is refused and latches the drive too.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("UssPzdOutputV9"))]
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
    /// [`OUTPUT_RELEASE`] or 0.
    pub flags: u8,
    pub reserved: [u8; 6],
    /// The latch this controller acknowledges: the input image's [`PzdInput::latch_id`] as it
    /// showed it (0 = none). A stop re-arms a latched drive only when it names the drive's
    /// current latch; while the drive is live ussd does not look at it.
    pub latch_id: u64,
}

/// The drive's input image, on `uss/<bus>/drive/<addr>/in`, written by ussd after every poll
/// of the drive, good or failed.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("UssPzdInputV9"))]
pub struct PzdInput {
    /// [`LAYOUT_VERSION`].
    pub version: u32,
    /// 1 while the drive answers, 0 after it went offline (USS.md section 4: "slave x does
    /// not respond").
    pub online: u8,
    /// A [`ControlState`] code: 0 live (the controller's words go out), 1 latched.
    pub control: u8,
    /// PZD words in use, counting ZSW1 and HIW (0..=16).
    pub word_count: u8,
    /// A [`LatchReason`] code: why the drive is latched (0 while live).
    pub latch_reason: u8,
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
    /// STW1 of the telegram this poll sent (what the drive was told, whoever decided it).
    pub sent_stw1: u16,
    /// The setpoint HSW of that telegram.
    pub sent_setpoint: u16,
    /// Latches of this drive since ussd started (the start-up latch counts 1). A controller
    /// that sees it grow has been tripped, overridden or refused.
    pub latches: u32,
    /// When the current (or last) latch began, `CLOCK_MONOTONIC` ns.
    pub latched_since_ns: u64,
    /// The operator process behind an override latch, or the controller process whose sample
    /// was refused or who released the drive; 0 when unknown.
    pub latched_by_pid: u32,
    /// The [`StopCommand`] a latched drive gets (0, `NO_STOP_COMMAND`, while live).
    pub latch_command: u8,
    /// The [`Rejection`] of the last refused sample (0 if none was refused).
    pub rejection: u8,
    /// 1 once the drive's first poll decided `online` (answered or not); 0: unknown yet.
    pub known: u8,
    /// Counts (mod 256) the changes of what ussd knows of the drive that clients scale by (its
    /// reference forgotten when it came online, was reset or commissioned, or read anew), as
    /// of this image. A description ([`crate::DriveDiag::info_for`]) of another count is not
    /// this drive's: its reference is not known then.
    pub picture: u8,
    /// `sequence` of the controller's latest sample ussd has taken for this drive (0 = none):
    /// a controller knows from it that ussd has seen a sample (a release, an OFF1).
    pub taken_sequence: u64,
    /// The identity of the current latch (0 while live): `CLOCK_MONOTONIC` ns when it began,
    /// made strictly greater than every earlier latch id of the drive (an earlier ussd's
    /// included, which began earlier). Every latch, a stronger command or a new reason for a
    /// latched drive included, gets a new id. A controller re-arms the drive with a stop that
    /// names it ([`PzdOutput::latch_id`]); a latch id it did not acknowledge is news.
    pub latch_id: u64,
    /// How often ussd expects to poll the drive now, ns: its share of the circulating list at
    /// the measured cycle time (an offline drive: its probe interval). What a client waits for
    /// the drive's next poll (a re-arm, a stop's confirmation), instead of a fixed time: a full
    /// line at 9600 baud polls each drive only every 1.3 s. 0: not known yet.
    pub period_ns: u64,
    /// An online drive's image older than this (`timestamp_ns` to now) is not the drive as it is:
    /// its poll is overdue (two periods and one poll with all its retries). 0: not known yet.
    pub stale_after_ns: u64,
}

/// Whether a drive that is `online` and last answered at `last_ns` is overdue at `now_ns` by
/// ussd's limit `stale_after_ns` for it (0: no limit known yet): the one rule behind
/// [`PzdInput::is_overdue`] and [`crate::DriveDiag::is_overdue`].
pub const fn overdue(online: u8, last_ns: u64, stale_after_ns: u64, now_ns: u64) -> bool {
    online != 0 && stale_after_ns != 0 && now_ns.saturating_sub(last_ns) > stale_after_ns
}

/// The least time a client waits for a poll of a drive to show in its image
/// ([`PzdInput::handshake_ns`]): one second.
pub const MIN_HANDSHAKE_NS: u64 = 1_000_000_000;

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
    /// Nothing written yet: no words, sequence 0. Not a valid sample for a drive with PZD.
    pub const EMPTY: Self = Self {
        version: LAYOUT_VERSION,
        controller_pid: 0,
        sequence: 0,
        timestamp_ns: 0,
        stw1: 0,
        setpoint: 0,
        extra: [0; EXTRA_PZD_WORDS],
        word_count: 0,
        flags: 0,
        reserved: [0; 6],
        latch_id: 0,
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

    /// This sample, naming `latch_id` as the latch its controller acknowledges.
    #[must_use]
    pub const fn naming(self, latch_id: u64) -> Self {
        Self { latch_id, ..self }
    }

    /// The image that hands the drive back ([`OUTPUT_RELEASE`], no words).
    pub fn release(sequence: u64, timestamp_ns: u64, controller_pid: u32) -> Self {
        Self {
            controller_pid,
            sequence,
            timestamp_ns,
            flags: OUTPUT_RELEASE,
            ..Self::EMPTY
        }
    }

    /// All 16 word slots and how many are in use, after checking the version and count:
    /// `let (w, n) = out.words()?; &w[..n]`.
    pub fn words(&self) -> Result<([u16; MAX_PZD_WORDS], usize), ContractError> {
        check_version(self.version)?;
        join(self.stw1, self.setpoint, &self.extra, self.word_count)
    }

    /// What the contract can read of this sample, in the rules' terms: refused for another
    /// layout version, undefined flags or more than 16 words; the rest (the drive's word count,
    /// STW1 bit 10) is the rules' to judge ([`uss_control::Received::check`]).
    pub fn received(&self) -> Received {
        let body = if self.version != LAYOUT_VERSION {
            Err(Rejection::Version)
        } else if self.flags & !OUTPUT_FLAGS != 0 {
            Err(Rejection::Flags)
        } else if self.flags & OUTPUT_RELEASE != 0 {
            Ok(Body::Release)
        } else {
            join(self.stw1, self.setpoint, &self.extra, self.word_count)
                .map(|(words, count)| Body::Words(Words { words, count }))
                .map_err(|_| Rejection::WordCount)
        };
        Received {
            sequence: self.sequence,
            timestamp_ns: self.timestamp_ns,
            pid: self.controller_pid,
            latch_id: self.latch_id,
            body,
        }
    }

    /// Whether ussd would send this sample to a drive with `pzd_words` PZD words, and what it
    /// asks for. The one check both sides use: ussd on every sample it receives, the client API
    /// before it publishes. Refused: another layout version, undefined flags, a word count
    /// other than the drive's, and (with PZD) STW1 without bit 10, which the drive would ignore
    /// together with any stop command in it (USS.md section 7). A release needs no words.
    pub fn validate(&self, pzd_words: usize) -> Result<Body, Rejection> {
        self.received().check(pzd_words)
    }
}

impl From<Sample> for PzdOutput {
    /// The sample as the contract carries it.
    fn from(s: Sample) -> Self {
        let (stw1, setpoint, extra, word_count, flags) = match s.body {
            Body::Words(w) => {
                let (stw1, setpoint, extra, count) = split_words(&w);
                (stw1, setpoint, extra, count, 0)
            }
            Body::Release => (0, 0, [0; EXTRA_PZD_WORDS], 0, OUTPUT_RELEASE),
        };
        Self {
            controller_pid: s.pid,
            sequence: s.sequence,
            timestamp_ns: s.timestamp_ns,
            stw1,
            setpoint,
            extra,
            word_count,
            flags,
            latch_id: s.latch_id,
            ..Self::EMPTY
        }
    }
}

/// The named word fields of `w` (at most 16 words: a longer count is cut, which the rules refuse
/// before a sample is made).
fn split_words(w: &Words) -> (u16, u16, [u16; EXTRA_PZD_WORDS], u8) {
    let mut extra = [0u16; EXTRA_PZD_WORDS];
    extra.copy_from_slice(&w.words[2..]);
    (w.words[0], w.words[1], extra, w.as_slice().len() as u8)
}

impl DriveImage for PzdInput {
    fn latch(&self) -> Option<u64> {
        PzdInput::latch(self)
    }

    fn latch_stop(&self) -> Option<StopCommand> {
        StopCommand::of_code(self.latch_command)
    }
}

impl Default for PzdOutput {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl PzdInput {
    /// The control state by name (`live`, `latched`), `unknown` for a code this layout does not
    /// define.
    pub fn control_name(&self) -> &'static str {
        ControlState::try_from(self.control).map_or("unknown", ControlState::name)
    }

    /// Why the drive is latched, by name (`none` while live), `unknown` for a code this layout
    /// does not define.
    pub fn latch_reason_name(&self) -> &'static str {
        LatchReason::try_from(self.latch_reason).map_or("unknown", LatchReason::name)
    }

    /// Whether `other` shows the drive as this image does: no new reply (`sequence`), and the
    /// same online, control, latch and status word. What tools that follow a drive (trace, the Zenoh
    /// bridge) use to tell a new picture from the one they already have.
    pub const fn same_picture(&self, other: &Self) -> bool {
        self.sequence == other.sequence
            && self.online == other.online
            && self.control == other.control
            && self.latch_id == other.latch_id
            && self.zsw1 == other.zsw1
    }

    /// No reply yet.
    pub const EMPTY: Self = Self {
        version: LAYOUT_VERSION,
        online: 0,
        control: ControlState::Latched.code(),
        word_count: 0,
        latch_reason: LatchReason::Startup.code(),
        sequence: 0,
        timestamp_ns: 0,
        age_ns: 0,
        zsw1: 0,
        hiw: 0,
        extra: [0; EXTRA_PZD_WORDS],
        sent_stw1: 0,
        sent_setpoint: 0,
        latches: 0,
        latched_since_ns: 0,
        latched_by_pid: 0,
        latch_command: crate::control::NO_STOP_COMMAND,
        rejection: Rejection::None.code(),
        known: 0,
        picture: 0,
        taken_sequence: 0,
        latch_id: 0,
        period_ns: 0,
        stale_after_ns: 0,
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

    /// Whether the drive gets its controller's words (not latched).
    pub fn is_live(&self) -> bool {
        self.control == ControlState::Live.code()
    }

    /// Whether the image of an online drive is older at `now_ns` than ussd's limit for it
    /// (`stale_after_ns`): its poll is overdue, the picture is not the drive as it is.
    pub const fn is_overdue(&self, now_ns: u64) -> bool {
        overdue(self.online, self.timestamp_ns, self.stale_after_ns, now_ns)
    }

    /// How long a client waits for what the drive's next poll brings (a re-arm taken, a stop
    /// confirmed, a release shown), ns: ussd's freshness limit for the drive, which covers the
    /// wait for its turn and the poll with all its retries, and never less than
    /// [`MIN_HANDSHAKE_NS`] (the IPC, a busy machine, a limit not known yet).
    pub const fn handshake_ns(&self) -> u64 {
        if self.stale_after_ns > MIN_HANDSHAKE_NS {
            self.stale_after_ns
        } else {
            MIN_HANDSHAKE_NS
        }
    }

    /// The current latch's id, `None` while the drive is live.
    pub fn latch(&self) -> Option<u64> {
        (!self.is_live()).then_some(self.latch_id)
    }

    pub fn control(&self) -> Result<ControlState, crate::UnknownCode> {
        ControlState::try_from(self.control)
    }

    pub fn latch_reason(&self) -> Result<LatchReason, crate::UnknownCode> {
        LatchReason::try_from(self.latch_reason)
    }

    pub fn latch_command(&self) -> Result<StopCommand, crate::UnknownCode> {
        StopCommand::try_from(self.latch_command)
    }

    pub fn rejection(&self) -> Result<Rejection, crate::UnknownCode> {
        Rejection::try_from(self.rejection)
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
    fn stops_are_off1_off2_off3_and_no_jog_or_on() {
        assert!(is_stop(0x047E) && is_stop(0x047C) && is_stop(0x047A));
        assert!(!is_stop(0x047F) && !is_stop(0x057E) && !is_stop(0x067E));
    }

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

    fn sample(words: &[u16]) -> PzdOutput {
        PzdOutput::from_words(words, 1, 0, 7).unwrap()
    }

    #[test]
    fn a_sample_for_the_drive_passes_validation_with_its_words() {
        let s = sample(&[0x047F, 0x2000]).validate(2).unwrap();
        let Body::Words(words) = s else {
            panic!("{s:?}")
        };
        assert_eq!(words.as_slice(), &[0x047F, 0x2000]);
        assert_eq!(PzdOutput::release(9, 0, 7).validate(2), Ok(Body::Release));
        assert!(sample(&[]).validate(0).is_ok(), "a drive without PZD");
    }

    #[test]
    fn samples_the_drive_would_misread_are_rejected_with_their_reason() {
        // An all-zero C struct: version 0.
        let zeroed = PzdOutput {
            version: 0,
            ..PzdOutput::EMPTY
        };
        assert_eq!(zeroed.validate(2), Err(Rejection::Version));
        assert_eq!(PzdOutput::EMPTY.validate(2), Err(Rejection::WordCount));
        assert_eq!(sample(&[0x047F]).validate(2), Err(Rejection::WordCount));
        assert_eq!(
            sample(&[0x047F, 0, 0]).validate(2),
            Err(Rejection::WordCount)
        );
        assert_eq!(
            sample(&[0x0000, 0]).validate(2),
            Err(Rejection::NoPlcControl)
        );
        assert_eq!(
            sample(&[0x007F, 0x2000]).validate(2),
            Err(Rejection::NoPlcControl)
        );
        let mut flagged = sample(&[0x047E, 0]);
        flagged.flags = 0x80;
        assert_eq!(flagged.validate(2), Err(Rejection::Flags));
        let mut foreign = sample(&[0x047E, 0]);
        foreign.version = LAYOUT_VERSION + 1;
        assert_eq!(foreign.validate(2), Err(Rejection::Version));
        let mut huge = sample(&[0x047E, 0]);
        huge.word_count = 17;
        assert_eq!(huge.validate(17), Err(Rejection::WordCount));
    }

    #[test]
    fn foreign_images_with_a_bad_count_or_version_are_refused() {
        let mut out = PzdOutput::EMPTY;
        out.word_count = 17;
        assert_eq!(out.words(), Err(ContractError::PzdWords(17)));
        let mut inp = PzdInput::EMPTY;
        inp.version = 1;
        assert_eq!(
            inp.words(),
            Err(ContractError::Version {
                expected: LAYOUT_VERSION,
                found: 1
            })
        );
    }
}
