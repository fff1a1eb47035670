//! The bus's output variables as the command path resolves them, and the rule that decides which
//! requests the native path may apply by itself.
//!
//! The node's Python code (`ether_ros.ros.bridge.resolve_write` and `values.check_value`) is the
//! reference: it accepts or refuses every request and words every error. This table accepts a
//! request only when it can tell for certain that Python would accept it, and then writes the
//! same bits; everything else — text values, names it cannot match exactly, out-of-range or
//! non-integral values, unknown slaves, a slave named together with `all_slaves`, variables
//! the master checks against more than their type (`VariableEntry::deferred`) — is `Defer`red
//! to Python, which answers it.
//! `tests/unit/test_native_commands.py` checks the two against each other.

use std::fmt::Write as _;

use ether_ros_engine::OutputField;
use ether_ros_protocol::address;
use ether_ros_protocol::dtype::Kind as ValueKind;
use ether_ros_protocol::value;

use crate::cdr::WriteRequest;

/// How a variable's value is encoded (the kind of its ESI data type).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A boolean (one bit).
    Bool,
    /// A signed integer of the entry's bit length.
    Int,
    /// An unsigned integer of the entry's bit length.
    Uint,
    /// An IEEE 754 single.
    Real32,
    /// An IEEE 754 double.
    Real64,
}

impl Kind {
    /// The kind of a data type name as the Python side gives it (`"bool"`, `"int"`, `"uint"`,
    /// `"real32"`, `"real64"`); None for any other.
    pub fn parse(name: &str) -> Option<Kind> {
        Some(match name {
            "bool" => Kind::Bool,
            "int" => Kind::Int,
            "uint" => Kind::Uint,
            "real32" => Kind::Real32,
            "real64" => Kind::Real64,
            _ => return None,
        })
    }

    /// The protocol crate's value kind of this encoding.
    fn value_kind(self) -> ValueKind {
        match self {
            Kind::Bool => ValueKind::Bool,
            Kind::Int => ValueKind::Int,
            Kind::Uint => ValueKind::Uint,
            Kind::Real32 | Kind::Real64 => ValueKind::Real,
        }
    }
}

/// One output variable: where its bits are in the process image and which values it takes.
#[derive(Debug, Clone, PartialEq)]
pub struct VariableEntry {
    /// The variable's name as the slave's ESI names it (what requests use).
    pub name: String,
    /// Index of the object the variable maps.
    pub index: u16,
    /// Subindex of the object the variable maps.
    pub subindex: u8,
    /// Bits from the start of the whole process image.
    pub bit_offset: usize,
    /// Width of the variable in the process image, in bits.
    pub bit_length: u32,
    /// How its value is encoded.
    pub kind: Kind,
    /// Smallest value its data type (or the configuration) allows.
    pub minimum: f64,
    /// Largest value its data type (or the configuration) allows.
    pub maximum: f64,
    /// The master checks more than type and range for this variable (a Laelaps II leg's
    /// trajectory against its workspace and current outputs): every write of it goes to Python.
    pub deferred: bool,
}

#[derive(Debug, Clone, PartialEq)]
/// One slave and its output variables, in the order Python gave them.
pub struct SlaveEntry {
    /// The slave's configured name (what `WriteVariable.slave` names).
    pub name: String,
    /// The slave's position on the bus (what `WriteVariable.position` names).
    pub position: i64,
    /// The output variables a request may write.
    pub outputs: Vec<VariableEntry>,
}

/// What to do with one request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Resolution {
    /// Certainly valid: the fields and the answer have been filled in.
    Apply,
    /// Python decides (and explains, if it refuses).
    Defer,
    /// Certainly invalid, refused here with the words Python would use (the joint table's
    /// structural checks: names and array lengths), so a flood of such messages never reaches
    /// the queue for Python.
    Refuse,
}

/// How many written variables the answer lists before "(+N more)" (as Python's).
const LISTED: usize = 8;

#[derive(Debug, Clone, Default)]
/// The output variables of every slave, built once from the configuration: the receiver
/// thread resolves `WriteVariable` requests against it without asking Python.
pub struct CommandTable {
    slaves: Vec<SlaveEntry>,
}

enum Lookup<'t> {
    Found(&'t VariableEntry),
    Missing,
    Unsure,
}

