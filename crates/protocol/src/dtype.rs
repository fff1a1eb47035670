//! CoE basic data types (ETG.1000.6 table 64): code, bit size and how values of the type are
//! encoded, with the names the bus configuration (`uint16`) and ESI files (`UINT`, `UNSIGNED16`,
//! `BIT3`, `STRING(20)`) use for them. One table serves the ESI parser, the SII builder, the
//! process-variable codec, the SDO tools, the simulator's object dictionary and the native
//! command path.

crate::named_constants! {
    /// Every type code, by name.
    pub const TABLE;
    /// BOOLEAN.
    pub const BOOL: u16 = 0x0001;
    /// INTEGER8.
    pub const INT8: u16 = 0x0002;
    /// INTEGER16.
    pub const INT16: u16 = 0x0003;
    /// INTEGER32.
    pub const INT32: u16 = 0x0004;
    /// UNSIGNED8.
    pub const UINT8: u16 = 0x0005;
    /// UNSIGNED16.
    pub const UINT16: u16 = 0x0006;
    /// UNSIGNED32.
    pub const UINT32: u16 = 0x0007;
    /// REAL32.
    pub const REAL32: u16 = 0x0008;
    /// VISIBLE_STRING.
    pub const VISIBLE_STRING: u16 = 0x0009;
    /// OCTET_STRING.
    pub const OCTET_STRING: u16 = 0x000A;
    /// UNICODE_STRING.
    pub const UNICODE_STRING: u16 = 0x000B;
    /// INTEGER24.
    pub const INT24: u16 = 0x0010;
    /// REAL64.
    pub const REAL64: u16 = 0x0011;
    /// INTEGER64.
    pub const INT64: u16 = 0x0015;
    /// UNSIGNED24.
    pub const UINT24: u16 = 0x0016;
    /// UNSIGNED64.
    pub const UINT64: u16 = 0x001B;
    /// BITARR8 (handled as an unsigned integer).
    pub const BITARR8: u16 = 0x002D;
    /// BITARR16.
    pub const BITARR16: u16 = 0x002E;
    /// BITARR32.
    pub const BITARR32: u16 = 0x002F;
    /// BIT1; BITn is `BIT1 + n - 1` up to BIT8 (0x0037).
    pub const BIT1: u16 = 0x0030;
    /// BIT8.
    pub const BIT8: u16 = 0x0037;
}

/// How values of a type are encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Kind {
    /// One bit, 0 or 1.
    Bool = 0,
    /// Two's complement integer of the type's bit length.
    Int = 1,
    /// Unsigned integer (also bit fields and bit arrays).
    Uint = 2,
    /// IEEE 754 float of 32 or 64 bits.
    Real = 3,
    /// Text (UTF-8 on the wire, NUL padded).
    String = 4,
    /// Raw bytes.
    Bytes = 5,
}

impl Kind {
    /// The kind's name as the Python side spells it.
    pub const fn name(self) -> &'static str {
        match self {
            Kind::Bool => "bool",
            Kind::Int => "int",
            Kind::Uint => "uint",
            Kind::Real => "real",
            Kind::String => "string",
            Kind::Bytes => "bytes",
        }
    }

    /// The kind a name denotes (inverse of `name`).
    pub fn from_name(name: &str) -> Option<Kind> {
        Some(match name {
            "bool" => Kind::Bool,
            "int" => Kind::Int,
            "uint" => Kind::Uint,
            "real" => Kind::Real,
            "string" => Kind::String,
            "bytes" => Kind::Bytes,
            _ => return None,
        })
    }

    /// Values are whole numbers (bool, int, uint).
    pub const fn integral(self) -> bool {
        matches!(self, Kind::Bool | Kind::Int | Kind::Uint)
    }

    /// Values are numbers (integral or real).
    pub const fn numeric(self) -> bool {
        !matches!(self, Kind::String | Kind::Bytes)
    }
}

/// One basic data type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DataType {
    /// ETG.1000.6 data type index.
    pub code: u16,
    /// Canonical short name (`uint16`): the bus configuration's `type:` and messages use it.
    pub name: &'static str,
    /// Bit length; 0 for variable-length types (strings, octet strings).
    pub bits: u16,
    /// How its values are encoded.
    pub kind: Kind,
}

const fn t(code: u16, name: &'static str, bits: u16, kind: Kind) -> DataType {
    DataType {
        code,
        name,
        bits,
        kind,
    }
}

