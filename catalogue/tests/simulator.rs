//! The simulator's parameter sets are made from the profiles (`ParamSet::of_profile`); this
//! checks the conversion, family by family: every parameter a simulated drive has is in its
//! family's catalogue with the same prefix, data type (PROFIdrive code), array size, change
//! class, access level and limits, and every parameter of the catalogue is in the simulator's
//! set. The values themselves are checked against the manuals, typed in, by the simulator's own
//! tests (`drive-sim/src/params/tests.rs`) and `catalogue/src/tests.rs`.

use uss_catalogue::{Catalogue, Change, DataType};
use uss_control::DriveFamily;
use uss_drive_sim::drive::Personality;
use uss_drive_sim::family::{Behaviour, param_set};
use uss_drive_sim::params::{Change as SimChange, ParamSet};
use uss_protocol::ParamRef;

/// Every family with a profile, with it: what the simulator plays.
fn families() -> impl Iterator<Item = (DriveFamily, &'static Catalogue)> {
    DriveFamily::ALL
        .iter()
        .filter_map(|&f| Some((f, Catalogue::of(f)?)))
}

/// The simulated drive monitors the telegram-off time, records the fault and scales by the
/// reference its family's profile names.
#[test]
fn every_simulated_family_plays_the_roles_its_profile_names() {
    let at = |p: Option<ParamRef>| {
        p.map(|p| (p.pnu.get(), p.index.map_or(0, uss_protocol::Subindex::get)))
    };
    assert!(families().count() >= 4, "micromaster4, g110, g120, simoreg");
    for (family, c) in families() {
        let personality = Personality::Drive(family);
        // The profile names a behaviour the simulator has.
        let named = c.simulator.as_deref().and_then(Behaviour::named);
        assert!(
            named.is_some(),
            "{}: simulator = {:?}",
            c.family,
            c.simulator
        );
        let roles = personality.roles();
        assert_eq!(roles.monitoring, at(c.monitoring), "{personality:?}");
        let fault = c.telegram_off_fault.unwrap_or(roles.telegram_off_fault);
        assert_eq!(roles.telegram_off_fault, fault, "{personality:?}");
        let reference = c.reference.or(c.reference_speed).map(|p| p.pnu.get());
        assert_eq!(roles.reference, reference, "{personality:?}");
        let source = c
            .command_source
            .map(|p| p.pnu.get())
            .zip(c.command_source_uss);
        assert_eq!(roles.command_source, source, "{personality:?}");
    }
}

#[test]
fn every_simulated_parameter_is_in_the_catalogue_as_the_simulator_has_it() {
    for (family, c) in families() {
        agree(c, param_set(family));
    }
}

fn agree(c: &Catalogue, set: &ParamSet) {
    for def in set.definitions() {
        let p = c
            .param(def.pnu)
            .unwrap_or_else(|| panic!("{} is not in the catalogue", def.name));
        assert_eq!(
            DataType::from_code(def.ty.code()),
            Some(p.data_type),
            "{}: type",
            def.name
        );
        // A data-set parameter is an array to the simulated MM440 that has the data sets.
        assert_eq!(
            u16::from(def.elements),
            p.array.max(u16::from(p.data_sets)),
            "{}: array",
            def.name
        );
        assert_eq!(def.level, p.level, "{}: access level", def.name);
        let change = match def.change {
            SimChange::ReadOnly => Change::ReadOnly,
            SimChange::Always => Change::Always,
            SimChange::NotRunning => Change::NotRunning,
            SimChange::Commissioning => Change::Commissioning,
        };
        assert_eq!(change, p.change, "{}: change", def.name);
        // The simulator names its parameters as the manual does: "P1082 Max. frequency".
        assert_eq!(def.name, format!("{} {}", p.id, p.name), "name");
        if p.is_writable() && (p.min, p.max) != (None, None) {
            // The drive holds steps of a fixed-point parameter; the catalogue says its unit.
            let step = p.scale.unwrap_or(1.0);
            let in_unit = |x: f64| (x * step * 1e6).round() / 1e6;
            assert_eq!(
                (p.min, p.max),
                (Some(in_unit(def.min)), Some(in_unit(def.max))),
                "{}: limits",
                def.name
            );
        }
        assert_eq!(def.allowed, p.values.as_slice(), "{}: settings", def.name);
    }
    assert_eq!(
        set.definitions().len(),
        c.param.len(),
        "{}: every parameter of the profile is simulated",
        set.family
    );
}
