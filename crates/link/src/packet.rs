//! The AF_PACKET links and the in-process link: the `Link` trait the engine drives, the
//! master's raw socket, the simulator's raw socket, and a direct call into an in-process
//! simulator.
//!
//! A link is owned by exactly one thread at a time (the caller of `transact` while the bus is
//! not cyclic, the real-time thread while it is), so its methods take `&mut self` and need no
//! locking.

use std::ffi::CString;
use std::io;

use crate::clock::{now_ns, realtime_ns, timespec};
use ether_ros_protocol::{ETHERTYPE, MAX_FRAME_LEN};

/// A frame that arrived: its length in the caller's buffer and when it arrived
/// (CLOCK_MONOTONIC ns; the kernel's receive timestamp when the link has one).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Received {
    /// Bytes of the frame in the caller's buffer.
    pub len: usize,
    /// When it arrived (CLOCK_MONOTONIC ns).
    pub rx_ns: i64,
}

/// Moves EtherCAT frames to the slaves and back.
pub trait Link: Send {
    /// Send one complete Ethernet frame.
    fn send(&mut self, frame: &[u8]) -> io::Result<()>;

    /// Receive one frame into `buf`, waiting at most until the absolute CLOCK_MONOTONIC time
    /// `deadline_ns` (a deadline in the past means: only what is already there). `Ok(None)`
    /// when nothing arrived in time. Frames this host sent itself are never returned.
    fn recv(&mut self, buf: &mut [u8], deadline_ns: i64) -> io::Result<Option<Received>>;

    /// What the link is attached to, for messages.
    fn describe(&self) -> String;
}

/// Which kind of link carries the frames on a network interface.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinkKind {
    /// An AF_PACKET raw socket: works on any interface, frames go through the kernel's stack.
    Packet,
    /// An AF_XDP socket fed by an XDP program: needs native XDP in the driver.
    Xdp,
}

impl std::str::FromStr for LinkKind {
    type Err = String;

    fn from_str(s: &str) -> Result<LinkKind, String> {
        match s {
            "packet" => Ok(LinkKind::Packet),
            "xdp" => Ok(LinkKind::Xdp),
            other => Err(format!("unknown link '{other}' (packet or xdp)")),
        }
    }
}

/// How a link should be opened: which queue, and whether the kernel busy-polls for us.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LinkOptions {
    /// `SO_BUSY_POLL` time in µs (0 = off): `recv` spins in the driver for this long before
    /// sleeping, which trades a CPU for wake-up latency.
    pub busy_poll_us: u32,
    /// AF_PACKET: hand frames straight to the driver (`PACKET_QDISC_BYPASS`, the default),
    /// past the queueing discipline and the packet taps. Off, frames take the kernel's
    /// transmit queue, so a capture on the master's own interface (tcpdump, tshark) sees what
    /// the master sends, at the cost measured in docs/benchmarks.md ("capture").
    pub qdisc_bypass: bool,
}

impl Default for LinkOptions {
    fn default() -> Self {
        LinkOptions {
            busy_poll_us: 0,
            qdisc_bypass: true,
        }
    }
}

/// Apply the busy-poll options to a socket (both links use them). Returns false when the
/// kernel refused one (needs CAP_NET_ADMIN for values above `net.core.busy_read`).
pub(crate) fn set_busy_poll(fd: libc::c_int, options: &LinkOptions) -> bool {
    if options.busy_poll_us == 0 {
        return true;
    }
    let us = options.busy_poll_us.min(i32::MAX as u32) as libc::c_int;
    set_int_option(fd, libc::SOL_SOCKET, libc::SO_BUSY_POLL, us)
        && set_int_option(fd, libc::SOL_SOCKET, SO_PREFER_BUSY_POLL, 1)
        && set_int_option(fd, libc::SOL_SOCKET, SO_BUSY_POLL_BUDGET, 8)
}

// Not in every libc version's generic Linux module.
const SO_PREFER_BUSY_POLL: libc::c_int = 69;
const SO_BUSY_POLL_BUDGET: libc::c_int = 70;

/// An AF_PACKET raw socket bound to one interface and to the EtherCAT EtherType.
pub struct RawSocketLink {
    fd: libc::c_int,
    ifname: String,
}

fn os_error(what: &str, ifname: &str) -> io::Error {
    let e = io::Error::last_os_error();
    io::Error::new(e.kind(), format!("{what} on interface '{ifname}': {e}"))
}

pub(crate) fn set_int_option(
    fd: libc::c_int,
    level: libc::c_int,
    name: libc::c_int,
    value: libc::c_int,
) -> bool {
    // SAFETY: `value` lives for the call and its size is passed.
    unsafe {
        libc::setsockopt(
            fd,
            level,
            name,
            &value as *const libc::c_int as *const libc::c_void,
            std::mem::size_of::<libc::c_int>() as libc::socklen_t,
        ) == 0
    }
}

