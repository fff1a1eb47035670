//! Datagram commands, working counters, addressing, SII access and FMMU mapping.

mod common;

use common::*;
use ether_ros_protocol::{self as wire, Command, FrameBuilder};
use ether_ros_sim::{Network, SlaveSpec};

#[test]
fn auto_increment_reads_the_addressed_slave_and_every_slave_increments_adp() {
    let mut net = net_with(3);
    let (d, wkc, addr) = try_xfer(
        &mut net,
        Command::Aprd,
        wire::auto_increment_address(1, 0x0000),
        &[0; 2],
    )
    .unwrap();
    assert_eq!(wkc, 1);
    assert_eq!(d, vec![0x11, 0x00], "ESC type register");
    // ADP was -1 and three slaves incremented it.
    assert_eq!(wire::split_address(addr).0, 2);
    // Position 3 does not exist: nobody answers, WKC 0.
    let (_, wkc, _) = try_xfer(
        &mut net,
        Command::Aprd,
        wire::auto_increment_address(3, 0),
        &[0; 2],
    )
    .unwrap();
    assert_eq!(wkc, 0);
}

#[test]
fn write_and_read_write_counters() {
    let mut net = net_with(2);
    assign_addresses(&mut net);
    // FPWR +1, FPRD +1, FPRW +3 (exchanges the value).
    assert_eq!(
        fpwr(&mut net, station(1), 0x0020, &[0; 2]),
        1,
        "reserved register write still counts"
    );
    let (d, wkc) = xfer(
        &mut net,
        Command::Fprw,
        wire::fixed_address(station(1), 0x0010),
        &0x2222u16.to_le_bytes(),
    );
    assert_eq!(wkc, 3);
    assert_eq!(d, station(1).to_le_bytes().to_vec());
    assert_eq!(
        fprd(&mut net, 0x2222, 0x0010, 2),
        (0x2222u16.to_le_bytes().to_vec(), 1)
    );
    // APRW on position 0.
    let (d, wkc) = xfer(
        &mut net,
        Command::Aprw,
        wire::auto_increment_address(0, 0x0010),
        &0x3333u16.to_le_bytes(),
    );
    assert_eq!((d, wkc), (station(0).to_le_bytes().to_vec(), 3));
    // Unmatched FPRD: WKC 0, data unchanged.
    assert_eq!(fprd(&mut net, 0x7777, 0x0010, 2), (vec![0, 0], 0));
}

#[test]
fn broadcast_counts_every_slave_and_ors_the_data() {
    let mut net = net_with(3);
    assign_addresses(&mut net);
    let (d, wkc) = xfer(
        &mut net,
        Command::Brd,
        wire::fixed_address(0, 0x0010),
        &[0; 2],
    );
    assert_eq!(wkc, 3);
    assert_eq!(u16::from_le_bytes([d[0], d[1]]), 0x1001 | 0x1002 | 0x1003);
    let (_, wkc) = xfer(
        &mut net,
        Command::Bwr,
        wire::fixed_address(0, 0x0200),
        &[0xff, 0xff],
    );
    assert_eq!(wkc, 3);
    let (_, wkc) = xfer(
        &mut net,
        Command::Brw,
        wire::fixed_address(0, 0x0200),
        &[1, 0],
    );
    assert_eq!(wkc, 9);
    // Each slave writes the data as it arrives: slave 0 the master's, the next ones the OR.
    assert_eq!(fprd(&mut net, station(0), 0x0200, 2).0, vec![1, 0]);
    assert_eq!(fprd(&mut net, station(2), 0x0200, 2).0, vec![0xff, 0xff]);
}

#[test]
fn nop_and_unknown_commands_leave_the_frame_alone() {
    let mut net = net_with(2);
    let (d, wkc) = xfer(&mut net, Command::Nop, 0, &[5, 6]);
    assert_eq!((d, wkc), (vec![5, 6], 0));
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    let mut b = FrameBuilder::new(&mut buf, wire::MASTER_MAC).unwrap();
    let slot = b.push(Command::Aprd, 0, 0, None, 2).unwrap();
    let n = b.finish();
    buf[slot.header] = 0x3f;
    assert!(net.process_frame(&mut buf[..n]));
    assert_eq!(wire::read_wkc(&buf, &slot), 0);
    assert_eq!(net.stats.unknown_commands, 1);
}

#[test]
fn armw_reads_at_the_addressed_slave_and_writes_at_the_others() {
    let mut net = net_with(3);
    assign_addresses(&mut net);
    // Use the ECAT event mask (plain rw register) to observe.
    fpwr(&mut net, station(1), 0x0200, &[0x34, 0x12]);
    let (d, wkc) = xfer(
        &mut net,
        Command::Armw,
        wire::auto_increment_address(1, 0x0200),
        &[0; 2],
    );
    assert_eq!(d, vec![0x34, 0x12]);
    assert_eq!(wkc, 3, "one read + two writes");
    assert_eq!(fprd(&mut net, station(2), 0x0200, 2).0, vec![0x34, 0x12]);
    assert_eq!(
        fprd(&mut net, station(0), 0x0200, 2).0,
        vec![0, 0],
        "slave before the reader sees the empty data"
    );
    let (_, wkc) = xfer(
        &mut net,
        Command::Frmw,
        wire::fixed_address(station(0), 0x0200),
        &[0; 2],
    );
    assert_eq!(wkc, 3);
}

