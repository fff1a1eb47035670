//! Frames walking a tree of ports: the visiting (auto-increment) order, the receive-time
//! latches of every port, DL status of open and closed ports, and a cable pulled on a branch.
//!
//! The tree used (ET1100 coupler, ports visited 0 → 3 → 1 → 2):
//!
//! ```text
//! master ─100─ coupler ─port 3─300─ a
//!                      ─port 1─200─ b ─port 1─150─ c
//!                      ─port 2─400─ d
//! ```
//! (numbers: one-way link delays in ns).

mod common;

use common::*;
use ether_ros_protocol::{self as wire, Command};
use ether_ros_sim::chip::EscChip;
use ether_ros_sim::Network;

/// Where a slave's port 0 is connected: (parent index, parent's port).
type Upstream = Option<(usize, u8)>;

/// (name, alias, upstream, delay) in the order the frame visits them.
const TREE: &[(&str, u16, Upstream, u64)] = &[
    ("coupler", 100, None, 100),
    ("a", 101, Some((0, 3)), 300),
    ("b", 102, Some((0, 1)), 200),
    ("c", 103, Some((2, 1)), 150),
    ("d", 104, Some((0, 2)), 400),
];

fn spec(
    name: &str,
    alias: u16,
    upstream: Option<(usize, u8)>,
    delay_ns: u64,
) -> ether_ros_sim::SlaveSpec {
    let mut s = io_spec();
    s.name = name.into();
    s.sii = sii_image(alias, true);
    s.upstream = upstream;
    s.delay_ns = delay_ns;
    s.esc = EscChip::Et1100;
    s
}

fn tree() -> Network {
    let mut net = Network::with_manual_clock(1_000_000_000);
    for &(name, alias, up, d) in TREE {
        net.add_slave(spec(name, alias, up, d)).unwrap();
    }
    assign_addresses(&mut net);
    net
}

/// Alias of the slave at auto-increment position `pos`, or None when nobody answers.
fn alias_at(net: &mut Network, pos: u16) -> Option<u16> {
    let (d, wkc) = xfer(
        net,
        Command::Aprd,
        wire::auto_increment_address(pos, 0x0012),
        &[0; 2],
    );
    (wkc == 1).then(|| u16::from_le_bytes([d[0], d[1]]))
}

/// Receive times of ports 0..3 of a slave, relative to port 0's (ns).
fn port_times(net: &mut Network, pos: usize) -> [i64; 4] {
    let (d, wkc) = fprd(net, station(pos), 0x0900, 16);
    assert_eq!(wkc, 1);
    let t = |p: usize| u32::from_le_bytes(d[4 * p..4 * p + 4].try_into().unwrap()) as i64;
    [0, t(1) - t(0), t(2) - t(0), t(3) - t(0)]
}

fn dl_status(net: &mut Network, pos: usize) -> u16 {
    let (d, _) = fprd(net, station(pos), 0x0110, 2);
    u16::from_le_bytes([d[0], d[1]])
}

/// DL status bits of port p: (link, loop closed, communication).
fn port_bits(status: u16, p: u16) -> (bool, bool, bool) {
    (
        status & (1 << (4 + p)) != 0,
        status & (1 << (8 + 2 * p)) != 0,
        status & (1 << (9 + 2 * p)) != 0,
    )
}

#[test]
fn auto_increment_positions_follow_the_port_order() {
    let mut net = tree();
    for (pos, &(name, alias, _, _)) in TREE.iter().enumerate() {
        assert_eq!(
            alias_at(&mut net, pos as u16),
            Some(alias),
            "{name} at {pos}"
        );
    }
    assert_eq!(alias_at(&mut net, TREE.len() as u16), None);
    assert_eq!(net.visit_order(), &[0, 1, 2, 3, 4]);
    // A broadcast is processed once by every slave (only the pass after port 0 processes).
    assert_eq!(xfer(&mut net, Command::Brd, 0, &[0; 2]).1, 5);
}

#[test]
fn receive_times_latch_the_return_into_each_port() {
    let mut net = tree();
    xfer(
        &mut net,
        Command::Bwr,
        wire::fixed_address(0, 0x0900),
        &[0; 4],
    );
    // Coupler: port 3's branch (a) first: 2 × 300; then port 1's (b, c): + 2 × (200 + 150);
    // then port 2's (d): + 2 × 400.
    assert_eq!(
        port_times(&mut net, 0),
        [0, 600 + 700, 600 + 700 + 800, 600]
    );
    // b: port 1 comes back after c's loop; ports 2 and 3 are closed and keep zero.
    let b = port_times(&mut net, 2);
    assert_eq!(b[1], 300);
    // Port 0 of each slave latches when the frame arrives there: a arrives 300 ns after the
    // coupler, b after a's whole branch (600) + 200, d after both branches + 400.
    let pu = |net: &mut Network, pos: usize| {
        let (d, _) = fprd(net, station(pos), 0x0918, 8);
        u64::from_le_bytes(d.try_into().unwrap()) as i64
    };
    let t0 = pu(&mut net, 0);
    assert_eq!(pu(&mut net, 1) - t0, 300);
    assert_eq!(pu(&mut net, 2) - t0, 600 + 200);
    assert_eq!(pu(&mut net, 3) - t0, 600 + 200 + 150);
    assert_eq!(pu(&mut net, 4) - t0, 600 + 700 + 400);
}

