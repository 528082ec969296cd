//! Parameters over the network: one queryable per bus for `.../drive/<addr>/param/<P1082>`. A
//! query without a payload reads the parameter from the drive through ussd; a query with a
//! payload (`45.0`) writes it, only when the bridge runs with `--allow-writes`, and then under
//! the same rules as a local write (refused while another process controls the drive, and while
//! this bridge holds the drive for a remote controller: [`crate::control::Held`]). Every
//! query ends in exactly one reply: the value as JSON, or an error reply with the text `ussctl`
//! gives for the same failure.

use crate::control::Held;
use crate::keys::Keys;
use crate::payload::ParamReply;
use core::time::Duration;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use uss_client::{Bus, ParamError, WriteOptions};
use zenoh::bytes::Encoding;
use zenoh::query::Query;
use zenoh::{Session, Wait};

/// What a write query is refused with while the bridge does not allow writes.
pub const WRITES_REFUSED: &str = "writes are refused: this uss-zenoh runs without --allow-writes";

/// One reply: its concrete key, and the JSON of the value or the error text.
type Answer = (String, Result<String, String>);

/// The answers to one query: for each parameter it names (one, or with wildcards every drive of
/// the bus its key intersects), the concrete key and the JSON of the value or the error text;
/// or why it names none.
fn answers(
    bus: Result<&Bus, &String>,
    keys: &Keys,
    name: &str,
    query: &Query,
    allow_writes: bool,
    held: &Held,
) -> Result<Vec<Answer>, String> {
    let key = query.key_expr().as_str();
    let drives = match (bus, crate::keys::has_wildcards(key)) {
        (Ok(b), true) => b.drives(),
        _ => Vec::new(),
    };
    let named = keys.params_named(key, &drives).map_err(|e| e.to_string())?;
    if named.len() > 1 && query.payload().is_some() {
        return Err(format!(
            "{key}: a write names one drive and one parameter exactly (this key names {})",
            named.len()
        ));
    }
    Ok(named
        .into_iter()
        .map(|n| {
            let answer = answer(bus, name, query, allow_writes, held, n.drive, n.param);
            (n.key, answer)
        })
        .collect())
}

/// The answer for one drive and parameter: the JSON of the value, or the error text.
fn answer(
    bus: Result<&Bus, &String>,
    name: &str,
    query: &Query,
    allow_writes: bool,
    held: &Held,
    drive: u8,
    param: uss_client::uss_protocol::ParamRef,
) -> Result<String, String> {
    let payload = query
        .payload()
        .map(|p| {
            p.try_to_string()
                .map(|s| s.trim().to_owned())
                .map_err(|_| "the value to write is not text: send e.g. 45.0".to_owned())
        })
        .transpose()?
        .filter(|s| !s.is_empty());
    let bus = bus.map_err(Clone::clone)?;
    // The texts of `ussctl param read/write` for the same failures.
    let failed = |e: ParamError| match e {
        ParamError::Value { .. } => format!("drive {drive} {e}"),
        e => format!("drive {drive} {param}: {e}"),
    };
    let value = match payload {
        None => ParamReply::new(
            name,
            drive,
            &bus.read_param(drive, param).map_err(failed)?,
            None,
        ),
        Some(_) if !allow_writes => return Err(WRITES_REFUSED.to_owned()),
        Some(_) if let Some(holder) = held.holder(drive) => {
            return Err(format!(
                "drive {drive} {param}: the drive runs under remote control by {holder:?} through \
                 this bridge: parameter writes from the network are refused until it releases \
                 the drive (the bridge cannot tell that peer's queries from another's); nothing \
                 was written"
            ));
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
            ParamReply::new(name, drive, &written, Some(options.eeprom))
        }
    };
    serde_json::to_string(&value).map_err(|e| e.to_string())
}

/// Serves the parameter queries of bus `name` until `stop`; writes to a drive in `held` are
/// refused.
pub fn serve(
    session: &Session,
    name: &str,
    keys: &Keys,
    allow_writes: bool,
    held: &Held,
    stop: &Arc<AtomicBool>,
) {
    let queryable = match session.declare_queryable(keys.params()).wait() {
        Ok(q) => q,
        Err(e) => {
            eprintln!(
                "uss-zenoh: cannot declare the queryable {}: {e}",
                keys.params()
            );
            return;
        }
    };
    let mut bus: Result<Bus, String> = Err(format!("ussd is not running on {name}"));
    while !stop.load(Ordering::Relaxed) {
        let query = match queryable.recv_timeout(Duration::from_millis(100)) {
            Ok(Some(q)) => q,
            Ok(None) => continue,
            Err(_) => break,
        };
        if bus.is_err() {
            bus = Bus::open_as(name, "uss-zenoh-params").map_err(|e| e.to_string());
        }
        match answers(bus.as_ref(), keys, name, &query, allow_writes, held) {
            Ok(list) => {
                for (key, answer) in list {
                    reply_as(&query, &key, answer);
                }
            }
            Err(text) => reply(&query, Err(text)),
        }
    }
}

/// Ends `query` with its one answer: the JSON as a reply, or the text as an error reply; a reply
/// that cannot be sent is reported on stderr.
pub fn reply(query: &Query, answer: Result<String, String>) {
    reply_as(query, query.key_expr().as_str(), answer);
}

/// One answer to `query` under the concrete `key` (the query's own when it has no wildcards).
pub fn reply_as(query: &Query, key: &str, answer: Result<String, String>) {
    let sent = match answer {
        Ok(json) => query
            .reply(key, json)
            .encoding(Encoding::APPLICATION_JSON)
            .wait(),
        Err(text) => query.reply_err(text).wait(),
    };
    if let Err(e) = sent {
        eprintln!("uss-zenoh: reply to {}: {e}", query.key_expr());
    }
}
