//! Process data (PZD): control and status words, the PROFIdrive states and setpoint scaling
//! (USS.md section 7).

use bitflags::bitflags;

bitflags! {
    /// Control word 1 (PZD1, master -> slave).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
    pub struct Stw1: u16 {
        /// ON (1) / OFF1 (0): ramp down and stop.
        const ON = 1 << 0;
        /// 0 = OFF2: coast stop.
        const NO_OFF2 = 1 << 1;
        /// 0 = OFF3: quick stop.
        const NO_OFF3 = 1 << 2;
        const ENABLE_OPERATION = 1 << 3;
        const RFG_ENABLE = 1 << 4;
        const RFG_START = 1 << 5;
        const SETPOINT_ENABLE = 1 << 6;
        /// Fault acknowledge on a rising edge.
        const FAULT_ACK = 1 << 7;
        const JOG_RIGHT = 1 << 8;
        const JOG_LEFT = 1 << 9;
        /// 0 = the slave ignores the PZD.
        const CONTROL_BY_PLC = 1 << 10;
        const REVERSE = 1 << 11;
        const VENDOR_12 = 1 << 12;
        const MOP_UP = 1 << 13;
        const MOP_DOWN = 1 << 14;
        const VENDOR_15 = 1 << 15;
    }
}

impl Stw1 {
    /// 0x047E: OFF1 with everything else enabled; leads S1 -> S2 and stops a running drive.
    pub const READY: Self = Self::from_bits_retain(0x047E);
    /// 0x047F: ON with operation enabled; leads S2 -> S3 -> S4.
    pub const RUN: Self = Self::from_bits_retain(0x047F);
    /// 0x04FE: the fault acknowledge edge (send for a few cycles, then [`Stw1::READY`]).
    pub const ACK_FAULT: Self = Self::from_bits_retain(0x04FE);
    /// 0x047C: OFF2, coast stop.
    pub const COAST: Self = Self::from_bits_retain(0x047C);
    /// 0x047A: OFF3, quick stop.
    pub const QUICK_STOP: Self = Self::from_bits_retain(0x047A);
}

bitflags! {
    /// Status word 1 (PZD1, slave -> master). On MM4/G110 bits 11-15 are alarms, mostly active low:
    /// the names here say what a set bit means.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
    pub struct Zsw1: u16 {
        const READY_TO_SWITCH_ON = 1 << 0;
        const READY_TO_RUN = 1 << 1;
        const OPERATION_ENABLED = 1 << 2;
        const FAULT = 1 << 3;
        const NO_OFF2 = 1 << 4;
        const NO_OFF3 = 1 << 5;
        const SWITCHING_ON_INHIBITED = 1 << 6;
        const WARNING = 1 << 7;
        const AT_SETPOINT = 1 << 8;
        const CONTROL_REQUESTED = 1 << 9;
        const MAX_FREQUENCY_REACHED = 1 << 10;
        /// Active low: 0 = current limit reached.
        const NO_CURRENT_LIMIT = 1 << 11;
        /// Active low: 0 = holding brake active.
        const NO_HOLDING_BRAKE = 1 << 12;
        /// Active low: 0 = motor overload.
        const NO_MOTOR_OVERLOAD = 1 << 13;
        const RUNNING_RIGHT = 1 << 14;
        /// Active low: 0 = inverter overload.
        const NO_INVERTER_OVERLOAD = 1 << 15;
    }
}

/// The PROFIdrive state as it can be read from ZSW1 (USS.md section 7). S5 "switching off" shows
/// as S4 until the ramp ends, since ZSW1 has no bit for it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DriveState {
    /// S1: switching-on inhibited; leave by sending OFF1 with OFF2/OFF3 inactive.
    SwitchingOnInhibited,
    /// S2: ready to switch on.
    ReadyToSwitchOn,
    /// S3: ready for operation.
    ReadyForOperation,
    /// S4: operation enabled (running).
    OperationEnabled,
    /// S5: switching off (OFF1/OFF3 ramp). Only a drive model knows it; ZSW1 alone shows S4.
    SwitchingOff,
    /// Fault active; acknowledge with a rising edge of STW1 bit 7.
    Fault,
    /// None of the state bits is set (a drive still starting up).
    NotReady,
}

impl DriveState {
    /// Reads the state from ZSW1. Also reads MICROMASTER's start-up words correctly (0xFB41 S1,
    /// 0xFB31 S2, 0xFB32 S3, 0xFB34 S4), where bit 0 drops in S3 and S4.
    pub fn from_zsw1(z: Zsw1) -> Self {
        if z.contains(Zsw1::FAULT) {
            Self::Fault
        } else if z.contains(Zsw1::SWITCHING_ON_INHIBITED) {
            Self::SwitchingOnInhibited
        } else if z.contains(Zsw1::OPERATION_ENABLED) {
            Self::OperationEnabled
        } else if z.contains(Zsw1::READY_TO_RUN) {
            Self::ReadyForOperation
        } else if z.contains(Zsw1::READY_TO_SWITCH_ON) {
            Self::ReadyToSwitchOn
        } else {
            Self::NotReady
        }
    }

