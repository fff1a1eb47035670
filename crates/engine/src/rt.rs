//! Real-time setup of the calling thread: CPU affinity, scheduling policy, locked memory and a
//! prefaulted stack, so the cyclic loop takes no page fault and is not preempted by ordinary
//! threads.

use std::io;

use crate::plan::{Policy, RtPlan};

/// Bytes of stack touched before the loop starts (the RT thread is spawned with more).
pub const PREFAULT_STACK: usize = 256 * 1024;
/// Stack size the RT thread is spawned with.
pub const RT_STACK: usize = 1024 * 1024;

/// Why the real-time setup was refused: what failed, in words, and the OS error code.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SetupError {
    /// What failed and the remedy.
    pub message: String,
    /// The errno of the refused call (None for a plan the OS was not asked about).
    pub errno: Option<i32>,
}

impl SetupError {
    fn os(message: String, e: &io::Error) -> SetupError {
        SetupError {
            message,
            errno: e.raw_os_error(),
        }
    }
}

/// Apply `rt` to the calling thread. The error says what failed and why.
pub fn apply(rt: &RtPlan, cycle_ns: u64) -> Result<(), SetupError> {
    if let Some(cpu) = rt.cpu {
        // SAFETY: the cpu_set_t is a plain bitmap initialised by CPU_ZERO.
        let r = unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_ZERO(&mut set);
            if cpu >= libc::CPU_SETSIZE as usize {
                return Err(SetupError {
                    message: format!("rt.cpu = {cpu} is not a valid CPU number"),
                    errno: None,
                });
            }
            libc::CPU_SET(cpu, &mut set);
            libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set)
        };
        if r != 0 {
            let e = io::Error::last_os_error();
            return Err(SetupError::os(
                format!("cannot pin the real-time thread to CPU {cpu}: {e}"),
                &e,
            ));
        }
    }
    if rt.lock_memory {
        // SAFETY: plain syscall.
        if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } != 0 {
            let e = io::Error::last_os_error();
            return Err(SetupError::os(
                format!(
                    "cannot lock memory (mlockall; needs root, CAP_IPC_LOCK or a large enough \
                     RLIMIT_MEMLOCK): {e}"
                ),
                &e,
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
                let e = io::Error::last_os_error();
                return Err(SetupError::os(
                    format!(
                        "cannot set SCHED_FIFO priority {} (needs root, CAP_SYS_NICE or an \
                         rtprio limit): {e}",
                        rt.priority
                    ),
                    &e,
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
            SetupError::os(
                format!(
                    "cannot set SCHED_DEADLINE runtime {} ns, deadline = period = {cycle_ns} \
                     ns: {e}{hint}",
                    rt.runtime_ns
                ),
                &e,
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
