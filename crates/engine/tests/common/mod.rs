//! Helpers shared by the engine's integration tests: the cyclic datagram list of a one-LRW
//! test bus, the non-real-time thread settings, polling/counter look-ups on an engine, and veth pairs.

// Each test binary uses a part of these helpers.
#![allow(dead_code)]

use std::collections::VecDeque;
use std::process::Command as Process;
use std::time::{Duration, Instant};

use ether_ros_engine::plan::{CyclicDatagram, DcMode, FramePlan, Logical, Policy, RtPlan};
use ether_ros_engine::{now_ns, Engine, Received};

/// Station address of the DC reference slave on the test buses.
pub const DC_REF_STATION: u16 = 0x1001;

/// A logical datagram of the image bytes `image_offset..+length` at logical address
/// 0x1_0000 + image_offset.
pub fn logical(command: Logical, image_offset: usize, length: usize, wkc: u16) -> CyclicDatagram {
    CyclicDatagram::Logical {
        command,
        address: 0x1_0000 + image_offset as u32,
        length,
        image_offset,
        expected_wkc: wkc,
    }
}

/// The one cyclic frame of a test bus: the DC datagrams `dc` asks for, then one LRW of
/// `length` bytes at logical address 0x1_0000 expecting working counter `expected_wkc`.
pub fn cyclic_frame(dc: DcMode, length: usize, expected_wkc: u16) -> Vec<FramePlan> {
    let mut datagrams = vec![];
    if dc == DcMode::RefFollowsMaster {
        datagrams.push(CyclicDatagram::DcWriteRef {
            station: DC_REF_STATION,
        });
    }
    if dc != DcMode::Off {
        datagrams.push(CyclicDatagram::DcSync {
            station: DC_REF_STATION,
        });
    }
    datagrams.push(logical(Logical::Lrw, 0, length, expected_wkc));
    vec![FramePlan {
        datagrams,
        every: 1,
        watchdog_ns: 0,
    }]
}

/// Thread settings any process may use: policy "other", no CPU pinning, no locked memory.
pub fn non_rt() -> RtPlan {
    RtPlan {
        policy: Policy::Other,
        priority: 0,
        cpu: None,
        runtime_ns: 0,
        lock_memory: false,
    }
}

/// Poll `cond` for up to 10 s (generous: this is about behaviour, not speed).
pub fn wait_for(mut cond: impl FnMut() -> bool, what: &str) {
    let start = Instant::now();
    while !cond() {
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "timed out waiting for {what}"
        );
        std::thread::sleep(Duration::from_micros(500));
    }
}

/// The engine's statistics counter `name`; panics if the engine has no such counter.
pub fn counter(e: &Engine, name: &str) -> u64 {
    e.stats()
        .counters
        .iter()
        .find(|(n, _)| *n == name)
        .unwrap_or_else(|| panic!("the engine has no counter named {name}"))
        .1
}

/// A veth pair created for one test and deleted when dropped.
pub struct Veth {
    pub master: String,
    pub peer: String,
}

impl Veth {
    /// A pair named `{prefix}m{pid}` / `{prefix}p{pid}` (distinct prefixes keep parallel test
    /// binaries apart). None when it cannot be created (no CAP_NET_ADMIN, no `ip`).
    pub fn create(prefix: &str) -> Option<Veth> {
        let tag = std::process::id() % 100_000;
        let v = Veth {
            master: format!("{prefix}m{tag}"),
            peer: format!("{prefix}p{tag}"),
        };
        let ok = |args: &[&str]| {
            Process::new("ip")
                .args(args)
                .output()
                .map(|o| o.status.success())
                .unwrap_or(false)
        };
        if !ok(&[
            "link", "add", &v.master, "type", "veth", "peer", "name", &v.peer,
        ]) {
            return None;
        }
        let up = ok(&["link", "set", &v.master, "up"]) && ok(&["link", "set", &v.peer, "up"]);
        // IPv6 link-local autoconfiguration would put foreign frames on the wire: harmless for
        // the audit (they are filtered by EtherType), but keep the link quiet anyway.
        for name in [&v.master, &v.peer] {
            let _ = std::fs::write(format!("/proc/sys/net/ipv6/conf/{name}/disable_ipv6"), "1");
        }
        up.then_some(v)
    }
}

impl Drop for Veth {
    fn drop(&mut self) {
        let _ = Process::new("ip")
            .args(["link", "del", &self.master])
            .output();
    }
}

/// A test link's receive: the next queued reply into `buf`, stamped now (rt_audit's links
/// answer in place and do not use it).
#[allow(dead_code)]
pub fn pop_reply(queue: &mut VecDeque<Vec<u8>>, buf: &mut [u8]) -> Option<Received> {
    queue.pop_front().map(|f| {
        buf[..f.len()].copy_from_slice(&f);
        Received {
            len: f.len(),
            rx_ns: now_ns(),
        }
    })
}
