//! The drive families the simulator plays: each one's parameter set and the parameters its drive
//! model uses (the [`Roles`]): which parameter is the command source, the ramp, the reference,
//! the telegram monitoring, the fault buffer, and in what unit.
//!
//! A family's parameter set is its profile's (`catalogue/data/*.toml`, made by
//! [`ParamSet::of_profile`]): numbers, names, types, limits, settings, factory settings and
//! change rules are written there once. This file adds only behaviour: the roles its profile
//! does not name, the parameters its table consults besides the profile's access level and
//! commissioning parameter, and what makes the unit (its firmware version), as a [`Behaviour`]
//! the profile names (`simulator = "g120"`): a family added as a data file is played without
//! code of its own. What a family's profile does not list, the simulated drive does not have:
//! clients learn such a parameter's type from a real drive's own description (AK 4).

use std::sync::LazyLock;
use uss_catalogue::Catalogue;
use uss_control::DriveFamily;
use uss_protocol::{ParamRef, Subindex};

use crate::params::{
    COM_LINK, MM4_OWN, Own, P0970, P1000, P1080, P1082, P1120, P1121, P1135, P2010, P2011, P2013,
    ParamSet, R0002, R0018, R0021, R0026, R0052, R0054, R0208, R0947, R0948, R0949, R2024,
};

/// How a family's link setting names a baud rate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BaudCoding {
    /// MICROMASTER 4 / G110 P2010: 3 = 1200 ... 9 = 57600 (USS.md section 2).
    P2010,
    /// SINAMICS G120 p2020: 6 = 9600 ... 12 = 115200.
    P2020,
}

impl BaudCoding {
    /// The setting for `baud`, where the family's list names one.
    pub const fn of(self, baud: uss_protocol::Baud) -> Option<u16> {
        match self {
            Self::P2010 => baud.p2010(),
            Self::P2020 => baud.p2020(),
        }
    }
}

/// Where a family keeps its fault buffer: `len` elements of fault codes and of fault values,
/// `per_trip` faults per trip (newest trip first), and on MICROMASTER 4 three time words per
/// trip in r0948; on SINAMICS the system runtime each fault came at, one element per fault
/// (`received`: its milliseconds r0948 and days r2130).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaultBuffer {
    pub codes: u16,
    pub values: u16,
    pub times: Option<u16>,
    pub received: Option<(u16, u16)>,
    pub len: u8,
    pub per_trip: u8,
}

