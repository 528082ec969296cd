//! The demo: a small built-in master polls the simulated drives over the virtual wire in real
//! time, brings them from S1 to running through STW1, sets ramp times through the parameter
//! channel, stops them again, and prints what it sees. `ussd` (the bus-engine work) is the real
//! master; this shows the simulator on its own with no hardware and no second process.

use crate::Failure;
use std::collections::VecDeque;
use std::io::Write as _;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use uss_drive_sim::spec::DriveSpec;
use uss_drive_sim::{SimBus, VirtualWire};
use uss_protocol::exchange::{Exchange, Heard, Silence};
use uss_protocol::telegram::{MAX_PKW_WORDS, MAX_TELEGRAM_BYTES};
use uss_protocol::{
    Address, Adr, DriveState, FramerConfig, Layout, MAX_RESPONSE_DELAY, ParamReply, ParamTask,
    PkwMode, Pnu, ReplyKind, Setpoint, Storage, Stw1, Timing, Value, Words, Zsw1, encode,
};

/// Four drives: PKW 4, variable PKW, PKW 3 with 4 PZD words, and one on a noisy cable.
pub fn default_drives() -> Vec<DriveSpec> {
    ["1", "2:pkw=127", "3:pkw=3,pzd=4", "4:drop=0.02,bcc=0.01"]
        .iter()
        .filter_map(|s| s.parse().ok())
        .collect()
}

struct Station {
    address: Address,
    layout: Layout,
    tasks: VecDeque<ParamTask>,
    zsw1: Zsw1,
    hiw: Setpoint,
    timeouts: u64,
    errors: u64,
}

fn tasks_for(layout: Layout) -> VecDeque<ParamTask> {
    let pnu = Pnu::from_u16;
    let mut tasks = VecDeque::new();
    match layout.pkw {
        PkwMode::None => {}
        PkwMode::Three => {
            tasks.push_back(ParamTask::Read { pnu: pnu(700) });
            tasks.push_back(ParamTask::Read { pnu: pnu(2014) });
        }
        PkwMode::Four | PkwMode::Variable => {
            let seconds = Value::from_f32(2.0);
            for p in [1120, 1121] {
                tasks.push_back(ParamTask::Write {
                    pnu: pnu(p),
                    value: seconds,
                    storage: Storage::Ram,
                });
            }
            tasks.push_back(ParamTask::Read { pnu: pnu(1082) });
            tasks.push_back(ParamTask::Read { pnu: pnu(2000) });
            tasks.push_back(ParamTask::Write {
                pnu: pnu(1080),
                value: Value::from_f32(5.0),
                storage: Storage::RamAndEeprom,
            });
        }
    }
    tasks
}

fn describe(reply: &ParamReply) -> String {
    match reply.kind {
        ReplyKind::Dword(bits) => format!("{} = {}", reply.pnu, f32::from_bits(bits)),
        ReplyKind::Word(w) => format!("{} = {w}", reply.pnu),
        ReplyKind::Error(e) => format!("{}: {e}", reply.pnu),
        other => format!("{}: {other:?}", reply.pnu),
    }
}

/// The demo's master: the virtual wire, its own receive framer, and the line state.
struct Master {
    wire: VirtualWire,
    exchange: Exchange,
    start: Instant,
    buf: [u8; MAX_TELEGRAM_BYTES],
}

impl Master {
    /// One exchange with `st`: send STW1, setpoint and the current PKW task, wait for the reply.
    fn exchange(
        &mut self,
        st: &mut Station,
        stw: Stw1,
        setpoint: Setpoint,
    ) -> Result<Option<Words>, Failure> {
        let mut pkw = [0u16; MAX_PKW_WORDS];
        let pkw_len = match st.tasks.front() {
            Some(task) => task
                .encode(st.layout.pkw, &mut pkw)
                .map_err(|e| Failure::Demo(e.to_string()))?,
            None => st.layout.pkw.request_words(),
        };
        let mut pzd = [0u16; 16];
        pzd[0] = stw.bits();
        pzd[1] = setpoint.word();
        let len = encode(
            &mut self.buf,
            Adr::to(st.address),
            &pkw[..pkw_len],
            &pzd[..st.layout.pzd.get()],
        )
        .map_err(|e| Failure::Demo(e.to_string()))?;
        // Observe the start pause, flush what is left of earlier replies, then send: the
        // exchange's rules are ussd's (`uss_protocol::exchange`), the I/O the virtual wire's.
        let send_at = self.start.elapsed().max(self.exchange.send_at());
        std::thread::sleep(send_at.saturating_sub(self.start.elapsed()));
        self.wire.flush_input(send_at);
        let end = self.wire.transmit(&self.buf[..len], send_at);
        self.exchange.sent(end, MAX_RESPONSE_DELAY);
        loop {
            let deadline = self.exchange.deadline();
            let Some(at) = self.wire.next_arrival().filter(|at| *at <= deadline) else {
                match self.exchange.silence() {
                    Silence::NoReply(None) => st.timeouts += 1,
                    Silence::NoReply(Some(_)) | Silence::Incomplete => st.errors += 1,
                }
                // A reply still on its way is not taken for the next one.
                self.exchange.busy_until(deadline);
                return Ok(None);
            };
            std::thread::sleep(at.saturating_sub(self.start.elapsed()));
            let Some(rx) = self.wire.receive(at) else {
                continue;
            };
            match self.exchange.heard(rx.byte, rx.error, rx.at) {
                Heard::More => {}
                Heard::Telegram { telegram, .. } if telegram.adr().address == st.address => {
                    return Ok(telegram.words(st.layout).ok());
                }
                // Another drive's reply, or a broken one: counted, and the line listened to on.
                Heard::Telegram { .. } | Heard::Broken(_) => st.errors += 1,
            }
        }
    }
}

