//! Values of process variables and SDO objects: the range of a type at a bit length, the one
//! check every write passes (finite, whole for integer types, inside the range), and the bit
//! patterns on the wire (little endian, two's complement, bit 0 of byte 0 first).
//!
//! The Python API (`Bus.write`, the configuration's `safe_outputs` and `sdo_init`), the ROS
//! node and console, the SDO tools and the native command path all check with these functions,
//! so a value one of them accepts is accepted by all. Nothing here allocates: the native
//! command path calls it for every request.

use crate::dtype::Kind;

/// Why a value does not fit a variable.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ValueError {
    /// NaN or infinite.
    NotFinite,
    /// A fraction for an integer type.
    NotInteger,
    /// Outside `minimum..=maximum`.
    OutOfRange {
        /// Smallest allowed value.
        minimum: f64,
        /// Largest allowed value.
        maximum: f64,
    },
    /// The type holds no numbers (strings, octet strings) or the bit length does not fit it.
    NotNumeric,
}

impl ValueError {
    /// A short name of the reason (`"out_of_range"`), for errors that carry it as data.
    pub const fn reason(&self) -> &'static str {
        match self {
            ValueError::NotFinite => "not_finite",
            ValueError::NotInteger => "not_integer",
            ValueError::OutOfRange { .. } => "out_of_range",
            ValueError::NotNumeric => "not_numeric",
        }
    }
}

impl core::fmt::Display for ValueError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ValueError::NotFinite => f.write_str("not a finite number"),
            ValueError::NotInteger => f.write_str("not an integer"),
            ValueError::OutOfRange { minimum, maximum } => {
                write!(f, "outside {minimum}..{maximum}")
            }
            ValueError::NotNumeric => f.write_str("not a numeric type"),
        }
    }
}

impl std::error::Error for ValueError {}

/// Bit lengths an integral value can have.
const fn integral_bits_ok(kind: Kind, bits: u32) -> bool {
    match kind {
        Kind::Bool => bits >= 1 && bits <= 64,
        Kind::Int | Kind::Uint => bits >= 1 && bits <= 64,
        _ => false,
    }
}

/// Inclusive range of an integral type (`Bool`, `Int`, `Uint`) at `bits` bits; `None` for the
/// other kinds or a bit length outside 1..=64.
pub const fn int_range(kind: Kind, bits: u32) -> Option<(i128, i128)> {
    if !integral_bits_ok(kind, bits) {
        return None;
    }
    Some(match kind {
        Kind::Bool => (0, 1),
        Kind::Int => (-(1i128 << (bits - 1)), (1i128 << (bits - 1)) - 1),
        _ => (0, (1i128 << bits) - 1),
    })
}

/// Inclusive range of a numeric type as floats: integral types as `int_range`, REAL32
/// ±`f32::MAX`, REAL64 unbounded (±∞). `None` for strings and bytes.
pub fn range(kind: Kind, bits: u32) -> Option<(f64, f64)> {
    match kind {
        Kind::Real if bits == 32 => Some((-(f32::MAX as f64), f32::MAX as f64)),
        Kind::Real if bits == 64 => Some((f64::NEG_INFINITY, f64::INFINITY)),
        Kind::Real => None,
        _ => int_range(kind, bits).map(|(lo, hi)| (lo as f64, hi as f64)),
    }
}

const fn mask(bits: u32) -> u64 {
    if bits >= 64 {
        u64::MAX
    } else {
        (1u64 << bits) - 1
    }
}

/// The raw bits (`bits` long, unsigned) of an integer `value` for an integral type, or why it
/// does not fit. A BOOL takes 0 and 1 only.
pub fn encode_int(kind: Kind, bits: u32, value: i128) -> Result<u64, ValueError> {
    let (lo, hi) = int_range(kind, bits).ok_or(ValueError::NotNumeric)?;
    if value < lo || value > hi {
        return Err(ValueError::OutOfRange {
            minimum: lo as f64,
            maximum: hi as f64,
        });
    }
    Ok((value as u64) & mask(bits))
}

/// The value of raw bits read from the wire for an integral type (sign extended for `Int`; a
/// BOOL is its bit 0). A bit length beyond 64 reads as unsigned 64 bits, never a panic.
pub const fn decode_int(kind: Kind, bits: u32, raw: u64) -> i128 {
    let raw = raw & mask(bits);
    match kind {
        Kind::Bool => (raw & 1) as i128,
        Kind::Int if bits > 0 && bits <= 64 && raw & (1u64 << (bits - 1)) != 0 => {
            raw as i128 - (1i128 << bits)
        }
        _ => raw as i128,
    }
}

/// The check of a numeric write: `value` must be finite, whole for integral types, and inside
/// `minimum..=maximum` (a variable's range, at most the type's).
pub fn check(kind: Kind, value: f64, minimum: f64, maximum: f64) -> Result<(), ValueError> {
    if !kind.numeric() {
        return Err(ValueError::NotNumeric);
    }
    if !value.is_finite() {
        return Err(ValueError::NotFinite);
    }
    if kind.integral() && value.fract() != 0.0 {
        return Err(ValueError::NotInteger);
    }
    if value < minimum || value > maximum {
        return Err(ValueError::OutOfRange { minimum, maximum });
    }
    Ok(())
}

/// Check `value` against the type's own range and return its raw bits: two's complement for
/// integers, IEEE 754 for reals (REAL32 rounds to the nearest float).
pub fn encode(kind: Kind, bits: u32, value: f64) -> Result<u64, ValueError> {
    let (lo, hi) = range(kind, bits).ok_or(ValueError::NotNumeric)?;
    check(kind, value, lo, hi)?;
    match kind {
        Kind::Real if bits == 32 => Ok(u64::from((value as f32).to_bits())),
        Kind::Real => Ok(value.to_bits()),
        // Whole and within ±2^64 here, so exact in i128; compared again as an integer because
        // the float limits round (u64::MAX as f64 is 2^64, one past the largest UINT64).
        _ => encode_int(kind, bits, value as i128),
    }
}