#[test]
fn dl_status_shows_open_and_closed_ports() {
    let mut net = tree();
    let coupler = dl_status(&mut net, 0);
    for p in 0..4 {
        assert_eq!(
            port_bits(coupler, p),
            (true, false, true),
            "coupler port {p}"
        );
    }
    let a = dl_status(&mut net, 1);
    assert_eq!(port_bits(a, 0), (true, false, true));
    for p in 1..4 {
        assert_eq!(
            port_bits(a, p),
            (false, true, false),
            "leaf port {p} closed"
        );
    }
    let b = dl_status(&mut net, 2);
    assert_eq!(port_bits(b, 1), (true, false, true));
    assert_eq!(port_bits(b, 2), (false, true, false));
}

#[test]
fn a_cable_pulled_on_a_branch_hides_only_that_branch() {
    let mut net = tree();
    // Pull the cable on port 1 of the coupler: b and c are gone, a and d still answer.
    let b = net.slave_on_port(0, 1).unwrap();
    assert_eq!(b, 2);
    net.set_link_cut(b, true);
    assert_eq!(xfer(&mut net, Command::Brd, 0, &[0; 2]).1, 3);
    assert_eq!(alias_at(&mut net, 0), Some(100));
    assert_eq!(alias_at(&mut net, 1), Some(101));
    assert_eq!(alias_at(&mut net, 2), Some(104), "d moves up to position 2");
    assert_eq!(alias_at(&mut net, 3), None);
    let coupler = dl_status(&mut net, 0);
    assert_eq!(port_bits(coupler, 1), (false, true, false), "port 1 closed");
    assert_eq!(port_bits(coupler, 2), (true, false, true));
    // The frame skips the closed port: d's branch comes right after a's.
    xfer(
        &mut net,
        Command::Bwr,
        wire::fixed_address(0, 0x0900),
        &[0; 4],
    );
    let t = port_times(&mut net, 0);
    assert_eq!((t[3], t[2]), (600, 600 + 800));
    // Mended: everybody back in place.
    net.set_link_cut(b, false);
    assert_eq!(xfer(&mut net, Command::Brd, 0, &[0; 2]).1, 5);
    assert_eq!(alias_at(&mut net, 2), Some(102));
}

#[test]
fn a_cut_behind_a_slave_in_a_line_keeps_the_slaves_before_it() {
    let mut net = net_with(3);
    assign_addresses(&mut net);
    net.set_link_cut(2, true);
    assert_eq!(xfer(&mut net, Command::Brd, 0, &[0; 2]).1, 2);
    assert_eq!(port_bits(dl_status(&mut net, 1), 1), (false, true, false));
    assert_eq!(port_bits(dl_status(&mut net, 0), 1), (true, false, true));
}

#[test]
fn slaves_must_be_added_in_visiting_order() {
    let mut net = Network::with_manual_clock(0);
    net.add_slave(spec("coupler", 1, None, 100)).unwrap();
    net.add_slave(spec("x", 2, Some((0, 1)), 100)).unwrap();
    // Port 3 comes before port 1: a slave there would be reached before x.
    let err = net.add_slave(spec("y", 3, Some((0, 3)), 100)).unwrap_err();
    assert_eq!(err.field, "upstream");
    let err = err.to_string();
    assert!(err.contains("'y'") && err.contains("before 'x'"), "{err}");
    assert_eq!(net.len(), 2, "the refused slave is not kept");
    let err = net
        .add_slave(spec("z", 4, Some((0, 1)), 100))
        .unwrap_err()
        .to_string();
    assert!(err.contains("port 1 of 'coupler' is taken by 'x'"), "{err}");
    let mut small = spec("w", 5, Some((0, 2)), 100);
    small.esc = EscChip::Lan9252;
    net.add_slave(small).unwrap();
    let err = net
        .add_slave(spec("v", 6, Some((2, 2)), 100))
        .unwrap_err()
        .to_string();
    assert!(err.contains("has no port 2"), "{err}");
}
