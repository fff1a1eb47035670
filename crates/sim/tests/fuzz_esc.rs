//! Fuzzing the simulated ESC with register writes a real master could send (proptest, fixed
//! seed): any sequence of physical and logical writes, at any time, leaves the slave as a real
//! ESC (ET1100 datasheet) would be — never a panic, identity registers unchanged, always
//! reachable by position, and back in service after the reset every master does at start-up
//! (AL INIT with acknowledge, FMMUs and SyncManagers cleared, station address assigned).
//!
//! `FUZZ_CASES` (default 128) and `FUZZ_SEED` (default 1) set the run.

mod common;

use common::*;
use ether_ros_protocol::{self as wire, Command, FrameBuilder};
use ether_ros_sim::Network;
use proptest::prelude::*;
use proptest::test_runner::{Config, RngSeed};

fn config() -> Config {
    let env = |name: &str, default: u64| {
        std::env::var(name)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(default)
    };
    Config {
        cases: env("FUZZ_CASES", 128) as u32,
        rng_seed: RngSeed::Fixed(env("FUZZ_SEED", 1)),
        failure_persistence: None,
        ..Config::default()
    }
}

/// One datagram of the fuzz: a write (or read-write) command, where, what, and how long the
/// clock runs before it.
#[derive(Clone, Debug)]
struct Access {
    cmd: Command,
    /// Register / memory offset (physical commands) or logical address.
    offset: u32,
    data: Vec<u8>,
    wait_ns: u64,
}

/// Offsets weighted towards what matters: the register space (below 0x1000, with the AL,
/// DL, SII, FMMU, SM and DC blocks), the process RAM, and anywhere.
fn offset() -> impl Strategy<Value = u32> {
    prop_oneof![
        4 => 0u32..0x1000,
        2 => prop_oneof![Just(0x0120u32), Just(0x0400), Just(0x0600), Just(0x0800), Just(0x0808),
                         Just(0x0810), Just(0x0900), Just(0x0910), Just(0x0980), Just(0x09A0)],
        2 => 0x1000u32..0x1400,
        1 => any::<u16>().prop_map(u32::from),
    ]
}

/// A SyncManager or FMMU configured over any memory, the register space included.
fn window_write() -> impl Strategy<Value = Access> {
    prop_oneof![
        (0usize..8, 0u16..0x2000, any::<u16>(), any::<u8>()).prop_map(
            |(k, start, len, control)| {
                Access {
                    cmd: Command::Apwr,
                    offset: 0x0800 + 8 * k as u32,
                    data: sm_bytes(start, len, control, 1).to_vec(),
                    wait_ns: 0,
                }
            }
        ),
        (0usize..8, any::<u32>(), any::<u16>(), 0u16..0x2000, 1u8..=3).prop_map(
            |(k, log, len, phys, kind)| Access {
                cmd: Command::Apwr,
                offset: 0x0600 + 16 * k as u32,
                data: fmmu_bytes(log % 0x10000, len, 0, 7, phys, 0, kind).to_vec(),
                wait_ns: 0,
            }
        ),
    ]
}

fn access(eeprom: bool) -> impl Strategy<Value = Access> {
    let cmd = prop_oneof![
        Just(Command::Apwr),
        Just(Command::Fpwr),
        Just(Command::Bwr),
        Just(Command::Aprw),
        Just(Command::Lwr),
        Just(Command::Lrw),
    ];
    let random = (
        cmd,
        offset(),
        proptest::collection::vec(any::<u8>(), 1..48),
        0u64..2_000_000,
    )
        .prop_map(|(cmd, offset, data, wait_ns)| Access {
            cmd,
            offset,
            data,
            wait_ns,
        })
        .prop_filter("EEPROM interface", move |a| {
            eeprom || !(a.offset < 0x0510 && a.offset + a.data.len() as u32 > 0x0500)
        });
    prop_oneof![3 => random, 1 => window_write()]
}

/// Send one datagram; None when the frame did not come back.
fn send(net: &mut Network, a: &Access) -> Option<u16> {
    let address = match a.cmd {
        Command::Apwr | Command::Aprw => wire::auto_increment_address(0, a.offset as u16),
        Command::Fpwr => wire::fixed_address(station(0), a.offset as u16),
        Command::Bwr => wire::fixed_address(0, a.offset as u16),
        _ => a.offset, // logical
    };
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    let mut b = FrameBuilder::new(&mut buf, wire::MASTER_MAC).unwrap();
    let slot = b.push(a.cmd, 7, address, Some(&a.data), 0).unwrap();
    let n = b.finish();
    net.advance_clock(a.wait_ns);
    net.process_frame(&mut buf[..n])
        .then(|| wire::read_wkc(&buf, &slot))
}

fn aprd(net: &mut Network, ado: u16, len: usize) -> Option<(Vec<u8>, u16)> {
    try_xfer(
        net,
        Command::Aprd,
        wire::auto_increment_address(0, ado),
        &vec![0; len],
    )
    .map(|(d, w, _)| (d, w))
}

