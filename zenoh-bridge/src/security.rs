//! Whether the bridge's Zenoh links authenticate who reaches it (guide, "Securing the network").
//!
//! A bridge that lets remote peers run a motor (`--allow-control`) or change a parameter
//! (`--allow-writes`) must know who they are. Zenoh authenticates the two ends of a link with
//! mutual TLS (both present a certificate of the configured CA) or with user/password (every
//! peer that connects presents a user of the bridge's dictionary file). Anything else lets any
//! host that reaches the port in: plain `tcp/` endpoints, a peer's default listener
//! (`tcp/[::]:0`), and multicast scouting, which makes the bridge connect to whatever a host on
//! the LAN advertises. [`links`] reads the configuration the session opens with and says which.

use zenoh::Config;

/// How the links of a Zenoh configuration authenticate the other end.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Links {
    /// Every endpoint is TLS (or QUIC) with `enable_mtls`: both ends show a certificate of
    /// `root_ca_certificate`, whose common name Zenoh's access control can name.
    MutualTls,
    /// `transport.auth.usrpwd.dictionary_file`: every peer that connects presents a user and
    /// password of that file (names access control can use).
    UserPassword,
    /// Anyone who reaches the bridge gets in; the reasons, for the refusal.
    Open(Vec<String>),
}

impl Links {
    /// For the start line: `mutual TLS`, `user/password`, `unauthenticated`.
    pub const fn name(&self) -> &'static str {
        match self {
            Self::MutualTls => "mutual TLS",
            Self::UserPassword => "user/password",
            Self::Open(_) => "unauthenticated",
        }
    }
}

/// A configuration value as JSON (`null` when unset or unknown).
fn value(config: &Config, key: &str) -> serde_json::Value {
    config
        .get_json(key)
        .ok()
        .and_then(|text| serde_json::from_str(&text).ok())
        .unwrap_or(serde_json::Value::Null)
}

/// The endpoints of `listen` or `connect` that apply in `mode`: a plain list, or a list per
/// mode (`{ router: [...], peer: [...], client: [...] }`).
fn endpoints(config: &Config, key: &str, mode: &str) -> Vec<String> {
    let list = match value(config, key) {
        serde_json::Value::Object(per_mode) => per_mode
            .get(mode)
            .cloned()
            .unwrap_or(serde_json::Value::Null),
        other => other,
    };
    list.as_array()
        .map(|l| {
            l.iter()
                .filter_map(|e| e.as_str().map(str::to_owned))
                .collect()
        })
        .unwrap_or_default()
}

fn is_set(v: &serde_json::Value) -> bool {
    v.as_str().is_some_and(|s| !s.is_empty())
}

/// How `config`'s links authenticate the other end.
pub fn links(config: &Config) -> Links {
    if is_set(&value(config, "transport/auth/usrpwd/dictionary_file")) {
        return Links::UserPassword;
    }
    let mode = value(config, "mode").as_str().unwrap_or("peer").to_owned();
    let mut open = Vec::new();
    let all: Vec<String> = ["listen/endpoints", "connect/endpoints"]
        .iter()
        .flat_map(|key| endpoints(config, key, &mode))
        .collect();
    for e in &all {
        if !(e.starts_with("tls/") || e.starts_with("quic/")) {
            open.push(format!("endpoint {e} is not TLS"));
        }
    }
    if all.is_empty() {
        open.push("no endpoint is configured".to_owned());
    }
    let tls = |key: &str| value(config, &format!("transport/link/tls/{key}"));
    if tls("enable_mtls") != serde_json::Value::Bool(true) {
        open.push("transport.link.tls.enable_mtls is not true".to_owned());
    }
    if !is_set(&tls("root_ca_certificate")) {
        open.push("transport.link.tls.root_ca_certificate is not set".to_owned());
    }
    let multicast = value(config, "scouting/multicast/enabled");
    if multicast != serde_json::Value::Bool(false) {
        open.push(
            "multicast scouting is on (the bridge would connect to whatever a host advertises)"
                .to_owned(),
        );
    }
    if open.is_empty() {
        Links::MutualTls
    } else {
        Links::Open(open)
    }
}

/// What to configure, for the refusal.
pub const HOW: &str = "configure mutual TLS (tls/ endpoints; transport.link.tls: \
root_ca_certificate, listen_certificate and listen_private_key, connect_certificate and \
connect_private_key, enable_mtls: true; scouting.multicast.enabled: false) or user/password \
authentication (transport.auth.usrpwd: dictionary_file, user, password) in --zenoh-config (guide, \
\"Securing the network\"), or start with --insecure-network in a lab (parameter writes only: \
remote control needs a policy that names who may control)";

