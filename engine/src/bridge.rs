//! The engine's seam to other processes ([`Bridge`]): their samples in, its images out, a wake
//! for the parameter server, and whether the process behind a parameter job still lives;
//! [`LocalBridge`] keeps everything in this process.

use crate::control::ControllerId;
use crate::image::DriveImages;
use crate::jobs::Requester;
use crate::stats::DriveStatus;
use uss_shm_types::PzdOutput;

/// Where process images leave and enter the bus thread (iceoryx2 in `ussd`; in-process cells
/// for [`EngineHandle::set_output`] otherwise). Called in the bus thread: implementations must
/// not allocate, block or log.
pub trait Bridge {
    /// Before the drive in `slot` is polled: the controller's newest sample since the last
    /// call, as it arrived, and who published it. The engine's [`Gate`] validates and decides;
    /// the bridge only carries.
    fn take_sample(
        &mut self,
        slot: usize,
        images: &DriveImages,
    ) -> Option<(PzdOutput, ControllerId)>;
    /// After every poll of the drive, good or failed: publish its input image and state.
    fn after_poll(&mut self, slot: usize, images: &DriveImages, status: &DriveStatus);
    /// After a pass through the circulating list.
    fn cycle_completed(&mut self);
    /// After a parameter job's result was handed to the parameter bridge: wake it.
    fn job_done(&mut self);
    /// Before a parameter job of `requester` leaves its drive's mailbox: whether the process
    /// that asked for it has ended (its work dies with it). Called on the bus thread: it must
    /// neither block nor allocate. A bridge that carries no other process's jobs (or cannot
    /// tell) says no: such jobs run, and their results find nobody.
    fn requester_ended(&self, requester: Requester) -> bool {
        let _ = requester;
        false
    }
}

/// Process images in this process only: samples come from [`EngineHandle::set_output`] and
/// friends, inputs are read with [`EngineHandle::input`].
#[derive(Debug, Clone, Copy, Default)]
pub struct LocalBridge;

impl Bridge for LocalBridge {
    fn take_sample(&mut self, _: usize, images: &DriveImages) -> Option<(PzdOutput, ControllerId)> {
        images.output.take().map(|s| (s, ControllerId::IN_PROCESS))
    }
    fn after_poll(&mut self, _: usize, _: &DriveImages, _: &DriveStatus) {}
    fn cycle_completed(&mut self) {}
    fn job_done(&mut self) {}
}
