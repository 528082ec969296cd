//! The rules a controller follows, written once: [`Session`] decides, from the drive's input
//! image and the time, what a controller publishes and which error its call gets. It does no
//! I/O (no clock, no shared memory, no allocation), so it is tested as a table, and every
//! controller is thin I/O around it: the Rust `uss_client::Controller` (and through it the C
//! ABI, the Python module and the `LinuxCNC` component), the Zenoh bridge and the Zenoh client.
//!
//! The rules (docs/SAFETY.md; ussd's side is [`crate::gate::Gate`]):
//! - **Latch identity.** The input image names the drive's current latch (`latch_id`). Every
//!   sample names the latch this controller acknowledged; ussd re-arms a latched drive only
//!   with a stop that names its current latch. A latch the controller did not acknowledge is
//!   news: every ON fails with [`SessionError::Tripped`] and nothing is published, by a
//!   refresher neither, until [`Session::rearm`] acknowledges it.
//! - **Only an explicit re-arm clears a latch** (SAFETY.md REARM). A session opens
//!   acknowledging nothing: the latch its drive shows then (ussd's start, an operator's stop, a
//!   trip of an earlier controller) is news like any other. Opening, reconnecting, a keepalive,
//!   a refresher or a relay's first sample never re-arm; [`Session::rearm`], called by the
//!   program after the latch was there to see, is the one deliberate act (IEC 60204-1: a reset
//!   never restarts a machine by itself; `PLCopen` `SF_EmergencyStop`: a restart of the
//!   controller is not a reset).
//! - **A re-arm carries the time it was asked.** Every re-arm ([`Session::rearm`], a relay's
//!   [`Session::acknowledge`]) names the moment of the deliberate act behind it (a program's
//!   start, a pin's edge, a remote command) and never clears a latch that began after it: a
//!   stop that lands between the ask and the re-arm wins.
//! - **Re-arm: a stop, then ON.** [`Session::rearm`] acknowledges the latch the image shows and
//!   publishes OFF1 naming it (every other word 0); [`Session::rearmed`] says when ussd took it.
//!   An ON asked of a latched drive waits for that ([`Step::AwaitRearm`]) when a re-arming stop
//!   is out, and fails with [`SessionError::NotArmed`] when none is.
//! - **A stop always goes out** (SAFETY.md STOP-ANYWHERE): OFF1, OFF2 or OFF3 is published
//!   whatever the drive shows and whatever happened (news, a stall); it names the latch this
//!   controller acknowledged, so it re-arms nothing it did not acknowledge.
//! - **The watchdog watches the program.** Only the program's own calls refresh the drive:
//!   [`Session::refresh`] (for a background refresher kept for tools) publishes only while the
//!   program called within the drive's watchdog time, and a call that comes after a longer gap
//!   (a paused process, a stalled thread) is a trip, not a fresh start: it fails with
//!   [`SessionError::Stalled`] and every ON does until [`Session::rearm`].
//! - **Every sample is one ussd takes:** the drive's PZD length, STW1 bit 10, a new sequence
//!   number; words ussd would refuse fail with [`SessionError::Invalid`] before they are sent.
//! - **Release** hands the drive back; nothing is published after it.
//!
//! What ussd's heartbeat says (gone, stopped, line down, a new generation) is the I/O layer's:
//! a restarted ussd latches every drive with a new id, which is news here.

use crate::latch::Rejection;
use crate::sample::{Body, Sample, Words};
use crate::stop::{StopCommand, is_stop};

/// STW1 of the re-arming stop: OFF1 with everything else enabled (0x047E).
pub const REARM_STW1: u16 = 0x047E;
// Written out for the C header (cbindgen does not evaluate calls); the same word as OFF1's.
const _: () = assert!(REARM_STW1 == StopCommand::Off1.stw1());

/// What a controller reads of its drive's input image: the latch it shows. The contract's
/// input image (`uss_shm_types::PzdInput`) is one; a relay's copy of it another.
pub trait DriveImage {
    /// The current latch's id, `None` while the drive is live.
    fn latch(&self) -> Option<u64>;
    /// The stop a latched drive gets (`None` while live, or when the image names none).
    fn latch_stop(&self) -> Option<StopCommand>;
}

