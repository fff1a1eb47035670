//! The AF_XDP link on a real veth pair: EtherCAT frames go out through the XDP socket and the
//! far end's answers come back through the XDP program's redirect; other EtherTypes pass to the
//! kernel; a second link on the same interface is refused; closing detaches the program.
//!
//! Skipped (with a message) where the test may not create a veth pair or load BPF programs.

use std::process::Command as Process;
use std::sync::Mutex;

use ether_ros_engine::{now_ns, Link, LinkOptions, RawSocketLink, XdpLink, XdpMode};
use ether_ros_protocol::MAX_FRAME_LEN;

mod common;
use common::Veth;

/// The tests use one veth pair name per process: one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

/// A broadcast EtherCAT frame carrying one BRD datagram with `tag` in its index.
fn ethercat_frame(tag: u8) -> Vec<u8> {
    let mut f = vec![0u8; 60];
    f[..6].fill(0xff);
    f[6..12].copy_from_slice(&[0x02, 0, 0, 0, 0, 1]);
    f[12..14].copy_from_slice(&[0x88, 0xa4]);
    f[14..16].copy_from_slice(&(12u16 | 0x1000).to_le_bytes()); // 12 bytes, type 1
    f[16] = 0x07; // BRD
    f[17] = tag;
    f[20..22].copy_from_slice(&0x0130u16.to_le_bytes());
    f[22..24].copy_from_slice(&2u16.to_le_bytes());
    f
}

fn open_pair(prefix: &str) -> Option<(Veth, XdpLink)> {
    let Some(veth) = Veth::create(prefix) else {
        eprintln!("SKIPPED: cannot create a veth pair here (needs CAP_NET_ADMIN and `ip`)");
        return None;
    };
    match XdpLink::open(&veth.master, &LinkOptions::default()) {
        Ok(link) => Some((veth, link)),
        Err(e) => {
            eprintln!("SKIPPED: no AF_XDP link here ({e})");
            None
        }
    }
}

fn xdp_attached(ifname: &str) -> bool {
    let out = Process::new("ip")
        .args(["-d", "link", "show", "dev", ifname])
        .output()
        .expect("ip link show");
    let text = String::from_utf8_lossy(&out.stdout);
    text.contains("prog/xdp") || text.contains(" xdp ")
}

#[test]
fn frames_round_trip_through_the_xdp_socket() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some((veth, mut master)) = open_pair("xdx") else {
        return;
    };
    assert_eq!(master.mode(), XdpMode::Copy, "veth has no zero-copy");
    assert!(master.describe().contains("AF_XDP"));
    assert!(xdp_attached(&veth.master), "the program is attached");
    let mut far = RawSocketLink::open(&veth.peer).expect("raw socket on the far end");
    let mut buf = [0u8; MAX_FRAME_LEN];
    for i in 0..500u32 {
        let tag = i as u8;
        master.send(&ethercat_frame(tag)).expect("xdp send");
        let got = far
            .recv(&mut buf, now_ns() + 1_000_000_000)
            .expect("far recv")
            .expect("the frame reached the far end");
        assert_eq!(&buf[..got.len], &ethercat_frame(tag)[..], "frame {i}");
        // The far end answers with the working counter set and the source MAC bit flipped.
        buf[6] |= 0x02;
        buf[24] = 1;
        far.send(&buf[..got.len]).expect("far send");
        let mut reply = [0u8; MAX_FRAME_LEN];
        let r = master
            .recv(&mut reply, now_ns() + 1_000_000_000)
            .expect("xdp recv")
            .expect("the answer came back through the XDP socket");
        assert_eq!(r.len, got.len);
        assert_eq!((reply[17], reply[24]), (tag, 1), "answer {i}");
    }
    // More answers than the ring holds, all at once: none is lost, order is kept.
    for tag in 0..40u8 {
        let mut f = ethercat_frame(tag);
        f[24] = 1;
        far.send(&f).unwrap();
    }
    for tag in 0..40u8 {
        let r = master
            .recv(&mut buf, now_ns() + 1_000_000_000)
            .unwrap()
            .expect("queued answer");
        assert_eq!((r.len, buf[17]), (60, tag));
    }
}

#[test]
fn other_ethertypes_pass_to_the_kernel() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some((veth, mut master)) = open_pair("xdo") else {
        return;
    };
    let mut far = RawSocketLink::open(&veth.peer).unwrap();
    // An ARP-typed frame from the far end must not reach the EtherCAT socket.
    let mut other = ethercat_frame(1);
    other[12..14].copy_from_slice(&[0x08, 0x06]);
    // The raw socket sends whatever frame it is given, whatever its bound EtherType.
    far.send(&other).unwrap();
    far.send(&ethercat_frame(2)).unwrap();
    let mut buf = [0u8; MAX_FRAME_LEN];
    let r = master
        .recv(&mut buf, now_ns() + 1_000_000_000)
        .unwrap()
        .expect("the EtherCAT frame");
    assert_eq!((buf[12], buf[13], buf[17]), (0x88, 0xa4, 2));
    assert_eq!(r.len, 60);
    assert!(master
        .recv(&mut buf, now_ns() + 50_000_000)
        .unwrap()
        .is_none());
}

#[test]
fn a_second_link_on_the_interface_is_refused_and_close_detaches() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some((veth, master)) = open_pair("xdb") else {
        return;
    };
    let err = match XdpLink::open(&veth.master, &LinkOptions::default()) {
        Ok(_) => panic!("a second AF_XDP link on the same interface was allowed"),
        Err(e) => e.to_string(),
    };
    assert!(err.contains(&veth.master), "{err}");
    assert!(err.contains("another master"), "{err}");
    drop(master);
    assert!(!xdp_attached(&veth.master), "the program stayed attached");
    // The interface is free again.
    let again = XdpLink::open(&veth.master, &LinkOptions::default()).expect("reopen");
    drop(again);
    assert!(!xdp_attached(&veth.master));
}

#[test]
fn an_interface_that_does_not_exist_is_named() {
    let err = XdpLink::open("nosuchif0", &LinkOptions::default())
        .err()
        .expect("no such interface")
        .to_string();
    assert!(
        err.contains("no network interface named 'nosuchif0'"),
        "{err}"
    );
}
