//! The frame path with the firmware on worker threads routes each datagram through precomputed
//! maps (station addresses, FMMU ranges) to only the slaves it addresses. These tests send the
//! same random frames to two networks, one routing that way and one visiting every slave (the
//! firmware inline), and require identical answers and identical slave memory: the maps change
//! which slaves are visited, never what a frame does.

mod common;

use common::*;
use ether_ros_protocol::{self as wire, Command, FrameBuilder};
use ether_ros_sim::faults::Rng;
use ether_ros_sim::network::FirmwareMode;
use ether_ros_sim::Network;

const SLAVES: usize = 12;

fn pair() -> (Network, Network) {
    let inline = net_with(SLAVES);
    let mut routed = net_with(SLAVES);
    routed.set_firmware_mode(FirmwareMode::Threads);
    (inline, routed)
}

/// A random datagram of the kinds a master sends, biased towards the registers and logical
/// ranges that change routing (station addresses, alias and DL control, FMMUs).
fn random_datagram(rng: &mut Rng) -> (Command, u32, Vec<u8>) {
    let pos = rng.below(SLAVES + 2) as u16; // sometimes past the end of the line
    let station = if rng.below(4) == 0 {
        0x1000 + rng.below(4) as u16 // a few aliases / stray addresses
    } else {
        0x1001 + rng.below(SLAVES + 1) as u16
    };
    let logical = 0x1_0000 + rng.below(64) as u32;
    let n = 1 + rng.below(12);
    let bytes = |rng: &mut Rng, n: usize| (0..n).map(|_| rng.next_u64() as u8).collect::<Vec<_>>();
    match rng.below(16) {
        14 => (
            // An SII reload (loads the alias from the EEPROM) or a read command.
            Command::Fpwr,
            wire::fixed_address(station, 0x0502),
            vec![0, if rng.below(2) == 0 { 0x04 } else { 0x01 }],
        ),
        0 => (
            Command::Apwr,
            wire::auto_increment_address(pos, 0x0010),
            (0x1001 + rng.below(SLAVES) as u16).to_le_bytes().to_vec(),
        ),
        1 => (
            Command::Fpwr,
            wire::fixed_address(station, 0x0012),
            (0x1000 + rng.below(4) as u16).to_le_bytes().to_vec(),
        ),
        2 => (
            Command::Fpwr,
            wire::fixed_address(station, 0x0100),
            vec![0, 0, 0, rng.below(2) as u8],
        ),
        3 => {
            // An FMMU: byte-aligned or not, read, write or both, onto the output or input area.
            let aligned = rng.below(2) == 0;
            let f = fmmu_bytes(
                logical,
                1 + rng.below(6) as u16,
                if aligned { 0 } else { rng.below(8) as u8 },
                if aligned { 7 } else { rng.below(8) as u8 },
                if rng.below(2) == 0 { OUT_SM } else { 0x1400 },
                if aligned { 0 } else { rng.below(8) as u8 },
                1 + rng.below(3) as u8,
            );
            let n = rng.below(2) as u16;
            (
                Command::Fpwr,
                wire::fixed_address(station, 0x0600 + 16 * n),
                f.to_vec(),
            )
        }
        4 => (Command::Lrw, logical, bytes(rng, n)),
        5 => (Command::Lrd, logical, vec![0; n]),
        6 => (Command::Lwr, logical, bytes(rng, n)),
        7 => (
            Command::Fprd,
            wire::fixed_address(station, 0x0010 + rng.below(4) as u16 * 2),
            vec![0; 2],
        ),
        8 => (
            Command::Aprd,
            wire::auto_increment_address(pos, 0x1400),
            vec![0; 4],
        ),
        9 => (
            Command::Brd,
            wire::auto_increment_address(0, 0x1400),
            vec![0; 2],
        ),
        10 => (
            Command::Bwr,
            wire::auto_increment_address(0, 0x1402),
            bytes(rng, 2),
        ),
        11 => (
            Command::Armw,
            wire::auto_increment_address(pos, 0x1404),
            bytes(rng, 4),
        ),
        12 => (
            Command::Frmw,
            wire::fixed_address(station, 0x1404),
            bytes(rng, 4),
        ),
        _ => (
            Command::Fprw,
            wire::fixed_address(station, 0x1400 + rng.below(8) as u16),
            bytes(rng, 3),
        ),
    }
}

fn same_frame(a: &mut Network, b: &mut Network, datagrams: &[(Command, u32, Vec<u8>)]) {
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    let mut fb = FrameBuilder::new(&mut buf, wire::MASTER_MAC).unwrap();
    for (k, (cmd, address, data)) in datagrams.iter().enumerate() {
        fb.push(*cmd, k as u8, *address, Some(data), 0).unwrap();
    }
    let n = fb.finish();
    let mut other = buf;
    let answered = (
        a.process_frame(&mut buf[..n]),
        b.process_frame(&mut other[..n]),
    );
    assert_eq!(answered.0, answered.1);
    assert_eq!(
        &buf[..n],
        &other[..n],
        "the routed network answered {datagrams:?} differently"
    );
}

#[test]
fn routed_frames_answer_as_visiting_every_slave() {
    for seed in 1..=40u64 {
        let (mut a, mut b) = pair();
        let mut rng = Rng::new(seed);
        if seed % 2 == 0 {
            // Half the runs start from a configured line, as after a master's bring-up.
            assign_addresses(&mut a);
            assign_addresses(&mut b);
        }
        for _ in 0..300 {
            let datagrams: Vec<_> = (0..1 + rng.below(4))
                .map(|_| random_datagram(&mut rng))
                .collect();
            same_frame(&mut a, &mut b, &datagrams);
        }
        for k in 0..SLAVES {
            assert!(
                a.slave(k).memory() == b.slave(k).memory(),
                "seed {seed}: slave {k}'s memory differs"
            );
        }
    }
}

#[test]
fn a_frame_that_moves_a_station_address_reaches_it_within_the_same_frame() {
    let (mut a, mut b) = pair();
    assign_addresses(&mut a);
    assign_addresses(&mut b);
    // Slave 3 takes address 0x2000, and the next datagram of the same frame writes there.
    let frame = [
        (
            Command::Fpwr,
            wire::fixed_address(station(3), 0x0010),
            0x2000u16.to_le_bytes().to_vec(),
        ),
        (
            Command::Fpwr,
            wire::fixed_address(0x2000, 0x1400),
            vec![0xAB],
        ),
    ];
    same_frame(&mut a, &mut b, &frame);
    assert_eq!(b.slave(3).memory()[0x1400], 0xAB);
    assert_eq!(fprd(&mut b, 0x2000, 0x1400, 1), (vec![0xAB], 1));
}
