//! The XDP side of the AF_XDP link: a socket map and a small XDP program that redirects
//! EtherCAT frames (EtherType 0x88A4) to the AF_XDP socket of the receiving queue and passes
//! everything else to the kernel's stack, attached through a BPF link.
//!
//! The program is twelve instructions, so it is assembled here and loaded with the `bpf()`
//! system call rather than compiled by clang and loaded by libbpf/libxdp: the build needs no BPF
//! toolchain and no C library, and the loader is the handful of commands below. It is attached
//! with `BPF_LINK_CREATE` (kernel 5.9+): the link lives as long as its file descriptor, so the
//! kernel detaches the program when the process exits or is killed, and nothing stays on the
//! interface. (libxdp attaches through netlink, which outlives the process.)
//!
//! Everything here runs once, when the link opens; nothing here is on the cyclic path.

use std::io;

use ether_ros_protocol::ETHERTYPE;

use crate::xdp::XdpMode;

const BPF_MAP_CREATE: libc::c_long = 0;
const BPF_MAP_UPDATE_ELEM: libc::c_long = 2;
const BPF_PROG_LOAD: libc::c_long = 5;
const BPF_LINK_CREATE: libc::c_long = 28;

const BPF_MAP_TYPE_XSKMAP: u32 = 17;
const BPF_PROG_TYPE_XDP: u32 = 6;
const BPF_XDP: u32 = 37;
/// Native ("driver") XDP: the program runs in the driver's receive path. Generic XDP
/// (`XDP_FLAGS_SKB_MODE`) would run after the skb is built and save nothing.
const XDP_FLAGS_DRV_MODE: u32 = 1 << 2;

const XDP_PASS: i32 = 2;
const BPF_FUNC_REDIRECT_MAP: i32 = 51;
const BPF_PSEUDO_MAP_FD: u8 = 1;

/// One BPF instruction as the kernel reads it (`struct bpf_insn`).
#[repr(C)]
#[derive(Clone, Copy)]
struct Insn {
    code: u8,
    regs: u8, // dst in the low nibble, src in the high nibble
    off: i16,
    imm: i32,
}

const fn insn(code: u8, dst: u8, src: u8, off: i16, imm: i32) -> Insn {
    Insn {
        code,
        regs: dst | (src << 4),
        off,
        imm,
    }
}

// Opcodes used by the program (linux/bpf.h: class | size/op | source).
const LDX_W: u8 = 0x61; // dst = *(u32 *)(src + off)
const LDX_H: u8 = 0x69; // dst = *(u16 *)(src + off)
const MOV64_X: u8 = 0xbf; // dst = src
const MOV64_K: u8 = 0xb7; // dst = imm
const ADD64_K: u8 = 0x07; // dst += imm
const JGT_X: u8 = 0x2d; // if dst > src goto +off
const JNE_K: u8 = 0x55; // if dst != imm goto +off
const LD_DW: u8 = 0x18; // dst = imm64 (two instructions; src 1 = map fd)
const CALL: u8 = 0x85;
const EXIT: u8 = 0x95;

/// `struct xdp_md` field offsets.
const XDP_MD_DATA: i16 = 0;
const XDP_MD_DATA_END: i16 = 4;
const XDP_MD_RX_QUEUE_INDEX: i16 = 16;

/// The program: EtherCAT frames go to the socket in `xsks[rx_queue_index]` (when that queue has
/// no socket the redirect fails and the frame passes, its flags argument), others pass.
fn program(map_fd: i32) -> [Insn; 15] {
    // The EtherType as a little-endian load of its two big-endian wire bytes.
    let ethertype_le = i32::from(ETHERTYPE.swap_bytes());
    [
        insn(LDX_W, 2, 1, XDP_MD_DATA, 0),
        insn(LDX_W, 3, 1, XDP_MD_DATA_END, 0),
        insn(MOV64_X, 4, 2, 0, 0),
        insn(ADD64_K, 4, 0, 0, 14),
        insn(JGT_X, 4, 3, 8, 0), // shorter than an Ethernet header: pass
        insn(LDX_H, 4, 2, 12, 0),
        insn(JNE_K, 4, 0, 6, ethertype_le), // not EtherCAT: pass
        insn(LDX_W, 2, 1, XDP_MD_RX_QUEUE_INDEX, 0),
        insn(LD_DW, 1, BPF_PSEUDO_MAP_FD, 0, map_fd),
        insn(0, 0, 0, 0, 0),
        insn(MOV64_K, 3, 0, 0, XDP_PASS),
        insn(CALL, 0, 0, 0, BPF_FUNC_REDIRECT_MAP),
        insn(EXIT, 0, 0, 0, 0),
        insn(MOV64_K, 0, 0, 0, XDP_PASS),
        insn(EXIT, 0, 0, 0, 0),
    ]
}

