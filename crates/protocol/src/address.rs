//! Object dictionary addresses: the one grammar for index and subindex, and the one way to
//! write them.
//!
//! Both parts are hexadecimal, as ETG and vendor documentation write them, with or without the
//! `0x` prefix, in either case:
//!
//! ```text
//! address  = index ":" subindex          (blanks around the whole are ignored)
//! index    = ["0x" | "0X"] hexdigit+     value 0x0000..=0xFFFF
//! subindex = ["0x" | "0X"] hexdigit+     value 0x00..=0xFF
//! ```
//!
//! So `0x1600:0a`, `0x1600:0x0a`, `1600:0A` and `1600:a` are all index 0x1600 subindex 0x0A,
//! `7000:01` is 0x7000 subindex 1 everywhere, and `0x1600:10` is subindex 0x10 (16), never
//! decimal ten. There is no decimal form: `28720:10` is refused (index 0x28720 is too large)
//! rather than read as 0x7030.
//!
//! Text that does not have the shape of an address (no colon, or something other than hex
//! digits around it) is no address: where a name is allowed too (process variables, ESI object
//! names), it is looked up as a name. Text with the shape but out of range is an error that
//! says so. The canonical form, used for keys and messages, is `0x7000:01` (`format`).
//!
//! An index on its own (a PDO index, an `sdo_init` index, a CiA 402 extra's object, an ESC
//! register address) and a subindex on its own follow the same rule: hexadecimal, with or
//! without `0x`. A bare `6040` is 0x6040 wherever an index is read from text (`parse_index`,
//! `parse_subindex`); there is no decimal form for either.
//!
//! ```text
//! index    = ["0x" | "0X"] hexdigit+     value 0x0000..=0xFFFF
//! subindex = ["0x" | "0X"] hexdigit+     value 0x00..=0xFF
//! ```
//!
//! A process-data entry that one slave maps more than once (EtherBerry maps 0x0005:01 in an
//! RxPDO and in a TxPDO) is named with the PDO in front:
//!
//! ```text
//! pdo_address = pdo "/" address         (0x1600/0x0005:01)
//! pdo         = ["0x" | "0X"] hexdigit+ value 0x0000..=0xFFFF
//! ```

/// Why text that looks like an address is not a valid one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AddressError {
    /// Not of the form `index:subindex` with hexadecimal parts (it may be a name).
    NotAnAddress,
    /// The index is larger than 0xFFFF.
    IndexTooLarge,
    /// The subindex is larger than 0xFF.
    SubindexTooLarge,
}

impl core::fmt::Display for AddressError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            AddressError::NotAnAddress => {
                "not an object address (index:subindex, both hexadecimal, e.g. 0x7000:01)"
            }
            AddressError::IndexTooLarge => {
                "index out of range (0x0000..0xFFFF; object addresses are hexadecimal)"
            }
            AddressError::SubindexTooLarge => {
                "subindex out of range (0x00..0xFF; object addresses are hexadecimal)"
            }
        })
    }
}

impl std::error::Error for AddressError {}

/// One hexadecimal part with an optional `0x`/`0X` prefix; `None` when it is not one, the value
/// saturated at `u32::MAX` otherwise (leading zeros are fine).
fn hex_part(part: &str) -> Option<u32> {
    let digits = part
        .strip_prefix("0x")
        .or_else(|| part.strip_prefix("0X"))
        .unwrap_or(part);
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    let mut value: u32 = 0;
    for b in digits.bytes() {
        let d = (b as char).to_digit(16)?;
        value = value.saturating_mul(16).saturating_add(d);
    }
    Some(value)
}

/// Parse an object address (see the module documentation for the grammar).
pub fn parse(text: &str) -> Result<(u16, u8), AddressError> {
    let (index, subindex) = text
        .trim()
        .split_once(':')
        .ok_or(AddressError::NotAnAddress)?;
    let (Some(index), Some(subindex)) = (hex_part(index), hex_part(subindex)) else {
        return Err(AddressError::NotAnAddress);
    };
    let index = u16::try_from(index).map_err(|_| AddressError::IndexTooLarge)?;
    let subindex = u8::try_from(subindex).map_err(|_| AddressError::SubindexTooLarge)?;
    Ok((index, subindex))
}

/// Parse an index on its own (`0x6040`, `6040`: hexadecimal either way; see the module
/// documentation).
pub fn parse_index(text: &str) -> Result<u16, AddressError> {
    let value = hex_part(text.trim()).ok_or(AddressError::NotAnAddress)?;
    u16::try_from(value).map_err(|_| AddressError::IndexTooLarge)
}

/// Parse a subindex on its own (`0x0a`, `a`, `10` = 0x10: hexadecimal either way).
pub fn parse_subindex(text: &str) -> Result<u8, AddressError> {
    let value = hex_part(text.trim()).ok_or(AddressError::NotAnAddress)?;
    u8::try_from(value).map_err(|_| AddressError::SubindexTooLarge)
}

