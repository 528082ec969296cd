//! The drive families the simulator plays: each one's parameter set and the parameters its drive
//! model uses (the [`Roles`]): which parameter is the command source, the ramp, the reference,
//! the telegram monitoring, the fault buffer, and in what unit.
//!
//! The numbers come from the families' parameter lists as uss-rt's catalogues give them
//! (`catalogue/data/*.toml`; `catalogue/tests/simulator.rs` checks that every parameter a
//! catalogue lists is in the simulator's set of that family with the same type, array size and
//! change rule). Where a family's parameter is not known for certain, the simulator leaves it
//! out or plays it as "a parameter of this kind", and the catalogue does not list it: clients
//! then learn its type from the drive's own description (AK 4), as they would on a real drive.

use std::sync::LazyLock;
use uss_catalogue::Catalogue;
use uss_protocol::{ParamRef, Subindex};

use crate::params::{
    Change, Consulted, DataType, P0003, P0010, P0700, P0970, P1000, P1080, P1082, P1120, P1121,
    P1135, P2000, P2011, P2012, P2013, ParamDef, ParamSet, R0018, R0021, R0052, R0054, R0947,
    R0948, R0949, R2024, U16_MAX,
};

/// Where a family keeps its fault buffer: `len` elements of fault codes and of fault values,
/// `per_trip` faults per trip (newest trip first), and on MICROMASTER 4 three time words per
/// trip in r0948.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaultBuffer {
    pub codes: u16,
    pub values: u16,
    pub times: Option<u16>,
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
    /// Telegram monitoring (P2014[1] in ms on MM4, p2040 in ms as a float on G120); `None`: a
    /// fixed time (the simulator's `p2014=`), with no parameter.
    pub monitoring: Option<(u16, u8)>,
    /// The link's address, PZD count and PKW count, with their index.
    pub address: Option<(u16, u8)>,
    pub pzd: Option<(u16, u8)>,
    pub pkw: Option<(u16, u8)>,
    /// Actual value, status word 1 and control word 1 as parameters (r0021, r0052, r0054).
    pub actual: Option<u16>,
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
    /// the fault its expiry records, its reference (in Hz, or the speed in rpm).
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

/// Index 1 of the MM4's USS parameters: the COM link (RS485).
const COM_LINK: u8 = 1;

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
    address: Some((P2011, COM_LINK)),
    pzd: Some((P2012, COM_LINK)),
    pkw: Some((P2013, COM_LINK)),
    actual: Some(R0021),
    status: Some(R0052),
    control: Some(R0054),
    faults: FaultBuffer {
        codes: R0947,
        values: R0949,
        times: Some(R0948),
        len: 8,
        per_trip: 2,
    },
    diagnostics: Some((R2024, COM_LINK)),
    telegram_off_fault: 0,
};

/// MICROMASTER 420/430/440 (and G110), with what its profile names.
pub static MICROMASTER4_ROLES: LazyLock<Roles> =
    LazyLock::new(|| MICROMASTER4_OWN.with_profile(Catalogue::micromaster4()));

/// A list of `N` parameters copied from `list` with r0018 (the firmware version) set to
/// `firmware`.
const fn with_firmware<const N: usize>(list: &[ParamDef], firmware: f32) -> [ParamDef; N] {
    let mut out = [list[0]; N];
    let mut i = 0;
    while i < N {
        out[i] = list[i];
        if list[i].pnu == R0018 {
            out[i] = out[i].default_f32(firmware);
        }
        i += 1;
    }
    out
}

const G110_DEFS: [ParamDef; crate::params::DEFS_LEN] =
    with_firmware(crate::params::DEFINITIONS_CONST, 1.18);

/// SINAMICS G110: the MICROMASTER 4 parameter numbers (its list shares them), firmware 1.18.
pub static G110: ParamSet = ParamSet::new("g110", &G110_DEFS, crate::params::MM4_CONSULTED);

/// p0700 = 6 and p1000 = 6: commands and speed setpoint from the fieldbus (the CU240's USS).
const G120_FIELDBUS: u32 = 6;
const R0945: u16 = 945;
const R0964: u16 = 964;
const P2020: u16 = 2020;
const P2021: u16 = 2021;
const P2022: u16 = 2022;
const P2023: u16 = 2023;
const P2030: u16 = 2030;
const P2040: u16 = 2040;
const R2122: u16 = 2122;
/// Speeds up to 210 000 rpm, times up to 999 999 s (the G120 list's limits).
const SPEED_MAX: f64 = 210_000.0;
const TIME_MAX: f64 = 999_999.0;

