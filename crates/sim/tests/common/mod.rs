//! Helpers for the ESC tests: a small SII image, a slave spec with a mailbox and one output and
//! one input PDO, and a way to exchange single-datagram frames.
#![allow(dead_code)]

use ether_ros_protocol::{self as wire, Command, FrameBuilder};
use ether_ros_sim::od::{dtype, Access, Entry, Object};
use ether_ros_sim::{MailboxSpec, Network, SlaveSpec};

pub const MBX_RX: (u16, u16) = (0x1000, 128);
pub const MBX_TX: (u16, u16) = (0x1080, 128);
pub const OUT_SM: u16 = 0x1100;
pub const IN_SM: u16 = 0x1180;

/// SII image: configuration area with checksum, identity, mailbox words, end marker.
pub fn sii_image(alias: u16, mailbox: bool) -> Vec<u8> {
    let mut w = [0u16; 0x41];
    w[0] = 0x0c80;
    w[4] = alias;
    w[8] = 0x0a12;
    w[10] = 0x86fd;
    w[11] = 0x00a9;
    if mailbox {
        w[0x18] = MBX_RX.0;
        w[0x19] = MBX_RX.1;
        w[0x1A] = MBX_TX.0;
        w[0x1B] = MBX_TX.1;
        w[0x1C] = 0x0004;
    }
    w[0x3E] = 0x0001;
    w[0x3F] = 0x0001;
    w[0x40] = 0xffff;
    let mut b: Vec<u8> = w.iter().flat_map(|x| x.to_le_bytes()).collect();
    b[14] = ether_ros_sim::sii::checksum(&b[..14]);
    b
}

fn entry(index: u16, sub: u8, t: u16, bits: u16, access: Access, value: &[u8]) -> Entry {
    Entry {
        index,
        subindex: sub,
        name: format!("{index:04x}:{sub}"),
        data_type: t,
        bit_length: bits,
        access,
        pdo_mappable: index >= 0x6000,
        value: value.to_vec(),
    }
}

/// A slave with a mailbox, output 0x7000:1 (u16) in 0x1600 and input 0x6000:1 (u32) in 0x1A00.
pub fn io_spec() -> SlaveSpec {
    let rw = Access::ReadWrite;
    let ro = Access::ReadOnly;
    let mut entries = vec![
        entry(0x7000, 1, dtype::UINT16, 16, rw, &[0, 0]),
        entry(0x6000, 1, dtype::UINT32, 32, ro, &[0x44, 0x33, 0x22, 0x11]),
        entry(0x1600, 0, dtype::UINT8, 8, rw, &[1]),
        entry(
            0x1600,
            1,
            dtype::UINT32,
            32,
            rw,
            &0x7000_0110u32.to_le_bytes(),
        ),
        entry(0x1A00, 0, dtype::UINT8, 8, rw, &[1]),
        entry(
            0x1A00,
            1,
            dtype::UINT32,
            32,
            rw,
            &0x6000_0120u32.to_le_bytes(),
        ),
        entry(0x1C12, 0, dtype::UINT8, 8, rw, &[1]),
        entry(0x1C12, 1, dtype::UINT16, 16, rw, &0x1600u16.to_le_bytes()),
        entry(0x1C13, 0, dtype::UINT8, 8, rw, &[1]),
        entry(0x1C13, 1, dtype::UINT16, 16, rw, &0x1A00u16.to_le_bytes()),
    ];
    entries.push(entry(
        0x1000,
        0,
        dtype::UINT32,
        32,
        ro,
        &[0x92, 0x01, 0x02, 0x00],
    ));
    let objects = [0x1000u16, 0x1600, 0x1A00, 0x1C12, 0x1C13, 0x6000, 0x7000]
        .iter()
        .map(|&i| Object {
            index: i,
            name: format!("{i:04x}"),
            object_code: if i == 0x1000 { 7 } else { 9 },
        })
        .collect();
    SlaveSpec {
        name: "io".into(),
        sii: sii_image(0, true),
        objects,
        entries,
        mailbox: Some(MailboxSpec {
            rx_offset: MBX_RX.0,
            rx_size: MBX_RX.1,
            tx_offset: MBX_TX.0,
            tx_size: MBX_TX.1,
        }),
        delay_ns: 1_000,
        ..Default::default()
    }
}

pub fn net_with(n: usize) -> Network {
    let mut net = Network::with_manual_clock(1_000_000_000);
    for _ in 0..n {
        net.add_slave(io_spec()).unwrap();
    }
    net
}

