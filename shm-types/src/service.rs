//! The iceoryx2 service variant of every uss-rt process, and where it keeps its files.
//!
//! [`Ipc`] and [`IpcThreadsafe`] are iceoryx2's `ipc` variants with every resource (shared
//! memory, connections, dynamic and static storage, node state, event sockets) a file below one
//! root directory, [`root`] (`/dev/shm/uss-rt`: tmpfs, so the files are memory). iceoryx2 0.10
//! decides the mode of each file it makes and offers no setting for it; built with its
//! `dev_permissions` feature (this workspace does) it makes them open to all, so the root
//! directory alone decides who may use ussd's services: ussd makes it owner-only, or with
//! `access_group` group-readable and -writable (mode 2770) for the members of that group
//! (`uss_master::daemon::access`). Every process of a bus must use this variant and root:
//! [`config`] is the iceoryx2 configuration that names it.

use std::path::PathBuf;

/// The environment variable that moves the root (tests, or a second installation); every
/// process of a bus must see the same.
pub const ROOT_ENV: &str = "USS_RT_SHM";
/// The root directory unless [`ROOT_ENV`] names another.
pub const DEFAULT_ROOT: &str = "/dev/shm/uss-rt";

/// The root directory of ussd's services.
pub fn root() -> PathBuf {
    std::env::var_os(ROOT_ENV)
        .filter(|r| !r.is_empty())
        .map_or_else(|| PathBuf::from(DEFAULT_ROOT), PathBuf::from)
}

#[cfg(feature = "ipc")]
pub use variants::{Ipc, IpcThreadsafe, config};

/// The iceoryx2 side: the configuration and the two variants (feature `ipc`).
#[cfg(feature = "ipc")]
mod variants {
    use core::fmt::Debug;
    use iceoryx2::config::Config;
    use iceoryx2::prelude::SemanticString as _;
    use iceoryx2_bb_elementary_traits::testing::abandonable::Abandonable;
    use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;
    use iceoryx2_bb_lock_free::mpmc::counting_bit_set::RelocatableCountingBitSet;
    use iceoryx2_cal::shm_allocator::{
        bump_allocator::BumpAllocator, pool_allocator::PoolAllocator,
    };
    use iceoryx2_cal::{
        arc_sync_policy, bag, dynamic_storage, event, hash, monitoring, reactor,
        resizable_shared_memory, serialize, shared_memory, static_storage, zero_copy_connection,
    };

    use super::root;

    /// The iceoryx2 configuration of every uss-rt node: its files below [`root`]. `None` for a
    /// root iceoryx2 cannot take as a path (not absolute, too long).
    pub fn config() -> Option<Config> {
        let root = root();
        let root = root.to_str()?;
        let path = iceoryx2_bb_system_types::path::Path::new(root.as_bytes()).ok()?;
        let mut c = Config::default();
        c.global.set_root_path(&path);
        Some(c)
    }

    macro_rules! variant {
        ($(#[$doc:meta])* $name:ident, $policy:ty) => {
            $(#[$doc])*
            #[derive(Debug, Clone)]
            pub struct $name {}

            impl iceoryx2::service::Service for $name {
                type StaticStorage = static_storage::file::Storage;
                type ConfigSerializer = serialize::recommended::Recommended;
                type PersistentDynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> =
                    dynamic_storage::file::Storage<T>;
                type Bag = bag::recommended::Recommended;
                type DynamicStorage<T: Debug + Send + Sync + ZeroCopySend + 'static> =
                    dynamic_storage::file::Storage<T>;
                type ServiceNameHasher = hash::recommended::Recommended;
                type SharedMemory = shared_memory::file::Memory<PoolAllocator>;
                type ResizableSharedMemory = resizable_shared_memory::dynamic::DynamicMemory<
                    PoolAllocator,
                    shared_memory::file::Memory<PoolAllocator>,
                >;
                type Connection = zero_copy_connection::file::Connection;
                type Event = event::trigger::unix_datagram_socket::GenericUnixDatagramSocketTrigger<
                    RelocatableCountingBitSet,
                    dynamic_storage::file::Storage<
                        event::trigger::State<RelocatableCountingBitSet, ()>,
                    >,
                >;
                type Monitoring = monitoring::recommended::Ipc;
                type Reactor = reactor::recommended::Ipc;
                type ArcThreadSafetyPolicy<T: Send + Debug + Abandonable> = $policy;
                type BlackboardMgmt<KeyType: Send + Sync + Debug + ZeroCopySend + 'static> =
                    dynamic_storage::file::Storage<KeyType>;
                type BlackboardPayload = shared_memory::file::Memory<BumpAllocator>;
                type UniqueId = iceoryx2::unique_id_generator::unique_system_id::UniqueSystemId;
            }

            impl iceoryx2::service::internal::ServiceInternal<$name> for $name {}
        };
    }

    variant!(
        /// iceoryx2's `ipc` variant with every resource a file below [`root`]; ports of one thread.
        Ipc,
        arc_sync_policy::single_threaded::SingleThreaded<T>
    );

    variant!(
        /// [`Ipc`] whose ports may be made in one thread and used in another (ussd, the client
        /// library).
        IpcThreadsafe,
        arc_sync_policy::mutex_protected::MutexProtected<T>
    );
}
