//! Servo drive profile over EtherCAT (SoE, ETG.1000.6 §5.8 / IEC 61158-6-12, the Sercos
//! parameter model of IEC 61800-7-204): the SoE header, its opcodes and element flags, the IDN
//! encoding, the attribute element and the error codes with their texts.
//!
//! Layout (little endian), after the 6-byte mailbox header (type 0x05):
//! - byte 0: OpCode (bits 0..=2), Incomplete (bit 3: more fragments follow), Error (bit 4),
//!   drive number (bits 5..=7: the drive of a multi-axis slave);
//! - byte 1: element flags (which elements of the IDN the service transfers);
//! - bytes 2..=3: the IDN, or in a fragment of a segmented transfer the fragments left;
//! - then the data. An error response carries the 16-bit error code as its last two bytes.
//!
//! An IDN: bit 15 S (0, standard) or P (1, product specific), bits 12..=14 the parameter set,
//! bits 0..=11 the number (S-0-0024 is 24, P-0-0010 is 0x800A).
//!
//! A list element (the value of S-0-0016, a name) starts with its current length in bytes and
//! its maximum length in bytes (u16 each), then the items.

crate::named_constants! {
    /// Header length, opcodes, header bits, element flags, IDN and attribute fields, by name.
    pub const TABLE;
    /// SoE header length (after the mailbox header).
    pub const HEADER_LEN: usize = 4;
    /// OpCode: read request.
    pub const OPCODE_READ_REQUEST: u8 = 1;
    /// OpCode: read response.
    pub const OPCODE_READ_RESPONSE: u8 = 2;
    /// OpCode: write request.
    pub const OPCODE_WRITE_REQUEST: u8 = 3;
    /// OpCode: write response.
    pub const OPCODE_WRITE_RESPONSE: u8 = 4;
    /// OpCode: notification (a changed procedure command, slave to master).
    pub const OPCODE_NOTIFICATION: u8 = 5;
    /// OpCode: slave info (SOEM names the code ECT_SOE_EMERGENCY).
    pub const OPCODE_SLAVE_INFO: u8 = 6;
    /// Byte 0 bits 0..=2: the OpCode.
    pub const OPCODE_MASK: u8 = 0x07;
    /// Byte 0 bit 3: more fragments follow (bytes 2..=3 then count the fragments left).
    pub const INCOMPLETE: u8 = 0x08;
    /// Byte 0 bit 4: the response is an error (its last two bytes are the error code).
    pub const ERROR: u8 = 0x10;
    /// Byte 0 bits 5..=7: the drive number.
    pub const DRIVE_SHIFT: u8 = 5;
    /// Drives a slave can address (3 bits).
    pub const MAX_DRIVES: u8 = 8;
    /// Element flag bit 0: data state.
    pub const ELEMENT_DATA_STATE: u8 = 0x01;
    /// Element flag bit 1: name.
    pub const ELEMENT_NAME: u8 = 0x02;
    /// Element flag bit 2: attribute.
    pub const ELEMENT_ATTRIBUTE: u8 = 0x04;
    /// Element flag bit 3: unit.
    pub const ELEMENT_UNIT: u8 = 0x08;
    /// Element flag bit 4: minimum.
    pub const ELEMENT_MINIMUM: u8 = 0x10;
    /// Element flag bit 5: maximum.
    pub const ELEMENT_MAXIMUM: u8 = 0x20;
    /// Element flag bit 6: value (the operation data).
    pub const ELEMENT_VALUE: u8 = 0x40;
    /// Element flag bit 7: default value.
    pub const ELEMENT_DEFAULT: u8 = 0x80;
    /// IDN bit 15: a product-specific (P) parameter; clear: a standard (S) one.
    pub const IDN_PRODUCT: u16 = 0x8000;
    /// IDN bits 12..=14: the parameter set.
    pub const IDN_SET_SHIFT: u16 = 12;
    /// IDN bits 0..=11: the parameter number.
    pub const IDN_NUMBER_MASK: u16 = 0x0FFF;
    /// S-0-0016: configuration list of the AT (the IDNs the drive sends cyclically, after
    /// its status word).
    pub const IDN_AT_LIST: u16 = 16;
    /// S-0-0024: configuration list of the MDT (the IDNs the drive receives cyclically, after
    /// the master control word).
    pub const IDN_MDT_LIST: u16 = 24;
    /// S-0-0134: master control word, always the first word of the MDT, never in its list.
    pub const IDN_CONTROL_WORD: u16 = 134;
    /// S-0-0135: drive status word, always the first word of the AT, never in its list.
    pub const IDN_STATUS_WORD: u16 = 135;
    /// A list element: current length (u16, bytes) and maximum length (u16, bytes).
    pub const LIST_HEADER_LEN: usize = 4;
    /// Attribute bits 0..=15: conversion factor.
    pub const ATTR_FACTOR_MASK: u32 = 0xFFFF;
    /// Attribute bits 16..=18: data length (see `ATTR_LEN_*`).
    pub const ATTR_LEN_SHIFT: u32 = 16;
    /// Data length 0b000: one byte (reserved in Sercos II; SOEM reads it as 8 bits).
    pub const ATTR_LEN_1: u32 = 0;
    /// Data length 0b001: two bytes.
    pub const ATTR_LEN_2: u32 = 1;
    /// Data length 0b010: four bytes.
    pub const ATTR_LEN_4: u32 = 2;
    /// Data length 0b011: eight bytes.
    pub const ATTR_LEN_8: u32 = 3;
    /// Data length bit 2 (attribute bit 18): variable length (a list or string) whose items
    /// are 1, 2, 4 or 8 bytes by bits 16..=17.
    pub const ATTR_LIST: u32 = 1 << 18;
    /// Attribute bit 19: a procedure command.
    pub const ATTR_COMMAND: u32 = 1 << 19;
    /// Attribute bits 20..=22: data type and display format (see `ATTR_TYPE_*`).
    pub const ATTR_TYPE_SHIFT: u32 = 20;
    /// Data type: binary.
    pub const ATTR_TYPE_BINARY: u32 = 0;
    /// Data type: unsigned integer.
    pub const ATTR_TYPE_UNSIGNED: u32 = 1;
    /// Data type: signed integer.
    pub const ATTR_TYPE_SIGNED: u32 = 2;
    /// Data type: unsigned integer shown in hexadecimal.
    pub const ATTR_TYPE_HEX: u32 = 3;
    /// Data type: text.
    pub const ATTR_TYPE_TEXT: u32 = 4;
    /// Data type: an IDN.
    pub const ATTR_TYPE_IDN: u32 = 5;
    /// Data type: floating point.
    pub const ATTR_TYPE_FLOAT: u32 = 6;
    /// Attribute bits 24..=27: decimal places.
    pub const ATTR_DECIMALS_SHIFT: u32 = 24;
    /// Attribute bit 28: write protected in PREOP (Sercos CP2).
    pub const ATTR_WP_PREOP: u32 = 1 << 28;
    /// Attribute bit 29: write protected in SAFEOP (CP3).
    pub const ATTR_WP_SAFEOP: u32 = 1 << 29;
    /// Attribute bit 30: write protected in OP (CP4).
    pub const ATTR_WP_OP: u32 = 1 << 30;
}

