//! Parameters over the network: one queryable per bus for `.../drive/<addr>/param/<P1082>`. A
//! query without a payload reads the parameter from the drive through ussd; a query with a
//! payload (`45.0`) writes it, only when the bridge runs with `--allow-writes`, and then under
//! the same rules as a local write (refused while another process controls the drive, and while
//! this bridge holds the drive for a remote controller: [`crate::control::Held`]), and the
//! rights of the bridge's access policy ([`crate::gate`]). Every
//! query ends in exactly one reply: the value as JSON, or an error reply with the text `ussctl`
//! gives for the same failure.

use crate::control::Held;
use crate::gate::{Gate, Peer};
use crate::keys::{Keys, ParamKey};
use crate::payload::ParamReply;
use crate::policy::Right;
use crate::refusal::Refusal;
use core::time::Duration;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use uss_client::{Address, Bus, ParamError, WriteOptions};
use zenoh::bytes::Encoding;
use zenoh::query::Query;
use zenoh::{Session, Wait};

/// What a write query is refused with while the bridge does not allow writes.
pub const WRITES_REFUSED: &str = "writes are refused: this uss-zenoh runs without --allow-writes";

/// One reply: its concrete key, and the JSON of the value or why not.
type Answer = (String, Result<String, Refusal>);

/// The answers to one query: for each parameter it names (one, or with wildcards every drive of
/// the bus its key intersects), the concrete key and the JSON of the value or the error text;
/// or why it names none.
fn answers(
    bus: Result<&Bus, &Refusal>,
    keys: &Keys,
    bus_name: &str,
    query: &Query,
    rules: Rules<'_>,
    which: ParamKey,
) -> Result<Vec<Answer>, Refusal> {
    let key = query.key_expr().as_str();
    if which == ParamKey::Write && query.payload().is_none() {
        return Err(Refusal::invalid(format!(
            "{key}: a query on .../set/<P> writes: send the value as its payload (e.g. 45.0)"
        )));
    }
    let (name, keys) = keys
        .sender(key)
        .map_err(|e| Refusal::invalid(e.to_string()))?;
    let peer = rules.gate.peer(name);
    let drives = match (bus, crate::keys::has_wildcards(key)) {
        (Ok(b), true) => b.drives(),
        _ => Vec::new(),
    };
    let named = keys
        .params_named(key, which, &drives)
        .map_err(|e| Refusal::invalid(e.to_string()))?;
    if named.len() > 1 && query.payload().is_some() {
        return Err(Refusal::invalid(format!(
            "{key}: a write names one drive and one parameter exactly (this key names {})",
            named.len()
        )));
    }
    Ok(named
        .into_iter()
        .map(|n| {
            let answer = answer(bus, bus_name, query, rules, &peer, n.drive, n.param);
            (n.key, answer)
        })
        .collect())
}

/// The answer for one drive and parameter: the JSON of the value, or why not.
fn answer(
    bus: Result<&Bus, &Refusal>,
    name: &str,
    query: &Query,
    rules: Rules<'_>,
    peer: &Peer,
    drive: Address,
    param: uss_client::uss_protocol::ParamRef,
) -> Result<String, Refusal> {
    let payload = query
        .payload()
        .map(|p| {
            p.try_to_string()
                .map(|s| s.trim().to_owned())
                .map_err(|_| Refusal::invalid("the value to write is not text: send e.g. 45.0"))
        })
        .transpose()?
        .filter(|s| !s.is_empty());
    let right = if payload.is_some() {
        Right::Write
    } else {
        Right::Read
    };
    if right == Right::Write && !rules.allow_writes {
        rules.gate.count(peer, right, WRITES_REFUSED);
        return Err(Refusal::refused(WRITES_REFUSED));
    }
    rules.gate.check(peer, right, Some(drive))?;
    let bus = bus.map_err(Clone::clone)?;
    // The texts of `ussctl param read/write` for the same failures.
    let failed = |e: ParamError| {
        let text = match (&e, bus.refusal_hint(drive, param, &e)) {
            (ParamError::Value { .. }, _) => format!("drive {drive} {e}"),
            (_, Some(hint)) => format!("drive {drive} {param}: {e}: {hint}"),
            (_, None) => format!("drive {drive} {param}: {e}"),
        };
        Refusal::new(e.kind(), text)
    };
    let value = match payload {
        None => ParamReply::new(
            name,
            drive.get(),
            &bus.read_param(drive, param).map_err(failed)?,
            None,
        ),
        Some(_) if let Some(holder) = rules.held.held_from(drive, peer) => {
            return Err(Refusal::refused(format!(
                "drive {drive} {param}: the drive runs under remote control by {:?} through \
                 this bridge: parameter writes from the network are refused until it releases \
                 the drive, but from that controller's own certificate (named in the bridge's \
                 access policy, sending under .../as/<its name>/...); nothing was written",
                holder.from
            )));
        }
        Some(text) => {
            let options = WriteOptions {
                eeprom: query
                    .parameters()
                    .get("eeprom")
                    .is_some_and(|v| v == "true" || v.is_empty()),
                force: false,
                // Never from across the network: a guarded parameter (command source, COM
                // link, ...) is written on the machine's own host, deliberately.
                unsafe_write: false,
            };
            let written = bus
                .write_param(drive, param, &text, options)
                .map_err(failed)?;
            ParamReply::new(name, drive.get(), &written, Some(options.eeprom))
        }
    };
    serde_json::to_string(&value)
        .map_err(|e| Refusal::new(uss_client::ErrorKind::Internal, e.to_string()))
}

