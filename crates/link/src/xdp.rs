//! The AF_XDP link: an XDP socket on one receive queue of the interface, its UMEM (the frame
//! memory shared with the kernel) and its four rings, with the XDP program of `bpf.rs` steering
//! EtherCAT frames into it. Frames skip the kernel's network stack in both directions: in
//! zero-copy mode the driver DMAs straight into the UMEM; in copy mode (veth, drivers without
//! zero-copy) the kernel copies once, still without building an skb on receive.
//!
//! All memory (UMEM and rings) is mapped with `MAP_POPULATE` when the link opens, so the cycle
//! touches no new page; `send` and `recv` only move descriptors and copy one frame. The syscalls
//! the cycle may make: `sendto` (the TX kick, needed in copy mode), `recvfrom` (a receive kick
//! when the kernel asks for one with the fill ring's need-wakeup flag) and `ppoll` (waiting for
//! a reply). Like the raw socket, the link is owned by one thread at a time and needs no lock.

use std::ffi::CString;
use std::io;
use std::sync::atomic::{AtomicU32, Ordering};

use crate::bpf::{self, bind_queue, Attached, Fd};
use crate::clock::now_ns;
use crate::packet::{set_busy_poll, wait_readable, Link, LinkOptions, Received};
use ether_ros_protocol::MAX_FRAME_LEN;

/// UMEM chunk size: one page, so a chunk never straddles pages.
const CHUNK: usize = 4096;
/// Entries in each ring (a power of two); the UMEM has one chunk per fill and per TX entry.
const RING: u32 = 64;
const CHUNKS: usize = 2 * RING as usize;
/// Chunks `[0, RING)` receive (they circulate through the fill and RX rings), chunks
/// `[RING, 2 RING)` transmit (they circulate through the TX and completion rings).
const TX_BASE: u64 = RING as u64 * CHUNK as u64;

/// One mapped ring: producer and consumer indexes shared with the kernel, and its entries.
struct Ring<T> {
    producer: *const AtomicU32,
    consumer: *const AtomicU32,
    flags: *const AtomicU32,
    entries: *mut T,
    map: *mut libc::c_void,
    map_len: usize,
}

impl<T: Copy> Ring<T> {
    /// Map ring `pgoff` of `fd` at the offsets the kernel reported.
    fn map(fd: i32, off: &libc::xdp_ring_offset, pgoff: u64, what: &str) -> io::Result<Ring<T>> {
        let map_len = off.desc as usize + RING as usize * std::mem::size_of::<T>();
        // SAFETY: maps the kernel's ring; MAP_POPULATE prefaults it so the cycle never faults.
        let map = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                map_len,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_SHARED | libc::MAP_POPULATE,
                fd,
                pgoff as libc::off_t,
            )
        };
        if map == libc::MAP_FAILED {
            let e = io::Error::last_os_error();
            return Err(io::Error::new(
                e.kind(),
                format!("cannot map the {what} ring: {e}"),
            ));
        }
        let at = |o: u64| (map as usize + o as usize) as *mut u8;
        Ok(Ring {
            producer: at(off.producer) as *const AtomicU32,
            consumer: at(off.consumer) as *const AtomicU32,
            flags: at(off.flags) as *const AtomicU32,
            entries: at(off.desc) as *mut T,
            map,
            map_len,
        })
    }

    fn producer(&self) -> &AtomicU32 {
        // SAFETY: points into the live mapping, 4-byte aligned by the kernel.
        unsafe { &*self.producer }
    }

    fn consumer(&self) -> &AtomicU32 {
        // SAFETY: as above.
        unsafe { &*self.consumer }
    }

    fn needs_wakeup(&self) -> bool {
        // SAFETY: as above.
        unsafe { &*self.flags }.load(Ordering::Relaxed) & libc::XDP_RING_NEED_WAKEUP != 0
    }

    /// Entry `index` (taken modulo the ring size).
    fn slot(&self, index: u32) -> *mut T {
        // SAFETY: the index is masked into the ring.
        unsafe { self.entries.add((index & (RING - 1)) as usize) }
    }

    /// Producer side (fill, TX): put `value` in the next free entry, if any.
    fn push(&self, value: T) -> bool {
        let prod = self.producer().load(Ordering::Relaxed);
        let cons = self.consumer().load(Ordering::Acquire);
        if prod.wrapping_sub(cons) >= RING {
            return false;
        }
        // SAFETY: the entry is ours until the producer index moves past it.
        unsafe { self.slot(prod).write(value) };
        self.producer()
            .store(prod.wrapping_add(1), Ordering::Release);
        true
    }

    /// Consumer side (RX, completion): take the oldest entry, if any.
    fn pop(&self) -> Option<T> {
        let cons = self.consumer().load(Ordering::Relaxed);
        let prod = self.producer().load(Ordering::Acquire);
        if prod == cons {
            return None;
        }
        // SAFETY: the kernel filled this entry before publishing the producer index.
        let value = unsafe { self.slot(cons).read() };
        self.consumer()
            .store(cons.wrapping_add(1), Ordering::Release);
        Some(value)
    }
}

