//! CANopen over EtherCAT (ETG.1000.6 §5.6): the CoE header's services, the SDO command
//! specifiers, the SDO Information opcodes, the object codes and the SDO abort codes with
//! their texts (taken over from CiA 301).
//!
//! Layout (little endian): CoE header (2 bytes: bits 0..=8 number, 12..=15 service); an SDO
//! request/response after it: command byte (bits 5..=7 command specifier, bit 4 complete access
//! on initiate or toggle on segments, bits 2..=3 unused bytes of an expedited transfer, bit 1
//! expedited, bit 0 size indicator or last segment), index (2), subindex (1), 4 data bytes.
//! The initiate and abort messages are [`SdoHeader`] (command byte [`InitiateCommand`]), the
//! segments [`Segment`]: the master's SDO client and the simulator's server use only these.

crate::named_constants! {
    /// Services, specifiers, opcodes and sizes, by name.
    pub const TABLE;
    /// CoE header length.
    pub const HEADER_LEN: usize = 2;
    /// Bytes of an SDO segment before its data: the CoE header and the command byte.
    pub const SEGMENT_HEADER_LEN: usize = HEADER_LEN + 1;
    /// Data bytes a segment carries at least: shorter data is padded to this and the command
    /// byte says how many of them are unused (bits 1..=3).
    pub const MIN_SEGMENT_DATA: usize = 7;
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
    /// Communication area: manufacturer software version (VISIBLE_STRING).
    pub const SOFTWARE_VERSION: u16 = 0x100A;
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

/// The decoded CoE header (2 bytes, little endian): bits 0..=8 number, bits 12..=15 service.
/// The same shape as the SoE header (`crate::soe::Header`): a struct with `decode`/`encode`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// Number (bits 0..=8): 0 for SDOs; the PDO number of a PDO over the mailbox.
    pub number: u16,
    /// Service (bits 12..=15): `SERVICE_*`.
    pub service: u16,
}

impl Header {
    /// The header of a message of `service` with number 0.
    pub const fn of(service: u16) -> Header {
        Header { number: 0, service }
    }

    /// Decode the first two bytes of `data` (`None` when shorter).
    pub fn decode(data: &[u8]) -> Option<Header> {
        let h = data.get(..HEADER_LEN)?;
        let word = u16::from_le_bytes([h[0], h[1]]);
        Some(Header {
            number: word & 0x01FF,
            service: word >> 12,
        })
    }

    /// The two header bytes.
    pub const fn encode(&self) -> [u8; HEADER_LEN] {
        ((self.number & 0x01FF) | ((self.service & 0x0F) << 12)).to_le_bytes()
    }
}

/// The CoE header of a message of `service` (number 0).
pub const fn header(service: u16) -> [u8; HEADER_LEN] {
    Header::of(service).encode()
}

/// The service of a CoE message (upper 4 bits of its header), `None` when too short.
pub fn service_of(payload: &[u8]) -> Option<u16> {
    Header::decode(payload).map(|h| h.service)
}

/// A segment message without data (an upload segment request from the master, a download
/// segment response from the slave): CoE header of `service`, command byte (`specifier`,
/// `toggle`; the unused and last bits are reserved here and 0), 7 zero bytes.
pub const fn toggle_message(
    service: u16,
    specifier: u8,
    toggle: bool,
) -> [u8; SEGMENT_HEADER_LEN + MIN_SEGMENT_DATA] {
    let h = header(service);
    let mut m = [0u8; SEGMENT_HEADER_LEN + MIN_SEGMENT_DATA];
    m[0] = h[0];
    m[1] = h[1];
    m[2] = (specifier << SPECIFIER_SHIFT) | if toggle { TOGGLE } else { 0 };
    m
}

