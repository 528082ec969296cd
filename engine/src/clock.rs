//! Time as the engine sees it. The engine reads the time and sleeps only through [`Clock`], so its
//! timing rules (start pause, response timeout, residual time, retries, job timeouts) run on a
//! [`VirtualClock`] in tests, deterministically, and on the [`MonotonicClock`] in `ussd`.

use core::time::Duration;
use nix::sys::time::TimeSpec;
use nix::time::{ClockId, ClockNanosleepFlags, clock_gettime, clock_nanosleep};

/// A monotonic clock with an origin; times are durations since that origin.
pub trait Clock {
    fn now(&self) -> Duration;
    /// Returns at `t` or as soon after as the clock allows; at once when `t` has passed.
    fn sleep_until(&mut self, t: Duration);

    /// Like [`Clock::sleep_until`], but as close to `t` as the clock can manage, at some CPU
    /// cost: for the start pause before a request, where every microsecond of lateness is a
    /// microsecond lost on the wire.
    fn sleep_until_precise(&mut self, t: Duration) {
        self.sleep_until(t);
    }

    /// This clock's zero on `CLOCK_MONOTONIC` (zero for a clock that is not on it): what makes
    /// a time of this clock a time stamp other processes read.
    fn monotonic_origin(&self) -> Duration {
        Duration::ZERO
    }
}

/// How long before a precise deadline the monotonic clock stops sleeping and spins: a wake-up
/// from `clock_nanosleep` is typically 5-50 us late even for a `SCHED_FIFO` thread.
pub const SPIN_BEFORE_DEADLINE: Duration = Duration::from_micros(60);

/// `CLOCK_MONOTONIC` with absolute sleeps (`clock_nanosleep` with `TIMER_ABSTIME`), so a late
/// wake-up never accumulates into the next deadline.
#[derive(Debug, Clone, Copy)]
pub struct MonotonicClock {
    origin: Duration,
    /// How long before a precise deadline [`Clock::sleep_until_precise`] stops sleeping and
    /// spins ([`SPIN_BEFORE_DEADLINE`] unless set).
    spin: Duration,
}

fn monotonic() -> Duration {
    // CLOCK_MONOTONIC cannot fail on Linux with a valid pointer; zero is a harmless fallback.
    clock_gettime(ClockId::CLOCK_MONOTONIC).map_or(Duration::ZERO, Duration::from)
}

impl MonotonicClock {
    /// A clock whose origin is now.
    pub fn new() -> Self {
        Self {
            origin: monotonic(),
            spin: SPIN_BEFORE_DEADLINE,
        }
    }

    /// This clock, spinning `spin` before a precise deadline instead of
    /// [`SPIN_BEFORE_DEADLINE`] (zero: no spin, a plain sleep).
    #[must_use]
    pub const fn with_spin(self, spin: Duration) -> Self {
        Self { spin, ..self }
    }

    /// The origin on `CLOCK_MONOTONIC`: add it to a time of this clock for an absolute stamp.
    pub const fn origin(&self) -> Duration {
        self.origin
    }

    /// A clock sharing another's origin (threads of one bus agree on times).
    pub const fn with_origin_of(other: &Self) -> Self {
        Self {
            origin: other.origin,
            spin: other.spin,
        }
    }
}

impl Default for MonotonicClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for MonotonicClock {
    fn now(&self) -> Duration {
        monotonic().saturating_sub(self.origin)
    }

    fn monotonic_origin(&self) -> Duration {
        self.origin
    }

    fn sleep_until(&mut self, t: Duration) {
        let target = TimeSpec::from(self.origin + t);
        // EINTR: a signal arrived; sleep on to the same absolute time.
        while let Err(nix::errno::Errno::EINTR) = clock_nanosleep(
            ClockId::CLOCK_MONOTONIC,
            ClockNanosleepFlags::TIMER_ABSTIME,
            &target,
        ) {}
    }

    /// Sleeps until `spin` before `t`, then spins on the clock: a wake-up is late by the
    /// kernel's timer latency, a spin by one `clock_gettime` (tens of ns, in the vDSO).
    fn sleep_until_precise(&mut self, t: Duration) {
        if let Some(wake) = t.checked_sub(self.spin)
            && wake > self.now()
        {
            self.sleep_until(wake);
        }
        while self.now() < t {
            core::hint::spin_loop();
        }
    }
}

/// A clock that only moves when the engine sleeps: tests of timing rules run instantly and
/// deterministically.
#[derive(Debug, Clone, Copy, Default)]
pub struct VirtualClock {
    now: Duration,
}

impl VirtualClock {
    pub const fn new() -> Self {
        Self {
            now: Duration::ZERO,
        }
    }

    /// Moves the clock forward (as time passing outside the engine would).
    pub fn advance(&mut self, by: Duration) {
        self.now += by;
    }
}

impl Clock for VirtualClock {
    fn now(&self) -> Duration {
        self.now
    }

    fn sleep_until(&mut self, t: Duration) {
        self.now = self.now.max(t);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn virtual_clock_moves_only_forward_when_sleeping() {
        let mut c = VirtualClock::new();
        c.sleep_until(Duration::from_millis(5));
        assert_eq!(c.now(), Duration::from_millis(5));
        c.sleep_until(Duration::from_millis(1));
        assert_eq!(c.now(), Duration::from_millis(5));
        c.advance(Duration::from_millis(1));
        assert_eq!(c.now(), Duration::from_millis(6));
    }

    #[test]
    fn monotonic_clock_sleeps_to_an_absolute_time() {
        let mut c = MonotonicClock::new();
        let target = c.now() + Duration::from_millis(3);
        c.sleep_until(target);
        assert!(c.now() >= target);
        let shared = MonotonicClock::with_origin_of(&c);
        assert!(shared.now() >= target);
        let precise = c.now() + Duration::from_micros(500);
        c.sleep_until_precise(precise);
        assert!(c.now() >= precise);
    }

    #[test]
    fn the_precise_wait_never_returns_early_with_or_without_its_spin() {
        for spin in [
            Duration::ZERO,
            SPIN_BEFORE_DEADLINE,
            Duration::from_millis(5),
        ] {
            let mut c = MonotonicClock::new().with_spin(spin);
            for wait_us in [0, 10, 100, 1000] {
                let target = c.now() + Duration::from_micros(wait_us);
                c.sleep_until_precise(target);
                assert!(c.now() >= target, "spin {spin:?}, wait {wait_us} us");
            }
            // A deadline already past returns at once (no sleep, no spin).
            let past = c.now().saturating_sub(Duration::from_millis(1));
            c.sleep_until_precise(past);
        }
    }
}
