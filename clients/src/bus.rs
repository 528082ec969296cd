//! [`Bus`]: one bus run by ussd, opened by name.

use crate::open::{Ipc, layout_verifier, opened};
use crate::{ClientError, ControlOptions, Controller, CycleListener, DriveWatch};
use core::time::Duration;
use iceoryx2::port::reader::{EntryHandle, Reader};
use iceoryx2::prelude::{CallbackProgression, Node, NodeBuilder, NodeName, SignalHandlingMode};
use iceoryx2::service::port_factory::blackboard::PortFactory as Blackboard;
use std::sync::OnceLock;
use uss_shm_types::names;
use uss_shm_types::{BlackboardKey, BusName, BusStatus, DriveAddress, DriveDiag};

/// The node name [`Bus::open`] uses, as `Node::list` (and a refused controller's error) shows it.
pub const DEFAULT_NODE_NAME: &str = "uss-client";

pub(crate) type ParamClient = iceoryx2::port::client::Client<
    Ipc,
    uss_shm_types::ParamRequest,
    (),
    uss_shm_types::ParamResponse,
    (),
>;

pub(crate) type CommandClient = iceoryx2::port::client::Client<
    Ipc,
    uss_shm_types::OperatorRequest,
    (),
    uss_shm_types::OperatorResponse,
    (),
>;

/// One bus run by ussd. Opening it checks that ussd runs there; everything else (drive
/// images, control, parameters, events) is opened on first use.
///
/// A `Bus` is `Send` and `Sync`. Its iceoryx2 node handles no signals: the application owns
/// SIGINT and SIGTERM. Run clients as the same user (or group) as ussd: iceoryx2 keeps its
/// state in `/dev/shm` and `/tmp/iceoryx2`.
pub struct Bus {
    name: BusName,
    node: Node<Ipc>,
    status: EntryHandle<Ipc, BlackboardKey, BusStatus>,
    diag_service: Blackboard<Ipc, BlackboardKey>,
    diag: Reader<Ipc, BlackboardKey>,
    params: OnceLock<ParamClient>,
    commands: OnceLock<CommandClient>,
    answer_timeout: Option<Duration>,
}

impl core::fmt::Debug for Bus {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Bus")
            .field("name", &self.name.as_str())
            .field("node", &self.node.name().as_str())
            .finish_non_exhaustive()
    }
}

impl Bus {
    /// Opens bus `name` (e.g. `bus0`) under the node name [`DEFAULT_NODE_NAME`].
    pub fn open(name: &str) -> Result<Bus, ClientError> {
        Self::open_as(name, DEFAULT_NODE_NAME)
    }

    /// Opens bus `name` under the node name `node_name` (shown by `Node::list` and in the
    /// error another process gets when it tries to take a drive this one controls).
    pub fn open_as(name: &str, node_name: &str) -> Result<Bus, ClientError> {
        let name = BusName::new(name)?;
        let bus = name.as_str();
        let node_name =
            NodeName::new(node_name).map_err(|e| ClientError::ipc("the node name", e))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Ipc>()
            .map_err(|e| ClientError::ipc("creating the iceoryx2 node", e))?;
        let not_running = || ClientError::NotRunning {
            bus: bus.to_owned(),
        };
        let verifier = layout_verifier()?;

        let status_name = names::status(&name);
        let status_service = opened(
            node.service_builder(&status_name)
                .blackboard_opener::<BlackboardKey>()
                .open_with_attributes(&verifier),
            bus,
            &status_name,
            not_running,
        )?;
        let status = status_service
            .reader_builder()
            .create()
            .map_err(|e| ClientError::ipc(format!("reading {}", status_name.as_str()), e))?
            .entry::<BusStatus>(&BlackboardKey::IMAGE)
            .map_err(|_| ClientError::Incompatible {
                bus: bus.to_owned(),
                service: status_name.as_str().to_owned(),
            })?;

        let diag_name = names::diag(&name);
        let diag_service = opened(
            node.service_builder(&diag_name)
                .blackboard_opener::<BlackboardKey>()
                .open_with_attributes(&verifier),
            bus,
            &diag_name,
            not_running,
        )?;
        let diag = diag_service
            .reader_builder()
            .create()
            .map_err(|e| ClientError::ipc(format!("reading {}", diag_name.as_str()), e))?;

        Ok(Bus {
            name,
            node,
            status,
            diag_service,
            diag,
            params: OnceLock::new(),
            commands: OnceLock::new(),
            answer_timeout: None,
        })
    }

