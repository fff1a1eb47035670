//! A mutex with priority inheritance (a glibc `pthread_mutex_t` with `PTHREAD_PRIO_INHERIT`).
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

extern "C" {
    // glibc; not bound by the libc crate for Linux.
    fn pthread_mutexattr_setprotocol(
        attr: *mut libc::pthread_mutexattr_t,
        protocol: libc::c_int,
    ) -> libc::c_int;
}

/// `PTHREAD_PRIO_INHERIT` (glibc, pthread.h).
const PTHREAD_PRIO_INHERIT: libc::c_int = 1;

pub struct PiMutex<T> {
    // Boxed: a pthread mutex must not move once initialised.
    raw: Box<UnsafeCell<libc::pthread_mutex_t>>,
    data: UnsafeCell<T>,
}

// SAFETY: access to `data` is serialised by the mutex, as for std::sync::Mutex.
unsafe impl<T: Send> Send for PiMutex<T> {}
// SAFETY: as above: `&PiMutex<T>` only hands out `T` under the lock.
unsafe impl<T: Send> Sync for PiMutex<T> {}

impl<T> PiMutex<T> {
    pub fn new(value: T) -> PiMutex<T> {
        let raw = Box::new(UnsafeCell::new(libc::PTHREAD_MUTEX_INITIALIZER));
        // SAFETY: attribute and mutex are initialised in place and the attribute destroyed
        // after use; the calls only fail on invalid arguments (then the mutex stays a plain
        // default mutex, still correct, just without inheritance).
        unsafe {
            let mut attr: libc::pthread_mutexattr_t = std::mem::zeroed();
            if libc::pthread_mutexattr_init(&mut attr) == 0 {
                pthread_mutexattr_setprotocol(&mut attr, PTHREAD_PRIO_INHERIT);
                libc::pthread_mutex_init(raw.get(), &attr);
                libc::pthread_mutexattr_destroy(&mut attr);
            }
        }
        PiMutex {
            raw,
            data: UnsafeCell::new(value),
        }
    }

    /// Wait for the lock. A thread that panicked while holding it has released it when its
    /// guard was dropped; the value is whatever it left (there is no poisoning).
    pub fn lock(&self) -> PiGuard<'_, T> {
        // SAFETY: the mutex was initialised in `new` and lives as long as `self`.
        let r = unsafe { libc::pthread_mutex_lock(self.raw.get()) };
        assert_eq!(r, 0, "pthread_mutex_lock failed ({r})");
        PiGuard {
            mutex: self,
            _thread: PhantomData,
        }
    }
}

impl<T> Drop for PiMutex<T> {
    fn drop(&mut self) {
        // SAFETY: nobody holds the lock (we own the mutex exclusively).
        unsafe { libc::pthread_mutex_destroy(self.raw.get()) };
    }
}

pub struct PiGuard<'a, T> {
    mutex: &'a PiMutex<T>,
    // Not Send: a pthread mutex is unlocked by the thread that locked it.
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
        // SAFETY: this thread locked the mutex in `lock`.
        unsafe { libc::pthread_mutex_unlock(self.mutex.raw.get()) };
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
