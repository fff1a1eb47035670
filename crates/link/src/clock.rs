//! CLOCK_MONOTONIC in nanoseconds and absolute-time sleeping: the time base links stamp frames
//! in and the engine's cyclic loop sleeps on.

/// Nanoseconds of CLOCK_MONOTONIC (a vDSO call, no syscall).
pub fn now_ns() -> i64 {
    clock_ns(libc::CLOCK_MONOTONIC)
}

/// Nanoseconds of CLOCK_REALTIME: kernel receive timestamps come in this clock.
pub fn realtime_ns() -> i64 {
    clock_ns(libc::CLOCK_REALTIME)
}

fn clock_ns(clock: libc::clockid_t) -> i64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid out-pointer; the clocks used here always exist on Linux.
    unsafe { libc::clock_gettime(clock, &mut ts) };
    ts.tv_sec * 1_000_000_000 + ts.tv_nsec
}

pub(crate) fn timespec(ns: i64) -> libc::timespec {
    libc::timespec {
        tv_sec: (ns / 1_000_000_000) as _,
        tv_nsec: (ns % 1_000_000_000) as _,
    }
}

/// Sleep until the absolute CLOCK_MONOTONIC time `t_ns` (restarting after signals).
pub fn sleep_until(t_ns: i64) {
    let ts = timespec(t_ns);
    loop {
        // SAFETY: `ts` is a valid timespec; the remainder pointer may be null for TIMER_ABSTIME.
        let r = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if r != libc::EINTR {
            return;
        }
    }
}
