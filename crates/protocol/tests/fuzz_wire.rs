//! Fuzzing the protocol crate's decoders with arbitrary input (proptest, fixed seed): frames and
//! datagrams as they come off the wire, mailbox headers, object addresses, the value codec and
//! bit fields. Whatever the bytes, nothing panics, every slot a decoder returns lies inside the
//! frame, and what the encoders write decodes back to what was written.
//!
//! `FUZZ_CASES` (default 256) and `FUZZ_SEED` (default 1) set the run; `make fuzz` runs many
//! more cases (docs/testing.md, "Fuzzing").

use ether_ros_protocol::dtype::Kind;
use ether_ros_protocol::{self as wire, address, mailbox, value, Command, FrameBuilder};
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
        cases: env("FUZZ_CASES", 256) as u32,
        rng_seed: RngSeed::Fixed(env("FUZZ_SEED", 1)),
        failure_persistence: None,
        ..Config::default()
    }
}

/// An EtherCAT frame's bytes: mostly well-formed headers with random contents, sometimes any
/// bytes at all.
fn frame_bytes() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        proptest::collection::vec(any::<u8>(), 0..1600),
        (
            proptest::collection::vec(any::<u8>(), 0..1500),
            any::<u16>()
        )
            .prop_map(|(body, header)| {
                let mut f = vec![0xff; 12];
                f.extend_from_slice(&wire::ETHERTYPE.to_be_bytes());
                // Type 1 (DLPDU) and a length that may lie.
                f.extend_from_slice(&((header & 0x07ff) | 0x1000).to_le_bytes());
                f.extend_from_slice(&body);
                f
            }),
    ]
}

fn command() -> impl Strategy<Value = Command> {
    (0u8..=14).prop_filter_map("a command", Command::from_u8)
}

fn kind() -> impl Strategy<Value = Kind> {
    prop_oneof![
        Just(Kind::Bool),
        Just(Kind::Int),
        Just(Kind::Uint),
        Just(Kind::Real),
    ]
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn any_frame_parses_without_panic_and_slots_stay_inside(frame in frame_bytes()) {
        if let Ok(datagrams) = wire::datagrams(&frame) {
            for d in datagrams {
                let Ok(d) = d else { break };
                prop_assert!(d.slot.data + d.slot.len <= frame.len());
                prop_assert!(d.slot.wkc + 2 <= frame.len());
                let _ = wire::read_wkc(&frame, &d.slot);
                let _ = d.command();
            }
        }
    }

    #[test]
    fn built_frames_parse_back_to_their_datagrams(
        items in proptest::collection::vec(
            (command(), any::<u8>(), any::<u32>(), proptest::collection::vec(any::<u8>(), 0..200)),
            1..8,
        )
    ) {
        let mut buf = [0u8; wire::MAX_FRAME_LEN];
        let mut b = FrameBuilder::new(&mut buf, wire::MASTER_MAC).unwrap();
        let mut pushed = Vec::new();
        for (cmd, index, address, data) in &items {
            match b.push(*cmd, *index, *address, Some(data), 0) {
                Ok(slot) => pushed.push((*cmd, *index, *address, data.clone(), slot)),
                Err(wire::WireError::NoRoom) => break,
                Err(e) => return Err(TestCaseError::fail(format!("push: {e}"))),
            }
        }
        let n = b.finish();
        let parsed: Vec<_> = wire::datagrams(&buf[..n]).unwrap().collect();
        prop_assert_eq!(parsed.len(), pushed.len());
        for (p, (cmd, index, address, data, slot)) in parsed.into_iter().zip(pushed) {
            let p = p.unwrap();
            prop_assert_eq!(p.command(), Some(cmd));
            prop_assert_eq!((p.index, p.address, p.slot), (index, address, slot));
            prop_assert_eq!(&buf[p.slot.data..p.slot.data + p.slot.len], &data[..]);
        }
    }

    #[test]
    fn mailbox_headers_decode_any_bytes_and_encode_back(data in proptest::collection::vec(any::<u8>(), 0..12)) {
        match mailbox::Header::decode(&data) {
            None => prop_assert!(data.len() < mailbox::HEADER_LEN),
            Some(h) => {
                let again = mailbox::Header::decode(&h.encode()).unwrap();
                prop_assert_eq!(again, h);
            }
        }
    }

    #[test]
    fn addresses_parse_any_text_and_format_back(text in ".{0,24}", index in any::<u16>(), sub in any::<u8>()) {
        let _ = address::parse(&text);
        prop_assert_eq!(address::parse(&address::format(index, sub)), Ok((index, sub)));
    }

    #[test]
    fn the_value_check_and_codec_take_any_number(
        kind in kind(),
        bits in 0u32..=80,
        v in any::<f64>(),
        lo in any::<f64>(),
        hi in any::<f64>(),
        raw in any::<u64>(),
    ) {
        let _ = value::check(kind, v, lo, hi);
        let _ = value::decode(kind, bits, raw);
        if let Ok(encoded) = value::encode(kind, bits, v) {
            // A value the check accepts encodes to bits that decode to the same value (REAL32
            // to the nearest float).
            // Reals keep their bits (-0.0 too); integers their value (-0.0 is 0).
            let back = value::decode(kind, bits, encoded);
            if kind == Kind::Real {
                let expected = if bits == 32 { f64::from(v as f32) } else { v };
                prop_assert_eq!(back.to_bits(), expected.to_bits());
            } else {
                prop_assert_eq!(back, v);
            }
        }
    }

    #[test]
    fn bit_fields_never_write_outside_their_bits(
        mut area in proptest::collection::vec(any::<u8>(), 0..16),
        offset in any::<usize>(),
        bits in 0u32..=70,
        raw in any::<u64>(),
    ) {
        let offset = offset % 160;
        let before = area.clone();
        if value::write_bits(&mut area, offset, bits, raw) {
            let mask = if bits >= 64 { u64::MAX } else { (1u64 << bits) - 1 };
            prop_assert_eq!(value::read_bits(&area, offset, bits), Some(raw & mask));
            for (i, (a, b)) in area.iter().zip(&before).enumerate() {
                for bit in 0..8 {
                    let n = i * 8 + bit;
                    if n < offset || n >= offset + bits as usize {
                        prop_assert_eq!((a >> bit) & 1, (b >> bit) & 1, "bit {} changed", n);
                    }
                }
            }
        } else {
            prop_assert_eq!(&area, &before);
        }
    }

    #[test]
    fn bit_fields_at_any_offset_are_refused_not_a_panic(offset in any::<usize>(), bits in any::<u32>()) {
        let mut area = [0u8; 8];
        let _ = value::read_bits(&area, offset, bits);
        let _ = value::write_bits(&mut area, offset, bits, u64::MAX);
    }
}
