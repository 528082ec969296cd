//! Who may do what through the bridge (guide, "Who may do what"): an access policy that maps
//! peers' names (their certificates' common names under mutual TLS, their users under
//! user/password authentication: [`Names`]) to rights per bus and drive.
//!
//! ```toml
//! default = ["read", "stop"]          # every peer with a certificate of the CA
//!
//! [[grant]]
//! who = ["hmi-1"]                      # certificate common names
//! rights = ["control"]
//! bus = "line1"                        # optional: every bus of this bridge
//! drives = [1, 2]                      # optional: every drive
//! ```
//!
//! Rights: `read` (status, images, diagnostics, liveliness, parameter reads, and the
//! commissioning reads: a parameter's description, a backup, a diff), `stop` (operator stops),
//! `write` (parameter writes, through `.../drive/<addr>/set/<P>`), `commission` (a restore of a
//! backup and the copy of RAM to ROM, through `.../drive/<addr>/restore` and `.../save`),
//! `control` (samples on `.../drive/<addr>/out`). A peer gets `default` and every grant naming
//! it.
//!
//! Two checks make it. **Zenoh's access control** (`access_control` of the session's
//! configuration, made here) knows the common name of the certificate each link authenticated:
//! it lets a subscription through only with `read`, and it binds names to keys, so only the peer
//! whose certificate says `hmi-1` may send under `<prefix>/<bus>/as/hmi-1/...` (for every name
//! the policy lists). Zenoh drops what it refuses without a word. **The bridge** then checks
//! every put and query against the rights of the name its key carries (a key without one, or
//! with a name the policy does not list, gets `default`): a refusal gets an error reply (a
//! query) or a control report (a sample) naming the missing right, is counted in the bus's
//! status and is logged with the name. A right cannot be withheld from one peer while every
//! authenticated peer has it: withhold it from `default` and grant it to the others.

use serde::Deserialize;
use serde_json::{Value, json};
use std::path::Path;

/// What a peer may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Right {
    Read,
    Stop,
    Write,
    Control,
    Commission,
}

impl Right {
    /// As the policy file writes it.
    pub const fn name(self) -> &'static str {
        match self {
            Self::Read => "read",
            Self::Stop => "stop",
            Self::Write => "write",
            Self::Control => "control",
            Self::Commission => "commission",
        }
    }
}

impl core::fmt::Display for Right {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name())
    }
}

/// Rights for some peers, on one bus or all, some drives or all.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Grant {
    /// Peers' names: certificate common names (the `/CN=` of the peer's certificate) under
    /// mutual TLS, users under user/password authentication.
    pub who: Vec<String>,
    pub rights: Vec<Right>,
    /// One bus of this bridge (default: every bus).
    pub bus: Option<String>,
    /// Drive addresses 0..=31 (default: every drive).
    pub drives: Option<Vec<u8>>,
}

/// The access policy of a bridge.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Policy {
    /// Every authenticated peer's rights (default `read` and `stop`: a safe command is
    /// sendable from anywhere).
    #[serde(default = "read_and_stop")]
    pub default: Vec<Right>,
    #[serde(default)]
    pub grant: Vec<Grant>,
}

fn read_and_stop() -> Vec<Right> {
    vec![Right::Read, Right::Stop]
}

/// What the links authenticate a peer by, and so what a policy's names are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Names {
    /// Mutual TLS: the common name of the peer's certificate.
    Certificates,
    /// User/password authentication: the user the peer logged in as.
    Users,
}

impl Names {
    /// What vouches for a name, as the bridge says it.
    pub const fn proof(self) -> &'static str {
        match self {
            Self::Certificates => "certificate",
            Self::Users => "user/password",
        }
    }

    /// The subject of Zenoh's access control for these names.
    fn subject(self, id: &str, names: &[&str]) -> Value {
        let key = match self {
            Self::Certificates => "cert_common_names",
            Self::Users => "usernames",
        };
        let mut subject = serde_json::Map::new();
        subject.insert("id".to_owned(), json!(id));
        subject.insert(key.to_owned(), json!(names));
        Value::Object(subject)
    }

    /// The subject of every authenticated peer: every TLS link under mutual TLS (the handshake
    /// refused every other certificate); every link under user/password (Zenoh refuses a peer
    /// without a user of the dictionary).
    fn everyone(self) -> Value {
        match self {
            Self::Certificates => json!({ "id": "authenticated", "link_protocols": ["tls"] }),
            Self::Users => json!({ "id": "authenticated", "link_protocols": ["tcp", "tls"] }),
        }
    }
}