impl RawSocketLink {
    /// Open a raw socket on `ifname`. Needs CAP_NET_RAW (root).
    pub fn open(ifname: &str) -> io::Result<RawSocketLink> {
        RawSocketLink::open_with(ifname, &LinkOptions::default())
    }

    /// Open a raw socket on `ifname` with `options` (busy polling).
    pub fn open_with(ifname: &str, options: &LinkOptions) -> io::Result<RawSocketLink> {
        let cname = CString::new(ifname).map_err(|_| {
            io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("bad interface name {ifname:?}"),
            )
        })?;
        // SAFETY: plain libc calls with valid arguments; the fd is closed on every error path.
        unsafe {
            let ifindex = libc::if_nametoindex(cname.as_ptr());
            if ifindex == 0 {
                return Err(io::Error::new(
                    io::ErrorKind::NotFound,
                    format!("no network interface named '{ifname}'"),
                ));
            }
            // Protocol 0: the socket receives nothing until bind() names the interface and the
            // EtherType, so frames of other interfaces never get queued in between.
            let fd = libc::socket(
                libc::AF_PACKET,
                libc::SOCK_RAW | libc::SOCK_NONBLOCK | libc::SOCK_CLOEXEC,
                0,
            );
            if fd < 0 {
                return Err(os_error(
                    "cannot open a raw socket (needs root or CAP_NET_RAW)",
                    ifname,
                ));
            }
            let link = RawSocketLink {
                fd,
                ifname: ifname.to_string(),
            };
            let mut sll: libc::sockaddr_ll = std::mem::zeroed();
            sll.sll_family = libc::AF_PACKET as u16;
            sll.sll_protocol = ETHERTYPE.to_be();
            sll.sll_ifindex = ifindex as i32;
            if libc::bind(
                fd,
                &sll as *const libc::sockaddr_ll as *const libc::sockaddr,
                std::mem::size_of::<libc::sockaddr_ll>() as libc::socklen_t,
            ) != 0
            {
                return Err(os_error("cannot bind the raw socket", ifname));
            }
            // Frames go straight to the driver: no queueing discipline between us and the wire
            // (nor the taps a capture on this interface listens at: off when one is wanted).
            // Optional (older kernels lack it), so failure is ignored.
            if options.qdisc_bypass {
                set_int_option(fd, libc::SOL_PACKET, libc::PACKET_QDISC_BYPASS, 1);
            }
            // Kernel receive timestamps make the round trip exact even when the reply is read
            // a cycle later (send_at_wake). Optional as well.
            set_int_option(fd, libc::SOL_SOCKET, libc::SO_TIMESTAMPNS, 1);
            set_int_option(fd, libc::SOL_SOCKET, libc::SO_RCVBUF, 1 << 20);
            if !set_busy_poll(fd, options) {
                return Err(os_error("cannot enable busy polling", ifname));
            }
            let mut link = link;
            link.drain();
            Ok(link)
        }
    }

    /// Throw away frames queued before we were interested (e.g. from other interfaces before
    /// bind, or a previous user of the bus).
    pub fn drain(&mut self) {
        let mut buf = [0u8; MAX_FRAME_LEN];
        while let Ok(Some(_)) = self.recv(&mut buf, 0) {}
    }
}

impl Drop for RawSocketLink {
    fn drop(&mut self) {
        // SAFETY: we own the fd.
        unsafe { libc::close(self.fd) };
    }
}