/// One SDO segment (ETG.1000.6 §5.6.2.3 and §5.6.2.5): a download segment request from the
/// master or an upload segment response from the slave. The messages that only toggle (upload
/// segment request, download segment response) are [`toggle_message`].
///
/// Layout: CoE header, command byte (bits 5..=7 specifier, bit 4 toggle, bits 1..=3 unused
/// bytes of a segment of up to 7 data bytes, bit 0 last segment), then the data, padded to 7
/// bytes. The master and the simulator build and read segments with this one codec.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Segment<'a> {
    /// The CoE service of the message (`SERVICE_SDO_REQUEST` or `SERVICE_SDO_RESPONSE`).
    pub service: u16,
    /// Command specifier (bits 5..=7): `CCS_*` from the master, `SCS_*` from the slave.
    pub specifier: u8,
    /// Toggle bit (bit 4): alternates from 0 with each segment of a transfer.
    pub toggle: bool,
    /// Last segment of the transfer (bit 0).
    pub last: bool,
    /// The segment's data, without the padding.
    pub data: &'a [u8],
}

impl<'a> Segment<'a> {
    /// The command byte: specifier, toggle, unused bytes and the last-segment bit.
    pub fn command(&self) -> u8 {
        let unused = MIN_SEGMENT_DATA.saturating_sub(self.data.len()) as u8;
        (self.specifier << SPECIFIER_SHIFT)
            | if self.toggle { TOGGLE } else { 0 }
            | (unused << SEGMENT_UNUSED_SHIFT)
            | if self.last { LAST_SEGMENT } else { 0 }
    }

    /// Bytes of the encoded message.
    pub fn encoded_len(&self) -> usize {
        SEGMENT_HEADER_LEN + self.data.len().max(MIN_SEGMENT_DATA)
    }

    /// Append the whole message to `out`: CoE header, command byte, data padded to 7 bytes.
    pub fn encode_into(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&header(self.service));
        out.push(self.command());
        out.extend_from_slice(self.data);
        let padding = MIN_SEGMENT_DATA.saturating_sub(self.data.len());
        out.extend_from_slice(&[0; MIN_SEGMENT_DATA][..padding]);
    }

    /// The whole message in a new vector.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.encoded_len());
        self.encode_into(&mut out);
        out
    }

    /// Decode a segment message (CoE header first). Of a segment of up to 7 data bytes only
    /// the bytes its unused count leaves are data; a longer segment is data to its end.
    /// `None` when the message is shorter than the CoE header and the command byte.
    pub fn decode(message: &'a [u8]) -> Option<Segment<'a>> {
        let header = Header::decode(message)?;
        let command = *message.get(HEADER_LEN)?;
        let body = &message[SEGMENT_HEADER_LEN..];
        let n = if body.len() > MIN_SEGMENT_DATA {
            body.len()
        } else {
            let unused = usize::from((command >> SEGMENT_UNUSED_SHIFT) & 0x07);
            MIN_SEGMENT_DATA.saturating_sub(unused).min(body.len())
        };
        Some(Segment {
            service: header.service,
            specifier: command >> SPECIFIER_SHIFT,
            toggle: command & TOGGLE != 0,
            last: command & LAST_SEGMENT != 0,
            data: &body[..n],
        })
    }
}

/// The command byte of an SDO initiate request or response, or of an abort (ETG.1000.6
/// §5.6.2.1, §5.6.2.4, §5.6.2.7), as bit fields: bits 5..=7 specifier, bit 4 complete access,
/// bits 2..=3 bytes of the 4 that hold no data (expedited with size indicated), bit 1
/// expedited, bit 0 size indicated. The master's SDO client and the simulator's SDO server
/// build and read it only through this type, so the bit layout is written once.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InitiateCommand {
    /// Command specifier (bits 5..=7): `CCS_*` from the master, `SCS_*` from the slave,
    /// `CS_ABORT` from either.
    pub specifier: u8,
    /// Complete access (bit 4): the whole object from subindex 0 or 1 in one transfer.
    pub complete_access: bool,
    /// Bytes of the 4 data bytes that hold no data (bits 2..=3); meaningful only when
    /// `expedited` and `size_indicated` are both set.
    pub unused: u8,
    /// Expedited transfer (bit 1): the data is in the 4 data bytes of the message.
    pub expedited: bool,
    /// Size indicated (bit 0): the size is given, in the data field of a normal transfer or
    /// by `unused` of an expedited one.
    pub size_indicated: bool,
}

