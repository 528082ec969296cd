//! Real-time setup of a bus thread: CPU pinning, `SCHED_FIFO`, stack prefault and memory locking.
//!
//! The steps run in the order of docs/ARCHITECTURE.md "Real-time setup (order matters)". None of them is
//! fatal here: a step that fails is recorded with its errno and the capabilities, limits and kernel
//! settings that explain it, plus what to change, and the thread carries on best-effort (honest,
//! actionable degradation). Whether that is acceptable is the caller's decision
//! (`--require-rt`).

use std::fmt;
use std::mem::MaybeUninit;

use nix::errno::Errno;
use nix::libc;
use nix::sched::{CpuSet, sched_getaffinity, sched_setaffinity};
use nix::sys::mman::{MlockAllFlags, mlockall};
use nix::sys::pthread::pthread_self;
use nix::sys::resource::{RLIM_INFINITY, Resource, getrlimit};
use nix::unistd::{Pid, SysconfVar, sysconf};

/// Lowest `SCHED_FIFO` priority on Linux (`sched_get_priority_min`).
pub const FIFO_PRIORITY_MIN: u8 = 1;
/// Highest `SCHED_FIFO` priority on Linux (`sched_get_priority_max`, `MAX_RT_PRIO - 1`).
pub const FIFO_PRIORITY_MAX: u8 = 99;

/// Capability bit numbers from `linux/capability.h`.
const CAP_IPC_LOCK: u32 = 14;
const CAP_SYS_NICE: u32 = 23;

/// The prefault recursion touches the stack in frames of this many bytes.
const PREFAULT_CHUNK: usize = 16 * 1024;
/// Linux pages are at least 4 KiB, so one write per 4 KiB faults in every page.
const PAGE_STRIDE: usize = 4096;
/// Generous bound on a prefault frame's size beyond its chunk (return address, saved registers, and
/// the larger frames of debug builds).
const PREFAULT_FRAME_OVERHEAD: usize = 1024;
/// Stack left untouched below the prefaulted region, so the prefault itself can never reach the
/// guard page: a stack overflow would kill the process instead of degrading.
const STACK_RESERVE: usize = 64 * 1024;

/// What the bus thread asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RtRequest {
    /// CPU to pin the thread to; `None` leaves the affinity alone.
    pub cpu: Option<usize>,
    /// `SCHED_FIFO` priority, `FIFO_PRIORITY_MIN..=FIFO_PRIORITY_MAX`.
    pub priority: u8,
    /// Lock all current and future pages (`mlockall`) so the bus loop never takes a page fault.
    pub lock_memory: bool,
    /// Stack the bus loop may use, faulted in now rather than on first use in the loop.
    pub prefault_stack_bytes: usize,
}

/// One step of the set-up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RtStep {
    Affinity,
    Scheduler,
    StackPrefault,
    MemoryLock,
}

impl fmt::Display for RtStep {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Affinity => "CPU affinity",
            Self::Scheduler => "SCHED_FIFO",
            Self::StackPrefault => "stack prefault",
            Self::MemoryLock => "memory lock",
        })
    }
}

/// One step that failed, with everything an operator needs to fix it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RtFailure {
    pub step: RtStep,
    /// The errno of the failed call, or of the check that stopped us from making it; `None` when
    /// no errno applies (the call was skipped on purpose, or only partly done).
    pub errno: Option<Errno>,
    /// Why, in one line: capabilities, limits, kernel settings, and what to change.
    pub detail: String,
}

impl fmt::Display for RtFailure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.errno {
            // Errno's Display is "EPERM: Operation not permitted": the name an operator searches for.
            Some(errno) => write!(f, "{} failed ({errno}): {}", self.step, self.detail),
            None => write!(f, "{} failed: {}", self.step, self.detail),
        }
    }
}

/// What was obtained; printed in status.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RtReport {
    /// Pinned CPU, if obtained.
    pub cpu: Option<usize>,
    /// `SCHED_FIFO` priority, if obtained.
    pub priority: Option<u8>,
    /// Bytes of stack faulted in.
    pub stack_prefaulted: usize,
    pub memory_locked: bool,
    pub failures: Vec<RtFailure>,
}