impl<T> Drop for Ring<T> {
    fn drop(&mut self) {
        // SAFETY: unmaps our own mapping.
        unsafe { libc::munmap(self.map, self.map_len) };
    }
}

/// Whether the driver moves frames to and from the UMEM itself.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum XdpMode {
    /// The driver DMAs straight into the UMEM (`XDP_ZEROCOPY`).
    ZeroCopy,
    /// The kernel copies each frame once (veth, drivers without zero-copy).
    Copy,
}

/// An AF_XDP socket on queue 0 of one interface, with the XDP program that feeds it.
pub struct XdpLink {
    // Field order is drop order: detach the program, then unmap the rings, close the socket,
    // and unmap the UMEM last.
    _program: Attached,
    fill: Ring<u64>,
    completion: Ring<u64>,
    rx: Ring<libc::xdp_desc>,
    tx: Ring<libc::xdp_desc>,
    socket: Fd,
    umem: Umem,
    /// TX chunks not in flight, as a stack of UMEM addresses.
    tx_free: [u64; RING as usize],
    tx_free_count: usize,
    mode: XdpMode,
    ifname: String,
}

// SAFETY: the raw pointers point into mappings owned by this value; the link is used by one
// thread at a time (see the module comment), which `&mut self` enforces.
unsafe impl Send for XdpLink {}

fn os_error(what: &str, ifname: &str) -> io::Error {
    with_hint(what, ifname, io::Error::last_os_error())
}

fn with_hint(what: &str, ifname: &str, e: io::Error) -> io::Error {
    let hint = match e.raw_os_error() {
        Some(libc::EPERM) | Some(libc::EACCES) => " (needs CAP_NET_RAW)",
        Some(libc::EAFNOSUPPORT) => " (this kernel has no AF_XDP: CONFIG_XDP_SOCKETS)",
        Some(libc::EBUSY) => " (the queue already has an AF_XDP socket: another master?)",
        _ => "",
    };
    io::Error::new(
        e.kind(),
        format!("{what} on interface '{ifname}': {e}{hint}"),
    )
}

fn set_option<T>(fd: i32, name: libc::c_int, value: &T) -> bool {
    // SAFETY: `value` is live for the call and its size is passed.
    unsafe {
        libc::setsockopt(
            fd,
            libc::SOL_XDP,
            name,
            value as *const T as *const libc::c_void,
            std::mem::size_of::<T>() as libc::socklen_t,
        ) == 0
    }
}

/// The UMEM mapping, unmapped when dropped (after the socket that uses it).
struct Umem(*mut u8);

impl Drop for Umem {
    fn drop(&mut self) {
        // SAFETY: unmaps our own mapping.
        unsafe { libc::munmap(self.0 as *mut libc::c_void, CHUNKS * CHUNK) };
    }
}

impl XdpLink {
    /// Open an AF_XDP socket on queue 0 of `ifname` and attach the XDP program. Needs
    /// CAP_NET_RAW, CAP_NET_ADMIN and CAP_BPF (or CAP_SYS_ADMIN) and a driver with native XDP.
    pub fn open(ifname: &str, options: &LinkOptions) -> io::Result<XdpLink> {
        let queue = 0u32;
        let cname = CString::new(ifname).map_err(|_| {
            io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("bad interface name {ifname:?}"),
            )
        })?;
        // SAFETY: a plain query with a valid C string.
        let ifindex = unsafe { libc::if_nametoindex(cname.as_ptr()) };
        if ifindex == 0 {
            return Err(io::Error::new(
                io::ErrorKind::NotFound,
                format!("no network interface named '{ifname}'"),
            ));
        }
        // SAFETY: plain socket creation; the fd is owned by `Fd` from here on.
        let fd = unsafe { libc::socket(libc::AF_XDP, libc::SOCK_RAW | libc::SOCK_CLOEXEC, 0) };
        if fd < 0 {
            return Err(os_error("cannot open an AF_XDP socket", ifname));
        }
        let socket = Fd(fd);

