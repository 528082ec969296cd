//! `uss-stop-flood PATH`: connects to the Unix stream socket PATH and closes at once, in a tight
//! loop, until killed: a storm of connections from a process of the access group (issue 45:
//! one such process delayed another's stop by 98 to 333 ms, forty by up to 2.45 s). Prints
//! `flooding` once its first connection was made. (Idle connections that are held:
//! `uss-idle-connections`.)
#![allow(clippy::unwrap_used)]

use std::io::Write as _;
use std::os::unix::net::UnixStream;

fn main() {
    let path = std::env::args().nth(1).expect("usage: uss-stop-flood PATH");
    let mut said = false;
    loop {
        if UnixStream::connect(&path).is_ok() && !said {
            println!("flooding");
            std::io::stdout().flush().unwrap();
            said = true;
        }
    }
}
