//! One simulated drive: the PROFIdrive state machine driven by STW1, a ramp-function generator,
//! the PKW handshake, telegram monitoring (P2014) and the USS diagnostics r2024..r2031
//! (USS.md sections 5, 6 and 7).
//!
//! The drive is sans-I/O like the codec: the bus hands it validated telegrams and the time, it
//! answers into a caller buffer. Nothing here allocates after construction, so the simulator can
//! run inside the master's real-time thread in tests.

use crate::family::Roles;
use crate::params::{Change, ParamDef, ParamSet, ParamTable};
use core::time::Duration;
use uss_control::DriveFamily;
use uss_protocol::pkw::{ErrorNumber, Value};
use uss_protocol::telegram::{Layout, MAX_PKW_WORDS, MAX_PZD_WORDS, Telegram, encode};
use uss_protocol::{Address, Adr, FrameError, LineError, Setpoint, Stw1, Zsw1};

/// Fault code of "USS (COM link) setpoint fault", a MICROMASTER 4's telegram-off trip (USS.md
/// section 5; other families: [`Roles::telegram_off_fault`]).
pub const FAULT_TELEGRAM_OFF: u16 = 72;
/// Setpoint and actual value within this many Hz set ZSW1 bit 8.
const AT_SETPOINT_TOLERANCE_HZ: f32 = 0.5;

mod pkw;

/// How a simulated drive is set up.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveConfig {
    pub address: Address,
    /// PKW mode (P2013) and PZD words (P2012); the master must use the same.
    pub layout: Layout,
    /// The slave's response delay (end of the request's BCC to the reply's STX), before jitter.
    pub response_delay: Duration,
    /// Up to this much is added to each response delay, uniformly.
    pub response_jitter: Duration,
    /// Telegrams a RAM + EEPROM change stays busy (reply ID 0) before its reply.
    pub eeprom_busy_telegrams: u32,
    /// Telegrams every other task stays busy before its reply (0 = answer at once).
    pub task_busy_telegrams: u32,
    /// The error a dword task over a 3-word PKW gets: 5 on MICROMASTER, 103 on MASTERDRIVES
    /// (USS.md section 6; sources disagree, so it is configurable).
    pub dword_over_three_words: ErrorNumber,
    /// Initial P2014 (ms, 0 = off) for the COM link.
    pub telegram_off_time_ms: u16,
    /// Initial P2000, the reference frequency in Hz (0x4000 = 100 %).
    pub reference_hz: f32,
    /// Whether the drive takes broadcasts (ADR bit 5, USS.md section 3); S110 and G120
    /// firmware 4 do not.
    pub takes_broadcasts: bool,
    /// Which parameters the slave has ([`Personality`]).
    pub personality: Personality,
    /// Parameters it has besides its family's profile.
    pub extra: Extra,
}

/// Parameters a simulated drive has besides its family's profile, by ranges of PNUs
/// (uss-sim's `extra=`, `extra-float=`, `extra-r=`): a drive whose own list is longer than
/// uss-rt's catalogue, as a real drive's is, for the clients that let a drive describe itself
/// (AK 4). They are the simulator's own test parameters, not any real drive's: `words` are
/// settable U16 values (factory setting: their PNU), `floats` settable Float arrays of three
/// elements (factory setting 1.5, limits -1000..=1000), `read_only` U16 actual values (their
/// PNU). A range's PNUs that the profile has already are refused.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub struct Extra {
    pub words: Option<(u16, u16)>,
    pub floats: Option<(u16, u16)>,
    pub read_only: Option<(u16, u16)>,
}

impl Extra {
    /// The definitions these ranges add.
    fn definitions(self) -> Vec<ParamDef> {
        let range = |r: Option<(u16, u16)>| r.into_iter().flat_map(|(a, b)| a..=b);
        let word = |pnu: u16, change| ParamDef {
            pnu,
            name: "uncatalogued (uss-sim's extra)",
            ty: crate::params::DataType::U16,
            elements: 0,
            min: 0.0,
            max: 65535.0,
            allowed: &[],
            default: u32::from(pnu),
            change,
            level: 1,
        };
        let mut defs: Vec<ParamDef> = range(self.words)
            .map(|pnu| word(pnu, Change::Always))
            .collect();
        defs.extend(range(self.read_only).map(|pnu| word(pnu, Change::ReadOnly)));
        defs.extend(range(self.floats).map(|pnu| ParamDef {
            ty: crate::params::DataType::Float,
            elements: 3,
            min: -1000.0,
            max: 1000.0,
            default: 1.5f32.to_bits(),
            ..word(pnu, Change::Always)
        }));
        defs
    }