/// The decoded SoE header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// OpCode (bits 0..=2 of byte 0).
    pub opcode: u8,
    /// More fragments follow.
    pub incomplete: bool,
    /// An error response.
    pub error: bool,
    /// Drive number 0..=7.
    pub drive: u8,
    /// Element flags.
    pub elements: u8,
    /// The IDN, or the fragments left of an incomplete transfer.
    pub idn: u16,
}

impl Header {
    /// Decode the first four bytes of `data` (`None` when shorter).
    pub fn decode(data: &[u8]) -> Option<Header> {
        let h = data.get(..HEADER_LEN)?;
        Some(Header {
            opcode: h[0] & OPCODE_MASK,
            incomplete: h[0] & INCOMPLETE != 0,
            error: h[0] & ERROR != 0,
            drive: h[0] >> DRIVE_SHIFT,
            elements: h[1],
            idn: u16::from_le_bytes([h[2], h[3]]),
        })
    }

    /// The four header bytes.
    pub fn encode(&self) -> [u8; HEADER_LEN] {
        let mut b0 = (self.opcode & OPCODE_MASK) | ((self.drive & 0x07) << DRIVE_SHIFT);
        if self.incomplete {
            b0 |= INCOMPLETE;
        }
        if self.error {
            b0 |= ERROR;
        }
        let [i0, i1] = self.idn.to_le_bytes();
        [b0, self.elements, i0, i1]
    }
}

/// An IDN from its parts: `product` (P, else S), parameter set 0..=7 and number 0..=4095.
pub const fn idn(product: bool, set: u16, number: u16) -> u16 {
    (if product { IDN_PRODUCT } else { 0 })
        | ((set & 0x7) << IDN_SET_SHIFT)
        | (number & IDN_NUMBER_MASK)
}

/// An IDN as written in Sercos documents: `S-0-0024`, `P-0-0010`.
pub fn format_idn(idn: u16) -> String {
    format!(
        "{}-{}-{:04}",
        if idn & IDN_PRODUCT != 0 { 'P' } else { 'S' },
        (idn >> IDN_SET_SHIFT) & 0x7,
        idn & IDN_NUMBER_MASK
    )
}