/// A policy file that cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {problem}")]
pub struct PolicyError {
    pub path: String,
    pub problem: String,
}

/// Every message kind Zenoh's access control knows.
const ALL_MESSAGES: [&str; 9] = [
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
];

impl Policy {
    /// Reads and checks a policy file against the buses this bridge serves.
    pub fn load(path: &Path, buses: &[String]) -> Result<Self, PolicyError> {
        let error = |problem: String| PolicyError {
            path: path.display().to_string(),
            problem,
        };
        let text = std::fs::read_to_string(path).map_err(|e| error(e.to_string()))?;
        Self::parse(&text, buses).map_err(error)
    }

    /// Reads and checks a policy's text: the file's line and key on a mistake.
    pub fn parse(text: &str, buses: &[String]) -> Result<Self, String> {
        let policy: Self = toml::from_str(text).map_err(|e| e.to_string())?;
        for (n, g) in policy.grant.iter().enumerate() {
            let at = format!("grant {} (who = {:?})", n + 1, g.who);
            if g.who.is_empty() || g.who.iter().any(String::is_empty) {
                return Err(format!(
                    "{at}: name the peers it is for (certificate common names, or users)"
                ));
            }
            if let Some(name) = g.who.iter().find(|n| n.contains(['/', '*', '$', '#', '?'])) {
                return Err(format!(
                    "{at}: {name:?} cannot be a peer's name in a key (.../as/<name>/...): a \
                     common name without / * $ # ?"
                ));
            }
            if g.rights.is_empty() {
                return Err(format!(
                    "{at}: give it rights: read, stop, write, control, commission"
                ));
            }
            if let Some(bus) = g.bus.as_ref().filter(|b| !buses.contains(b)) {
                return Err(format!(
                    "{at}: bus {bus:?} is not one this bridge serves ({})",
                    buses.join(", ")
                ));
            }
            if let Some(d) = g.drives.iter().flatten().find(|&&d| d > 31) {
                return Err(format!("{at}: drive {d} is not an address 0..=31"));
            }
        }
        Ok(policy)
    }

    /// The keys a right lets a peer subscribe to on `bus` for `drives` (`None`: all): only
    /// `read` has any (every put and query is the bridge's to check).
    fn watched(right: Right, prefix: &str, bus: &str, drives: Option<&[u8]>) -> Vec<String> {
        if right != Right::Read {
            return Vec::new();
        }
        let base = format!("{prefix}/{bus}");
        let drives: Vec<String> = drives.map_or_else(
            || vec!["*".to_owned()],
            |d| d.iter().map(ToString::to_string).collect(),
        );
        let mut keys = vec![
            format!("{prefix}/bridge"),
            format!("{base}/status"),
            format!("{base}/alive"),
        ];
        for d in &drives {
            for t in ["in", "diag", "info", "control"] {
                keys.push(format!("{base}/drive/{d}/{t}"));
            }
        }
        keys
    }