#[test]
fn alias_addressing_needs_dl_control_bit_24() {
    let mut net = net_with(0);
    let mut spec = io_spec();
    spec.sii = sii_image(0x0A0A, true);
    net.add_slave(spec).unwrap();
    assign_addresses(&mut net);
    assert_eq!(fprd(&mut net, station(0), 0x0012, 2).0, vec![0x0A, 0x0A]);
    assert_eq!(fprd(&mut net, 0x0A0A, 0x0010, 2).1, 0);
    fpwr(&mut net, station(0), 0x0100, &[0, 0, 0, 1]);
    assert_eq!(
        fprd(&mut net, 0x0A0A, 0x0010, 2),
        (station(0).to_le_bytes().to_vec(), 1)
    );
    // The alias register is read-only for the master.
    fpwr(&mut net, station(0), 0x0012, &[1, 1]);
    assert_eq!(fprd(&mut net, station(0), 0x0012, 2).0, vec![0x0A, 0x0A]);
}

#[test]
fn dl_status_shows_the_line_position() {
    let mut net = net_with(2);
    assign_addresses(&mut net);
    let s0 = u16::from_le_bytes(fprd(&mut net, station(0), 0x0110, 2).0.try_into().unwrap());
    let s1 = u16::from_le_bytes(fprd(&mut net, station(1), 0x0110, 2).0.try_into().unwrap());
    assert_eq!(s0 & 0x0030, 0x0030, "links on ports 0 and 1");
    assert_eq!(s0 & 0x0400, 0, "port 1 loop open");
    assert_eq!(s1 & 0x0030, 0x0010);
    assert_eq!(s1 & 0x0400, 0x0400, "last slave closes port 1");
}

#[test]
fn sii_reads_eight_bytes_and_flags_out_of_range() {
    let mut net = net_with(1);
    assign_addresses(&mut net);
    let st = station(0);
    let (d, _) = fprd(&mut net, st, 0x0502, 2);
    assert_ne!(u16::from_le_bytes([d[0], d[1]]) & 0x0040, 0, "8-byte reads");
    // Read command with the address in the same write, as SOEM does.
    assert_eq!(
        fpwr(&mut net, st, 0x0502, &[0x00, 0x01, 0x08, 0x00, 0, 0]),
        1
    );
    let (d, _) = fprd(&mut net, st, 0x0502, 2);
    assert_eq!(u16::from_le_bytes([d[0], d[1]]) & 0xf800, 0);
    let (d, _) = fprd(&mut net, st, 0x0508, 8);
    assert_eq!(d, vec![0x12, 0x0a, 0, 0, 0xfd, 0x86, 0xa9, 0x00]);
    // Out of range: missing acknowledge; writing no command clears the error.
    fpwr(&mut net, st, 0x0502, &[0x00, 0x01, 0x00, 0x40, 0, 0]);
    let (d, _) = fprd(&mut net, st, 0x0502, 2);
    assert_ne!(u16::from_le_bytes([d[0], d[1]]) & 0x2000, 0);
    fpwr(&mut net, st, 0x0502, &[0, 0]);
    let (d, _) = fprd(&mut net, st, 0x0502, 2);
    assert_eq!(u16::from_le_bytes([d[0], d[1]]) & 0x7800, 0);
    // Write without write enable is refused; with it the word changes.
    fpwr(&mut net, st, 0x0504, &[0x20, 0, 0, 0, 0xcd, 0xab]);
    fpwr(&mut net, st, 0x0502, &[0x00, 0x02]);
    let (d, _) = fprd(&mut net, st, 0x0502, 2);
    assert_ne!(u16::from_le_bytes([d[0], d[1]]) & 0x4000, 0);
    fpwr(&mut net, st, 0x0502, &[0x01, 0x02]);
    assert_eq!(&net.slave(0).sii_image()[0x40..0x42], &[0xcd, 0xab]);
}

#[test]
fn sii_busy_bit_is_visible_while_the_eeprom_works() {
    let mut net = net_with(1);
    assign_addresses(&mut net);
    net.slave(0).set_sii_busy_ns(50_000);
    fpwr(
        &mut net,
        station(0),
        0x0502,
        &[0x00, 0x01, 0x08, 0x00, 0, 0],
    );
    let (d, _) = fprd(&mut net, station(0), 0x0502, 2);
    assert_ne!(d[1] & 0x80, 0);
    net.advance_clock(100_000);
    let (d, _) = fprd(&mut net, station(0), 0x0502, 2);
    assert_eq!(d[1] & 0x80, 0);
}