    /// The parameter set of a drive of `personality` with these extras (made once per kind).
    ///
    /// # Errors
    /// An extra PNU its profile has, or more parameters than a simulated drive holds.
    pub fn param_set(self, personality: Personality) -> Result<&'static ParamSet, String> {
        type Made = Vec<((Personality, Extra), &'static ParamSet)>;
        static MADE: std::sync::Mutex<Made> = std::sync::Mutex::new(Vec::new());
        let base = personality.param_set();
        if self == Self::default() {
            return Ok(base);
        }
        let mut made = MADE
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some((_, set)) = made.iter().find(|(k, _)| *k == (personality, self)) {
            return Ok(set);
        }
        let set = base.with_extra(&self.definitions())?;
        made.push(((personality, self), set));
        Ok(set)
    }
}

/// What kind of USS slave is simulated: its parameters, and how it takes a task it does not
/// know.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Personality {
    /// A drive of a family with a built-in profile (`catalogue/data/*.toml`): its parameters
    /// are its profile's, its behaviour the one its profile names ([`crate::family::Behaviour`]).
    Drive(DriveFamily),
    /// A USS slave that is not a drive of a known family (a pump controller, say): the state
    /// machine and PZD as any USS slave, but only [`GENERIC_PARAMS`] as parameters (values,
    /// no descriptions) and error 0 (illegal parameter number) to the rest. `fragile`: a task
    /// it does not know makes it stop answering for good, as some firmware does.
    Generic { fragile: bool },
}

impl Default for Personality {
    fn default() -> Self {
        Self::MICROMASTER4
    }
}

impl Personality {
    /// A MICROMASTER 4-like drive.
    pub const MICROMASTER4: Self = Self::Drive(DriveFamily::Micromaster4);
    /// A SINAMICS G110: the MICROMASTER 4 numbers, its own firmware version.
    pub const G110: Self = Self::Drive(DriveFamily::G110);
    /// A SINAMICS G120 with a CU240 on USS: speeds in rpm, p2040 monitoring, r0945 faults.
    pub const G120: Self = Self::Drive(DriveFamily::G120);
    /// A SIMOREG DC-Master 6RA70.
    pub const SIMOREG: Self = Self::Drive(DriveFamily::Simoreg);

    /// The family it plays: `generic` for a generic slave.
    pub const fn family(self) -> DriveFamily {
        match self {
            Self::Drive(family) => family,
            Self::Generic { .. } => DriveFamily::Generic,
        }
    }

    /// The parameter set the drive keeps (a generic slave's model runs on a MICROMASTER 4's,
    /// which it never shows).
    pub fn param_set(self) -> &'static ParamSet {
        crate::family::param_set(self.family())
    }

    /// The parameters its drive model uses (its family profile's roles, read once).
    pub fn roles(self) -> &'static Roles {
        crate::family::roles(self.family())
    }
}

/// The parameters of a [`Personality::Generic`] slave: number, value, writable. P1 a device
/// type word, P2 a setpoint word, P3 operating hours as a double word.
pub const GENERIC_PARAMS: [(u16, Value, bool); 3] = [
    (1, Value::Word(0x0A51), false),
    (2, Value::Word(500), true),
    (3, Value::Dword(12_345), false),
];

impl DriveConfig {
    /// A drive with a typical MICROMASTER response: 1 ms response delay, 3 busy telegrams for
    /// EEPROM writes, no telegram monitoring.
    pub fn new(address: Address, layout: Layout) -> Self {
        Self {
            address,
            layout,
            response_delay: Duration::from_millis(1),
            response_jitter: Duration::ZERO,
            eeprom_busy_telegrams: 3,
            task_busy_telegrams: 0,
            dword_over_three_words: ErrorNumber::WrongDataType,
            telegram_off_time_ms: 0,
            reference_hz: 50.0,
            takes_broadcasts: true,
            personality: Personality::MICROMASTER4,
            extra: Extra::default(),
        }
    }
}