/// What an image shows of the latch, and nothing else: an image of a relay's own (a remote
/// controller's copy), or a table's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct LatchView {
    /// The current latch's id, `None` while live.
    pub latch: Option<u64>,
    /// The stop the latch sends.
    pub stop: Option<StopCommand>,
}

impl LatchView {
    /// A live drive.
    pub const LIVE: Self = Self {
        latch: None,
        stop: None,
    };

    /// A drive latched with `stop` since latch `id`.
    pub const fn latched(id: u64, stop: StopCommand) -> Self {
        Self {
            latch: Some(id),
            stop: Some(stop),
        }
    }
}

impl DriveImage for LatchView {
    fn latch(&self) -> Option<u64> {
        self.latch
    }

    fn latch_stop(&self) -> Option<StopCommand> {
        self.stop
    }
}

/// The longest a controller goes between two samples while its program waits inside its own
/// call, or its refresher fills a gap: 20 ms, a fifth of ussd's default watchdog (100 ms).
pub const MAX_REFRESH_NS: u64 = 20_000_000;

/// How often a controller refreshes a drive whose watchdog time is `watchdog_ns`: a quarter of
/// it, at most [`MAX_REFRESH_NS`], never 0. A wait never comes near the watchdog, however short
/// the drive's is (`watchdog_ms` may be as short as 1 ms).
pub const fn refresh_ns(watchdog_ns: u64) -> u64 {
    let quarter = watchdog_ns / 4;
    if quarter == 0 {
        1
    } else if quarter < MAX_REFRESH_NS {
        quarter
    } else {
        MAX_REFRESH_NS
    }
}

/// What a session needs to know of its drive and controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SessionSetup {
    /// PZD words the drive exchanges (P2012); every sample carries exactly these.
    pub pzd: usize,
    /// The controlling process (written into every sample).
    pub pid: u32,
    /// The drive's watchdog time (`DriveInfo::watchdog_ms`), ns: the longest gap between the
    /// program's calls.
    pub watchdog_ns: u64,
    /// The sequence number before the first sample: a clock-based start, so a new controller
    /// never repeats its predecessor's last number (ussd takes a sample only when it changes).
    pub first_sequence: u64,
}

/// What the I/O layer does after a call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// Publish this sample.
    Publish(Sample),
    /// An ON while the re-arming stop is out and ussd has not shown the drive live yet: wait
    /// for the next image and make the same call again (nothing was changed).
    AwaitRearm,
}

/// Why a call publishes nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SessionError {
    /// The image shows a latch this controller has not acknowledged (a trip, an operator's
    /// stop, a restarted ussd): re-arm it ([`Session::rearm`]).
    #[error("the drive latched (latch {latch_id}): re-arm it (OFF1, then ON)")]
    Tripped { latch_id: u64 },
    /// An ON for a latched drive that no re-arming stop of this controller has been sent to.
    #[error("the drive is latched (latch {latch_id}): re-arm it (Session::rearm), then ON")]
    NotArmed { latch_id: u64 },
    /// The program made no call for longer than the drive's watchdog time: a trip.
    #[error(
        "no call for {:.3} s, longer than the drive's watchdog ({:.3} s): a trip; re-arm it (OFF1, then ON)",
        *gap_ns as f64 / 1e9, *watchdog_ns as f64 / 1e9
    )]
    Stalled { gap_ns: u64, watchdog_ns: u64 },
    /// Words ussd would refuse and latch the drive for; nothing was sent.
    #[error("ussd would refuse these words ({0}); nothing was sent")]
    Invalid(Rejection),
    /// A relay named a latch the drive does not show now (an old one, or none).
    #[error("latch {named} is not the drive's current latch ({shown}): nothing was re-armed")]
    NotTheLatch { named: u64, shown: u64 },
    /// The controller handed the drive back.
    #[error("this controller released the drive")]
    Released,
}

/// The client side of one drive's control. See the module documentation.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Session {
    setup: SessionSetup,
    words: Words,
    sequence: u64,
    /// The latch this controller acknowledged (named in every sample); 0 = none.
    acknowledged: u64,
    /// A stop naming `acknowledged` went out while the drive showed that latch.
    rearming: bool,
    /// When the program last called (`None` before its first call).
    last_call_ns: Option<u64>,
    /// The gap that tripped this session, until a re-arm.
    stalled: Option<u64>,
    /// Stops committed so far: an ON that waits for a re-arm (another thread's call) is
    /// dropped when a stop came meanwhile ([`Session::stops`]).
    stops: u64,
    released: bool,
}

