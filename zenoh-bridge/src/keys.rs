//! The Zenoh key expressions of a bus (the guide's table), and reading a parameter query's
//! key back into a drive and a parameter.

use uss_client::uss_protocol::ParamRef;
use uss_client::uss_shm_types::Address;

/// The keys of one bus under a prefix (`uss/<site>`).
#[derive(Debug, Clone)]
pub struct Keys {
    /// `<prefix>/<bus>`.
    base: String,
}

impl Keys {
    pub fn new(prefix: &str, bus: &str) -> Self {
        Self {
            base: format!("{}/{bus}", prefix.trim_end_matches('/')),
        }
    }

    /// The bus's status (JSON, every 0.5 s and when ussd comes or goes).
    pub fn status(&self) -> String {
        format!("{}/status", self.base)
    }

    /// The liveliness token declared while ussd serves the bus.
    pub fn alive(&self) -> String {
        format!("{}/alive", self.base)
    }

    /// A drive's input images (JSON, each new one).
    pub fn input(&self, drive: Address) -> String {
        format!("{}/drive/{drive}/in", self.base)
    }

    /// A drive's diagnostics (JSON, every second).
    pub fn diag(&self, drive: Address) -> String {
        format!("{}/drive/{drive}/diag", self.base)
    }

    /// What ussd knows of a drive from its configuration (JSON, every 5 s).
    pub fn info(&self, drive: Address) -> String {
        format!("{}/drive/{drive}/info", self.base)
    }

    /// Every drive's `out` key (`.../drive/<addr>/out`, where a remote controller sends a drive's
    /// output image, only with `--allow-control`), for one subscriber.
    pub fn outputs(&self) -> String {
        format!("{}/drive/*/out", self.base)
    }

    /// The drive an `out` sample's key names.
    pub fn output_of(&self, key: &str) -> Option<Address> {
        key.strip_prefix(&self.base)?
            .strip_prefix("/drive/")?
            .strip_suffix("/out")
            .and_then(address)
    }

    /// What the bridge did with the remote controller's samples of a drive (JSON).
    pub fn control(&self, drive: Address) -> String {
        format!("{}/drive/{drive}/control", self.base)
    }

    /// The queryable of operator stops: `.../drive/<addr>/stop` for one drive, `.../stop` for
    /// every drive of the bus (`**` matches both).
    pub fn stops(&self) -> String {
        format!("{}/**/stop", self.base)
    }

    /// The drive a stop query's key names (`None`: every drive), or why it names none.
    pub fn stop_of(&self, key: &str) -> Result<Option<Address>, KeyError> {
        let bad = |kind| KeyError {
            key: key.to_owned(),
            kind,
        };
        let rest = key
            .strip_prefix(&self.base)
            .ok_or_else(|| bad(BadKey::Foreign(self.base.clone())))?;
        if rest == "/stop" {
            return Ok(None);
        }
        rest.strip_prefix("/drive/")
            .and_then(|r| r.strip_suffix("/stop"))
            .and_then(address)
            .map(Some)
            .ok_or_else(|| bad(BadKey::Stop))
    }

    /// The queryable of every drive's parameters: `.../drive/<addr>/param/<P1082>`.
    pub fn params(&self) -> String {
        format!("{}/drive/*/param/*", self.base)
    }

    /// The queryable of every drive's parameter writes: `.../drive/<addr>/set/<P1082>` (a
    /// query with the value as its payload), the key an access policy's `write` right covers.
    pub fn writes(&self) -> String {
        format!("{}/drive/*/set/*", self.base)
    }

    /// The queryables of every drive's commissioning (`crate::commission`): a parameter's
    /// description, a backup, a diff, a restore, the copy of RAM to ROM.
    pub fn commissioning(&self) -> Vec<String> {
        ["describe/*", "backup", "diff", "restore", "save"]
            .iter()
            .map(|what| format!("{}/drive/*/{what}", self.base))
            .collect()
    }