impl CommandTable {
    /// Checks what Python cannot have got wrong but a caller might: field sizes and kinds.
    pub fn new(slaves: Vec<SlaveEntry>) -> Result<CommandTable, String> {
        for s in &slaves {
            for v in &s.outputs {
                let ok = match v.kind {
                    Kind::Bool | Kind::Int | Kind::Uint => (1..=64).contains(&v.bit_length),
                    Kind::Real32 => v.bit_length == 32,
                    Kind::Real64 => v.bit_length == 64,
                };
                if !ok {
                    return Err(format!(
                        "slave '{}': variable '{}' is {:?} with {} bit(s)",
                        s.name, v.name, v.kind, v.bit_length
                    ));
                }
                if v.minimum.is_nan() || v.maximum.is_nan() || v.minimum > v.maximum {
                    return Err(format!(
                        "slave '{}': variable '{}' has the range {}..{}",
                        s.name, v.name, v.minimum, v.maximum
                    ));
                }
            }
        }
        Ok(CommandTable { slaves })
    }

    /// The slaves of the table, in bus order.
    pub fn slaves(&self) -> &[SlaveEntry] {
        &self.slaves
    }

    /// Resolve `req`: on `Apply`, `fields` holds the bits to write and `answer` the success
    /// message Python would give; on `Defer` both are unspecified.
    pub fn resolve(
        &self,
        req: &WriteRequest<'_>,
        fields: &mut Vec<OutputField>,
        answer: &mut String,
    ) -> Resolution {
        fields.clear();
        answer.clear();
        if !req.text.is_empty() || req.variable.is_empty() || !req.value.is_finite() {
            return Resolution::Defer;
        }
        if !req.variable.is_ascii() {
            return Resolution::Defer;
        }
        if req.all_slaves && (!req.slave.is_empty() || req.position >= 0) {
            return Resolution::Defer; // one slave or all of them: Python refuses both at once
        }
        answer.push_str("wrote ");
        let mut count = 0usize;
        if req.all_slaves {
            for s in &self.slaves {
                match find(s, req.variable) {
                    Lookup::Found(v) if v.deferred => return Resolution::Defer,
                    Lookup::Found(v) => {
                        if !self.add(s, v, req.value, fields, answer, &mut count) {
                            return Resolution::Defer;
                        }
                    }
                    Lookup::Missing => {}
                    Lookup::Unsure => return Resolution::Defer,
                }
            }
            if count == 0 {
                return Resolution::Defer;
            }
        } else {
            let Some(s) = self.target(req) else {
                return Resolution::Defer;
            };
            let Lookup::Found(v) = find(s, req.variable) else {
                return Resolution::Defer;
            };
            if v.deferred {
                return Resolution::Defer;
            }
            if !self.add(s, v, req.value, fields, answer, &mut count) {
                return Resolution::Defer;
            }
        }
        if count > LISTED {
            let _ = write!(answer, " (+{} more)", count - LISTED);
        }
        Resolution::Apply
    }

    /// The one slave a request names: by name, or by position when the name is empty (a name
    /// made of digits is a position, as in Python).
    fn target(&self, req: &WriteRequest<'_>) -> Option<&SlaveEntry> {
        if !req.slave.is_empty() {
            if !req.slave.is_ascii() {
                return None;
            }
            if req.slave.bytes().all(|b| b.is_ascii_digit()) {
                let position: i64 = req.slave.parse().ok()?;
                return self.slaves.iter().find(|s| s.position == position);
            }
            return self.slaves.iter().find(|s| s.name == req.slave);
        }
        if req.position >= 0 {
            return self
                .slaves
                .iter()
                .find(|s| s.position == i64::from(req.position));
        }
        None
    }

    /// Check `value` for `v` (the protocol crate's check, as Python's `check_value`) and add its
    /// field; false if invalid.
    fn add(
        &self,
        s: &SlaveEntry,
        v: &VariableEntry,
        value: f64,
        fields: &mut Vec<OutputField>,
        answer: &mut String,
        count: &mut usize,
    ) -> bool {
        if value::check(v.kind.value_kind(), value, v.minimum, v.maximum).is_err() {
            return false;
        }
        let Ok(raw) = value::encode(v.kind.value_kind(), v.bit_length, value) else {
            return false;
        };
        fields.push(OutputField {
            bit_offset: v.bit_offset,
            bit_length: v.bit_length,
            raw,
        });
        if *count < LISTED {
            if *count > 0 {
                answer.push_str(", ");
            }
            let _ = write!(answer, "{}.{}={}", s.name, v.name, format_g(value));
        }
        *count += 1;
        true
    }
}