impl RtReport {
    /// Everything requested was obtained: every step that was not obtained records a failure.
    pub fn is_full_rt(&self) -> bool {
        self.failures.is_empty()
    }

    /// The mode shown in status.
    pub fn mode(&self) -> &'static str {
        if self.is_full_rt() {
            "realtime"
        } else {
            "best-effort"
        }
    }

    /// One line for a structured log warning: what was obtained, what failed and why (errno name,
    /// capabilities, limits).
    pub fn summary(&self) -> String {
        let mut obtained = Vec::new();
        if let Some(cpu) = self.cpu {
            obtained.push(format!("pinned to CPU {cpu}"));
        }
        if let Some(priority) = self.priority {
            obtained.push(format!("SCHED_FIFO priority {priority}"));
        }
        if self.stack_prefaulted > 0 {
            obtained.push(format!(
                "{} bytes of stack prefaulted",
                self.stack_prefaulted
            ));
        }
        if self.memory_locked {
            obtained.push("memory locked".to_owned());
        }
        let obtained = if obtained.is_empty() {
            "nothing".to_owned()
        } else {
            obtained.join(", ")
        };
        if self.is_full_rt() {
            return format!("realtime: {obtained}");
        }
        let failed: Vec<String> = self.failures.iter().map(ToString::to_string).collect();
        format!("best-effort: obtained {obtained}; {}", failed.join(" | "))
    }
}

/// Applies the request to the calling thread, in the order of ARCHITECTURE.md: pin the CPU first
/// (so the stack is faulted in on the node it will run on), then `SCHED_FIFO`, then prefault the
/// stack, then `mlockall` (which keeps the prefaulted pages resident). Never panics; every failure
/// is recorded and the thread continues best-effort.
pub fn apply_to_current_thread(req: &RtRequest) -> RtReport {
    let mut report = RtReport {
        cpu: None,
        priority: None,
        stack_prefaulted: 0,
        memory_locked: false,
        failures: Vec::new(),
    };
    if let Some(cpu) = req.cpu {
        match pin_to_cpu(cpu) {
            Ok(()) => report.cpu = Some(cpu),
            Err(failure) => report.failures.push(failure),
        }
    }
    match set_fifo(req.priority) {
        Ok(()) => report.priority = Some(req.priority),
        Err(failure) => report.failures.push(failure),
    }
    if req.prefault_stack_bytes > 0 {
        let (bytes, failure) = prefault_stack(req.prefault_stack_bytes);
        report.stack_prefaulted = bytes;
        report.failures.extend(failure);
    }
    if req.lock_memory {
        match lock_memory() {
            Ok(()) => report.memory_locked = true,
            Err(failure) => report.failures.push(failure),
        }
    }
    report
}

/// The calling thread's scheduling policy (`libc::SCHED_OTHER`, `libc::SCHED_FIFO`, ...) and
/// priority; `(-1, -1)` if the kernel refuses to say, which it does not for a live thread.
pub fn current_thread_sched() -> (i32, i32) {
    let mut policy = 0;
    let mut param = libc::sched_param { sched_priority: 0 };
    // SAFETY: pthread_self() names the calling thread, alive for the whole call; both out-pointers
    // point to live locals of the right types.
    let rc =
        unsafe { libc::pthread_getschedparam(pthread_self(), &raw mut policy, &raw mut param) };
    if rc == 0 {
        (policy, param.sched_priority)
    } else {
        (-1, -1)
    }
}

/// The CPUs the calling thread may run on, ascending; empty if the kernel refuses to say.
pub fn current_thread_cpus() -> Vec<usize> {
    // Pid 0 is the calling thread, not the whole process.
    let Ok(set) = sched_getaffinity(Pid::from_raw(0)) else {
        return Vec::new();
    };
    (0..CpuSet::count())
        .filter(|&cpu| set.is_set(cpu).unwrap_or(false))
        .collect()
}

