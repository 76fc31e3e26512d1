//! Real CPU work: spin on arithmetic until the calling thread has consumed
//! a given amount of its own CPU time (`CLOCK_THREAD_CPUTIME_ID`). Under
//! cgroup throttling or contention the wall time stretches while the CPU
//! cost per message stays what was asked — like real computation.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// CPU time consumed by the calling thread so far.
pub fn thread_cpu_time() -> Duration {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec for the duration of the
    // call, and CLOCK_THREAD_CPUTIME_ID is always supported on Linux.
    #[allow(unsafe_code)]
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &raw mut ts) };
    if rc != 0 {
        return Duration::ZERO;
    }
    Duration::new(
        u64::try_from(ts.tv_sec).unwrap_or(0),
        u32::try_from(ts.tv_nsec).unwrap_or(0),
    )
}

/// About 20–50 µs of integer work between clock reads.
fn chunk(state: &mut u64) {
    let mut x = *state;
    for _ in 0..4096 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x = x.wrapping_mul(0x2545_f491_4f6c_dd1d);
    }
    *state = std::hint::black_box(x);
}

/// Burns `cost` of this thread's CPU time (returns early once `stop` is
/// set) and returns the CPU time actually consumed.
pub fn burn(cost: Duration, stop: &AtomicBool) -> Duration {
    let start = thread_cpu_time();
    if cost.is_zero() {
        return Duration::ZERO;
    }
    let mut state = 0x9e37_79b9_7f4a_7c15_u64 ^ u64::from(start.subsec_nanos());
    loop {
        chunk(&mut state);
        let used = thread_cpu_time().saturating_sub(start);
        if used >= cost || stop.load(Ordering::Relaxed) {
            return used;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Instant;

    #[test]
    fn burns_the_requested_cpu_time() {
        let stop = AtomicBool::new(false);
        let t0 = thread_cpu_time();
        let wall = Instant::now();
        let used = burn(Duration::from_millis(30), &stop);
        let cpu = thread_cpu_time() - t0;
        assert!(used >= Duration::from_millis(30), "{used:?}");
        // Overshoot is one work chunk plus a clock read.
        assert!(cpu < Duration::from_millis(35), "{cpu:?}");
        // Wall time is at least the CPU time (it is real work, not a sleep).
        assert!(wall.elapsed() >= Duration::from_millis(30));
    }

    #[test]
    fn sleeping_is_not_cpu_time_and_stop_cuts_short() {
        let t0 = thread_cpu_time();
        std::thread::sleep(Duration::from_millis(30));
        assert!(thread_cpu_time() - t0 < Duration::from_millis(10));
        let stop = AtomicBool::new(true);
        assert!(burn(Duration::from_secs(5), &stop) < Duration::from_millis(50));
    }
}