impl Link for RawSocketLink {
    fn send(&mut self, frame: &[u8]) -> io::Result<()> {
        // SAFETY: the buffer is valid for its length; the socket is bound to the interface.
        let n = unsafe {
            libc::send(
                self.fd,
                frame.as_ptr() as *const libc::c_void,
                frame.len(),
                0,
            )
        };
        if n < 0 {
            return Err(io::Error::last_os_error());
        }
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], deadline_ns: i64) -> io::Result<Option<Received>> {
        loop {
            // SAFETY: every pointer handed to recvmsg points to a live local of the stated size.
            let (n, pkt_type, stamp) = unsafe {
                let mut addr: libc::sockaddr_ll = std::mem::zeroed();
                let mut iov = libc::iovec {
                    iov_base: buf.as_mut_ptr() as *mut libc::c_void,
                    iov_len: buf.len(),
                };
                let mut control = [0u64; 16];
                let mut msg: libc::msghdr = std::mem::zeroed();
                msg.msg_name = &mut addr as *mut libc::sockaddr_ll as *mut libc::c_void;
                msg.msg_namelen = std::mem::size_of::<libc::sockaddr_ll>() as libc::socklen_t;
                msg.msg_iov = &mut iov;
                msg.msg_iovlen = 1;
                msg.msg_control = control.as_mut_ptr() as *mut libc::c_void;
                msg.msg_controllen = std::mem::size_of_val(&control) as _;
                let n = libc::recvmsg(self.fd, &mut msg, libc::MSG_DONTWAIT);
                let mut stamp = None;
                if n >= 0 {
                    let mut cmsg = libc::CMSG_FIRSTHDR(&msg);
                    while !cmsg.is_null() {
                        if (*cmsg).cmsg_level == libc::SOL_SOCKET
                            && (*cmsg).cmsg_type == libc::SCM_TIMESTAMPNS
                        {
                            let ts = std::ptr::read_unaligned(
                                libc::CMSG_DATA(cmsg) as *const libc::timespec
                            );
                            stamp = Some(ts.tv_sec as i64 * 1_000_000_000 + ts.tv_nsec as i64);
                        }
                        cmsg = libc::CMSG_NXTHDR(&msg, cmsg);
                    }
                }
                (n, addr.sll_pkttype, stamp)
            };
            if n >= 0 {
                if pkt_type == libc::PACKET_OUTGOING {
                    continue; // our own frame, looped back to packet sockets by the kernel
                }
                let now = now_ns();
                let rx_ns = match stamp {
                    // Move the wall-clock stamp onto the monotonic clock; never into the future.
                    Some(real) => (now - (realtime_ns() - real)).min(now),
                    None => now,
                };
                return Ok(Some(Received {
                    len: (n as usize).min(buf.len()),
                    rx_ns,
                }));
            }
            let err = io::Error::last_os_error();
            match err.raw_os_error() {
                Some(libc::EAGAIN) => {}
                Some(libc::EINTR) => continue,
                _ => return Err(err),
            }
            let remaining = deadline_ns - now_ns();
            if remaining <= 0 {
                return Ok(None);
            }
            wait_readable(self.fd, remaining)?;
        }
    }

    fn describe(&self) -> String {
        format!("interface '{}'", self.ifname)
    }
}

/// Answers a frame in place: gets a buffer of `MAX_FRAME_LEN` bytes holding the frame in
/// `[..len]`, returns the reply's length (the reply is left in the buffer), or `None` when the
/// frame is lost. The Python binding builds one around the simulator; the engine never depends on
/// the simulator crate.
pub type Responder = Box<dyn FnMut(&mut [u8], usize) -> Option<usize> + Send>;

const IN_PROCESS_QUEUE: usize = 8;

/// Hands frames straight to an in-process responder (the simulator). Replies wait in a small
/// preallocated queue until `recv` picks them up, like frames in a socket's receive queue.
pub struct InProcessLink {
    responder: Responder,
    queue: Box<[[u8; MAX_FRAME_LEN]; IN_PROCESS_QUEUE]>,
    lens: [usize; IN_PROCESS_QUEUE],
    stamps: [i64; IN_PROCESS_QUEUE],
    head: usize,
    count: usize,
    name: String,
}

impl InProcessLink {
    /// A link named `name` (for messages) whose frames `responder` answers.
    pub fn new(name: &str, responder: Responder) -> InProcessLink {
        InProcessLink {
            responder,
            queue: Box::new([[0u8; MAX_FRAME_LEN]; IN_PROCESS_QUEUE]),
            lens: [0; IN_PROCESS_QUEUE],
            stamps: [0; IN_PROCESS_QUEUE],
            head: 0,
            count: 0,
            name: name.to_string(),
        }
    }
}

impl Link for InProcessLink {
    fn send(&mut self, frame: &[u8]) -> io::Result<()> {
        if frame.len() > MAX_FRAME_LEN {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "frame longer than the MTU",
            ));
        }
        if self.count == IN_PROCESS_QUEUE {
            // Receive queue full: the reply is lost, as with an overflowing socket buffer.
            self.head = (self.head + 1) % IN_PROCESS_QUEUE;
            self.count -= 1;
        }
        let slot = (self.head + self.count) % IN_PROCESS_QUEUE;
        let buf = &mut self.queue[slot];
        buf[..frame.len()].copy_from_slice(frame);
        if let Some(len) = (self.responder)(&mut buf[..], frame.len()) {
            self.lens[slot] = len.min(MAX_FRAME_LEN);
            self.stamps[slot] = now_ns();
            self.count += 1;
        }
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], _deadline_ns: i64) -> io::Result<Option<Received>> {
        // Replies are produced synchronously by `send`: waiting longer cannot bring more.
        if self.count == 0 {
            return Ok(None);
        }
        let slot = self.head;
        self.head = (self.head + 1) % IN_PROCESS_QUEUE;
        self.count -= 1;
        let len = self.lens[slot].min(buf.len());
        buf[..len].copy_from_slice(&self.queue[slot][..len]);
        Ok(Some(Received {
            len,
            rx_ns: self.stamps[slot],
        }))
    }

    fn describe(&self) -> String {
        format!("in-process {}", self.name)
    }
}