impl Session {
    /// A controller that opened its drive: it sends OFF1 (every other word 0) and acknowledges
    /// no latch, so whatever latch the drive shows is news until [`Session::rearm`]. A relay of
    /// a remote controller (the Zenoh bridge) acknowledges the latch its remote controller
    /// names instead ([`Session::acknowledge`]).
    pub fn new(setup: SessionSetup) -> Self {
        Self {
            setup,
            words: stop_words(setup.pzd, REARM_STW1),
            sequence: setup.first_sequence,
            acknowledged: 0,
            rearming: false,
            last_call_ns: None,
            stalled: None,
            stops: 0,
            released: false,
        }
    }

    /// The words this controller sends.
    pub const fn words(&self) -> &Words {
        &self.words
    }

    /// The sequence number of the last sample.
    pub const fn sequence(&self) -> u64 {
        self.sequence
    }

    /// The latch this controller acknowledged (0: none).
    pub const fn acknowledged(&self) -> u64 {
        self.acknowledged
    }

    /// The drive's PZD length.
    pub const fn pzd(&self) -> usize {
        self.setup.pzd
    }

    /// How often this controller refreshes while its program waits inside its own call, or
    /// its refresher fills a gap ([`refresh_ns`] of the drive's watchdog time).
    pub const fn refresh_ns(&self) -> u64 {
        refresh_ns(self.setup.watchdog_ns)
    }

    /// Whether a call at `now_ns` may go on, and what `image` means for it: released, stalled
    /// (with ON), a latch not acknowledged. For programs that read more than they write; it is
    /// no call that keeps the drive refreshed.
    pub fn check(&self, now_ns: u64, image: &impl DriveImage) -> Result<(), SessionError> {
        if self.released {
            return Err(SessionError::Released);
        }
        self.news(image)?;
        match (self.stalled, self.gap(now_ns)) {
            (Some(gap_ns), _) | (None, Some(gap_ns)) => Err(self.stall(gap_ns)),
            (None, None) => Ok(()),
        }
    }

    /// A call of the program at `now_ns` that changes the words with `change` (or only
    /// refreshes them); `image` is the drive's latest input image.
    pub fn publish(
        &mut self,
        now_ns: u64,
        image: &impl DriveImage,
        change: impl FnOnce(&mut Words),
    ) -> Result<Step, SessionError> {
        if self.released {
            return Err(SessionError::Released);
        }
        if let Some(gap_ns) = self.gap(now_ns) {
            self.stalled = Some(gap_ns);
        }
        self.last_call_ns = Some(now_ns);
        let mut next = self.words;
        change(&mut next);
        let sample = self.sample(now_ns, &next)?;
        if !self.is_on(&next) {
            // A stop goes out whatever happened; it names the acknowledged latch, so it
            // re-arms the drive only when that is the latch the drive shows.
            self.rearming = image.latch().is_some_and(|id| id == self.acknowledged);
            self.stops += 1;
            return Ok(Step::Publish(self.commit(next, sample)));
        }
        self.news(image)?;
        if let Some(gap_ns) = self.stalled {
            return Err(self.stall(gap_ns));
        }
        match image.latch() {
            Some(_) if self.rearming => Ok(Step::AwaitRearm),
            Some(latch_id) => Err(SessionError::NotArmed { latch_id }),
            None => Ok(Step::Publish(self.commit(next, sample))),
        }
    }

    /// Whether a call that changes the words with `change` asks for a stop (OFF1, OFF2, OFF3,
    /// or a drive without PZD): what always goes out, whatever ussd's heartbeat says.
    pub fn stops_with(&self, change: impl FnOnce(&mut Words)) -> bool {
        let mut next = self.words;
        change(&mut next);
        !self.is_on(&next)
    }

    /// How many stops this session committed (a count, only ever growing).
    pub const fn stops(&self) -> u64 {
        self.stops
    }