    /// What follows `<base>/drive/` in `key` (`3/backup`), if it is a drive's key of this bus.
    pub fn drive_rest<'k>(&self, key: &'k str) -> Option<&'k str> {
        key.strip_prefix(self.base.as_str())?
            .strip_prefix("/drive/")
    }

    /// The same layout under a peer's name (`<prefix>/<bus>/as/<name>/drive/...`), where a peer
    /// that names itself sends: under an access policy Zenoh lets only the peer whose
    /// certificate's common name is `name` send there (for every name the policy lists), so the
    /// bridge knows who asks and answers a refusal with the right that is missing.
    pub fn as_peer(&self, name: &str) -> Self {
        Self {
            base: format!("{}/as/{name}", self.base),
        }
    }

    /// Every named peer's keys (`<prefix>/<bus>/as/*/...`), for one subscriber or queryable.
    pub fn named(&self) -> Self {
        self.as_peer("*")
    }

    /// Who a message's key says sent it, and the keys to read the rest of it with: the name
    /// and [`Self::as_peer`] for a key with the identity segment (`.../as/<name>/drive/...`,
    /// `.../as/<name>/stop`), `None` and these keys for one without.
    pub fn sender(&self, key: &str) -> Result<(Option<String>, Self), KeyError> {
        let segments: Vec<&str> = key.split('/').collect();
        let named = (0..segments.len().saturating_sub(2)).rev().find(|&i| {
            segments[i] == "as"
                && (segments[i + 2] == "drive"
                    || (segments[i + 2] == "stop" && i + 3 == segments.len()))
        });
        let Some(i) = named else {
            return Ok((None, self.clone()));
        };
        let name = segments[i + 1];
        if name.is_empty() || has_wildcards(name) || name.contains('$') {
            return Err(KeyError {
                key: key.to_owned(),
                kind: BadKey::Name(name.to_owned()),
            });
        }
        Ok((Some(name.to_owned()), self.as_peer(name)))
    }

    /// The drive and parameter a parameter query's key names (a read key `.../param/<P>` or a
    /// write key `.../set/<P>`), or why it names none.
    pub fn param_of(&self, key: &str, which: ParamKey) -> Result<(Address, ParamRef), KeyError> {
        let bad = |kind| KeyError {
            key: key.to_owned(),
            kind,
        };
        let rest = key
            .strip_prefix(&self.base)
            .and_then(|r| r.strip_prefix("/drive/"))
            .ok_or_else(|| bad(BadKey::ForeignParam(self.base.clone())))?;
        let (drive, param) = rest
            .split_once(&format!("/{}/", which.segment()))
            .ok_or_else(|| bad(BadKey::Param))?;
        let drive = address(drive).ok_or_else(|| bad(BadKey::Address(drive.to_owned())))?;
        let param = param
            .parse::<ParamRef>()
            .map_err(|e| bad(BadKey::Notation(param.to_owned(), e)))?;
        Ok((drive, param))
    }
}

/// Which key of a drive's parameter a query is on: `.../param/<P>` (a read, or without an
/// access policy a write) or `.../set/<P>` (a write).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamKey {
    Read,
    Write,
}

impl ParamKey {
    /// The key's segment before the parameter.
    pub const fn segment(self) -> &'static str {
        match self {
            Self::Read => "param",
            Self::Write => "set",
        }
    }
}

/// One parameter a query names: the drive, the parameter, and the concrete key its reply goes
/// out under.
#[derive(Debug, Clone, PartialEq)]
pub struct Named {
    pub drive: Address,
    pub param: ParamRef,
    pub key: String,
}

/// Whether a key expression has wildcards (`*`, `**`, `$*`).
pub fn has_wildcards(key: &str) -> bool {
    key.contains('*')
}

impl Keys {
    /// The parameters of `drives` a query's key expression names: itself when it is concrete,
    /// else every `.../drive/<addr>/param/<P>` (or `set/<P>`) of this bus it intersects (`**/line1/drive/1/
    /// param/P1082`, `uss/*/line1/drive/*/param/P1082`), each with its concrete key. The
    /// parameter itself must be written out: parameters cannot be listed.
    pub fn params_named(
        &self,
        key: &str,
        which: ParamKey,
        drives: &[Address],
    ) -> Result<Vec<Named>, KeyError> {
        if !has_wildcards(key) {
            let (drive, param) = self.param_of(key, which)?;
            return Ok(vec![Named {
                drive,
                param,
                key: key.to_owned(),
            }]);
        }
        let bad = |kind| KeyError {
            key: key.to_owned(),
            kind,
        };
        let last = key.rsplit('/').next().unwrap_or_default();
        if has_wildcards(last) {
            return Err(bad(BadKey::ParamWildcard));
        }
        let param = last
            .parse::<ParamRef>()
            .map_err(|e| bad(BadKey::Notation(last.to_owned(), e)))?;
        let query = zenoh::key_expr::KeyExpr::try_from(key)
            .map_err(|e| bad(BadKey::Expression(e.to_string())))?;
        let named: Vec<Named> = drives
            .iter()
            .map(|&drive| {
                let segment = which.segment();
                (
                    drive,
                    format!("{}/drive/{drive}/{segment}/{last}", self.base),
                )
            })
            .filter(|(_, concrete)| {
                zenoh::key_expr::KeyExpr::try_from(concrete.as_str())
                    .is_ok_and(|c| query.intersects(&c))
            })
            .map(|(drive, key)| Named { drive, param, key })
            .collect();
        if named.is_empty() {
            return Err(bad(BadKey::ForeignParam(self.base.clone())));
        }
        Ok(named)
    }
}