#[cfg(test)]
mod tests {
    use super::*;

    fn config(entries: &[(&str, &str)]) -> Config {
        let mut c = Config::default();
        for (key, value) in entries {
            c.insert_json5(key, value).unwrap();
        }
        c
    }

    const MTLS: [(&str, &str); 6] = [
        ("listen/endpoints", r#"["tls/0.0.0.0:7447"]"#),
        ("transport/link/tls/root_ca_certificate", r#""ca.pem""#),
        ("transport/link/tls/listen_certificate", r#""bridge.pem""#),
        ("transport/link/tls/listen_private_key", r#""bridge.key""#),
        ("transport/link/tls/enable_mtls", "true"),
        ("scouting/multicast/enabled", "false"),
    ];

    /// Issue 47, item 3: the guide's router recipe failed as written (a bridge.json5 without
    /// `listen` gets Zenoh's plain-TCP default listener). Every bridge configuration the
    /// network chapter shows, with the `--connect` of its router recipe, authenticates by
    /// mutual TLS.
    #[test]
    fn every_bridge_configuration_of_the_guide_authenticates_with_its_connect_too() {
        let chapter = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../docs/guide/src/network.md"
        ))
        .unwrap();
        let blocks: Vec<&str> = chapter
            .split("```json5\n")
            .skip(1)
            .filter_map(|b| b.split("```").next())
            .collect();
        assert!(
            blocks.len() >= 2,
            "the network chapter's bridge.json5 files"
        );
        // ... and the example the package installs beside uss-zenoh.service.
        let example = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/examples/bridge.json5"
        ))
        .unwrap();
        for text in blocks.into_iter().chain([example.as_str()]) {
            let mut c = Config::from_json5(text).unwrap_or_else(|e| panic!("{e}: {text}"));
            assert_eq!(links(&c), Links::MutualTls, "{text}");
            c.insert_json5("connect/endpoints", r#"["tls/10.0.0.1:7447"]"#)
                .unwrap();
            assert_eq!(links(&c), Links::MutualTls, "with --connect: {text}");
        }
        // The recipe's warning holds: without `listen`, the default listener is refused.
        let mut bare = config(&MTLS[1..]);
        bare.insert_json5("connect/endpoints", r#"["tls/10.0.0.1:7447"]"#)
            .unwrap();
        assert!(matches!(links(&bare), Links::Open(why) if why.join(" ").contains("tcp/[::]:0")));
    }

    #[test]
    fn mutual_tls_on_every_endpoint_without_multicast_authenticates() {
        assert_eq!(links(&config(&MTLS)), Links::MutualTls);
        let mut connect = MTLS.to_vec();
        connect.push(("connect/endpoints", r#"["tls/10.0.0.5:7447"]"#));
        assert_eq!(links(&config(&connect)), Links::MutualTls);
    }

    #[test]
    fn plain_tcp_a_default_listener_server_only_tls_or_multicast_let_anyone_in() {
        let open = |entries: &[(&str, &str)]| match links(&config(entries)) {
            Links::Open(why) => why.join("; "),
            other => panic!("{other:?}"),
        };
        // The default peer: tcp/[::]:0, multicast on.
        let default = open(&[]);
        assert!(
            default.contains("endpoint tcp/[::]:0 is not TLS"),
            "{default}"
        );
        assert!(default.contains("multicast scouting is on"), "{default}");
        let mut tcp = MTLS.to_vec();
        tcp.push(("connect/endpoints", r#"["tcp/10.0.0.5:7447"]"#));
        assert_eq!(open(&tcp), "endpoint tcp/10.0.0.5:7447 is not TLS");
        let mut server_only = MTLS.to_vec();
        server_only[4] = ("transport/link/tls/enable_mtls", "false");
        assert_eq!(
            open(&server_only),
            "transport.link.tls.enable_mtls is not true"
        );
        let mut multicast = MTLS.to_vec();
        multicast[5] = ("scouting/multicast/enabled", "true");
        assert!(open(&multicast).starts_with("multicast scouting is on"));
    }

    #[test]
    fn a_dictionary_of_users_authenticates_every_link() {
        let c = config(&[
            ("listen/endpoints", r#"["tcp/0.0.0.0:7447"]"#),
            ("transport/auth/usrpwd/dictionary_file", r#""users.txt""#),
        ]);
        assert_eq!(links(&c), Links::UserPassword);
    }
}
