//! A mutex with priority inheritance: a PI futex (futex(2), FUTEX_LOCK_PI/FUTEX_UNLOCK_PI).
//!
//! The frame thread runs SCHED_FIFO; the firmware workers run as ordinary threads. When the
//! frame thread needs a slave a worker holds, the kernel lends the worker the frame thread's
//! priority until it lets go, so the frame waits for one device step at most — never for
//! whatever else the machine is running (with `std::sync::Mutex` a preempted worker would hold
//! the frame up for as long as the scheduler leaves it out). Uncontended, locking is one atomic
//! compare-and-swap in user space, as with the standard mutex.

use std::cell::UnsafeCell;
use std::marker::PhantomData;
use std::ops::{Deref, DerefMut};
use std::sync::atomic::{AtomicU32, Ordering};

// The futex operations of futex(2) for PI locks (linux/futex.h).
const FUTEX_LOCK_PI: libc::c_int = 6;
const FUTEX_UNLOCK_PI: libc::c_int = 7;
const FUTEX_PRIVATE_FLAG: libc::c_int = 128;

/// This thread's kernel thread id: the value a PI futex holds while this thread owns it.
fn tid() -> u32 {
    thread_local! {
        // SAFETY: gettid has no preconditions.
        static TID: u32 = unsafe { libc::gettid() } as u32;
    }
    TID.with(|t| *t)
}

fn futex(word: &AtomicU32, op: libc::c_int) -> libc::c_long {
    // SAFETY: a futex operation on a word we own for the mutex's lifetime; the PI operations
    // take no timeout (null) and ignore the other arguments.
    unsafe {
        libc::syscall(
            libc::SYS_futex,
            word.as_ptr(),
            op | FUTEX_PRIVATE_FLAG,
            0,
            std::ptr::null::<libc::timespec>(),
            std::ptr::null::<u32>(),
            0,
        )
    }
}

/// The lock word (0: free, else the owner's thread id, plus the kernel's waiters bit) lives
/// next to the value, so locking touches the value's own cache lines only.
pub struct PiMutex<T> {
    word: AtomicU32,
    data: UnsafeCell<T>,
}

// SAFETY: access to `data` is serialised by the lock, as for std::sync::Mutex.
unsafe impl<T: Send> Send for PiMutex<T> {}
// SAFETY: as above: `&PiMutex<T>` only hands out `T` under the lock.
unsafe impl<T: Send> Sync for PiMutex<T> {}

impl<T> PiMutex<T> {
    /// A mutex holding `value`.
    pub fn new(value: T) -> PiMutex<T> {
        PiMutex {
            word: AtomicU32::new(0),
            data: UnsafeCell::new(value),
        }
    }

    /// Wait for the lock (the kernel queues waiters by priority and lends the owner the
    /// highest waiter's). A thread that panicked while holding it has released it when its
    /// guard was dropped; the value is whatever it left (there is no poisoning).
    pub fn lock(&self) -> PiGuard<'_, T> {
        let me = tid();
        if self
            .word
            .compare_exchange(0, me, Ordering::Acquire, Ordering::Relaxed)
            .is_err()
        {
            loop {
                if futex(&self.word, FUTEX_LOCK_PI) == 0 {
                    break;
                }
                let err = std::io::Error::last_os_error();
                assert_eq!(
                    err.raw_os_error(),
                    Some(libc::EINTR),
                    "FUTEX_LOCK_PI failed: {err}"
                );
            }
        }
        PiGuard {
            mutex: self,
            _thread: PhantomData,
        }
    }
}

/// The lock held on a [`PiMutex`]: derefs to the value and unlocks when dropped.
pub struct PiGuard<'a, T> {
    mutex: &'a PiMutex<T>,
    // Not Send: a PI futex is released by the thread that holds it.
    _thread: PhantomData<*const ()>,
}

impl<T> Deref for PiGuard<'_, T> {
    type Target = T;

    fn deref(&self) -> &T {
        // SAFETY: the guard holds the lock.
        unsafe { &*self.mutex.data.get() }
    }
}

impl<T> DerefMut for PiGuard<'_, T> {
    fn deref_mut(&mut self) -> &mut T {
        // SAFETY: the guard holds the lock, and `&mut self` makes this the only reference.
        unsafe { &mut *self.mutex.data.get() }
    }
}

impl<T> Drop for PiGuard<'_, T> {
    fn drop(&mut self) {
        let word = &self.mutex.word;
        // Waiters (the kernel set its bit): the kernel hands the lock over.
        if word
            .compare_exchange(tid(), 0, Ordering::Release, Ordering::Relaxed)
            .is_err()
        {
            futex(word, FUTEX_UNLOCK_PI);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn threads_take_turns() {
        let m = Arc::new(PiMutex::new(0u64));
        let handles: Vec<_> = (0..4)
            .map(|_| {
                let m = m.clone();
                std::thread::spawn(move || {
                    for _ in 0..10_000 {
                        *m.lock() += 1;
                    }
                })
            })
            .collect();
        for h in handles {
            h.join().unwrap();
        }
        assert_eq!(*m.lock(), 40_000);
    }
}
