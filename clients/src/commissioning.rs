//! Commissioning calls a service engineer makes with STARTER (issue 46), in the
//! client library so that every front-end makes them the same way: the copy of RAM to ROM
//! ([`Bus::save_to_rom`]), the guided factory reset ([`Bus::factory_reset`]) and quick
//! commissioning ([`Bus::quick_commission`]).
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
use uss_protocol::{ParamRef, Storage, Value};
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
        raised_text(self.raised)
    }
}

/// A raise of the access level as every front-end shows it: "P0003 1 -> 3 -> 1".
fn raised_text(raised: Option<(ParamRef, u16, u16)>) -> Option<String> {
    raised.map(|(p, to, was)| format!("{p} {was} -> {to} -> {was}"))
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
    /// What ussd read of the drive again after the reset.
    pub picture: Picture,
}

/// How long the end of quick commissioning may take before the drive says it is done (a
/// MICROMASTER 4 calculates its motor model in seconds; it shows "busy" meanwhile).
pub const QUICK_WAIT: Duration = Duration::from_secs(60);

/// What ussd read of a drive again after a write that may have changed every setting (a
/// factory reset, the end of quick commissioning).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Picture {
    /// The reference frequency ussd scales Hz by now; none when ussd did not have it within
    /// the drive's [`crate::DriveWatch::reference_wait`].
    pub reference_hz: Option<f32>,
    /// The drive's telegram monitoring as ussd read it, and its time in ms.
    pub monitoring: Monitoring,
    pub monitoring_ms: u32,
}

/// What a quick commissioning did, and what ussd read of the drive after it.
#[derive(Debug, Clone, PartialEq)]
pub struct Commissioned {
    /// The commissioning parameter set to 1 for it, and back to 0 by the drive (P0010).
    pub commissioning: ParamRef,
    /// The end of quick commissioning and the value written (P3900, 3).
    pub end: (ParamRef, u16),
    /// The motor data written, each as the drive holds it now ("400 V").
    pub written: Vec<(ParamRef, String)>,
    /// The access level raised for it and put back in RAM: (its parameter, raised to, put
    /// back to).
    pub raised: Option<(ParamRef, u16, u16)>,
    /// From the first write until the drive said it was done.
    pub took: Duration,
    /// What ussd read of the drive again after it.
    pub picture: Picture,
}

impl Commissioned {
    /// The raise as every front-end shows it: "P0003 1 -> 3 -> 1"; none when none was needed.
    pub fn raised_text(&self) -> Option<String> {
        raised_text(self.raised)
    }

    /// The writes in order, as every front-end shows them: "P0010 := 1", "P0304 := 400 V",
    /// ..., "P3900 := 3".
    pub fn writes(&self) -> Vec<String> {
        let mut writes = vec![format!("{} := 1", self.commissioning)];
        writes.extend(self.written.iter().map(|(p, v)| format!("{p} := {v}")));
        writes.push(format!("{} := {}", self.end.0, self.end.1));
        writes
    }
}

impl Reset {
    /// The writes in order, as every front-end shows them: "P0010 := 30", "P0970 := 1".
    pub fn writes(&self) -> Vec<String> {
        let (commissioning, setting) = self.unlocked_by;
        vec![
            format!("{commissioning} := {setting}"),
            format!("{} := 1", self.param),
        ]
    }
}

/// A put-back of the drive's own value after a commissioning call: whoever took control
/// meanwhile (forced), and as unsafe (putting back P0010 = 30 is a guarded value of its own;
/// ussd logs it).
const fn forced() -> WriteOptions {
    WriteOptions {
        eeprom: false,
        force: true,
        unsafe_write: true,
    }
}