impl InitiateCommand {
    /// The command byte.
    pub const fn encode(&self) -> u8 {
        (self.specifier << SPECIFIER_SHIFT)
            | if self.complete_access {
                COMPLETE_ACCESS
            } else {
                0
            }
            | ((self.unused & 0x03) << EXPEDITED_UNUSED_SHIFT)
            | if self.expedited { EXPEDITED } else { 0 }
            | if self.size_indicated {
                SIZE_INDICATED
            } else {
                0
            }
    }

    /// The fields of a command byte.
    pub const fn decode(byte: u8) -> InitiateCommand {
        InitiateCommand {
            specifier: byte >> SPECIFIER_SHIFT,
            complete_access: byte & COMPLETE_ACCESS != 0,
            unused: (byte >> EXPEDITED_UNUSED_SHIFT) & 0x03,
            expedited: byte & EXPEDITED != 0,
            size_indicated: byte & SIZE_INDICATED != 0,
        }
    }
}

/// The 10-byte SDO header of an initiate request or response and of an abort (ETG.1000.6
/// §5.6.2): CoE header, command byte ([`InitiateCommand`]), index (2), subindex (1) and the 4
/// data bytes (the data of an expedited transfer, the size of a normal one, the abort code).
/// A normal transfer's first data follows the header; the caller appends it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SdoHeader {
    /// The CoE service of the message (`SERVICE_SDO_REQUEST` or `SERVICE_SDO_RESPONSE`).
    pub service: u16,
    /// The command byte's fields.
    pub command: InitiateCommand,
    /// Object index.
    pub index: u16,
    /// Subindex (with complete access: 0 or 1, where the transfer starts).
    pub subindex: u8,
    /// The 4 data bytes, as on the wire.
    pub data: [u8; 4],
}

impl SdoHeader {
    /// A header with no transfer flags and zero data: an upload initiate request, a download
    /// initiate response.
    pub const fn new(
        service: u16,
        specifier: u8,
        index: u16,
        subindex: u8,
        complete_access: bool,
    ) -> SdoHeader {
        SdoHeader {
            service,
            command: InitiateCommand {
                specifier,
                complete_access,
                unused: 0,
                expedited: false,
                size_indicated: false,
            },
            index,
            subindex,
            data: [0; 4],
        }
    }

    /// An expedited transfer of `data` (1 to 4 bytes; `None` otherwise) with its size
    /// indicated: a download initiate request or an upload initiate response.
    pub fn expedited(
        service: u16,
        specifier: u8,
        index: u16,
        subindex: u8,
        complete_access: bool,
        data: &[u8],
    ) -> Option<SdoHeader> {
        if data.is_empty() || data.len() > 4 {
            return None;
        }
        let mut h = SdoHeader::new(service, specifier, index, subindex, complete_access);
        h.command.expedited = true;
        h.command.size_indicated = true;
        h.command.unused = (4 - data.len()) as u8;
        h.data[..data.len()].copy_from_slice(data);
        Some(h)
    }

    /// A normal transfer of `size` bytes (size indicated, the size in the data field): a
    /// download initiate request or an upload initiate response; the first data follows.
    pub const fn normal(
        service: u16,
        specifier: u8,
        index: u16,
        subindex: u8,
        complete_access: bool,
        size: u32,
    ) -> SdoHeader {
        let mut h = SdoHeader::new(service, specifier, index, subindex, complete_access);
        h.command.size_indicated = true;
        h.data = size.to_le_bytes();
        h
    }

    /// An abort of the transfer of `index:subindex` with `code` (`ABORT_*`).
    pub const fn abort(service: u16, index: u16, subindex: u8, code: u32) -> SdoHeader {
        let mut h = SdoHeader::new(service, CS_ABORT, index, subindex, false);
        h.data = code.to_le_bytes();
        h
    }

    /// The 10 bytes of the header.
    pub const fn encode(&self) -> [u8; SDO_HEADER_LEN] {
        let h = header(self.service);
        let i = self.index.to_le_bytes();
        let d = self.data;
        [
            h[0],
            h[1],
            self.command.encode(),
            i[0],
            i[1],
            self.subindex,
            d[0],
            d[1],
            d[2],
            d[3],
        ]
    }