/// What a stop query's key names, and where its replies go.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StopTarget {
    /// Every drive of the bus: one reply (an array) under `.../stop`.
    Bus(String),
    /// These drives, each with the concrete key its reply goes out under.
    Drives(Vec<(Address, String)>),
}

impl Keys {
    /// What a stop query's key expression names: itself when it is concrete; with wildcards,
    /// the whole bus when it intersects `.../stop`, else every `.../drive/<addr>/stop` of
    /// `drives` it intersects.
    pub fn stops_named(&self, key: &str, drives: &[Address]) -> Result<StopTarget, KeyError> {
        let bus_key = format!("{}/stop", self.base);
        if !has_wildcards(key) {
            return Ok(match self.stop_of(key)? {
                None => StopTarget::Bus(bus_key),
                Some(d) => StopTarget::Drives(vec![(d, key.to_owned())]),
            });
        }
        let bad = |kind| KeyError {
            key: key.to_owned(),
            kind,
        };
        let query = zenoh::key_expr::KeyExpr::try_from(key)
            .map_err(|e| bad(BadKey::Expression(e.to_string())))?;
        let meets = |concrete: &str| {
            zenoh::key_expr::KeyExpr::try_from(concrete).is_ok_and(|c| query.intersects(&c))
        };
        if meets(&bus_key) {
            return Ok(StopTarget::Bus(bus_key));
        }
        let named: Vec<(Address, String)> = drives
            .iter()
            .map(|&d| (d, format!("{}/drive/{d}/stop", self.base)))
            .filter(|(_, k)| meets(k))
            .collect();
        if named.is_empty() {
            return Err(bad(BadKey::Foreign(self.base.clone())));
        }
        Ok(StopTarget::Drives(named))
    }
}

/// A query's key that names no drive or parameter of this bridge.
#[derive(Debug, PartialEq, thiserror::Error)]
#[error("{key}: {kind}")]
pub struct KeyError {
    pub key: String,
    pub kind: BadKey,
}

/// What is wrong with a key.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum BadKey {
    #[error("not a key of {0}")]
    Foreign(String),
    #[error("not a parameter key of {0}")]
    ForeignParam(String),
    #[error("write .../drive/<address 0..=31>/stop or .../stop")]
    Stop,
    #[error("write .../drive/<address>/param/<parameter>")]
    Param,
    #[error("{0:?} is not a drive address 0..=31")]
    Address(String),
    #[error("{0:?}: {1}")]
    Notation(String, uss_client::uss_protocol::NotationError),
    #[error(
        "name the parameter: .../param/P1082 (a wildcard may stand for the prefix, the bus or \
         the drive, not for the parameter)"
    )]
    ParamWildcard,
    #[error("not a key expression: {0}")]
    Expression(String),
    #[error(
        "{0:?}: .../as/<name>/... names one peer: write out its name (its certificate's common \
         name), not a wildcard"
    )]
    Name(String),
}