/// Every basic type.
pub const TYPES: &[DataType] = &[
    t(BOOL, "bool", 1, Kind::Bool),
    t(INT8, "int8", 8, Kind::Int),
    t(INT16, "int16", 16, Kind::Int),
    t(INT32, "int32", 32, Kind::Int),
    t(UINT8, "uint8", 8, Kind::Uint),
    t(UINT16, "uint16", 16, Kind::Uint),
    t(UINT32, "uint32", 32, Kind::Uint),
    t(REAL32, "real32", 32, Kind::Real),
    t(VISIBLE_STRING, "string", 0, Kind::String),
    t(OCTET_STRING, "octet_string", 0, Kind::Bytes),
    t(UNICODE_STRING, "unicode_string", 0, Kind::Bytes),
    t(INT24, "int24", 24, Kind::Int),
    t(REAL64, "real64", 64, Kind::Real),
    t(INT64, "int64", 64, Kind::Int),
    t(UINT24, "uint24", 24, Kind::Uint),
    t(UINT64, "uint64", 64, Kind::Uint),
    t(BITARR8, "bitarr8", 8, Kind::Uint),
    t(BITARR16, "bitarr16", 16, Kind::Uint),
    t(BITARR32, "bitarr32", 32, Kind::Uint),
    t(BIT1, "bit1", 1, Kind::Uint),
    t(BIT1 + 1, "bit2", 2, Kind::Uint),
    t(BIT1 + 2, "bit3", 3, Kind::Uint),
    t(BIT1 + 3, "bit4", 4, Kind::Uint),
    t(BIT1 + 4, "bit5", 5, Kind::Uint),
    t(BIT1 + 5, "bit6", 6, Kind::Uint),
    t(BIT1 + 6, "bit7", 7, Kind::Uint),
    t(BIT8, "bit8", 8, Kind::Uint),
];

/// The type with ETG.1000.6 code `code`.
pub fn by_code(code: u16) -> Option<&'static DataType> {
    TYPES.iter().find(|t| t.code == code)
}

/// The type with canonical name `name` (`uint16`).
pub fn by_name(name: &str) -> Option<&'static DataType> {
    TYPES.iter().find(|t| t.name == name)
}

/// ESI spellings (IEC 61131-3 and ETG.1000.6 names) of the basic types.
const ESI_NAMES: &[(&str, u16)] = &[
    ("BOOL", BOOL),
    ("BOOLEAN", BOOL),
    ("BIT", BIT1),
    ("SINT", INT8),
    ("INTEGER8", INT8),
    ("INT", INT16),
    ("INTEGER16", INT16),
    ("DINT", INT32),
    ("INTEGER32", INT32),
    ("INT24", INT24),
    ("INTEGER24", INT24),
    ("LINT", INT64),
    ("INTEGER64", INT64),
    ("USINT", UINT8),
    ("BYTE", UINT8),
    ("UNSIGNED8", UINT8),
    ("UINT", UINT16),
    ("WORD", UINT16),
    ("UNSIGNED16", UINT16),
    ("UINT24", UINT24),
    ("UNSIGNED24", UINT24),
    ("UDINT", UINT32),
    ("DWORD", UINT32),
    ("UNSIGNED32", UINT32),
    ("ULINT", UINT64),
    ("LWORD", UINT64),
    ("UNSIGNED64", UINT64),
    ("REAL", REAL32),
    ("REAL32", REAL32),
    ("FLOAT", REAL32),
    ("LREAL", REAL64),
    ("REAL64", REAL64),
    ("DOUBLE", REAL64),
    ("STRING", VISIBLE_STRING),
    ("VISIBLE_STRING", VISIBLE_STRING),
    ("OCTET_STRING", OCTET_STRING),
    ("UNICODE_STRING", UNICODE_STRING),
    ("BITARR8", BITARR8),
    ("BITARR16", BITARR16),
    ("BITARR32", BITARR32),
    // C-style widths vendors write (SMC's EX250 types its entries UINT8).
    ("UINT8", UINT8),
    ("UINT16", UINT16),
    ("UINT32", UINT32),
    ("UINT64", UINT64),
    ("INT8", INT8),
    ("INT16", INT16),
    ("INT32", INT32),
    ("INT64", INT64),
    ("FLOAT32", REAL32),
    ("FLOAT64", REAL64),
];

