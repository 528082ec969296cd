//! What an engine is built from: each drive's setup ([`DriveSetup`]) and the bus's
//! configuration ([`EngineConfig`]).

use crate::monitoring::{MonitoringSetup, WatchedParam};
use crate::{picture, reference};
use core::time::Duration;
use uss_protocol::{Address, Layout, Timing};
use uss_shm_types::StopCommand;

/// One drive as the engine polls it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveSetup {
    pub address: Address,
    pub layout: Layout,
    /// How many times the drive appears in the circulating list (USS.md section 5).
    pub weight: u8,
    /// What a latched drive gets (OFF1 by default), with a zero setpoint.
    pub safe: StopCommand,
    /// A live controller that has published nothing new for this long is stale.
    pub watchdog: Duration,
    pub params_writable: bool,
    /// The drive's own telegram monitoring, checked when it comes online.
    pub monitoring: MonitoringSetup,
    /// The reference frequency P2000 in Hz (0x4000 = 100 %, USS.md section 7) as configured:
    /// the engine does not scale, it publishes it for the clients that do, unless the drive's
    /// own value was read ([`reference::Reference`]).
    pub reference_hz: f32,
    /// The drive's reference parameter (P2000 on MICROMASTER 4 / G110, in Hz; p2000 on a G120
    /// whose pole pairs are configured, in rpm), read when it comes online; `None`: not read.
    pub reference_param: Option<WatchedParam>,
    /// What unit `reference_param` is in, and how it becomes Hz.
    pub reference_unit: reference::ReferenceUnit,
    /// The parameters whose write may change every setting (commissioning, factory reset):
    /// after one, the reference and the monitoring are unknown until read again
    /// ([`picture`]).
    pub rereads_after: picture::Rereads,
    /// The drive takes broadcasts (ADR bit 5): a stop of every drive reaches it in one
    /// broadcast telegram (`engine::turns`). S110 and G120 firmware 4 do not.
    pub broadcast: bool,
    /// What kind of slave it is, published for the clients (which read a generic slave's
    /// parameters by value alone). The engine reads only `monitoring` and `reference_param`
    /// of its own, which the family decides.
    pub family: uss_shm_types::DriveFamily,
}

impl DriveSetup {
    /// A drive with the defaults of ussd's configuration: weight 1, OFF1, 100 ms watchdog,
    /// writable, MICROMASTER telegram monitoring (P2014.0, checked, not required).
    pub fn new(address: Address, layout: Layout) -> Self {
        Self {
            address,
            layout,
            weight: 1,
            safe: StopCommand::Off1,
            watchdog: Duration::from_millis(100),
            params_writable: true,
            monitoring: MonitoringSetup::micromaster(),
            reference_hz: 50.0,
            reference_param: Some(reference::P2000),
            reference_unit: reference::ReferenceUnit::Hz,
            rereads_after: picture::Rereads::MICROMASTER,
            broadcast: true,
            family: uss_shm_types::DriveFamily::Micromaster4,
        }
    }

    /// The reference-frequency parameter ussd reads: only over a PKW channel that carries its
    /// float.
    pub fn reference_read(&self) -> Option<WatchedParam> {
        self.reference_param
            .filter(|_| self.layout.pkw.carries_dword())
    }
}

/// How the engine runs one bus.
#[derive(Debug, Clone, PartialEq)]
// Four independent switches of the configuration (echo, parameter priority, safety first,
// capture), not the states of one machine.
#[allow(clippy::struct_excessive_bools)]
pub struct EngineConfig {
    pub timing: Timing,
    /// Limit for the reply's STX after our BCC (20 ms by USS.md section 4, plus any margin).
    pub response_timeout: Duration,
    pub retries: u8,
    /// Consecutive failed polls before a drive is marked offline.
    pub offline_after: u32,
    /// How often an offline drive is probed.
    pub offline_probe: Duration,
    /// Fixed time per pass through the circulating list, if any.
    pub cycle_time: Option<Duration>,
    /// A parameter job without a matching reply this long after it first went out times out.
    pub param_timeout: Duration,
    /// Discard the echo of our own bytes (2-wire adapters, USS.md section 9).
    pub echo: bool,
    /// Clients' parameter jobs each drive can hold (its mailbox holds [`OWN_READS`] more for
    /// ussd's own reads); a request is taken whole, so a larger one than this is refused. ussd:
    /// 64, above a request's 39 items.
    pub mailbox_depth: usize,
    /// How often statistics are published to other threads.
    pub publish_every: Duration,
    /// A drive with a parameter job waiting gets an extra poll after every poll of the
    /// circulating list, so the job does not wait a whole cycle for its drive's turn; at most one
    /// extra poll follows each regular one, so no other drive's poll period more than doubles.
    pub param_priority: bool,
    /// Safety telegrams jump the queue (`engine::turns`): before every telegram every drive is
    /// looked at, a stop, a trip or a re-arm goes out in the next telegram, a stop of every
    /// drive as a broadcast. Always on in ussd; `false` only measures what it buys (the
    /// `safety` benchmark): then a drive's words are decided at its turn alone.
    pub safety_first: bool,
    /// How late the line's adapter may deliver a received byte (USB latency timer, UART FIFO
    /// trigger): the residual-time and start-pause allowances and the response timeout widen
    /// by exactly this much, and a retry after a timeout first waits it out, so a reply on its
    /// way is not taken for the retry's answer.
    pub rx_latency: Duration,
    /// Copy every telegram into the capture channel ([`EngineHandle::captures`]).
    pub capture: bool,
    pub drives: Vec<DriveSetup>,
}