/// The drive's state in the PROFIdrive state machine (USS.md section 7).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum State {
    /// S1: switching-on inhibited.
    SwitchingOnInhibited,
    /// S2: ready to switch on.
    ReadyToSwitchOn,
    /// S3: ready for operation.
    ReadyForOperation,
    /// S4: operation enabled.
    OperationEnabled,
    /// S5: ramping down after OFF1 or OFF3.
    SwitchingOff(Stop),
    /// A fault is active; left by a rising edge of STW1 bit 7 once its cause is gone.
    Fault,
}

/// How a drive in S5 is stopping.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Stop {
    /// OFF1: ramp down with P1121, then S2.
    Off1,
    /// OFF3: quick stop with P1135, then S1.
    Off3,
}

impl core::fmt::Display for State {
    /// The state as the manuals name it: "S4 operation enabled", "S5 OFF1 ramp-down", "fault".
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::SwitchingOnInhibited => "S1 switching on inhibited",
            Self::ReadyToSwitchOn => "S2 ready to switch on",
            Self::ReadyForOperation => "S3 ready for operation",
            Self::OperationEnabled => "S4 operation enabled",
            Self::SwitchingOff(Stop::Off1) => "S5 OFF1 ramp-down",
            Self::SwitchingOff(Stop::Off3) => "S5 OFF3 quick stop",
            Self::Fault => "fault",
        })
    }
}

impl State {
    /// Whether the motor is energised (S4 or S5): some parameters cannot be changed then.
    pub const fn is_running(self) -> bool {
        matches!(self, Self::OperationEnabled | Self::SwitchingOff(_))
    }
}

/// Receive statistics kept like r2024..r2031 (USS.md section 7).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Counters {
    pub good: u16,
    pub rejected: u16,
    pub frame: u16,
    pub overrun: u16,
    pub parity: u16,
    pub start: u16,
    pub bcc: u16,
    pub length: u16,
}

impl Counters {
    fn as_array(self) -> [u16; 8] {
        [
            self.good,
            self.rejected,
            self.frame,
            self.overrun,
            self.parity,
            self.start,
            self.bcc,
            self.length,
        ]
    }
}

/// The PKW channel: one task at a time, answered idempotently while the master repeats it.
#[derive(Debug, Clone, Copy, Default)]
struct PkwChannel {
    request: [u16; MAX_PKW_WORDS],
    request_len: usize,
    reply: [u16; MAX_PKW_WORDS],
    reply_len: usize,
    busy_reply: [u16; MAX_PKW_WORDS],
    busy_left: u32,
}

/// One simulated drive.
#[derive(Debug, Clone)]
pub struct Drive {
    config: DriveConfig,
    params: ParamTable,
    state: State,
    frequency_hz: f32,
    stw1: Stw1,
    setpoint: Setpoint,
    fault: Option<u16>,
    pkw: PkwChannel,
    last_valid: Option<Duration>,
    last_tick: Option<Duration>,
    counters: Counters,
    /// The values of a generic slave's parameters ([`GENERIC_PARAMS`]).
    generic: [Value; GENERIC_PARAMS.len()],
    /// A fragile generic slave that met a task it does not know: silent for good.
    dead: bool,
}

impl Drive {
    /// A drive just powered up, in S1. The configured address, layout and telegram-off time are
    /// stored as if commissioned (RAM and EEPROM).
    pub fn new(config: DriveConfig) -> Self {
        let personality = config.personality;
        let roles = personality.roles();
        // Extras are checked when the drive is configured (`SimOptions::apply`).
        let set = config
            .extra
            .param_set(personality)
            .unwrap_or_else(|e| panic!("drive {}: {e}", config.address));
        let mut params = ParamTable::of(set);
        let layout = config.layout;
        let float = |v: f32| v.to_bits();
        let monitoring = match roles.monitoring.and_then(|(pnu, _)| params.definition(pnu)) {
            Some(d) if d.ty == crate::params::DataType::Float => {
                float(f32::from(config.telegram_off_time_ms))
            }
            _ => u32::from(config.telegram_off_time_ms),
        };
        let commissioned = [
            (roles.address, u32::from(config.address.get())),
            (roles.pzd, layout.pzd.get() as u32),
            (roles.pkw, u32::from(layout.pkw.p2013())),
            (roles.monitoring, monitoring),
            (roles.reference.map(|p| (p, 0)), float(config.reference_hz)),
        ];
        for (param, value) in commissioned {
            if let Some((pnu, index)) = param {
                params.set_commissioned(pnu, index, value);
            }
        }
        let identification = crate::family::behaviour(personality.family()).identification();
        for (i, &word) in identification.iter().enumerate() {
            params.set_internal(964, i as u8, u32::from(word));
        }
        let mut drive = Self {
            config,
            params,
            state: State::SwitchingOnInhibited,
            frequency_hz: 0.0,
            stw1: Stw1::empty(),
            setpoint: Setpoint::from_raw(0),
            fault: None,
            pkw: PkwChannel::default(),
            last_valid: None,
            last_tick: None,
            counters: Counters::default(),
            generic: GENERIC_PARAMS.map(|(_, value, _)| value),
            dead: false,
        };
        drive.publish();
        drive
    }

