//! Zenoh's errors in words a user can act on (issue 47, item 4: a client without a certificate
//! printed `Unable to connect to any of [...]! at <the cargo registry>/.../orchestrator.rs:447`).

/// `e`'s text without the place in Zenoh's sources it came from (` at /.../file.rs:447.`).
pub fn plain(e: &impl core::fmt::Display) -> String {
    let text = e.to_string();
    let cut = text.match_indices(" at ").map(|(at, _)| at).find(|&at| {
        let tail = text[at + 4..].trim_end_matches(['.', ' ']);
        tail.contains(".rs:")
            && tail
                .rsplit(':')
                .next()
                .is_some_and(|n| n.chars().all(|c| c.is_ascii_digit()))
    });
    let kept = cut.map_or(text.as_str(), |at| &text[..at]);
    kept.trim_end().trim_end_matches('!').to_owned()
}

/// What to do when a session could not be opened, where the text tells.
pub fn session_hint(text: &str) -> &'static str {
    if text.contains("Unable to connect") && text.contains("tls/") {
        ": nothing answered at that endpoint over TLS, or it refused this client: a bridge or router \
         with mutual TLS lets in only a client that shows a certificate of its CA (--cert, --key, --ca)"
    } else if text.contains("Unable to connect") {
        ": nothing answered at that endpoint: is uss-zenoh (or the router) running and listening there?"
    } else {
        ""
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_place_in_zenohs_sources_is_cut_and_a_hint_follows() {
        let raw = "Unable to connect to any of [Single(tls/10.0.0.2:7447)]! at /root/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/zenoh-1.10.2/src/net/runtime/orchestrator.rs:447.";
        assert_eq!(
            plain(&raw),
            "Unable to connect to any of [Single(tls/10.0.0.2:7447)]"
        );
        assert!(session_hint(raw).contains("--cert, --key, --ca"));
        assert_eq!(plain(&"no place here"), "no place here");
        assert_eq!(plain(&"meet at noon"), "meet at noon");
    }
}
