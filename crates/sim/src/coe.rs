//! CoE (CANopen over EtherCAT, ETG.1000.6) server of a virtual slave: SDO upload and download
//! (expedited, normal, segmented, complete access), SDO abort, the PDO assignment/mapping rules,
//! the SDO Information service and emergency messages.
//!
//! The ESC core hands every CoE mailbox message to [`CoeServer::handle`] with the mailbox header
//! already stripped (and the data trimmed to the header's length field) and wraps each returned
//! payload into its own mailbox message. Nothing a master sends can make this code panic: a
//! malformed request is answered with an abort or ignored.
//!
//! The CoE header, the SDO initiate and abort messages and the SDO segments are read and
//! written with the protocol crate's codecs (`ether_ros_protocol::coe::{Header, SdoHeader,
//! Segment, toggle_message}`), the ones the master uses.
//!
//! Wire layout facts used here (all little endian):
//! - CoE header (2 bytes): bits 0..=8 number, 9..=11 reserved, 12..=15 service.
//! - SDO request/response after it: command byte, index (2), subindex (1), 4 data bytes.
//!   Command byte: bits 5..=7 command specifier, bit 4 complete access (initiate) or toggle
//!   (segments), bits 2..=3 unused bytes of an expedited transfer, bit 1 expedited, bit 0 size
//!   indicator (initiate) or last segment (segments); segments carry bits 1..=3 as the number of
//!   unused bytes of a 7-byte segment.
//! - Complete access transfers the subindices back to back as one bit stream; subindex 0 takes
//!   16 bits (8 bits value, 8 bits padding).

use crate::od::{dtype, Access, Entry, ObjectDictionary};

/// CoE services (upper 4 bits of the CoE header): the protocol crate's.
pub mod service {
    pub use ether_ros_protocol::coe::{
        SERVICE_EMERGENCY as EMERGENCY, SERVICE_SDO_INFORMATION as SDO_INFORMATION,
        SERVICE_SDO_REQUEST as SDO_REQUEST, SERVICE_SDO_RESPONSE as SDO_RESPONSE,
    };
}

/// SDO abort codes (ETG.1000.6 / CiA 301) the server sends: the protocol crate's.
pub mod abort {
    pub use ether_ros_protocol::coe::{
        ABORT_CANNOT_MAP as CANNOT_MAP, ABORT_DEVICE_STATE as DEVICE_STATE,
        ABORT_INVALID_COMMAND as INVALID_COMMAND, ABORT_LENGTH_TOO_HIGH as LENGTH_TOO_HIGH,
        ABORT_LENGTH_TOO_LOW as LENGTH_TOO_LOW, ABORT_NO_OBJECT as NO_OBJECT,
        ABORT_NO_SUBINDEX as NO_SUBINDEX, ABORT_PDO_TOO_LONG as PDO_TOO_LONG,
        ABORT_READ_ONLY as READ_ONLY, ABORT_SUBINDEX0_NOT_ZERO as SUBINDEX0_NOT_ZERO,
        ABORT_TOGGLE_BIT as TOGGLE_BIT, ABORT_UNSUPPORTED_ACCESS as UNSUPPORTED_ACCESS,
        ABORT_VALUE_RANGE as VALUE_RANGE, ABORT_VALUE_TOO_HIGH as VALUE_TOO_HIGH,
        ABORT_WRITE_ONLY as WRITE_ONLY,
    };
}

/// Command specifiers (bits 5..=7 of the SDO command byte): the protocol crate's.
mod cs {
    pub use ether_ros_protocol::coe::{
        CCS_DOWNLOAD_INITIATE as DOWNLOAD_INITIATE, CCS_DOWNLOAD_SEGMENT as SEGMENT_DOWN_REQ,
        CCS_UPLOAD_INITIATE as UPLOAD_INITIATE, CCS_UPLOAD_SEGMENT as UPLOAD_SEGMENT_REQ,
        CS_ABORT as ABORT, SCS_DOWNLOAD_INITIATE as DOWNLOAD_INITIATE_RESP,
        SCS_DOWNLOAD_SEGMENT as DOWNLOAD_SEGMENT_RESP, SCS_UPLOAD_INITIATE as UPLOAD_INITIATE_RESP,
        SCS_UPLOAD_SEGMENT as UPLOAD_SEGMENT_RESP,
    };
}

/// SDO Information opcodes: the protocol crate's.
mod info {
    pub use ether_ros_protocol::coe::{
        INFO_ENTRY_DESC_REQ as ENTRY_DESC_REQ, INFO_ENTRY_DESC_RESP as ENTRY_DESC_RESP,
        INFO_ERROR as ERROR, INFO_INCOMPLETE as INCOMPLETE,
        INFO_OBJECT_DESC_REQ as OBJECT_DESC_REQ, INFO_OBJECT_DESC_RESP as OBJECT_DESC_RESP,
        INFO_OD_LIST_REQ as OD_LIST_REQ, INFO_OD_LIST_RESP as OD_LIST_RESP,
        INFO_OPCODE_MASK as OPCODE_MASK,
    };
}

use ether_ros_protocol::coe as facts;

/// Largest process data one PDO may map, in bits: what one datagram of a standard frame carries.
const MAX_PDO_BITS: u32 = 1486 * 8;
/// The smallest payload a response needs (an SDO frame); a smaller mailbox is treated as this.
const MIN_PAYLOAD: usize = 10;
const AL_PREOP: u8 = ether_ros_protocol::al::PREOP;

/// A transfer that spans several mailbox messages.
#[derive(Debug, Default)]
enum Transfer {
    #[default]
    Idle,
    Download {
        index: u16,
        subindex: u8,
        complete_access: bool,
        size: usize,
        data: Vec<u8>,
        toggle: bool,
    },
    Upload {
        index: u16,
        subindex: u8,
        data: Vec<u8>,
        sent: usize,
        toggle: bool,
    },
}

/// The SDO server of one virtual slave. It keeps only the state of a segmented transfer.
#[derive(Debug, Default)]
pub struct CoeServer {
    transfer: Transfer,
}

fn u16_at(b: &[u8], at: usize) -> Option<u16> {
    Some(u16::from_le_bytes([*b.get(at)?, *b.get(at + 1)?]))
}

#[cfg(test)]
fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    let s = b.get(at..at + 4)?;
    Some(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
}

/// SDO abort. Sent with the SDO request service, as slave stacks do; masters accept either.
fn abort_frame(index: u16, subindex: u8, code: u32) -> Vec<u8> {
    facts::SdoHeader::abort(service::SDO_REQUEST, index, subindex, code)
        .encode()
        .to_vec()
}

fn is_string(data_type: u16) -> bool {
    matches!(data_type, dtype::VISIBLE_STRING | dtype::OCTET_STRING)
}

fn is_pdo_assign(index: u16) -> bool {
    index == facts::RXPDO_ASSIGN || index == facts::TXPDO_ASSIGN
}

fn is_rx_mapping(index: u16) -> bool {
    (facts::RXPDO_MAPPING..=facts::RXPDO_MAPPING_LAST).contains(&index)
}

fn is_tx_mapping(index: u16) -> bool {
    (facts::TXPDO_MAPPING..=facts::TXPDO_MAPPING_LAST).contains(&index)
}

/// Objects the master may only change in PREOP, with the PDO rules of ETG.1000.6.
fn is_pdo_config(index: u16) -> bool {
    is_pdo_assign(index) || is_rx_mapping(index) || is_tx_mapping(index)
}

fn object_exists(od: &ObjectDictionary, index: u16) -> bool {
    od.object(index).is_some() || od.entries().iter().any(|e| e.index == index)
}