    /// The short name operators use: S1..S5, "fault", "not ready".
    pub const fn short_name(self) -> &'static str {
        match self {
            Self::SwitchingOnInhibited => "S1",
            Self::ReadyToSwitchOn => "S2",
            Self::ReadyForOperation => "S3",
            Self::OperationEnabled => "S4",
            Self::SwitchingOff => "S5",
            Self::Fault => "fault",
            Self::NotReady => "not ready",
        }
    }

    /// Every state, by [`DriveState::code`].
    pub const ALL: [Self; 7] = [
        Self::NotReady,
        Self::SwitchingOnInhibited,
        Self::ReadyToSwitchOn,
        Self::ReadyForOperation,
        Self::OperationEnabled,
        Self::SwitchingOff,
        Self::Fault,
    ];

    /// The number every front-end gives the state: 1..5 for S1..S5, 6 fault, 0 not ready.
    pub const fn code(self) -> u8 {
        match self {
            Self::NotReady => 0,
            Self::SwitchingOnInhibited => 1,
            Self::ReadyToSwitchOn => 2,
            Self::ReadyForOperation => 3,
            Self::OperationEnabled => 4,
            Self::SwitchingOff => 5,
            Self::Fault => 6,
        }
    }

    /// The state numbered `code` ([`DriveState::code`]).
    pub fn of_code(code: u8) -> Option<Self> {
        Self::ALL.get(usize::from(code)).copied()
    }
}

/// A main setpoint (HSW) or main actual value (HIW): signed 16 bit, 0x4000 = 100 % of the
/// reference (P2000), 0x8000..0x7FFF = -200 % .. +199.99 % (USS.md section 7).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Setpoint(i16);

impl Setpoint {
    /// The raw value of 100 %.
    pub const FULL_SCALE: i16 = 0x4000;

    pub const fn from_raw(raw: i16) -> Self {
        Self(raw)
    }

    /// The word as sent on the wire.
    pub const fn from_word(word: u16) -> Self {
        Self(word as i16)
    }

    pub const fn raw(self) -> i16 {
        self.0
    }

    pub const fn word(self) -> u16 {
        self.0 as u16
    }

    /// A percentage of the reference, rounded and saturated to -200 % .. +199.99 %. NaN gives 0.
    pub fn from_percent(percent: f32) -> Self {
        Self(round_saturating(
            percent * f32::from(Self::FULL_SCALE) / 100.0,
        ))
    }

    /// The setpoint of `percent`, or `None` when the word cannot carry it: not a finite number,
    /// or outside -200 % .. +199.99 % (where [`Setpoint::from_percent`] would saturate).
    pub fn try_from_percent(percent: f32) -> Option<Self> {
        let scaled = percent * f32::from(Self::FULL_SCALE) / 100.0;
        // Rounded half away from zero as `round_saturating` does (`f32::round` is std's, and
        // this crate builds without it): `as` truncates toward zero, so a value in
        // (-32769, 32768) lands in i16's range; NaN and infinities compare false.
        let r = if scaled >= 0.0 {
            scaled + 0.5
        } else {
            scaled - 0.5
        };
        (r > -32769.0 && r < 32768.0).then_some(Self(r as i16))
    }

    pub fn percent(self) -> f32 {
        f32::from(self.0) * 100.0 / f32::from(Self::FULL_SCALE)
    }

    /// A frequency given the reference frequency P2000 in Hz; saturates like [`Setpoint::from_percent`].
    pub fn from_hz(hz: f32, reference_hz: f32) -> Self {
        Self::from_percent(hz / reference_hz * 100.0)
    }

    /// [`Setpoint::try_from_percent`] of `hz` at the reference frequency `reference_hz`.
    pub fn try_from_hz(hz: f32, reference_hz: f32) -> Option<Self> {
        Self::try_from_percent(hz / reference_hz * 100.0)
    }

    /// `f = HSW / 0x4000 x P2000`.
    pub fn hz(self, reference_hz: f32) -> f32 {
        f32::from(self.0) / f32::from(Self::FULL_SCALE) * reference_hz
    }
}

