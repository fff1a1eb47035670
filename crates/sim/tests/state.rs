//! AL state machine, process data, mailbox, DC, watchdog, faults and fuzzing.

mod common;

use common::*;
use ether_ros_protocol::{self as wire, Command, FrameBuilder};
use ether_ros_sim::faults::Rng;

#[test]
fn invalid_transitions_set_the_error_flag_until_acknowledged() {
    let mut net = net_with(1);
    assign_addresses(&mut net);
    let st = station(0);
    assert_eq!(al_status(&mut net, st), (1, 0));
    fpwr(&mut net, st, 0x0120, &[8, 0]);
    assert_eq!(al_status(&mut net, st), (0x11, 0x0011));
    // Without acknowledge the slave ignores requests and keeps the error.
    fpwr(&mut net, st, 0x0120, &[2, 0]);
    assert_eq!(al_status(&mut net, st), (0x11, 0x0011));
    // Acknowledge + PREOP with unconfigured mailbox SMs: invalid mailbox configuration.
    fpwr(&mut net, st, 0x0120, &[0x12, 0]);
    assert_eq!(al_status(&mut net, st), (0x11, 0x0016));
    fpwr(&mut net, st, 0x0120, &[0x11, 0]);
    assert_eq!(al_status(&mut net, st), (1, 0));
    // Wrong mailbox size.
    fpwr(&mut net, st, 0x0800, &sm_bytes(MBX_RX.0, 64, 0x26, 1));
    fpwr(&mut net, st, 0x0808, &sm_bytes(MBX_TX.0, MBX_TX.1, 0x22, 1));
    fpwr(&mut net, st, 0x0120, &[2, 0]);
    assert_eq!(al_status(&mut net, st), (0x11, 0x0016));
    fpwr(&mut net, st, 0x0120, &[0x11, 0]);
    // An enabled SM keeps its configuration until disabled in the same write.
    fpwr(&mut net, st, 0x0800, &sm_bytes(MBX_RX.0, MBX_RX.1, 0x26, 1));
    fpwr(&mut net, st, 0x0120, &[2, 0]);
    assert_eq!(al_status(&mut net, st), (0x11, 0x0016));
    fpwr(&mut net, st, 0x0120, &[0x11, 0]);
    fpwr(&mut net, st, 0x0806, &[0]);
    to_preop(&mut net, st);
    // Unknown state value.
    fpwr(&mut net, st, 0x0120, &[6, 0]);
    assert_eq!(al_status(&mut net, st), (0x12, 0x0012));
    fpwr(&mut net, st, 0x0120, &[0x12, 0]);
    // PREOP -> OP skips SAFEOP: invalid; BOOT without a bootstrap mailbox: not supported.
    fpwr(&mut net, st, 0x0120, &[8, 0]);
    assert_eq!(al_status(&mut net, st), (0x12, 0x0011));
    fpwr(&mut net, st, 0x0120, &[0x11, 0]);
    fpwr(&mut net, st, 0x0120, &[3, 0]);
    assert_eq!(al_status(&mut net, st), (0x11, 0x0013));
}

#[test]
fn process_data_sms_are_checked_against_the_pdo_mapping() {
    let mut net = net_with(1);
    assign_addresses(&mut net);
    let st = station(0);
    to_preop(&mut net, st);
    // Output SM one byte too short.
    fpwr(&mut net, st, 0x0810, &sm_bytes(OUT_SM, 1, 0x64, 1));
    fpwr(&mut net, st, 0x0818, &sm_bytes(IN_SM, 4, 0x20, 1));
    fpwr(&mut net, st, 0x0120, &[4, 0]);
    assert_eq!(al_status(&mut net, st), (0x12, 0x001D));
    fpwr(&mut net, st, 0x0120, &[0x12, 0]);
    fpwr(&mut net, st, 0x0810, &sm_bytes(OUT_SM, 2, 0x64, 0));
    fpwr(&mut net, st, 0x0810, &sm_bytes(OUT_SM, 2, 0x64, 1));
    // Input SM with the wrong direction.
    fpwr(&mut net, st, 0x0818, &sm_bytes(IN_SM, 4, 0x24, 0));
    fpwr(&mut net, st, 0x0818, &sm_bytes(IN_SM, 4, 0x24, 1));
    fpwr(&mut net, st, 0x0120, &[4, 0]);
    assert_eq!(al_status(&mut net, st), (0x12, 0x001E));
    fpwr(&mut net, st, 0x0120, &[0x12, 0]);
    fpwr(&mut net, st, 0x0818, &sm_bytes(IN_SM, 4, 0x20, 0));
    // A mapping that points at a missing entry.
    net.slave(0).od.set_int(0x1600, 1, 0x7001_0110);
    to_safeop_err(&mut net, st, 0x0025);
    net.slave(0).od.set_int(0x1600, 1, 0x7000_0110);
    to_safeop(&mut net, st, 0x1_0000);
}

