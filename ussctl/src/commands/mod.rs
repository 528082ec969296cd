//! One file per subcommand.

pub mod ack;
pub mod backup;
pub mod capture;
pub mod common;
pub mod param;
pub mod run;
pub mod scan;
pub mod status;
pub mod stop;
pub mod top;
pub mod trace;
pub mod watch;
