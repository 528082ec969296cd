//! `uss-idle-connections PATH N`: holds N connections to the Unix stream socket PATH that never
//! say anything, each made again as soon as the other side closes it, until killed: what a
//! careless or hostile process of the access group can do to ussd's stop socket
//! (docs/SAFETY.md, STOP-ANYWHERE; `tests/tests/failsafe.rs`, `benches/benches/safety.rs`).
//! Prints `holding N` once every connection was made once.
//!
//! `uss-idle-connections PATH N --processes`: the same connections from N forked processes, one
//! each (issue 45's adversarial run: 400 to 1000 such processes never reach a per-process
//! bound). Killing this process ends them too (each has SIGKILL as its parent-death signal).
#![allow(clippy::unwrap_used)]

use std::io::Read as _;
use std::os::unix::net::UnixStream;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = args
        .get(1)
        .expect("usage: uss-idle-connections PATH N [--processes]")
        .clone();
    let n: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(8);
    if args.get(3).map(String::as_str) == Some("--processes") {
        processes(&path, n);
    } else {
        threads(&path, n);
    }
    println!("holding {n}");
    loop {
        std::thread::sleep(Duration::from_secs(3600));
    }
}

/// One connection that says nothing, made again whenever the other side closes it, for ever;
/// `made` is called once, when it was first made.
fn hold(path: &str, made: impl FnOnce()) -> ! {
    let mut made = Some(made);
    loop {
        let Ok(mut s) = UnixStream::connect(path) else {
            std::thread::sleep(Duration::from_millis(5));
            continue;
        };
        if let Some(made) = made.take() {
            made();
        }
        // Says nothing; reads until the other side closes.
        let mut sink = [0u8; 64];
        while matches!(s.read(&mut sink), Ok(k) if k > 0) {}
    }
}

/// N threads of this process, one connection each; returns once each was made once.
fn threads(path: &str, n: usize) {
    let made = Arc::new(AtomicUsize::new(0));
    for _ in 0..n {
        let (path, made) = (path.to_owned(), Arc::clone(&made));
        std::thread::spawn(move || hold(&path, || _ = made.fetch_add(1, Ordering::SeqCst)));
    }
    while made.load(Ordering::SeqCst) < n {
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// N forked processes, one connection each; returns once each was made once.
fn processes(path: &str, n: usize) {
    let (ready_rx, ready_tx) = nix::unistd::pipe().unwrap();
    let parent = nix::unistd::getpid();
    for _ in 0..n {
        // SAFETY: this process has one thread here (it has spawned none), so the child may run
        // anything after fork.
        if let nix::unistd::ForkResult::Child = unsafe { nix::unistd::fork() }.unwrap() {
            nix::sys::prctl::set_pdeathsig(nix::sys::signal::Signal::SIGKILL).unwrap();
            if nix::unistd::getppid() != parent {
                std::process::exit(0);
            }
            hold(path, || _ = nix::unistd::write(&ready_tx, b"x").unwrap());
        }
    }
    drop(ready_tx);
    let mut got = vec![0u8; n];
    std::fs::File::from(ready_rx).read_exact(&mut got).unwrap();
}