/// The parameters a family's drive model reads and writes itself. Those its family profile
/// names (`uss-catalogue`: the command source, the telegram monitoring and its fault, the
/// reference) come from the profile ([`Roles::with_profile`]); the simulator keeps only the
/// others.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Roles {
    /// The command source and the value that selects this USS link (P0700 = 5 on MM4); `None`:
    /// the drive always takes its commands from the link.
    pub command_source: Option<(u16, u32)>,
    /// The setpoint source and its USS value (P1000 = 5 on MM4); `None`: always the link's.
    pub setpoint_source: Option<(u16, u32)>,
    /// Minimum and maximum of the ramp's output (P1080, P1082), in the reference's unit.
    pub min: Option<u16>,
    pub max: Option<u16>,
    /// Ramp-up, ramp-down and OFF3 ramp-down times (P1120, P1121, P1135).
    pub ramp_up: u16,
    pub ramp_down: u16,
    pub off3: Option<u16>,
    /// Seconds per unit of the ramp times (1 for a float in s, 0.01 for a word in 10 ms).
    pub time_unit: f32,
    /// The reference that 0x4000 of the setpoint stands for (P2000 Hz on MM4, p2000 rpm on
    /// G120); `None`: a fixed reference (the simulator's `ref=`), with no parameter.
    pub reference: Option<u16>,
    /// Telegram monitoring (P2014\[0\] in ms on MM4, p2040 in ms as a float on G120); `None`: a
    /// fixed time (the simulator's `p2014=`), with no parameter.
    pub monitoring: Option<(u16, u8)>,
    /// The link's baud rate setting with its index, and its value for a line's rate (MM4's
    /// P2010[0], a G120's p2020), where the family has one.
    pub baud: Option<(u16, u8, BaudCoding)>,
    /// The link's address, PZD count and PKW count, with their index.
    pub address: Option<(u16, u8)>,
    pub pzd: Option<(u16, u8)>,
    pub pkw: Option<(u16, u8)>,
    /// Actual value, status word 1 and control word 1 as parameters (r0021, r0052, r0054).
    pub actual: Option<u16>,
    /// The drive's state as a number (MM4 r0002: 0 commissioning mode, P0010 not 0; 1 ready; 2
    /// fault active; 4 running; 5 stopping, ramping down. The values as the MM440 parameter
    /// list 6SE6400-5BB00-0BP0 gives r0002; not reached in a stored copy: inferred).
    pub drive_state: Option<u16>,
    /// The DC-link voltage and the rated voltage it is made from (MM4 r0026 from r0208): a
    /// powered unit's DC link charges to the supply's peak, sqrt(2) times its rated voltage
    /// (the simulator's supply is the rated one).
    pub dc_link: Option<(u16, u16)>,
    pub status: Option<u16>,
    pub control: Option<u16>,
    pub faults: FaultBuffer,
    /// The first of the eight USS receive counters r2024..r2031, and its index.
    pub diagnostics: Option<(u16, u8)>,
    /// The fault a telegram-off trip records: F0072 on MM4 ("USS (COM link) setpoint fault"),
    /// F01910 on G120 ("fieldbus: setpoint timeout"), F011 on SIMOREG (telegram failure on
    /// G-SST1).
    pub telegram_off_fault: u16,
}

impl Roles {
    /// These roles with what `profile` names: its command source, its telegram monitoring and
    /// the fault its expiry records, its PZD length, its reference (in Hz, or the speed in rpm).
    #[must_use]
    pub fn with_profile(self, profile: &Catalogue) -> Self {
        let at = |p: ParamRef| (p.pnu.get(), p.index.map_or(0, Subindex::get));
        Self {
            command_source: profile
                .command_source
                .map(|p| p.pnu.get())
                .zip(profile.command_source_uss)
                .or(self.command_source),
            monitoring: profile.monitoring.map(at).or(self.monitoring),
            pzd: profile.pzd_length.map(at).or(self.pzd),
            reference: profile
                .reference
                .or(profile.reference_speed)
                .map(|p| p.pnu.get())
                .or(self.reference),
            telegram_off_fault: profile
                .telegram_off_fault
                .unwrap_or(self.telegram_off_fault),
            ..self
        }
    }
}

/// MICROMASTER 420/430/440: the simulator's own roles; the rest are its profile's.
const MICROMASTER4_OWN: Roles = Roles {
    command_source: None,
    setpoint_source: Some((P1000, 5)),
    min: Some(P1080),
    max: Some(P1082),
    ramp_up: P1120,
    ramp_down: P1121,
    off3: Some(P1135),
    time_unit: 1.0,
    reference: None,
    monitoring: None,
    baud: Some((P2010, COM_LINK, BaudCoding::P2010)),
    address: Some((P2011, COM_LINK)),
    pzd: None,
    pkw: Some((P2013, COM_LINK)),
    actual: Some(R0021),
    drive_state: Some(R0002),
    dc_link: Some((R0026, R0208)),
    status: Some(R0052),
    control: Some(R0054),
    faults: FaultBuffer {
        codes: R0947,
        values: R0949,
        times: Some(R0948),
        received: None,
        len: 8,
        per_trip: 2,
    },
    diagnostics: Some((R2024, COM_LINK)),
    telegram_off_fault: 0,
};

/// r0018 of the simulated G110: firmware 1.18.
const G110_FIRMWARE: u32 = 1.18f32.to_bits();

/// r0018 of the simulated MICROMASTER 4: firmware 2.09.
const MM4_FIRMWARE: u32 = 2.09f32.to_bits();

