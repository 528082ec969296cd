//! `uss-idle-connections PATH N`: holds N connections to the Unix stream socket PATH that never
//! say anything, each made again as soon as the other side closes it, until killed: what a
//! careless or hostile process of the access group can do to ussd's stop socket
//! (docs/SAFETY.md, STOP-ANYWHERE; `tests/tests/failsafe.rs`, `benches/benches/safety.rs`).
//! Prints `holding N` once every connection was made once.
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
        .expect("usage: uss-idle-connections PATH N")
        .clone();
    let n: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(8);
    let made = Arc::new(AtomicUsize::new(0));
    for _ in 0..n {
        let (path, made) = (path.clone(), Arc::clone(&made));
        std::thread::spawn(move || {
            let mut first = true;
            loop {
                let Ok(mut s) = UnixStream::connect(&path) else {
                    std::thread::sleep(Duration::from_millis(5));
                    continue;
                };
                if first {
                    made.fetch_add(1, Ordering::SeqCst);
                    first = false;
                }
                // Says nothing; reads until the other side closes.
                let mut sink = [0u8; 64];
                while matches!(s.read(&mut sink), Ok(k) if k > 0) {}
            }
        });
    }
    while made.load(Ordering::SeqCst) < n {
        std::thread::sleep(Duration::from_millis(1));
    }
    println!("holding {n}");
    loop {
        std::thread::sleep(Duration::from_secs(3600));
    }
}