/// A variable of `s` by name or address, matched as `ether_ros.ros.layout._find` does: an
/// address ("0x7010:01", "7010:1": the protocol crate's grammar) by index and subindex; a name
/// exactly, else case-insensitively when that is unambiguous. Names that are not plain ASCII
/// are left to Python (`Unsure`), whose case folding is Unicode's; so is an address out of
/// range, which Python refuses with the reason.
fn find<'t>(s: &'t SlaveEntry, reference: &str) -> Lookup<'t> {
    match address::parse(reference) {
        Ok((index, subindex)) => {
            return match s
                .outputs
                .iter()
                .find(|v| (v.index, v.subindex) == (index, subindex))
            {
                Some(v) => Lookup::Found(v),
                None => Lookup::Missing,
            }
        }
        Err(address::AddressError::NotAnAddress) => {}
        Err(_) => return Lookup::Unsure,
    }
    if let Some(v) = s.outputs.iter().find(|v| v.name == reference) {
        return Lookup::Found(v);
    }
    if s.outputs.iter().any(|v| !v.name.is_ascii()) {
        return Lookup::Unsure;
    }
    let mut folded = s
        .outputs
        .iter()
        .filter(|v| v.name.eq_ignore_ascii_case(reference));
    match (folded.next(), folded.next()) {
        (Some(v), None) => Lookup::Found(v),
        _ => Lookup::Missing,
    }
}

/// Python's `format(value, "g")` for a finite value (the only kind a write accepts): 6
/// significant digits, trailing zeros dropped, scientific notation below 1e-4 and from 1e6 on.
pub fn format_g(value: f64) -> String {
    if value == 0.0 {
        return if value.is_sign_negative() { "-0" } else { "0" }.to_string();
    }
    let scientific = format!("{value:.5e}");
    let (mantissa, exponent) = scientific.split_once('e').expect("LowerExp has an 'e'");
    let exponent: i32 = exponent.parse().expect("LowerExp exponent is an integer");
    if !(-4..6).contains(&exponent) {
        let sign = if exponent < 0 { '-' } else { '+' };
        format!(
            "{}e{sign}{:02}",
            trim_fraction(mantissa),
            exponent.unsigned_abs()
        )
    } else {
        let decimals = (5 - exponent) as usize;
        trim_fraction(&format!("{value:.decimals$}")).to_string()
    }
}