/// Wait until `fd` is readable or `remaining_ns` have passed (one `ppoll`); an interrupted
/// wait is not an error, the caller looks again. Shared by the links' `recv`.
pub(crate) fn wait_readable(fd: libc::c_int, remaining_ns: i64) -> io::Result<()> {
    let mut pfd = libc::pollfd {
        fd,
        events: libc::POLLIN,
        revents: 0,
    };
    let ts = timespec(remaining_ns);
    // SAFETY: one valid pollfd; the timeout timespec is valid; no signal mask change.
    let r = unsafe { libc::ppoll(&mut pfd, 1, &ts, std::ptr::null()) };
    if r < 0 {
        let err = io::Error::last_os_error();
        if err.raw_os_error() != Some(libc::EINTR) {
            return Err(err);
        }
    }
    Ok(())
}

/// Receive timeout of [`SlaveSocket`] when the line is idle (µs): a blocking receive returns
/// after this long at the latest, so the simulator's frame loop can run its timers.
pub const SLAVE_IDLE_POLL_US: u32 = 1_000;

/// The simulator's side of an AF_PACKET link: a raw socket bound to one interface and to the
/// EtherCAT EtherType, promiscuous, whose idle wait is one blocking receive (`SO_RCVTIMEO` is
/// the idle poll time, [`SLAVE_IDLE_POLL_US`]), so answering a frame costs one syscall each way.
pub struct SlaveSocket {
    fd: libc::c_int,
}

impl Drop for SlaveSocket {
    fn drop(&mut self) {
        // SAFETY: we own the descriptor.
        unsafe { libc::close(self.fd) };
    }
}

impl SlaveSocket {
    /// Open the socket on `ifname`. Needs CAP_NET_RAW (root).
    pub fn open(ifname: &str) -> io::Result<SlaveSocket> {
        let name = CString::new(ifname).map_err(|_| {
            io::Error::new(io::ErrorKind::InvalidInput, "interface name contains NUL")
        })?;
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
            // opening with the EtherType directly would queue EtherCAT frames from every
            // interface (e.g. other buses on the same host) in the window before bind().
            let fd = libc::socket(libc::AF_PACKET, libc::SOCK_RAW, 0);
            if fd < 0 {
                return Err(io::Error::last_os_error());
            }
            let sock = SlaveSocket { fd };
            let mut sll: libc::sockaddr_ll = std::mem::zeroed();
            sll.sll_family = libc::AF_PACKET as u16;
            sll.sll_protocol = ETHERTYPE.to_be();
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
            // A blocking receive returns after the idle poll time at the latest.
            let tv = libc::timeval {
                tv_sec: 0,
                tv_usec: SLAVE_IDLE_POLL_US as libc::suseconds_t,
            };
            libc::setsockopt(
                fd,
                libc::SOL_SOCKET,
                libc::SO_RCVTIMEO,
                &tv as *const libc::timeval as *const libc::c_void,
                std::mem::size_of::<libc::timeval>() as u32,
            );
            Ok(sock)
        }
    }

    /// Wait up to `timeout_ns` for a frame from the wire; its length in `buf`, or `None` when
    /// none came. Frames this socket sent itself are skipped.
    pub fn recv(&mut self, buf: &mut [u8], timeout_ns: u64) -> Option<usize> {
        // An idle wait is one blocking receive (SO_RCVTIMEO is the idle poll time): one
        // syscall per frame. A shorter wait (delayed answers due) polls first.
        let flags = if timeout_ns >= SLAVE_IDLE_POLL_US as u64 * 1_000 {
            0
        } else if poll_readable(self.fd, timeout_ns) {
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
                    self.fd,
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

    /// Send one frame; false when the kernel refused it.
    pub fn send(&mut self, frame: &[u8]) -> bool {
        // SAFETY: send a buffer we own on the bound socket.
        unsafe {
            libc::send(
                self.fd,
                frame.as_ptr() as *const libc::c_void,
                frame.len(),
                0,
            ) >= 0
        }
    }
}

/// Wait until `fd` is readable or `timeout_ns` passed (ns resolution, unlike poll()).
fn poll_readable(fd: libc::c_int, timeout_ns: u64) -> bool {
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
