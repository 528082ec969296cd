//! The Rust front-end of the safety conformance suite (`tests/tests/conformance.rs`,
//! docs/SAFETY.md): a controller of `uss_client` driven line by line from stdin, so the suite
//! runs the same scenario against every language with real processes and signals.
//!
//! Each line is a command (`open BUS ADDRESS`, `keepalive`, `run HZ`, `rearm [MS]`, ...); a line that
//! starts with `&` runs on a thread of its own (a second thread of the same program). Every
//! command is answered by one line: `<< ok` or `<< err KIND MESSAGE` (`<&` for a thread's),
//! where KIND is the error's name in snake case (`tripped`, `not_armed`, `stalled`, ...), the
//! same word every front-end's driver prints.
#![allow(clippy::unwrap_used)]

use std::io::{BufRead as _, Write as _};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use uss_client::{Address, Bus, ClientError, ControlOptions, Controller, DriveState};

/// The error's variant name in snake case: `NotArmed { .. }` -> `not_armed`.
fn kind(e: &ClientError) -> String {
    let debug = format!("{e:?}");
    let name: String = debug
        .chars()
        .take_while(char::is_ascii_alphanumeric)
        .collect();
    let mut snake = String::new();
    for (i, c) in name.chars().enumerate() {
        if c.is_ascii_uppercase() && i > 0 {
            snake.push('_');
        }
        snake.push(c.to_ascii_lowercase());
    }
    snake
}

fn state(n: &str) -> Result<DriveState, String> {
    Ok(match n {
        "1" => DriveState::SwitchingOnInhibited,
        "2" => DriveState::ReadyToSwitchOn,
        "3" => DriveState::ReadyForOperation,
        "4" => DriveState::OperationEnabled,
        other => return Err(format!("state {other}: 1..4")),
    })
}

/// What one command came to.
fn call(c: &Controller, words: &[&str]) -> Result<(), ClientError> {
    let arg = |i: usize| words.get(i).copied().unwrap_or_default();
    match words.first().copied().unwrap_or_default() {
        "keepalive" => c.keepalive(),
        "enable" => c.enable(),
        "stop" => c.stop(),
        "coast" => c.coast(),
        "quick_stop" => c.quick_stop(),
        // The re-arm is asked for when the line arrives; `rearm MS` makes the call MS later (a
        // program that re-arms once it is set up): a stop meanwhile is not re-armed.
        "rearm" => {
            let asked = uss_client::monotonic_ns();
            std::thread::sleep(Duration::from_millis(arg(1).parse().unwrap_or(0)));
            c.rearm(asked).map(|_| ())
        }
        "check" => c.check().map(|_| ()),
        "run" => c.run_hz(arg(1).parse().unwrap()),
        "acknowledge" => c.acknowledge_fault(Duration::from_millis(arg(1).parse().unwrap())),
        "set_words" => {
            let words: Vec<u16> = words[1..]
                .iter()
                .map(|w| u16::from_str_radix(w.trim_start_matches("0x"), 16).unwrap())
                .collect();
            c.set_words(&words)
        }
        "wait_state" => c
            .wait_for_state(
                state(arg(1)).unwrap(),
                Duration::from_millis(arg(2).parse().unwrap()),
            )
            .map(|_| ()),
        other => panic!("unknown command {other:?}"),
    }
}

fn answer(tag: &str, result: Result<(), ClientError>) {
    let line = match result {
        Ok(()) => format!("{tag} ok"),
        Err(e) => format!("{tag} err {} {e}", kind(&e)),
    };
    let mut out = std::io::stdout().lock();
    writeln!(out, "{line}").unwrap();
    out.flush().unwrap();
}

fn main() {
    let mut bus: Option<Bus> = None;
    let controller: Arc<Mutex<Option<Arc<Controller>>>> = Arc::default();
    let mut threads = Vec::new();
    for line in std::io::stdin().lock().lines() {
        let line = line.unwrap();
        let (tag, text) = match line.strip_prefix('&') {
            Some(rest) => ("<&", rest.trim()),
            None => ("<<", line.trim()),
        };
        let words: Vec<&str> = text.split_whitespace().collect();
        match words.first().copied().unwrap_or_default() {
            "open" => {
                let result = Bus::open(words[1]).and_then(|b| {
                    let address = Address::new(words[2].parse().unwrap())?;
                    let c = b.control(address, ControlOptions::default())?;
                    *controller.lock().unwrap() = Some(Arc::new(c));
                    bus = Some(b);
                    Ok(())
                });
                answer(tag, result);
            }
            "release" => {
                let taken = controller.lock().unwrap().take();
                let result = match taken.map(Arc::try_unwrap) {
                    Some(Ok(c)) => c.release().map(|_| ()),
                    Some(Err(_)) => panic!("release while another thread calls"),
                    None => Ok(()),
                };
                answer(tag, result);
            }
            "exit" => break,
            _ => {
                let c = controller.lock().unwrap().clone().expect("open first");
                let words: Vec<String> = words.iter().map(|w| (*w).to_owned()).collect();
                let work = move || {
                    let words: Vec<&str> = words.iter().map(String::as_str).collect();
                    answer(tag, call(&c, &words));
                };
                if tag == "<&" {
                    threads.push(std::thread::spawn(work));
                } else {
                    work();
                }
            }
        }
    }
    for t in threads {
        t.join().unwrap();
    }
    drop(controller);
    drop(bus);
}
