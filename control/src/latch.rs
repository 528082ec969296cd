//! Whether a drive gets its controller's words, and why not: the latch's vocabulary, spoken by
//! ussd's [`Gate`](crate) and the client's [`Session`](crate) alike, and carried as bytes by the
//! contract.

use crate::code_table;

code_table! {
    /// Whether a drive gets its controller's words; the `control` byte of the input image and
    /// the diagnostics.
    pub enum ControlState {
        /// The controller's samples go to the drive.
        Live = 0 => "live",
        /// The drive gets a stop command until its controller re-arms it (OFF1, then ON).
        Latched = 1 => "latched",
    }
}

code_table! {
    /// Why a drive is latched; the `latch_reason` byte.
    pub enum LatchReason {
        /// Not latched.
        None = 0 => "none",
        /// ussd started: no controller has armed the drive since.
        Startup = 1 => "ussd started",
        /// The controller stopped publishing within the drive's watchdog time: it froze, hung
        /// or died.
        Stale = 2 => "controller stale",
        /// ussd refused a sample the drive would misread; the `rejection` byte says why.
        Rejected = 3 => "sample rejected",
        /// The controller handed the drive back cleanly (dropped, exited, Ctrl-C).
        Released = 4 => "released",
        /// An operator stopped the drive from another process (`ussctl stop/coast/quick-stop`).
        Override = 5 => "operator stop",
        /// The bus line came back after it was down.
        LineRestored = 6 => "line restored",
        /// An ON was refused: the drive's own telegram monitoring is off, too long or not
        /// verified, and its configuration requires it (`require_monitoring`).
        MonitoringOff = 7 => "telegram monitoring off",
        /// ussd itself could not look for longer than the drive's watchdog time (paused by
        /// SIGSTOP, a suspended machine, a starved CPU): nothing it held from before is fresh.
        Paused = 8 => "ussd paused",
        /// Another controller's sample arrived while the drive was live under its controller,
        /// with no release in between (a controller killed and replaced within the watchdog
        /// time, a crash-restart loop): the new controller must re-arm.
        Replaced = 9 => "controller replaced",
        /// The drive's reference frequency (P2000 / p2000) changed while a controller held it
        /// (a factory reset, a quick commissioning, a power cycle back to the EEPROM's value):
        /// the controller's setpoint was scaled with the old one, so the drive would run at a
        /// speed nobody commanded. The controller re-arms after it scaled again.
        ReferenceChanged = 10 => "reference changed",
    }
}

code_table! {
    /// Why ussd refused a controller's sample; the `rejection` byte.
    pub enum Rejection {
        None = 0 => "none",
        /// `version` is not the layout version ussd speaks.
        Version = 1 => "unknown layout version",
        /// `word_count` differs from the drive's PZD length (P2012).
        WordCount = 2 => "word count differs from the drive's PZD length",
        /// STW1 bit 10 ("control by PLC") is clear: the drive would ignore the PZD, the safe
        /// command included (USS.md section 7).
        NoPlcControl = 3 => "STW1 bit 10 (control by PLC) is clear",
        /// `flags` has bits this layout does not define.
        Flags = 4 => "unknown flags",
    }
}