        // SAFETY: anonymous private mapping, prefaulted.
        let mem = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                CHUNKS * CHUNK,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_PRIVATE | libc::MAP_ANONYMOUS | libc::MAP_POPULATE,
                -1,
                0,
            )
        };
        if mem == libc::MAP_FAILED {
            return Err(os_error("cannot allocate the UMEM", ifname));
        }
        let umem = Umem(mem as *mut u8);
        let reg = libc::xdp_umem_reg {
            addr: mem as u64,
            len: (CHUNKS * CHUNK) as u64,
            chunk_size: CHUNK as u32,
            headroom: 0,
            flags: 0,
            tx_metadata_len: 0,
        };
        if !set_option(fd, libc::XDP_UMEM_REG, &reg) {
            return Err(os_error("cannot register the UMEM", ifname));
        }
        for ring in [
            libc::XDP_UMEM_FILL_RING,
            libc::XDP_UMEM_COMPLETION_RING,
            libc::XDP_RX_RING,
            libc::XDP_TX_RING,
        ] {
            if !set_option(fd, ring, &RING) {
                return Err(os_error("cannot size the AF_XDP rings", ifname));
            }
        }
        // SAFETY: xdp_mmap_offsets is plain data; the kernel fills it.
        let mut off: libc::xdp_mmap_offsets = unsafe { std::mem::zeroed() };
        let mut len = std::mem::size_of::<libc::xdp_mmap_offsets>() as libc::socklen_t;
        // SAFETY: `off` is live and `len` its size.
        let r = unsafe {
            libc::getsockopt(
                fd,
                libc::SOL_XDP,
                libc::XDP_MMAP_OFFSETS,
                &mut off as *mut libc::xdp_mmap_offsets as *mut libc::c_void,
                &mut len,
            )
        };
        if r != 0 {
            return Err(os_error("cannot read the AF_XDP ring offsets", ifname));
        }
        let fill = Ring::<u64>::map(fd, &off.fr, libc::XDP_UMEM_PGOFF_FILL_RING, "fill")?;
        let completion = Ring::<u64>::map(
            fd,
            &off.cr,
            libc::XDP_UMEM_PGOFF_COMPLETION_RING,
            "completion",
        )?;
        let rx = Ring::<libc::xdp_desc>::map(fd, &off.rx, libc::XDP_PGOFF_RX_RING as u64, "RX")?;
        let tx = Ring::<libc::xdp_desc>::map(fd, &off.tx, libc::XDP_PGOFF_TX_RING as u64, "TX")?;
        // Every receive chunk goes to the kernel before the first frame can arrive.
        for i in 0..RING as u64 {
            fill.push(i * CHUNK as u64);
        }

        // Zero-copy when the driver can, copy mode otherwise.
        let mode = bind_queue(fd, ifindex, queue)
            .map_err(|e| with_hint("cannot bind the AF_XDP socket to queue 0", ifname, e))?;
        if !set_busy_poll(fd, options) {
            return Err(os_error("cannot enable busy polling", ifname));
        }
        let program = bpf::attach(ifname, ifindex, queue, fd)?;

        let mut tx_free = [0u64; RING as usize];
        for (i, addr) in tx_free.iter_mut().enumerate() {
            *addr = TX_BASE + (i * CHUNK) as u64;
        }
        Ok(XdpLink {
            _program: program,
            fill,
            completion,
            rx,
            tx,
            socket,
            umem,
            tx_free,
            tx_free_count: RING as usize,
            mode,
            ifname: ifname.to_string(),
        })
    }

    /// Whether the driver bound the socket in zero-copy or copy mode.
    pub fn mode(&self) -> XdpMode {
        self.mode
    }

    /// Take back the TX chunks the kernel has sent.
    fn reclaim(&mut self) {
        while let Some(addr) = self.completion.pop() {
            if self.tx_free_count < self.tx_free.len() {
                self.tx_free[self.tx_free_count] = addr;
                self.tx_free_count += 1;
            }
        }
    }

    /// Tell the kernel there is something on the TX ring (copy mode always needs this; in
    /// zero-copy mode only when the ring asks for a wakeup).
    fn kick_tx(&self) -> io::Result<()> {
        if self.mode == XdpMode::ZeroCopy && !self.tx.needs_wakeup() {
            return Ok(());
        }
        // SAFETY: a kick with no buffer and no address.
        let r = unsafe {
            libc::sendto(
                self.socket.0,
                std::ptr::null(),
                0,
                libc::MSG_DONTWAIT,
                std::ptr::null(),
                0,
            )
        };
        if r < 0 {
            let e = io::Error::last_os_error();
            // The kernel is still sending the previous batch or its queue is full: the frame
            // stays on the ring and goes with the next kick.
            if !matches!(
                e.raw_os_error(),
                Some(libc::EAGAIN) | Some(libc::EBUSY) | Some(libc::ENOBUFS)
            ) {
                return Err(e);
            }
        }
        Ok(())
    }

    fn umem_chunk(&mut self, addr: u64, len: usize) -> &mut [u8] {
        let start = addr as usize;
        assert!(start + len <= CHUNKS * CHUNK, "descriptor outside the UMEM");
        // SAFETY: inside the UMEM mapping (checked above); the chunk is ours (off the rings).
        unsafe { std::slice::from_raw_parts_mut(self.umem.0.add(start), len) }
    }
}