fn to_safeop_err(net: &mut ether_ros_sim::Network, st: u16, code: u16) {
    fpwr(net, st, 0x0810, &sm_bytes(OUT_SM, 2, 0x64, 1));
    fpwr(net, st, 0x0818, &sm_bytes(IN_SM, 4, 0x20, 1));
    fpwr(net, st, 0x0120, &[4, 0]);
    assert_eq!(al_status(net, st), (0x12, code));
    fpwr(net, st, 0x0120, &[0x12, 0]);
}

#[test]
fn op_needs_valid_outputs_and_exchanges_process_data_in_free_run() {
    let mut net = net_with(2);
    assign_addresses(&mut net);
    for p in 0..2 {
        to_preop(&mut net, station(p));
    }
    // PREOP: process-data SMs are disabled by the slave, LRW counts nothing.
    fpwr(
        &mut net,
        station(0),
        0x0600,
        &fmmu_bytes(0x1_0000, 2, 0, 7, OUT_SM, 0, 2),
    );
    fpwr(&mut net, station(0), 0x0810, &sm_bytes(OUT_SM, 2, 0x64, 1));
    assert_eq!(xfer(&mut net, Command::Lrw, 0x1_0000, &[0; 12]).1, 0);
    to_safeop(&mut net, station(0), 0x1_0000);
    to_safeop(&mut net, station(1), 0x1_0006);
    // OP requested before any outputs: the request stays pending (SAFEOP, no error) until
    // the SAFEOP->OP timeout, then it is refused with 0x0019.
    fpwr(&mut net, station(0), 0x0120, &[8, 0]);
    assert_eq!(al_status(&mut net, station(0)), (0x04, 0), "pending");
    assert!(net.slave(0).op_request_pending());
    net.advance_clock(9_000_000_000);
    assert_eq!(al_status(&mut net, station(0)), (0x04, 0), "still pending");
    net.advance_clock(1_100_000_000);
    assert_eq!(
        al_status(&mut net, station(0)),
        (0x14, 0x0019),
        "no outputs within the SAFEOP->OP timeout"
    );
    assert!(!net.slave(0).op_request_pending());
    fpwr(&mut net, station(0), 0x0120, &[0x14, 0]);
    // In SAFEOP the inputs are valid and outputs accepted: WKC 3 per slave.
    let mut frame = [0u8; 12];
    frame[0..2].copy_from_slice(&0xBEEFu16.to_le_bytes());
    frame[6..8].copy_from_slice(&0x1234u16.to_le_bytes());
    let (d, wkc) = xfer(&mut net, Command::Lrw, 0x1_0000, &frame);
    assert_eq!(wkc, 6);
    assert_eq!(&d[2..6], &[0x44, 0x33, 0x22, 0x11]);
    assert_eq!(
        net.slave(0).od.get_int(0x7000, 1),
        0,
        "SAFEOP keeps outputs away from the app"
    );
    for p in 0..2 {
        fpwr(&mut net, station(p), 0x0120, &[8, 0]);
        assert_eq!(al_status(&mut net, station(p)), (8, 0));
    }
    xfer(&mut net, Command::Lrw, 0x1_0000, &frame);
    assert_eq!(net.slave(0).od.get_int(0x7000, 1), 0xBEEF);
    assert_eq!(net.slave(1).od.get_int(0x7000, 1), 0x1234);
    net.slave(1).od.set_int(0x6000, 1, 0x0102_0304);
    let (d, _) = xfer(&mut net, Command::Lrd, 0x1_0008, &[0; 4]);
    assert_eq!(d, vec![4, 3, 2, 1]);
    // Back transitions are always allowed.
    fpwr(&mut net, station(1), 0x0120, &[2, 0]);
    assert_eq!(al_status(&mut net, station(1)), (2, 0));
    fpwr(&mut net, station(0), 0x0120, &[1, 0]);
    assert_eq!(al_status(&mut net, station(0)), (1, 0));
}

