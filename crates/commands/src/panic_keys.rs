//! The operator's panic key, in native code: a thread reads the terminal and sends the node's
//! `panic` request through rcl the moment a panic key arrives.
//!
//! The console (`ether_ros.console`) is a Python process whose ROS executor may be busy with
//! topic callbacks (process data, a flood of write results) and whose command worker may be in
//! the middle of anything: a panic key read by Python waits for the GIL, and on a loaded machine
//! for the GIL holder to get a CPU again. This thread needs neither. It owns the terminal:
//!
//! 1. it reads whatever the terminal has (one `read`, up to 64 KiB);
//! 2. if a panic key is in it ([`PANIC_KEYS`], also one split across two reads), it sends the
//!    `std_srvs/Trigger` request on the `panic` client Python created (`rcl_send_request`,
//!    after `rcl_service_server_is_available`) and records what it did ([`Sent`]);
//! 3. it passes the bytes on, unchanged, to a pipe the console's Python key reader reads (never
//!    blocking: bytes the reader does not take are dropped and counted).
//!
//! The answer comes back on the same client; Python takes it (its own wait set on the client,
//! no executor) and matches it to the sequence numbers recorded here.

use std::collections::VecDeque;
use std::ffi::c_void;
use std::os::fd::RawFd;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use ether_ros_engine::now_ns;

use crate::rcl::{self, Rcl};
use crate::receiver::set_priority;

/// The keys that panic: Ctrl-P, and F1 as xterm (SS3 P), VT220/rxvt (CSI 11 ~) and the Linux
/// console (CSI [ A) send it. The console's Python side takes this list from here.
pub const PANIC_KEYS: [&[u8]; 4] = [b"\x10", b"\x1bOP", b"\x1b[11~", b"\x1b[[A"];

/// The longest panic key: what a read may end with that the next one completes.
const LONGEST_KEY: usize = 5;
const READ_CHUNK: usize = 65536;

/// `std_srvs__srv__Trigger_Request`: an empty request, which C gives one byte.
#[repr(C)]
struct TriggerRequest {
    structure_needs_at_least_one_member: u8,
}

/// Whether `data` holds a panic key.
pub fn contains_panic_key(data: &[u8]) -> bool {
    PANIC_KEYS
        .iter()
        .any(|key| data.windows(key.len()).any(|w| w == *key))
}

/// What the thread did for one read that held a panic key.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Sent {
    /// The request went out with this sequence number; CLOCK_MONOTONIC times when the read
    /// that held the key returned and when the request was sent.
    Request {
        /// Sequence number rcl gave the request.
        sequence: i64,
        /// CLOCK_MONOTONIC ns when the read that held the key returned.
        read_ns: i64,
        /// CLOCK_MONOTONIC ns when the request was sent.
        at_ns: i64,
    },
    /// It could not be sent (the service is not available, an rcl error): why.
    Failed(String),
}

/// What Python hands over: the loaded libraries and the rcl node and `panic` client rclpy
/// created (addresses from their `handle.pointer`), the terminal to read (borrowed: never
/// closed here), the pipe to pass its bytes on to (owned: closed when the thread ends, so
/// the reader sees the end of the input) and the SCHED_FIFO priority to ask for (0: none).
#[derive(Debug, Clone)]
pub struct PanicKeyHandles {
    /// Path of the librcl rclpy loaded (the same copy, so handles are compatible).
    pub librcl: String,
    /// Path of the librcutils rclpy loaded.
    pub librcutils: String,
    /// Address of the rcl node (`handle.pointer`).
    pub node: usize,
    /// Address of the rcl client of the `panic` service.
    pub client: usize,
    /// The terminal to read keys from (borrowed, never closed here).
    pub terminal: RawFd,
    /// Write end of the pipe the other bytes are passed on to (owned, closed at the end).
    pub forward: RawFd,
    /// SCHED_FIFO priority for the thread (0: normal scheduling).
    pub priority: i32,
}

#[derive(Default)]
struct Shared {
    sent: Mutex<VecDeque<Sent>>,
    scheduling: Mutex<String>,
    running: AtomicBool,
    presses: AtomicU64,
    dropped: AtomicU64,
}

