//! [`Bus`]: one bus run by ussd, opened by name.

use crate::link::{Health, Link, Services};
use crate::open::Ipc;
use crate::{ClientError, ControlOptions, Controller, CycleListener, DriveWatch};
use core::time::Duration;
use iceoryx2::prelude::{CallbackProgression, NodeBuilder, NodeName, SignalHandlingMode};
use std::sync::Arc;
use uss_shm_types::{Address, BlackboardKey, BusName, BusStatus, DriveDiag};

/// The node name [`Bus::open`] uses, as `Node::list` (and a refused controller's error) shows it.
pub const DEFAULT_NODE_NAME: &str = "uss-client";

/// One bus run by ussd. Opening it waits for ussd's heartbeat; everything else (drive images,
/// control, parameters, events) is opened on first use.
///
/// **ussd's health.** Every call looks at ussd's heartbeat (at most every millisecond): when
/// ussd died or hangs (no heartbeat for 0.5 s), stopped, or its bus line is down, images show
/// the drives offline and calls that need a polling bus fail with [`ClientError::UssdGone`],
/// [`ClientError::UssdStopped`] or [`ClientError::LineDown`]. [`Bus::health`] says which. When a
/// ussd serves the bus again (a restart), everything opened from this `Bus` reconnects by
/// itself: watches resume; controllers find their drive latched by the new ussd and must
/// re-arm it (see [`Controller`]).
///
/// A `Bus` is `Send` and `Sync`. Its iceoryx2 node handles no signals: the application owns
/// SIGINT and SIGTERM. Run clients as the same user (or group) as ussd: iceoryx2 keeps its
/// state below one root directory (`uss_shm_types::service`, `/dev/shm/uss-rt`), which ussd's
/// `access_group` opens to a group.
pub struct Bus {
    link: Arc<Link>,
    answer_timeout: Option<Duration>,
    /// Data types the drives described (AK 4) for parameters the catalogue does not know,
    /// shared with the views of [`Bus::with_answer_timeout`].
    pub(crate) described: Arc<crate::typed::Described>,
    /// When this handle last sent each drive a stop ([`Bus::wait_stopped`]).
    pub(crate) stops_sent: Arc<crate::command::StopsSent>,
}

impl core::fmt::Debug for Bus {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Bus")
            .field("name", &self.name())
            .field("node", &self.link.node.name().as_str())
            .finish_non_exhaustive()
    }
}

impl Bus {
    /// Opens bus `name` (e.g. `bus0`) under the node name [`DEFAULT_NODE_NAME`].
    pub fn open(name: &str) -> Result<Bus, ClientError> {
        Self::open_as(name, DEFAULT_NODE_NAME)
    }