/// Append `nbits` bits of `src` (little-endian bit order) to `buf` at bit position `pos`.
fn put_bits(buf: &mut Vec<u8>, pos: &mut usize, src: &[u8], nbits: usize) {
    for i in 0..nbits {
        let bit = src.get(i / 8).is_some_and(|b| b >> (i % 8) & 1 != 0);
        let at = *pos + i;
        if buf.len() <= at / 8 {
            buf.resize(at / 8 + 1, 0);
        }
        if bit {
            buf[at / 8] |= 1 << (at % 8);
        }
    }
    *pos += nbits;
}

/// Take `nbits` bits from `src` at bit position `pos` into a fresh little-endian byte string.
fn get_bits(src: &[u8], pos: &mut usize, nbits: usize) -> Vec<u8> {
    let mut out = vec![0u8; nbits.div_ceil(8)];
    for i in 0..nbits {
        let at = *pos + i;
        if src.get(at / 8).is_some_and(|b| b >> (at % 8) & 1 != 0) {
            out[i / 8] |= 1 << (i % 8);
        }
    }
    *pos += nbits;
    out
}

/// Bits an entry takes in a complete-access stream.
fn ca_bits(e: &Entry) -> usize {
    if e.subindex == 0 {
        16
    } else {
        e.bit_length as usize
    }
}

fn le_u32(bytes: &[u8]) -> u32 {
    let mut raw = [0u8; 4];
    for (d, s) in raw.iter_mut().zip(bytes) {
        *d = *s;
    }
    u32::from_le_bytes(raw)
}

/// Check one PDO assignment or mapping entry value the master wants to write.
fn check_pdo_entry(od: &ObjectDictionary, index: u16, value: &[u8]) -> Result<(), u32> {
    let v = le_u32(value);
    if is_pdo_assign(index) {
        let pdo = v as u16;
        let in_range = if index == facts::RXPDO_ASSIGN {
            is_rx_mapping(pdo)
        } else {
            is_tx_mapping(pdo)
        };
        return if in_range && object_exists(od, pdo) {
            Ok(())
        } else {
            Err(abort::VALUE_RANGE)
        };
    }
    let (target, sub, bits) = ((v >> 16) as u16, (v >> 8) as u8, v as u8 as u16);
    if bits == 0 {
        return Err(abort::CANNOT_MAP);
    }
    // Index 0 maps a gap (padding) of any length.
    if target == 0 {
        return Ok(());
    }
    let Some(e) = od.entry(target, sub) else {
        return Err(abort::CANNOT_MAP);
    };
    let direction_ok = if is_rx_mapping(index) {
        e.access != Access::ReadOnly
    } else {
        e.access != Access::WriteOnly
    };
    if !e.pdo_mappable || e.bit_length != bits || !direction_ok {
        return Err(abort::CANNOT_MAP);
    }
    Ok(())
}

/// Check that a PDO assignment or mapping object may enable `count` entries with these values
/// (`values[k]` is the value of subindex k+1).
fn check_pdo_count(
    od: &ObjectDictionary,
    index: u16,
    count: u8,
    values: &[Vec<u8>],
) -> Result<(), u32> {
    if count as usize > values.len() {
        return Err(abort::VALUE_TOO_HIGH);
    }
    let mut bits = 0u32;
    for v in &values[..count as usize] {
        check_pdo_entry(od, index, v)?;
        bits += le_u32(v) & 0xFF;
    }
    if !is_pdo_assign(index) && bits > MAX_PDO_BITS {
        return Err(abort::PDO_TOO_LONG);
    }
    Ok(())
}

/// Values of subindices 1.. of an object, in subindex order (gaps not filled).
fn sub_values(od: &ObjectDictionary, index: u16) -> Vec<Vec<u8>> {
    od.entries_of(index)
        .into_iter()
        .filter(|e| e.subindex > 0)
        .map(|e| e.value.clone())
        .collect()
}

impl CoeServer {
    pub fn new() -> Self {
        Self::default()
    }

    /// request = mailbox data after the 6-byte mailbox header (starts with the 2-byte CoE
    /// header). Pushes zero or more CoE response payloads (each starting with the CoE header) to
    /// `out`; the ESC wraps each in a mailbox header. `max_payload` is the read mailbox size
    /// minus the mailbox header.
    pub fn handle(
        &mut self,
        request: &[u8],
        od: &mut ObjectDictionary,
        al_state: u8,
        max_payload: usize,
        out: &mut Vec<Vec<u8>>,
    ) {
        let Some(header) = facts::Header::decode(request) else {
            return;
        };
        let max_payload = max_payload.max(MIN_PAYLOAD);
        match header.service {
            service::SDO_REQUEST => {
                let reply = self.sdo_request(
                    request,
                    od,
                    al_state & ether_ros_protocol::al::STATE_MASK,
                    max_payload,
                );
                out.extend(reply);
            }
            service::SDO_INFORMATION => Self::sdo_information(request, od, max_payload, out),
            // PDOs over the mailbox and everything else are not supported: no answer.
            _ => {}
        }
    }

    /// CoE emergency payload (service 1): error code, error register, 5 data bytes.
    pub fn emergency(error_code: u16, error_register: u8, data: [u8; 5]) -> Vec<u8> {
        let mut v = Vec::with_capacity(10);
        v.extend_from_slice(&facts::header(service::EMERGENCY));
        v.extend_from_slice(&error_code.to_le_bytes());
        v.push(error_register);
        v.extend_from_slice(&data);
        v
    }

    fn sdo_request(
        &mut self,
        r: &[u8],
        od: &mut ObjectDictionary,
        al_state: u8,
        max_payload: usize,
    ) -> Option<Vec<u8>> {
        let index = u16_at(r, 3).unwrap_or(0);
        let subindex = r.get(5).copied().unwrap_or(0);
        if r.len() < 10 {
            self.transfer = Transfer::Idle;
            return Some(abort_frame(index, subindex, abort::INVALID_COMMAND));
        }
        // Initiate and segment messages keep the specifier in the same bits (5..=7).
        match facts::InitiateCommand::decode(r[2]).specifier {
            cs::DOWNLOAD_INITIATE => Some(self.download_initiate(r, od, al_state)),
            cs::SEGMENT_DOWN_REQ => Some(self.download_segment(r, od, al_state)),
            cs::UPLOAD_INITIATE => Some(self.upload_initiate(r, od, max_payload)),
            cs::UPLOAD_SEGMENT_REQ => Some(self.upload_segment(r, max_payload)),
            cs::ABORT => {
                // The master gives up: forget the transfer, no answer.
                self.transfer = Transfer::Idle;
                None
            }
            _ => {
                self.transfer = Transfer::Idle;
                Some(abort_frame(index, subindex, abort::INVALID_COMMAND))
            }
        }
    }

    fn download_initiate(&mut self, r: &[u8], od: &mut ObjectDictionary, al: u8) -> Vec<u8> {
        self.transfer = Transfer::Idle;
        // The caller checked the length: the header decodes.
        let Some(h) = facts::SdoHeader::decode(r) else {
            return abort_frame(0, 0, abort::INVALID_COMMAND);
        };
        let (index, subindex) = (h.index, h.subindex);
        let complete_access = h.command.complete_access;
        let (size, first) = if let Some(d) = h.expedited_data() {
            (d.len(), d)
        } else {
            let size = h.word() as usize;
            let data = &r[facts::SDO_HEADER_LEN..];
            (size, &data[..data.len().min(size)])
        };
        // Refuse early what can never succeed, before the master sends all the segments.
        if let Err(code) = Self::check_download(od, index, subindex, complete_access, size, al) {
            return abort_frame(index, subindex, code);
        }
        if first.len() >= size {
            if let Err(code) = Self::write(od, index, subindex, complete_access, first, al) {
                return abort_frame(index, subindex, code);
            }
        } else {
            self.transfer = Transfer::Download {
                index,
                subindex,
                complete_access,
                size,
                data: first.to_vec(),
                toggle: false,
            };
        }
        facts::SdoHeader::new(
            service::SDO_RESPONSE,
            cs::DOWNLOAD_INITIATE_RESP,
            index,
            subindex,
            complete_access,
        )
        .encode()
        .to_vec()
    }

