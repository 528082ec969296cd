//! Commissioning calls a service engineer makes with STARTER (issue 46), in the
//! client library so that every front-end makes them the same way: the copy of RAM to ROM
//! ([`Bus::save_to_rom`]) and the guided factory reset ([`Bus::factory_reset`]).
//!
//! A drive keeps a parameter written over USS in RAM unless the write asks for EEPROM as well
//! (task codes 11..14 on MICROMASTER 4). A SINAMICS G120 (CU2x0-2) has no such task codes: its
//! settings become permanent only by its "copy RAM to ROM", p0971 = 1, which stores every
//! setting at once. MICROMASTER 4 has the same call, P0971.

use crate::params::WriteOptions;
use crate::{Bus, ParamError};
use core::time::Duration;
use std::time::Instant;
use uss_catalogue::Catalogue;
use uss_protocol::{ParamRef, Value};
use uss_shm_types::{Address, Monitoring};

/// How long a copy of RAM to ROM may take before the drive says it is done (its parameter
/// reads 0 again). A MICROMASTER 4 stores its whole list in well under this.
pub const SAVE_WAIT: Duration = Duration::from_secs(30);

/// How often the copy's parameter is read while the drive stores.
const SAVE_POLL: Duration = Duration::from_millis(50);

/// What a copy of RAM to ROM did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Saved {
    /// The parameter that started it (P0971, p0971).
    pub param: ParamRef,
    /// The access level raised for it and put back, in RAM and EEPROM alike: (its parameter,
    /// raised to, put back to).
    pub raised: Option<(ParamRef, u16, u16)>,
}

impl Saved {
    /// The raise as every front-end shows it: "P0003 1 -> 3 -> 1"; none when none was needed.
    pub fn raised_text(&self) -> Option<String> {
        self.raised
            .map(|(p, to, was)| format!("{p} {was} -> {to} -> {was}"))
    }
}

/// How long a factory reset may take before the drive says it is done (its reset parameter
/// reads 0 again; a drive that restarts for it answers nothing meanwhile).
pub const RESET_WAIT: Duration = Duration::from_secs(60);

/// What a factory reset did, and what ussd read of the drive after it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reset {
    /// The commissioning parameter and the value that unlocked the reset (P0010, 30).
    pub unlocked_by: (ParamRef, u16),
    /// The reset's parameter (P0970, p0970).
    pub param: ParamRef,
    /// From the first write to the drive saying it is done.
    pub took: Duration,
    /// The reference frequency ussd scales Hz by now, read again after the reset; none when
    /// ussd did not have it within the drive's [`crate::DriveWatch::reference_wait`].
    pub reference_hz: Option<f32>,
    /// The drive's telegram monitoring as ussd read it again, and its time in ms.
    pub monitoring: Monitoring,
    pub monitoring_ms: u32,
}

/// A parameter as a whole (its index dropped): the plain parameters the commissioning calls
/// write.
const fn whole(p: ParamRef) -> ParamRef {
    ParamRef { index: None, ..p }
}

impl Bus {
    /// Copies every setting of drive `address` from RAM to EEPROM ("copy RAM to ROM": P0971 on
    /// MICROMASTER 4, p0971 on SINAMICS G120), and returns once the drive says it is done (the
    /// parameter reads 0 again, within [`SAVE_WAIT`]). Every value then survives a power cycle.
    ///
    /// Where the call needs a higher access level than the drive has (P0971 is level 3 on
    /// MICROMASTER 4), the level is raised for it and put back afterwards, in EEPROM too: the
    /// copy stored the raised level, and a temporary raise must not outlive the call.
    ///
    /// # Errors
    /// [`ParamError::NotOnFamily`] for a family without a known copy (a generic slave, a
    /// SIMOREG); the drive's or the path's error otherwise (the level is put back all the same).
    pub fn save_to_rom(&self, address: Address) -> Result<Saved, ParamError> {
        let family = self.family(address);
        let catalogue = Catalogue::of(family);
        let Some(save) = catalogue.and_then(|c| c.save).map(whole) else {
            return Err(ParamError::NotOnFamily {
                address: address.get(),
                family: family.name(),
                what: "uss-rt knows no copy of RAM to ROM for this family",
            });
        };
        let catalogue = catalogue.ok_or(ParamError::Dropped)?;
        let needed = catalogue.param(save.pnu.get()).map(|p| u16::from(p.level));
        let raise = match (catalogue.access_level.map(whole), needed) {
            (Some(level), Some(needed)) => {
                let now = self.read_u16(address, level)?;
                (needed > now).then_some((level, needed, now))
            }
            _ => None,
        };
        if let Some((level, to, _)) = raise {
            self.write(address, level, Value::Word(to), false)?;
        }
        let saved = self.copy_ram_to_rom(address, save);
        if saved.is_err() {
            // A copy whose answer was lost may still be storing: let it end (bounded) before
            // the level is put back, or the copy would store the raised level after it.
            self.wait_saved(address, save);
        }
        let Some((level, _, was)) = raise else {
            return saved.map(|()| Saved {
                param: save,
                raised: None,
            });
        };
        // Its own raise goes back whoever took control meanwhile (forced), in RAM first (a
        // quick write, whatever the EEPROM does), then in EEPROM, which the copy may have
        // stored the raised level in: by the task that stores one value, or (a G120) by a
        // second copy. Each is tried whatever became of the other.
        let back = WriteOptions {
            force: true,
            ..WriteOptions::default()
        };
        let ram = self.write_with(address, level, Value::Word(was), back);
        let eeprom = if catalogue.eeprom_tasks {
            self.write_with(
                address,
                level,
                Value::Word(was),
                WriteOptions {
                    eeprom: true,
                    ..back
                },
            )
            .map(|_| ())
        } else {
            self.copy_ram_to_rom(address, save)
        };
        let put_back = ram.map(|_| ()).and(eeprom).map_err(|e| ParamError::Value {
            param: level.to_string(),
            problem: format!(
                "raised to {} for the copy of RAM to ROM and not surely put back to {was} ({e}): \
                 read it, and write {was} to RAM and EEPROM",
                raise.map_or(0, |(_, to, _)| to)
            ),
        });
        saved.and(put_back).map(|()| Saved {
            param: save,
            raised: raise,
        })
    }