    /// Opens bus `name` under the node name `node_name` (shown by `Node::list` and in the
    /// error another process gets when it tries to take a drive this one controls). Fails
    /// with [`ClientError::NotRunning`] when no ussd serves the bus.
    pub fn open_as(name: &str, node_name: &str) -> Result<Bus, ClientError> {
        let name = BusName::new(name)?;
        let node_name =
            NodeName::new(node_name).map_err(|e| ClientError::ipc("the node name", e))?;
        let config = crate::open::iceoryx_config(name.as_str())?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .config(&config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Ipc>()
            .map_err(|e| ClientError::ipc("creating the iceoryx2 node", e))?;
        Ok(Bus {
            described: Arc::default(),
            stops_sent: Arc::default(),
            link: Arc::new(Link::open(name, node)?),
            answer_timeout: None,
        })
    }

    /// The bus name.
    pub fn name(&self) -> &str {
        self.link.name.as_str()
    }

    pub(crate) fn link(&self) -> &Arc<Link> {
        &self.link
    }

    /// What ussd's heartbeat says now: running, line down, stopped or gone.
    pub fn health(&self) -> Health {
        self.link.health()
    }

    /// How long a parameter request may take before [`crate::ParamError::NoAnswer`]; `None`
    /// (the default) allows 5 s plus 2.5 s per item (ussd's default parameter timeout is 2 s
    /// per item).
    pub fn set_answer_timeout(&mut self, timeout: Option<Duration>) {
        self.answer_timeout = timeout;
    }

    /// This bus with another answer timeout for parameter requests ([`Bus::set_answer_timeout`]):
    /// the same connection and everything it knows, for calls that wait longer or shorter
    /// than the others (a client library's per-call timeout).
    #[must_use]
    pub fn with_answer_timeout(&self, timeout: Option<Duration>) -> Bus {
        Bus {
            link: Arc::clone(&self.link),
            answer_timeout: timeout,
            described: Arc::clone(&self.described),
            stops_sent: Arc::clone(&self.stops_sent),
        }
    }

    pub(crate) fn answer_timeout(&self, items: usize) -> Duration {
        self.answer_timeout
            .unwrap_or_else(|| Duration::from_secs(5) + Duration::from_millis(2500) * items as u32)
    }

    /// The services of the ussd serving the bus now, or why there are none.
    pub(crate) fn services(&self) -> Result<Arc<Services>, ClientError> {
        self.link.services()
    }

    /// The bus status, as ussd last published it (every 50 ms; its line fields say whether
    /// the line is down). Fails when ussd is gone or stopped.
    pub fn status(&self) -> Result<BusStatus, ClientError> {
        let (health, services) = self.link.current();
        match (health, services) {
            (Health::Running { .. } | Health::LineDown { .. }, Some(s)) => Ok(s.status()),
            (health, _) => Err(health
                .error(self.name())
                .unwrap_or_else(|| ClientError::not_running(self.name().to_owned()))),
        }
    }

    /// The addresses of the drives ussd polls on this bus, ascending (none while no ussd
    /// serves it).
    pub fn drives(&self) -> Vec<Address> {
        let Ok(services) = self.services() else {
            return Vec::new();
        };
        let mut keys = Vec::new();
        services.diag_service.list_keys(|k| {
            if let Some(a) = u8::try_from(k.value)
                .ok()
                .and_then(|a| Address::new(a).ok())
            {
                keys.push(a);
            }
            CallbackProgression::Continue
        });
        keys.sort_unstable();
        keys
    }

    /// A drive's diagnostics, as ussd last published them (every 50 ms). Fails when ussd is
    /// gone or stopped.
    pub fn diag(&self, address: Address) -> Result<DriveDiag, ClientError> {
        // A drive ussd does not serve has no entry: one look answers both.
        let services = self.services()?;
        let entry = services
            .diag
            .entry::<DriveDiag>(&BlackboardKey::drive(address))
            .map_err(|_| self.unknown_drive(address))?;
        Ok(*entry.get())
    }

    /// Watches a drive's input image (written by ussd after every poll).
    pub fn watch(&self, address: Address) -> Result<DriveWatch, ClientError> {
        DriveWatch::open(self, address)
    }

    /// A subscription to every telegram of the bus, as ussd's bus thread sent and received it.
    pub fn capture(&self) -> Result<crate::Capture, ClientError> {
        crate::Capture::open(self)
    }

    /// A listener for the bus's exchange and cycle events, to run in step with the bus.
    pub fn cycle_listener(&self) -> Result<CycleListener, ClientError> {
        CycleListener::open(self)
    }

    /// Takes exclusive control of a drive. Fails with [`ClientError::Controlled`] ("drive 5 on
    /// bus0 is controlled by process 1234") while another controller holds it. See
    /// [`Controller`] for the watchdog and latch rules.
    pub fn control(
        &self,
        address: Address,
        options: ControlOptions,
    ) -> Result<Controller, ClientError> {
        Controller::open(self, address, options)
    }

    pub(crate) fn unknown_drive(&self, address: Address) -> ClientError {
        ClientError::UnknownDrive {
            bus: self.name().to_owned(),
            address: address.get(),
            known: self.drives().into_iter().map(Address::get).collect(),
        }
    }
}
