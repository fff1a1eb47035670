//! Runs a `Network` on a network interface: an `AF_PACKET` raw socket bound to EtherType
//! 0x88A4, a background thread that receives a frame, processes it through the line of slaves
//! and sends the answer back, and polls the slaves every millisecond when no frame arrives so
//! device models and watchdogs keep running without traffic.

use std::ffi::CString;
use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use ether_ros_wire as wire;

use crate::network::{monotonic_ns, Network};

/// Receive timeout when the line is idle (µs).
const IDLE_POLL_US: libc::suseconds_t = 1_000;
/// Real-time priority the frame thread asks for (ignored when not permitted).
const RT_PRIORITY: i32 = 70;
/// Receive buffer size (largest Ethernet frame without FCS, rounded up).
const FRAME_BUF: usize = 1536;
/// Answers the `delay` fault can hold back at once.
const DELAY_QUEUE: usize = 256;

struct Socket(libc::c_int);

impl Drop for Socket {
    fn drop(&mut self) {
        // SAFETY: we own the descriptor.
        unsafe { libc::close(self.0) };
    }
}

fn open_socket(ifname: &str) -> io::Result<Socket> {
    let name = CString::new(ifname)
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "interface name contains NUL"))?;
    // SAFETY: plain libc calls with valid arguments; every result is checked.
    unsafe {
        let ifindex = libc::if_nametoindex(name.as_ptr());
        if ifindex == 0 {
            return Err(io::Error::new(
                io::ErrorKind::NotFound,
                format!("no network interface named '{ifname}'"),
            ));
        }
        // Protocol 0 receives nothing until bind() names the interface and the EtherType;
        // opening with the EtherType directly would queue EtherCAT frames from every interface
        // (e.g. other buses on the same host) in the window before bind().
        let fd = libc::socket(libc::AF_PACKET, libc::SOCK_RAW, 0);
        if fd < 0 {
            return Err(io::Error::last_os_error());
        }
        let sock = Socket(fd);
        let mut sll: libc::sockaddr_ll = std::mem::zeroed();
        sll.sll_family = libc::AF_PACKET as u16;
        sll.sll_protocol = wire::ETHERTYPE.to_be();
        sll.sll_ifindex = ifindex as i32;
        let r = libc::bind(
            fd,
            &sll as *const libc::sockaddr_ll as *const libc::sockaddr,
            std::mem::size_of::<libc::sockaddr_ll>() as u32,
        );
        if r < 0 {
            return Err(io::Error::last_os_error());
        }
        // Promiscuous, so frames addressed to any MAC reach us (masters use broadcast anyway).
        let mut mreq: libc::packet_mreq = std::mem::zeroed();
        mreq.mr_ifindex = ifindex as i32;
        mreq.mr_type = libc::PACKET_MR_PROMISC as u16;
        libc::setsockopt(
            fd,
            libc::SOL_PACKET,
            libc::PACKET_ADD_MEMBERSHIP,
            &mreq as *const libc::packet_mreq as *const libc::c_void,
            std::mem::size_of::<libc::packet_mreq>() as u32,
        );
        Ok(sock)
    }
}

fn try_realtime() {
    // SAFETY: best-effort scheduling and memory locking; failures are ignored on purpose.
    unsafe {
        let param = libc::sched_param {
            sched_priority: RT_PRIORITY,
        };
        libc::sched_setscheduler(0, libc::SCHED_FIFO, &param);
        libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE);
    }
}

/// A running frame thread.
pub struct Runner {
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
    pub interface: String,
}

impl Runner {
    /// Open the socket (errors are reported here) and start the thread.
    pub fn start(net: Arc<Mutex<Network>>, ifname: &str) -> io::Result<Runner> {
        let sock = open_socket(ifname)?;
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let handle = std::thread::Builder::new()
            .name("ether-ros-sim".into())
            .spawn(move || frame_loop(sock, net, stop2))?;
        Ok(Runner {
            stop,
            handle: Some(handle),
            interface: ifname.to_string(),
        })
    }

    pub fn stop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }

    pub fn is_running(&self) -> bool {
        self.handle.as_ref().is_some_and(|h| !h.is_finished())
    }
}

impl Drop for Runner {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Answers held back by the `delay` fault, sent when due. Preallocated so the frame path
/// never allocates; when full, further delayed answers are dropped (and counted).
struct DelayQueue {
    frames: Vec<[u8; FRAME_BUF]>,
    lens: Vec<usize>,
    due: Vec<u64>,
    head: usize,
    count: usize,
}

impl DelayQueue {
    fn new() -> Self {
        DelayQueue {
            frames: vec![[0u8; FRAME_BUF]; DELAY_QUEUE],
            lens: vec![0; DELAY_QUEUE],
            due: vec![0; DELAY_QUEUE],
            head: 0,
            count: 0,
        }
    }

    fn push(&mut self, frame: &[u8], due: u64) -> bool {
        if self.count == DELAY_QUEUE || frame.len() > FRAME_BUF {
            return false;
        }
        let i = (self.head + self.count) % DELAY_QUEUE;
        self.frames[i][..frame.len()].copy_from_slice(frame);
        self.lens[i] = frame.len();
        self.due[i] = due;
        self.count += 1;
        true
    }