    fn download_segment(&mut self, r: &[u8], od: &mut ObjectDictionary, al: u8) -> Vec<u8> {
        let Transfer::Download {
            index,
            subindex,
            complete_access,
            size,
            mut data,
            toggle,
        } = std::mem::take(&mut self.transfer)
        else {
            return abort_frame(0, 0, abort::INVALID_COMMAND);
        };
        // A segment of up to 7 bytes is padded to 7 and says how many bytes are unused: the
        // protocol crate's segment codec reads it (the caller checked the length).
        let Some(segment) = facts::Segment::decode(r) else {
            return abort_frame(index, subindex, abort::INVALID_COMMAND);
        };
        let this_toggle = segment.toggle;
        if this_toggle != toggle {
            return abort_frame(index, subindex, abort::TOGGLE_BIT);
        }
        data.extend_from_slice(segment.data);
        let last = segment.last;
        if data.len() > size {
            return abort_frame(index, subindex, abort::LENGTH_TOO_HIGH);
        }
        if last {
            if data.len() < size {
                return abort_frame(index, subindex, abort::LENGTH_TOO_LOW);
            }
            if let Err(code) = Self::write(od, index, subindex, complete_access, &data, al) {
                return abort_frame(index, subindex, code);
            }
        } else {
            self.transfer = Transfer::Download {
                index,
                subindex,
                complete_access,
                size,
                data,
                toggle: !toggle,
            };
        }
        facts::toggle_message(
            service::SDO_RESPONSE,
            cs::DOWNLOAD_SEGMENT_RESP,
            this_toggle,
        )
        .to_vec()
    }

    fn upload_initiate(&mut self, r: &[u8], od: &ObjectDictionary, max_payload: usize) -> Vec<u8> {
        self.transfer = Transfer::Idle;
        let Some(h) = facts::SdoHeader::decode(r) else {
            return abort_frame(0, 0, abort::INVALID_COMMAND);
        };
        let (index, subindex) = (h.index, h.subindex);
        let complete_access = h.command.complete_access;
        let data = match Self::read(od, index, subindex, complete_access) {
            Ok(d) => d,
            Err(code) => return abort_frame(index, subindex, code),
        };
        let resp = cs::UPLOAD_INITIATE_RESP;
        if let Some(h) = facts::SdoHeader::expedited(
            service::SDO_RESPONSE,
            resp,
            index,
            subindex,
            complete_access,
            &data,
        ) {
            return h.encode().to_vec();
        }
        // Normal upload: complete size, then as much data as the mailbox holds; the rest
        // follows in segments the master asks for.
        let first = data.len().min(max_payload - facts::SDO_HEADER_LEN);
        let mut v = facts::SdoHeader::normal(
            service::SDO_RESPONSE,
            resp,
            index,
            subindex,
            complete_access,
            data.len() as u32,
        )
        .encode()
        .to_vec();
        v.extend_from_slice(&data[..first]);
        if first < data.len() {
            self.transfer = Transfer::Upload {
                index,
                subindex,
                data,
                sent: first,
                toggle: false,
            };
        }
        v
    }

    fn upload_segment(&mut self, r: &[u8], max_payload: usize) -> Vec<u8> {
        let Transfer::Upload {
            index,
            subindex,
            data,
            sent,
            toggle,
        } = std::mem::take(&mut self.transfer)
        else {
            return abort_frame(0, 0, abort::INVALID_COMMAND);
        };
        let Some(request) = facts::Segment::decode(r) else {
            return abort_frame(index, subindex, abort::INVALID_COMMAND);
        };
        let this_toggle = request.toggle;
        if this_toggle != toggle {
            return abort_frame(index, subindex, abort::TOGGLE_BIT);
        }
        let n = (data.len() - sent).min(max_payload - facts::SEGMENT_HEADER_LEN);
        let last = sent + n == data.len();
        let v = facts::Segment {
            service: service::SDO_RESPONSE,
            specifier: cs::UPLOAD_SEGMENT_RESP,
            toggle: this_toggle,
            last,
            data: &data[sent..sent + n],
        }
        .encode();
        if !last {
            self.transfer = Transfer::Upload {
                index,
                subindex,
                data,
                sent: sent + n,
                toggle: !toggle,
            };
        }
        v
    }

    /// Entries a complete access starting at `subindex` covers.
    fn ca_entries(od: &ObjectDictionary, index: u16, subindex: u8) -> Result<Vec<&Entry>, u32> {
        if subindex > 1 {
            return Err(abort::UNSUPPORTED_ACCESS);
        }
        let entries = od.entries_of(index);
        let is_var = od
            .object(index)
            .map_or(entries.len() == 1 && entries[0].subindex == 0, |o| {
                o.object_code == 7
            });
        if is_var {
            return Err(abort::UNSUPPORTED_ACCESS);
        }
        Ok(entries
            .into_iter()
            .filter(|e| e.subindex >= subindex)
            .collect())
    }

    /// The bytes an upload returns.
    fn read(
        od: &ObjectDictionary,
        index: u16,
        subindex: u8,
        complete_access: bool,
    ) -> Result<Vec<u8>, u32> {
        if !object_exists(od, index) {
            return Err(abort::NO_OBJECT);
        }
        if !complete_access {
            let e = od.entry(index, subindex).ok_or(abort::NO_SUBINDEX)?;
            if e.access == Access::WriteOnly {
                return Err(abort::WRITE_ONLY);
            }
            return Ok(e.value.clone());
        }
        let mut buf = Vec::new();
        let mut pos = 0;
        for e in Self::ca_entries(od, index, subindex)? {
            // Write-only entries read as zeros inside a complete access.
            let value: &[u8] = if e.access == Access::WriteOnly {
                &[]
            } else {
                &e.value
            };
            put_bits(&mut buf, &mut pos, value, ca_bits(e));
        }
        buf.resize(pos.div_ceil(8), 0);
        Ok(buf)
    }

    /// Checks a download can do before the data arrives: target, access, state and size.
    fn check_download(
        od: &ObjectDictionary,
        index: u16,
        subindex: u8,
        complete_access: bool,
        size: usize,
        al: u8,
    ) -> Result<(), u32> {
        if !object_exists(od, index) {
            return Err(abort::NO_OBJECT);
        }
        if complete_access {
            let bits: usize = Self::ca_entries(od, index, subindex)?
                .iter()
                .map(|e| ca_bits(e))
                .sum();
            if size > bits.div_ceil(8) {
                return Err(abort::LENGTH_TOO_HIGH);
            }
        } else {
            let e = od.entry(index, subindex).ok_or(abort::NO_SUBINDEX)?;
            if e.access == Access::ReadOnly {
                return Err(abort::READ_ONLY);
            }
            if size > e.value.len() {
                return Err(abort::LENGTH_TOO_HIGH);
            }
            if size < e.value.len() && !is_string(e.data_type) {
                return Err(abort::LENGTH_TOO_LOW);
            }
        }
        if is_pdo_config(index) && al != AL_PREOP {
            return Err(abort::DEVICE_STATE);
        }
        Ok(())
    }