    pub const fn config(&self) -> &DriveConfig {
        &self.config
    }

    pub const fn address(&self) -> Address {
        self.config.address
    }

    pub const fn state(&self) -> State {
        self.state
    }

    /// The output frequency in Hz; negative when running left.
    pub const fn frequency_hz(&self) -> f32 {
        self.frequency_hz
    }

    /// The active fault code, if any.
    pub const fn fault(&self) -> Option<u16> {
        self.fault
    }

    pub const fn counters(&self) -> Counters {
        self.counters
    }

    /// The last control word the drive accepted.
    pub const fn stw1(&self) -> Stw1 {
        self.stw1
    }

    pub const fn params(&self) -> &ParamTable {
        &self.params
    }

    /// The parameter table, for setting a scenario up (as an operator would at the panel).
    pub fn params_mut(&mut self) -> &mut ParamTable {
        &mut self.params
    }

    /// Trips the drive with a fault code (as an overcurrent or the telegram monitor would).
    pub fn trip(&mut self, code: u16) {
        self.trip_with_value(code, 0);
    }

    /// Trips the drive with a fault code and its fault value (r0949). As on MICROMASTER 4, the
    /// fault buffer holds four trips of two faults each, newest first: r0947/r0949 elements 0
    /// and 1 are the latest trip, 2 and 3 the one before, ...; r0948 holds each trip's time in
    /// three words (elements 0..=2 the latest trip's). A second fault while the drive is
    /// already tripped becomes the trip's second fault.
    pub fn trip_with_value(&mut self, code: u16, value: u16) {
        self.state = State::Fault;
        self.frequency_hz = 0.0;
        let f = self.roles().faults;
        if self.fault.is_none() {
            let mut buffers = [
                (f.codes, f.per_trip, f.len),
                (f.values, f.per_trip, f.len),
                (0, 0, 0),
                (0, 0, 0),
                (0, 0, 0),
            ];
            if let Some(times) = f.times {
                // Three time words per trip.
                buffers[2] = (times, 3, f.len / f.per_trip * 3);
            }
            if let Some((ms, days)) = f.received {
                // One runtime per fault, shifted with the codes.
                buffers[3] = (ms, f.per_trip, f.len);
                buffers[4] = (days, f.per_trip, f.len);
            }
            for (pnu, per_trip, len) in buffers.into_iter().filter(|b| b.2 > 0) {
                for i in (per_trip..len).rev() {
                    let older = self.params.get(pnu, i - per_trip).unwrap_or(0);
                    self.params.set_internal(pnu, i, older);
                }
                for i in 0..per_trip {
                    self.params.set_internal(pnu, i, 0);
                }
            }
            self.params.set_internal(f.codes, 0, u32::from(code));
            self.params.set_internal(f.values, 0, u32::from(value));
            self.stamp_received(0);
            if let Some(times) = f.times {
                for (i, word) in fault_time(self.last_tick.unwrap_or_default())
                    .into_iter()
                    .enumerate()
                {
                    self.params.set_internal(times, i as u8, u32::from(word));
                }
            }
        } else if self.params.get(f.codes, 1) == Some(0) && self.fault != Some(code) {
            self.params.set_internal(f.codes, 1, u32::from(code));
            self.params.set_internal(f.values, 1, u32::from(value));
            self.stamp_received(1);
        }
        self.fault = Some(code);
        self.publish();
    }

    /// The drive set up for the line it is on: its baud rate setting (MM4's P2010[0], a
    /// G120's p2020) names the line's rate, as commissioned, where its list has a value for it.
    pub fn commission_line(&mut self, baud: uss_protocol::Baud) {
        if let Some((pnu, index, coding)) = self.roles().baud
            && let Some(value) = coding.of(baud)
        {
            self.params.set_commissioned(pnu, index, u32::from(value));
        }
    }