/// p0700 = 6 and p1000 = 6: commands and speed setpoint from the fieldbus (the CU240's USS).
const G120_FIELDBUS: u32 = 6;
const R0945: u16 = 945;
/// The day count of each fault's time on SINAMICS (r0948 its milliseconds).
const R2130: u16 = 2130;
const P2020: u16 = 2020;
const P2021: u16 = 2021;
const P2023: u16 = 2023;

/// What a SINAMICS G120's table consults besides its profile (speeds in rpm, p2000 the
/// reference speed, fieldbus p2020..p2023 with p2030 = 1 USS, monitoring p2040 in ms as a float,
/// fault buffer r0945 / r0949 with 8 fault cases of 8 faults): the p0970 reset; firmware 4.7
/// (r0018 = 4070000).
const G120_OWN_PARAMS: Own = Own {
    change_rights: None,
    factory_reset: Some(P0970),
    save: None,
    start: &[(R0018, 4_070_000)],
};

/// The G120's device identification r0964 as the simulator reports it (device type and firmware
/// date are the simulator's own).
pub const G120_IDENTIFICATION: [u16; 7] = [42, 0, 470, 2016, 1801, 1, 0];

/// The G120's own roles; the rest are its profile's.
const G120_OWN: Roles = Roles {
    command_source: None,
    setpoint_source: Some((P1000, G120_FIELDBUS)),
    min: Some(P1080),
    max: Some(P1082),
    ramp_up: P1120,
    ramp_down: P1121,
    off3: Some(P1135),
    time_unit: 1.0,
    reference: None,
    monitoring: None,
    baud: Some((P2020, 0, BaudCoding::P2020)),
    address: Some((P2021, 0)),
    pzd: None,
    pkw: Some((P2023, 0)),
    actual: Some(R0021),
    drive_state: None,
    dc_link: None,
    status: Some(R0052),
    control: Some(R0054),
    faults: FaultBuffer {
        codes: R0945,
        values: R0949,
        times: None,
        received: Some((R0948, R2130)),
        len: 64,
        per_trip: 8,
    },
    diagnostics: None,
    telegram_off_fault: 0,
};

const P303: u16 = 303;
const P304: u16 = 304;
const P782: u16 = 782;
const R947: u16 = 947;
const R949: u16 = 949;

/// SIMOREG DC-Master 6RA70, as far as its profile (`catalogue/data/simoreg.toml`) lists it:
/// the ramp-function generator's ramp-up and ramp-down times (words in 10 ms), the PKW length
/// of the first USS interface (P782: 0, 3, 4 or 127), and the fault memory r947 with the fault
/// values r949 (8 faults per fault case). Its speed setpoint is a share of the rated speed
/// (0x4000 = 100 %); it has no command-source parameter and no telegram monitoring parameter
/// the simulator plays. Its table consults nothing besides its profile.
const SIMOREG_OWN_PARAMS: Own = Own {
    change_rights: None,
    factory_reset: None,
    save: None,
    start: &[],
};

/// The SIMOREG's roles: its profile names none of them (the telegram failure on G-SST1 is
/// F011 in its operating instructions; the simulator's own).
const SIMOREG_OWN: Roles = Roles {
    command_source: None,
    setpoint_source: None,
    min: None,
    max: None,
    ramp_up: P303,
    ramp_down: P304,
    off3: None,
    time_unit: 0.01,
    reference: None,
    monitoring: None,
    baud: None,
    address: None,
    pzd: None,
    pkw: Some((P782, 0)),
    actual: None,
    drive_state: None,
    dc_link: None,
    status: None,
    control: None,
    faults: FaultBuffer {
        codes: R947,
        values: R949,
        times: None,
        received: None,
        len: 64,
        per_trip: 8,
    },
    diagnostics: None,
    telegram_off_fault: 11,
};

/// How the simulator plays a family's drive beyond its profile: the roles the profile does not
/// name, the parameters its table consults, what makes the unit (its firmware). A family's
/// profile names the behaviour it is played with (`simulator = "g120"`), so a family added as a
/// data file is simulated without code; the G110 shares the MICROMASTER 4's profile and differs
/// in its firmware alone.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Behaviour {
    Micromaster4,
    G110,
    G120,
    Simoreg,
}