    /// What a background refresher publishes at `now_ns`: the current words again, only while
    /// the program called within the watchdog time and the drive shows no news; `None` else.
    pub fn refresh(&mut self, now_ns: u64, image: &impl DriveImage) -> Option<Sample> {
        let fed = self.last_call_ns.is_some() && self.gap(now_ns).is_none();
        if self.released || self.stalled.is_some() || !fed || self.news(image).is_err() {
            return None;
        }
        // A latched drive gets only the re-arming stop again, never an ON.
        if self.is_on(&self.words) && image.latch().is_some() {
            return None;
        }
        let words = self.words;
        let sample = self.sample(now_ns, &words).ok()?;
        self.sequence = sample.sequence;
        Some(sample)
    }

    /// Acknowledges the latch `image` shows (if any) and re-arms: OFF1 naming it, every other
    /// word 0. Clears a stall. Wait with [`Session::rearmed`] before an ON.
    ///
    /// `asked_ns` is when the deliberate act that asked for the re-arm happened, in the clock of
    /// the image's latch ids (`CLOCK_MONOTONIC` of ussd's host): a program's start for one that
    /// re-arms once it is set up (`ussctl run`), the edge of a pin (`uss_vfd`'s spindle-on), the
    /// remote command's own time (translated by the relay's client), the moment of the call for
    /// a program that re-arms as soon as it decides to. A latch that began after it (an
    /// operator's stop between the ask and the re-arm) is not acknowledged:
    /// [`SessionError::Tripped`], nothing is sent, and the stop stays (SAFETY.md REARM). A latch's
    /// id is the moment it began.
    pub fn rearm(
        &mut self,
        now_ns: u64,
        image: &impl DriveImage,
        asked_ns: u64,
    ) -> Result<Sample, SessionError> {
        self.rearm_with(now_ns, image, asked_ns, REARM_STW1)
    }

    /// Like [`Session::rearm`], with the stop the latch `image` shows as the re-arming words:
    /// a drive latched with OFF2 (coast) or OFF3 (quick stop) keeps it on the wire, live under
    /// this session, so a program that only acknowledges a fault and lets go never weakens it
    /// (and dying meanwhile leaves it: a latch keeps a live controller's own stop). From S1 an
    /// ON then needs OFF1 first ([`Session::rearm`] gives it).
    pub fn rearm_keeping_stop(
        &mut self,
        now_ns: u64,
        image: &impl DriveImage,
        asked_ns: u64,
    ) -> Result<Sample, SessionError> {
        let stw1 = image
            .latch()
            .and_then(|_| image.latch_stop())
            .map_or(REARM_STW1, StopCommand::stw1);
        self.rearm_with(now_ns, image, asked_ns, stw1)
    }

    fn rearm_with(
        &mut self,
        now_ns: u64,
        image: &impl DriveImage,
        asked_ns: u64,
        stw1: u16,
    ) -> Result<Sample, SessionError> {
        if self.released {
            return Err(SessionError::Released);
        }
        began_before(image, asked_ns)?;
        if let Some(latch_id) = image.latch() {
            self.acknowledged = latch_id;
        }
        self.stalled = None;
        self.last_call_ns = Some(now_ns);
        let next = stop_words(self.setup.pzd, stw1);
        let sample = self.sample(now_ns, &next)?;
        self.rearming = image.latch().is_some();
        self.stops += 1;
        Ok(self.commit(next, sample))
    }

    /// For a relay (the Zenoh bridge): acknowledges latch `named`, which the remote controller
    /// names in its sample at `now_ns` for a re-arm it asked for at `asked_ns` (the remote
    /// command's own time, in the clock of the image's latch ids), only when `image` shows it as
    /// the drive's current latch and it began before `asked_ns` ([`SessionError::Tripped`]
    /// else, as [`Session::rearm`]). Like a local [`Session::rearm`] it clears a stall and
    /// counts as a call; the relay's stop then re-arms the drive.
    pub fn acknowledge(
        &mut self,
        now_ns: u64,
        image: &impl DriveImage,
        named: u64,
        asked_ns: u64,
    ) -> Result<(), SessionError> {
        if self.released {
            return Err(SessionError::Released);
        }
        match image.latch() {
            Some(shown) if shown == named => {
                began_before(image, asked_ns)?;
                if self.acknowledged != named {
                    self.acknowledged = named;
                    self.rearming = false;
                }
                self.stalled = None;
                self.last_call_ns = Some(now_ns);
                Ok(())
            }
            shown => Err(SessionError::NotTheLatch {
                named,
                shown: shown.unwrap_or(0),
            }),
        }
    }