fn failure(step: RtStep, errno: Option<Errno>, detail: String) -> RtFailure {
    RtFailure {
        step,
        errno,
        detail,
    }
}

fn pin_to_cpu(cpu: usize) -> Result<(), RtFailure> {
    let online = online_cpu_count();
    if let Some(online) = online.filter(|&online| cpu >= online) {
        return Err(failure(
            RtStep::Affinity,
            Some(Errno::EINVAL),
            format!(
                "CPU {cpu} does not exist: {online} CPUs online (0..={}); not attempted; \
                 configure a CPU below {online}, or none to leave the affinity alone",
                online.saturating_sub(1)
            ),
        ));
    }
    let mut set = CpuSet::new();
    if let Err(errno) = set.set(cpu) {
        return Err(failure(
            RtStep::Affinity,
            Some(errno),
            format!(
                "CPU {cpu} does not fit a cpu_set_t of {} CPUs; not attempted; configure an existing CPU",
                CpuSet::count()
            ),
        ));
    }
    // Pid 0 is the calling thread: only the bus thread is pinned, not the whole daemon.
    sched_setaffinity(Pid::from_raw(0), &set).map_err(|errno| {
        let online = online.map_or_else(|| "unknown".to_owned(), |n| n.to_string());
        failure(
            RtStep::Affinity,
            Some(errno),
            format!(
                "sched_setaffinity(CPU {cpu}) refused; CPUs online: {online}; this thread may run on \
                 {:?}; EINVAL means the CPU is offline or outside this process's cpuset \
                 (cgroup cpuset, docker --cpuset-cpus, systemd AllowedCPUs=, taskset): \
                 configure one of the allowed CPUs or widen the cpuset",
                current_thread_cpus()
            ),
        )
    })
}

fn online_cpu_count() -> Option<usize> {
    match sysconf(SysconfVar::_NPROCESSORS_ONLN) {
        Ok(Some(n)) => usize::try_from(n).ok(),
        _ => None,
    }
}

fn set_fifo(priority: u8) -> Result<(), RtFailure> {
    if !(FIFO_PRIORITY_MIN..=FIFO_PRIORITY_MAX).contains(&priority) {
        return Err(failure(
            RtStep::Scheduler,
            Some(Errno::EINVAL),
            format!(
                "priority {priority} is outside SCHED_FIFO's {FIFO_PRIORITY_MIN}..={FIFO_PRIORITY_MAX}; \
                 not attempted; {}; configure a priority in {FIFO_PRIORITY_MIN}..={FIFO_PRIORITY_MAX}",
                rlimit_text(Resource::RLIMIT_RTPRIO, "RLIMIT_RTPRIO")
            ),
        ));
    }
    let param = libc::sched_param {
        sched_priority: i32::from(priority),
    };
    // SAFETY: pthread_self() names the calling thread, alive for the whole call; `param` is a valid
    // sched_param that the call only reads.
    let rc =
        unsafe { libc::pthread_setschedparam(pthread_self(), libc::SCHED_FIFO, &raw const param) };
    // pthread functions return the error number; they do not return -1 and set errno.
    if rc == 0 {
        Ok(())
    } else {
        Err(scheduler_failure(Errno::from_raw(rc), priority))
    }
}