fn trim_fraction(s: &str) -> &str {
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn var(
        name: &str,
        sub: u8,
        bit: usize,
        bits: u32,
        kind: Kind,
        lo: f64,
        hi: f64,
    ) -> VariableEntry {
        VariableEntry {
            name: name.into(),
            index: 0x7000,
            subindex: sub,
            bit_offset: bit,
            bit_length: bits,
            kind,
            minimum: lo,
            maximum: hi,
            deferred: false,
        }
    }

    fn table() -> CommandTable {
        let leg = |name: &str, position: i64, base: usize| SlaveEntry {
            name: name.into(),
            position,
            outputs: vec![
                var("Kp100_hip", 1, base, 16, Kind::Int, -32768.0, 32767.0),
                var("Enable", 2, base + 16, 1, Kind::Bool, 0.0, 1.0),
                var("Gain", 3, base + 24, 32, Kind::Real32, -3.4e38, 3.4e38),
                var("Count", 4, base + 56, 12, Kind::Uint, 0.0, 4095.0),
            ],
        };
        CommandTable::new(vec![leg("left", 0, 0), leg("right", 1, 128)]).unwrap()
    }

    fn req<'a>(slave: &'a str, variable: &'a str, value: f64) -> WriteRequest<'a> {
        WriteRequest {
            slave,
            position: -1,
            all_slaves: false,
            variable,
            value,
            text: "",
            request_id: 1,
        }
    }

    fn run(t: &CommandTable, r: &WriteRequest<'_>) -> Option<(Vec<OutputField>, String)> {
        let (mut fields, mut answer) = (Vec::new(), String::new());
        (t.resolve(r, &mut fields, &mut answer) == Resolution::Apply).then_some((fields, answer))
    }

    #[test]
    fn a_valid_write_gives_its_bits_and_pythons_answer() {
        let (fields, answer) = run(&table(), &req("right", "Kp100_hip", -2.0)).unwrap();
        assert_eq!(
            fields,
            vec![OutputField {
                bit_offset: 128,
                bit_length: 16,
                raw: 0xfffe
            }]
        );
        assert_eq!(answer, "wrote right.Kp100_hip=-2");
    }

    #[test]
    fn slaves_by_position_and_digit_names() {
        let t = table();
        let mut r = req("", "Count", 4095.0);
        r.position = 1;
        assert_eq!(run(&t, &r).unwrap().0[0].bit_offset, 128 + 56);
        assert_eq!(
            run(&t, &req("0", "Count", 1.0)).unwrap().0[0].bit_offset,
            56
        );
        assert!(run(&t, &req("7", "Count", 1.0)).is_none());
        r.position = -1;
        r.slave = "";
        assert!(run(&t, &r).is_none(), "no slave named: Python refuses");
    }

    #[test]
    fn all_slaves_writes_every_slave_with_the_variable() {
        let mut r = req("", "enable", 1.0);
        r.all_slaves = true;
        let (fields, answer) = run(&table(), &r).unwrap();
        assert_eq!(fields.len(), 2);
        assert_eq!(answer, "wrote left.Enable=1, right.Enable=1");
    }

    #[test]
    fn addresses_match_like_python() {
        let t = table();
        // The one grammar (ether_ros_protocol::address): both parts hex, "0x" in either case.
        for address in [
            "0x7000:03",
            "7000:3",
            " 7000:03 ",
            "0x7000:0x3",
            "0X7000:03",
        ] {
            let (fields, _) = run(&t, &req("left", address, 1.5)).unwrap();
            assert_eq!(fields[0].raw, u64::from(1.5f32.to_bits()), "{address}");
        }
        for not_ours in ["17000:3", "7000:", "7000:103"] {
            assert!(run(&t, &req("left", not_ours, 1.0)).is_none(), "{not_ours}");
        }
    }

    #[test]
    fn everything_uncertain_or_invalid_is_deferred() {
        let t = table();
        let mut text = req("left", "Count", 1.0);
        text.text = "0x10";
        for r in [
            text,
            req("left", "Count", 4096.0),
            req("left", "Count", -1.0),
            req("left", "Count", 1.5),
            req("left", "Enable", 2.0),
            req("left", "Kp100_hip", f64::NAN),
            req("left", "Kp100_hip", f64::INFINITY),
            req("left", "Nope", 1.0),
            req("nobody", "Count", 1.0),
            req("left", "", 1.0),
            req("left", "Cöunt", 1.0),
            req("lëft", "Count", 1.0),
        ] {
            assert!(run(&t, &r).is_none(), "{r:?}");
        }
    }

    #[test]
    fn ambiguous_case_folding_is_missing_and_non_ascii_names_are_unsure() {
        let s = SlaveEntry {
            name: "s".into(),
            position: 0,
            outputs: vec![
                var("ab", 1, 0, 8, Kind::Uint, 0.0, 255.0),
                var("AB", 2, 8, 8, Kind::Uint, 0.0, 255.0),
            ],
        };
        assert!(matches!(find(&s, "Ab"), Lookup::Missing));
        assert!(matches!(find(&s, "AB"), Lookup::Found(v) if v.subindex == 2));
        let mut odd = s.clone();
        odd.outputs[1].name = "Kelvin\u{212a}".into();
        assert!(matches!(find(&odd, "kelvink"), Lookup::Unsure));
    }

    #[test]
    fn a_slave_named_with_all_slaves_is_deferred() {
        let t = table();
        let mut r = req("left", "Count", 1.0);
        r.all_slaves = true;
        assert!(run(&t, &r).is_none(), "slave name + all_slaves");
        let mut r = req("", "Count", 1.0);
        r.all_slaves = true;
        r.position = 0;
        assert!(run(&t, &r).is_none(), "position + all_slaves");
        r.position = -1;
        assert_eq!(run(&t, &r).unwrap().0.len(), 2, "all_slaves alone");
    }

    #[test]
    fn deferred_variables_always_go_to_python() {
        let mut slaves = table().slaves;
        slaves[1].outputs[3].deferred = true; // right.Count
        let t = CommandTable::new(slaves).unwrap();
        assert!(run(&t, &req("right", "Count", 1.0)).is_none());
        assert!(run(&t, &req("left", "Count", 1.0)).is_some());
        let mut all = req("", "Count", 1.0);
        all.all_slaves = true;
        assert!(
            run(&t, &all).is_none(),
            "one deferred slave defers the whole write"
        );
    }

    #[test]
    fn formats_like_python_g() {
        for (value, python) in [
            (123.0, "123"),
            (-2.0, "-2"),
            (0.5, "0.5"),
            (1e6, "1e+06"),
            (123456.0, "123456"),
            (1234567.0, "1.23457e+06"),
            (0.0001, "0.0001"),
            (0.00001, "1e-05"),
            (-0.0, "-0"),
            (3.4028234663852886e38, "3.40282e+38"),
            (65535.0, "65535"),
            (2.5e-7, "2.5e-07"),
            (999999.5, "1e+06"),
        ] {
            assert_eq!(format_g(value), python, "{value}");
        }
    }

    #[test]
    fn rejects_malformed_tables() {
        let mut bad = table().slaves;
        bad[0].outputs[2].bit_length = 16; // a REAL32 in 16 bits
        assert!(CommandTable::new(bad).is_err());
    }
}
