//! CANopen over EtherCAT (ETG.1000.6 §5.6): the CoE header's services, the SDO command
//! specifiers, the SDO Information opcodes, the object codes and the SDO abort codes with
//! their texts (taken over from CiA 301).
//!
//! Layout (little endian): CoE header (2 bytes: bits 0..=8 number, 12..=15 service); an SDO
//! request/response after it: command byte (bits 5..=7 command specifier, bit 4 complete access
//! on initiate or toggle on segments, bits 2..=3 unused bytes of an expedited transfer, bit 1
//! expedited, bit 0 size indicator or last segment), index (2), subindex (1), 4 data bytes.

crate::named_constants! {
    /// Services, specifiers, opcodes and sizes, by name.
    pub const TABLE;
    /// CoE header length.
    pub const HEADER_LEN: usize = 2;
    /// SDO frame: CoE header, command, index, subindex, 4 data bytes.
    pub const SDO_HEADER_LEN: usize = 10;
    /// Service: emergency.
    pub const SERVICE_EMERGENCY: u16 = 1;
    /// Service: SDO request.
    pub const SERVICE_SDO_REQUEST: u16 = 2;
    /// Service: SDO response.
    pub const SERVICE_SDO_RESPONSE: u16 = 3;
    /// Service: TxPDO.
    pub const SERVICE_TXPDO: u16 = 4;
    /// Service: RxPDO.
    pub const SERVICE_RXPDO: u16 = 5;
    /// Service: SDO information.
    pub const SERVICE_SDO_INFORMATION: u16 = 8;
    /// Client command specifier: download segment.
    pub const CCS_DOWNLOAD_SEGMENT: u8 = 0;
    /// Client command specifier: initiate download.
    pub const CCS_DOWNLOAD_INITIATE: u8 = 1;
    /// Client command specifier: initiate upload.
    pub const CCS_UPLOAD_INITIATE: u8 = 2;
    /// Client command specifier: upload segment.
    pub const CCS_UPLOAD_SEGMENT: u8 = 3;
    /// Command specifier of an abort (client or server).
    pub const CS_ABORT: u8 = 4;
    /// Server command specifier: upload segment.
    pub const SCS_UPLOAD_SEGMENT: u8 = 0;
    /// Server command specifier: download segment.
    pub const SCS_DOWNLOAD_SEGMENT: u8 = 1;
    /// Server command specifier: initiate upload.
    pub const SCS_UPLOAD_INITIATE: u8 = 2;
    /// Server command specifier: initiate download.
    pub const SCS_DOWNLOAD_INITIATE: u8 = 3;
    /// Command byte bit 4 on an initiate: complete access.
    pub const COMPLETE_ACCESS: u8 = 0x10;
    /// Command byte bit 4 on a segment: toggle.
    pub const TOGGLE: u8 = 0x10;
    /// Command byte bit 1 on an initiate: expedited transfer (the data is in the 4 bytes).
    pub const EXPEDITED: u8 = 0x02;
    /// Command byte bit 0 on an initiate: the size is indicated.
    pub const SIZE_INDICATED: u8 = 0x01;
    /// Command byte bit 0 on a segment: last segment.
    pub const LAST_SEGMENT: u8 = 0x01;
    /// Command byte bits 2..=3 of an expedited initiate: bytes of the 4 that hold no data.
    pub const EXPEDITED_UNUSED_SHIFT: u8 = 2;
    /// Command byte bits 1..=3 of a segment: bytes of the 7 that hold no data.
    pub const SEGMENT_UNUSED_SHIFT: u8 = 1;
    /// Bits 5..=7 of the command byte: the command specifier.
    pub const SPECIFIER_SHIFT: u8 = 5;
    /// SDO information: get OD list request.
    pub const INFO_OD_LIST_REQ: u8 = 1;
    /// SDO information: get OD list response.
    pub const INFO_OD_LIST_RESP: u8 = 2;
    /// SDO information: get object description request.
    pub const INFO_OBJECT_DESC_REQ: u8 = 3;
    /// SDO information: get object description response.
    pub const INFO_OBJECT_DESC_RESP: u8 = 4;
    /// SDO information: get entry description request.
    pub const INFO_ENTRY_DESC_REQ: u8 = 5;
    /// SDO information: get entry description response.
    pub const INFO_ENTRY_DESC_RESP: u8 = 6;
    /// SDO information: error request.
    pub const INFO_ERROR: u8 = 7;
    /// SDO information opcode bit 7: more fragments follow.
    pub const INFO_INCOMPLETE: u8 = 0x80;
    /// SDO information: the opcode bits.
    pub const INFO_OPCODE_MASK: u8 = 0x7F;
    /// SDO information header: CoE header, opcode, reserved, fragments left (u16).
    pub const INFO_HEADER_LEN: usize = 6;
    /// Entry description access bits 0..=2: readable in PREOP, SAFEOP, OP.
    pub const ACCESS_READ: u16 = 0x07;
    /// Entry description access bits 3..=5: writable in PREOP, SAFEOP, OP.
    pub const ACCESS_WRITE: u16 = 0x38;
    /// Entry description access bit 6: mappable in an RxPDO.
    pub const ACCESS_RXPDO: u16 = 0x40;
    /// Entry description access bit 7: mappable in a TxPDO.
    pub const ACCESS_TXPDO: u16 = 0x80;
    /// OD list type: all objects.
    pub const OD_LIST_ALL: u16 = 1;
    /// Object code: variable.
    pub const OBJECT_VAR: u8 = 7;
    /// Object code: array.
    pub const OBJECT_ARRAY: u8 = 8;
    /// Object code: record.
    pub const OBJECT_RECORD: u8 = 9;
    /// Communication area: device type (u32).
    pub const DEVICE_TYPE: u16 = 0x1000;
    /// Communication area: error register (u8).
    pub const ERROR_REGISTER: u16 = 0x1001;
    /// Communication area: identity object (1 vendor, 2 product, 3 revision, 4 serial).
    pub const IDENTITY: u16 = 0x1018;
    /// First RxPDO mapping object.
    pub const RXPDO_MAPPING: u16 = 0x1600;
    /// Last RxPDO mapping object.
    pub const RXPDO_MAPPING_LAST: u16 = 0x17FF;
    /// First TxPDO mapping object.
    pub const TXPDO_MAPPING: u16 = 0x1A00;
    /// Last TxPDO mapping object.
    pub const TXPDO_MAPPING_LAST: u16 = 0x1BFF;
    /// SyncManager communication types.
    pub const SM_COMM_TYPE: u16 = 0x1C00;
    /// PDO assignment of SyncManager n is at `SM_PDO_ASSIGN + n`.
    pub const SM_PDO_ASSIGN: u16 = 0x1C10;
    /// RxPDO assignment (of SM2, the outputs).
    pub const RXPDO_ASSIGN: u16 = 0x1C12;
    /// TxPDO assignment (of SM3, the inputs).
    pub const TXPDO_ASSIGN: u16 = 0x1C13;
}