fn scheduler_failure(errno: Errno, priority: u8) -> RtFailure {
    let caps = effective_caps();
    let rtprio = getrlimit(Resource::RLIMIT_RTPRIO).ok();
    let hint = if errno != Errno::EPERM {
        "unexpected error from pthread_setschedparam; check the kernel log".to_owned()
    } else if has_cap(caps, CAP_SYS_NICE)
        || rtprio.is_some_and(|(soft, _)| soft >= u64::from(priority))
    {
        // Allowed by capability or limit, yet refused: RT group scheduling gives this cgroup no
        // RT runtime (the kernel then refuses SCHED_FIFO even to root).
        "the capability or limit allows it, so RT bandwidth refused it: give this task's cgroup an \
         RT budget (cgroup v1 cpu.rt_runtime_us, docker --cpu-rt-runtime=950000) or run it in the \
         root cpu cgroup"
            .to_owned()
    } else {
        format!(
            "run as root, grant CAP_SYS_NICE (setcap cap_sys_nice+ep ussd, systemd \
             AmbientCapabilities=CAP_SYS_NICE) or raise rtprio to at least {priority} \
             (/etc/security/limits.conf `<user> - rtprio {priority}`, systemd LimitRTPRIO={priority}, \
             docker --ulimit rtprio={priority})"
        )
    };
    failure(
        RtStep::Scheduler,
        Some(errno),
        format!(
            "pthread_setschedparam(SCHED_FIFO, {priority}) refused; {}; {}; {}; {}; {hint}",
            rlimit_text(Resource::RLIMIT_RTPRIO, "RLIMIT_RTPRIO"),
            cap_text(caps, CAP_SYS_NICE, "CAP_SYS_NICE"),
            kernel_rt_runtime_text(),
            cgroup_rt_runtime_text(),
        ),
    )
}

/// Faults in `requested` bytes of stack below the caller's frame, as far as the thread's stack
/// allows without coming near its guard page; returns the bytes touched and a failure if that is
/// less than requested.
fn prefault_stack(requested: usize) -> (usize, Option<RtFailure>) {
    let headroom = match stack_headroom() {
        Ok(headroom) => headroom,
        Err(errno) => {
            let detail =
                "pthread_getattr_np could not report this thread's stack, and touching an \
                          unknown stack could overflow it; not attempted; the thread runs without \
                          a prefaulted stack (first use of each stack page faults)"
                    .to_owned();
            return (0, Some(failure(RtStep::StackPrefault, Some(errno), detail)));
        }
    };
    let usable = headroom.saturating_sub(STACK_RESERVE);
    let fits = usable / (PREFAULT_CHUNK + PREFAULT_FRAME_OVERHEAD) * PREFAULT_CHUNK;
    let bytes = requested.min(fits);
    touch_stack(bytes);
    if bytes == requested {
        return (bytes, None);
    }
    let detail = format!(
        "{requested} bytes requested but only {headroom} bytes of stack remain below this frame, \
         {bytes} prefaulted ({STACK_RESERVE} kept clear of the guard page); spawn the bus thread \
         with a larger stack (std::thread::Builder::stack_size) or prefault less"
    );
    (bytes, Some(failure(RtStep::StackPrefault, None, detail)))
}

/// Bytes between the current stack position and the low end of the thread's usable stack (the
/// stack grows down on every architecture Linux runs the daemon on).
fn stack_headroom() -> Result<usize, Errno> {
    let mut attr = MaybeUninit::<libc::pthread_attr_t>::uninit();
    // SAFETY: pthread_self() names the calling, live thread; on success pthread_getattr_np
    // initialises `attr`, which is destroyed below.
    let rc = unsafe { libc::pthread_getattr_np(pthread_self(), attr.as_mut_ptr()) };
    if rc != 0 {
        return Err(Errno::from_raw(rc));
    }
    let mut low: *mut libc::c_void = std::ptr::null_mut();
    let mut size: libc::size_t = 0;
    // SAFETY: `attr` was initialised by the successful pthread_getattr_np above; the out-pointers
    // point to live locals of the right types.
    let rc = unsafe { libc::pthread_attr_getstack(attr.as_ptr(), &raw mut low, &raw mut size) };
    // SAFETY: `attr` is initialised and destroyed exactly once, here.
    unsafe { libc::pthread_attr_destroy(attr.as_mut_ptr()) };
    if rc != 0 {
        return Err(Errno::from_raw(rc));
    }
    // The address of a local is the current stack position, near enough with STACK_RESERVE.
    let marker = 0u8;
    let here = std::hint::black_box(&raw const marker).addr();
    Ok(here.saturating_sub(low.addr()))
}

