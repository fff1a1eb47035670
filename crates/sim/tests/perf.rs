//! Cost of one cyclic frame through four Laelaps-leg slaves (run on demand:
//! `cargo test -p ether-ros-sim --release --test perf -- --ignored --nocapture`). Prints the
//! CPU share a 20 kHz cycle would take; asserts nothing about time (this VM has spikes).

mod common;

use std::time::Instant;

use common::*;
use ether_ros_protocol::{self as wire, Command, FrameBuilder};
use ether_ros_sim::Network;

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
    let steps: u64 = net
        .cells()
        .iter()
        .map(|c| ether_ros_sim::network::lock(c).counters.device_steps)
        .sum();
    println!(
        "per frame {:.2} µs (incl. {:.1} device steps), 20 kHz share {:.1} %",
        per_frame * 1e6,
        steps as f64 / frames as f64,
        per_frame * 20_000.0 * 100.0
    );
}

/// Cost of one drive period of the 2-axis CiA 402 model in CSP (a ramp on both axes) next to
/// one period of the Laelaps leg firmware measured in the same run (run on demand:
/// `cargo test -p ether-ros-sim --release --test perf cia402 -- --ignored --nocapture`).
#[test]
#[ignore]
fn cia402_step_cost_next_to_the_leg() {
    use ether_ros_sim::device::DeviceApp;
    use ether_ros_sim::devices::{cia402, laelaps_leg};

    let periods = 200_000u64;
    let mut od = cia402::dictionary(2);
    let mut drive = cia402::Cia402Drive::new(cia402::Cia402Config::from_params(&[]).unwrap());
    drive.reset(&mut od);
    let mut now = 0u64;
    drive.step(&mut od, now, true);
    for axis in [0u16, 0x800] {
        od.set_int(0x6060 + axis, 0, 8);
        for word in [0x06, 0x07, 0x0F] {
            od.set_int(0x6040 + axis, 0, word);
            for _ in 0..8 {
                now += cia402::PERIOD_NS;
                drive.step(&mut od, now, true);
            }
        }
    }
    let t = Instant::now();
    for k in 0..periods {
        if k % 8 == 0 {
            let target = (k / 8) as i64 * 20;
            od.set_int(0x607A, 0, target);
            od.set_int(0x687A, 0, -target);
        }
        now += cia402::PERIOD_NS;
        drive.step(&mut od, now, true);
    }
    let drive_ns = t.elapsed().as_nanos() as f64 / periods as f64;
    assert_eq!(od.get_int(0x6041, 0) & 0x6F, 0x27, "still enabled");

    let mut od = laelaps_leg::object_dictionary();
    let config = laelaps_leg::LaelapsLegConfig::from_params(&[]).unwrap();
    let mut leg = laelaps_leg::LaelapsLeg::new(config);
    leg.reset(&mut od);
    let mut now = 0u64;
    let t = Instant::now();
    for _ in 0..periods {
        now += laelaps_leg::PERIOD_NS;
        leg.step(&mut od, now, true);
    }
    let leg_ns = t.elapsed().as_nanos() as f64 / periods as f64;
    println!(
        "cia402 (2 axes) {drive_ns:.0} ns per 125 µs period ({:.2} % of a core); laelaps leg \
         {leg_ns:.0} ns per 100 µs period; ratio {:.2}",
        drive_ns / 125_000.0 * 100.0,
        drive_ns / leg_ns
    );
}

/// Cost of the frame path on a line of 1024 slaves in SAFEOP with a loopback firmware each:
/// the DC frame (FRMW to every slave), a logical frame for 38 slaves and a broadcast read.
/// Baseline in the same run: the older model (`FirmwareMode::Inline`), where each frame first
/// advances the firmware of every slave it reaches; against it the frame path alone
/// (`FirmwareMode::Threads`, the firmware belongs to the workers, here not running). Prints
/// both and their ratio (run on demand:
/// `cargo test -p ether-ros-sim --release --test perf frame_path -- --ignored --nocapture`).
#[test]
#[ignore]
fn frame_path_cost_for_1024_slaves() {
    use ether_ros_sim::network::FirmwareMode;
    const N: usize = 1024;
    const FRAMES: u32 = 2_000;
    let build = |mode: FirmwareMode| {
        let mut net = Network::with_manual_clock(1_000_000_000);
        for _ in 0..N {
            let mut s = io_spec();
            s.device = "loopback".into();
            s.loopback_links = vec![(0x7000, 1, 0x6000, 1)];
            net.add_slave(s).unwrap();
        }
        net.set_firmware_mode(mode);
        assign_addresses(&mut net);
        for p in 0..N {
            let st = station(p);
            to_preop(&mut net, st);
            to_safeop(&mut net, st, 0x1_0000 + 6 * p as u32);
        }
        net
    };
    // µs per frame, each frame 1 ms of simulated time after the last (a 1 kHz cycle).
    let time = |net: &mut Network, build: &dyn Fn(&mut FrameBuilder)| {
        let mut buf = [0u8; wire::MAX_FRAME_LEN];
        let mut b = FrameBuilder::new(&mut buf, wire::MASTER_MAC).unwrap();
        build(&mut b);
        let n = b.finish();
        let template = buf;
        let t = Instant::now();
        for _ in 0..FRAMES {
            net.advance_clock(1_000_000);
            buf[..n].copy_from_slice(&template[..n]);
            assert!(net.process_frame(&mut buf[..n]));
        }
        t.elapsed().as_secs_f64() / FRAMES as f64 * 1e6
    };
    type Build = Box<dyn Fn(&mut FrameBuilder)>;
    let frames: [(&str, Build); 3] = [
        (
            "FRMW 0x0910 (DC sync, every slave)",
            Box::new(|b| {
                b.push(
                    Command::Frmw,
                    1,
                    wire::fixed_address(station(0), 0x0910),
                    None,
                    8,
                )
                .unwrap();
            }),
        ),
        (
            "LRW of 38 slaves",
            Box::new(|b| {
                b.push(Command::Lrw, 1, 0x1_0000, None, 38 * 6).unwrap();
            }),
        ),
        (
            "BRD AL status (every slave)",
            Box::new(|b| {
                b.push(Command::Brd, 1, 0x0130 << 16, None, 2).unwrap();
            }),
        ),
    ];
    let mut inline = build(FirmwareMode::Inline);
    let mut threads = build(FirmwareMode::Threads);
    for (what, frame) in &frames {
        let base = time(&mut inline, frame.as_ref());
        let alone = time(&mut threads, frame.as_ref());
        println!(
            "{what}: inline firmware {base:.1} µs, frame path alone {alone:.1} µs per frame \
             ({:.0} ns per slave), ratio {:.2}",
            alone * 1e3 / N as f64,
            alone / base
        );
    }
}
