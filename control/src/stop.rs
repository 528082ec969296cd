//! The stops: OFF1, OFF2 and OFF3 as a command, and what a control word does (USS.md section 7),
//! read from the codec's [`Stw1`]: the one test of "is a stop" and "how hard" for ussd and for
//! every controller.

use crate::code_table;
use uss_protocol::Stw1;

/// The byte of a stop command field that carries none ([`StopCommand`] has no "none": a live
/// drive gets no stop command, and a byte of 0 says so).
pub const NO_STOP_COMMAND: u8 = 0;

code_table! {
    /// A stop command: what a latched drive gets, and what an operator asks for. A byte that
    /// carries one is [`NO_STOP_COMMAND`] where there is none (a live drive).
    pub enum StopCommand {
        /// OFF1: ramp down along the ramp-down time (STW1 0x047E).
        Off1 = 1 => "OFF1",
        /// OFF2: coast, the motor is switched off at once (STW1 0x047C).
        Off2 = 2 => "OFF2",
        /// OFF3: quick stop along the OFF3 ramp (STW1 0x047A).
        Off3 = 3 => "OFF3",
    }
}

/// Whether control word `stw1` is a stop (OFF1, OFF2, OFF3): ON and both jog bits clear (a jog
/// runs the motor). Only a stop that names the drive's current latch re-arms a latched drive.
pub const fn is_stop(stw1: u16) -> bool {
    !Stw1::from_bits_retain(stw1).intersects(Stw1::ON.union(Stw1::JOG_RIGHT).union(Stw1::JOG_LEFT))
}

/// How strongly control word `stw1` stops the drive, as [`StopCommand::strength`]: 3 for OFF2
/// (bit 1 clear: coast, whatever else is set), 2 for OFF3 (bit 2 clear: quick stop), 1 for OFF1
/// (a stop by [`is_stop`]), 0 for a word that runs the motor (ON, a jog).
pub const fn stop_strength(stw1: u16) -> u8 {
    let word = Stw1::from_bits_retain(stw1);
    if !word.contains(Stw1::NO_OFF2) {
        StopCommand::Off2.strength()
    } else if !word.contains(Stw1::NO_OFF3) {
        StopCommand::Off3.strength()
    } else if is_stop(stw1) {
        StopCommand::Off1.strength()
    } else {
        0
    }
}

impl StopCommand {
    /// The operator's commands, weakest first: a latched drive keeps the strongest it was given
    /// (OFF2 switches the pulses off at once, OFF3 brakes hard, OFF1 ramps).
    pub const fn strength(self) -> u8 {
        match self {
            Self::Off1 => 1,
            Self::Off3 => 2,
            Self::Off2 => 3,
        }
    }

    /// The control word that carries the command out (USS.md section 7); bit 10 is set, so
    /// the drive does not ignore it.
    pub const fn stw1(self) -> u16 {
        match self {
            Self::Off1 => Stw1::READY.bits(),
            Self::Off2 => Stw1::COAST.bits(),
            Self::Off3 => Stw1::QUICK_STOP.bits(),
        }
    }

    /// The command stop word `stw1` carries out, the strongest of its bits (OFF2 over OFF3 over
    /// OFF1, as [`stop_strength`]); `None` for a word that runs the motor.
    pub const fn of_stw1(stw1: u16) -> Option<Self> {
        match stop_strength(stw1) {
            3 => Some(Self::Off2),
            2 => Some(Self::Off3),
            1 => Some(Self::Off1),
            _ => None,
        }
    }

    /// The command a byte carries, `None` for [`NO_STOP_COMMAND`] (or a byte no command has).
    pub fn of_code(code: u8) -> Option<Self> {
        Self::try_from(code).ok()
    }

    /// The byte that carries `command`: its code, [`NO_STOP_COMMAND`] for none (the inverse of
    /// [`Self::of_code`]).
    pub const fn code_of(command: Option<Self>) -> u8 {
        match command {
            Some(c) => c.code(),
            None => NO_STOP_COMMAND,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every control word there is: what it stops, and the command it carries out, agree; a
    /// command's own word stops as hard as it says and carries bit 10.
    #[test]
    fn every_control_word_stops_as_its_bits_say() {
        for stw1 in 0..=u16::MAX {
            let word = Stw1::from_bits_retain(stw1);
            let strength = stop_strength(stw1);
            let (off2, off3) = (!word.contains(Stw1::NO_OFF2), !word.contains(Stw1::NO_OFF3));
            assert_eq!(
                strength == 3,
                off2,
                "{stw1:#06x}: OFF2, whatever else is set"
            );
            assert_eq!(strength == 2, !off2 && off3, "{stw1:#06x}: OFF3");
            assert_eq!(
                strength == 0,
                !is_stop(stw1) && !off2 && !off3,
                "{stw1:#06x}: runs"
            );
            assert_eq!(
                StopCommand::of_stw1(stw1).map(StopCommand::strength),
                (strength > 0).then_some(strength),
                "{stw1:#06x}"
            );
        }
        for command in StopCommand::ALL {
            let stw1 = command.stw1();
            assert_eq!(StopCommand::of_stw1(stw1), Some(*command));
            assert!(Stw1::from_bits_retain(stw1).contains(Stw1::CONTROL_BY_PLC));
            assert!(is_stop(stw1));
        }
    }
}
