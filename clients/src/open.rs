//! Opening ussd's services: the layout attribute every one carries, and what each open error
//! means to a client.

use crate::ClientError;
use iceoryx2::port::reader::EntryHandle;
use iceoryx2::prelude::{AttributeVerifier, ServiceName};
use iceoryx2::service::builder::blackboard::BlackboardOpenError;
use iceoryx2::service::builder::event::EventOpenError;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;
use iceoryx2::service::builder::request_response::RequestResponseOpenError;
use iceoryx2::service::port_factory::blackboard::PortFactory as Blackboard;
use uss_shm_types::BlackboardKey;
use uss_shm_types::LAYOUT_VERSION;
use uss_shm_types::names::LAYOUT_VERSION_ATTRIBUTE;

/// The client's side of iceoryx2 everywhere in this crate: uss-rt's service variant
/// (`uss_shm_types::service`) with thread-safe ports, so a `Bus`, a `DriveWatch` and a
/// `Controller` can move between threads (a refresher thread publishes through the
/// controller's publisher). Its files are those of `uss_shm_types::service::Ipc`: both
/// interoperate.
pub(crate) type Ipc = uss_shm_types::service::IpcThreadsafe;

/// The iceoryx2 configuration of uss-rt (`uss_shm_types::service::config`), once this process
/// may use ussd's root directory: [`ClientError::NotRunning`] when there is none (no ussd made
/// it), [`ClientError::Access`] when this process may not enter it.
pub(crate) fn iceoryx_config(bus: &str) -> Result<iceoryx2::config::Config, ClientError> {
    use nix::unistd::{AccessFlags, Group, User, access};
    use std::os::unix::fs::MetadataExt as _;
    let root = uss_shm_types::service::root();
    let Ok(meta) = std::fs::metadata(&root) else {
        return Err(ClientError::not_running(bus.to_owned()));
    };
    if access(
        &root,
        AccessFlags::R_OK | AccessFlags::W_OK | AccessFlags::X_OK,
    )
    .is_err()
    {
        let owner = User::from_uid(meta.uid().into())
            .ok()
            .flatten()
            .map_or_else(|| meta.uid().to_string(), |u| u.name);
        let group = Group::from_gid(meta.gid().into())
            .ok()
            .flatten()
            .map_or_else(|| meta.gid().to_string(), |g| g.name);
        return Err(ClientError::Access {
            root,
            owner,
            group,
            mode: meta.mode() & 0o7777,
        });
    }
    uss_shm_types::service::config().ok_or_else(|| {
        ClientError::ipc(
            "the shared-memory root",
            format!("{} is not an absolute path iceoryx2 takes", root.display()),
        )
    })
}

/// Requires `uss.layout_version` = [`LAYOUT_VERSION`], so a ussd built against another layout
/// is refused at open time with a clear message instead of read as garbage.
pub(crate) fn layout_verifier() -> Result<AttributeVerifier, ClientError> {
    let key = LAYOUT_VERSION_ATTRIBUTE
        .try_into()
        .map_err(|e| ClientError::ipc("the layout attribute key", e))?;
    let value = LAYOUT_VERSION
        .to_string()
        .as_str()
        .try_into()
        .map_err(|e| ClientError::ipc("the layout attribute value", e))?;
    AttributeVerifier::new()
        .require(&key, &value)
        .map_err(|e| ClientError::ipc("the layout attribute", e))
}

/// What an open error means to a client.
pub(crate) enum Failure {
    /// The service does not exist (or is being removed): ussd is not there.
    Missing,
    /// It exists with another layout, type or pattern.
    Incompatible,
    /// Anything else (permissions, limits, corruption).
    Other,
}

pub(crate) trait OpenError: core::fmt::Debug {
    fn failure(&self) -> Failure;
}

impl OpenError for BlackboardOpenError {
    fn failure(&self) -> Failure {
        match self {
            Self::DoesNotExist | Self::IsMarkedForDestruction => Failure::Missing,
            Self::IncompatibleAttributes
            | Self::IncompatibleKeys
            | Self::IncompatibleMessagingPattern => Failure::Incompatible,
            _ => Failure::Other,
        }
    }
}

impl OpenError for PublishSubscribeOpenError {
    fn failure(&self) -> Failure {
        match self {
            Self::DoesNotExist | Self::IsMarkedForDestruction => Failure::Missing,
            Self::IncompatibleAttributes
            | Self::IncompatibleTypes
            | Self::IncompatibleMessagingPattern => Failure::Incompatible,
            _ => Failure::Other,
        }
    }
}

impl OpenError for EventOpenError {
    fn failure(&self) -> Failure {
        match self {
            Self::DoesNotExist | Self::IsMarkedForDestruction => Failure::Missing,
            Self::IncompatibleAttributes | Self::IncompatibleMessagingPattern => {
                Failure::Incompatible
            }
            _ => Failure::Other,
        }
    }
}

impl OpenError for RequestResponseOpenError {
    fn failure(&self) -> Failure {
        match self {
            Self::DoesNotExist | Self::IsMarkedForDestruction => Failure::Missing,
            Self::IncompatibleAttributes
            | Self::IncompatibleRequestOrResponseType
            | Self::IncompatibleMessagingPattern => Failure::Incompatible,
            _ => Failure::Other,
        }
    }
}

/// The entry `key` of a blackboard service `name` of bus `bus`, through a reader of its own
/// (the entry keeps it); a missing or differently typed entry is [`ClientError::Incompatible`].
pub(crate) fn entry<T: Copy + core::fmt::Debug + iceoryx2::prelude::ZeroCopySend + 'static>(
    service: &Blackboard<Ipc, BlackboardKey>,
    bus: &str,
    name: &ServiceName,
    key: BlackboardKey,
) -> Result<EntryHandle<Ipc, BlackboardKey, T>, ClientError> {
    service
        .reader_builder()
        .create()
        .map_err(|e| ClientError::ipc(format!("reading {}", name.as_str()), e))?
        .entry::<T>(&key)
        .map_err(|_| ClientError::Incompatible {
            bus: bus.to_owned(),
            service: name.as_str().to_owned(),
        })
}

/// The error for a drive whose service does not exist (the list of drives is filled in by
/// [`crate::Bus`], which knows them).
pub(crate) fn unknown_drive(bus: &str, address: u8) -> impl FnOnce() -> ClientError {
    let bus = bus.to_owned();
    move || ClientError::UnknownDrive {
        bus,
        address,
        known: Vec::new(),
    }
}

/// Maps an open error of service `name` on `bus`; `missing` says what a missing service means
/// (ussd not running, or a drive ussd does not poll).
pub(crate) fn opened<T, E: OpenError>(
    result: Result<T, E>,
    bus: &str,
    name: &ServiceName,
    missing: impl FnOnce() -> ClientError,
) -> Result<T, ClientError> {
    result.map_err(|e| match e.failure() {
        Failure::Missing => missing(),
        Failure::Incompatible => ClientError::Incompatible {
            bus: bus.to_owned(),
            service: name.as_str().to_owned(),
        },
        Failure::Other => ClientError::ipc(format!("opening {}", name.as_str()), e),
    })
}