/// Touches `bytes` of stack, one chunk per recursion level, one volatile write per page.
#[inline(never)]
fn touch_stack(bytes: usize) {
    let mut chunk = [0u8; PREFAULT_CHUNK];
    let here = bytes.min(PREFAULT_CHUNK);
    for offset in (0..here).step_by(PAGE_STRIDE) {
        // SAFETY: `offset < here <= PREFAULT_CHUNK`, so the pointer is to an element of the local
        // array; volatile so the write, and with it the page fault, is not optimised away.
        unsafe { std::ptr::write_volatile(&raw mut chunk[offset], 1) };
    }
    if bytes > here {
        touch_stack(bytes - here);
    }
    // Keeps `chunk` live across the call, so the recursion cannot become a loop reusing one frame.
    std::hint::black_box(&chunk);
}

/// Whether `mlockall` is safe to call: the memlock limit is unlimited or the process has
/// `CAP_IPC_LOCK` (then no limit applies).
pub fn may_lock_memory() -> bool {
    getrlimit(Resource::RLIMIT_MEMLOCK).is_ok_and(|(soft, _)| soft == RLIM_INFINITY)
        || has_cap(effective_caps(), CAP_IPC_LOCK)
}

fn lock_memory() -> Result<(), RtFailure> {
    let caps = effective_caps();
    let (soft, hard) = getrlimit(Resource::RLIMIT_MEMLOCK).map_err(|errno| {
        let detail = "getrlimit(RLIMIT_MEMLOCK) failed, so locking could break later thread and \
                      shared-memory creation; mlockall not attempted"
            .to_owned();
        failure(RtStep::MemoryLock, Some(errno), detail)
    })?;
    let limits = format!(
        "RLIMIT_MEMLOCK soft={} hard={}; {}",
        limit_text(soft),
        limit_text(hard),
        cap_text(caps, CAP_IPC_LOCK, "CAP_IPC_LOCK")
    );
    // With CAP_IPC_LOCK the limit does not apply (mlock(2)); without it, MCL_FUTURE charges every
    // later mapping to the limit: measured here, later thread spawns fail with EAGAIN and
    // iceoryx2 shared-memory creation fails (ARCHITECTURE.md "Gotchas").
    if soft != RLIM_INFINITY && !has_cap(caps, CAP_IPC_LOCK) {
        let raise = if hard == RLIM_INFINITY {
            "the hard limit allows it: `ulimit -l unlimited` before starting ussd"
        } else {
            "set memlock unlimited (/etc/security/limits.conf `<user> - memlock unlimited`, systemd \
             LimitMEMLOCK=infinity, docker --ulimit memlock=-1) or grant CAP_IPC_LOCK"
        };
        return Err(failure(
            RtStep::MemoryLock,
            None,
            format!(
                "mlockall(MCL_CURRENT|MCL_FUTURE) not attempted: {limits}; under a finite limit every \
                 later mapping counts against it, so later thread spawns (EAGAIN) and shared-memory \
                 creation would fail; {raise}"
            ),
        ));
    }
    mlockall(MlockAllFlags::MCL_CURRENT | MlockAllFlags::MCL_FUTURE).map_err(|errno| {
        failure(
            RtStep::MemoryLock,
            Some(errno),
            format!(
                "mlockall(MCL_CURRENT|MCL_FUTURE) refused; {limits}; ENOMEM means not enough free \
                 RAM to lock the mapped pages: reduce buffer sizes or add memory; EPERM means the \
                 limit or CAP_IPC_LOCK disallows it"
            ),
        )
    })
}

/// `CapEff` of the calling thread (capabilities are per thread); `None` if unreadable.
fn effective_caps() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/thread-self/status")
        .or_else(|_| std::fs::read_to_string("/proc/self/status"))
        .ok()?;
    parse_cap_eff(&status)
}

fn parse_cap_eff(status: &str) -> Option<u64> {
    let hex = status
        .lines()
        .find_map(|line| line.strip_prefix("CapEff:"))?;
    u64::from_str_radix(hex.trim(), 16).ok()
}