    /// Apply a complete download, or refuse it without changing anything.
    fn write(
        od: &mut ObjectDictionary,
        index: u16,
        subindex: u8,
        complete_access: bool,
        data: &[u8],
        al: u8,
    ) -> Result<(), u32> {
        Self::check_download(od, index, subindex, complete_access, data.len(), al)?;
        if complete_access {
            return Self::write_complete(od, index, subindex, data);
        }
        let e = od.entry(index, subindex).ok_or(abort::NO_SUBINDEX)?;
        if e.data_type == dtype::BOOL && data.first().is_some_and(|&b| b > 1) {
            return Err(abort::VALUE_RANGE);
        }
        if is_pdo_config(index) {
            if subindex == 0 {
                let count = data.first().copied().unwrap_or(0);
                check_pdo_count(od, index, count, &sub_values(od, index))?;
            } else {
                if od.get_int(index, 0) != 0 {
                    return Err(abort::SUBINDEX0_NOT_ZERO);
                }
                check_pdo_entry(od, index, data)?;
            }
        }
        od.set_bytes(index, subindex, data);
        Ok(())
    }

    fn write_complete(
        od: &mut ObjectDictionary,
        index: u16,
        subindex: u8,
        data: &[u8],
    ) -> Result<(), u32> {
        // Decode the stream into (subindex, value) while whole entries are available.
        let mut values: Vec<(u8, Vec<u8>)> = Vec::new();
        let mut pos = 0;
        let total = data.len() * 8;
        for e in Self::ca_entries(od, index, subindex)? {
            let bits = ca_bits(e);
            if pos + bits > total {
                break;
            }
            let mut v = get_bits(data, &mut pos, bits);
            v.truncate(e.value.len());
            if e.access == Access::ReadOnly && v != e.value {
                return Err(abort::READ_ONLY);
            }
            if e.data_type == dtype::BOOL && v.first().is_some_and(|&b| b > 1) {
                return Err(abort::VALUE_RANGE);
            }
            values.push((e.subindex, v));
        }
        if values.is_empty() && !data.is_empty() {
            return Err(abort::LENGTH_TOO_LOW);
        }
        // Subindex 0 holds the number of valid entries: they must all be in the data.
        let count = match values.first() {
            Some((0, v)) => v.first().copied().unwrap_or(0),
            _ => od.get_int(index, 0) as u8,
        };
        let covered = values.iter().filter(|(s, _)| *s > 0).count();
        let max_sub = od
            .entries_of(index)
            .iter()
            .filter(|e| e.subindex > 0)
            .count();
        if subindex == 0 && (count as usize) > covered && (count as usize) <= max_sub {
            return Err(abort::LENGTH_TOO_LOW);
        }
        if is_pdo_config(index) {
            let mut subs = sub_values(od, index);
            for (s, v) in &values {
                if *s > 0 {
                    if let Some(slot) = subs.get_mut(*s as usize - 1) {
                        *slot = v.clone();
                    }
                }
            }
            check_pdo_count(od, index, count, &subs)?;
        } else if subindex == 0 && count as usize > max_sub {
            return Err(abort::VALUE_TOO_HIGH);
        }
        for (s, v) in values {
            od.set_bytes(index, s, &v);
        }
        Ok(())
    }

    // ---- SDO Information -------------------------------------------------------------------

    fn sdo_information(
        r: &[u8],
        od: &ObjectDictionary,
        max_payload: usize,
        out: &mut Vec<Vec<u8>>,
    ) {
        let Some(&opcode) = r.get(2) else {
            return;
        };
        let body = &r[r.len().min(6)..];
        let result = match opcode & info::OPCODE_MASK {
            info::OD_LIST_REQ => Self::od_list(body, od).map(|b| (info::OD_LIST_RESP, b)),
            info::OBJECT_DESC_REQ => {
                Self::object_description(body, od).map(|b| (info::OBJECT_DESC_RESP, b))
            }
            info::ENTRY_DESC_REQ => {
                Self::entry_description(body, od).map(|b| (info::ENTRY_DESC_RESP, b))
            }
            _ => Err(abort::INVALID_COMMAND),
        };
        match result {
            Ok((opcode, body)) => Self::fragments(opcode, &body, max_payload, out),
            Err(code) => {
                let mut v = Vec::with_capacity(10);
                v.extend_from_slice(&facts::header(service::SDO_INFORMATION));
                v.extend_from_slice(&[info::ERROR, 0, 0, 0]);
                v.extend_from_slice(&code.to_le_bytes());
                out.push(v);
            }
        }
    }

    /// Split an SDO Information response over as many mailbox messages as it needs. Every
    /// fragment but the last has the "incomplete" bit; "fragments left" counts down to 0.
    fn fragments(opcode: u8, body: &[u8], max_payload: usize, out: &mut Vec<Vec<u8>>) {
        // Keep fragments an even length so an object list never splits an index.
        let room = ((max_payload - 6) & !1).max(2);
        let count = body.len().div_ceil(room).max(1);
        for k in 0..count {
            let chunk = &body[(k * room).min(body.len())..((k + 1) * room).min(body.len())];
            let left = (count - 1 - k) as u16;
            let mut v = Vec::with_capacity(6 + chunk.len());
            v.extend_from_slice(&facts::header(service::SDO_INFORMATION));
            v.push(opcode | if left > 0 { info::INCOMPLETE } else { 0 });
            v.push(0);
            v.extend_from_slice(&left.to_le_bytes());
            v.extend_from_slice(chunk);
            out.push(v);
        }
    }

    fn is_rx_mappable(e: &Entry) -> bool {
        e.pdo_mappable && e.access != Access::ReadOnly
    }

    fn is_tx_mappable(e: &Entry) -> bool {
        e.pdo_mappable && e.access != Access::WriteOnly
    }

    fn od_list(body: &[u8], od: &ObjectDictionary) -> Result<Vec<u8>, u32> {
        let list_type = u16_at(body, 0).ok_or(abort::INVALID_COMMAND)?;
        let mut indices: Vec<u16> = od.objects().map(|o| o.index).collect();
        for e in od.entries() {
            indices.push(e.index);
        }
        indices.sort_unstable();
        indices.dedup();
        let with_entry = |pred: fn(&Entry) -> bool| -> Vec<u16> {
            indices
                .iter()
                .copied()
                .filter(|&i| od.entries_of(i).into_iter().any(pred))
                .collect()
        };
        let mut v = list_type.to_le_bytes().to_vec();
        match list_type {
            0 => {
                let counts = [
                    indices.len(),
                    with_entry(Self::is_rx_mappable).len(),
                    with_entry(Self::is_tx_mappable).len(),
                    0,
                    0,
                ];
                for c in counts {
                    v.extend_from_slice(&(c as u16).to_le_bytes());
                }
            }
            1..=3 => {
                let list = match list_type {
                    1 => indices,
                    2 => with_entry(Self::is_rx_mappable),
                    _ => with_entry(Self::is_tx_mappable),
                };
                for i in list {
                    v.extend_from_slice(&i.to_le_bytes());
                }
            }
            // Backup and settings lists: the simulator marks no object for either.
            4 | 5 => {}
            _ => return Err(abort::UNSUPPORTED_ACCESS),
        }
        Ok(v)
    }