    /// The bus name.
    pub fn name(&self) -> &str {
        self.name.as_str()
    }

    pub(crate) fn bus_name(&self) -> &BusName {
        &self.name
    }

    pub(crate) fn node(&self) -> &Node<Ipc> {
        &self.node
    }

    /// How long a parameter request may take before [`crate::ParamError::NoAnswer`]; `None`
    /// (the default) allows 5 s plus 2.5 s per item (ussd's default parameter timeout is 2 s
    /// per item).
    pub fn set_answer_timeout(&mut self, timeout: Option<Duration>) {
        self.answer_timeout = timeout;
    }

    pub(crate) fn answer_timeout(&self, items: usize) -> Duration {
        self.answer_timeout
            .unwrap_or_else(|| Duration::from_secs(5) + Duration::from_millis(2500) * items as u32)
    }

    pub(crate) fn params_client(&self) -> &OnceLock<ParamClient> {
        &self.params
    }

    pub(crate) fn command_client(&self) -> &OnceLock<CommandClient> {
        &self.commands
    }

    /// The bus status, as ussd last published it (about every 100 ms).
    pub fn status(&self) -> BusStatus {
        *self.status.get()
    }

    /// The addresses of the drives ussd polls on this bus, ascending.
    pub fn drives(&self) -> Vec<u8> {
        let mut keys = Vec::new();
        self.diag_service.list_keys(|k| {
            if let Ok(a) = u8::try_from(k.value) {
                keys.push(a);
            }
            CallbackProgression::Continue
        });
        keys.sort_unstable();
        keys
    }

    /// A drive's diagnostics, as ussd last published them (about every 100 ms).
    pub fn diag(&self, address: u8) -> Result<DriveDiag, ClientError> {
        let a = self.known(address)?;
        let entry = self
            .diag
            .entry::<DriveDiag>(&BlackboardKey::drive(a))
            .map_err(|_| self.unknown_drive(address))?;
        Ok(*entry.get())
    }

    /// Watches a drive's input image (written by ussd after every good reply).
    pub fn watch(&self, address: u8) -> Result<DriveWatch, ClientError> {
        DriveWatch::open(self, DriveAddress::new(address)?)
    }

    /// A listener for the bus's exchange and cycle events, to run in step with the bus.
    pub fn cycle_listener(&self) -> Result<CycleListener, ClientError> {
        CycleListener::open(self)
    }

    /// Takes exclusive control of a drive. Fails with [`ClientError::Controlled`] ("drive 5 on
    /// bus0 is controlled by process 1234") while another controller holds it. See
    /// [`Controller`] for the watchdog rule.
    pub fn control(&self, address: u8, options: ControlOptions) -> Result<Controller, ClientError> {
        Controller::open(self, DriveAddress::new(address)?, options)
    }

    /// Checks that ussd polls `address` on this bus.
    pub(crate) fn known(&self, address: u8) -> Result<DriveAddress, ClientError> {
        let a = DriveAddress::new(address)?;
        if self.drives().contains(&address) {
            Ok(a)
        } else {
            Err(self.unknown_drive(address))
        }
    }

    pub(crate) fn unknown_drive(&self, address: u8) -> ClientError {
        ClientError::UnknownDrive {
            bus: self.name().to_owned(),
            address,
            known: self.drives(),
        }
    }
}