#[test]
fn op_requested_before_outputs_is_entered_when_the_first_outputs_arrive() {
    let mut net = net_with(1);
    assign_addresses(&mut net);
    let st = station(0);
    to_preop(&mut net, st);
    to_safeop(&mut net, st, 0x1_0000);
    // As ethercrab does it: request OP first, then start the cyclic exchange.
    fpwr(&mut net, st, 0x0120, &[8, 0]);
    assert_eq!(al_status(&mut net, st), (0x04, 0));
    // Another request replaces the pending one...
    fpwr(&mut net, st, 0x0120, &[2, 0]);
    assert_eq!(al_status(&mut net, st), (0x02, 0));
    assert!(!net.slave(0).op_request_pending());
    to_safeop(&mut net, st, 0x1_0000);
    fpwr(&mut net, st, 0x0120, &[8, 0]);
    net.advance_clock(5_000_000_000);
    // ...and the first outputs complete it, within the same frame.
    xfer(&mut net, Command::Lrw, 0x1_0000, &[0; 6]);
    assert_eq!(al_status(&mut net, st), (0x08, 0));
}

#[test]
fn esi_timeout_bounds_the_pending_request() {
    let mut spec = io_spec();
    spec.safeop_op_timeout_ms = 50;
    let mut net = ether_ros_sim::Network::with_manual_clock(1_000_000_000);
    net.add_slave(spec).unwrap();
    assign_addresses(&mut net);
    let st = station(0);
    to_preop(&mut net, st);
    to_safeop(&mut net, st, 0x1_0000);
    fpwr(&mut net, st, 0x0120, &[8, 0]);
    net.advance_clock(40_000_000);
    assert_eq!(al_status(&mut net, st), (0x04, 0));
    net.advance_clock(20_000_000);
    assert_eq!(al_status(&mut net, st), (0x14, 0x0019));
}

fn to_op(net: &mut ether_ros_sim::Network, st: u16) {
    to_preop(net, st);
    to_safeop(net, st, 0x1_0000);
    xfer(net, Command::Lrw, 0x1_0000, &[0; 6]);
    fpwr(net, st, 0x0120, &[8, 0]);
    assert_eq!(al_status(net, st), (8, 0));
}

#[test]
fn watchdog_expiry_drops_to_safeop_with_0x001b() {
    let mut net = net_with(1);
    assign_addresses(&mut net);
    let st = station(0);
    to_op(&mut net, st);
    for _ in 0..5 {
        net.advance_clock(50_000_000);
        xfer(&mut net, Command::Lrw, 0x1_0000, &[1, 0, 0, 0, 0, 0]);
    }
    assert_eq!(al_status(&mut net, st), (8, 0), "outputs kept coming");
    net.advance_clock(150_000_000);
    net.poll();
    assert!(net.slave(0).watchdog_expired);
    assert_eq!(al_status(&mut net, st), (0x14, 0x001B));
    assert_eq!(fprd(&mut net, st, 0x0440, 2).0, vec![0, 0]);
    assert_eq!(fprd(&mut net, st, 0x0442, 1).0, vec![1]);
}

fn mailbox_write(net: &mut ether_ros_sim::Network, st: u16, counter: u8, payload: &[u8]) -> u16 {
    let mut m = vec![0u8; MBX_RX.1 as usize];
    m[0..2].copy_from_slice(&(payload.len() as u16).to_le_bytes());
    m[5] = 0x03 | (counter << 4);
    m[6..6 + payload.len()].copy_from_slice(payload);
    fpwr(net, st, MBX_RX.0, &m)
}