    fn object_description(body: &[u8], od: &ObjectDictionary) -> Result<Vec<u8>, u32> {
        let index = u16_at(body, 0).ok_or(abort::INVALID_COMMAND)?;
        if !object_exists(od, index) {
            return Err(abort::NO_OBJECT);
        }
        let entries = od.entries_of(index);
        let max_sub = entries.iter().map(|e| e.subindex).max().unwrap_or(0);
        let (name, code) = match od.object(index) {
            Some(o) => (o.name.clone(), o.object_code),
            None if max_sub == 0 => (entries.first().map_or(String::new(), |e| e.name.clone()), 7),
            None => (String::new(), 9),
        };
        // The data type of a VAR is its own; of an ARRAY or RECORD, that of its first element.
        let data_type = entries
            .iter()
            .find(|e| e.subindex == 1)
            .or(entries.first())
            .map_or(0, |e| e.data_type);
        let mut v = Vec::with_capacity(6 + name.len());
        v.extend_from_slice(&index.to_le_bytes());
        v.extend_from_slice(&data_type.to_le_bytes());
        v.push(max_sub);
        v.push(code);
        v.extend_from_slice(name.as_bytes());
        Ok(v)
    }

    fn entry_description(body: &[u8], od: &ObjectDictionary) -> Result<Vec<u8>, u32> {
        let index = u16_at(body, 0).ok_or(abort::INVALID_COMMAND)?;
        let subindex = *body.get(2).ok_or(abort::INVALID_COMMAND)?;
        if !object_exists(od, index) {
            return Err(abort::NO_OBJECT);
        }
        let e = od.entry(index, subindex).ok_or(abort::NO_SUBINDEX)?;
        // Object access bits (the protocol crate's): read and write per state, mappable.
        let mut access: u16 = 0;
        if e.access != Access::WriteOnly {
            access |= facts::ACCESS_READ;
        }
        if e.access != Access::ReadOnly {
            // PDO configuration objects are writable in PREOP only (bit 3).
            let preop_only = facts::ACCESS_WRITE & !(facts::ACCESS_WRITE << 1);
            access |= if is_pdo_config(index) {
                preop_only
            } else {
                facts::ACCESS_WRITE
            };
        }
        if Self::is_rx_mappable(e) {
            access |= facts::ACCESS_RXPDO;
        }
        if Self::is_tx_mappable(e) {
            access |= facts::ACCESS_TXPDO;
        }
        let mut v = Vec::with_capacity(10 + e.name.len());
        v.extend_from_slice(&index.to_le_bytes());
        v.push(subindex);
        // Value info: the simulator sends no unit, default, minimum or maximum.
        v.push(0);
        v.extend_from_slice(&e.data_type.to_le_bytes());
        v.extend_from_slice(&e.bit_length.to_le_bytes());
        v.extend_from_slice(&access.to_le_bytes());
        v.extend_from_slice(e.name.as_bytes());
        Ok(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::od::Object;

    const PREOP: u8 = 2;
    const OP: u8 = 8;
    const MBX: usize = 128 - 6;

    fn entry(index: u16, sub: u8, t: u16, bits: u16, access: Access, map: bool, v: u64) -> Entry {
        Entry {
            index,
            subindex: sub,
            name: format!("Entry {index:04X}:{sub}"),
            data_type: t,
            bit_length: bits,
            access,
            pdo_mappable: map,
            value: v.to_le_bytes().to_vec(),
        }
    }

    fn object(od: &mut ObjectDictionary, index: u16, code: u8, name: &str) {
        od.add_object(Object {
            index,
            name: name.into(),
            object_code: code,
        });
    }

    /// A small dictionary covering every access path the server implements.
    fn dictionary() -> ObjectDictionary {
        use Access::*;
        let mut od = ObjectDictionary::new();
        object(&mut od, 0x1000, 7, "Device type");
        od.add_entry(entry(0x1000, 0, dtype::UINT32, 32, ReadOnly, false, 0x1389));
        object(&mut od, 0x1008, 7, "Device name");
        let mut name = entry(
            0x1008,
            0,
            dtype::VISIBLE_STRING,
            8 * 300,
            ReadOnly,
            false,
            0,
        );
        name.value = (0..300u32).map(|i| b'a' + (i % 26) as u8).collect();
        od.add_entry(name);
        object(&mut od, 0x2000, 7, "Gain");
        od.add_entry(entry(0x2000, 0, dtype::UINT16, 16, ReadWrite, false, 7));
        object(&mut od, 0x2001, 7, "Enable");
        od.add_entry(entry(0x2001, 0, dtype::BOOL, 1, ReadWrite, false, 0));
        object(&mut od, 0x2002, 7, "Password");
        od.add_entry(entry(0x2002, 0, dtype::UINT32, 32, WriteOnly, false, 0));
        object(&mut od, 0x2003, 7, "Blob");
        od.add_entry(entry(
            0x2003,
            0,
            dtype::OCTET_STRING,
            8 * 200,
            ReadWrite,
            false,
            0,
        ));
        // Process data objects.
        object(&mut od, 0x6000, 9, "Inputs");
        od.add_entry(entry(0x6000, 0, dtype::UINT8, 8, ReadOnly, false, 2));
        od.add_entry(entry(
            0x6000,
            1,
            dtype::INT32,
            32,
            ReadOnly,
            true,
            0x1122_3344,
        ));
        od.add_entry(entry(0x6000, 2, dtype::UINT16, 16, ReadOnly, true, 0x5566));
        object(&mut od, 0x7000, 9, "Outputs");
        od.add_entry(entry(0x7000, 0, dtype::UINT8, 8, ReadOnly, false, 2));
        od.add_entry(entry(0x7000, 1, dtype::INT16, 16, ReadWrite, true, 0));
        od.add_entry(entry(0x7000, 2, dtype::BOOL, 1, ReadWrite, true, 0));
        // PDO mapping and assignment.
        for (index, first) in [(0x1600u16, 0x7000_0110u64), (0x1A00, 0x6000_0120)] {
            object(&mut od, index, 9, "PDO mapping");
            od.add_entry(entry(index, 0, dtype::UINT8, 8, ReadWrite, false, 1));
            od.add_entry(entry(index, 1, dtype::UINT32, 32, ReadWrite, false, first));
            for sub in 2..=4 {
                od.add_entry(entry(index, sub, dtype::UINT32, 32, ReadWrite, false, 0));
            }
        }
        object(&mut od, 0x1601, 9, "PDO mapping");
        od.add_entry(entry(0x1601, 0, dtype::UINT8, 8, ReadWrite, false, 0));
        od.add_entry(entry(0x1601, 1, dtype::UINT32, 32, ReadWrite, false, 0));
        for (index, pdo) in [(0x1C12u16, 0x1600u64), (0x1C13, 0x1A00)] {
            object(&mut od, index, 8, "PDO assignment");
            od.add_entry(entry(index, 0, dtype::UINT8, 8, ReadWrite, false, 1));
            od.add_entry(entry(index, 1, dtype::UINT16, 16, ReadWrite, false, pdo));
            od.add_entry(entry(index, 2, dtype::UINT16, 16, ReadWrite, false, 0));
        }
        od
    }

    fn run(s: &mut CoeServer, od: &mut ObjectDictionary, req: &[u8], al: u8) -> Vec<Vec<u8>> {
        let mut out = Vec::new();
        s.handle(req, od, al, MBX, &mut out);
        out
    }

    fn one(s: &mut CoeServer, od: &mut ObjectDictionary, req: &[u8], al: u8) -> Vec<u8> {
        let out = run(s, od, req, al);
        assert_eq!(out.len(), 1, "expected one reply, got {out:?}");
        out.into_iter().next().unwrap()
    }

    fn req(command: u8, index: u16, sub: u8, data: &[u8]) -> Vec<u8> {
        let mut d = [0u8; 4];
        d[..data.len().min(4)].copy_from_slice(&data[..data.len().min(4)]);
        // Raw bytes on purpose: the tests state the wire image, not the codec's view of it.
        let mut v = facts::header(service::SDO_REQUEST).to_vec();
        v.push(command);
        v.extend_from_slice(&index.to_le_bytes());
        v.push(sub);
        v.extend_from_slice(&d);
        if data.len() > 4 {
            v.extend_from_slice(&data[4..]);
        }
        v
    }

    fn expedited_download(index: u16, sub: u8, data: &[u8]) -> Vec<u8> {
        req(0x23 | ((4 - data.len() as u8) << 2), index, sub, data)
    }

    fn abort_code(reply: &[u8]) -> Option<u32> {
        (reply[2] == 0x80).then(|| u32_at(reply, 6).unwrap())
    }

    /// Upload through the public interface like a master would (segments included).
    fn upload(
        s: &mut CoeServer,
        od: &mut ObjectDictionary,
        index: u16,
        sub: u8,
        ca: bool,
    ) -> Result<Vec<u8>, u32> {
        let r = one(
            s,
            od,
            &req(0x40 | if ca { 0x10 } else { 0 }, index, sub, &[]),
            PREOP,
        );
        if let Some(code) = abort_code(&r) {
            return Err(code);
        }
        assert_eq!(r[2] >> 5, 2);
        if r[2] & 0x02 != 0 {
            let n = 4 - ((r[2] >> 2) & 3) as usize;
            return Ok(r[6..6 + n].to_vec());
        }
        let size = u32_at(&r, 6).unwrap() as usize;
        let mut data = r[10..].to_vec();
        let mut toggle = 0u8;
        while data.len() < size {
            let seg = one(s, od, &req(0x60 | toggle, 0, 0, &[]), PREOP);
            if let Some(code) = abort_code(&seg) {
                return Err(code);
            }
            assert_eq!(seg[2] & 0x10, toggle, "toggle echoed");
            let n = if seg.len() - 3 > 7 {
                seg.len() - 3
            } else {
                7 - ((seg[2] >> 1) & 7) as usize
            };
            data.extend_from_slice(&seg[3..3 + n]);
            assert_eq!(seg[2] & 1 == 1, data.len() == size, "last-segment flag");
            toggle ^= 0x10;
        }
        assert_eq!(data.len(), size);
        Ok(data)
    }

    #[test]
    fn expedited_upload_and_download() {
        let (mut s, mut od) = (CoeServer::new(), dictionary());
        assert_eq!(
            upload(&mut s, &mut od, 0x1000, 0, false),
            Ok(0x1389u32.to_le_bytes().to_vec())
        );
        let r = one(
            &mut s,
            &mut od,
            &expedited_download(0x2000, 0, &[0x34, 0x12]),
            OP,
        );
        assert_eq!(r[..6], [0x00, 0x30, 0x60, 0x00, 0x20, 0x00]);
        assert_eq!(od.get_int(0x2000, 0), 0x1234);
        assert_eq!(
            upload(&mut s, &mut od, 0x2000, 0, false),
            Ok(vec![0x34, 0x12])
        );
    }

    #[test]
    fn segmented_upload_splits_by_mailbox_size_and_checks_toggle() {
        let (mut s, mut od) = (CoeServer::new(), dictionary());
        let data = upload(&mut s, &mut od, 0x1008, 0, false).unwrap();
        assert_eq!(data, od.get_bytes(0x1008, 0).unwrap());
        // A repeated toggle is refused and ends the transfer.
        one(&mut s, &mut od, &req(0x40, 0x1008, 0, &[]), PREOP);
        one(&mut s, &mut od, &req(0x60, 0, 0, &[]), PREOP);
        let r = one(&mut s, &mut od, &req(0x60, 0, 0, &[]), PREOP);
        assert_eq!(abort_code(&r), Some(abort::TOGGLE_BIT));
        assert_eq!(r[3..6], [0x08, 0x10, 0x00]);
        let r = one(&mut s, &mut od, &req(0x70, 0, 0, &[]), PREOP);
        assert_eq!(abort_code(&r), Some(abort::INVALID_COMMAND));
    }

    #[test]
    fn normal_upload_fits_in_one_mailbox_when_large_enough() {
        let (mut s, mut od) = (CoeServer::new(), dictionary());
        let mut out = Vec::new();
        s.handle(&req(0x40, 0x1008, 0, &[]), &mut od, PREOP, 1024, &mut out);
        assert_eq!(out.len(), 1);
        assert_eq!(out[0][2], 0x41);
        assert_eq!(u32_at(&out[0], 6), Some(300));
        assert_eq!(&out[0][10..], od.get_bytes(0x1008, 0).unwrap());
    }

    #[test]
    fn normal_and_segmented_download() {
        let (mut s, mut od) = (CoeServer::new(), dictionary());
        let blob: Vec<u8> = (0..200u32).map(|i| (i * 7) as u8).collect();
        // Normal download with everything in the first message.
        let mut r = req(0x21, 0x2003, 0, &200u32.to_le_bytes());
        r.extend_from_slice(&blob);
        assert_eq!(one(&mut s, &mut od, &r, PREOP)[2], 0x60);
        assert_eq!(od.get_bytes(0x2003, 0).unwrap(), &blob[..]);
        // Segmented: 20 bytes in the initiate, then segments of 50, 50, 50 and 30 bytes.
        let reversed: Vec<u8> = blob.iter().rev().copied().collect();
        let mut r = req(0x21, 0x2003, 0, &200u32.to_le_bytes());
        r.extend_from_slice(&reversed[..20]);
        assert_eq!(one(&mut s, &mut od, &r, PREOP)[2], 0x60);
        let mut toggle = 0u8;
        for (k, chunk) in reversed[20..].chunks(50).enumerate() {
            let last = u8::from(k == 3);
            let mut seg = vec![0x00, 0x20, toggle | last];
            seg.extend_from_slice(chunk);
            let resp = one(&mut s, &mut od, &seg, PREOP);
            assert_eq!(resp[2], 0x20 | toggle);
            assert_eq!(resp.len(), 10);
            toggle ^= 0x10;
        }
        assert_eq!(od.get_bytes(0x2003, 0).unwrap(), &reversed[..]);
        // Short segments use the "unused bytes" field of a 7-byte segment.
        let mut r = req(0x21, 0x2003, 0, &5u32.to_le_bytes());
        r.truncate(10);
        one(&mut s, &mut od, &r, PREOP);
        let seg = [0x00, 0x20, 0x01 | (2 << 1), 1, 2, 3, 4, 5, 0, 0];
        assert_eq!(one(&mut s, &mut od, &seg, PREOP)[2], 0x20);
        assert_eq!(&od.get_bytes(0x2003, 0).unwrap()[..6], &[1, 2, 3, 4, 5, 0]);
    }

    #[test]
    fn segmented_download_refuses_wrong_toggle_and_lengths() {
        let (mut s, mut od) = (CoeServer::new(), dictionary());
        let mut r = req(0x21, 0x2003, 0, &20u32.to_le_bytes());
        r.truncate(10);
        one(&mut s, &mut od, &r, PREOP);
        let seg = [0x00, 0x20, 0x10, 1, 2, 3, 4, 5, 6, 7];
        assert_eq!(
            abort_code(&one(&mut s, &mut od, &seg, PREOP)),
            Some(abort::TOGGLE_BIT)
        );
        // Segment without a transfer.
        assert_eq!(
            abort_code(&one(&mut s, &mut od, &seg, PREOP)),
            Some(abort::INVALID_COMMAND)
        );
        // Last segment too early / too much data.
        one(&mut s, &mut od, &r, PREOP);
        let seg = [0x00, 0x20, 0x01, 1, 2, 3, 4, 5, 6, 7];
        assert_eq!(
            abort_code(&one(&mut s, &mut od, &seg, PREOP)),
            Some(abort::LENGTH_TOO_LOW)
        );
        one(&mut s, &mut od, &r, PREOP);
        let mut seg = vec![0x00, 0x20, 0x00];
        seg.extend_from_slice(&[9; 21]);
        assert_eq!(
            abort_code(&one(&mut s, &mut od, &seg, PREOP)),
            Some(abort::LENGTH_TOO_HIGH)
        );
        // Announcing more than the entry holds is refused at once.
        let r = req(0x21, 0x2003, 0, &201u32.to_le_bytes());
        assert_eq!(
            abort_code(&one(&mut s, &mut od, &r, PREOP)),
            Some(abort::LENGTH_TOO_HIGH)
        );
        // A master abort ends the transfer silently.
        let r2 = req(0x21, 0x2003, 0, &20u32.to_le_bytes());
        one(&mut s, &mut od, &r2, PREOP);
        assert!(run(&mut s, &mut od, &req(0x80, 0x2003, 0, &[0, 0, 0, 5]), PREOP).is_empty());
        let seg = [0x00, 0x20, 0x00, 1, 2, 3, 4, 5, 6, 7];
        assert_eq!(
            abort_code(&one(&mut s, &mut od, &seg, PREOP)),
            Some(abort::INVALID_COMMAND)
        );
    }

    #[test]
    fn abort_codes_for_access_errors() {
        let (mut s, mut od) = (CoeServer::new(), dictionary());
        let cases: Vec<(Vec<u8>, u32)> = vec![
            (req(0x40, 0x5555, 0, &[]), abort::NO_OBJECT),
            (req(0x40, 0x6000, 9, &[]), abort::NO_SUBINDEX),
            (req(0x40, 0x2002, 0, &[]), abort::WRITE_ONLY),
            (
                expedited_download(0x1000, 0, &[1, 2, 3, 4]),
                abort::READ_ONLY,
            ),
            (
                expedited_download(0x2000, 0, &[1, 2, 3]),
                abort::LENGTH_TOO_HIGH,
            ),
            (expedited_download(0x2000, 0, &[1]), abort::LENGTH_TOO_LOW),
            (expedited_download(0x2001, 0, &[2]), abort::VALUE_RANGE),
            (req(0xE0, 0x2000, 0, &[]), abort::INVALID_COMMAND),
            (req(0x50, 0x1000, 0, &[]), abort::UNSUPPORTED_ACCESS),
            (req(0x50, 0x6000, 2, &[]), abort::UNSUPPORTED_ACCESS),
            (expedited_download(0x1C12, 0, &[0]), abort::DEVICE_STATE),
            (expedited_download(0x1600, 0, &[0]), abort::DEVICE_STATE),
        ];
        for (r, code) in cases {
            let reply = one(&mut s, &mut od, &r, OP);
            assert_eq!(abort_code(&reply), Some(code), "request {r:02x?}");
            // Index and subindex echo the request.
            assert_eq!(reply[3..6], r[3..6]);
            assert_eq!(reply[1] >> 4, 2, "aborts use the SDO request service");
        }
        assert_eq!(od.get_int(0x2000, 0), 7, "nothing was written");
        // Writing the write-only entry works.
        let r = one(
            &mut s,
            &mut od,
            &expedited_download(0x2002, 0, &[1, 2, 3, 4]),
            OP,
        );
        assert_eq!(r[2], 0x60);
    }

    #[test]
    fn malformed_requests_never_panic() {
        let (mut s, mut od) = (CoeServer::new(), dictionary());
        let mut out = Vec::new();
        for len in 0..16 {
            for fill in [0x00u8, 0xFF, 0x21, 0x41, 0x60, 0x81] {
                for svc in [0u8, 0x10, 0x20, 0x30, 0x80, 0xF0] {
                    let mut r = vec![fill; len];
                    if len > 1 {
                        r[1] = svc;
                    }
                    s.handle(&r, &mut od, OP, 0, &mut out);
                    s.handle(&r, &mut od, PREOP, MBX, &mut out);
                }
            }
        }
        // A short SDO request is answered with an abort.
        out.clear();
        s.handle(&[0x00, 0x20, 0x40, 0x00], &mut od, OP, MBX, &mut out);
        assert_eq!(abort_code(&out[0]), Some(abort::INVALID_COMMAND));
    }

    #[test]
    fn complete_access_upload_packs_subindex0_as_16_bits_and_bits() {
        let (mut s, mut od) = (CoeServer::new(), dictionary());
        let data = upload(&mut s, &mut od, 0x6000, 0, true).unwrap();
        assert_eq!(data, [2, 0, 0x44, 0x33, 0x22, 0x11, 0x66, 0x55]);
        let data = upload(&mut s, &mut od, 0x6000, 1, true).unwrap();
        assert_eq!(data, [0x44, 0x33, 0x22, 0x11, 0x66, 0x55]);
        od.set_int(0x7000, 1, -2);
        od.set_int(0x7000, 2, 1);
        // sub0 (16) + INT16 (16) + BOOL (1 bit) = 33 bits -> 5 bytes.
        let data = upload(&mut s, &mut od, 0x7000, 0, true).unwrap();
        assert_eq!(data, [2, 0, 0xFE, 0xFF, 0x01]);
    }

    #[test]
    fn complete_access_download_writes_all_entries() {
        let (mut s, mut od) = (CoeServer::new(), dictionary());
        // Read-only sub0 unchanged is accepted; the values land bit-exactly.
        let mut r = req(0x31, 0x7000, 0, &5u32.to_le_bytes());
        r.extend_from_slice(&[2, 0, 0x05, 0x00, 0x01]);
        let reply = one(&mut s, &mut od, &r, OP);
        assert_eq!(
            reply[2], 0x70,
            "download response with the complete-access bit"
        );
        assert_eq!(od.get_int(0x7000, 1), 5);
        assert_eq!(od.get_int(0x7000, 2), 1);
        // Changing a read-only sub0 is refused.
        let mut r = req(0x31, 0x7000, 0, &5u32.to_le_bytes());
        r.extend_from_slice(&[1, 0, 0x06, 0x00, 0x00]);
        assert_eq!(
            abort_code(&one(&mut s, &mut od, &r, OP)),
            Some(abort::READ_ONLY)
        );
        let mut r = req(0x31, 0x7000, 0, &6u32.to_le_bytes());
        r.extend_from_slice(&[2, 0, 0x06, 0x00, 0x00, 0]);
        assert_eq!(
            abort_code(&one(&mut s, &mut od, &r, OP)),
            Some(abort::LENGTH_TOO_HIGH)
        );
        assert_eq!(od.get_int(0x7000, 1), 5);
    }

    #[test]
    fn pdo_assignment_rules() {
        let (mut s, mut od) = (CoeServer::new(), dictionary());
        // Entries may only change while sub0 is 0.
        let r = expedited_download(0x1C12, 1, &[0x01, 0x16]);
        assert_eq!(
            abort_code(&one(&mut s, &mut od, &r, PREOP)),
            Some(abort::SUBINDEX0_NOT_ZERO)
        );
        assert_eq!(
            one(&mut s, &mut od, &expedited_download(0x1C12, 0, &[0]), PREOP)[2],
            0x60
        );
        // A TxPDO in the RxPDO assignment, or a PDO that does not exist, is out of range.
        for bad in [0x1A00u16, 0x1605] {
            let r = expedited_download(0x1C12, 1, &bad.to_le_bytes());
            assert_eq!(
                abort_code(&one(&mut s, &mut od, &r, PREOP)),
                Some(abort::VALUE_RANGE)
            );
        }
        let r = expedited_download(0x1C12, 1, &0x1601u16.to_le_bytes());
        assert_eq!(one(&mut s, &mut od, &r, PREOP)[2], 0x60);
        let r = expedited_download(0x1C12, 0, &[3]);
        assert_eq!(
            abort_code(&one(&mut s, &mut od, &r, PREOP)),
            Some(abort::VALUE_TOO_HIGH)
        );
        // Sub 2 still holds 0, which is not a PDO.
        let r = expedited_download(0x1C12, 0, &[2]);
        assert_eq!(
            abort_code(&one(&mut s, &mut od, &r, PREOP)),
            Some(abort::VALUE_RANGE)
        );
        assert_eq!(
            one(&mut s, &mut od, &expedited_download(0x1C12, 0, &[1]), PREOP)[2],
            0x60
        );
        assert_eq!(od.get_int(0x1C12, 1), 0x1601);
        // Complete access writes count and entries in one go; only in PREOP.
        let mut r = req(0x31, 0x1C12, 0, &6u32.to_le_bytes());
        r.extend_from_slice(&[2, 0, 0x00, 0x16, 0x01, 0x16]);
        assert_eq!(
            abort_code(&one(&mut s, &mut od, &r, 4)),
            Some(abort::DEVICE_STATE)
        );
        assert_eq!(one(&mut s, &mut od, &r, PREOP)[2], 0x70);
        assert_eq!(
            (
                od.get_int(0x1C12, 0),
                od.get_int(0x1C12, 1),
                od.get_int(0x1C12, 2)
            ),
            (2, 0x1600, 0x1601)
        );
        // The error flag of the AL status does not change the state.
        let r = expedited_download(0x1C12, 0, &[0]);
        assert_eq!(one(&mut s, &mut od, &r, PREOP | 0x10)[2], 0x60);
        // A count whose entries are not all in the data is refused.
        let mut r = req(0x31, 0x1C12, 0, &4u32.to_le_bytes());
        r.extend_from_slice(&[2, 0, 0x00, 0x16]);
        assert_eq!(
            abort_code(&one(&mut s, &mut od, &r, PREOP)),
            Some(abort::LENGTH_TOO_LOW)
        );
    }

    #[test]
    fn pdo_mapping_rules() {
        let (mut s, mut od) = (CoeServer::new(), dictionary());
        let write = |s: &mut CoeServer, od: &mut ObjectDictionary, sub: u8, v: u32| {
            let r = expedited_download(0x1600, sub, &v.to_le_bytes());
            let r = if sub == 0 {
                expedited_download(0x1600, 0, &[v as u8])
            } else {
                r
            };
            abort_code(&one(s, od, &r, PREOP))
        };
        assert_eq!(
            write(&mut s, &mut od, 2, 0x7000_0201),
            Some(abort::SUBINDEX0_NOT_ZERO)
        );
        assert_eq!(write(&mut s, &mut od, 0, 0), None);
        assert_eq!(write(&mut s, &mut od, 2, 0x7000_0201), None);
        // Wrong length, not mappable, missing, input object in an RxPDO, zero length.
        for bad in [
            0x7000_0108u32,
            0x2000_0010,
            0x7000_0310,
            0x6000_0120,
            0x7000_0100,
        ] {
            assert_eq!(
                write(&mut s, &mut od, 3, bad),
                Some(abort::CANNOT_MAP),
                "{bad:08x}"
            );
        }
        // Padding (index 0) of any length.
        assert_eq!(write(&mut s, &mut od, 3, 0x0000_0007), None);
        assert_eq!(write(&mut s, &mut od, 0, 3), None);
        assert_eq!(od.get_int(0x1600, 0), 3);
        assert_eq!(write(&mut s, &mut od, 0, 5), Some(abort::VALUE_TOO_HIGH));
        // TxPDO mapping takes readable objects.
        let r = expedited_download(0x1A00, 0, &[0]);
        one(&mut s, &mut od, &r, PREOP);
        let r = expedited_download(0x1A00, 2, &0x6000_0210u32.to_le_bytes());
        assert_eq!(one(&mut s, &mut od, &r, PREOP)[2], 0x60);
        // In SAFEOP nothing changes.
        let r = expedited_download(0x1A00, 0, &[2]);
        assert_eq!(
            abort_code(&one(&mut s, &mut od, &r, 4)),
            Some(abort::DEVICE_STATE)
        );
    }

    fn info_req(opcode: u8, body: &[u8]) -> Vec<u8> {
        let mut v = facts::header(service::SDO_INFORMATION).to_vec();
        v.extend_from_slice(&[opcode, 0, 0, 0]);
        v.extend_from_slice(body);
        v
    }

    #[test]
    fn sdo_information_object_list_is_fragmented() {
        let (mut s, mut od) = (CoeServer::new(), dictionary());
        for i in 0..100u16 {
            od.add_entry(entry(
                0x3000 + i,
                0,
                dtype::UINT8,
                8,
                Access::ReadWrite,
                false,
                0,
            ));
        }
        let out = run(&mut s, &mut od, &info_req(1, &1u16.to_le_bytes()), PREOP);
        assert!(out.len() > 1);
        let mut body = Vec::new();
        for (k, frag) in out.iter().enumerate() {
            assert!(frag.len() <= MBX);
            assert_eq!(frag[1] >> 4, 8);
            let left = (out.len() - 1 - k) as u16;
            assert_eq!(frag[2], 2 | if left > 0 { 0x80 } else { 0 });
            assert_eq!(u16_at(frag, 4), Some(left));
            body.extend_from_slice(&frag[6..]);
        }
        assert_eq!(u16_at(&body, 0), Some(1));
        let list: Vec<u16> = body[2..]
            .chunks(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect();
        assert_eq!(list.len(), 113);
        assert!(list.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(list[0], 0x1000);
        // List lengths (type 0): all, RxPDO-mappable, TxPDO-mappable, backup, settings.
        let out = run(&mut s, &mut od, &info_req(1, &0u16.to_le_bytes()), PREOP);
        assert_eq!(out[0][6..], [0, 0, 113, 0, 1, 0, 2, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn sdo_information_descriptions_and_errors() {
        let (mut s, mut od) = (CoeServer::new(), dictionary());
        let out = one(
            &mut s,
            &mut od,
            &info_req(3, &0x6000u16.to_le_bytes()),
            PREOP,
        );
        assert_eq!(out[2], 4);
        assert_eq!(out[6..12], [0x00, 0x60, 0x04, 0x00, 2, 9]);
        assert_eq!(&out[12..], b"Inputs");
        let out = one(
            &mut s,
            &mut od,
            &info_req(5, &[0x00, 0x70, 0x01, 0x00]),
            PREOP,
        );
        assert_eq!(out[2], 6);
        assert_eq!(
            out[6..16],
            [0x00, 0x70, 1, 0, 0x03, 0x00, 16, 0, 0xFF, 0x00]
        );
        assert_eq!(&out[16..], b"Entry 7000:1");
        for (r, code) in [
            (info_req(3, &0x5555u16.to_le_bytes()), abort::NO_OBJECT),
            (info_req(5, &[0x00, 0x70, 0x09, 0]), abort::NO_SUBINDEX),
            (info_req(9, &[]), abort::INVALID_COMMAND),
            (info_req(5, &[0x00]), abort::INVALID_COMMAND),
        ] {
            let out = one(&mut s, &mut od, &r, PREOP);
            assert_eq!(out[2], 7);
            assert_eq!(u32_at(&out, 6), Some(code));
        }
    }

    #[test]
    fn emergency_layout() {
        let e = CoeServer::emergency(0x8611, 0x81, [1, 2, 3, 4, 5]);
        assert_eq!(e, [0x00, 0x10, 0x11, 0x86, 0x81, 1, 2, 3, 4, 5]);
    }
}