/// SINAMICS G120 with a CU240 on RS485: speeds in rpm (p2000 is the reference speed), the
/// fieldbus settings p2020..p2023 with p2030 = 1 (USS), monitoring p2040 in ms (a float), and
/// the fault buffer r0945 (fault codes) / r0949 (fault values), 8 fault cases of 8 faults.
const G120_DEFS: &[ParamDef] = {
    use Change::{Always, Commissioning, NotRunning, ReadOnly};
    use DataType::{Float, I32, U16, U32};
    &[
        ParamDef::new(P0003, "p0003 Access level", U16, Always, 1)
            .limits(0.0, 4.0)
            .default_raw(1),
        ParamDef::new(
            P0010,
            "p0010 Drive commissioning parameter filter",
            U16,
            NotRunning,
            1,
        )
        .limits(0.0, 30.0)
        .settings(&[0, 1, 30]),
        ParamDef::new(
            R0018,
            "r0018 Control Unit firmware version",
            U32,
            ReadOnly,
            1,
        )
        .limits(0.0, 4_294_967_295.0)
        .default_raw(4_070_000),
        ParamDef::new(R0021, "r0021 CO: Actual speed smoothed", Float, ReadOnly, 2)
            .limits(-SPEED_MAX, SPEED_MAX),
        ParamDef::new(R0052, "r0052 CO/BO: Status word 1", U16, ReadOnly, 2).limits(0.0, U16_MAX),
        ParamDef::new(R0054, "r0054 CO/BO: Control word 1", U16, ReadOnly, 3).limits(0.0, U16_MAX),
        ParamDef::new(P0700, "p0700 Macro Binector Input (BI)", U16, NotRunning, 1)
            .limits(0.0, 99.0)
            .default_raw(G120_FIELDBUS),
        ParamDef::new(R0945, "r0945 Fault code", U16, ReadOnly, 2)
            .limits(0.0, U16_MAX)
            .array(64),
        ParamDef::new(R0949, "r0949 Fault value", I32, ReadOnly, 3)
            .limits(-2_147_483_648.0, 2_147_483_647.0)
            .array(64),
        // PROFIdrive device identification: manufacturer (42 = Siemens), device type, firmware
        // version, firmware year, firmware day/month, drive objects, patch.
        ParamDef::new(R0964, "r0964 Device identification", U16, ReadOnly, 2)
            .limits(0.0, U16_MAX)
            .array(7),
        ParamDef::new(P0970, "p0970 Reset drive parameters", U16, Commissioning, 1)
            .limits(0.0, 1.0),
        ParamDef::new(P1000, "p1000 Speed setpoint selection", U16, NotRunning, 1)
            .limits(0.0, 200.0)
            .default_raw(G120_FIELDBUS),
        ParamDef::new(P1080, "p1080 Minimum speed", Float, Always, 1).limits(0.0, 19_500.0),
        ParamDef::new(P1082, "p1082 Maximum speed", Float, NotRunning, 1)
            .limits(0.0, SPEED_MAX)
            .default_f32(1500.0),
        ParamDef::new(
            P1120,
            "p1120 Ramp-function generator ramp-up time",
            Float,
            Always,
            1,
        )
        .limits(0.0, TIME_MAX)
        .default_f32(10.0),
        ParamDef::new(
            P1121,
            "p1121 Ramp-function generator ramp-down time",
            Float,
            Always,
            1,
        )
        .limits(0.0, TIME_MAX)
        .default_f32(10.0),
        ParamDef::new(P1135, "p1135 OFF3 ramp-down time", Float, Always, 2)
            .limits(0.0, 5400.0)
            .default_f32(5.0),
        ParamDef::new(
            P2000,
            "p2000 Reference speed reference frequency",
            Float,
            NotRunning,
            2,
        )
        .limits(6.0, SPEED_MAX)
        .default_f32(1500.0),
        ParamDef::new(P2020, "p2020 Field bus interface baud rate", U16, Always, 2)
            .limits(4.0, 13.0)
            .default_raw(6),
        ParamDef::new(P2021, "p2021 Field bus interface address", U16, Always, 2)
            .limits(0.0, 31.0)
            .default_raw(1),
        ParamDef::new(
            P2022,
            "p2022 Field bus interface USS PZD number",
            U16,
            Always,
            2,
        )
        .limits(0.0, 8.0)
        .default_raw(2),
        ParamDef::new(
            P2023,
            "p2023 Field bus interface USS PKW number",
            U16,
            Always,
            2,
        )
        .limits(0.0, 127.0)
        .settings(&[0, 3, 4, 127])
        .default_raw(127),
        ParamDef::new(
            P2030,
            "p2030 Field bus interface protocol selection",
            U16,
            Always,
            1,
        )
        .limits(0.0, 7.0)
        .default_raw(1),
        ParamDef::new(
            P2040,
            "p2040 Field bus interface monitoring time",
            Float,
            Always,
            2,
        )
        .limits(0.0, 1_999_999.0)
        .default_f32(100.0),
        ParamDef::new(R2122, "r2122 Alarm code", U16, ReadOnly, 2)
            .limits(0.0, U16_MAX)
            .array(64),
    ]
};