/// A drive address 0..=31 as a key writes it.
pub fn address(text: &str) -> Option<Address> {
    Address::new(text.parse::<u8>().ok()?).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn addr(a: u8) -> Address {
        Address::new(a).unwrap()
    }

    #[test]
    fn keys_follow_the_readme_table_and_parameter_keys_read_back() {
        let k = Keys::new("uss/plant/", "line1");
        assert_eq!(k.input(addr(3)), "uss/plant/line1/drive/3/in");
        assert_eq!(k.params(), "uss/plant/line1/drive/*/param/*");
        assert_eq!(k.alive(), "uss/plant/line1/alive");
        let (drive, param) = k
            .param_of("uss/plant/line1/drive/3/param/r0947[2]", ParamKey::Read)
            .unwrap();
        assert_eq!((drive, param.to_string().as_str()), (addr(3), "r0947[2]"));
        assert_eq!(k.output_of("uss/plant/line1/drive/3/out"), Some(addr(3)));
        assert_eq!(k.output_of("uss/plant/line1/drive/32/out"), None);
        assert_eq!(k.output_of("uss/plant/line1/drive/3/in"), None);
        assert_eq!(k.stop_of("uss/plant/line1/drive/3/stop"), Ok(Some(addr(3))));
        assert_eq!(k.stop_of("uss/plant/line1/stop"), Ok(None));
        assert!(k.stop_of("uss/plant/line1/drive/32/stop").is_err());
        assert!(k.stop_of("uss/plant/line2/stop").is_err());
        for bad in [
            "uss/plant/line2/drive/3/param/P1082",
            "uss/plant/line1/drive/32/param/P1082",
            "uss/plant/line1/drive/3/param/X1",
            "uss/plant/line1/drive/3/in",
        ] {
            assert!(k.param_of(bad, ParamKey::Read).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_query_with_wildcards_names_each_drive_it_intersects_under_its_concrete_key() {
        let k = Keys::new("uss/plant", "line1");
        let keys = |query: &str| -> Vec<String> {
            k.params_named(query, ParamKey::Read, &[addr(1), addr(2), addr(5)])
                .unwrap()
                .into_iter()
                .map(|n| n.key)
                .collect()
        };
        assert_eq!(
            keys("**/line1/drive/1/param/P1082"),
            ["uss/plant/line1/drive/1/param/P1082"]
        );
        assert_eq!(
            keys("uss/*/line1/drive/*/param/P1082"),
            [
                "uss/plant/line1/drive/1/param/P1082",
                "uss/plant/line1/drive/2/param/P1082",
                "uss/plant/line1/drive/5/param/P1082"
            ]
        );
        assert_eq!(
            keys("uss/plant/line1/drive/3/param/P1082"),
            ["uss/plant/line1/drive/3/param/P1082"],
            "a concrete key is itself"
        );
        let named = k
            .params_named(
                "**/drive/2/param/r0947[3]",
                ParamKey::Read,
                &[addr(1), addr(2)],
            )
            .unwrap();
        assert_eq!(
            (named[0].drive, named[0].param.to_string()),
            (addr(2), "r0947[3]".to_owned())
        );
        let err = |query: &str| {
            k.params_named(query, ParamKey::Read, &[addr(1), addr(2)])
                .unwrap_err()
                .kind
        };
        assert_eq!(err("**/line1/drive/1/param/*"), BadKey::ParamWildcard);
        assert_eq!(
            err("**/line2/drive/1/param/P1082"),
            BadKey::ForeignParam("uss/plant/line1".into())
        );
        assert_eq!(
            err("**/line1/drive/9/param/P1082"),
            BadKey::ForeignParam("uss/plant/line1".into()),
            "no such drive on the bus"
        );
    }

    #[test]
    fn a_stop_with_wildcards_stops_what_it_intersects() {
        let k = Keys::new("uss/plant", "line1");
        let named = |q: &str| k.stops_named(q, &[addr(1), addr(2)]).unwrap();
        let one = |d: u8| {
            let d = addr(d);
            StopTarget::Drives(vec![(d, format!("uss/plant/line1/drive/{d}/stop"))])
        };
        assert_eq!(named("**/line1/drive/2/stop"), one(2));
        assert_eq!(named("uss/plant/line1/drive/1/stop"), one(1));
        assert_eq!(
            named("uss/*/line1/drive/*/stop"),
            StopTarget::Drives(vec![
                (addr(1), "uss/plant/line1/drive/1/stop".into()),
                (addr(2), "uss/plant/line1/drive/2/stop".into())
            ])
        );
        // `**/stop` reaches the bus's own stop too: every drive, one broadcast.
        for bus in ["**/line1/stop", "**/stop", "uss/plant/line1/stop"] {
            assert_eq!(
                named(bus),
                StopTarget::Bus("uss/plant/line1/stop".into()),
                "{bus}"
            );
        }
        assert!(
            k.stops_named("**/line2/drive/1/stop", &[addr(1), addr(2)])
                .is_err()
        );
    }

    #[test]
    fn a_write_key_is_read_by_its_own_segment_whatever_the_prefix_holds() {
        let k = Keys::new("uss/set/param", "line1");
        let named = k
            .params_named(
                "uss/set/param/line1/drive/2/set/P1121",
                ParamKey::Write,
                &[],
            )
            .unwrap();
        assert_eq!(
            (
                named[0].drive,
                named[0].param.to_string(),
                named[0].key.as_str()
            ),
            (
                addr(2),
                "P1121".to_owned(),
                "uss/set/param/line1/drive/2/set/P1121"
            )
        );
        let wild = k
            .params_named(
                "**/line1/drive/2/set/P1121",
                ParamKey::Write,
                &[addr(1), addr(2)],
            )
            .unwrap();
        assert_eq!(wild[0].key, "uss/set/param/line1/drive/2/set/P1121");
        assert!(
            k.params_named(
                "uss/set/param/line1/drive/2/param/P1121",
                ParamKey::Write,
                &[]
            )
            .is_err()
        );
    }

    #[test]
    fn a_key_under_as_names_its_sender_and_reads_like_any_other() {
        let k = Keys::new("uss/plant", "line1");
        let (who, peer) = k.sender("uss/plant/line1/as/hmi-1/drive/3/out").unwrap();
        assert_eq!(who.as_deref(), Some("hmi-1"));
        assert_eq!(
            peer.output_of("uss/plant/line1/as/hmi-1/drive/3/out"),
            Some(addr(3))
        );
        assert_eq!(
            peer.control(addr(3)),
            "uss/plant/line1/as/hmi-1/drive/3/control"
        );
        let (who, peer) = k.sender("uss/plant/line1/as/hmi-1/stop").unwrap();
        assert_eq!(who.as_deref(), Some("hmi-1"));
        assert_eq!(peer.stop_of("uss/plant/line1/as/hmi-1/stop"), Ok(None));
        // A wildcard prefix: the name is found from the end, the reply key is concrete.
        let (who, peer) = k.sender("**/line1/as/eng/drive/2/set/P1121").unwrap();
        assert_eq!(who.as_deref(), Some("eng"));
        let named = peer
            .params_named(
                "**/line1/as/eng/drive/2/set/P1121",
                ParamKey::Write,
                &[addr(1), addr(2)],
            )
            .unwrap();
        assert_eq!(named[0].key, "uss/plant/line1/as/eng/drive/2/set/P1121");
        // No name: the keys themselves.
        let (who, peer) = k.sender("uss/plant/line1/drive/3/param/P1082").unwrap();
        assert_eq!((who, peer.input(addr(3))), (None, k.input(addr(3))));
        // A wildcard for the name names nobody.
        for bad in [
            "uss/plant/line1/as/*/drive/1/set/P1121",
            "uss/plant/line1/as/ctl$*/drive/1/out",
            "uss/plant/line1/as/**/drive/1/out",
        ] {
            assert!(
                matches!(k.sender(bad).unwrap_err().kind, BadKey::Name(_)),
                "{bad}"
            );
        }
        assert_eq!(k.named().params(), "uss/plant/line1/as/*/drive/*/param/*");
    }

    proptest::proptest! {
        /// Any key is read or refused, never a panic.
        #[test]
        fn any_key_is_read_or_refused(tail in ".{0,40}") {
            let k = Keys::new("uss/p", "b");
            let _ = k.param_of(&format!("uss/p/b/drive/{tail}"), ParamKey::Read);
            let _ = k.stop_of(&format!("uss/p/b/drive/{tail}"));
            let _ = k.output_of(&format!("uss/p/b/drive/{tail}"));
            let _ = k.params_named(&format!("**/b/drive/{tail}"), ParamKey::Read, &[addr(1), addr(2)]);
            let _ = k.params_named(&format!("**/b/drive/{tail}"), ParamKey::Write, &[addr(1), addr(2)]);
            let _ = k.stops_named(&format!("**/b/drive/{tail}"), &[addr(1), addr(2)]);
            let _ = k.sender(&format!("uss/p/b/as/{tail}"));
        }
    }
}