/// Prints a line of the demo; when nobody reads any more (`uss-sim --demo | head -1`), the demo
/// ends quietly instead of failing on the closed pipe.
macro_rules! say {
    ($($arg:tt)*) => {
        if writeln!(std::io::stdout(), $($arg)*).is_err() {
            return Ok(());
        }
    };
}

pub fn run(
    bus: SimBus,
    timing: Timing,
    duration: Duration,
    stop: &AtomicBool,
) -> Result<(), Failure> {
    let mut stations: Vec<Station> = bus
        .drives()
        .map(|d| Station {
            address: d.address(),
            layout: d.config().layout,
            tasks: tasks_for(d.config().layout),
            zsw1: Zsw1::empty(),
            hiw: Setpoint::default(),
            timeouts: 0,
            errors: 0,
        })
        .collect();
    let mut master = Master {
        wire: VirtualWire::new(bus, timing),
        exchange: Exchange::new(FramerConfig::strict(timing), Duration::ZERO),
        start: Instant::now(),
        buf: [0u8; MAX_TELEGRAM_BYTES],
    };
    let start = master.start;
    let mut next_print = Duration::ZERO;
    let mut exchanges = 0u64;
    say!(
        "demo: {} simulated drives at {} baud on the virtual wire, {:.0} s; start pause {:?}",
        stations.len(),
        timing.baud(),
        duration.as_secs_f64(),
        timing.start_pause()
    );
    while start.elapsed() < duration && !stop.load(Ordering::Relaxed) {
        for (i, st) in stations.iter_mut().enumerate() {
            let t = start.elapsed();
            let stw = if t < Duration::from_secs(1) || t > duration.mul_f64(0.6) {
                Stw1::READY
            } else {
                Stw1::RUN
            };
            let setpoint = Setpoint::from_percent(40.0 + 20.0 * i as f32);
            exchanges += 1;
            let Some(words) = master.exchange(st, stw, setpoint)? else {
                continue;
            };
            st.zsw1 = Zsw1::from_bits_retain(words.pzd().first().copied().unwrap_or(0));
            st.hiw = Setpoint::from_word(words.pzd().get(1).copied().unwrap_or(0));
            if let (Some(task), Ok(r)) = (st.tasks.front(), ParamReply::decode(words.pkw()))
                && r.answers(task)
            {
                say!(
                    "{:6.2} s  drive {}: {}",
                    start.elapsed().as_secs_f64(),
                    st.address,
                    describe(&r)
                );
                st.tasks.pop_front();
            }
        }
        let t = start.elapsed();
        if t >= next_print {
            next_print += Duration::from_secs(1);
            let line: Vec<String> = stations
                .iter()
                .map(|s| {
                    format!(
                        "#{} {} {:5.1} Hz",
                        s.address,
                        DriveState::from_zsw1(s.zsw1).short_name(),
                        s.hiw.hz(50.0)
                    )
                })
                .collect();
            say!("{:6.2} s  {}", t.as_secs_f64(), line.join(" | "));
        }
    }
    let secs = start.elapsed().as_secs_f64();
    say!(
        "demo done: {exchanges} exchanges in {secs:.2} s ({:.0}/s)",
        exchanges as f64 / secs
    );
    for s in &stations {
        let counters = master
            .wire
            .bus()
            .drive(s.address)
            .map(uss_drive_sim::Drive::counters)
            .unwrap_or_default();
        say!(
            "  drive {}: master saw {} timeouts, {} bad replies; drive counted {} good telegrams",
            s.address,
            s.timeouts,
            s.errors,
            counters.good
        );
    }
    Ok(())
}
