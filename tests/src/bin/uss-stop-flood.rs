//! `uss-stop-flood PATH`: connects to the Unix stream socket PATH and closes at once, in a tight
//! loop, until killed: a storm of connections from a process of the access group (issue 45:
//! one such process delayed another's stop by 98 to 333 ms, forty by up to 2.45 s). Prints
//! `flooding` once its first connection was made.
//!
//! `uss-stop-flood PATH --idle N`: forks N processes that each hold one connection that says
//! nothing, made again as soon as the other side closes it (issue 45's adversarial run: 400 to
//! 1000 such processes, one connection each, never reach a per-process bound). Prints
//! `holding N` once every one connected once; killing this process ends them too (each child
//! has SIGKILL as its parent-death signal).
#![allow(clippy::unwrap_used)]

use std::io::{Read as _, Write as _};
use std::os::unix::net::UnixStream;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = args
        .get(1)
        .expect("usage: uss-stop-flood PATH [--idle N]")
        .clone();
    if args.get(2).map(String::as_str) == Some("--idle") {
        let n: usize = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(100);
        return idle(&path, n);
    }
    let mut said = false;
    loop {
        if UnixStream::connect(&path).is_ok() && !said {
            println!("flooding");
            std::io::stdout().flush().unwrap();
            said = true;
        }
    }
}

/// N children, one idle connection each; this process waits for their first connections.
fn idle(path: &str, n: usize) {
    let (ready_rx, ready_tx) = nix::unistd::pipe().unwrap();
    let parent = nix::unistd::getpid();
    for _ in 0..n {
        // SAFETY: this process has one thread here (it spawns none), so the child may run
        // anything after fork.
        match unsafe { nix::unistd::fork() }.unwrap() {
            nix::unistd::ForkResult::Child => {
                // Ends with its parent (the test kills it).
                nix::sys::prctl::set_pdeathsig(nix::sys::signal::Signal::SIGKILL).unwrap();
                if nix::unistd::getppid() != parent {
                    std::process::exit(0);
                }
                let mut first = true;
                loop {
                    let Ok(mut s) = UnixStream::connect(path) else {
                        std::thread::sleep(std::time::Duration::from_millis(5));
                        continue;
                    };
                    if first {
                        nix::unistd::write(&ready_tx, b"x").unwrap();
                        first = false;
                    }
                    let mut sink = [0u8; 16];
                    while matches!(s.read(&mut sink), Ok(k) if k > 0) {}
                }
            }
            nix::unistd::ForkResult::Parent { .. } => {}
        }
    }
    drop(ready_tx);
    let mut ready = std::fs::File::from(ready_rx);
    let mut got = vec![0u8; n];
    ready.read_exact(&mut got).unwrap();
    println!("holding {n}");
    std::io::stdout().flush().unwrap();
    loop {
        std::thread::sleep(std::time::Duration::from_secs(3600));
    }
}