#[test]
fn mailbox_handshake_and_sdo_upload() {
    let mut net = net_with(1);
    assign_addresses(&mut net);
    let st = station(0);
    // INIT: the mailbox is not active, reads and writes are refused.
    fpwr(&mut net, st, 0x0800, &sm_bytes(MBX_RX.0, MBX_RX.1, 0x26, 1));
    assert_eq!(mailbox_write(&mut net, st, 1, &[0; 10]), 0);
    fpwr(&mut net, st, 0x0800, &sm_bytes(MBX_RX.0, MBX_RX.1, 0x26, 0));
    to_preop(&mut net, st);
    // Empty read mailbox: refused.
    assert_eq!(fprd(&mut net, st, MBX_TX.0, MBX_TX.1 as usize).1, 0);
    // SDO upload 0x1000:00.
    let req = [0x00, 0x20, 0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0];
    assert_eq!(mailbox_write(&mut net, st, 1, &req), 1);
    // The answer is waiting: SM1 status shows "mailbox full".
    let (s, _) = fprd(&mut net, st, 0x080D, 1);
    assert_ne!(s[0] & 0x08, 0);
    let (d, wkc) = fprd(&mut net, st, MBX_TX.0, MBX_TX.1 as usize);
    assert_eq!(wkc, 1);
    assert_eq!(d[5] & 0x0f, 3, "CoE");
    assert_eq!(&d[6..8], &[0x00, 0x30], "SDO response");
    assert_eq!(&d[9..12], &[0x00, 0x10, 0x00]);
    assert_eq!(&d[12..16], &[0x92, 0x01, 0x02, 0x00]);
    // Read completely: empty again.
    assert_eq!(fprd(&mut net, st, MBX_TX.0, MBX_TX.1 as usize).1, 0);
    // Repeat request: the slave puts the last answer back.
    fpwr(&mut net, st, 0x080E, &[0x03]);
    let (d2, wkc) = fprd(&mut net, st, MBX_TX.0, MBX_TX.1 as usize);
    assert_eq!((wkc, &d2[..16]), (1, &d[..16]));
    assert_eq!(
        fprd(&mut net, st, 0x080F, 1).0[0] & 0x02,
        0x02,
        "repeat acknowledged"
    );
    // Unknown mailbox type: mailbox error reply (type 0, unsupported protocol).
    let mut m = vec![0u8; MBX_RX.1 as usize];
    m[0] = 4;
    m[5] = 0x0E | (2 << 4);
    fpwr(&mut net, st, MBX_RX.0, &m);
    let (d, _) = fprd(&mut net, st, MBX_TX.0, MBX_TX.1 as usize);
    assert_eq!((d[5] & 0x0f, d[6], d[8]), (0, 1, 2));
}

#[test]
fn a_full_write_mailbox_refuses_the_next_write_and_a_stalled_slave_never_answers() {
    let mut net = net_with(1);
    assign_addresses(&mut net);
    let st = station(0);
    to_preop(&mut net, st);
    net.slave(0).mailbox_stalled = true;
    let req = [0x00, 0x20, 0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0];
    assert_eq!(mailbox_write(&mut net, st, 1, &req), 1);
    assert_eq!(mailbox_write(&mut net, st, 2, &req), 0, "full: WKC stays 0");
    assert_eq!(fprd(&mut net, st, 0x0805, 1).0[0] & 0x08, 0x08);
    assert_eq!(fprd(&mut net, st, MBX_TX.0, 8).1, 0);
    net.slave(0).mailbox_stalled = false;
    net.poll();
    assert_eq!(fprd(&mut net, st, MBX_TX.0, MBX_TX.1 as usize).1, 1);
}

#[test]
fn receive_times_show_the_propagation_delays() {
    let mut net = net_with(3);
    assign_addresses(&mut net);
    let (_, wkc) = xfer(
        &mut net,
        Command::Bwr,
        wire::fixed_address(0, 0x0900),
        &[0; 4],
    );
    assert_eq!(wkc, 3);
    let t = |net: &mut ether_ros_sim::Network, p: usize| {
        let d = fprd(net, station(p), 0x0900, 8).0;
        (
            u32::from_le_bytes(d[0..4].try_into().unwrap()) as i64,
            u32::from_le_bytes(d[4..8].try_into().unwrap()) as i64,
        )
    };
    let (a0, a1) = t(&mut net, 0);
    let (b0, b1) = t(&mut net, 1);
    // Each slave's delay is 1 µs: port 1 of slave 0 sees the frame back after 2·2 µs, slave 1
    // after 2·1 µs.
    assert!((a1 - a0 - 4_000).abs() <= 2, "{}", a1 - a0);
    assert!((b1 - b0 - 2_000).abs() <= 2, "{}", b1 - b0);
}