    /// Decode the first 10 bytes of `message` (CoE header first); `None` when shorter.
    pub fn decode(message: &[u8]) -> Option<SdoHeader> {
        let h = Header::decode(message)?;
        let m = message.get(..SDO_HEADER_LEN)?;
        Some(SdoHeader {
            service: h.service,
            command: InitiateCommand::decode(m[2]),
            index: u16::from_le_bytes([m[3], m[4]]),
            subindex: m[5],
            data: [m[6], m[7], m[8], m[9]],
        })
    }

    /// The data of an expedited transfer (the bytes the unused count leaves; all 4 when the
    /// size is not indicated), `None` when the transfer is not expedited.
    pub fn expedited_data(&self) -> Option<&[u8]> {
        if !self.command.expedited {
            return None;
        }
        let n = if self.command.size_indicated {
            4 - usize::from(self.command.unused)
        } else {
            4
        };
        Some(&self.data[..n])
    }

    /// The data field as a number: the size of a normal transfer, the code of an abort.
    pub const fn word(&self) -> u32 {
        u32::from_le_bytes(self.data)
    }
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

    #[test]
    fn header_round_trips_and_matches_etg1000_6() {
        // ETG.1000.6 table 29: number in bits 0..=8, service in bits 12..=15. An SDO request
        // is 0x2000 on the wire as 00 20; an emergency 00 10.
        assert_eq!(Header::of(SERVICE_SDO_REQUEST).encode(), [0x00, 0x20]);
        assert_eq!(Header::of(SERVICE_EMERGENCY).encode(), [0x00, 0x10]);
        let h = Header {
            number: 0x1FF,
            service: SERVICE_TXPDO,
        };
        assert_eq!(h.encode(), [0xFF, 0x41]);
        assert_eq!(Header::decode(&h.encode()), Some(h));
        assert_eq!(Header::decode(&[0x00]), None);
    }