#[repr(C)]
#[derive(Default)]
struct MapCreateAttr {
    map_type: u32,
    key_size: u32,
    value_size: u32,
    max_entries: u32,
    map_flags: u32,
}

#[repr(C)]
#[derive(Default)]
struct MapElemAttr {
    map_fd: u32,
    _pad: u32,
    key: u64,
    value: u64,
    flags: u64,
}

#[repr(C)]
#[derive(Default)]
struct ProgLoadAttr {
    prog_type: u32,
    insn_cnt: u32,
    insns: u64,
    license: u64,
    log_level: u32,
    log_size: u32,
    log_buf: u64,
    kern_version: u32,
    prog_flags: u32,
    prog_name: [u8; 16],
    prog_ifindex: u32,
    expected_attach_type: u32,
}

#[repr(C)]
#[derive(Default)]
struct LinkCreateAttr {
    prog_fd: u32,
    target_ifindex: u32,
    attach_type: u32,
    flags: u32,
}

fn bpf<T>(cmd: libc::c_long, attr: &mut T) -> io::Result<i32> {
    // SAFETY: `attr` is a live, fully initialised `bpf_attr` prefix of the size passed; the
    // kernel zero-extends the rest.
    let r = unsafe {
        libc::syscall(
            libc::SYS_bpf,
            cmd,
            attr as *mut T as *mut libc::c_void,
            std::mem::size_of::<T>() as libc::c_uint,
        )
    };
    if r < 0 {
        Err(io::Error::last_os_error())
    } else {
        Ok(r as i32)
    }
}

/// A file descriptor closed when dropped.
pub(crate) struct Fd(pub(crate) i32);

impl Drop for Fd {
    fn drop(&mut self) {
        // SAFETY: we own the descriptor.
        unsafe { libc::close(self.0) };
    }
}

/// The program attached to one interface. Dropping it closes the link (detaching the program),
/// then the program and the map.
pub(crate) struct Attached {
    _link: Fd,
    _prog: Fd,
    _map: Fd,
}

// Capability bits (linux/capability.h).
const CAP_NET_ADMIN: u32 = 12;
const CAP_SYS_ADMIN: u32 = 21;
const CAP_BPF: u32 = 39;

/// The capabilities the BPF steps need that this process's effective set lacks, by name.
fn missing_capabilities() -> String {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let effective = status
        .lines()
        .find_map(|l| l.strip_prefix("CapEff:"))
        .and_then(|v| u64::from_str_radix(v.trim(), 16).ok())
        .unwrap_or(0);
    let has = |bit: u32| effective & (1u64 << bit) != 0;
    let mut missing = vec![];
    if !has(CAP_NET_ADMIN) {
        missing.push("CAP_NET_ADMIN");
    }
    if !has(CAP_BPF) && !has(CAP_SYS_ADMIN) {
        missing.push("CAP_BPF");
    }
    missing.join(" and ")
}

/// Why a BPF step failed, in words an operator can act on.
fn explain(step: &str, ifname: &str, e: io::Error) -> io::Error {
    let hint = match e.raw_os_error() {
        Some(libc::EPERM) | Some(libc::EACCES) => {
            let missing = missing_capabilities();
            if missing.is_empty() {
                " (the xdp link needs CAP_NET_ADMIN and CAP_BPF, or CAP_SYS_ADMIN before \
                 Linux 5.8; check kernel.unprivileged_bpf_disabled and LSM policy)"
                    .to_string()
            } else {
                format!(" (the xdp link needs CAP_NET_ADMIN and CAP_BPF; missing {missing})")
            }
        }
        Some(libc::ENOSYS) => " (this kernel has no bpf() system call)".to_string(),
        Some(libc::EBUSY) | Some(libc::EEXIST) => {
            " (an XDP program is already attached: another master on this interface?)".to_string()
        }
        Some(libc::EOPNOTSUPP) | Some(libc::EINVAL) if step.starts_with("cannot attach") => {
            " (the driver has no native XDP support)".to_string()
        }
        _ => String::new(),
    };
    io::Error::new(
        e.kind(),
        format!("{step} on interface '{ifname}': {e}{hint}"),
    )
}