    fn next_due(&self) -> Option<u64> {
        (self.count > 0).then(|| self.due[self.head])
    }

    /// Send every answer due by `now`.
    fn send_due(&mut self, fd: libc::c_int, now: u64) -> u64 {
        let mut errors = 0;
        while self.count > 0 && self.due[self.head] <= now {
            let f = &self.frames[self.head][..self.lens[self.head]];
            // SAFETY: send a buffer we own on the bound socket.
            let sent = unsafe { libc::send(fd, f.as_ptr() as *const libc::c_void, f.len(), 0) };
            if sent < 0 {
                errors += 1;
            }
            self.head = (self.head + 1) % DELAY_QUEUE;
            self.count -= 1;
        }
        errors
    }
}

/// Wait until the socket is readable or `timeout_ns` passed (ns resolution, unlike poll()).
fn wait_readable(fd: libc::c_int, timeout_ns: u64) -> bool {
    let mut pfd = libc::pollfd {
        fd,
        events: libc::POLLIN,
        revents: 0,
    };
    let ts = libc::timespec {
        tv_sec: (timeout_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (timeout_ns % 1_000_000_000) as libc::c_long,
    };
    // SAFETY: one valid pollfd and a valid timeout.
    unsafe { libc::ppoll(&mut pfd, 1, &ts, std::ptr::null()) > 0 }
}

fn frame_loop(sock: Socket, net: Arc<Mutex<Network>>, stop: Arc<AtomicBool>) {
    try_realtime();
    let fd = sock.0;
    // A blocking receive with a 1 ms timeout: one syscall per frame, and a poll of the
    // slaves whenever the line is idle.
    let tv = libc::timeval {
        tv_sec: 0,
        tv_usec: IDLE_POLL_US,
    };
    // SAFETY: setting a socket option from a valid timeval.
    unsafe {
        libc::setsockopt(
            fd,
            libc::SOL_SOCKET,
            libc::SO_RCVTIMEO,
            &tv as *const libc::timeval as *const libc::c_void,
            std::mem::size_of::<libc::timeval>() as u32,
        );
    }
    let mut buf = [0u8; FRAME_BUF];
    let mut delayed = DelayQueue::new();
    let mut last_poll = 0u64;
    while !stop.load(Ordering::Relaxed) {
        let mut flags = 0;
        if delayed.next_due().is_some() {
            // Delayed answers pending: wait only until the first is due.
            let now = monotonic_ns();
            let errors = delayed.send_due(fd, now);
            if errors > 0 {
                if let Ok(mut net) = net.lock() {
                    net.stats.send_errors += errors;
                }
            }
            if let Some(due) = delayed.next_due() {
                let wait = due
                    .saturating_sub(now)
                    .clamp(1_000, IDLE_POLL_US as u64 * 1_000);
                if !wait_readable(fd, wait) {
                    continue;
                }
                flags = libc::MSG_DONTWAIT;
            }
        }
        // SAFETY: recvfrom into our buffer and address struct, sizes passed correctly.
        let mut sll: libc::sockaddr_ll = unsafe { std::mem::zeroed() };
        let mut alen = std::mem::size_of::<libc::sockaddr_ll>() as libc::socklen_t;
        let n = unsafe {
            libc::recvfrom(
                fd,
                buf.as_mut_ptr() as *mut libc::c_void,
                buf.len(),
                flags,
                &mut sll as *mut libc::sockaddr_ll as *mut libc::sockaddr,
                &mut alen,
            )
        };
        if n <= 0 {
            if flags == 0 {
                if let Ok(mut net) = net.lock() {
                    net.poll();
                    last_poll = net.now();
                }
            }
            continue;
        }
        if sll.sll_pkttype == libc::PACKET_OUTGOING {
            continue;
        }
        let len = n as usize;
        let (answer, delay_us) = match net.lock() {
            Ok(mut net) => {
                let a = net.process_frame(&mut buf[..len]);
                // Frames advance the slaves they reach; a poll now and then keeps a slave
                // behind a broken link (or a dropped-frame burst) running too.
                let now = net.now();
                if now.saturating_sub(last_poll) > 1_000_000 {
                    net.poll();
                    last_poll = now;
                }
                (a, net.reply_delay_us())
            }
            Err(_) => return,
        };
        if !answer {
            continue;
        }
        // Once answers are held back, later ones queue behind them: the order is kept.
        if delay_us > 0 || delayed.next_due().is_some() {
            let due = monotonic_ns() + delay_us * 1_000;
            if !delayed.push(&buf[..len], due) {
                if let Ok(mut net) = net.lock() {
                    net.stats.frames_dropped += 1;
                }
            }
            continue;
        }
        // SAFETY: send our buffer on the bound socket.
        let sent = unsafe { libc::send(fd, buf.as_ptr() as *const libc::c_void, len, 0) };
        if sent < 0 {
            if let Ok(mut net) = net.lock() {
                net.stats.send_errors += 1;
            }
        }
    }
}