    /// The keys a peer sends puts and queries on, under `base` (`<prefix>/<bus>`, or a peer's
    /// `<prefix>/<bus>/as/<name>`).
    fn action_keys(base: &str) -> [(&'static str, Vec<String>); 2] {
        [
            ("put", vec![format!("{base}/drive/*/out")]),
            (
                "query",
                vec![
                    format!("{base}/drive/*/param/*"),
                    format!("{base}/drive/*/set/*"),
                    format!("{base}/drive/*/describe/*"),
                    format!("{base}/drive/*/backup"),
                    format!("{base}/drive/*/diff"),
                    format!("{base}/drive/*/restore"),
                    format!("{base}/drive/*/save"),
                    format!("{base}/drive/*/stop"),
                    format!("{base}/stop"),
                ],
            ),
        ]
    }

    /// Every name the policy grants something to.
    pub fn names(&self) -> Vec<&str> {
        let mut names: Vec<&str> = self
            .grant
            .iter()
            .flat_map(|g| g.who.iter().map(String::as_str))
            .collect();
        names.sort_unstable();
        names.dedup();
        names
    }

    /// Whether the policy names `name` (so Zenoh binds it to its certificate or user).
    pub fn lists(&self, name: &str) -> bool {
        self.grant.iter().any(|g| g.who.iter().any(|w| w == name))
    }

    /// Whether the peer `name` (`None`: a peer that did not name itself, or a name the policy
    /// does not list) may do `right` on `bus`, for `drive` (`None`: every drive of the bus).
    pub fn allows(&self, name: Option<&str>, right: Right, bus: &str, drive: Option<u8>) -> bool {
        self.default.contains(&right)
            || name.is_some_and(|n| {
                self.grant.iter().any(|g| {
                    g.who.iter().any(|w| w == n)
                        && g.rights.contains(&right)
                        && g.bus.as_ref().is_none_or(|b| b == bus)
                        && match (&g.drives, drive) {
                            (None, _) => true,
                            (Some(ds), Some(d)) => ds.contains(&d),
                            (Some(_), None) => false,
                        }
                })
            })
    }

    /// Zenoh's `access_control` for this policy on `buses` under `prefix`: subscriptions only
    /// with `read`; puts and queries on the bridge's keys from every authenticated peer, under
    /// `.../as/<name>/...` for a listed name only from the peer whose certificate (or user) says
    /// it;
    /// nothing else (but what the bridge itself sends).
    pub fn access_control(&self, prefix: &str, buses: &[String], by: Names) -> Value {
        const WATCH: [&str; 3] = [
            "declare_subscriber",
            "declare_liveliness_subscriber",
            "liveliness_query",
        ];
        let mut rules = vec![json!({
            "id": "the bridge's own messages",
            "permission": "allow",
            "flows": ["egress"],
            "messages": ALL_MESSAGES,
            "key_exprs": [format!("{prefix}/**")],
        })];
        let mut subjects = vec![by.everyone()];
        let mut policies = Vec::new();
        let rule = |rules: &mut Vec<Value>,
                    id: String,
                    permission,
                    messages: &[&str],
                    keys: Vec<String>| {
            rules.push(json!({
                "id": id,
                "permission": permission,
                "flows": ["ingress"],
                "messages": messages,
                "key_exprs": keys,
            }));
            id
        };
        let names = self.names();
        let mut authenticated = vec!["the bridge's own messages".to_owned()];
        for bus in buses {
            let base = format!("{prefix}/{bus}");
            for (message, keys) in Self::action_keys(&base)
                .into_iter()
                .chain(Self::action_keys(&format!("{base}/as/*")))
            {
                let id = format!("everyone {message} {}", keys[0]);
                authenticated.push(rule(&mut rules, id, "allow", &[message], keys));
            }
            if !names.is_empty() {
                let keys = names.iter().map(|n| format!("{base}/as/{n}/**")).collect();
                let id = format!("listed names {bus}");
                authenticated.push(rule(&mut rules, id, "deny", &["put", "query"], keys));
            }
            for &right in &self.default {
                let keys = Self::watched(right, prefix, bus, None);
                if !keys.is_empty() {
                    let id = format!("default {right} {bus}");
                    authenticated.push(rule(&mut rules, id, "allow", &WATCH, keys));
                }
            }
        }
        policies.push(json!({ "rules": authenticated, "subjects": ["authenticated"] }));
        // Each listed name on its own keys, from its own certificate only (one subject per
        // name: a subject of two names would let each send as the other).
        for name in &names {
            let subject = format!("peer {name}");
            subjects.push(by.subject(&subject, &[name]));
            let keys = buses
                .iter()
                .map(|b| format!("{prefix}/{b}/as/{name}/**"))
                .collect();
            let id = rule(
                &mut rules,
                format!("{subject} sends"),
                "allow",
                &["put", "query"],
                keys,
            );
            policies.push(json!({ "rules": [id], "subjects": [subject] }));
        }
        for (n, g) in self.grant.iter().enumerate() {
            let subject = format!("grant {}", n + 1);
            let mut ids = Vec::new();
            for bus in buses
                .iter()
                .filter(|b| g.bus.as_ref().is_none_or(|x| x == *b))
            {
                for &right in &g.rights {
                    let keys = Self::watched(right, prefix, bus, g.drives.as_deref());
                    if !keys.is_empty() {
                        ids.push(rule(
                            &mut rules,
                            format!("{subject} {right} {bus}"),
                            "allow",
                            &WATCH,
                            keys,
                        ));
                    }
                }
            }
            if !ids.is_empty() {
                let who: Vec<&str> = g.who.iter().map(String::as_str).collect();
                subjects.push(by.subject(&subject, &who));
                policies.push(json!({ "rules": ids, "subjects": [subject] }));
            }
        }
        json!({
            "enabled": true,
            "default_permission": "deny",
            "rules": rules,
            "subjects": subjects,
            "policies": policies,
        })
    }

    /// For the start line: `2 grants; default read, stop`.
    pub fn summary(&self) -> String {
        let default: Vec<String> = self
            .default
            .iter()
            .map(|r| format!("{r:?}").to_lowercase())
            .collect();
        format!(
            "{} grant{}; every authenticated peer: {}",
            self.grant.len(),
            if self.grant.len() == 1 { "" } else { "s" },
            if default.is_empty() {
                "nothing".to_owned()
            } else {
                default.join(", ")
            }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn buses() -> Vec<String> {
        vec!["line1".to_owned(), "line2".to_owned()]
    }

    #[test]
    fn a_policy_reads_its_grants_and_refuses_what_it_cannot_mean() {
        let p = Policy::parse(
            "[[grant]]\nwho = [\"hmi-1\"]\nrights = [\"control\"]\nbus = \"line1\"\ndrives = [1, 2]\n",
            &buses(),
        )
        .unwrap();
        assert_eq!(p.default, [Right::Read, Right::Stop]);
        assert_eq!(p.grant[0].drives.as_deref(), Some(&[1, 2][..]));
        let refused = |text: &str| Policy::parse(text, &buses()).unwrap_err();
        assert!(
            refused("[[grant]]\nwho = []\nrights = [\"read\"]")
                .contains("name the peers it is for")
        );
        assert!(refused("[[grant]]\nwho = [\"a\"]\nrights = []").contains("give it rights"));
        assert!(
            refused("[[grant]]\nwho = [\"a\"]\nrights = [\"read\"]\nbus = \"line9\"")
                .contains("not one this bridge serves (line1, line2)")
        );
        assert!(
            refused("[[grant]]\nwho = [\"a\"]\nrights = [\"read\"]\ndrives = [32]")
                .contains("drive 32")
        );
        let unknown = refused("[[grant]]\nwho = [\"a\"]\nrights = [\"run\"]");
        assert!(
            unknown.contains("line 3") && unknown.contains("run"),
            "{unknown}"
        );
    }

    #[test]
    fn rights_are_default_and_grants_per_bus_and_drive() {
        let p = Policy::parse(
            "default = [\"read\"]\n[[grant]]\nwho = [\"hmi-1\", \"hmi-2\"]\nrights = [\"control\", \"stop\"]\nbus = \"line1\"\ndrives = [3]\n[[grant]]\nwho = [\"eng\"]\nrights = [\"write\"]\n",
            &buses(),
        )
        .unwrap();
        let allows = |who, right, bus, drive| p.allows(who, right, bus, drive);
        assert!(allows(None, Right::Read, "line2", Some(1)), "default");
        assert!(
            !allows(None, Right::Stop, "line1", Some(3)),
            "withheld from default"
        );
        assert!(allows(Some("hmi-2"), Right::Control, "line1", Some(3)));
        assert!(
            !allows(Some("hmi-2"), Right::Control, "line1", Some(4)),
            "its drive only"
        );
        assert!(
            !allows(Some("hmi-2"), Right::Control, "line2", Some(3)),
            "its bus only"
        );
        assert!(
            !allows(Some("hmi-1"), Right::Stop, "line1", None),
            "not the whole bus"
        );
        assert!(allows(Some("eng"), Right::Write, "line2", Some(9)));
        assert!(!allows(Some("eng"), Right::Control, "line1", Some(3)));
        assert!(p.lists("hmi-1") && !p.lists("viewer"));
        assert_eq!(p.names(), ["eng", "hmi-1", "hmi-2"]);
        assert!(
            Policy::parse("[[grant]]\nwho = [\"a/b\"]\nrights = [\"read\"]", &buses())
                .unwrap_err()
                .contains("cannot be a peer's name in a key")
        );
    }

    #[test]
    fn zenoh_binds_each_listed_name_to_its_certificate_and_subscriptions_to_read() {
        let p = Policy::parse(
            "default = [\"stop\"]\n[[grant]]\nwho = [\"hmi-1\"]\nrights = [\"control\", \"read\"]\nbus = \"line1\"\ndrives = [3]\n",
            &buses(),
        )
        .unwrap();
        let acl = p.access_control("uss/plant", &buses(), Names::Certificates);
        assert_eq!(acl["default_permission"], "deny");
        let rules = acl["rules"].as_array().unwrap();
        let rule = |id: &str| rules.iter().find(|r| r["id"] == id).cloned().unwrap();
        // Every authenticated peer sends on the bridge's keys, named or not ...
        let puts = rule("everyone put uss/plant/line1/as/*/drive/*/out");
        assert_eq!(puts["permission"], "allow");
        assert_eq!(
            puts["key_exprs"],
            json!(["uss/plant/line1/as/*/drive/*/out"])
        );
        // ... but not under a listed name: only that name's certificate does.
        let listed = rule("listed names line1");
        assert_eq!(
            (listed["permission"].clone(), listed["key_exprs"].clone()),
            (json!("deny"), json!(["uss/plant/line1/as/hmi-1/**"]))
        );
        let own = rule("peer hmi-1 sends");
        assert_eq!(
            own["key_exprs"],
            json!(["uss/plant/line1/as/hmi-1/**", "uss/plant/line2/as/hmi-1/**"])
        );
        assert!(
            acl["subjects"]
                .as_array()
                .unwrap()
                .contains(&json!({ "id": "peer hmi-1", "cert_common_names": ["hmi-1"] }))
        );
        // Subscriptions: read only, its drive only; `stop` (no read) subscribes to nothing.
        assert_eq!(
            rule("grant 1 read line1")["key_exprs"][3],
            json!("uss/plant/line1/drive/3/in")
        );
        assert!(rules.iter().all(|r| r["id"] != "grant 1 read line2"));
        assert!(rules.iter().all(|r| r["id"] != "default stop line1"));
        // Zenoh reads it.
        let mut config = zenoh::Config::default();
        config
            .insert_json5("access_control", &acl.to_string())
            .unwrap();
    }

    /// Zenoh's own decision on the rules made here: the policy decision is Zenoh's, so the
    /// test asks a real session (the interceptor is built when the session opens).
    #[test]
    fn zenoh_accepts_the_access_control_in_a_session() {
        use zenoh::Wait as _;
        let p = Policy::parse(
            "[[grant]]\nwho = [\"hmi-1\"]\nrights = [\"control\"]\n",
            &buses(),
        )
        .unwrap();
        for by in [Names::Certificates, Names::Users] {
            let mut config = zenoh::Config::default();
            config
                .insert_json5(
                    "access_control",
                    &p.access_control("uss/t", &buses(), by).to_string(),
                )
                .unwrap();
            config
                .insert_json5("scouting/multicast/enabled", "false")
                .unwrap();
            config.insert_json5("listen/endpoints", "[]").unwrap();
            let session = zenoh::open(config).wait().expect("Zenoh takes the rules");
            let _ = session.close().wait();
        }
    }
}