    #[test]
    fn segment_byte_images() {
        // A download segment of 3 bytes, toggle 1, last (ETG.1000.6 §5.6.2.3): command
        // 000 1 100 1 = 0x19 (4 unused bytes), data padded to 7.
        let s = Segment {
            service: SERVICE_SDO_REQUEST,
            specifier: CCS_DOWNLOAD_SEGMENT,
            toggle: true,
            last: true,
            data: &[1, 2, 3],
        };
        assert_eq!(s.encode(), [0x00, 0x20, 0x19, 1, 2, 3, 0, 0, 0, 0]);
        assert_eq!(Segment::decode(&s.encode()), Some(s));
        // An upload segment request (master, no data): 011 t 000 0 and 7 zero bytes.
        assert_eq!(
            toggle_message(SERVICE_SDO_REQUEST, CCS_UPLOAD_SEGMENT, false),
            [0x00, 0x20, 0x60, 0, 0, 0, 0, 0, 0, 0]
        );
        assert_eq!(
            toggle_message(SERVICE_SDO_RESPONSE, SCS_DOWNLOAD_SEGMENT, true),
            [0x00, 0x30, 0x30, 0, 0, 0, 0, 0, 0, 0]
        );
        // An empty data segment says 7 unused: decoded, it carries no data.
        let empty = Segment {
            service: SERVICE_SDO_REQUEST,
            specifier: CCS_DOWNLOAD_SEGMENT,
            toggle: false,
            last: true,
            data: &[],
        };
        assert_eq!(empty.encode(), [0x00, 0x20, 0x0F, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(Segment::decode(&empty.encode()), Some(empty));
        // Segments of 7 and more bytes say 0 unused and carry everything.
        let long: Vec<u8> = (0..20).collect();
        let l = Segment {
            service: SERVICE_SDO_RESPONSE,
            specifier: SCS_UPLOAD_SEGMENT,
            toggle: false,
            last: false,
            data: &long,
        };
        let enc = l.encode();
        assert_eq!(&enc[..3], &[0x00, 0x30, 0x00]);
        assert_eq!(Segment::decode(&enc), Some(l));
        assert_eq!(Segment::decode(&[0x00, 0x20]), None);
    }

    #[test]
    fn segments_round_trip_for_every_length() {
        let data: Vec<u8> = (0..40).map(|i| i as u8 ^ 0x5A).collect();
        for n in 0..data.len() {
            for (toggle, last) in [(false, false), (true, false), (false, true), (true, true)] {
                let s = Segment {
                    service: SERVICE_SDO_REQUEST,
                    specifier: CCS_DOWNLOAD_SEGMENT,
                    toggle,
                    last,
                    data: &data[..n],
                };
                let enc = s.encode();
                assert_eq!(enc.len(), s.encoded_len());
                assert_eq!(Segment::decode(&enc), Some(s), "length {n}");
            }
        }
    }

    #[test]
    fn initiate_headers_round_trip_and_match_etg1000_6() {
        // Expedited download of 2 bytes (ETG.1000.6 §5.6.2.1): 001 0 10 1 1 = 0x2B.
        let e = SdoHeader::expedited(
            SERVICE_SDO_REQUEST,
            CCS_DOWNLOAD_INITIATE,
            0x6040,
            0,
            false,
            &[0x0F, 0x00],
        )
        .unwrap();
        assert_eq!(e.encode(), [0x00, 0x20, 0x2B, 0x40, 0x60, 0, 0x0F, 0, 0, 0]);
        assert_eq!(SdoHeader::decode(&e.encode()), Some(e));
        assert_eq!(e.expedited_data(), Some(&[0x0F, 0x00][..]));
        for n in 1..=4 {
            let data = [1, 2, 3, 4];
            let h = SdoHeader::expedited(
                SERVICE_SDO_RESPONSE,
                SCS_UPLOAD_INITIATE,
                0x1000,
                0,
                false,
                &data[..n],
            )
            .unwrap();
            let back = SdoHeader::decode(&h.encode()).unwrap();
            assert_eq!(back.expedited_data(), Some(&data[..n]));
        }
        assert_eq!(
            SdoHeader::expedited(SERVICE_SDO_REQUEST, 1, 0x1000, 0, false, &[]),
            None
        );
        assert_eq!(
            SdoHeader::expedited(SERVICE_SDO_REQUEST, 1, 0x1000, 0, false, &[0; 5]),
            None
        );
        // Upload initiate request with complete access: 010 1 00 0 0 = 0x50.
        let u = SdoHeader::new(SERVICE_SDO_REQUEST, CCS_UPLOAD_INITIATE, 0x1C12, 0, true);
        assert_eq!(u.encode(), [0x00, 0x20, 0x50, 0x12, 0x1C, 0, 0, 0, 0, 0]);
        assert_eq!(SdoHeader::decode(&u.encode()), Some(u));
        assert_eq!(u.expedited_data(), None);
        // Normal upload response of 300 bytes: 010 0 00 0 1 = 0x41, size in the data field.
        let n = SdoHeader::normal(
            SERVICE_SDO_RESPONSE,
            SCS_UPLOAD_INITIATE,
            0x1008,
            0,
            false,
            300,
        );
        assert_eq!(
            n.encode(),
            [0x00, 0x30, 0x41, 0x08, 0x10, 0, 0x2C, 0x01, 0, 0]
        );
        assert_eq!(SdoHeader::decode(&n.encode()), Some(n));
        assert_eq!(n.word(), 300);
        // Abort: 100 0 00 0 0 = 0x80, the code in the data field.
        let a = SdoHeader::abort(SERVICE_SDO_REQUEST, 0x7000, 1, ABORT_TOGGLE_BIT);
        assert_eq!(
            a.encode(),
            [0x00, 0x20, 0x80, 0x00, 0x70, 1, 0, 0, 0x03, 0x05]
        );
        assert_eq!(SdoHeader::decode(&a.encode()), Some(a));
        assert_eq!(a.word(), ABORT_TOGGLE_BIT);
        // Every command byte decodes and encodes to itself.
        for byte in 0..=255u8 {
            assert_eq!(InitiateCommand::decode(byte).encode(), byte);
        }
        assert_eq!(SdoHeader::decode(&[0x00, 0x20, 0x40]), None);
    }
}