/// The CoE header of a message of `service` (number 0).
pub const fn header(service: u16) -> [u8; 2] {
    (service << 12).to_le_bytes()
}

/// The service of a CoE message (upper 4 bits of its header), `None` when too short.
pub fn service_of(payload: &[u8]) -> Option<u16> {
    Some(u16::from(*payload.get(1)? >> 4))
}

/// Name of an object code (`"VAR"`, `"ARRAY"`, `"RECORD"`).
pub fn object_code_name(code: u8) -> Option<&'static str> {
    Some(match code {
        OBJECT_VAR => "VAR",
        OBJECT_ARRAY => "ARRAY",
        OBJECT_RECORD => "RECORD",
        _ => return None,
    })
}

crate::coded_texts! {
    /// SDO abort codes by name.
    pub const ABORTS: u32;
    /// SDO abort codes (ETG.1000.6 table 41 / CiA 301) with their texts.
    pub const ABORT_TEXTS;
    /// Toggle bit not alternated.
    ABORT_TOGGLE_BIT = 0x0503_0000, "toggle bit not alternated";
    /// SDO protocol timed out.
    ABORT_TIMEOUT = 0x0504_0000, "SDO protocol timed out";
    /// Command specifier not valid.
    ABORT_INVALID_COMMAND = 0x0504_0001, "client/server command specifier not valid or unknown";
    /// Invalid block size.
    ABORT_INVALID_BLOCK_SIZE = 0x0504_0002, "invalid block size";
    /// Invalid sequence number.
    ABORT_INVALID_SEQUENCE = 0x0504_0003, "invalid sequence number";
    /// CRC error.
    ABORT_CRC = 0x0504_0004, "CRC error";
    /// Out of memory.
    ABORT_OUT_OF_MEMORY = 0x0504_0005, "out of memory";
    /// Unsupported access.
    ABORT_UNSUPPORTED_ACCESS = 0x0601_0000, "unsupported access to an object";
    /// Read of a write-only object.
    ABORT_WRITE_ONLY = 0x0601_0001, "attempt to read a write-only object";
    /// Write of a read-only object.
    ABORT_READ_ONLY = 0x0601_0002, "attempt to write a read-only object";
    /// Subindex 0 must be 0 for write access.
    ABORT_SUBINDEX0_NOT_ZERO = 0x0601_0003,
        "subindex cannot be written, subindex 0 must be 0 for write access";
    /// Complete access not supported.
    ABORT_NO_COMPLETE_ACCESS = 0x0601_0004, "complete access not supported for this object";
    /// Object longer than the mailbox.
    ABORT_OBJECT_TOO_LONG = 0x0601_0005, "object length exceeds the mailbox size";
    /// Object mapped to an RxPDO.
    ABORT_MAPPED_TO_RXPDO = 0x0601_0006, "object mapped to an RxPDO, SDO download blocked";
    /// Object does not exist.
    ABORT_NO_OBJECT = 0x0602_0000, "object does not exist in the object dictionary";
    /// Object cannot be mapped.
    ABORT_CANNOT_MAP = 0x0604_0041, "object cannot be mapped to the PDO";
    /// PDO too long.
    ABORT_PDO_TOO_LONG = 0x0604_0042,
        "number and length of the mapped objects would exceed the PDO length";
    /// General parameter incompatibility.
    ABORT_PARAMETER_INCOMPATIBLE = 0x0604_0043, "general parameter incompatibility";
    /// General internal incompatibility.
    ABORT_INTERNAL_INCOMPATIBLE = 0x0604_0047, "general internal incompatibility in the device";
    /// Hardware error.
    ABORT_HARDWARE = 0x0606_0000, "access failed because of a hardware error";
    /// Length mismatch.
    ABORT_LENGTH_MISMATCH = 0x0607_0010,
        "data type does not match, length of service parameter does not match";
    /// Length too high.
    ABORT_LENGTH_TOO_HIGH = 0x0607_0012,
        "data type does not match, length of service parameter too high";
    /// Length too low.
    ABORT_LENGTH_TOO_LOW = 0x0607_0013,
        "data type does not match, length of service parameter too low";
    /// Subindex does not exist.
    ABORT_NO_SUBINDEX = 0x0609_0011, "subindex does not exist";
    /// Value range exceeded.
    ABORT_VALUE_RANGE = 0x0609_0030, "value range of parameter exceeded";
    /// Value too high.
    ABORT_VALUE_TOO_HIGH = 0x0609_0031, "value of parameter written too high";
    /// Value too low.
    ABORT_VALUE_TOO_LOW = 0x0609_0032, "value of parameter written too low";
    /// Maximum below minimum.
    ABORT_MAX_BELOW_MIN = 0x0609_0036, "maximum value is less than minimum value";
    /// General error.
    ABORT_GENERAL = 0x0800_0000, "general error";
    /// Cannot transfer or store.
    ABORT_TRANSFER = 0x0800_0020, "data cannot be transferred or stored to the application";
    /// Local control.
    ABORT_LOCAL_CONTROL = 0x0800_0021,
        "data cannot be transferred or stored because of local control";
    /// Device state.
    ABORT_DEVICE_STATE = 0x0800_0022,
        "data cannot be transferred or stored in the present device state";
    /// No object dictionary.
    ABORT_NO_DICTIONARY = 0x0800_0023, "object dictionary not present or cannot be generated";
    /// No data available.
    ABORT_NO_DATA = 0x0800_0024, "no data available";
}

/// Text of an SDO abort code.
pub fn abort_text(code: u32) -> &'static str {
    crate::lookup(ABORT_TEXTS, code).unwrap_or("unknown abort code")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn abort_texts_and_headers() {
        assert_eq!(
            abort_text(0x0602_0000),
            "object does not exist in the object dictionary"
        );
        assert_eq!(abort_text(0x1234_5678), "unknown abort code");
        assert_eq!(header(SERVICE_SDO_REQUEST), [0x00, 0x20]);
        assert_eq!(service_of(&[0x00, 0x30, 0x40]), Some(SERVICE_SDO_RESPONSE));
        assert_eq!(object_code_name(OBJECT_RECORD), Some("RECORD"));
    }
}