impl Link for XdpLink {
    fn send(&mut self, frame: &[u8]) -> io::Result<()> {
        if frame.len() > MAX_FRAME_LEN {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "frame longer than the MTU",
            ));
        }
        self.reclaim();
        if self.tx_free_count == 0 {
            self.kick_tx()?;
            self.reclaim();
        }
        if self.tx_free_count == 0 {
            return Err(io::Error::new(
                io::ErrorKind::WouldBlock,
                "AF_XDP TX ring full: the driver sends nothing",
            ));
        }
        self.tx_free_count -= 1;
        let addr = self.tx_free[self.tx_free_count];
        self.umem_chunk(addr, frame.len()).copy_from_slice(frame);
        let desc = libc::xdp_desc {
            addr,
            len: frame.len() as u32,
            options: 0,
        };
        if !self.tx.push(desc) {
            self.tx_free_count += 1;
            return Err(io::Error::new(
                io::ErrorKind::WouldBlock,
                "AF_XDP TX ring full",
            ));
        }
        self.kick_tx()
    }

    fn recv(&mut self, buf: &mut [u8], deadline_ns: i64) -> io::Result<Option<Received>> {
        loop {
            if let Some(desc) = self.rx.pop() {
                let len = (desc.len as usize).min(buf.len());
                let chunk_start = desc.addr - desc.addr % CHUNK as u64;
                buf[..len].copy_from_slice(self.umem_chunk(desc.addr, len));
                // The chunk goes straight back to the kernel for the next frame.
                self.fill.push(chunk_start);
                return Ok(Some(Received {
                    len,
                    rx_ns: now_ns(),
                }));
            }
            let remaining = deadline_ns - now_ns();
            if remaining <= 0 {
                if self.fill.needs_wakeup() {
                    // The driver waits for a syscall before it refills: give it one.
                    // SAFETY: a zero-length non-blocking receive, used only as a kick.
                    unsafe {
                        libc::recvfrom(
                            self.socket.0,
                            std::ptr::null_mut(),
                            0,
                            libc::MSG_DONTWAIT,
                            std::ptr::null_mut(),
                            std::ptr::null_mut(),
                        )
                    };
                    if self.rx.producer().load(Ordering::Acquire)
                        != self.rx.consumer().load(Ordering::Relaxed)
                    {
                        continue;
                    }
                }
                return Ok(None);
            }
            wait_readable(self.socket.0, remaining)?;
        }
    }

    fn describe(&self) -> String {
        let mode = match self.mode {
            XdpMode::ZeroCopy => "zero-copy",
            XdpMode::Copy => "copy mode",
        };
        format!("interface '{}' (AF_XDP, {mode})", self.ifname)
    }
}