/// The ESI name a type is usually written with (`UINT` for uint16), for messages and listings.
pub fn esi_name(code: u16) -> Option<&'static str> {
    Some(match code {
        BOOL => "BOOL",
        INT8 => "SINT",
        INT16 => "INT",
        INT32 => "DINT",
        UINT8 => "USINT",
        UINT16 => "UINT",
        UINT32 => "UDINT",
        REAL32 => "REAL",
        VISIBLE_STRING => "STRING",
        OCTET_STRING => "OCTET_STRING",
        UNICODE_STRING => "UNICODE_STRING",
        INT24 => "INT24",
        REAL64 => "LREAL",
        INT64 => "LINT",
        UINT24 => "UINT24",
        UINT64 => "ULINT",
        BITARR8 => "BITARR8",
        BITARR16 => "BITARR16",
        BITARR32 => "BITARR32",
        BIT1..=BIT8 => [
            "BIT1", "BIT2", "BIT3", "BIT4", "BIT5", "BIT6", "BIT7", "BIT8",
        ][(code - BIT1) as usize],
        _ => return None,
    })
}

/// The basic type an ESI type name denotes (`USINT`, `BIT3`, `STRING(20)`,
/// `ARRAY [0..511] OF BYTE`), or `None` when it is no basic type (a record type such as
/// `DT7000`). Case and surrounding blanks do not matter.
pub fn esi_type(name: &str) -> Option<&'static DataType> {
    let key = name.trim().to_ascii_uppercase();
    if let Some((_, code)) = ESI_NAMES.iter().find(|(n, _)| *n == key) {
        return by_code(*code);
    }
    if let Some(n) = key.strip_prefix("BIT") {
        if let Ok(n @ 1..=8) = n.parse::<u16>() {
            return by_code(BIT1 + n - 1);
        }
    }
    // Sized strings: STRING(20), OCTET_STRING(4), ARRAY OF BYTE(8).
    if let Some((base, size)) = key.split_once('(') {
        let size = size.strip_suffix(')').map(str::trim);
        if size.is_some_and(|s| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit())) {
            return match base.trim() {
                "STRING" | "VISIBLE_STRING" => by_code(VISIBLE_STRING),
                "UNICODE_STRING" => by_code(UNICODE_STRING),
                "OCTET_STRING" | "ARRAY OF BYTE" => by_code(OCTET_STRING),
                _ => None,
            };
        }
    }
    // Byte arrays as several vendors write them: ARRAY [0..511] OF BYTE.
    if is_byte_array(&key) {
        return by_code(OCTET_STRING);
    }
    None
}

fn is_byte_array(key: &str) -> bool {
    let Some(rest) = key.strip_prefix("ARRAY") else {
        return false;
    };
    let rest = rest.trim_start();
    let Some(rest) = rest.strip_prefix('[') else {
        return false;
    };
    let Some((bounds, rest)) = rest.split_once(']') else {
        return false;
    };
    let Some((lo, hi)) = bounds.split_once("..") else {
        return false;
    };
    let digits = |s: &str| {
        let s = s.trim();
        !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit())
    };
    if !digits(lo) || !digits(hi) {
        return false;
    }
    let Some(element) = rest.trim_start().strip_prefix("OF") else {
        return false;
    };
    // "OF" must be followed by blanks or directly by the element name.
    matches!(element.trim(), "BYTE" | "USINT" | "UINT8")
}

/// The type a bus configuration's `type:` names: a canonical name (`uint16`, any case) or an
/// ESI name.
pub fn config_type(name: &str) -> Option<&'static DataType> {
    by_name(&name.trim().to_ascii_lowercase()).or_else(|| esi_type(name))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_codes_and_sizes() {
        assert_eq!(
            by_code(UINT16).map(|t| (t.name, t.bits)),
            Some(("uint16", 16))
        );
        assert_eq!(esi_type(" unsigned32 ").map(|t| t.code), Some(UINT32));
        assert_eq!(
            esi_type("BIT3").map(|t| (t.code, t.bits)),
            Some((0x0032, 3))
        );
        assert_eq!(esi_type("STRING(20)").map(|t| t.code), Some(VISIBLE_STRING));
        assert_eq!(
            esi_type("ARRAY [0..511] OF BYTE").map(|t| t.code),
            Some(OCTET_STRING)
        );
        assert_eq!(
            esi_type("ARRAY OF BYTE(8)").map(|t| t.code),
            Some(OCTET_STRING)
        );
        assert_eq!(esi_type("DT7000"), None);
        assert_eq!(esi_type("BIT9"), None);
        assert_eq!(config_type("UINT").map(|t| t.name), Some("uint16"));
        assert_eq!(config_type("Real32").map(|t| t.code), Some(REAL32));
        assert_eq!(esi_name(0x0034), Some("BIT5"));
        for t in TYPES {
            assert_eq!(by_code(t.code), Some(t), "{} once", t.name);
            assert_eq!(Kind::from_name(t.kind.name()), Some(t.kind));
        }
    }
}
