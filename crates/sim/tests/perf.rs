//! Cost of one cyclic frame through four Laelaps-leg slaves (run on demand:
//! `cargo test -p ether-ros-sim --release --test perf -- --ignored --nocapture`). Prints the
//! CPU share a 20 kHz cycle would take; asserts nothing about time (this VM has spikes).

mod common;

use std::time::Instant;

use common::*;
use ether_ros_sim::Network;
use ether_ros_wire::{self as wire, Command, FrameBuilder};

#[test]
#[ignore]
fn cyclic_frame_cost_for_four_legs() {
    let mut net = Network::with_manual_clock(1_000_000_000);
    for _ in 0..4 {
        let mut s = io_spec();
        s.device = "laelaps_leg".into();
        net.add_slave(s).unwrap();
    }
    assign_addresses(&mut net);
    for p in 0..4 {
        let st = station(p);
        to_preop(&mut net, st);
        fpwr(&mut net, st, 0x0810, &sm_bytes(OUT_SM, 2, 0x64, 1));
        fpwr(&mut net, st, 0x0818, &sm_bytes(IN_SM, 4, 0x20, 1));
        let log = 0x1_0000 + 6 * p as u32;
        fpwr(
            &mut net,
            st,
            0x0600,
            &fmmu_bytes(log, 2, 0, 7, OUT_SM, 0, 2),
        );
        fpwr(
            &mut net,
            st,
            0x0610,
            &fmmu_bytes(log + 2, 4, 0, 7, IN_SM, 0, 1),
        );
        fpwr(&mut net, st, 0x0120, &[4, 0]);
    }
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    let mut b = FrameBuilder::new(&mut buf, wire::MASTER_MAC).unwrap();
    b.push(Command::Lrw, 0, 0x1_0000, None, 24).unwrap();
    b.push(
        Command::Armw,
        1,
        wire::auto_increment_address(0, 0x0910),
        None,
        8,
    )
    .unwrap();
    let n = b.finish();
    let template = buf;
    let frames = 200_000u32;
    let t = Instant::now();
    for _ in 0..frames {
        net.advance_clock(50_000);
        buf[..n].copy_from_slice(&template[..n]);
        assert!(net.process_frame(&mut buf[..n]));
    }
    let per_frame = t.elapsed().as_secs_f64() / frames as f64;
    let steps: u64 = net.slaves.iter().map(|s| s.counters.device_steps).sum();
    println!(
        "per frame {:.2} µs (incl. {:.1} device steps), 20 kHz share {:.1} %",
        per_frame * 1e6,
        steps as f64 / frames as f64,
        per_frame * 20_000.0 * 100.0
    );
}