    /// On SINAMICS, the fault buffer's element `slot` gets the system runtime r2114 (here the
    /// time since the simulator started): its milliseconds of the day (r0948) and days (r2130).
    fn stamp_received(&mut self, slot: u8) {
        if let Some((ms, days)) = self.roles().faults.received {
            let t = self.last_tick.unwrap_or_default().as_millis();
            let (of_day, day) = (t % 86_400_000, t / 86_400_000);
            self.params.set_internal(ms, slot, of_day as u32);
            self.params
                .set_internal(days, slot, day.min(u128::from(u16::MAX)) as u32);
        }
    }

    /// A simulated power cycle: RAM parameters come back from EEPROM, the drive starts in S1
    /// with its receive statistics cleared.
    pub fn power_cycle(&mut self) {
        self.params.power_cycle();
        self.state = State::SwitchingOnInhibited;
        self.frequency_hz = 0.0;
        self.stw1 = Stw1::empty();
        self.setpoint = Setpoint::from_raw(0);
        self.fault = None;
        self.pkw = PkwChannel::default();
        self.last_valid = None;
        self.counters = Counters::default();
        self.publish();
    }

    /// Counts a receive error the drive's UART saw on the bus (every drive hears every byte).
    pub fn count_error(&mut self, error: &FrameError) {
        let c = &mut self.counters;
        match error {
            FrameError::MissingStx(_) | FrameError::StartPauseNotObserved => {
                c.start = c.start.wrapping_add(1);
            }
            FrameError::BadLge(_) | FrameError::ResidualTimeExceeded { .. } => {
                c.length = c.length.wrapping_add(1);
            }
            FrameError::Bcc { .. } => c.bcc = c.bcc.wrapping_add(1),
            FrameError::Line(LineError::Parity) => c.parity = c.parity.wrapping_add(1),
            FrameError::Line(LineError::Framing) => c.frame = c.frame.wrapping_add(1),
            FrameError::Line(LineError::Overrun) => c.overrun = c.overrun.wrapping_add(1),
        }
        c.rejected = c.rejected.wrapping_add(1);
        self.publish_counters();
    }

    /// Counts a telegram the drive received intact but refused (special telegram, wrong length).
    pub fn count_rejected(&mut self) {
        self.counters.rejected = self.counters.rejected.wrapping_add(1);
        self.publish_counters();
    }

    /// Handles a valid telegram addressed to this drive and writes the reply into `out`. Returns
    /// the reply length, or `None` when the drive must stay silent (wrong length for its layout;
    /// counted as rejected). PZD is processed before PKW (USS.md section 7).
    pub fn receive(
        &mut self,
        telegram: &Telegram<'_>,
        now: Duration,
        out: &mut [u8],
    ) -> Option<usize> {
        if self.dead {
            return None;
        }
        self.advance(now);
        let Ok(words) = telegram.words(self.config.layout) else {
            self.counters.length = self.counters.length.wrapping_add(1);
            self.count_rejected();
            return None;
        };
        self.counters.good = self.counters.good.wrapping_add(1);
        if self.apply_pzd(words.pzd()) {
            self.last_valid = Some(now);
        }
        let mut pkw = [0u16; MAX_PKW_WORDS];
        let pkw_len = if words.pkw().is_empty() {
            0
        } else {
            self.handle_pkw(words.pkw(), &mut pkw)
        };
        if self.dead {
            return None;
        }
        self.advance(now);
        let mut pzd = [0u16; MAX_PZD_WORDS];
        let pzd_len = self.config.layout.pzd.get();
        if pzd_len >= 1 {
            pzd[0] = self.zsw1().bits();
        }
        if pzd_len >= 2 {
            pzd[1] = self.actual_value().word();
        }
        let adr = Adr::to(self.config.address);
        // The reply words always fit: at most 4 PKW and 16 PZD words.
        encode(out, adr, &pkw[..pkw_len], &pzd[..pzd_len]).ok()
    }

