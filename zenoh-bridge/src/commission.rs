//! Commissioning over the network (issue 46): per bus, the queries a service engineer's tool
//! asks as STARTER would, answered by the client library's own calls (`uss_client::backup`,
//! `uss_client::restore`, `Bus::save_to_rom`, `Bus::drive_description`), so a remote tool
//! commissions exactly as `ussctl`, Python and C do:
//!
//! | key (under `<prefix>/<bus>`, or `.../as/<name>`) | right | payload | reply |
//! |---|---|---|---|
//! | `drive/<addr>/describe/<P>` | `read` | none | [`DescribeReply`] |
//! | `drive/<addr>/backup` | `read` | none | the backup file (TOML) |
//! | `drive/<addr>/diff` | `read` | a backup file (TOML), or another drive's address | [`DiffReply`] |
//! | `drive/<addr>/restore` | `commission`, `--allow-writes` | a backup file (TOML); `?eeprom`, `?dry_run` | [`RestoreReply`] |
//! | `drive/<addr>/save` | `commission`, `--allow-writes` | none | [`SaveReply`] |
//!
//! What the network never does: a restore writes no guarded parameter (the command or
//! setpoint source, telegram monitoring off, the COM link: those are written on the machine's
//! own host, deliberately, as a guarded parameter write is) and no drive another process
//! controls (no force from across the network); a drive this bridge holds for a remote
//! controller takes no restore and no copy from another peer. A factory reset and quick
//! commissioning are not offered: each ends in a guarded write (P0970, P3900). Every query ends
//! in exactly one reply. The queries run on a thread of their own (an upload takes seconds):
//! parameter reads and stops never wait behind them.

use crate::control::Held;
use crate::gate::Peer;
use crate::keys::{Keys, has_wildcards};
use crate::params::{Queued, WRITES_REFUSED, reply};
use crate::payload::{DescribeReply, DiffReply, Differs, RestoreReply, SaveReply, VERSION};
use crate::policy::Right;
use crate::refusal::Refusal;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use uss_client::backup::{BackupFile, Diff, settings_catalogue};
use uss_client::restore::{NeverCancelled, RestoreOptions};
use uss_client::{Address, Bus, ParamError, ParamRef};
use zenoh::bytes::Encoding;
use zenoh::query::Query;
use zenoh::{Session, Wait};

/// What a commissioning query asks.
#[derive(Debug, Clone, PartialEq)]
enum Ask {
    Describe(ParamRef),
    Backup,
    Diff,
    Restore,
    Save,
}

impl Ask {
    /// The right it needs.
    const fn right(&self) -> Right {
        match self {
            Self::Describe(_) | Self::Backup | Self::Diff => Right::Read,
            Self::Restore | Self::Save => Right::Commission,
        }
    }
}

/// The drive and the ask a key names (after `<prefix>/<bus>[/as/<name>]`), or why none.
fn ask_of(keys: &Keys, key: &str) -> Result<(Address, Ask), Refusal> {
    if has_wildcards(key) {
        return Err(Refusal::invalid(format!(
            "{key}: a commissioning query names one drive exactly (no wildcards)"
        )));
    }
    let rest = keys
        .drive_rest(key)
        .ok_or_else(|| Refusal::invalid(format!("{key}: not a commissioning key of this bus")))?;
    let (drive, what) = rest.split_once('/').ok_or_else(|| {
        Refusal::invalid(format!(
            "{key}: .../drive/<addr>/<backup|diff|restore|save|describe/P>"
        ))
    })?;
    let address = crate::keys::address(drive).ok_or_else(|| {
        Refusal::invalid(format!("{key}: {drive:?} is not a drive address 0..=31"))
    })?;
    let ask = match what {
        "backup" => Ask::Backup,
        "diff" => Ask::Diff,
        "restore" => Ask::Restore,
        "save" => Ask::Save,
        other => match other.strip_prefix("describe/") {
            Some(p) => Ask::Describe(
                p.parse::<ParamRef>()
                    .map_err(|e| Refusal::invalid(format!("{key}: {p:?}: {e}")))?,
            ),
            None => {
                return Err(Refusal::invalid(format!(
                    "{key}: .../drive/<addr>/<backup|diff|restore|save|describe/P>"
                )));
            }
        },
    };
    Ok((address, ask))
}

/// The query's payload as text, `None` without one.
fn text_of(query: &Query) -> Result<Option<String>, Refusal> {
    query
        .payload()
        .map(|p| {
            p.try_to_string()
                .map(std::borrow::Cow::into_owned)
                .map_err(|_| Refusal::invalid("the payload is not text (UTF-8)"))
        })
        .transpose()
        .map(|t| t.filter(|t| !t.trim().is_empty()))
}

