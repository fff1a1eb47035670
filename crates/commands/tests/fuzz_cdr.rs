//! Fuzzing the command path's CDR decoders and its resolver (proptest, fixed seed): any bytes
//! a DDS participant can publish on `pdo_listener`, `joint_commands` or `joint_trajectory`.
//! Nothing panics or allocates beyond the message, every decoded string is whole (a NUL inside
//! is refused, never cut), well-formed messages decode to what was encoded, and the resolver
//! applies only writes that fit their variable.
//!
//! `FUZZ_CASES` (default 256) and `FUZZ_SEED` (default 1) set the run.

use ether_ros_commands::cdr::check_joint_trajectory;
use ether_ros_commands::{
    decode_joint_state, decode_write_variable, CdrError, CommandTable, Kind, Resolution,
    SlaveEntry, VariableEntry, WriteRequest,
};
use ether_ros_protocol::dtype::Kind as ValueKind;
use ether_ros_protocol::value;
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

/// CDR little endian, as rclpy writes it: fields aligned to their size after the 4-byte header.
struct Writer(Vec<u8>);

impl Writer {
    fn new() -> Writer {
        Writer(vec![0x00, 0x01, 0x00, 0x00])
    }
    fn align(&mut self, n: usize) {
        while !(self.0.len() - 4).is_multiple_of(n) {
            self.0.push(0xAA); // padding carries no meaning: garbage, as Fast DDS leaves it
        }
    }
    fn u32(&mut self, v: u32) {
        self.align(4);
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.align(8);
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.0.extend_from_slice(s.as_bytes());
        self.0.push(0);
    }
    fn f64_seq(&mut self, v: &[f64]) {
        self.u32(v.len() as u32);
        for x in v {
            self.f64(*x);
        }
    }
}

fn write_variable(r: &WriteRequest<'_>) -> Vec<u8> {
    let mut w = Writer::new();
    w.string(r.slave);
    w.u32(r.position as u32);
    w.0.push(u8::from(r.all_slaves));
    w.string(r.variable);
    w.f64(r.value);
    w.string(r.text);
    w.u32(r.request_id);
    w.0
}

fn joint_state(names: &[String], position: &[f64]) -> Vec<u8> {
    let mut w = Writer::new();
    w.u32(0);
    w.u32(0);
    w.string("frame");
    w.u32(names.len() as u32);
    for n in names {
        w.string(n);
    }
    w.f64_seq(position);
    w.f64_seq(&[]);
    w.f64_seq(&[]);
    w.0
}

fn joint_trajectory(names: &[String], points: &[Vec<f64>]) -> Vec<u8> {
    let mut w = Writer::new();
    w.u32(0);
    w.u32(0);
    w.string("");
    w.u32(names.len() as u32);
    for n in names {
        w.string(n);
    }
    w.u32(points.len() as u32);
    for (i, p) in points.iter().enumerate() {
        w.f64_seq(p);
        w.f64_seq(&[]);
        w.f64_seq(&[]);
        w.f64_seq(&[]);
        w.u32(i as u32);
        w.u32(0);
    }
    w.0
}

/// Text without NUL (what rclpy can carry whole).
fn text() -> impl Strategy<Value = String> {
    "[^\u{0}]{0,20}"
}

/// Mutations of a well-formed message: flipped bytes, a cut, a length word overwritten.
fn mutated(base: Vec<u8>) -> impl Strategy<Value = Vec<u8>> {
    let n = base.len();
    (
        proptest::collection::vec((0..n, any::<u8>()), 0..6),
        0..=n,
        0..n,
        any::<u32>(),
    )
        .prop_map(move |(flips, cut, at, word)| {
            let mut b = base.clone();
            for (i, v) in flips {
                b[i] = v;
            }
            if at + 4 <= b.len() && word % 3 == 0 {
                b[at..at + 4].copy_from_slice(&word.to_le_bytes());
            }
            b.truncate(cut.max(1));
            b
        })
}