/// What every master does before it configures a bus: INIT with acknowledge to all, every
/// FMMU and SyncManager cleared, station addresses by position.
fn master_reset(net: &mut Network) {
    let bwr = |net: &mut Network, ado: u16, data: &[u8]| {
        xfer(net, Command::Bwr, wire::fixed_address(0, ado), data).1
    };
    bwr(net, 0x0120, &[0x11, 0x00]);
    bwr(net, 0x0600, &[0; 256]);
    bwr(net, 0x0800, &[0; 128]);
    assign_addresses(net);
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn any_writes_leave_the_slave_reachable_and_recoverable(
        accesses in proptest::collection::vec(access(false), 1..24)
    ) {
        let mut net = net_with(1);
        assign_addresses(&mut net);
        let (identity, _) = aprd(&mut net, 0x0000, 8).unwrap();
        for a in &accesses {
            let _ = send(&mut net, a);
            // Reachable by position whatever was written: the registers stay registers.
            let (d, wkc) = aprd(&mut net, 0x0000, 8).expect("the frame comes back");
            prop_assert_eq!(wkc, 1, "APRD 0x0000 after {:?}", a);
            prop_assert_eq!(&d, &identity, "identity registers are read only ({:?})", a);
        }
        master_reset(&mut net);
        let (d, wkc) = fprd(&mut net, station(0), 0x0010, 2);
        prop_assert_eq!((u16::from_le_bytes([d[0], d[1]]), wkc), (station(0), 1));
        prop_assert_eq!(al_status(&mut net, station(0)).0 & 0x0f, 1, "INIT after the reset");
        to_preop(&mut net, station(0));
    }

    #[test]
    fn eeprom_and_any_other_writes_never_panic(
        accesses in proptest::collection::vec(access(true), 1..32)
    ) {
        let mut net = net_with(2);
        assign_addresses(&mut net);
        for a in &accesses {
            let _ = send(&mut net, a);
        }
        net.advance_clock(50_000_000);
        prop_assert!(aprd(&mut net, 0x0000, 2).is_some());
    }

    #[test]
    fn any_frame_bytes_never_panic(frame in proptest::collection::vec(any::<u8>(), 0..1514)) {
        let mut net = net_with(2);
        let mut f = frame.clone();
        if f.len() >= 16 {
            // Mostly EtherCAT frames, so the datagram walk is reached.
            f[12..14].copy_from_slice(&wire::ETHERTYPE.to_be_bytes());
        }
        let _ = net.process_frame(&mut f);
        let _ = net.process_frame(&mut frame.clone());
    }
}

#[test]
fn a_sync_manager_over_the_registers_leaves_the_slave_addressable() {
    // Issue 19: one 8-byte write of SM0 (start 0x0000, length 0x1000, enabled) made the slave
    // unaddressable until power-cycled. An ESC never lets an SM guard its registers.
    let mut net = net_with(1);
    assign_addresses(&mut net);
    assert_eq!(
        fpwr(
            &mut net,
            station(0),
            0x0800,
            &sm_bytes(0x0000, 0x1000, 0x26, 1)
        ),
        1
    );
    let (d, wkc) = fprd(&mut net, station(0), 0x0010, 2);
    assert_eq!((u16::from_le_bytes([d[0], d[1]]), wkc), (station(0), 1));
    fpwr(&mut net, station(0), 0x0120, &[0x11, 0]);
    fpwr(&mut net, station(0), 0x0800, &[0; 8]);
    to_preop(&mut net, station(0));
}

#[test]
fn a_logical_write_onto_the_fmmu_registers_takes_effect_after_the_datagram() {
    // Found by the fuzz: FMMU 1 maps logical 0x100.. onto the FMMU registers themselves; an LWR
    // there rewrote the FMMU list while the simulator walked it (index out of bounds).
    let mut net = net_with(1);
    assign_addresses(&mut net);
    let st = station(0);
    fpwr(
        &mut net,
        st,
        0x0600,
        &fmmu_bytes(0x0, 2, 0, 7, OUT_SM, 0, 2),
    );
    fpwr(
        &mut net,
        st,
        0x0610,
        &fmmu_bytes(0x100, 32, 0, 7, 0x0600, 0, 2),
    );
    let (_, wkc) = xfer(&mut net, Command::Lwr, 0x100, &[0; 32]);
    assert_eq!(wkc, 1, "the write through FMMU 1 counts");
    let (_, wkc) = xfer(&mut net, Command::Lwr, 0x100, &[0; 32]);
    assert_eq!(wkc, 0, "both FMMUs were cleared by the first write");
    let (d, wkc) = fprd(&mut net, st, 0x0600, 32);
    assert_eq!((d, wkc), (vec![0; 32], 1));
}

#[test]
fn writes_to_read_only_registers_are_ignored() {
    // ET1100 datasheet, register overview: the ESC information (0x0000..0x000B), the DL status
    // (0x0110) and the AL status and status code (0x0130..0x0135) are read-only for EtherCAT;
    // a write to them counts (the ESC answers the datagram) but changes nothing.
    let mut net = net_with(1);
    assign_addresses(&mut net);
    let st = station(0);
    for (ado, len) in [(0x0000u16, 12usize), (0x0110, 2), (0x0130, 6)] {
        let (before, _) = fprd(&mut net, st, ado, len);
        fpwr(&mut net, st, ado, &vec![0xA5; len]);
        let (after, wkc) = fprd(&mut net, st, ado, len);
        assert_eq!(
            (after, wkc),
            (before, 1),
            "register 0x{ado:04X} was written"
        );
    }
    assert_eq!(al_status(&mut net, st).0 & 0x0f, 1, "still INIT");
}