/// SINAMICS G120 (CU240 over USS).
pub static G120: ParamSet = ParamSet::new(
    "g120",
    G120_DEFS,
    Consulted {
        access_level: Some(P0003),
        commissioning: Some(P0010),
        change_rights: None,
        factory_reset: Some(P0970),
    },
);

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
    address: Some((P2021, 0)),
    pzd: Some((P2022, 0)),
    pkw: Some((P2023, 0)),
    actual: Some(R0021),
    status: Some(R0052),
    control: Some(R0054),
    faults: FaultBuffer {
        codes: R0945,
        values: R0949,
        times: None,
        len: 64,
        per_trip: 8,
    },
    diagnostics: None,
    telegram_off_fault: 0,
};

/// SINAMICS G120 (CU240 over USS), with what its profile names.
pub static G120_ROLES: LazyLock<Roles> = LazyLock::new(|| G120_OWN.with_profile(Catalogue::g120()));

const P303: u16 = 303;
const P304: u16 = 304;
const P782: u16 = 782;
const R947: u16 = 947;
const R949: u16 = 949;

/// SIMOREG DC-Master 6RA70, as far as the simulator plays it: the ramp-function generator's
/// ramp-up and ramp-down times (words in 10 ms), the PKW length of the first USS interface
/// (P782: 0, 3, 4 or 127), and the fault memory r947 with the fault values r949 (8 faults per
/// fault case). Its speed setpoint is a share of the rated speed (0x4000 = 100 %); it has no
/// command-source parameter and no telegram monitoring parameter the simulator plays.
const SIMOREG_DEFS: &[ParamDef] = {
    use Change::{Always, ReadOnly};
    use DataType::U16;
    &[
        ParamDef::new(P303, "P0303 Ramp-up time 1", U16, Always, 1)
            .limits(1.0, 65000.0)
            .default_raw(1000),
        ParamDef::new(P304, "P0304 Ramp-down time 1", U16, Always, 1)
            .limits(1.0, 65000.0)
            .default_raw(1000),
        ParamDef::new(P782, "P0782 G-SST1 parameter data length", U16, Always, 1)
            .limits(0.0, 127.0)
            .settings(&[0, 3, 4, 127])
            .default_raw(127),
        ParamDef::new(R947, "r0947 Fault memory", U16, ReadOnly, 1)
            .limits(0.0, U16_MAX)
            .array(64),
        ParamDef::new(R949, "r0949 Fault value", U16, ReadOnly, 1)
            .limits(0.0, U16_MAX)
            .array(64),
    ]
};

/// SIMOREG DC-Master 6RA70.
pub static SIMOREG: ParamSet = ParamSet::new(
    "simoreg",
    SIMOREG_DEFS,
    Consulted {
        access_level: None,
        commissioning: None,
        change_rights: None,
        factory_reset: None,
    },
);

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
    address: None,
    pzd: None,
    pkw: Some((P782, 0)),
    actual: None,
    status: None,
    control: None,
    faults: FaultBuffer {
        codes: R947,
        values: R949,
        times: None,
        len: 64,
        per_trip: 8,
    },
    diagnostics: None,
    telegram_off_fault: 11,
};

/// SIMOREG DC-Master 6RA70, with what its profile names.
pub static SIMOREG_ROLES: LazyLock<Roles> =
    LazyLock::new(|| SIMOREG_OWN.with_profile(Catalogue::simoreg()));
