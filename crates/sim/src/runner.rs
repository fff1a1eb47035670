//! Runs a `Network` on a network interface: an `AF_PACKET` raw socket bound to EtherType
//! 0x88A4 (or the engine's AF_XDP link, so the simulator is never the slower side of an xdp
//! master), a background thread that receives a frame, processes it through the line of slaves
//! and sends the answer back, and polls the slaves every millisecond when no frame arrives so
//! device models and watchdogs keep running without traffic.

use std::ffi::CString;
use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use ether_ros_engine::{Link, LinkKind, LinkOptions, XdpLink};
use ether_ros_protocol as wire;

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

/// Where the frame loop gets frames and puts answers.
trait FrameIo: Send {
    /// Wait up to `timeout_ns` for a frame; its length, or None when none came.
    fn recv(&mut self, buf: &mut [u8], timeout_ns: u64) -> Option<usize>;
    /// Send one frame; false when the kernel refused it.
    fn send(&mut self, frame: &[u8]) -> bool;
}

impl FrameIo for Socket {
    fn recv(&mut self, buf: &mut [u8], timeout_ns: u64) -> Option<usize> {
        // An idle wait is one blocking receive (SO_RCVTIMEO is the idle poll time): one
        // syscall per frame. A shorter wait (delayed answers due) polls first.
        let flags = if timeout_ns >= IDLE_POLL_US as u64 * 1_000 {
            0
        } else if wait_readable(self.0, timeout_ns) {
            libc::MSG_DONTWAIT
        } else {
            return None;
        };
        loop {
            // SAFETY: recvfrom into our buffer and address struct, sizes passed correctly.
            let mut sll: libc::sockaddr_ll = unsafe { std::mem::zeroed() };
            let mut alen = std::mem::size_of::<libc::sockaddr_ll>() as libc::socklen_t;
            let n = unsafe {
                libc::recvfrom(
                    self.0,
                    buf.as_mut_ptr() as *mut libc::c_void,
                    buf.len(),
                    flags,
                    &mut sll as *mut libc::sockaddr_ll as *mut libc::sockaddr,
                    &mut alen,
                )
            };
            if n <= 0 {
                return None;
            }
            // Our own answers come back to packet sockets as outgoing frames: not for us.
            if sll.sll_pkttype != libc::PACKET_OUTGOING {
                return Some(n as usize);
            }
        }
    }

    fn send(&mut self, frame: &[u8]) -> bool {
        // SAFETY: send a buffer we own on the bound socket.
        unsafe {
            libc::send(
                self.0,
                frame.as_ptr() as *const libc::c_void,
                frame.len(),
                0,
            ) >= 0
        }
    }
}

impl FrameIo for XdpLink {
    fn recv(&mut self, buf: &mut [u8], timeout_ns: u64) -> Option<usize> {
        let deadline = ether_ros_engine::now_ns() + timeout_ns as i64;
        Link::recv(self, buf, deadline)
            .ok()
            .flatten()
            .map(|r| r.len)
    }

    fn send(&mut self, frame: &[u8]) -> bool {
        Link::send(self, frame).is_ok()
    }
}

fn open_io(ifname: &str, kind: LinkKind) -> io::Result<Box<dyn FrameIo>> {
    match kind {
        LinkKind::Packet => {
            let sock = open_socket(ifname)?;
            set_idle_timeout(sock.0);
            Ok(Box::new(sock))
        }
        LinkKind::Xdp => Ok(Box::new(XdpLink::open(ifname, &LinkOptions::default())?)),
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
        Runner::start_on(net, ifname, LinkKind::Packet)
    }

    /// Like `start`, through the link `kind` (an AF_XDP socket for `LinkKind::Xdp`).
    pub fn start_on(net: Arc<Mutex<Network>>, ifname: &str, kind: LinkKind) -> io::Result<Runner> {
        let sock = open_io(ifname, kind)?;
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
    fn send_due(&mut self, io: &mut dyn FrameIo, now: u64) -> u64 {
        let mut errors = 0;
        while self.count > 0 && self.due[self.head] <= now {
            let f = &self.frames[self.head][..self.lens[self.head]];
            if !io.send(f) {
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

/// A blocking receive on the raw socket returns after the idle poll time at the latest.
fn set_idle_timeout(fd: libc::c_int) {
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
}

fn frame_loop(mut io: Box<dyn FrameIo>, net: Arc<Mutex<Network>>, stop: Arc<AtomicBool>) {
    try_realtime();
    let mut buf = [0u8; FRAME_BUF];
    let mut delayed = DelayQueue::new();
    let mut last_poll = 0u64;
    let idle_ns = IDLE_POLL_US as u64 * 1_000;
    while !stop.load(Ordering::Relaxed) {
        let mut wait = idle_ns;
        if delayed.next_due().is_some() {
            // Delayed answers pending: wait only until the first is due.
            let now = monotonic_ns();
            let errors = delayed.send_due(io.as_mut(), now);
            if errors > 0 {
                if let Ok(mut net) = net.lock() {
                    net.stats.send_errors += errors;
                }
            }
            if let Some(due) = delayed.next_due() {
                wait = due.saturating_sub(now).clamp(1_000, idle_ns - 1);
            }
        }
        let Some(len) = io.recv(&mut buf, wait) else {
            if wait == idle_ns {
                if let Ok(mut net) = net.lock() {
                    net.poll();
                    last_poll = net.now();
                }
            }
            continue;
        };
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
        if !io.send(&buf[..len]) {
            if let Ok(mut net) = net.lock() {
                net.stats.send_errors += 1;
            }
        }
    }
}
