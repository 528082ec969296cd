//! The simulator's parameter sets and the catalogues agree, family by family: every parameter a
//! simulated drive has is in its family's catalogue with the same prefix, data type (PROFIdrive
//! code), array size, change class, access level and, for settable parameters whose limits the
//! catalogue gives, limits.

use uss_catalogue::{Catalogue, Change, DataType};
use uss_drive_sim::family::{G110, G120, SIMOREG};
use uss_drive_sim::params::{Change as SimChange, MICROMASTER4, ParamSet};

#[test]
fn every_simulated_parameter_is_in_the_catalogue_as_the_simulator_has_it() {
    let families: [(&Catalogue, &ParamSet); 4] = [
        (Catalogue::micromaster4(), &MICROMASTER4),
        (Catalogue::micromaster4(), &G110),
        (Catalogue::g120(), &G120),
        (Catalogue::simoreg(), &SIMOREG),
    ];
    for (c, set) in families {
        agree(c, set);
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
        assert_eq!(u16::from(def.elements), p.array, "{}: array", def.name);
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
            assert_eq!(
                (p.min, p.max),
                (Some(def.min), Some(def.max)),
                "{}: limits",
                def.name
            );
        }
    }
}
