//! What the bridge answers a query it cannot carry out with: the text `ussctl` would print and
//! the kind of failure from the one error table every front-end speaks (`uss_client::kinds`:
//! its C status and Python exception), as a JSON error reply, so a remote program tells a
//! refusal from a timeout or a drive's error the way a local one does.

use uss_client::{ClientError, ErrorKind};

/// A query's failure: its kind and its text.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refusal {
    pub kind: ErrorKind,
    pub text: String,
}

impl Refusal {
    pub fn new(kind: ErrorKind, text: impl Into<String>) -> Self {
        Self {
            kind,
            text: text.into(),
        }
    }

    /// Refused by the bridge's own rules: its access policy, writes or control not allowed, a
    /// drive held by another remote controller, a queue that is full.
    pub fn refused(text: impl Into<String>) -> Self {
        Self::new(ErrorKind::Refused, text)
    }

    /// A query that cannot be right: its key, its payload.
    pub fn invalid(text: impl Into<String>) -> Self {
        Self::new(ErrorKind::InvalidArgument, text)
    }

    /// The error reply's payload ([`crate::payload::ErrorReply`]): `{"v": 1, "error": text,
    /// "kind": ..., "code": ...}`, the kind as the C status's snake-case name and number.
    pub fn json(&self) -> String {
        let status = self.kind.status();
        let reply = crate::payload::ErrorReply {
            v: crate::payload::VERSION,
            error: &self.text,
            kind: status.snake(),
            code: status.code(),
        };
        serde_json::to_string(&reply).unwrap_or_default()
    }
}

impl core::fmt::Display for Refusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(&self.text)
    }
}

impl From<ClientError> for Refusal {
    fn from(e: ClientError) -> Self {
        Self::new(e.kind(), e.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_error_reply_says_its_kind_and_code_from_the_error_table() {
        let r = Refusal::refused("writes are refused");
        let v: serde_json::Value = serde_json::from_str(&r.json()).unwrap();
        assert_eq!(v["error"], "writes are refused");
        assert_eq!(v["v"], crate::payload::VERSION);
        assert_eq!(v["kind"], ErrorKind::Refused.status().snake());
        assert_eq!(v["code"], ErrorKind::Refused.status().code());
        let gone = Refusal::from(ClientError::NotRunning {
            bus: "b".into(),
            served: Vec::new(),
        });
        assert_eq!(gone.kind, ErrorKind::NotRunning);
    }
}