impl Behaviour {
    /// The behaviour a profile's `simulator` names.
    #[must_use]
    pub fn named(name: &str) -> Option<Self> {
        Some(match name {
            "micromaster4" => Self::Micromaster4,
            "g110" => Self::G110,
            "g120" => Self::G120,
            "simoreg" => Self::Simoreg,
            _ => return None,
        })
    }

    /// The behaviour `family`'s drive is played with: its profile's `simulator` (the G110: its
    /// own firmware on the MICROMASTER 4's profile).
    #[must_use]
    pub fn of(family: DriveFamily) -> Self {
        if family == DriveFamily::G110 {
            return Self::G110;
        }
        Catalogue::of(family)
            .and_then(|c| c.simulator.as_deref())
            .and_then(Self::named)
            .unwrap_or(Self::Micromaster4)
    }

    fn own_params(self) -> Own {
        match self {
            Self::Micromaster4 => Own {
                // A 400 V unit (MM440 6SE6440-2UD..: 380..480 V 3AC).
                start: &[(R0018, MM4_FIRMWARE), (R0208, 400)],
                ..MM4_OWN
            },
            Self::G110 => Own {
                // A 230 V unit (G110: 200..240 V 1AC).
                start: &[(R0018, G110_FIRMWARE), (R0208, 230)],
                ..MM4_OWN
            },
            Self::G120 => G120_OWN_PARAMS,
            Self::Simoreg => SIMOREG_OWN_PARAMS,
        }
    }

    const fn own_roles(self) -> Roles {
        match self {
            Self::Micromaster4 | Self::G110 => MICROMASTER4_OWN,
            Self::G120 => G120_OWN,
            Self::Simoreg => SIMOREG_OWN,
        }
    }

    /// What the drive reports of itself beyond its parameters' start values: the G120's device
    /// identification r0964 (element, word).
    #[must_use]
    pub fn identification(self) -> &'static [u16] {
        match self {
            Self::G120 => &G120_IDENTIFICATION,
            _ => &[],
        }
    }
}

/// A family the simulator plays: its parameter set and roles, made from its profile once.
struct Simulated {
    family: DriveFamily,
    behaviour: Behaviour,
    params: ParamSet,
    roles: Roles,
}

/// Every family with a profile, made before any drive runs (at the first drive).
static SIMULATED: LazyLock<Vec<Simulated>> = LazyLock::new(|| {
    DriveFamily::ALL
        .iter()
        .filter_map(|&family| {
            let profile = Catalogue::of(family)?;
            let behaviour = Behaviour::of(family);
            Some(Simulated {
                family,
                behaviour,
                params: ParamSet::of_profile(family.name(), profile, behaviour.own_params()),
                roles: behaviour.own_roles().with_profile(profile),
            })
        })
        .collect()
});

fn simulated(family: DriveFamily) -> &'static Simulated {
    SIMULATED
        .iter()
        .find(|s| s.family == family)
        .or_else(|| {
            SIMULATED
                .iter()
                .find(|s| s.family == DriveFamily::Micromaster4)
        })
        .unwrap_or_else(|| unreachable!("the MICROMASTER 4 has a built-in profile (tested)"))
}

/// The parameter set of `family`'s simulated drive (a family without a profile, `generic`:
/// the MICROMASTER 4's, which a generic slave's model runs on and never shows).
#[must_use]
pub fn param_set(family: DriveFamily) -> &'static ParamSet {
    &simulated(family).params
}

/// The behaviour `family`'s drive is played with (a generic slave's: a MICROMASTER 4's).
#[must_use]
pub fn behaviour(family: DriveFamily) -> Behaviour {
    simulated(family).behaviour
}

/// The parameters `family`'s drive model uses (its profile's roles, and its behaviour's).
#[must_use]
pub fn roles(family: DriveFamily) -> &'static Roles {
    &simulated(family).roles
}