/// Send one datagram; returns (data, wkc, address after the trip) or None when unanswered.
pub fn try_xfer(
    net: &mut Network,
    cmd: Command,
    address: u32,
    data: &[u8],
) -> Option<(Vec<u8>, u16, u32)> {
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    let mut b = FrameBuilder::new(&mut buf, wire::MASTER_MAC).unwrap();
    let slot = b.push(cmd, 0x42, address, Some(data), 0).unwrap();
    let n = b.finish();
    if !net.process_frame(&mut buf[..n]) {
        return None;
    }
    assert_eq!(
        buf[6],
        wire::MASTER_MAC[0] | 0x02,
        "source MAC marked by the return path"
    );
    let addr = u32::from_le_bytes(buf[slot.header + 2..slot.header + 6].try_into().unwrap());
    Some((
        buf[slot.data..slot.data + slot.len].to_vec(),
        wire::read_wkc(&buf, &slot),
        addr,
    ))
}

pub fn xfer(net: &mut Network, cmd: Command, address: u32, data: &[u8]) -> (Vec<u8>, u16) {
    let (d, w, _) = try_xfer(net, cmd, address, data).expect("frame answered");
    (d, w)
}

pub fn fpwr(net: &mut Network, station: u16, ado: u16, data: &[u8]) -> u16 {
    xfer(net, Command::Fpwr, wire::fixed_address(station, ado), data).1
}

pub fn fprd(net: &mut Network, station: u16, ado: u16, len: usize) -> (Vec<u8>, u16) {
    xfer(
        net,
        Command::Fprd,
        wire::fixed_address(station, ado),
        &vec![0; len],
    )
}

pub fn station(pos: usize) -> u16 {
    0x1001 + pos as u16
}

/// Give every slave its station address 0x1001 + position.
pub fn assign_addresses(net: &mut Network) {
    for p in 0..net.len() {
        let w = xfer(
            net,
            Command::Apwr,
            wire::auto_increment_address(p as u16, 0x0010),
            &station(p).to_le_bytes(),
        )
        .1;
        assert_eq!(w, 1);
    }
}

pub fn al_status(net: &mut Network, st: u16) -> (u16, u16) {
    let (d, _) = fprd(net, st, 0x0130, 6);
    (
        u16::from_le_bytes([d[0], d[1]]),
        u16::from_le_bytes([d[4], d[5]]),
    )
}

pub fn sm_bytes(start: u16, len: u16, control: u8, activate: u8) -> [u8; 8] {
    let s = start.to_le_bytes();
    let l = len.to_le_bytes();
    [s[0], s[1], l[0], l[1], control, 0, activate, 0]
}

/// Configure the mailbox SyncManagers and go to PREOP.
pub fn to_preop(net: &mut Network, st: u16) {
    assert_eq!(
        fpwr(net, st, 0x0800, &sm_bytes(MBX_RX.0, MBX_RX.1, 0x26, 1)),
        1
    );
    assert_eq!(
        fpwr(net, st, 0x0808, &sm_bytes(MBX_TX.0, MBX_TX.1, 0x22, 1)),
        1
    );
    fpwr(net, st, 0x0120, &[2, 0]);
    assert_eq!(al_status(net, st), (2, 0));
}

/// FMMU bytes: logical start, length, bits, physical, type.
pub fn fmmu_bytes(
    log: u32,
    len: u16,
    lbit: u8,
    lstop: u8,
    phys: u16,
    pbit: u8,
    kind: u8,
) -> [u8; 16] {
    let mut f = [0u8; 16];
    f[0..4].copy_from_slice(&log.to_le_bytes());
    f[4..6].copy_from_slice(&len.to_le_bytes());
    f[6] = lbit;
    f[7] = lstop;
    f[8..10].copy_from_slice(&phys.to_le_bytes());
    f[10] = pbit;
    f[11] = kind;
    f[12] = 1;
    f
}

/// Configure process-data SMs (2 bytes out at OUT_SM, 4 bytes in at IN_SM) and FMMUs mapping
/// them at logical `log` (outputs) and `log + 2` (inputs), then request SAFEOP.
pub fn to_safeop(net: &mut Network, st: u16, log: u32) {
    assert_eq!(fpwr(net, st, 0x0810, &sm_bytes(OUT_SM, 2, 0x64, 1)), 1);
    assert_eq!(fpwr(net, st, 0x0818, &sm_bytes(IN_SM, 4, 0x20, 1)), 1);
    fpwr(net, st, 0x0600, &fmmu_bytes(log, 2, 0, 7, OUT_SM, 0, 2));
    fpwr(net, st, 0x0610, &fmmu_bytes(log + 2, 4, 0, 7, IN_SM, 0, 1));
    fpwr(net, st, 0x0120, &[4, 0]);
    assert_eq!(al_status(net, st), (4, 0));
}