/// Create the socket map, put `xsk_fd` at `queue`, load the program and attach it to `ifindex`
/// in native mode.
pub(crate) fn attach(ifname: &str, ifindex: u32, queue: u32, xsk_fd: i32) -> io::Result<Attached> {
    let mut create = MapCreateAttr {
        map_type: BPF_MAP_TYPE_XSKMAP,
        key_size: 4,
        value_size: 4,
        max_entries: queue + 1,
        map_flags: 0,
    };
    let map = Fd(bpf(BPF_MAP_CREATE, &mut create)
        .map_err(|e| explain("cannot create the XDP socket map", ifname, e))?);
    let key = queue;
    let value = xsk_fd as u32;
    let mut update = MapElemAttr {
        map_fd: map.0 as u32,
        key: &key as *const u32 as u64,
        value: &value as *const u32 as u64,
        ..Default::default()
    };
    bpf(BPF_MAP_UPDATE_ELEM, &mut update)
        .map_err(|e| explain("cannot register the AF_XDP socket", ifname, e))?;

    let insns = program(map.0);
    let license = c"GPL";
    let mut log = [0u8; 1024];
    let mut name = [0u8; 16];
    name[..15].copy_from_slice(b"ether_ros_ecat\0");
    let mut load = ProgLoadAttr {
        prog_type: BPF_PROG_TYPE_XDP,
        insn_cnt: insns.len() as u32,
        insns: insns.as_ptr() as u64,
        license: license.as_ptr() as u64,
        log_level: 1,
        log_size: log.len() as u32,
        log_buf: log.as_mut_ptr() as u64,
        prog_name: name,
        expected_attach_type: BPF_XDP,
        ..Default::default()
    };
    let prog = match bpf(BPF_PROG_LOAD, &mut load) {
        Ok(fd) => Fd(fd),
        Err(e) => {
            let end = log.iter().position(|&b| b == 0).unwrap_or(log.len());
            let verifier = String::from_utf8_lossy(&log[..end]);
            let e = io::Error::new(e.kind(), format!("{e}; verifier: {}", verifier.trim()));
            return Err(explain("cannot load the XDP program", ifname, e));
        }
    };
    let mut link = LinkCreateAttr {
        prog_fd: prog.0 as u32,
        target_ifindex: ifindex,
        attach_type: BPF_XDP,
        flags: XDP_FLAGS_DRV_MODE,
    };
    let link = Fd(bpf(BPF_LINK_CREATE, &mut link)
        .map_err(|e| explain("cannot attach the XDP program", ifname, e))?);
    Ok(Attached {
        _link: link,
        _prog: prog,
        _map: map,
    })
}

/// How long a queue may stay busy after its previous socket closed: the kernel releases a
/// socket's UMEM in deferred work, so a stop followed at once by a restart can find the queue
/// still taken for a few milliseconds (longer when the kernel's workqueue is starved).
const RELEASE_GRACE_MS: u32 = 2000;

/// Bind zero-copy when the driver can, in copy mode otherwise; retry while the queue is still
/// being released (a real second user keeps it busy past the grace time).
pub(crate) fn bind_queue(fd: i32, ifindex: u32, queue: u32) -> io::Result<XdpMode> {
    let mut tries = RELEASE_GRACE_MS / 10;
    loop {
        if bind(fd, ifindex, queue, libc::XDP_ZEROCOPY) {
            return Ok(XdpMode::ZeroCopy);
        }
        if bind(fd, ifindex, queue, libc::XDP_COPY) {
            return Ok(XdpMode::Copy);
        }
        let e = io::Error::last_os_error();
        tries -= 1;
        if e.raw_os_error() != Some(libc::EBUSY) || tries == 0 {
            return Err(e);
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
}

fn bind(fd: i32, ifindex: u32, queue: u32, mode: u16) -> bool {
    let addr = libc::sockaddr_xdp {
        sxdp_family: libc::AF_XDP as u16,
        sxdp_flags: mode | libc::XDP_USE_NEED_WAKEUP,
        sxdp_ifindex: ifindex,
        sxdp_queue_id: queue,
        sxdp_shared_umem_fd: 0,
    };
    // SAFETY: `addr` is live and its size is passed.
    unsafe {
        libc::bind(
            fd,
            &addr as *const libc::sockaddr_xdp as *const libc::sockaddr,
            std::mem::size_of::<libc::sockaddr_xdp>() as libc::socklen_t,
        ) == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jumps_land_on_the_pass_exit() {
        let p = program(3);
        for (i, ins) in p.iter().enumerate() {
            if ins.code == JGT_X || ins.code == JNE_K {
                let target = i as i64 + 1 + i64::from(ins.off);
                assert_eq!(p[target as usize].code, MOV64_K, "jump at {i}");
                assert_eq!(p[target as usize].imm, XDP_PASS);
                assert_eq!(p[target as usize + 1].code, EXIT);
            }
        }
    }

    #[test]
    fn the_ethertype_compare_matches_the_wire_bytes() {
        let p = program(3);
        let wire = ETHERTYPE.to_be_bytes();
        assert_eq!(p[6].imm, i32::from(u16::from_le_bytes(wire)));
    }
}