    /// Whether the re-arm is done: `Ok(true)` once `image` shows the drive live, `Ok(false)`
    /// while it still shows the acknowledged latch, [`SessionError::Tripped`] for a new latch.
    pub fn rearmed(&mut self, image: &impl DriveImage) -> Result<bool, SessionError> {
        self.news(image)?;
        let live = image.latch().is_none();
        if live {
            self.rearming = false;
        }
        Ok(live)
    }

    /// The release sample at `now_ns`; the session publishes nothing after it.
    pub fn release(&mut self, now_ns: u64) -> Sample {
        self.released = true;
        self.sequence = next(self.sequence);
        Sample {
            sequence: self.sequence,
            timestamp_ns: now_ns,
            pid: self.setup.pid,
            latch_id: self.acknowledged,
            body: Body::Release,
        }
    }

    /// Whether this session has released the drive.
    pub const fn is_released(&self) -> bool {
        self.released
    }

    /// Whether `words` run the drive: anything but a stop (a jog word runs it too).
    fn is_on(&self, words: &Words) -> bool {
        self.setup.pzd > 0 && !is_stop(words.stw1())
    }

    fn news(&self, image: &impl DriveImage) -> Result<(), SessionError> {
        match image.latch() {
            Some(latch_id) if latch_id != self.acknowledged => {
                Err(SessionError::Tripped { latch_id })
            }
            _ => Ok(()),
        }
    }

    /// The gap since the program's last call, when it is longer than the watchdog time.
    fn gap(&self, now_ns: u64) -> Option<u64> {
        let gap = now_ns.saturating_sub(self.last_call_ns?);
        (gap > self.setup.watchdog_ns).then_some(gap)
    }

    const fn stall(&self, gap_ns: u64) -> SessionError {
        SessionError::Stalled {
            gap_ns,
            watchdog_ns: self.setup.watchdog_ns,
        }
    }

    /// The sample `words` make with the next sequence number, as ussd would check it.
    fn sample(&self, now_ns: u64, words: &Words) -> Result<Sample, SessionError> {
        words.check(self.setup.pzd).map_err(SessionError::Invalid)?;
        Ok(Sample {
            sequence: next(self.sequence),
            timestamp_ns: now_ns,
            pid: self.setup.pid,
            latch_id: self.acknowledged,
            body: Body::Words(*words),
        })
    }

    fn commit(&mut self, words: Words, sample: Sample) -> Sample {
        self.words = words;
        self.sequence = sample.sequence;
        sample
    }
}

/// `asked_ns`, a moment on this program's clock, on the clock of the latch ids (ussd's host's
/// `CLOCK_MONOTONIC`, which a program in another time namespace, or on another host, does not
/// share), reckoned from `seen_ns`, a time stamp of that clock (an image's, a heartbeat's)
/// that this program read at `seen_at_ns` on its own. It errs early: the stamp was made before
/// it was read, so a latch that began after the ask is never taken for one before it; the
/// price is a re-arm refused for a latch that began less than the stamp's age before the ask.
pub const fn on_latch_clock(asked_ns: u64, seen_ns: u64, seen_at_ns: u64) -> u64 {
    let ahead = seen_ns as i128 - seen_at_ns as i128;
    let asked = asked_ns as i128 + ahead;
    if asked <= 0 {
        0
    } else if asked >= u64::MAX as i128 {
        u64::MAX
    } else {
        asked as u64
    }
}

/// Whether the latch `image` shows (if any) began before `asked_ns`, the moment the re-arm was
/// asked for: a latch that began after it is news the re-arm must not clear.
fn began_before(image: &impl DriveImage, asked_ns: u64) -> Result<(), SessionError> {
    match image.latch() {
        Some(latch_id) if latch_id > asked_ns => Err(SessionError::Tripped { latch_id }),
        _ => Ok(()),
    }
}

/// The stop `stw1` and every other of `pzd` words 0: nothing of the words before a latch (a
/// setpoint, STW2, a second setpoint) goes out again with a re-arm.
const fn stop_words(pzd: usize, stw1: u16) -> Words {
    Words::stop(pzd, stw1)
}

const fn next(sequence: u64) -> u64 {
    let n = sequence.wrapping_add(1);
    if n == 0 { 1 } else { n }
}

#[cfg(test)]
mod tests;