    /// Puts every setting of drive `address` back to its factory value, as its manual gives it
    /// (MICROMASTER 4 and G120: the commissioning parameter to 30, then P0970 / p0970 = 1),
    /// waits until the drive says it is done (the reset parameter reads 0 again, within
    /// [`RESET_WAIT`]; a drive that restarts for it is waited for), and then until ussd has
    /// read again what it scales and judges the drive by (its reference and its telegram
    /// monitoring, `crate::DriveWatch::reference_wait`). The writes are deliberate (ussd logs
    /// them as unsafe: the reset takes the command source, the COM link and the monitoring back
    /// to their defaults); `force` writes while another process controls the drive. Only RAM
    /// and what the drive itself stores are changed: nothing of it is copied to ROM here.
    ///
    /// # Errors
    /// [`ParamError::NotOnFamily`] for a family without a known reset; the drive's or the
    /// path's error otherwise.
    pub fn factory_reset(&self, address: Address, force: bool) -> Result<Reset, ParamError> {
        let family = self.family(address);
        let catalogue = Catalogue::of(family);
        let known = catalogue.and_then(|c| {
            Some((
                whole(c.factory_reset?),
                whole(c.commissioning?),
                c.factory_setting?,
            ))
        });
        let Some((reset, commissioning, setting)) = known else {
            return Err(ParamError::NotOnFamily {
                address: address.get(),
                family: family.name(),
                what: "uss-rt knows no factory reset for this family",
            });
        };
        let deliberate = WriteOptions {
            eeprom: false,
            force,
            unsafe_write: true,
        };
        let start = Instant::now();
        let was = self.read_u16(address, commissioning)?;
        self.write_with(address, commissioning, Value::Word(setting), deliberate)?;
        match self.write_with(address, reset, Value::Word(1), deliberate) {
            // The drive may answer with the reset's own 0, or restart before it answers.
            Ok(_) => {}
            Err(e) if e.may_be_applied() => {}
            Err(e) => {
                // Refused (the drive runs, a level too low): not left in factory-setting mode,
                // where it would not run.
                let _ = self.write_with(address, commissioning, Value::Word(was), deliberate);
                return Err(e);
            }
        }
        let until = start + RESET_WAIT;
        loop {
            match self.read_u16(address, reset) {
                Ok(0) => break,
                Ok(_) | Err(_) if Instant::now() < until => std::thread::sleep(SAVE_POLL),
                Ok(v) => {
                    return Err(ParamError::Value {
                        param: reset.to_string(),
                        problem: format!(
                            "still {v} after {} s: the drive has not finished its reset",
                            RESET_WAIT.as_secs()
                        ),
                    });
                }
                Err(e) => return Err(e),
            }
        }
        let took = start.elapsed();
        let done_ns = crate::monotonic_ns();
        // ussd reads the drive again once the reset's write took effect (and when it comes
        // back, had it restarted): wait for diagnostics published after the drive said it was
        // done (a reply of it after then), which show what ussd read.
        let until = Instant::now() + self.watch(address)?.reference_wait();
        loop {
            let read = self
                .diag(address)
                .ok()
                .filter(|d| d.last_good_ns >= done_ns);
            let monitoring = read.and_then(|d| d.monitoring().ok());
            let reference = read.and_then(|d| d.info.reference());
            let known = reference.is_some() && monitoring.is_some_and(|m| m != Monitoring::Unknown);
            if known || Instant::now() >= until {
                return Ok(Reset {
                    unlocked_by: (commissioning, setting),
                    param: reset,
                    took,
                    reference_hz: reference,
                    monitoring: monitoring.unwrap_or(Monitoring::Unknown),
                    monitoring_ms: read.map_or(0, |d| d.monitoring_ms),
                });
            }
            std::thread::sleep(SAVE_POLL);
        }
    }

    /// Waits (up to [`SAVE_WAIT`]) until `save` reads 0: a copy whose answer was lost has ended.
    fn wait_saved(&self, address: Address, save: ParamRef) {
        let until = Instant::now() + SAVE_WAIT;
        while self.read_u16(address, save) != Ok(0) && Instant::now() < until {
            std::thread::sleep(SAVE_POLL);
        }
    }

    /// Writes 1 to `save` and waits until it reads 0 again: the drive is done.
    fn copy_ram_to_rom(&self, address: Address, save: ParamRef) -> Result<(), ParamError> {
        self.write(address, save, Value::Word(1), false)?;
        let until = Instant::now() + SAVE_WAIT;
        loop {
            match self.read_u16(address, save)? {
                0 => return Ok(()),
                _ if Instant::now() >= until => {
                    return Err(ParamError::Value {
                        param: save.to_string(),
                        problem: format!(
                            "still 1 after {} s: the drive has not finished storing its settings",
                            SAVE_WAIT.as_secs()
                        ),
                    });
                }
                _ => std::thread::sleep(SAVE_POLL),
            }
        }
    }
}
