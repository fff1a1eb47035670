//! Real-time setup of the calling thread: CPU affinity, scheduling policy, locked memory and a
//! prefaulted stack, so the cyclic loop takes no page fault and is not preempted by ordinary
//! threads.

use std::io;

use crate::plan::{Policy, RtPlan};

/// Bytes of stack touched before the loop starts (the RT thread is spawned with more).
pub const PREFAULT_STACK: usize = 256 * 1024;
/// Stack size the RT thread is spawned with.
pub const RT_STACK: usize = 1024 * 1024;

/// Apply `rt` to the calling thread. The error says what failed and why.
pub fn apply(rt: &RtPlan, cycle_ns: u64) -> Result<(), String> {
    if let Some(cpu) = rt.cpu {
        // SAFETY: the cpu_set_t is a plain bitmap initialised by CPU_ZERO.
        let r = unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_ZERO(&mut set);
            if cpu >= libc::CPU_SETSIZE as usize {
                return Err(format!("rt.cpu = {cpu} is not a valid CPU number"));
            }
            libc::CPU_SET(cpu, &mut set);
            libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set)
        };
        if r != 0 {
            return Err(format!(
                "cannot pin the real-time thread to CPU {cpu}: {}",
                io::Error::last_os_error()
            ));
        }
    }
    if rt.lock_memory {
        // SAFETY: plain syscall.
        if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } != 0 {
            return Err(format!(
                "cannot lock memory (mlockall; needs root, CAP_IPC_LOCK or a large enough \
                 RLIMIT_MEMLOCK): {}",
                io::Error::last_os_error()
            ));
        }
    }
    match rt.policy {
        Policy::Other => {}
        Policy::Fifo => {
            let param = libc::sched_param {
                sched_priority: rt.priority,
            };
            // SAFETY: valid sched_param for the calling thread.
            if unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) } != 0 {
                return Err(format!(
                    "cannot set SCHED_FIFO priority {} (needs root, CAP_SYS_NICE or an rtprio \
                     limit): {}",
                    rt.priority,
                    io::Error::last_os_error()
                ));
            }
        }
        Policy::Deadline => set_deadline(rt.runtime_ns, cycle_ns).map_err(|e| {
            let hint = if rt.cpu.is_some() {
                " (SCHED_DEADLINE refuses a thread pinned to a subset of CPUs: set rt.cpu to \
                 None or use an exclusive cpuset)"
            } else {
                ""
            };
            format!(
                "cannot set SCHED_DEADLINE runtime {} ns, deadline = period = {cycle_ns} ns: \
                 {e}{hint}",
                rt.runtime_ns
            )
        })?,
    }
    prefault_stack();
    Ok(())
}

/// `struct sched_attr` of sched_setattr(2) (not in the libc crate).
#[repr(C)]
struct SchedAttr {
    size: u32,
    sched_policy: u32,
    sched_flags: u64,
    sched_nice: i32,
    sched_priority: u32,
    sched_runtime: u64,
    sched_deadline: u64,
    sched_period: u64,
}

const SCHED_DEADLINE: u32 = 6;

fn set_deadline(runtime_ns: u64, period_ns: u64) -> io::Result<()> {
    let attr = SchedAttr {
        size: std::mem::size_of::<SchedAttr>() as u32,
        sched_policy: SCHED_DEADLINE,
        sched_flags: 0,
        sched_nice: 0,
        sched_priority: 0,
        sched_runtime: runtime_ns,
        sched_deadline: period_ns,
        sched_period: period_ns,
    };
    // SAFETY: `attr` is a valid sched_attr of the size it declares; pid 0 = calling thread.
    let r = unsafe { libc::syscall(libc::SYS_sched_setattr, 0, &attr as *const SchedAttr, 0) };
    if r != 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

/// Touch the stack the loop will use so its pages are mapped (and locked) before the first cycle.
#[inline(never)]
fn prefault_stack() {
    let mut block = [0u8; PREFAULT_STACK];
    for i in (0..PREFAULT_STACK).step_by(4096) {
        // SAFETY: in-bounds write; volatile so the compiler keeps it.
        unsafe { std::ptr::write_volatile(block.as_mut_ptr().add(i), 1) };
    }
    std::hint::black_box(&block);
}