#[test]
fn fmmu_maps_bits_onto_physical_memory() {
    let mut net = net_with(2);
    assign_addresses(&mut net);
    // Slave 0: logical bits 0x100.3..=0x100.5 -> physical 0x1400 bits 6,7 and 0x1401 bit 0.
    fpwr(
        &mut net,
        station(0),
        0x0600,
        &fmmu_bytes(0x100, 1, 3, 5, 0x1400, 6, 3),
    );
    // Slave 1: byte-aligned write of logical 0x101 -> 0x1400.
    fpwr(
        &mut net,
        station(1),
        0x0600,
        &fmmu_bytes(0x101, 1, 0, 7, 0x1400, 0, 2),
    );
    // LWR: +1 for each slave written (ESC datasheet; +2 is LRW's write increment).
    let (_, wkc) = xfer(&mut net, Command::Lwr, 0x100, &[0b0010_1000, 0x5a]);
    assert_eq!(wkc, 1 + 1);
    let m = net.slave(0).memory()[0x1400..0x1402].to_vec();
    assert_eq!((m[0], m[1]), (0b0100_0000, 0b0000_0001));
    assert_eq!(net.slave(1).memory()[0x1400], 0x5a);
    // Read back: only the mapped bits come back; slave 1's write-only FMMU does not read.
    let (d, wkc) = xfer(&mut net, Command::Lrd, 0x100, &[0, 0]);
    assert_eq!(wkc, 1);
    assert_eq!(d, vec![0b0010_1000, 0]);
    // LRW: +1 read at slave 0 (+2 write there too: its FMMU is read/write), +2 at slave 1.
    let (_, wkc) = xfer(&mut net, Command::Lrw, 0x100, &[0, 0x11]);
    assert_eq!(wkc, 3 + 2);
    // A datagram outside every mapping: nobody counts.
    assert_eq!(xfer(&mut net, Command::Lrd, 0x2000, &[0; 4]).1, 0);
}

#[test]
fn an_esc_without_lrw_says_so_and_ignores_lrw_but_serves_lrd_and_lwr() {
    let mut net = Network::with_manual_clock(1_000_000_000);
    net.add_slave(io_spec()).unwrap();
    net.add_slave(SlaveSpec {
        lrw_supported: false,
        ..io_spec()
    })
    .unwrap();
    assign_addresses(&mut net);
    // Register 0x0008 bit 9: LRW not supported (ESC datasheet, "ESC Features supported").
    assert_eq!(fprd(&mut net, station(0), 0x0008, 2).0[1] & 0x02, 0);
    assert_eq!(fprd(&mut net, station(1), 0x0008, 2).0[1] & 0x02, 0x02);
    for k in 0..2 {
        // Logical byte 0x100 + k read/write at 0x1400 of slave k.
        fpwr(
            &mut net,
            station(k),
            0x0600,
            &fmmu_bytes(0x100 + k as u32, 1, 0, 7, 0x1400, 0, 3),
        );
    }
    // LRW: only slave 0 takes part (+3); slave 1 neither writes nor counts.
    let (_, wkc) = xfer(&mut net, Command::Lrw, 0x100, &[0x11, 0x22]);
    assert_eq!(wkc, 3);
    assert_eq!(net.slave(0).memory()[0x1400], 0x11);
    assert_eq!(net.slave(1).memory()[0x1400], 0);
    // LWR and LRD reach it: +1 each per slave.
    assert_eq!(xfer(&mut net, Command::Lwr, 0x100, &[0x33, 0x44]).1, 2);
    assert_eq!(net.slave(1).memory()[0x1400], 0x44);
    let (d, wkc) = xfer(&mut net, Command::Lrd, 0x100, &[0, 0]);
    assert_eq!((d, wkc), (vec![0x33, 0x44], 2));
}

#[test]
fn process_ram_beyond_its_size_reads_zero() {
    let mut net = net_with(1);
    assign_addresses(&mut net);
    assert_eq!(fpwr(&mut net, station(0), 0xF000, &[1, 2]), 1);
    assert_eq!(fprd(&mut net, station(0), 0xF000, 2).0, vec![0, 0]);
    assert_eq!(
        fprd(&mut net, station(0), 0xFFFF, 4).1,
        1,
        "an access wrapping the space does not panic"
    );
}

#[test]
fn several_datagrams_are_processed_slave_by_slave() {
    let mut net = net_with(2);
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    let mut b = FrameBuilder::new(&mut buf, wire::MASTER_MAC).unwrap();
    let s1 = b
        .push(
            Command::Bwr,
            0,
            wire::fixed_address(0, 0x0200),
            Some(&[9, 0]),
            0,
        )
        .unwrap();
    let s2 = b
        .push(Command::Brd, 1, wire::fixed_address(0, 0x0200), None, 2)
        .unwrap();
    let n = b.finish();
    assert!(net.process_frame(&mut buf[..n]));
    assert_eq!(wire::read_wkc(&buf, &s1), 2);
    assert_eq!(wire::read_wkc(&buf, &s2), 2);
    assert_eq!(buf[s2.data], 9);
    assert_eq!(net.stats.per_command[Command::Brd as usize], 1);
}
