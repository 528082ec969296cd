//! Who may do what through the bridge (README, "Who may do what"): an access policy that maps
//! certificate common names to rights per bus and drive, made into Zenoh's own access control
//! (`access_control` of the session's configuration), which checks every message against the
//! identity its link authenticated.
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
//! Rights: `read` (status, images, diagnostics, liveliness, parameter reads), `stop` (operator
//! stops), `write` (parameter writes, through `.../drive/<addr>/set/<P>`), `control` (samples on
//! `.../drive/<addr>/out`). A peer gets `default` and every grant naming it. What Zenoh's access
//! control cannot do, this cannot either: a refused message is dropped, not answered (the peer's
//! query gets no reply, its samples change nothing), and a right cannot be withheld from one
//! peer while every authenticated peer has it (list the peers instead of `default`).

use serde::Deserialize;
use serde_json::{Value, json};
use std::path::Path;

/// What a peer may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Right {
    Read,
    Stop,
    Write,
    Control,
}

/// Rights for some peers, on one bus or all, some drives or all.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Grant {
    /// Certificate common names (the `/CN=` of the peer's certificate).
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
                return Err(format!("{at}: name the certificate common names it is for"));
            }
            if g.rights.is_empty() {
                return Err(format!("{at}: give it rights: read, stop, write, control"));
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

    /// The keys and message kinds one right covers on `bus` for `drives` (`None`: all).
    fn keys_of(
        right: Right,
        prefix: &str,
        bus: &str,
        drives: Option<&[u8]>,
    ) -> Vec<(Vec<&'static str>, Vec<String>)> {
        let base = format!("{prefix}/{bus}");
        let drives: Vec<String> = drives.map_or_else(
            || vec!["*".to_owned()],
            |d| d.iter().map(ToString::to_string).collect(),
        );
        let per_drive = |tails: &[&str]| -> Vec<String> {
            let mut keys = Vec::new();
            for d in &drives {
                for t in tails {
                    keys.push(format!("{base}/drive/{d}/{t}"));
                }
            }
            keys
        };
        match right {
            Right::Read => {
                let mut watched = vec![
                    format!("{prefix}/bridge"),
                    format!("{base}/status"),
                    format!("{base}/alive"),
                ];
                watched.extend(per_drive(&["in", "diag", "info", "control"]));
                vec![
                    (
                        vec![
                            "declare_subscriber",
                            "declare_liveliness_subscriber",
                            "liveliness_query",
                        ],
                        watched,
                    ),
                    (vec!["query"], per_drive(&["param/*"])),
                ]
            }
            Right::Stop => {
                let mut keys = per_drive(&["stop"]);
                if drives == ["*"] {
                    keys.push(format!("{base}/stop"));
                }
                vec![(vec!["query"], keys)]
            }
            Right::Write => vec![(vec!["query"], per_drive(&["set/*"]))],
            Right::Control => vec![(vec!["put"], per_drive(&["out"]))],
        }
    }

    /// Zenoh's `access_control` for this policy on `buses` under `prefix`: nothing is allowed
    /// but what a right grants (and what the bridge itself sends).
    pub fn access_control(&self, prefix: &str, buses: &[String]) -> Value {
        let mut rules = vec![json!({
            "id": "the bridge's own messages",
            "permission": "allow",
            "flows": ["egress"],
            "messages": ALL_MESSAGES,
            "key_exprs": [format!("{prefix}/**")],
        })];
        let mut subjects = vec![json!({ "id": "authenticated", "link_protocols": ["tls"] })];
        let mut policies = Vec::new();
        let rule_ids =
            |rules: &mut Vec<Value>, name: &str, right: Right, bus: &str, drives: Option<&[u8]>| {
                let mut ids = Vec::new();
                for (k, (messages, keys)) in Self::keys_of(right, prefix, bus, drives)
                    .into_iter()
                    .enumerate()
                {
                    let id = format!("{name} {right:?} {bus} {k}");
                    rules.push(json!({
                        "id": id,
                        "permission": "allow",
                        "flows": ["ingress"],
                        "messages": messages,
                        "key_exprs": keys,
                    }));
                    ids.push(id);
                }
                ids
            };
        let mut default_rules = vec!["the bridge's own messages".to_owned()];
        for bus in buses {
            for &right in &self.default {
                default_rules.extend(rule_ids(&mut rules, "default", right, bus, None));
            }
        }
        policies.push(json!({ "rules": default_rules, "subjects": ["authenticated"] }));
        for (n, g) in self.grant.iter().enumerate() {
            let subject = format!("grant {}", n + 1);
            subjects.push(json!({ "id": subject, "cert_common_names": g.who }));
            let mut ids = Vec::new();
            for bus in buses
                .iter()
                .filter(|b| g.bus.as_ref().is_none_or(|x| x == *b))
            {
                for &right in &g.rights {
                    ids.extend(rule_ids(
                        &mut rules,
                        &subject,
                        right,
                        bus,
                        g.drives.as_deref(),
                    ));
                }
            }
            policies.push(json!({ "rules": ids, "subjects": [subject] }));
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
            refused("[[grant]]\nwho = []\nrights = [\"read\"]").contains("name the certificate")
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
    fn rights_become_zenoh_rules_on_the_keys_they_cover() {
        let p = Policy::parse(
            "default = [\"stop\"]\n[[grant]]\nwho = [\"hmi-1\"]\nrights = [\"control\", \"read\"]\nbus = \"line1\"\ndrives = [3]\n",
            &buses(),
        )
        .unwrap();
        let acl = p.access_control("uss/plant", &buses());
        assert_eq!(acl["default_permission"], "deny");
        let rules = acl["rules"].as_array().unwrap();
        let keys_of = |id: &str| {
            rules
                .iter()
                .find(|r| r["id"] == id)
                .map(|r| r["key_exprs"].clone())
                .unwrap()
        };
        assert_eq!(
            keys_of("default Stop line1 0"),
            json!(["uss/plant/line1/drive/*/stop", "uss/plant/line1/stop"])
        );
        assert_eq!(
            keys_of("grant 1 Control line1 0"),
            json!(["uss/plant/line1/drive/3/out"])
        );
        assert!(
            rules.iter().all(|r| r["id"] != "grant 1 Control line2 0"),
            "only its bus"
        );
        assert_eq!(
            acl["subjects"][1],
            json!({ "id": "grant 1", "cert_common_names": ["hmi-1"] })
        );
        // Zenoh reads it.
        let mut config = zenoh::Config::default();
        config
            .insert_json5("access_control", &acl.to_string())
            .unwrap();
    }
}