/// Whether the query's parameters set `name` (`?eeprom`, `?eeprom=true`).
fn flag(query: &Query, name: &str) -> bool {
    query
        .parameters()
        .get(name)
        .is_some_and(|v| v.is_empty() || v == "true")
}

/// The one answer to a commissioning query: the reply's payload and encoding, or why not.
fn answer(
    bus: Result<&Bus, &Refusal>,
    keys: &Keys,
    name: &str,
    query: &Query,
    rules: crate::params::Rules<'_>,
) -> Result<(String, Encoding), Refusal> {
    let key = query.key_expr().as_str();
    let (sender, keys) = keys
        .sender(key)
        .map_err(|e| Refusal::invalid(e.to_string()))?;
    let peer = rules.gate.peer(sender);
    let (drive, ask) = ask_of(&keys, key)?;
    let right = ask.right();
    if right == Right::Commission && !rules.allow_writes {
        rules.gate.count(&peer, right, WRITES_REFUSED);
        return Err(Refusal::refused(WRITES_REFUSED));
    }
    rules.gate.check(&peer, right, Some(drive))?;
    if right == Right::Commission {
        held_by_another(rules.held, &peer, drive)?;
    }
    let bus = bus.map_err(Clone::clone)?;
    let failed = |e: ParamError| Refusal::new(e.kind(), format!("drive {drive}: {e}"));
    let json = |v: &dyn erased::Json| v.json().map(|j| (j, Encoding::APPLICATION_JSON));
    match ask {
        Ask::Describe(param) => {
            let said = bus
                .drive_description(drive, param.pnu)
                .map_err(|e| Refusal::new(e.kind(), format!("drive {drive} {param}: {e}")))?;
            let entry = bus.catalogue_entry(drive, param.pnu);
            json(&DescribeReply {
                v: VERSION,
                bus: name,
                drive: drive.get(),
                param: entry.map_or_else(|| param.to_string(), |p| p.id.to_string()),
                family: bus.family(drive).name(),
                data_type: said.data_type.to_string(),
                elements: said.elements,
                read_only: said.read_only,
                min: said.min,
                max: said.max,
                name: entry.map(|p| p.name.as_str()),
                unit: entry.map(|p| p.unit.as_str()),
                change: entry.map(|p| p.change.words()),
                default: entry.and_then(|p| p.default),
            })
        }
        Ask::Backup => {
            // `?discover=FROM-TO`: also what the drive describes beyond the catalogue.
            let discover = match query.parameters().get("discover") {
                None => None,
                Some(range) => Some(uss_client::backup::pnu_range(range).ok_or_else(|| {
                    Refusal::invalid(format!(
                        "{key}: discover={range}: a range of parameter numbers FROM-TO (0-3999)"
                    ))
                })?),
            };
            let options = uss_client::backup::UploadOptions { discover };
            let upload = bus
                .upload_with(drive, &options, &mut |_, _| {})
                .map_err(failed)?;
            Ok((upload.file.to_text(), Encoding::TEXT_PLAIN))
        }
        Ask::Diff => {
            let other = text_of(query)?.ok_or_else(|| {
                Refusal::invalid(format!(
                    "{key}: send a backup file (its TOML) or another drive's address as the payload"
                ))
            })?;
            let diff = match other.trim().parse::<u8>() {
                Ok(a) => {
                    let second = Address::new(a).map_err(|e| Refusal::invalid(e.to_string()))?;
                    bus.diff_drives(drive, second, &mut |_, _| {})
                }
                Err(_) => bus.diff_file(drive, &other, "the query's payload", &mut |_, _| {}),
            }
            .map_err(failed)?;
            json(&diff_reply(name, drive, &diff))
        }
        Ask::Restore => json(&restore(bus, name, drive, query)?),
        Ask::Save => {
            let saved = bus.save_to_rom(drive).map_err(failed)?;
            json(&SaveReply {
                v: VERSION,
                bus: name,
                drive: drive.get(),
                param: saved.param.to_string(),
                raised: saved.raised_text(),
            })
        }
    }
}