/// Rounds half away from zero and saturates to i16; `as` maps NaN to 0 and clamps infinities.
fn round_saturating(x: f32) -> i16 {
    let r = if x >= 0.0 { x + 0.5 } else { x - 0.5 };
    r as i16
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // the values asserted are exactly representable
mod tests {
    use super::*;

    #[test]
    fn a_setpoint_beyond_the_word_is_none_not_full_scale() {
        assert_eq!(
            Setpoint::try_from_percent(100.0),
            Some(Setpoint::from_raw(0x4000))
        );
        assert_eq!(
            Setpoint::try_from_percent(-200.0),
            Some(Setpoint::from_raw(i16::MIN))
        );
        assert_eq!(
            Setpoint::try_from_percent(199.99),
            Some(Setpoint::from_raw(32766))
        );
        let top = Setpoint::from_raw(i16::MAX);
        assert_eq!(Setpoint::try_from_percent(top.percent()), Some(top));
        for beyond in [200.0, -200.01, 1e30, f32::NAN, f32::INFINITY] {
            assert_eq!(Setpoint::try_from_percent(beyond), None, "{beyond}");
        }
        assert_eq!(Setpoint::try_from_hz(5000.0, 50.0), None);
        assert_eq!(
            Setpoint::try_from_hz(25.0, 50.0),
            Some(Setpoint::from_raw(0x2000))
        );
    }

    #[test]
    fn common_control_words() {
        assert_eq!(Stw1::READY.bits(), 0x047E);
        assert!(!Stw1::READY.contains(Stw1::ON));
        assert!(Stw1::READY.contains(Stw1::CONTROL_BY_PLC | Stw1::NO_OFF2 | Stw1::NO_OFF3));
        assert_eq!(Stw1::RUN, Stw1::READY | Stw1::ON);
        assert_eq!(Stw1::ACK_FAULT, Stw1::READY | Stw1::FAULT_ACK);
        assert_eq!(Stw1::COAST, Stw1::READY - Stw1::NO_OFF2);
        assert_eq!(Stw1::QUICK_STOP, Stw1::READY - Stw1::NO_OFF3);
    }

    /// The Profibus trace of an MM420 start-up in USS.md section 7.
    #[test]
    fn mm420_start_up_trace_states() {
        let s = |z: u16| DriveState::from_zsw1(Zsw1::from_bits_retain(z));
        assert_eq!(s(0xFB41), DriveState::SwitchingOnInhibited);
        assert_eq!(s(0xFB31), DriveState::ReadyToSwitchOn);
        assert_eq!(s(0xFB32), DriveState::ReadyForOperation);
        assert_eq!(s(0xFB34), DriveState::OperationEnabled);
        assert_eq!(s(0x6B37), DriveState::OperationEnabled);
        assert_eq!(s(0xFB3C), DriveState::Fault);
        assert_eq!(s(0x0000), DriveState::NotReady);
        let running = Zsw1::from_bits_retain(0x6B37);
        assert!(
            running.contains(Zsw1::RUNNING_RIGHT | Zsw1::CONTROL_REQUESTED | Zsw1::AT_SETPOINT)
        );
        assert!(!running.contains(Zsw1::NO_INVERTER_OVERLOAD));
        // The STW1 words of that trace: 0x0476 is OFF1 with OFF2/OFF3 inactive and PLC control.
        let off1 = Stw1::from_bits_retain(0x0476);
        assert!(off1.contains(Stw1::NO_OFF2 | Stw1::NO_OFF3 | Stw1::CONTROL_BY_PLC));
        assert!(!off1.contains(Stw1::ON));
    }

    #[test]
    fn setpoint_scaling() {
        assert_eq!(Setpoint::from_percent(100.0).word(), 0x4000);
        assert_eq!(Setpoint::from_percent(-100.0).word(), 0xC000);
        assert_eq!(Setpoint::from_percent(10.0).word(), 0x0666);
        assert_eq!(Setpoint::from_word(0x199A).percent(), 40.002_44);
        assert_eq!(Setpoint::from_hz(25.0, 50.0).word(), 0x2000);
        assert_eq!(Setpoint::from_word(0x2000).hz(50.0), 25.0);
        assert_eq!(
            Setpoint::from_word(0x199A).hz(50.0).to_bits(),
            20.001_22_f32.to_bits()
        );
    }

    #[test]
    fn setpoint_saturates_at_minus_200_and_plus_199_99_percent() {
        assert_eq!(Setpoint::from_percent(250.0).word(), 0x7FFF);
        assert_eq!(Setpoint::from_percent(-250.0).word(), 0x8000);
        assert_eq!(Setpoint::from_percent(-200.0).word(), 0x8000);
        assert_eq!(Setpoint::from_percent(f32::NAN).word(), 0);
        assert_eq!(Setpoint::from_percent(f32::INFINITY).word(), 0x7FFF);
        assert_eq!(Setpoint::from_raw(i16::MIN).percent(), -200.0);
    }
}