#[test]
fn drift_compensation_converges_and_sync0_latches_process_data() {
    let mut net = net_with(0);
    for drift in [0.0, 60.0, -40.0] {
        let mut s = io_spec();
        s.drift_ppm = drift;
        s.delay_ns = 0;
        net.add_slave(s).unwrap();
    }
    assign_addresses(&mut net);
    // Offsets: make every system time equal to slave 0's.
    let t0 = net.slave(0).system_time();
    for p in 1..3 {
        let off = t0.wrapping_sub(net.slave(p).local_time());
        fpwr(&mut net, station(p), 0x0920, &off.to_le_bytes());
    }
    for _ in 0..500 {
        net.advance_clock(1_000_000);
        xfer(
            &mut net,
            Command::Armw,
            wire::auto_increment_address(0, 0x0910),
            &[0; 8],
        );
    }
    for p in 1..3 {
        let d = fprd(&mut net, station(p), 0x092C, 4).0;
        let diff = u32::from_le_bytes(d.try_into().unwrap()) & 0x7fff_ffff;
        assert!(diff < 50, "slave {p}: {diff} ns");
    }
    // SYNC0: activate 1 ms cycles on slave 1, then check the app sees outputs only at events.
    let st = station(1);
    to_op(&mut net, st);
    let now = net.slave(1).system_time();
    fpwr(&mut net, st, 0x09A0, &1_000_000u32.to_le_bytes());
    fpwr(&mut net, st, 0x0990, &(now + 500_000).to_le_bytes());
    fpwr(&mut net, st, 0x0981, &[3]);
    assert!(net.slave(1).sync0_active());
    xfer(&mut net, Command::Lrw, 0x1_0000, &[7, 0, 0, 0, 0, 0]);
    assert_eq!(
        net.slave(1).od.get_int(0x7000, 1),
        0,
        "not latched before SYNC0"
    );
    net.advance_clock(700_000);
    net.poll();
    assert_eq!(net.slave(1).od.get_int(0x7000, 1), 7);
    assert_eq!(fprd(&mut net, st, 0x098E, 1).0, vec![1]);
    assert_eq!(
        fprd(&mut net, st, 0x098E, 1).0,
        vec![0],
        "SYNC0 status clears on read"
    );
}

#[test]
fn dc_required_refuses_safeop_without_sync0() {
    let mut net = net_with(0);
    let mut s = io_spec();
    s.dc_required = true;
    net.add_slave(s).unwrap();
    assign_addresses(&mut net);
    let st = station(0);
    to_preop(&mut net, st);
    to_safeop_err(&mut net, st, 0x0030);
    fpwr(&mut net, st, 0x09A0, &400_000u32.to_le_bytes());
    fpwr(&mut net, st, 0x0981, &[3]);
    to_safeop(&mut net, st, 0x1_0000);
}

#[test]
fn faults_drop_refuse_reset_and_break_the_link() {
    let mut net = net_with(3);
    assign_addresses(&mut net);
    net.faults.drop_rate = 1.0;
    assert!(try_xfer(&mut net, Command::Brd, 0, &[0; 2]).is_none());
    // Lost on the way back: the write landed. Lost on the way out: it did not.
    assert!(try_xfer(
        &mut net,
        Command::Bwr,
        wire::fixed_address(0, 0x0200),
        &[5, 0]
    )
    .is_none());
    net.faults.drop_outbound = true;
    assert!(try_xfer(
        &mut net,
        Command::Bwr,
        wire::fixed_address(0, 0x0200),
        &[6, 0]
    )
    .is_none());
    net.faults.drop_outbound = false;
    net.faults.drop_rate = 0.0;
    net.faults.drop_burst = 0;
    assert_eq!(fprd(&mut net, station(1), 0x0200, 2).0, vec![5, 0]);
    assert!(try_xfer(&mut net, Command::Brd, 0, &[0; 2]).is_some());
    // Burst: one trigger drops `burst` frames.
    net.faults.drop_rate = 1.0;
    net.faults.drop_burst = 3;
    assert!(try_xfer(&mut net, Command::Brd, 0, &[0; 2]).is_none());
    net.faults.drop_rate = 0.0;
    assert!(try_xfer(&mut net, Command::Brd, 0, &[0; 2]).is_none());
    assert!(try_xfer(&mut net, Command::Brd, 0, &[0; 2]).is_none());
    assert!(try_xfer(&mut net, Command::Brd, 0, &[0; 2]).is_some());
    // Link break after slave 0: only slave 0 answers, and closes its port 1.
    net.set_link_cut(1, true);
    assert_eq!(xfer(&mut net, Command::Brd, 0, &[0; 2]).1, 1);
    assert_eq!(fprd(&mut net, station(0), 0x0110, 2).0[1] & 0x04, 0x04);
    net.set_link_cut(1, false);
    net.faults.link_down = true;
    assert!(try_xfer(&mut net, Command::Brd, 0, &[0; 2]).is_none());
    net.faults.link_down = false;
    // Refuse OP.
    net.slave(2).refuse_op = true;
    to_preop(&mut net, station(2));
    to_safeop(&mut net, station(2), 0x1_0000);
    xfer(&mut net, Command::Lrw, 0x1_0000, &[0; 6]);
    fpwr(&mut net, station(2), 0x0120, &[8, 0]);
    assert_eq!(al_status(&mut net, station(2)), (0x14, 0x001A));
    // Reset: back to INIT with power-on registers.
    assert!(net.reset_slave(2));
    assert_eq!(
        xfer(
            &mut net,
            Command::Aprd,
            wire::auto_increment_address(2, 0x0130),
            &[0; 2]
        )
        .0,
        vec![1, 0]
    );
    assert_eq!(
        xfer(
            &mut net,
            Command::Aprd,
            wire::auto_increment_address(2, 0x0010),
            &[0; 2]
        )
        .0,
        vec![0, 0]
    );
}