fn has_cap(caps: Option<u64>, bit: u32) -> bool {
    caps.is_some_and(|caps| caps >> bit & 1 == 1)
}

fn cap_text(caps: Option<u64>, bit: u32, name: &str) -> String {
    match caps {
        Some(caps) if has_cap(Some(caps), bit) => {
            format!("{name} in effective set (CapEff={caps:016x})")
        }
        Some(caps) => format!("{name} not in effective set (CapEff={caps:016x})"),
        None => format!("{name} unknown (CapEff unreadable in /proc/self/status)"),
    }
}

fn rlimit_text(resource: Resource, name: &str) -> String {
    match getrlimit(resource) {
        Ok((soft, hard)) => format!("{name} soft={} hard={}", limit_text(soft), limit_text(hard)),
        Err(errno) => format!("{name} unreadable ({errno})"),
    }
}

fn limit_text(limit: libc::rlim_t) -> String {
    if limit == RLIM_INFINITY {
        "unlimited".to_owned()
    } else {
        limit.to_string()
    }
}

/// The system-wide RT throttle: `-1` is none, the default 950000 of 1000000 leaves non-RT tasks 5 %.
fn kernel_rt_runtime_text() -> String {
    let read = |name: &str| {
        std::fs::read_to_string(format!("/proc/sys/kernel/{name}"))
            .map_or_else(|_| "unreadable".to_owned(), |value| value.trim().to_owned())
    };
    format!(
        "sched_rt_runtime_us={} of sched_rt_period_us={}",
        read("sched_rt_runtime_us"),
        read("sched_rt_period_us")
    )
}

