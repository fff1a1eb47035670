//! FoE through the ESC's mailbox: the BOOT state with the bootstrap mailbox of the SII, a
//! firmware image written there, and the software version (0x100A) it brings after the
//! restart into INIT.

mod common;

use common::*;
use ether_ros_protocol::foe::{self, Message};
use ether_ros_protocol::sii::word as sii_word;
use ether_ros_protocol::{coe, mailbox};
use ether_ros_sim::FoeSpec;

/// The bootstrap mailbox: elsewhere and smaller than the standard one, as on devices whose
/// boot loader has its own.
const BOOT_RX: (u16, u16) = (0x1400, 64);
const BOOT_TX: (u16, u16) = (0x1440, 64);

fn foe_spec() -> ether_ros_sim::SlaveSpec {
    let mut spec = io_spec();
    let mut sii = spec.sii.clone();
    let mut put = |word: u16, value: u16| {
        let at = 2 * word as usize;
        sii[at..at + 2].copy_from_slice(&value.to_le_bytes());
    };
    put(sii_word::BOOT_RX_MBX_OFFSET, BOOT_RX.0);
    put(sii_word::BOOT_RX_MBX_SIZE, BOOT_RX.1);
    put(sii_word::BOOT_TX_MBX_OFFSET, BOOT_TX.0);
    put(sii_word::BOOT_TX_MBX_SIZE, BOOT_TX.1);
    put(
        sii_word::MBX_PROTOCOL,
        mailbox::PROTOCOL_COE | mailbox::PROTOCOL_FOE,
    );
    spec.sii = sii;
    spec.foe = FoeSpec {
        password: Some(0xB007),
        ..FoeSpec::default()
    };
    spec
}

/// Write `payload` of mailbox type `kind` into the write mailbox at `rx` (its size).
fn mbx_send(
    net: &mut ether_ros_sim::Network,
    st: u16,
    rx: (u16, u16),
    kind: u8,
    counter: u8,
    payload: &[u8],
) {
    let mut m = vec![0u8; rx.1 as usize];
    m[0..2].copy_from_slice(&(payload.len() as u16).to_le_bytes());
    m[5] = kind | (counter << 4);
    m[6..6 + payload.len()].copy_from_slice(payload);
    assert_eq!(fpwr(net, st, rx.0, &m), 1, "write mailbox took the message");
}

/// Read the read mailbox at `tx`: (type, payload).
fn mbx_receive(net: &mut ether_ros_sim::Network, st: u16, tx: (u16, u16)) -> (u8, Vec<u8>) {
    let (d, wkc) = fprd(net, st, tx.0, tx.1 as usize);
    assert_eq!(wkc, 1, "an answer waits in the read mailbox");
    let len = u16::from_le_bytes([d[0], d[1]]) as usize;
    (d[5] & 0x0F, d[6..6 + len].to_vec())
}

#[test]
fn firmware_update_in_boot_changes_the_software_version_after_restart() {
    let mut net = ether_ros_sim::Network::with_manual_clock(1_000_000_000);
    net.add_slave(foe_spec()).unwrap();
    assign_addresses(&mut net);
    let st = station(0);
    // The standard mailbox is not the bootstrap one: INIT -> BOOT refused (0x0016).
    fpwr(&mut net, st, 0x0800, &sm_bytes(MBX_RX.0, MBX_RX.1, 0x26, 1));
    fpwr(&mut net, st, 0x0808, &sm_bytes(MBX_TX.0, MBX_TX.1, 0x22, 1));
    fpwr(&mut net, st, 0x0120, &[3, 0]);
    assert_eq!(al_status(&mut net, st), (0x11, 0x0016));
    // With the SII's bootstrap mailbox it enters BOOT (an enabled SM is locked: off first).
    fpwr(&mut net, st, 0x0800, &sm_bytes(MBX_RX.0, MBX_RX.1, 0x26, 0));
    fpwr(&mut net, st, 0x0808, &sm_bytes(MBX_TX.0, MBX_TX.1, 0x22, 0));
    fpwr(
        &mut net,
        st,
        0x0800,
        &sm_bytes(BOOT_RX.0, BOOT_RX.1, 0x26, 1),
    );
    fpwr(
        &mut net,
        st,
        0x0808,
        &sm_bytes(BOOT_TX.0, BOOT_TX.1, 0x22, 1),
    );
    fpwr(&mut net, st, 0x0120, &[0x13, 0]);
    assert_eq!(al_status(&mut net, st), (3, 0));
    // The bootstrap mailbox carries FoE only: an SDO upload is refused.
    let sdo = [0x00, 0x20, 0x40, 0x0A, 0x10, 0x00, 0, 0, 0, 0];
    mbx_send(&mut net, st, BOOT_RX, mailbox::TYPE_COE, 1, &sdo);
    let (kind, body) = mbx_receive(&mut net, st, BOOT_TX);
    assert_eq!(
        (kind, body[2]),
        (mailbox::TYPE_ERR, 2),
        "unsupported protocol"
    );
    // A wrong password: "no rights".
    let bad = Message::Write {
        password: 1,
        name: b"firmware.efw",
    };
    mbx_send(&mut net, st, BOOT_RX, mailbox::TYPE_FOE, 2, &bad.encode());
    let (kind, body) = mbx_receive(&mut net, st, BOOT_TX);
    assert_eq!(kind, mailbox::TYPE_FOE);
    assert_eq!(
        Message::parse(&body),
        Ok(Message::Error {
            code: foe::ERR_NO_RIGHTS,
            text: b"no rights"
        })
    );
    // The image, in packets of the bootstrap mailbox's size (52 data bytes).
    let mut image = vec![0xA5u8; 70];
    image.extend_from_slice(b"version=3.2.1\0");
    image.resize(130, 0x5A);
    let write = Message::Write {
        password: 0xB007,
        name: b"firmware.efw",
    };
    let mut counter = 3;
    mbx_send(
        &mut net,
        st,
        BOOT_RX,
        mailbox::TYPE_FOE,
        counter,
        &write.encode(),
    );
    let (_, body) = mbx_receive(&mut net, st, BOOT_TX);
    assert_eq!(Message::parse(&body), Ok(Message::Ack { packet: 0 }));
    let chunk = foe::max_data(BOOT_RX.1 as usize);
    assert_eq!(chunk, 52);
    for (n, part) in image.chunks(chunk).enumerate() {
        counter = counter % 7 + 1;
        let packet = n as u32 + 1;
        let data = Message::Data { packet, data: part };
        mbx_send(
            &mut net,
            st,
            BOOT_RX,
            mailbox::TYPE_FOE,
            counter,
            &data.encode(),
        );
        let (_, body) = mbx_receive(&mut net, st, BOOT_TX);
        assert_eq!(Message::parse(&body), Ok(Message::Ack { packet }));
    }
    {
        let slave = net.slave(0);
        assert_eq!(slave.foe().unwrap().file("firmware.efw"), Some(&image[..]));
        // Not before the restart.
        assert_eq!(slave.od.get_bytes(coe::SOFTWARE_VERSION, 0), None);
    }
    fpwr(&mut net, st, 0x0120, &[1, 0]);
    assert_eq!(al_status(&mut net, st), (1, 0));
    assert_eq!(
        net.slave(0).od.get_bytes(coe::SOFTWARE_VERSION, 0),
        Some(&b"3.2.1"[..])
    );
}