    /// Processes a broadcast as a drive does: the PZD are taken (STW1 and setpoint, counted for
    /// telegram monitoring), the PKW ignored, nothing is sent. A drive that does not take
    /// broadcasts ([`DriveConfig::takes_broadcasts`]), or whose layout the telegram does not
    /// fit, ignores it.
    pub fn receive_broadcast(&mut self, telegram: &Telegram<'_>, now: Duration) {
        if !self.config.takes_broadcasts || self.dead {
            return;
        }
        self.advance(now);
        let Ok(words) = telegram.words(self.config.layout) else {
            self.counters.length = self.counters.length.wrapping_add(1);
            self.count_rejected();
            return;
        };
        self.counters.good = self.counters.good.wrapping_add(1);
        if self.apply_pzd(words.pzd()) {
            self.last_valid = Some(now);
        }
        self.advance(now);
    }

    /// Applies STW1 and the setpoint. Returns whether the telegram counts for telegram monitoring:
    /// one with STW1 bit 10 = 0 is ignored and counts as missing (USS.md section 5).
    fn apply_pzd(&mut self, pzd: &[u16]) -> bool {
        let Some(&stw_word) = pzd.first() else {
            return true;
        };
        let stw = Stw1::from_bits_retain(stw_word);
        if !stw.contains(Stw1::CONTROL_BY_PLC) {
            return false;
        }
        if self.takes_commands() {
            let rising_ack = stw.contains(Stw1::FAULT_ACK) && !self.stw1.contains(Stw1::FAULT_ACK);
            if rising_ack && self.state == State::Fault {
                self.fault = None;
                self.state = State::SwitchingOnInhibited;
            }
            self.stw1 = stw;
            self.step_state_machine();
        }
        let setpoint_from_link = self
            .roles()
            .setpoint_source
            .is_none_or(|(pnu, uss)| self.param_u32(pnu) == uss);
        if setpoint_from_link && let Some(&hsw) = pzd.get(1) {
            self.setpoint = Setpoint::from_word(hsw);
        }
        self.publish();
        true
    }

    /// Follows STW1 through S1..S5 until the state is stable (0x047F in S2 goes on to S4).
    fn step_state_machine(&mut self) {
        let s = self.stw1;
        let on = s.contains(Stw1::ON);
        let off2 = !s.contains(Stw1::NO_OFF2);
        let off3 = !s.contains(Stw1::NO_OFF3);
        let commissioning = self.params.in_commissioning();
        for _ in 0..4 {
            let next = match self.state {
                State::Fault => State::Fault,
                _ if off2 => State::SwitchingOnInhibited,
                State::SwitchingOnInhibited if !on && !off3 => State::ReadyToSwitchOn,
                State::SwitchingOnInhibited => State::SwitchingOnInhibited,
                State::ReadyToSwitchOn | State::ReadyForOperation if off3 => {
                    State::SwitchingOnInhibited
                }
                State::ReadyToSwitchOn if on && !commissioning => State::ReadyForOperation,
                State::ReadyToSwitchOn => State::ReadyToSwitchOn,
                State::ReadyForOperation if !on => State::ReadyToSwitchOn,
                State::ReadyForOperation if s.contains(Stw1::ENABLE_OPERATION) => {
                    State::OperationEnabled
                }
                State::ReadyForOperation => State::ReadyForOperation,
                State::OperationEnabled | State::SwitchingOff(_) if off3 => {
                    State::SwitchingOff(Stop::Off3)
                }
                State::OperationEnabled if !on => State::SwitchingOff(Stop::Off1),
                State::OperationEnabled | State::SwitchingOff(Stop::Off1)
                    if !s.contains(Stw1::ENABLE_OPERATION) =>
                {
                    // Pulses off: the motor coasts.
                    State::ReadyForOperation
                }
                State::SwitchingOff(Stop::Off1) if on => State::OperationEnabled,
                other => other,
            };
            if next == self.state {
                break;
            }
            self.state = next;
        }
        if !self.state.is_running() {
            self.frequency_hz = 0.0;
        }
    }

    /// Whether the drive takes its commands from USS (P0700 = 5 on a MICROMASTER 4, p0700 = 6
    /// on a G120; a family without a command-source parameter and a generic slave always do).
    fn takes_commands(&self) -> bool {
        match self.config.personality {
            Personality::Generic { .. } => true,
            Personality::Drive(_) => self
                .roles()
                .command_source
                .is_none_or(|(pnu, uss)| self.param_u32(pnu) == uss),
        }
    }