/// The RT budget of this task's cpu cgroup, where RT group scheduling exposes one (cgroup v1
/// `cpu.rt_runtime_us`): 0 there makes the kernel refuse `SCHED_FIFO` with EPERM even to root.
fn cgroup_rt_runtime_text() -> String {
    let Ok(cgroups) = std::fs::read_to_string("/proc/self/cgroup") else {
        return "cgroup unreadable".to_owned();
    };
    for line in cgroups.lines() {
        // "hierarchy-id:controllers:path"; cgroup v2 has empty controllers.
        let mut fields = line.splitn(3, ':');
        let (Some(_), Some(controllers), Some(path)) =
            (fields.next(), fields.next(), fields.next())
        else {
            continue;
        };
        let path = path.trim_end_matches('/');
        let candidates = if controllers.is_empty() {
            vec![format!("/sys/fs/cgroup{path}/cpu.rt_runtime_us")]
        } else if controllers.split(',').any(|c| c == "cpu") {
            vec![
                format!("/sys/fs/cgroup/{controllers}{path}/cpu.rt_runtime_us"),
                format!("/sys/fs/cgroup/cpu{path}/cpu.rt_runtime_us"),
            ]
        } else {
            continue;
        };
        for file in candidates {
            if let Ok(value) = std::fs::read_to_string(&file) {
                return format!("{file}={}", value.trim());
            }
        }
    }
    "no cgroup cpu.rt_runtime_us (no RT group scheduling limit)".to_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs `f` on a fresh thread so scheduling, affinity and stack changes never touch the test
    /// harness's threads.
    fn on_fresh_thread<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
        std::thread::Builder::new()
            .stack_size(1024 * 1024)
            .spawn(f)
            .expect("spawn test thread")
            .join()
            .expect("test thread panicked")
    }

    fn request(priority: u8) -> RtRequest {
        RtRequest {
            cpu: None,
            priority,
            lock_memory: false,
            prefault_stack_bytes: 0,
        }
    }

    fn failure_of(report: &RtReport, step: RtStep) -> Option<&RtFailure> {
        report.failures.iter().find(|failure| failure.step == step)
    }

    #[test]
    fn fifo_read_back_matches_what_the_report_claims() {
        let (report, sched) = on_fresh_thread(|| {
            let report = apply_to_current_thread(&request(10));
            (report, current_thread_sched())
        });
        if report.priority == Some(10) {
            assert_eq!(sched, (libc::SCHED_FIFO, 10));
            assert!(report.is_full_rt());
            assert_eq!(report.mode(), "realtime");
        } else {
            let failure =
                failure_of(&report, RtStep::Scheduler).expect("scheduler failure recorded");
            assert!(failure.errno.is_some());
            assert!(failure.detail.contains("CAP_SYS_NICE"));
            assert!(failure.detail.contains("RLIMIT_RTPRIO"));
            assert!(failure.detail.contains("sched_rt_runtime_us"));
            assert_eq!(sched, (libc::SCHED_OTHER, 0));
            assert_eq!(report.mode(), "best-effort");
        }
    }

    #[test]
    fn pinning_to_cpu_0_leaves_only_cpu_0_or_records_why_not() {
        let (report, before, after) = on_fresh_thread(|| {
            let before = current_thread_cpus();
            let report = apply_to_current_thread(&RtRequest {
                cpu: Some(0),
                ..request(10)
            });
            (report, before, current_thread_cpus())
        });
        if report.cpu == Some(0) {
            assert_eq!(after, vec![0]);
            assert!(failure_of(&report, RtStep::Affinity).is_none());
        } else {
            assert!(failure_of(&report, RtStep::Affinity).is_some());
            assert_eq!(after, before);
        }
    }

    #[test]
    fn nonexistent_cpu_fails_with_einval_and_keeps_the_affinity() {
        let (report, before, after) = on_fresh_thread(|| {
            let before = current_thread_cpus();
            let report = apply_to_current_thread(&RtRequest {
                cpu: Some(999),
                ..request(10)
            });
            (report, before, current_thread_cpus())
        });
        let failure = failure_of(&report, RtStep::Affinity).expect("affinity failure recorded");
        assert_eq!(failure.errno, Some(Errno::EINVAL));
        assert!(failure.detail.contains("CPU 999"));
        assert!(failure.detail.contains("online"));
        assert_eq!(report.cpu, None);
        assert!(!before.is_empty());
        assert_eq!(after, before);
        assert!(!report.is_full_rt());
    }

    #[test]
    fn priority_outside_1_to_99_fails_with_einval_and_keeps_the_policy() {
        for priority in [0, 100] {
            let (report, before, after) = on_fresh_thread(move || {
                let before = current_thread_sched();
                let report = apply_to_current_thread(&request(priority));
                (report, before, current_thread_sched())
            });
            let failure = failure_of(&report, RtStep::Scheduler).expect("scheduler failure");
            assert_eq!(failure.errno, Some(Errno::EINVAL), "priority {priority}");
            assert!(failure.detail.contains(&format!("priority {priority}")));
            assert_eq!(report.priority, None);
            assert_eq!(after, before);
        }
    }

    #[test]
    fn memory_lock_is_skipped_with_an_explanation_unless_memlock_is_unlimited_or_capable() {
        let (soft, _) = getrlimit(Resource::RLIMIT_MEMLOCK).expect("getrlimit");
        let report = on_fresh_thread(|| {
            apply_to_current_thread(&RtRequest {
                lock_memory: true,
                ..request(10)
            })
        });
        if may_lock_memory() {
            // mlockall is process-wide: undo it so the other tests run as usual.
            nix::sys::mman::munlockall().expect("munlockall");
            assert!(report.memory_locked);
            assert!(failure_of(&report, RtStep::MemoryLock).is_none());
        } else {
            assert!(!report.memory_locked);
            let failure = failure_of(&report, RtStep::MemoryLock).expect("memory lock failure");
            assert_eq!(failure.errno, None, "mlockall must not have been called");
            assert!(failure.detail.contains("not attempted"));
            assert!(
                failure
                    .detail
                    .contains(&format!("RLIMIT_MEMLOCK soft={soft}"))
            );
            assert!(failure.detail.contains("CAP_IPC_LOCK"));
        }
    }

    #[test]
    fn summary_names_the_errno_and_the_limits() {
        let report = on_fresh_thread(|| {
            apply_to_current_thread(&RtRequest {
                cpu: Some(999),
                lock_memory: true,
                ..request(0)
            })
        });
        let summary = report.summary();
        assert!(summary.starts_with("best-effort: "), "{summary}");
        assert!(summary.contains("EINVAL"), "{summary}");
        assert!(summary.contains("RLIMIT_RTPRIO soft="), "{summary}");
        assert!(!summary.contains('\n'), "one line: {summary}");
        if may_lock_memory() {
            nix::sys::mman::munlockall().expect("munlockall");
        } else {
            assert!(summary.contains("RLIMIT_MEMLOCK soft="), "{summary}");
        }
    }

    #[test]
    fn prefault_reports_the_bytes_touched() {
        let report = on_fresh_thread(|| {
            apply_to_current_thread(&RtRequest {
                prefault_stack_bytes: 256 * 1024 + 100,
                ..request(10)
            })
        });
        assert_eq!(report.stack_prefaulted, 256 * 1024 + 100);
        assert!(failure_of(&report, RtStep::StackPrefault).is_none());
        assert!(
            report
                .summary()
                .contains("262244 bytes of stack prefaulted")
        );
    }

    #[test]
    fn prefault_larger_than_the_stack_touches_what_fits_and_does_not_overflow() {
        let report = std::thread::Builder::new()
            .stack_size(256 * 1024)
            .spawn(|| {
                apply_to_current_thread(&RtRequest {
                    prefault_stack_bytes: 4 * 1024 * 1024,
                    ..request(10)
                })
            })
            .expect("spawn")
            .join()
            .expect("prefault overflowed the stack");
        // glibc may hand the thread a cached stack up to 4 times the size asked for, so the bound
        // is the request, not 256 KiB.
        assert!(report.stack_prefaulted > 0);
        assert!(report.stack_prefaulted < 4 * 1024 * 1024);
        let failure = failure_of(&report, RtStep::StackPrefault).expect("stack prefault failure");
        assert!(failure.detail.contains("stack_size"));
    }

    #[test]
    fn full_rt_summary_lists_what_was_obtained() {
        let report = RtReport {
            cpu: Some(1),
            priority: Some(80),
            stack_prefaulted: 4096,
            memory_locked: true,
            failures: Vec::new(),
        };
        assert!(report.is_full_rt());
        assert_eq!(report.mode(), "realtime");
        assert_eq!(
            report.summary(),
            "realtime: pinned to CPU 1, SCHED_FIFO priority 80, 4096 bytes of stack prefaulted, \
             memory locked"
        );
    }

    #[test]
    fn failure_display_carries_the_errno_name_and_description() {
        let refused = failure(RtStep::Scheduler, Some(Errno::EPERM), "why".to_owned());
        assert_eq!(
            refused.to_string(),
            "SCHED_FIFO failed (EPERM: Operation not permitted): why"
        );
        let skipped = failure(RtStep::MemoryLock, None, "why".to_owned());
        assert_eq!(skipped.to_string(), "memory lock failed: why");
    }

    #[test]
    fn cap_eff_is_parsed_from_proc_status_and_bits_are_named() {
        let status = "Name:\tussd\nCapPrm:\t0000000000000000\nCapEff:\t0000000000804000\n";
        let caps = parse_cap_eff(status);
        assert_eq!(caps, Some((1 << CAP_SYS_NICE) | (1 << CAP_IPC_LOCK)));
        assert!(has_cap(caps, CAP_SYS_NICE));
        assert!(has_cap(caps, CAP_IPC_LOCK));
        assert!(!has_cap(Some(1 << CAP_IPC_LOCK), CAP_SYS_NICE));
        assert!(!has_cap(None, CAP_SYS_NICE));
        assert_eq!(parse_cap_eff("Name:\tussd\n"), None);
        assert_eq!(
            cap_text(Some(0), CAP_SYS_NICE, "CAP_SYS_NICE"),
            "CAP_SYS_NICE not in effective set (CapEff=0000000000000000)"
        );
    }
}