/// The terminal reader thread (see the module doc), from `start` until `stop`.
pub struct PanicKeys {
    shared: Arc<Shared>,
    wake: RawFd,
    thread: Mutex<Option<JoinHandle<()>>>,
}

impl PanicKeys {
    /// Load rcl and start the thread that reads the terminal and sends the panic request on a
    /// panic key; an error says which library or symbol could not be loaded.
    pub fn start(handles: PanicKeyHandles) -> Result<PanicKeys, String> {
        let rcl = Rcl::load(&handles.librcl, &handles.librcutils)?;
        let mut pipe = [0 as RawFd; 2];
        // SAFETY: pipe2 fills the two descriptors of a new pipe.
        if unsafe { libc::pipe2(pipe.as_mut_ptr(), libc::O_CLOEXEC) } != 0 {
            return Err(format!(
                "creating the wake-up pipe: {}",
                std::io::Error::last_os_error()
            ));
        }
        // SAFETY: fcntl on the descriptor Python handed over; only its O_NONBLOCK flag changes.
        unsafe {
            let flags = libc::fcntl(handles.forward, libc::F_GETFL);
            libc::fcntl(handles.forward, libc::F_SETFL, flags | libc::O_NONBLOCK);
        }
        let shared = Arc::new(Shared::default());
        shared.running.store(true, Ordering::SeqCst);
        let (thread_shared, wake_read) = (shared.clone(), pipe[0]);
        let thread = std::thread::Builder::new()
            .name("ether_ros-panic-keys".into())
            .spawn(move || {
                // Woken by a key while the machine is busy, it runs ahead of normal threads
                // (it sleeps in poll otherwise, and does little per read).
                *thread_shared
                    .scheduling
                    .lock()
                    .unwrap_or_else(|e| e.into_inner()) = set_priority(handles.priority);
                read_terminal(&rcl, &handles, wake_read, &thread_shared);
                // SAFETY: both descriptors belong to this thread from here on.
                unsafe {
                    libc::close(handles.forward);
                    libc::close(wake_read);
                }
                thread_shared.running.store(false, Ordering::SeqCst);
            })
            .map_err(|e| format!("starting the panic key thread: {e}"))?;
        Ok(PanicKeys {
            shared,
            wake: pipe[1],
            thread: Mutex::new(Some(thread)),
        })
    }

    /// What the thread did since the last call, oldest first.
    pub fn take_sent(&self) -> Vec<Sent> {
        let mut sent = self.shared.sent.lock().unwrap_or_else(|e| e.into_inner());
        sent.drain(..).collect()
    }

    /// Reads that held a panic key, since start.
    pub fn presses(&self) -> u64 {
        self.shared.presses.load(Ordering::SeqCst)
    }

    /// Bytes the Python reader did not take in time (dropped), since start.
    pub fn dropped(&self) -> u64 {
        self.shared.dropped.load(Ordering::SeqCst)
    }

    /// True while the thread runs (it ends with the terminal's input or on an error).
    pub fn is_running(&self) -> bool {
        self.shared.running.load(Ordering::SeqCst)
    }