/// What the parameter queries of a bus may do.
#[derive(Debug, Clone, Copy)]
pub struct Rules<'a> {
    /// `--allow-writes`.
    pub allow_writes: bool,
    /// The drives the bridge holds for a remote controller: no writes to them from another.
    pub held: &'a Held,
    /// The bus's check of who may do what.
    pub gate: &'a Gate,
}

/// Queries waiting for the parameter thread; a full queue answers at once that it is full.
const QUEUE: usize = 256;

/// Serves the parameter queries of bus `name` until `stop`: reads (and writes) on
/// `.../drive/<addr>/param/<P>`, writes on `.../drive/<addr>/set/<P>`, each also under a peer's
/// name (`.../as/<name>/drive/...`), checked against the bus's access policy.
pub fn serve(session: &Session, name: &str, keys: &Keys, rules: Rules<'_>, stop: &Arc<AtomicBool>) {
    // Queries of peers that do not name themselves, and of those that do (.../as/<name>/...).
    let queued = Queued::declare(
        session,
        vec![
            (keys.params(), ParamKey::Read),
            (keys.writes(), ParamKey::Write),
            (keys.named().params(), ParamKey::Read),
            (keys.named().writes(), ParamKey::Write),
        ],
        QUEUE,
        "parameter queries",
    );
    if let Some(queued) = queued {
        queued.serve(
            name,
            "uss-zenoh-params",
            stop,
            |bus, query, which| match answers(bus, keys, name, query, rules, which) {
                Ok(list) => {
                    for (key, answer) in list {
                        reply_as(query, &key, answer);
                    }
                }
                Err(refusal) => reply(query, Err(refusal)),
            },
        );
    }
}

/// Queries on some keys, queued for one thread of the bridge (`T` says which key each came on),
/// with the queryables that take them. Zenoh's callback never blocks: a full queue, or a
/// thread that has ended, is an answer too, so every query ends in one.
pub struct Queued<T> {
    rx: crossbeam_channel::Receiver<(Query, T)>,
    _queryables: Vec<zenoh::query::Queryable<()>>,
}

impl<T: Copy + Send + Sync + 'static> Queued<T> {
    /// Declares a queryable on each key, queueing up to `queue` queries (`what` says which
    /// in the answer of a full queue); `None` when one cannot be declared (said on stderr).
    pub fn declare(
        session: &Session,
        keys: Vec<(String, T)>,
        queue: usize,
        what: &'static str,
    ) -> Option<Self> {
        let (tx, rx) = crossbeam_channel::bounded::<(Query, T)>(queue);
        let mut queryables = Vec::new();
        for (key, tag) in keys {
            let tx = tx.clone();
            let declared = session
                .declare_queryable(&key)
                .callback(move |q| match tx.try_send((q, tag)) {
                    Ok(()) => {}
                    Err(crossbeam_channel::TrySendError::Full((q, _))) => reply(
                        &q,
                        Err(Refusal::refused(format!(
                            "the bridge is {queue} {what} behind: ask again"
                        ))),
                    ),
                    Err(crossbeam_channel::TrySendError::Disconnected((q, _))) => reply(
                        &q,
                        Err(Refusal::new(
                            uss_client::ErrorKind::UssdStopped,
                            "the bridge is stopping: nothing was done",
                        )),
                    ),
                })
                .wait();
            match declared {
                Ok(q) => queryables.push(q),
                Err(e) => {
                    eprintln!("uss-zenoh: cannot declare the queryable {key}: {e}");
                    return None;
                }
            }
        }
        Some(Self {
            rx,
            _queryables: queryables,
        })
    }

    /// Answers each query with `answer` until `stop`, on bus `name` (opened as `node` when a
    /// query comes and it is not open yet: ussd may start after the bridge).
    pub fn serve(
        &self,
        name: &str,
        node: &str,
        stop: &Arc<AtomicBool>,
        mut answer: impl FnMut(Result<&Bus, &Refusal>, &Query, T),
    ) {
        let mut bus: Result<Bus, Refusal> = Err(Refusal::new(
            uss_client::ErrorKind::NotRunning,
            format!("ussd is not running on {name}"),
        ));
        while !stop.load(Ordering::Relaxed) {
            let (query, tag) = match self.rx.recv_timeout(Duration::from_millis(100)) {
                Ok(q) => q,
                Err(crossbeam_channel::RecvTimeoutError::Timeout) => continue,
                Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
            };
            if bus.is_err() {
                bus = Bus::open_as(name, node).map_err(Refusal::from);
            }
            answer(bus.as_ref(), &query, tag);
        }
    }
}

/// Ends `query` with its one answer: the JSON as a reply, or the refusal as an error reply (its
/// JSON: text, kind and code, [`Refusal::json`]); a reply that cannot be sent is reported on
/// stderr.
pub fn reply(query: &Query, answer: Result<String, Refusal>) {
    reply_as(query, query.key_expr().as_str(), answer);
}

/// One answer to `query` under the concrete `key` (the query's own when it has no wildcards).
pub fn reply_as(query: &Query, key: &str, answer: Result<String, Refusal>) {
    let sent = match answer {
        Ok(json) => query
            .reply(key, json)
            .encoding(Encoding::APPLICATION_JSON)
            .wait(),
        Err(refusal) => query
            .reply_err(refusal.json())
            .encoding(Encoding::APPLICATION_JSON)
            .wait(),
    };
    if let Err(e) = sent {
        eprintln!("uss-zenoh: reply to {}: {e}", query.key_expr());
    }
}