/// A restore of the backup file the query sends, never guarded, never forced.
fn restore<'a>(
    bus: &Bus,
    name: &'a str,
    drive: Address,
    query: &Query,
) -> Result<RestoreReply<'a>, Refusal> {
    let key = query.key_expr().as_str();
    let failed = |e: ParamError| Refusal::new(e.kind(), format!("drive {drive}: {e}"));
    let text = text_of(query)?.ok_or_else(|| {
        Refusal::invalid(format!(
            "{key}: send the backup file (its TOML) as the payload"
        ))
    })?;
    let catalogue = settings_catalogue(drive, bus.family(drive)).map_err(failed)?;
    let loaded =
        BackupFile::parse(&text, "the query's payload", catalogue).map_err(|e| failed(e.into()))?;
    let options = RestoreOptions {
        eeprom: flag(query, "eeprom"),
        dry_run: flag(query, "dry_run"),
        // Never from across the network (see the module's text).
        force: false,
        unsafe_write: false,
        ..RestoreOptions::default()
    };
    let done = bus
        .restore(
            drive,
            &loaded,
            options,
            &NeverCancelled,
            &mut |_, _| {},
            &mut |_| {},
        )
        .map_err(|e| match e {
            ParamError::Guarded {
                ref params,
                ref why,
            } => Refusal::new(
                e.kind(),
                format!(
                    "drive {drive}: the backup changes {params}, which can take the drive \
                     away from ussd ({why}); nothing was written: a guarded parameter is \
                     written on the machine's own host, deliberately (ussctl param restore \
                     --unsafe), never from across the network"
                ),
            ),
            e => failed(e),
        })?;
    Ok(RestoreReply {
        v: VERSION,
        bus: name,
        drive: drive.get(),
        complete: done.is_complete(),
        dry_run: options.dry_run,
        equal: done.equal,
        written: done.written,
        refused: done.refused,
        unknown: done.unknown,
        kept: done.kept,
        cut_short: done.cut_short.clone(),
        left_raised: done
            .left_raised
            .iter()
            .map(|l| format!("{} := {} (was {}: {})", l.param, l.to, l.was, l.meaning))
            .collect(),
        stored: done.stored.clone(),
        ignored: done.ignored.clone(),
        lines: done.lines.clone(),
        seconds: done.took.as_secs_f64(),
    })
}

/// A restore or copy of a drive this bridge holds for a remote controller, asked by another
/// peer than that controller's verified name: refused.
fn held_by_another(held: &Held, peer: &Peer, drive: Address) -> Result<(), Refusal> {
    match held.held_from(drive, peer) {
        Some(holder) => Err(Refusal::refused(format!(
            "drive {drive}: the drive runs under remote control by {:?} through this bridge: \
             commissioning from the network is refused until it releases the drive, but from \
             that controller's own certificate; nothing was done",
            holder.from
        ))),
        None => Ok(()),
    }
}

/// A diff as its reply.
fn diff_reply<'a>(bus: &'a str, drive: Address, diff: &Diff) -> DiffReply<'a> {
    DiffReply {
        v: VERSION,
        bus,
        drive: drive.get(),
        same: diff.same,
        differ: diff
            .differ
            .iter()
            .map(|d| Differs {
                param: d.param.to_string(),
                name: d.info.name.as_str(),
                drive: d.drive.map(|v| d.info.show(v)),
                other: d.other.map(|v| d.info.show(v)),
            })
            .collect(),
        ignored: diff.ignored.clone(),
    }
}

/// A payload as JSON, for any of the replies.
mod erased {
    pub trait Json {
        fn json(&self) -> Result<String, crate::refusal::Refusal>;
    }

    impl<T: serde::Serialize> Json for T {
        fn json(&self) -> Result<String, crate::refusal::Refusal> {
            serde_json::to_string(self).map_err(|e| {
                crate::refusal::Refusal::new(uss_client::ErrorKind::Internal, e.to_string())
            })
        }
    }
}

/// Commissioning queries waiting for the thread; a full queue answers at once that it is full.
const QUEUE: usize = 16;

/// Serves the commissioning queries of bus `name` until `stop` (see the module's table), each
/// also under a peer's name, checked against the bus's access policy.
pub fn serve(
    session: &Session,
    name: &str,
    keys: &Keys,
    rules: crate::params::Rules<'_>,
    stop: &Arc<AtomicBool>,
) {
    let on = keys
        .commissioning()
        .into_iter()
        .chain(keys.named().commissioning())
        .map(|k| (k, ()))
        .collect();
    let Some(queued) = Queued::declare(session, on, QUEUE, "commissioning queries") else {
        return;
    };
    queued.serve(
        name,
        "uss-zenoh-commission",
        stop,
        |bus, query, ()| match answer(bus, keys, name, query, rules) {
            Ok((payload, encoding)) => {
                let key = query.key_expr().as_str().to_owned();
                if let Err(e) = query.reply(key, payload).encoding(encoding).wait() {
                    eprintln!("uss-zenoh: reply to {}: {e}", query.key_expr());
                }
            }
            Err(refusal) => reply(query, Err(refusal)),
        },
    );
}
