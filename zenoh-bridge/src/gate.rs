//! The bridge's own check of every put and query against the access policy
//! ([`crate::policy`]): who sent it (the name its key carries, which Zenoh has bound to the
//! peer's certificate when the policy lists it), whether that peer has the right, and, when it
//! has not, a refusal that names the missing right, counted per right in the bus's status and
//! logged with the name.

use crate::policy::{Names, Policy, Right};
use core::time::Duration;
use std::collections::HashMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;
use uss_client::Address;

/// Who sent a message, as far as the bridge can tell.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Peer {
    /// The name its key carries (`.../as/<name>/...`), if any.
    pub name: Option<String>,
    /// What vouches for that name (`certificate`, `user/password`): Zenoh's access control let
    /// only the peer of that certificate's common name, or of that user, send under it (the
    /// policy lists the name). `None`: nothing does.
    pub vouched: Option<&'static str>,
}

impl Peer {
    /// The name, when the bridge can rely on it: one whose certificate or user Zenoh checked.
    pub fn verified_name(&self) -> Option<&str> {
        self.name.as_deref().filter(|_| self.vouched.is_some())
    }
}

impl core::fmt::Display for Peer {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match (&self.name, self.vouched) {
            (Some(n), Some(proof)) => write!(f, "{n:?} ({proof})"),
            (Some(n), None) => write!(f, "{n:?} (a name nothing vouches for)"),
            (None, _) => f.write_str("a peer that did not name itself"),
        }
    }
}

/// How often one peer's refusals of one right are logged at most: a controller sending 50
/// samples a second that it may not send is said once a second, with the count.
const LOG_EVERY: Duration = Duration::from_secs(1);

/// Per peer and right: when a refusal was last logged, and how many since.
type Logged = HashMap<(Option<String>, Right), (Option<Instant>, u64)>;

/// The check of one bus.
#[derive(Debug)]
pub struct Gate {
    bus: String,
    policy: Option<(Policy, Names)>,
    refused: [AtomicU64; 5],
    logged: Mutex<Logged>,
}

/// The refusals of a bus, per right, since the bridge started (the bus's status).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, schemars::JsonSchema)]
pub struct Refused {
    pub read: u64,
    pub stop: u64,
    pub write: u64,
    pub control: u64,
    pub commission: u64,
}

impl Gate {
    pub fn new(bus: &str, policy: Option<(Policy, Names)>) -> Self {
        Self {
            bus: bus.to_owned(),
            policy,
            refused: Default::default(),
            logged: Mutex::new(HashMap::new()),
        }
    }

    /// The sender of a message whose key carries `name`.
    pub fn peer(&self, name: Option<String>) -> Peer {
        let vouched = match (&self.policy, &name) {
            (Some((p, by)), Some(n)) if p.lists(n) => Some(by.proof()),
            _ => None,
        };
        Peer { name, vouched }
    }

    /// Whether `peer` may do `right` on `drive` (`None`: the whole bus); without a policy, every
    /// authenticated peer may (the bridge's flags decide). A refusal is counted and logged,
    /// and its text names the right.
    pub fn check(
        &self,
        peer: &Peer,
        right: Right,
        drive: Option<Address>,
    ) -> Result<(), crate::refusal::Refusal> {
        let Some((policy, _)) = &self.policy else {
            return Ok(());
        };
        if policy.allows(
            peer.verified_name(),
            right,
            &self.bus,
            drive.map(Address::get),
        ) {
            return Ok(());
        }
        let what = drive.map_or_else(
            || format!("every drive of {}", self.bus),
            |d| format!("drive {d} of {}", self.bus),
        );
        let text = format!(
            "refused: {peer} has not the right `{right}` on {what} in this bridge's access policy{}; nothing was done",
            if peer.vouched.is_some() {
                ""
            } else {
                " (a peer granted rights by name sends under .../as/<its name>/...)"
            }
        );
        self.count(peer, right, &text);
        Err(crate::refusal::Refusal::refused(text))
    }

    /// Counts a refusal of `right` to `peer` and logs it (at most every [`LOG_EVERY`] per peer
    /// and right, with how many were not logged).
    pub fn count(&self, peer: &Peer, right: Right, text: &str) {
        let total = self.refused[right as usize].fetch_add(1, Ordering::Relaxed) + 1;
        let mut logged = self
            .logged
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let now = Instant::now();
        let entry = logged
            .entry((peer.name.clone(), right))
            .or_insert((None, 0));
        if entry.0.is_none_or(|t| now.duration_since(t) >= LOG_EVERY) {
            let more = if entry.1 > 0 {
                format!(" (and {} more since the last said)", entry.1)
            } else {
                String::new()
            };
            eprintln!(
                "uss-zenoh: {}: {text}{more}; {total} `{right}` refused on this bus",
                self.bus
            );
            *entry = (Some(now), 0);
        } else {
            entry.1 += 1;
        }
    }

    /// The refusals so far.
    pub fn refused(&self) -> Refused {
        let n = |r: Right| self.refused[r as usize].load(Ordering::Relaxed);
        Refused {
            read: n(Right::Read),
            stop: n(Right::Stop),
            write: n(Right::Write),
            control: n(Right::Control),
            commission: n(Right::Commission),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refusal_names_the_right_and_the_peer_and_is_counted() {
        let policy = Policy::parse(
            "default = [\"read\", \"stop\"]\n[[grant]]\nwho = [\"ctl\"]\nrights = [\"control\"]\ndrives = [1]\n",
            &["line1".to_owned()],
        )
        .unwrap();
        let gate = Gate::new("line1", Some((policy, Names::Certificates)));
        let ctl = gate.peer(Some("ctl".to_owned()));
        assert_eq!(ctl.vouched, Some("certificate"));
        assert_eq!(
            gate.check(&ctl, Right::Control, Address::new(1).ok()),
            Ok(())
        );
        let no = gate
            .check(&ctl, Right::Control, Address::new(2).ok())
            .unwrap_err()
            .text;
        assert!(
            no.contains("\"ctl\" (certificate) has not the right `control` on drive 2 of line1"),
            "{no}"
        );
        // An unlisted name, or none, gets the default rights only.
        let viewer = gate.peer(Some("viewer".to_owned()));
        assert_eq!(viewer.vouched, None);
        assert_eq!(
            gate.check(&viewer, Right::Stop, Address::new(2).ok()),
            Ok(())
        );
        let no = gate
            .check(&viewer, Right::Write, Address::new(2).ok())
            .unwrap_err()
            .text;
        assert!(
            no.contains("(a name nothing vouches for)") && no.contains("`write`"),
            "{no}"
        );
        let no = gate
            .check(&gate.peer(None), Right::Control, None)
            .unwrap_err()
            .text;
        assert!(
            no.contains("a peer that did not name itself") && no.contains("every drive of line1"),
            "{no}"
        );
        assert_eq!(
            gate.refused(),
            Refused {
                control: 2,
                write: 1,
                ..Refused::default()
            }
        );
        // Without a policy the bridge's flags decide, not the gate.
        let open = Gate::new("line1", None);
        assert_eq!(
            open.check(&open.peer(None), Right::Control, Address::new(1).ok()),
            Ok(())
        );
        assert_eq!(open.peer(Some("ctl".to_owned())).vouched, None);
    }
}