#[test]
fn corrupted_answers_differ_from_clean_ones() {
    let mut net = net_with(1);
    net.faults.corrupt_rate = 1.0;
    let (d, w, _) = try_xfer(&mut net, Command::Brd, 0, &[0; 32]).unwrap();
    assert!(d.iter().any(|&b| b != 0x11 && b != 0) || w != 1 || net.stats.frames_corrupted == 1);
    assert_eq!(net.stats.frames_corrupted, 1);
}

#[test]
fn random_bytes_and_mutated_frames_never_panic() {
    let mut net = net_with(3);
    assign_addresses(&mut net);
    to_preop(&mut net, station(0));
    let mut rng = Rng::new(0xE7C4);
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    for i in 0..60_000 {
        let n = rng.below(wire::MAX_FRAME_LEN + 1);
        if i % 2 == 0 {
            for b in buf[..n].iter_mut() {
                *b = rng.next_u64() as u8;
            }
            if n > 16 {
                // Often a plausible header, so parsing goes deeper.
                buf[12] = 0x88;
                buf[13] = 0xA4;
                buf[15] = (buf[15] & 0x07) | 0x10;
            }
        } else {
            // A valid frame with a few flipped bytes.
            let mut b = FrameBuilder::new(&mut buf, wire::MASTER_MAC).unwrap();
            for _ in 0..1 + rng.below(4) {
                let cmd = Command::from_u8(rng.below(15) as u8).unwrap();
                let mut data = [0u8; 64];
                for d in data.iter_mut() {
                    *d = rng.next_u64() as u8;
                }
                let len = rng.below(64);
                // Mostly registers (SMs, FMMUs, AL control, SII, DC) and the mailbox area.
                let ado = match rng.below(4) {
                    0 => rng.below(0x1000),
                    1 => 0x0800 + rng.below(0x40),
                    2 => 0x0900 + rng.below(0xB0),
                    _ => rng.below(0x10000),
                } as u32;
                let adp = [0u32, 1, 0xffff, 0xfffe, 0x1001, 0x1002, 0x1003][rng.below(7)];
                let addr = if cmd.addressing() == wire::Addressing::Logical {
                    rng.next_u64() as u32 & 0x0001_ffff
                } else {
                    (ado << 16) | adp
                };
                let _ = b.push(cmd, 0, addr, Some(&data[..len]), 0);
            }
            let len = b.finish();
            for _ in 0..rng.below(4) {
                let at = rng.below(len);
                buf[at] ^= rng.next_u64() as u8;
            }
            let _ = net.process_frame(&mut buf[..len]);
            net.advance_clock(rng.below(2_000_000) as u64);
            continue;
        }
        let _ = net.process_frame(&mut buf[..n]);
    }
    assert!(net.stats.frames_seen >= 60_000);
    let touched: u64 = net
        .cells()
        .iter()
        .map(|c| ether_ros_sim::network::lock(c).counters.al_errors)
        .sum();
    assert!(touched > 0, "the fuzzer reached the AL state machine");
}