/// The attribute of an IDN whose operation data is `bits` long (fixed length: 8, 16, 32 or
/// 64 bits; other lengths take the next of these) with data type `kind` (`ATTR_TYPE_*`),
/// conversion factor 1 and no decimals.
pub const fn attribute(bits: u32, kind: u32) -> u32 {
    let len = if bits <= 8 {
        ATTR_LEN_1
    } else if bits <= 16 {
        ATTR_LEN_2
    } else if bits <= 32 {
        ATTR_LEN_4
    } else {
        ATTR_LEN_8
    };
    1 | (len << ATTR_LEN_SHIFT) | ((kind & 0x7) << ATTR_TYPE_SHIFT)
}

/// The attribute of a list IDN (variable length) of `item_bytes`-byte items (1, 2, 4, 8).
pub const fn list_attribute(item_bytes: u32, kind: u32) -> u32 {
    attribute(item_bytes * 8, kind) | ATTR_LIST
}

/// Bytes of the operation data an attribute describes: `Some(1|2|4|8)` for fixed length,
/// `None` for a list (variable length).
pub const fn attribute_data_len(attribute: u32) -> Option<usize> {
    if attribute & ATTR_LIST != 0 {
        None
    } else {
        Some(1 << ((attribute >> ATTR_LEN_SHIFT) & 0x3))
    }
}

crate::coded_texts! {
    /// SoE error codes by name.
    pub const ERRORS: u16;
    /// SoE error codes (ETG.1000.6, the Sercos service channel errors) with their texts.
    pub const ERROR_TEXTS;
    /// No error.
    ERR_NONE = 0x0000, "no error";
    /// The IDN does not exist.
    ERR_NO_IDN = 0x1001, "IDN not existing";
    /// Invalid access to element 1 (the IDN).
    ERR_INVALID_ACCESS_ELEMENT1 = 0x1009, "invalid access to element 1";
    /// No name.
    ERR_NO_NAME = 0x2001, "name not existing";
    /// Name too short.
    ERR_NAME_TOO_SHORT = 0x2002, "name transmission too short";
    /// Name too long.
    ERR_NAME_TOO_LONG = 0x2003, "name transmission too long";
    /// Name read only.
    ERR_NAME_READ_ONLY = 0x2004, "name cannot be changed (read only)";
    /// Name write protected now.
    ERR_NAME_WRITE_PROTECTED = 0x2005, "name is write-protected at this time";
    /// Attribute too short.
    ERR_ATTRIBUTE_TOO_SHORT = 0x3002, "attribute transmission too short";
    /// Attribute too long.
    ERR_ATTRIBUTE_TOO_LONG = 0x3003, "attribute transmission too long";
    /// Attribute read only.
    ERR_ATTRIBUTE_READ_ONLY = 0x3004, "attribute cannot be changed (read only)";
    /// Attribute write protected now.
    ERR_ATTRIBUTE_WRITE_PROTECTED = 0x3005, "attribute is write-protected at this time";
    /// No unit.
    ERR_NO_UNIT = 0x4001, "unit not existing";
    /// Unit too short.
    ERR_UNIT_TOO_SHORT = 0x4002, "unit transmission too short";
    /// Unit too long.
    ERR_UNIT_TOO_LONG = 0x4003, "unit transmission too long";
    /// Unit read only.
    ERR_UNIT_READ_ONLY = 0x4004, "unit cannot be changed (read only)";
    /// Unit write protected now.
    ERR_UNIT_WRITE_PROTECTED = 0x4005, "unit is write-protected at this time";
    /// No minimum.
    ERR_NO_MINIMUM = 0x5001, "minimum input value not existing";
    /// Minimum too short.
    ERR_MINIMUM_TOO_SHORT = 0x5002, "minimum input value transmission too short";
    /// Minimum too long.
    ERR_MINIMUM_TOO_LONG = 0x5003, "minimum input value transmission too long";
    /// Minimum read only.
    ERR_MINIMUM_READ_ONLY = 0x5004, "minimum input value cannot be changed (read only)";
    /// Minimum write protected now.
    ERR_MINIMUM_WRITE_PROTECTED = 0x5005, "minimum input value is write-protected at this time";
    /// No maximum.
    ERR_NO_MAXIMUM = 0x6001, "maximum input value not existing";
    /// Maximum too short.
    ERR_MAXIMUM_TOO_SHORT = 0x6002, "maximum input value transmission too short";
    /// Maximum too long.
    ERR_MAXIMUM_TOO_LONG = 0x6003, "maximum input value transmission too long";
    /// Maximum read only.
    ERR_MAXIMUM_READ_ONLY = 0x6004, "maximum input value cannot be changed (read only)";
    /// Maximum write protected now.
    ERR_MAXIMUM_WRITE_PROTECTED = 0x6005, "maximum input value is write-protected at this time";
    /// Operation data too short.
    ERR_DATA_TOO_SHORT = 0x7002, "operation data transmission too short";
    /// Operation data too long.
    ERR_DATA_TOO_LONG = 0x7003, "operation data transmission too long";
    /// Operation data read only.
    ERR_DATA_READ_ONLY = 0x7004, "operation data cannot be changed (read only)";
    /// Operation data write protected in this state.
    ERR_DATA_WRITE_PROTECTED = 0x7005, "operation data is write-protected at this time";
    /// Below the minimum.
    ERR_DATA_BELOW_MINIMUM = 0x7006, "operation data is smaller than the minimum input value";
    /// Above the maximum.
    ERR_DATA_ABOVE_MAXIMUM = 0x7007, "operation data is greater than the maximum input value";
    /// Invalid operation data.
    ERR_DATA_INVALID = 0x7008, "invalid operation data: configured IDN will not be supported";
    /// Password protected.
    ERR_DATA_PASSWORD = 0x7009, "operation data write protected by a password";
    /// Configured cyclically.
    ERR_DATA_CYCLIC = 0x700A, "operation data is write protected, it is configured cyclically";
    /// Invalid indirect addressing.
    ERR_DATA_INDIRECT = 0x700B, "invalid indirect addressing (data container, list handling)";
    /// Write protected by other settings.
    ERR_DATA_OTHER_SETTINGS = 0x700C, "operation data is write protected due to other settings";
    /// Procedure command already active.
    ERR_COMMAND_ACTIVE = 0x7010, "procedure command already active";
    /// Procedure command not interruptible.
    ERR_COMMAND_NOT_INTERRUPTIBLE = 0x7011, "procedure command not interruptible";
    /// Procedure command not executable now.
    ERR_COMMAND_NOT_NOW = 0x7012, "procedure command at this time not executable";
    /// Procedure command not executable (parameters).
    ERR_COMMAND_INVALID = 0x7013,
        "procedure command not executable (invalid or false parameters)";
    /// No data state.
    ERR_NO_DATA_STATE = 0x7014, "no data state";
    /// No default value.
    ERR_NO_DEFAULT = 0x8001, "no default value";
    /// Default value too long.
    ERR_DEFAULT_TOO_LONG = 0x8002, "default value transmission too long";
    /// Default value read only.
    ERR_DEFAULT_READ_ONLY = 0x8004, "default value cannot be changed, read only";
    /// Invalid drive number.
    ERR_INVALID_DRIVE = 0x800A, "invalid drive number";
    /// General error.
    ERR_GENERAL = 0x800B, "general error";
    /// No element addressed.
    ERR_NO_ELEMENT = 0x800C, "no element addressed";
}

