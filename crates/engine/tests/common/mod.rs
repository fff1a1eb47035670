//! Helpers shared by the engine's integration tests: the cyclic datagram list of a one-LRW
//! test bus, the non-real-time thread settings, and polling/counter look-ups on an engine.

use std::time::{Duration, Instant};

use ether_ros_engine::plan::{CyclicDatagram, DcMode, Policy, RtPlan};
use ether_ros_engine::Engine;

/// Station address of the DC reference slave on the test buses.
pub const DC_REF_STATION: u16 = 0x1001;

/// The cyclic datagrams of a test bus: the DC datagrams `dc` asks for, then one LRW of
/// `length` bytes at logical address 0x1_0000 expecting working counter `expected_wkc`.
pub fn cyclic_datagrams(dc: DcMode, length: usize, expected_wkc: u16) -> Vec<CyclicDatagram> {
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
    datagrams.push(CyclicDatagram::Lrw {
        address: 0x1_0000,
        length,
        image_offset: 0,
        expected_wkc,
    });
    datagrams
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