/// `e`, the error a commissioning call ends with, and whether its clean-up (`param` put back to
/// `was`) went through: `e` itself when it did, else an error that says both, so that a drive
/// left in quick commissioning or at a raised level is never unsaid.
fn and_cleanup(
    e: ParamError,
    back: Result<Value, ParamError>,
    param: ParamRef,
    was: u16,
) -> ParamError {
    match back {
        Ok(_) => e,
        Err(b) => ParamError::Value {
            param: param.to_string(),
            problem: format!(
                "{e}; and it was not surely put back to {was} ({b}): read it, and write {was}"
            ),
        },
    }
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
        // A copy stores the raised level too: put back by ussd, should this process die
        // after it, in EEPROM as well where the family has the task (a G120 has none).
        let back_to = if catalogue.eeprom_tasks {
            Storage::RamAndEeprom
        } else {
            Storage::Ram
        };
        let raise = self.raise_for(
            address,
            catalogue,
            [save],
            (WriteOptions::default(), back_to),
        )?;
        let saved = self.copy_ram_to_rom(address, save);
        if saved.is_err() {
            // A copy whose answer was lost may still be storing: let it end (bounded) before
            // the level is put back, or the copy would store the raised level after it.
            let _ = self.wait_zero(address, &[save], SAVE_WAIT);
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
    /// monitoring, `crate::DriveWatch::reference_wait`). The reset takes the command source,
    /// the COM link and the monitoring back to their defaults: it is done only when asked as
    /// unsafe (`options.unsafe_write`; ussd logs the writes), and `options.force` does it while
    /// another process controls the drive. Only RAM and what the drive itself stores are
    /// changed: nothing of it is copied to ROM here (`options.eeprom` is not used).
    ///
    /// # Errors
    /// [`ParamError::Guarded`] without `unsafe_write` (nothing written);
    /// [`ParamError::NotOnFamily`] for a family without a known reset; the drive's or the
    /// path's error otherwise.
    pub fn factory_reset(
        &self,
        address: Address,
        options: WriteOptions,
    ) -> Result<Reset, ParamError> {
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
        if !options.unsafe_write {
            return Err(ParamError::Guarded {
                params: format!("{commissioning} = {setting}, {reset} = 1"),
                why: "a factory reset takes the command source, the COM link and the telegram \
                      monitoring back to their factory values"
                    .to_owned(),
            });
        }
        let deliberate = WriteOptions {
            eeprom: false,
            ..options
        };
        let start = Instant::now();
        let was = self.read_u16(address, commissioning)?;
        // ussd puts the commissioning parameter back should this process die before the
        // reset (which leaves it 0 itself).
        self.write_putting_back(
            address,
            commissioning,
            Value::Word(setting),
            Some((Value::Word(was), Storage::Ram)),
            deliberate,
        )?;
        match self.write_with(address, reset, Value::Word(1), deliberate) {
            // The drive may answer with the reset's own 0, or restart before it answers.
            Ok(_) => {}
            Err(e) if e.may_be_applied() => {}
            Err(e) => {
                // Refused (the drive runs, a level too low): not left in factory-setting mode,
                // where it would not run.
                let back = self.write_with(address, commissioning, Value::Word(was), forced());
                return Err(and_cleanup(e, back, commissioning, was));
            }
        }
        self.wait_zero(address, &[reset], RESET_WAIT)?;
        // The reset left the commissioning parameter at its factory value: written as it
        // reads, so ussd holds no put-back of it for when this process ends.
        let after = self.read_u16(address, commissioning)?;
        self.write_with(address, commissioning, Value::Word(after), forced())?;
        let took = start.elapsed();
        let picture = self.read_again(address)?;
        Ok(Reset {
            unlocked_by: (commissioning, setting),
            param: reset,
            took,
            picture,
        })
    }

    /// Waits until ussd has read drive `address` again after a write that may have changed
    /// every setting (a reset, the end of quick commissioning), and returns what it read. ussd
    /// reads the drive again once the write took effect (and when it comes back, had it
    /// restarted): this waits for diagnostics published after now (a reply of the drive after
    /// then) that show a known reference and monitoring, for at most
    /// [`crate::DriveWatch::reference_wait`].
    fn read_again(&self, address: Address) -> Result<Picture, ParamError> {
        let done_ns = crate::monotonic_ns();
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
                return Ok(Picture {
                    reference_hz: reference,
                    monitoring: monitoring.unwrap_or(Monitoring::Unknown),
                    monitoring_ms: read.map_or(0, |d| d.monitoring_ms),
                });
            }
            std::thread::sleep(SAVE_POLL);
        }
    }

    /// Quick commissioning as the drive's manual gives it (MICROMASTER 4: P0010 = 1, the motor
    /// data, then P3900; MICROMASTER 440 Parameter List 6SE6400-5BB00-0BP0, P3900): raises the
    /// access level where a value written needs it, sets the commissioning parameter to 1,
    /// writes `motor` in the order given (text in the parameter's own type and unit, checked
    /// as [`Bus::write_param`] checks it), then writes `end` to the end of quick commissioning
    /// (3: calculate the motor model only; 2: and put the I/O back to factory values; 1: and
    /// every setting outside quick commissioning, the command source, the COM link and the
    /// telegram monitoring included), waits until the drive says it is done (the commissioning
    /// parameter and the end read 0 again, within [`QUICK_WAIT`]), puts the access level back
    /// in RAM, and waits until ussd has read the drive's reference and monitoring again.
    ///
    /// The end of quick commissioning is a guarded write: the call is made only when asked as
    /// unsafe (`options.unsafe_write`; ussd logs that write). The motor data are written as any
    /// write is, so a guarded parameter among them (the command source, the telegram
    /// monitoring off) is refused by ussd: write it on its own, deliberately. `options.force`
    /// writes while another process controls the drive. Nothing is copied to ROM here
    /// ([`Bus::save_to_rom`] does). A write the drive refuses (a value outside its limits,
    /// error 2) ends the call: the drive leaves quick commissioning without a calculation (the
    /// commissioning parameter back to 0), the level is put back, and the error is returned;
    /// values written before stay in RAM. A clean-up that does not go through is said in the
    /// error ([`ParamError::Value`], naming what to write).
    ///
    /// # Errors
    /// [`ParamError::Guarded`] without `unsafe_write`, [`ParamError::Value`] for an `end`
    /// outside 1..=3 (nothing written in both); [`ParamError::NotOnFamily`] for a family
    /// without a known quick commissioning; the drive's or the path's error otherwise.
    pub fn quick_commission(
        &self,
        address: Address,
        motor: &[(ParamRef, &str)],
        end: u16,
        options: WriteOptions,
    ) -> Result<Commissioned, ParamError> {
        let family = self.family(address);
        let catalogue = Catalogue::of(family);
        let known =
            catalogue.and_then(|c| Some((whole(c.quick_commissioning?), whole(c.commissioning?))));
        let (Some(catalogue), Some((quick, commissioning))) = (catalogue, known) else {
            return Err(ParamError::NotOnFamily {
                address: address.get(),
                family: family.name(),
                what: "uss-rt knows no quick commissioning for this family",
            });
        };
        if !(1..=3).contains(&end) {
            return Err(ParamError::Value {
                param: quick.to_string(),
                problem: format!(
                    "{end}: the end of quick commissioning is 1 (and factory values for every \
                     other setting), 2 (and for the I/O) or 3 (the motor model only); nothing \
                     was written"
                ),
            });
        }
        if !options.unsafe_write {
            return Err(ParamError::Guarded {
                params: format!("{quick} = {end}"),
                why: "the end of quick commissioning recalculates the motor model (1: and puts \
                      every other setting, the command source and the COM link included, back \
                      to its factory value)"
                    .to_owned(),
            });
        }
        // The motor data and the commissioning parameter as any write of them: a guarded one
        // among them (the command source, ...) is refused by ussd, not slipped in.
        let plain = WriteOptions {
            eeprom: false,
            unsafe_write: false,
            ..options
        };
        let deliberate = WriteOptions {
            eeprom: false,
            ..options
        };
        let start = Instant::now();
        let params = motor.iter().map(|(p, _)| *p).chain([quick, commissioning]);
        let raise = self.raise_for(address, catalogue, params, (plain, Storage::Ram))?;
        let put_back_level = |e: Option<ParamError>| -> Result<(), ParamError> {
            let Some((level, to, was)) = raise else {
                return e.map_or(Ok(()), Err);
            };
            let back = self.write_with(address, level, Value::Word(was), forced());
            match (e, back) {
                (None, Ok(_)) => Ok(()),
                (Some(e), back) => Err(and_cleanup(e, back, level, was)),
                (None, Err(b)) => Err(ParamError::Value {
                    param: level.to_string(),
                    problem: format!(
                        "raised to {to} for quick commissioning and not surely put back to \
                         {was} ({b}): read it, and write {was}"
                    ),
                }),
            }
        };
        let mut written = Vec::with_capacity(motor.len());
        let steps =
            self.enter_quick_commissioning(address, commissioning, motor, plain, &mut written);
        // Out of quick commissioning without a calculation where a write failed.
        let leave = |e: ParamError| {
            let back = self.write_with(address, commissioning, Value::Word(0), forced());
            and_cleanup(e, back, commissioning, 0)
        };
        let ended = steps.map_err(leave).and_then(|()| {
            match self.write_with(address, quick, Value::Word(end), deliberate) {
                Ok(_) => Ok(()),
                // The drive may be calculating: it is asked below whether it is done.
                Err(e) if e.may_be_applied() => Ok(()),
                Err(e) => Err(leave(e)),
            }
            .and_then(|()| self.wait_zero(address, &[quick, commissioning], QUICK_WAIT))
            // The drive left quick commissioning itself: written as it reads, so ussd holds
            // no put-back of it for when this process ends.
            .and_then(|()| {
                self.write_with(address, commissioning, Value::Word(0), forced())
                    .map(|_| ())
            })
        });
        put_back_level(ended.err())?;
        let took = start.elapsed();
        let picture = self.read_again(address)?;
        Ok(Commissioned {
            commissioning,
            end: (quick, end),
            written,
            raised: raise,
            took,
            picture,
        })
    }

    /// Enters quick commissioning (`commissioning` := 1; ussd takes the drive out of it again
    /// should this process die in it) and writes `motor` in order, each written value noted in
    /// `written`.
    fn enter_quick_commissioning(
        &self,
        address: Address,
        commissioning: ParamRef,
        motor: &[(ParamRef, &str)],
        options: WriteOptions,
        written: &mut Vec<(ParamRef, String)>,
    ) -> Result<(), ParamError> {
        self.write_putting_back(
            address,
            commissioning,
            Value::Word(1),
            Some((Value::Word(0), Storage::Ram)),
            options,
        )?;
        for (param, text) in motor {
            let now = self.write_param(address, *param, text, options)?;
            written.push((now.param, now.shown()));
        }
        Ok(())
    }

    /// Raises the access level of drive `address` (its family's P0003) to the highest that
    /// `params` need by `catalogue`, where the drive's is lower, writing it with `options`:
    /// (the level's parameter, raised to, was), to be put back; none when no raise was needed.
    /// ussd holds the put-back, in RAM or, where the raised level may reach the EEPROM (a copy
    /// of RAM to ROM), in RAM and EEPROM (`back_to`), should this process die first.
    fn raise_for(
        &self,
        address: Address,
        catalogue: &Catalogue,
        params: impl IntoIterator<Item = ParamRef>,
        (options, back_to): (WriteOptions, Storage),
    ) -> Result<Option<(ParamRef, u16, u16)>, ParamError> {
        let needed = params
            .into_iter()
            .filter_map(|p| catalogue.param(p.pnu.get()).map(|p| u16::from(p.level)))
            .max();
        let (Some(level), Some(needed)) = (catalogue.access_level.map(whole), needed) else {
            return Ok(None);
        };
        let now = self.read_u16(address, level)?;
        if needed <= now {
            return Ok(None);
        }
        // ussd puts it back should this process die before it does.
        let raised = self.write_putting_back(
            address,
            level,
            Value::Word(needed),
            Some((Value::Word(now), back_to)),
            options,
        );
        if let Err(e) = raised {
            // Its answer lost, the drive may hold the raised level: put back, said if not.
            if e.may_be_applied() {
                let back = self.write_with(address, level, Value::Word(now), forced());
                return Err(and_cleanup(e, back, level, now));
            }
            return Err(e);
        }
        Ok(Some((level, needed, now)))
    }

    /// Waits (up to `wait`) until every parameter of `params` reads 0: the drive is done.
    fn wait_zero(
        &self,
        address: Address,
        params: &[ParamRef],
        wait: Duration,
    ) -> Result<(), ParamError> {
        let until = Instant::now() + wait;
        for &param in params {
            loop {
                match self.read_u16(address, param) {
                    Ok(0) => break,
                    Ok(_) | Err(_) if Instant::now() < until => std::thread::sleep(SAVE_POLL),
                    Ok(v) => {
                        return Err(ParamError::Value {
                            param: param.to_string(),
                            problem: format!(
                                "still {v} after {} s: the drive has not finished",
                                wait.as_secs()
                            ),
                        });
                    }
                    Err(e) => return Err(e),
                }
            }
        }
        Ok(())
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