    /// The parameters this drive's model uses.
    fn roles(&self) -> &'static Roles {
        self.config.personality.roles()
    }

    /// The telegram-off time in ms: the family's monitoring parameter, or the configured fixed
    /// time where the family has none.
    fn telegram_off_ms(&self) -> f32 {
        match self.roles().monitoring {
            Some((pnu, index)) => self.params.get_f32(pnu, index).unwrap_or(0.0),
            None => f32::from(self.config.telegram_off_time_ms),
        }
    }

    /// A ramp time in seconds.
    fn ramp_time(&self, pnu: Option<u16>) -> f32 {
        pnu.map_or(0.0, |p| self.param_f32(p) * self.roles().time_unit)
    }

    /// The maximum of the ramp's output: P1082, or the reference where the family has none.
    fn max_output(&self) -> f32 {
        self.roles()
            .max
            .map_or_else(|| self.reference(), |p| self.param_f32(p))
    }

    /// What 0x4000 of the setpoint stands for.
    fn reference(&self) -> f32 {
        self.roles()
            .reference
            .map_or(self.config.reference_hz, |p| self.param_f32(p))
    }

    /// Moves the model to `now`: telegram monitoring and the ramp-function generator.
    pub fn advance(&mut self, now: Duration) {
        let dt = self
            .last_tick
            .map_or(Duration::ZERO, |t| now.saturating_sub(t));
        self.last_tick = Some(self.last_tick.map_or(now, |t| t.max(now)));
        let off_time = self.telegram_off_ms();
        if let Some(last) = self.last_valid {
            let limit = Duration::from_secs_f32(off_time.max(0.0) / 1000.0);
            if off_time > 0.0 && now.saturating_sub(last) > limit && self.state != State::Fault {
                self.trip(self.roles().telegram_off_fault);
                // Monitoring re-arms with the next valid telegram.
                self.last_valid = None;
            }
        }
        self.ramp(dt.as_secs_f32());
        self.publish();
    }

    fn ramp(&mut self, dt: f32) {
        let max = self.max_output().max(0.0);
        if self.state == State::OperationEnabled && !self.stw1.contains(Stw1::RFG_ENABLE) {
            // STW1 bit 4 = 0 sets the ramp-function generator's output to zero at once.
            self.frequency_hz = 0.0;
        }
        let mut target = self.target_hz(max);
        let f = self.frequency_hz;
        // Away from zero is ramping up (P1120); towards zero, a reversal included, is ramping
        // down (P1121) until zero, where the other side begins.
        let reversing = f != 0.0 && target != 0.0 && target.signum() != f.signum();
        if reversing {
            target = 0.0;
        }
        let ramp_time = match self.state {
            State::SwitchingOff(Stop::Off3) => self.ramp_time(self.roles().off3),
            _ if target.abs() > f.abs() => self.ramp_time(Some(self.roles().ramp_up)),
            _ => self.ramp_time(Some(self.roles().ramp_down)),
        };
        // A ramp time too short to matter (down to the smallest float) ends the ramp in one
        // step; the rate is capped so a zero time step never multiplies an infinity into NaN.
        let step = if ramp_time > 0.0 && max > 0.0 {
            (max / ramp_time).min(f32::MAX) * dt
        } else {
            f32::INFINITY
        };
        let delta = target - self.frequency_hz;
        self.frequency_hz = if delta.abs() <= step {
            target
        } else {
            self.frequency_hz + step.copysign(delta)
        };
        if let State::SwitchingOff(stop) = self.state
            && self.frequency_hz == 0.0
        {
            self.state = match stop {
                Stop::Off1 => State::ReadyToSwitchOn,
                Stop::Off3 => State::SwitchingOnInhibited,
            };
        }
    }

    /// Where the ramp is heading: the scaled setpoint in S4, zero otherwise.
    fn target_hz(&self, max: f32) -> f32 {
        let s = self.stw1;
        if self.state != State::OperationEnabled || !s.contains(Stw1::RFG_ENABLE) {
            return 0.0;
        }
        if !s.contains(Stw1::RFG_START) {
            // RFG frozen.
            return self.frequency_hz;
        }
        if !s.contains(Stw1::SETPOINT_ENABLE) {
            return 0.0;
        }
        let mut hz = self.setpoint.hz(self.reference());
        if s.contains(Stw1::REVERSE) {
            hz = -hz;
        }
        let min = self
            .roles()
            .min
            .map_or(0.0, |p| self.param_f32(p))
            .clamp(0.0, max);
        let magnitude = hz.abs().clamp(min, max);
        magnitude.copysign(hz)
    }

    /// ZSW1 as the drive reports it (USS.md section 7).
    pub fn zsw1(&self) -> Zsw1 {
        let mut z = Zsw1::NO_CURRENT_LIMIT
            | Zsw1::NO_HOLDING_BRAKE
            | Zsw1::NO_MOTOR_OVERLOAD
            | Zsw1::NO_INVERTER_OVERLOAD;
        // Control requested: the drive takes its commands from this link (USS on the COM
        // link); with another command source it ignores the control words.
        if self.takes_commands() {
            z |= Zsw1::CONTROL_REQUESTED;
        }
        z |= match self.state {
            State::SwitchingOnInhibited => Zsw1::SWITCHING_ON_INHIBITED,
            State::ReadyToSwitchOn => Zsw1::READY_TO_SWITCH_ON,
            State::ReadyForOperation => Zsw1::READY_TO_SWITCH_ON | Zsw1::READY_TO_RUN,
            State::OperationEnabled | State::SwitchingOff(_) => {
                Zsw1::READY_TO_SWITCH_ON | Zsw1::READY_TO_RUN | Zsw1::OPERATION_ENABLED
            }
            State::Fault => Zsw1::FAULT,
        };
        if self.stw1.contains(Stw1::NO_OFF2) {
            z |= Zsw1::NO_OFF2;
        }
        if self.stw1.contains(Stw1::NO_OFF3) {
            z |= Zsw1::NO_OFF3;
        }
        let max = self.max_output();
        if (self.frequency_hz - self.target_hz(max)).abs() <= AT_SETPOINT_TOLERANCE_HZ {
            z |= Zsw1::AT_SETPOINT;
        }
        if max > 0.0 && self.frequency_hz.abs() >= max {
            z |= Zsw1::MAX_FREQUENCY_REACHED;
        }
        if self.frequency_hz > 0.0 {
            z |= Zsw1::RUNNING_RIGHT;
        }
        z
    }

    /// The main actual value HIW: the output frequency scaled by P2000.
    pub fn actual_value(&self) -> Setpoint {
        Setpoint::from_hz(self.frequency_hz, self.reference())
    }

    fn param_f32(&self, pnu: u16) -> f32 {
        self.params.get_f32(pnu, 0).unwrap_or(0.0)
    }

    fn param_u32(&self, pnu: u16) -> u32 {
        self.params.get(pnu, 0).unwrap_or(0)
    }

    /// Mirrors the model into its read-only parameters r0002, r0021, r0026, r0052, r0054.
    fn publish(&mut self) {
        let z = self.zsw1();
        let roles = self.roles();
        let state = match self.state {
            _ if self.params.in_commissioning() => 0,
            State::Fault => 2,
            State::OperationEnabled => 4,
            State::SwitchingOff(_) => 5,
            _ => 1,
        };
        let dc_link = roles.dc_link.map_or(0.0, |(_, rated)| {
            core::f32::consts::SQRT_2 * self.param_u32(rated) as f32
        });
        for (param, value) in [
            (roles.drive_state, state),
            (roles.dc_link.map(|(r, _)| r), dc_link.to_bits()),
            (roles.actual, self.frequency_hz.to_bits()),
            (roles.status, u32::from(z.bits())),
            (roles.control, u32::from(self.stw1.bits())),
        ] {
            if let Some(pnu) = param {
                self.params.set_internal(pnu, 0, value);
            }
        }
        self.publish_counters();
    }

    fn publish_counters(&mut self) {
        let Some((first, index)) = self.roles().diagnostics else {
            return;
        };
        for (i, value) in self.counters.as_array().into_iter().enumerate() {
            self.params
                .set_internal(first + i as u16, index, u32::from(value));
        }
    }
}

/// A trip's time as r0948 holds it, in the format of the real-time clock P2115 (low byte
/// first: seconds + minutes, hours + days, month + year). The simulator's clock was never set:
/// it counts days from 0 since the simulator started, month and year stay 0.
fn fault_time(since_start: Duration) -> [u16; 3] {
    let s = since_start.as_secs();
    let (seconds, minutes, hours, days) = (s % 60, s / 60 % 60, s / 3600 % 24, s / 86_400);
    let pair = |low: u64, high: u64| (low | (high.min(255) << 8)) as u16;
    [pair(seconds, minutes), pair(hours, days), 0]
}
