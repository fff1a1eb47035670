//! Helpers shared by the engine's integration tests: the cyclic datagram list of a one-LRW
//! test bus, the non-real-time thread settings, and polling/counter look-ups on an engine.

use std::collections::VecDeque;
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