/// Text of an SoE error code.
pub fn error_text(code: u16) -> &'static str {
    crate::lookup(ERROR_TEXTS, code).unwrap_or("unknown SoE error")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_bits_round_trip() {
        let h = Header {
            opcode: OPCODE_READ_RESPONSE,
            incomplete: true,
            error: false,
            drive: 5,
            elements: ELEMENT_VALUE,
            idn: 24,
        };
        // opcode 2 | incomplete 0x08 | drive 5 << 5 = 0xAA.
        assert_eq!(h.encode(), [0xAA, 0x40, 24, 0]);
        assert_eq!(Header::decode(&h.encode()), Some(h));
        assert_eq!(Header::decode(&[0; 3]), None);
        let e = Header::decode(&[0x12, 0x04, 0x0A, 0x80]).unwrap();
        assert!(e.error && !e.incomplete);
        assert_eq!(
            (e.opcode, e.drive, e.idn),
            (OPCODE_READ_RESPONSE, 0, 0x800A)
        );
    }

    #[test]
    fn idns_and_attributes() {
        assert_eq!(idn(true, 0, 10), 0x800A);
        assert_eq!(format_idn(0x800A), "P-0-0010");
        assert_eq!(format_idn(idn(false, 1, 24)), "S-1-0024");
        // As Beckhoff's AX5000 dictionary gives S-0-0047 (DINT): 0x0022_0001 plus its
        // write-protection bits.
        assert_eq!(attribute(32, ATTR_TYPE_SIGNED), 0x0022_0001);
        assert_eq!(
            attribute_data_len(attribute(16, ATTR_TYPE_UNSIGNED)),
            Some(2)
        );
        assert_eq!(attribute_data_len(attribute(8, ATTR_TYPE_BINARY)), Some(1));
        // S-0-0016 in the AX5000 dictionary: 0x6055_0001, a list of 2-byte IDNs.
        assert_eq!(list_attribute(2, ATTR_TYPE_IDN), 0x0055_0001);
        assert_eq!(attribute_data_len(list_attribute(2, ATTR_TYPE_IDN)), None);
        assert_eq!(error_text(0x1001), "IDN not existing");
        assert_eq!(error_text(0x1234), "unknown SoE error");
    }
}
