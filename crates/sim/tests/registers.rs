//! The register table of `docs/simulator.md`, checked register by register for each selectable
//! chip, through real datagrams (the same path a master's frames take).

mod common;

use common::*;
use ether_ros_protocol::Command;
use ether_ros_sim::chip::EscChip;
use ether_ros_sim::Network;

fn net_of(chip: EscChip, n: usize, dc: bool) -> Network {
    let mut net = Network::with_manual_clock(1_000_000_000);
    for _ in 0..n {
        let mut spec = io_spec();
        spec.esc = chip;
        spec.dc_supported = dc;
        net.add_slave(spec).unwrap();
    }
    assign_addresses(&mut net);
    net
}

fn read16(net: &mut Network, pos: usize, ado: u16) -> u16 {
    let (d, wkc) = fprd(net, station(pos), ado, 2);
    assert_eq!(wkc, 1, "FPRD {ado:#06x} answered");
    u16::from_le_bytes([d[0], d[1]])
}

/// (register, ET1100, ET1200, LAN9252): the identity and capability registers.
const IDENTITY: &[(u16, &str, [u8; 3])] = &[
    (0x0000, "type", [0x11, 0x12, 0xC0]),
    (0x0001, "revision", [0x00, 0x00, 0x01]),
    (0x0004, "FMMUs supported", [8, 3, 3]),
    (0x0005, "SyncManagers supported", [8, 4, 4]),
    (0x0006, "RAM size (KiB)", [8, 1, 4]),
    (0x0007, "port descriptor", [0xAF, 0x2B, 0x0F]),
];
const BUILD: [u16; 3] = [0x0002, 0x0001, 0x0001];
const FEATURES: [u16; 3] = [0x01FC, 0x01FC, 0x01CC];
const CHIPS: [EscChip; 3] = [EscChip::Et1100, EscChip::Et1200, EscChip::Lan9252];

#[test]
fn identity_and_capability_registers_per_chip() {
    for (c, chip) in CHIPS.into_iter().enumerate() {
        let mut net = net_of(chip, 1, true);
        for &(ado, what, values) in IDENTITY {
            let (d, _) = fprd(&mut net, station(0), ado, 1);
            assert_eq!(d[0], values[c], "{chip:?} {what} ({ado:#06x})");
        }
        assert_eq!(read16(&mut net, 0, 0x0002), BUILD[c], "{chip:?} build");
        let features = read16(&mut net, 0, 0x0008);
        assert_eq!(features, FEATURES[c], "{chip:?} features");
        assert_ne!(features & 0x0100, 0, "enhanced DC SYNC activation");
        assert_eq!(
            features & 0x0E00,
            0,
            "LRW, BRW/APRW/FPRW supported, FMMUs free"
        );
        // Identity registers are read only.
        fpwr(&mut net, station(0), 0x0000, &[0xFF; 10]);
        let (d, _) = fprd(&mut net, station(0), 0x0000, 1);
        assert_eq!(d[0], IDENTITY[0].2[c], "{chip:?} type is read only");
    }
}

#[test]
fn a_slave_without_dc_clears_only_the_dc_feature_bits() {
    for (c, chip) in CHIPS.into_iter().enumerate() {
        let mut net = net_of(chip, 1, false);
        let features = read16(&mut net, 0, 0x0008);
        assert_eq!(features, FEATURES[c] & !0x010C, "{chip:?}");
    }
}

#[test]
fn fmmus_and_sync_managers_beyond_the_chip_read_zero_and_ignore_writes() {
    for chip in CHIPS {
        let p = chip.profile();
        let mut net = net_of(chip, 1, true);
        for k in 0..8u16 {
            let fmmu = 0x0600 + 16 * k;
            fpwr(&mut net, station(0), fmmu, &[0x5A; 4]);
            let (d, _) = fprd(&mut net, station(0), fmmu, 4);
            let present = k < u16::from(p.fmmus);
            assert_eq!(d == [0x5A; 4], present, "{chip:?} FMMU {k}");
            let sm = 0x0800 + 8 * k;
            fpwr(&mut net, station(0), sm, &[0x34, 0x12]);
            let (d, _) = fprd(&mut net, station(0), sm, 2);
            let present = k < u16::from(p.sync_managers);
            assert_eq!(d == [0x34, 0x12], present, "{chip:?} SM {k}");
        }
    }
}

#[test]
fn process_ram_is_the_chips_size() {
    for chip in CHIPS {
        let kib = chip.profile().ram_kib as u16;
        let mut net = net_of(chip, 1, true);
        let last = 0x1000 + kib * 1024 - 2;
        fpwr(&mut net, station(0), last, &[0xA5, 0xA5, 0xA5, 0xA5]);
        let (d, _) = fprd(&mut net, station(0), last, 4);
        assert_eq!(d, vec![0xA5, 0xA5, 0, 0], "{chip:?}: RAM ends at {kib} KiB");
    }
}

#[test]
fn dl_status_per_port_on_a_line() {
    for chip in CHIPS {
        let mut net = net_of(chip, 2, true);
        let first = read16(&mut net, 0, 0x0110);
        let last = read16(&mut net, 1, 0x0110);
        // Bit 0 EEPROM loaded (PDI operational), bit 1 PDI watchdog not expired.
        assert_eq!(first & 0x0003, 0x0003, "{chip:?}");
        // Ports 0 and 1 have a link, both open, communication on both.
        assert_eq!(first & 0x00F0, 0x0030, "{chip:?} links");
        assert_eq!(
            first & 0x0F00,
            0x0A00,
            "{chip:?} ports 0/1 open + communication"
        );
        // Ports 2 and 3 (not connected or not there): loop closed, no link.
        assert_eq!(first & 0xF000, 0x5000, "{chip:?} ports 2/3 closed");
        // The last slave closes port 1 (no link behind it).
        assert_eq!(last & 0x00F0, 0x0010, "{chip:?}");
        assert_eq!(last & 0x0F00, 0x0600, "{chip:?} port 1 closed");
    }
}

#[test]
fn source_mac_bit_is_set_not_toggled() {
    let mut net = net_of(EscChip::Et1100, 1, true);
    let mut buf = [0u8; ether_ros_protocol::MAX_FRAME_LEN];
    for mac0 in [0x00u8, 0x02, 0x01, 0x03] {
        let mut mac = ether_ros_protocol::MASTER_MAC;
        mac[0] = mac0;
        let mut b = ether_ros_protocol::FrameBuilder::new(&mut buf, mac).unwrap();
        b.push(Command::Brd, 1, 0, Some(&[0, 0]), 0).unwrap();
        let n = b.finish();
        assert!(net.process_frame(&mut buf[..n]));
        assert_eq!(buf[6], mac0 | 0x02, "source MAC byte 0 after {mac0:#04x}");
    }
}

#[test]
fn chip_names_are_validated() {
    assert!(EscChip::from_name("lan9252").is_ok());
    let err = EscChip::from_name("et1300").unwrap_err();
    assert!(err.contains("'et1300'"), "{err}");
}