/// The value of raw bits as a float (reals from their IEEE 754 bits).
pub fn decode(kind: Kind, bits: u32, raw: u64) -> f64 {
    match kind {
        Kind::Real if bits == 32 => f64::from(f32::from_bits(raw as u32)),
        Kind::Real => f64::from_bits(raw),
        _ => decode_int(kind, bits, raw) as f64,
    }
}

/// Read a little-endian bit field of `area` (bit 0 is the LSB of byte 0), `None` when the area
/// is too short. At most 64 bits.
pub fn read_bits(area: &[u8], bit_offset: usize, bit_length: u32) -> Option<u64> {
    if bit_length == 0 || bit_length > 64 {
        return None;
    }
    let first = bit_offset / 8;
    let last = (bit_offset + bit_length as usize).div_ceil(8);
    let bytes = area.get(first..last)?;
    let mut chunk: u128 = 0;
    for (i, b) in bytes.iter().enumerate() {
        chunk |= u128::from(*b) << (8 * i);
    }
    Some(((chunk >> (bit_offset % 8)) as u64) & mask(bit_length))
}

/// Write `raw` into a little-endian bit field of `area`; false when the area is too short.
pub fn write_bits(area: &mut [u8], bit_offset: usize, bit_length: u32, raw: u64) -> bool {
    if bit_length == 0 || bit_length > 64 {
        return false;
    }
    let first = bit_offset / 8;
    let last = (bit_offset + bit_length as usize).div_ceil(8);
    let Some(bytes) = area.get_mut(first..last) else {
        return false;
    };
    let shift = bit_offset % 8;
    let field = u128::from(mask(bit_length)) << shift;
    let value = (u128::from(raw) << shift) & field;
    for (i, b) in bytes.iter_mut().enumerate() {
        let m = (field >> (8 * i)) as u8;
        *b = (*b & !m) | ((value >> (8 * i)) as u8 & m);
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_of_types_at_bit_lengths() {
        assert_eq!(int_range(Kind::Int, 8), Some((-128, 127)));
        assert_eq!(int_range(Kind::Uint, 12), Some((0, 4095)));
        assert_eq!(int_range(Kind::Bool, 1), Some((0, 1)));
        assert_eq!(int_range(Kind::Uint, 64), Some((0, u64::MAX as i128)));
        assert_eq!(int_range(Kind::Real, 32), None);
        assert_eq!(
            range(Kind::Real, 32),
            Some((-3.4028234663852886e38, 3.4028234663852886e38))
        );
    }

    #[test]
    fn integers_encode_as_twos_complement_and_back() {
        assert_eq!(encode_int(Kind::Int, 16, -2), Ok(0xFFFE));
        assert_eq!(decode_int(Kind::Int, 16, 0xFFFE), -2);
        assert_eq!(encode_int(Kind::Int, 64, i64::MIN as i128), Ok(1 << 63));
        assert_eq!(decode_int(Kind::Uint, 64, u64::MAX), u64::MAX as i128);
        assert_eq!(
            encode_int(Kind::Int, 8, 200),
            Err(ValueError::OutOfRange {
                minimum: -128.0,
                maximum: 127.0
            })
        );
        assert!(encode_int(Kind::Bool, 1, 2).is_err());
        assert_eq!(decode_int(Kind::Bool, 1, 3), 1);
    }

    #[test]
    fn the_write_check() {
        assert_eq!(
            check(Kind::Int, f64::NAN, -1.0, 1.0),
            Err(ValueError::NotFinite)
        );
        assert_eq!(
            check(Kind::Uint, 1.5, 0.0, 9.0),
            Err(ValueError::NotInteger)
        );
        assert_eq!(check(Kind::Real, 1.5, 0.0, 9.0), Ok(()));
        assert!(matches!(
            check(Kind::Uint, 10.0, 0.0, 9.0),
            Err(ValueError::OutOfRange { .. })
        ));
        assert_eq!(
            check(Kind::String, 1.0, 0.0, 9.0),
            Err(ValueError::NotNumeric)
        );
        assert_eq!(encode(Kind::Int, 16, -2.0), Ok(0xFFFE));
        assert_eq!(encode(Kind::Real, 32, 1.5), Ok(u64::from(1.5f32.to_bits())));
        assert_eq!(decode(Kind::Real, 32, u64::from(1.5f32.to_bits())), 1.5);
        // 2^64 passes the float comparison (the limit rounds up to it) but not the integer one.
        assert!(encode(Kind::Uint, 64, 18_446_744_073_709_551_616.0).is_err());
        assert_eq!(
            encode(Kind::Int, 64, -9_223_372_036_854_775_808.0),
            Ok(1 << 63)
        );
    }

    #[test]
    fn bit_fields_little_endian() {
        let mut area = [0u8; 4];
        assert!(write_bits(&mut area, 3, 12, 0xABC));
        assert_eq!(area, [0xE0, 0x55, 0x00, 0x00]);
        assert_eq!(read_bits(&area, 3, 12), Some(0xABC));
        assert!(write_bits(&mut area, 0, 32, 0xFFFF_FFFF));
        assert_eq!(read_bits(&area, 0, 32), Some(0xFFFF_FFFF));
        assert_eq!(read_bits(&area, 30, 8), None);
        assert!(!write_bits(&mut area, 30, 8, 1));
    }
}
