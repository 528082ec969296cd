//! The simulated drive's side of the PKW handshake (USS.md section 6): a task is taken when
//! its words change, answered "not yet" while it is busy (an EEPROM write takes a few
//! telegrams), then answered for as long as the master repeats it.

use super::{Drive, GENERIC_PARAMS, Personality};
use crate::params::DriveContext;
use uss_protocol::pkw::{ErrorNumber, ParamReply, ParamTask, PkwError, Pnu, ReplyKind, Value};
use uss_protocol::telegram::MAX_PKW_WORDS;

impl Drive {
    pub(super) fn handle_pkw(&mut self, request: &[u16], out: &mut [u16; MAX_PKW_WORDS]) -> usize {
        let same =
            self.pkw.request_len == request.len() && self.pkw.request[..request.len()] == *request;
        if !same {
            self.start_task(request);
        }
        let layout = self.config.layout;
        if self.pkw.busy_left > 0 {
            self.pkw.busy_left -= 1;
            out.copy_from_slice(&self.pkw.busy_reply);
            return if layout.pkw == uss_protocol::PkwMode::Variable {
                3
            } else {
                layout.pkw.request_words()
            };
        }
        out.copy_from_slice(&self.pkw.reply);
        self.pkw.reply_len
    }

    /// Executes a new task once; repeats of it get the stored reply (USS.md section 6).
    pub(super) fn start_task(&mut self, request: &[u16]) {
        self.pkw.request[..request.len()].copy_from_slice(request);
        self.pkw.request_len = request.len();
        let (task, kind) = match ParamTask::decode(request) {
            Ok(task) if task != ParamTask::None => match self.config.personality {
                Personality::Drive(_) => {
                    let ctx = DriveContext {
                        running: self.state.is_running(),
                    };
                    (
                        Some(task),
                        self.params.execute(&task, self.config.layout.pkw, ctx),
                    )
                }
                Personality::Generic { fragile } => {
                    let kind = self.generic_task(&task);
                    if fragile && kind == ReplyKind::Error(ErrorNumber::IllegalPnu) {
                        self.dead = true;
                    }
                    (Some(task), kind)
                }
            },
            Ok(task) => (Some(task), ReplyKind::NotYet),
            Err(e) => (None, ReplyKind::Error(self.decode_error(e))),
        };
        let reply = match task {
            Some(ParamTask::None) => ParamReply::NOT_YET,
            Some(t) => ParamReply {
                pnu: t.pnu().unwrap_or(Pnu::from_u16(0)),
                subindex: t.subindex(),
                kind,
            },
            // Undecodable: its PNU and index as the request words carry them.
            None => ParamReply {
                pnu: Pnu::from_parts(request[0] & 0x07FF, (request[1] >> 8) as u8)
                    .unwrap_or(Pnu::from_u16(0)),
                subindex: (request[1] & 0xFF) as u8,
                kind,
            },
        };
        let mode = self.config.layout.pkw;
        let mut words = [0u16; MAX_PKW_WORDS];
        let undecodable = task.is_none();
        self.pkw.reply_len = reply.encode(mode, &mut words).unwrap_or_else(|_| {
            let narrow = ParamReply {
                kind: ReplyKind::Error(ErrorNumber::ChannelTooNarrow),
                ..reply
            };
            narrow.encode(mode, &mut words).unwrap_or(0)
        });
        if undecodable {
            // A task that names no parameter (a PNU field of 2000..2047 without the page bit)
            // is refused with its PNU bits as they came, as every reply echoes them.
            words[0] = (words[0] & 0xF800) | (request[0] & 0x07FF);
            words[1] = (words[1] & 0x00FF) | (request[1] & 0xFF00);
        }
        self.pkw.reply = words;
        self.pkw.busy_left = match task {
            Some(ParamTask::None) | None => 0,
            Some(t) if t.is_write() && is_eeprom(&t) => self.config.eeprom_busy_telegrams,
            Some(_) => self.config.task_busy_telegrams,
        };
        if self.pkw.busy_left > 0 {
            let busy = ParamReply {
                kind: ReplyKind::NotYet,
                ..reply
            };
            let mut busy_words = [0u16; MAX_PKW_WORDS];
            // A "not yet" reply is a word reply: it fits every mode with a channel.
            let _ = busy.encode(mode, &mut busy_words);
            self.pkw.busy_reply = busy_words;
        }
    }

    /// A generic slave's answer: a value of [`GENERIC_PARAMS`] read or changed, error 0 to
    /// anything else (another parameter, a description, an array).
    pub(super) fn generic_task(&mut self, task: &ParamTask) -> ReplyKind {
        let reply = |v: Value| match v {
            Value::Word(w) => ReplyKind::Word(w),
            Value::Dword(d) => ReplyKind::Dword(d),
        };
        let slot = |pnu: Pnu| {
            GENERIC_PARAMS
                .iter()
                .position(|p| Pnu::from_u16(p.0) == pnu)
        };
        match *task {
            ParamTask::Read { pnu } => match slot(pnu) {
                Some(i) => reply(self.generic[i]),
                None => ReplyKind::Error(ErrorNumber::IllegalPnu),
            },
            ParamTask::Write { pnu, value, .. } => match slot(pnu) {
                Some(i) if !GENERIC_PARAMS[i].2 => {
                    ReplyKind::Error(ErrorNumber::ValueNotChangeable)
                }
                Some(i)
                    if core::mem::discriminant(&value)
                        == core::mem::discriminant(&self.generic[i]) =>
                {
                    self.generic[i] = value;
                    reply(value)
                }
                Some(_) => ReplyKind::Error(ErrorNumber::WrongDataType),
                None => ReplyKind::Error(ErrorNumber::IllegalPnu),
            },
            _ => ReplyKind::Error(ErrorNumber::IllegalPnu),
        }
    }

    /// Whether a fragile generic slave stopped answering.
    pub const fn is_dead(&self) -> bool {
        self.dead
    }

    pub(super) fn decode_error(&self, e: PkwError) -> ErrorNumber {
        match e {
            PkwError::DwordOverThreeWords => self.config.dword_over_three_words,
            PkwError::Subindex(_) => ErrorNumber::FaultySubindex,
            PkwError::PnuPart(_) => ErrorNumber::IllegalPnu,
            PkwError::UnsupportedTask(_) | PkwError::NoChannel | PkwError::Words(_) => {
                ErrorNumber::TaskNotImplemented
            }
        }
    }
}

fn is_eeprom(task: &ParamTask) -> bool {
    matches!(
        task,
        ParamTask::Write {
            storage: uss_protocol::Storage::RamAndEeprom,
            ..
        } | ParamTask::WriteArray {
            storage: uss_protocol::Storage::RamAndEeprom,
            ..
        }
    )
}