fn table() -> CommandTable {
    let var =
        |name: &str, sub: u8, bit: usize, bits: u32, kind: Kind, lo: f64, hi: f64| VariableEntry {
            name: name.into(),
            index: 0x7000,
            subindex: sub,
            bit_offset: bit,
            bit_length: bits,
            kind,
            minimum: lo,
            maximum: hi,
            deferred: sub == 5,
        };
    let slave = |name: &str, position: i64, base: usize| SlaveEntry {
        name: name.into(),
        position,
        outputs: vec![
            var("Kp", 1, base, 16, Kind::Int, -32768.0, 32767.0),
            var("Enable", 2, base + 16, 1, Kind::Bool, 0.0, 1.0),
            var("Gain", 3, base + 24, 32, Kind::Real32, -100.0, 100.0),
            var("Count", 4, base + 56, 12, Kind::Uint, 0.0, 4095.0),
            var(
                "a_ellipse100",
                5,
                base + 72,
                16,
                Kind::Int,
                -32768.0,
                32767.0,
            ),
        ],
    };
    CommandTable::new(vec![slave("left", 0, 0), slave("right", 1, 128)]).unwrap()
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn any_bytes_are_decoded_or_refused_never_a_panic(data in proptest::collection::vec(any::<u8>(), 0..256)) {
        let _ = decode_write_variable(&data);
        let mut names = Vec::new();
        if decode_joint_state(&data, &mut names).is_ok() {
            prop_assert!(names.len() <= data.len() / 4);
        }
        let _ = check_joint_trajectory(&data);
    }

    #[test]
    fn write_variables_decode_to_what_was_encoded(
        slave in text(), position in any::<i32>(), all in any::<bool>(), variable in text(),
        v in any::<f64>(), t in text(), id in any::<u32>(),
    ) {
        let r = WriteRequest { slave: &slave, position, all_slaves: all, variable: &variable,
                               value: v, text: &t, request_id: id };
        let data = write_variable(&r);
        let d = decode_write_variable(&data).unwrap();
        prop_assert_eq!((d.slave, d.position, d.all_slaves, d.variable), (r.slave, position, all, r.variable));
        prop_assert_eq!((d.value.to_bits(), d.text, d.request_id), (v.to_bits(), r.text, id));
    }

    #[test]
    fn a_nul_inside_any_string_is_refused_naming_the_field(
        before in text(), after in text(), field in 0usize..3,
    ) {
        let nul = format!("{before}\u{0}{after}");
        let mut strings = ["s".to_string(), "v".to_string(), String::new()];
        strings[field] = nul;
        let r = WriteRequest { slave: &strings[0], position: -1, all_slaves: false,
                               variable: &strings[1], value: 1.0, text: &strings[2], request_id: 1 };
        let names = ["slave", "variable", "text"];
        let data = write_variable(&r);
        prop_assert_eq!(
            decode_write_variable(&data),
            Err(CdrError::EmbeddedNul { field: names[field], at: before.len() })
        );
        let joints = vec!["hip".to_string(), format!("{before}\u{0}{after}")];
        let mut got = Vec::new();
        prop_assert!(matches!(decode_joint_state(&joint_state(&joints, &[]), &mut got),
                              Err(CdrError::EmbeddedNul { field: "name", .. })), "joint name");
        prop_assert!(matches!(check_joint_trajectory(&joint_trajectory(&joints, &[])),
                              Err(CdrError::EmbeddedNul { field: "joint_names", .. })), "trajectory");
    }

    #[test]
    fn joint_messages_decode_to_what_was_encoded(
        names in proptest::collection::vec(text(), 0..6),
        position in proptest::collection::vec(any::<f64>(), 0..6),
        points in proptest::collection::vec(proptest::collection::vec(any::<f64>(), 0..4), 0..5),
    ) {
        let mut got = Vec::new();
        let data = joint_state(&names, &position);
        let j = decode_joint_state(&data, &mut got).unwrap();
        prop_assert_eq!(&got, &names.iter().map(String::as_str).collect::<Vec<_>>());
        prop_assert_eq!(j.position.len(), position.len());
        for (i, p) in position.iter().enumerate() {
            prop_assert_eq!(j.position.get(i).to_bits(), p.to_bits());
        }
        prop_assert_eq!(check_joint_trajectory(&joint_trajectory(&names, &points)), Ok(()));
    }

    #[test]
    fn mutated_messages_never_panic(
        data in mutated(write_variable(&WriteRequest { slave: "left", position: -1, all_slaves: false,
            variable: "Kp", value: 3.0, text: "", request_id: 9 })),
        joints in mutated(joint_state(&["hip".into(), "knee".into()], &[0.5, 1.5])),
        trajectory in mutated(joint_trajectory(&["hip".into()], &[vec![0.1], vec![0.2]])),
    ) {
        let _ = decode_write_variable(&data);
        let mut names = Vec::new();
        let _ = decode_joint_state(&joints, &mut names);
        let _ = check_joint_trajectory(&trajectory);
    }

    #[test]
    fn the_resolver_applies_only_writes_that_fit(
        slave in prop_oneof![Just(String::new()), Just("left".to_string()), Just("right".to_string()),
                             Just("1".to_string()), text()],
        position in -2i32..3,
        all in any::<bool>(),
        variable in prop_oneof![Just("Kp".to_string()), Just("enable".to_string()), Just("0x7000:03".to_string()),
                                Just("Count".to_string()), Just("a_ellipse100".to_string()), text()],
        v in prop_oneof![any::<f64>(), -40000.0f64..40000.0, Just(1.0), Just(0.0)],
    ) {
        let t = table();
        let r = WriteRequest { slave: &slave, position, all_slaves: all, variable: &variable,
                               value: v, text: "", request_id: 1 };
        let (mut fields, mut answer) = (Vec::new(), String::new());
        if t.resolve(&r, &mut fields, &mut answer) == Resolution::Apply {
            prop_assert!(!fields.is_empty());
            prop_assert!(!(all && (!slave.is_empty() || position >= 0)), "one slave or all, never both");
            prop_assert!(variable != "a_ellipse100", "deferred variables are Python's");
            for f in &fields {
                let var = t.slaves().iter().flat_map(|s| &s.outputs)
                    .find(|x| x.bit_offset == f.bit_offset).unwrap();
                prop_assert!(v.is_finite() && v >= var.minimum && v <= var.maximum);
                let kind = match var.kind {
                    Kind::Bool => ValueKind::Bool,
                    Kind::Int => ValueKind::Int,
                    Kind::Uint => ValueKind::Uint,
                    Kind::Real32 | Kind::Real64 => ValueKind::Real,
                };
                prop_assert_eq!(value::encode(kind, var.bit_length, v), Ok(f.raw));
            }
        }
    }
}
