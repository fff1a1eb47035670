//! The firmware apart from the frame path (`FirmwareMode::Threads`): the device runs when its
//! worker advances it (here called directly, with the manual clock, as a worker would) and
//! exchanges process data with the ESC through the SyncManager buffers.

mod common;

use common::*;
use ether_ros_protocol::Command;
use ether_ros_sim::network::FirmwareMode;
use ether_ros_sim::Network;

/// One slave running the loopback model (output 0x7000:1 → input 0x6000:1), in OP, its
/// firmware left to a worker.
fn loopback_in_op() -> Network {
    let mut net = Network::with_manual_clock(1_000_000_000);
    let mut spec = io_spec();
    spec.device = "loopback".into();
    spec.loopback_links = vec![(0x7000, 1, 0x6000, 1)];
    net.add_slave(spec).unwrap();
    net.set_firmware_mode(FirmwareMode::Threads);
    assign_addresses(&mut net);
    let st = station(0);
    to_preop(&mut net, st);
    to_safeop(&mut net, st, 0x1_0000);
    xfer(&mut net, Command::Lrw, 0x1_0000, &[0; 6]);
    fpwr(&mut net, st, 0x0120, &[8, 0]);
    assert_eq!(al_status(&mut net, st), (8, 0));
    net
}

/// The worker's turn: advance the slave to the network's present.
fn worker_runs(net: &mut Network) {
    let now = net.now();
    assert!(net.slave(0).advance_firmware(now, u64::MAX));
}

#[test]
fn free_run_outputs_reach_the_firmware_at_its_step_and_its_inputs_the_next_frame() {
    let mut net = loopback_in_op();
    worker_runs(&mut net);
    let mut frame = [0u8; 6];
    frame[0..2].copy_from_slice(&0xBEEFu16.to_le_bytes());
    xfer(&mut net, Command::Lrw, 0x1_0000, &frame);
    // The frame path did not run the firmware: the output waits in the SyncManager.
    assert_eq!(net.slave(0).od.get_int(0x7000, 1), 0);
    let (d, _) = xfer(&mut net, Command::Lrd, 0x1_0002, &[0; 4]);
    assert_eq!(d, vec![0, 0, 0, 0], "no step yet, nothing looped back");
    // One firmware period later the worker takes the output, steps, publishes the input.
    net.advance_clock(250_000);
    worker_runs(&mut net);
    assert_eq!(net.slave(0).od.get_int(0x7000, 1), 0xBEEF);
    let (d, _) = xfer(&mut net, Command::Lrd, 0x1_0002, &[0; 4]);
    assert_eq!(d, vec![0xEF, 0xBE, 0, 0]);
}