/// Parse an address with an optional PDO in front (`0x1600/0x0005:01`): `(pdo, index,
/// subindex)`, the PDO `None` when there is none.
pub fn parse_in_pdo(text: &str) -> Result<(Option<u16>, u16, u8), AddressError> {
    let text = text.trim();
    let Some((pdo, address)) = text.split_once('/') else {
        let (index, subindex) = parse(text)?;
        return Ok((None, index, subindex));
    };
    let pdo = hex_part(pdo).ok_or(AddressError::NotAnAddress)?;
    if address.starts_with(char::is_whitespace) {
        return Err(AddressError::NotAnAddress);
    }
    let (index, subindex) = parse(address)?;
    let pdo = u16::try_from(pdo).map_err(|_| AddressError::IndexTooLarge)?;
    Ok((Some(pdo), index, subindex))
}

/// The canonical form of an address in a PDO: `0x1600/0x0005:01`.
pub fn format_in_pdo(pdo: u16, index: u16, subindex: u8) -> String {
    format!("0x{pdo:04x}/{}", format(index, subindex))
}

/// Write an address in the canonical form `0x7000:01` into `out` (no allocation).
pub fn write(index: u16, subindex: u8, out: &mut impl core::fmt::Write) -> core::fmt::Result {
    write!(out, "0x{index:04x}:{subindex:02x}")
}

/// The canonical form of an address: `0x7000:01`.
pub fn format(index: u16, subindex: u8) -> String {
    let mut s = String::with_capacity(9);
    let _ = write(index, subindex, &mut s);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_spelling_of_one_address() {
        for text in [
            "0x1600:0a",
            "0x1600:0x0a",
            "1600:0A",
            "1600:a",
            " 0X1600:0X0A ",
            "01600:00a",
        ] {
            assert_eq!(parse(text), Ok((0x1600, 0x0A)), "{text}");
        }
        assert_eq!(parse("7000:01"), Ok((0x7000, 1)));
        assert_eq!(
            parse("0x1600:10"),
            Ok((0x1600, 0x10)),
            "the subindex is hex too"
        );
    }

    #[test]
    fn a_bare_index_is_hexadecimal() {
        for text in ["6040", "0x6040", "0X6040", " 6040 ", "06040"] {
            assert_eq!(parse_index(text), Ok(0x6040), "{text}");
        }
        assert_eq!(parse_subindex("10"), Ok(0x10));
        assert_eq!(parse_subindex("0x0a"), Ok(0x0A));
        assert_eq!(parse_index("1_000"), Err(AddressError::NotAnAddress));
        assert_eq!(parse_index("-1"), Err(AddressError::NotAnAddress));
        assert_eq!(parse_index(""), Err(AddressError::NotAnAddress));
        assert_eq!(parse_index("10000"), Err(AddressError::IndexTooLarge));
        assert_eq!(parse_subindex("100"), Err(AddressError::SubindexTooLarge));
    }

    #[test]
    fn names_and_out_of_range_addresses() {
        for name in [
            "hip_angle",
            "7000",
            "7000:",
            ":1",
            "0x:1",
            "7000:1:2",
            "7000 :1",
            "g000:1",
        ] {
            assert_eq!(parse(name), Err(AddressError::NotAnAddress), "{name}");
        }
        assert_eq!(parse("28720:10"), Err(AddressError::IndexTooLarge));
        assert_eq!(parse("17000:3"), Err(AddressError::IndexTooLarge));
        assert_eq!(parse("7000:103"), Err(AddressError::SubindexTooLarge));
        assert_eq!(parse("ffffffffffff:1"), Err(AddressError::IndexTooLarge));
    }

    #[test]
    fn an_address_in_a_pdo() {
        assert_eq!(parse_in_pdo("0x1600/0x0005:01"), Ok((Some(0x1600), 5, 1)));
        assert_eq!(parse_in_pdo("1a00/5:1"), Ok((Some(0x1a00), 5, 1)));
        assert_eq!(parse_in_pdo("0x7000:01"), Ok((None, 0x7000, 1)));
        assert_eq!(parse_in_pdo("x/5:1"), Err(AddressError::NotAnAddress));
        assert_eq!(parse_in_pdo("1600/ 5:1"), Err(AddressError::NotAnAddress));
        assert_eq!(parse_in_pdo("10000/5:1"), Err(AddressError::IndexTooLarge));
        assert_eq!(format_in_pdo(0x1a00, 5, 1), "0x1a00/0x0005:01");
    }

    #[test]
    fn canonical_form() {
        assert_eq!(format(0x7030, 0x0a), "0x7030:0a");
        assert_eq!(parse(&format(0x1c12, 0)), Ok((0x1c12, 0)));
    }
}