    /// How the thread is scheduled ("SCHED_FIFO 50", or "normal: ..." saying why).
    pub fn scheduling(&self) -> String {
        self.shared
            .scheduling
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Stop and join the thread (idempotent).
    pub fn stop(&self) {
        let thread = self.thread.lock().unwrap_or_else(|e| e.into_inner()).take();
        if let Some(thread) = thread {
            // SAFETY: one byte to the wake-up pipe's write end, which this object owns.
            unsafe {
                libc::write(self.wake, b"x".as_ptr().cast(), 1);
            }
            let _ = thread.join();
            // SAFETY: closed once, after the thread is gone.
            unsafe {
                libc::close(self.wake);
            }
        }
    }
}

impl Drop for PanicKeys {
    fn drop(&mut self) {
        self.stop();
    }
}

fn read_terminal(rcl: &Rcl, handles: &PanicKeyHandles, wake: RawFd, shared: &Shared) {
    let mut buffer = vec![0u8; LONGEST_KEY + READ_CHUNK];
    let mut tail = 0usize; // bytes kept from the previous read, for a key split across reads
    loop {
        let mut fds = [
            libc::pollfd {
                fd: handles.terminal,
                events: libc::POLLIN,
                revents: 0,
            },
            libc::pollfd {
                fd: wake,
                events: libc::POLLIN,
                revents: 0,
            },
        ];
        // SAFETY: poll on two valid descriptors.
        let ready = unsafe { libc::poll(fds.as_mut_ptr(), 2, -1) };
        if ready < 0 {
            if std::io::Error::last_os_error().kind() == std::io::ErrorKind::Interrupted {
                continue;
            }
            return;
        }
        if fds[1].revents != 0 {
            return; // stop()
        }
        // SAFETY: read into the part of the buffer after the kept tail.
        let n = unsafe {
            libc::read(
                handles.terminal,
                buffer[tail..].as_mut_ptr().cast(),
                READ_CHUNK,
            )
        };
        if n < 0 {
            let error = std::io::Error::last_os_error();
            if matches!(
                error.kind(),
                std::io::ErrorKind::Interrupted | std::io::ErrorKind::WouldBlock
            ) {
                continue;
            }
            return; // EIO: the terminal hung up
        }
        if n == 0 {
            return; // end of input
        }
        let read_ns = now_ns();
        let (start, end) = (tail, tail + n as usize);
        let found = contains_panic_key(&buffer[..end]);
        if found {
            let sent = send_panic(rcl, handles, read_ns);
            shared.presses.fetch_add(1, Ordering::SeqCst);
            shared
                .sent
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .push_back(sent);
        }
        forward(handles.forward, &buffer[start..end], shared);
        // Keep the last bytes, which may begin a key the next read completes (forwarded
        // already: they are only looked at again). After a key acted on, nothing is kept, so
        // no part of it counts twice.
        tail = if found { 0 } else { end.min(LONGEST_KEY - 1) };
        buffer.copy_within(end - tail..end, 0);
    }
}

fn send_panic(rcl: &Rcl, handles: &PanicKeyHandles, read_ns: i64) -> Sent {
    let (node, client) = (
        handles.node as *const c_void,
        handles.client as *const c_void,
    );
    // SAFETY: the node and client are rclpy's, kept alive by Python while this thread runs.
    match unsafe { rcl::server_is_available(rcl, node, client) } {
        Ok(true) => {}
        Ok(false) => return Sent::Failed("the node's panic service is not available".into()),
        Err(e) => return Sent::Failed(e),
    }
    let request = TriggerRequest {
        structure_needs_at_least_one_member: 0,
    };
    // SAFETY: as above; the request is the C struct of std_srvs/Trigger's request.
    match unsafe { rcl::send_request(rcl, client, (&request as *const TriggerRequest).cast()) } {
        Ok(sequence) => Sent::Request {
            sequence,
            read_ns,
            at_ns: now_ns(),
        },
        Err(e) => Sent::Failed(e),
    }
}

fn forward(fd: RawFd, mut data: &[u8], shared: &Shared) {
    while !data.is_empty() {
        // SAFETY: write from a valid slice to the (non-blocking) pipe.
        let n = unsafe { libc::write(fd, data.as_ptr().cast(), data.len()) };
        if n < 0 {
            if std::io::Error::last_os_error().kind() == std::io::ErrorKind::Interrupted {
                continue;
            }
            // Full (the reader is not taking it) or closed: never wait for it.
            shared
                .dropped
                .fetch_add(data.len() as u64, Ordering::SeqCst);
            return;
        }
        data = &data[n as usize..];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_every_panic_key_anywhere() {
        for key in PANIC_KEYS {
            let mut data = b"set hind".to_vec();
            data.extend_from_slice(key);
            data.extend_from_slice(b"_leg");
            assert!(contains_panic_key(&data));
        }
        assert!(!contains_panic_key(b"set all b_ellipse100=4\r\x1b[A"));
        assert!(!contains_panic_key(b"\x1bO"));
    }
}
