//! SoE (Servo drive profile over EtherCAT, ETG.1000.6) server of a virtual slave whose SII
//! announces SoE (word 0x1C bit 4): reads and writes of the IDNs of each drive the slave has.
//!
//! What the drives hold:
//! - the device's IDN dictionary (`SlaveSpec::idns`, built from the ESI's dictionary file),
//!   the same for every drive;
//! - S-0-0024 (MDT configuration list) and S-0-0016 (AT configuration list) of each drive,
//!   built from the SII's RxPDOs and TxPDOs: the PDO index names the drive in bits 12..=14
//!   (Beckhoff's AX5000: MDT 0x0018 is drive 0's, 0x1018 drive 1's), the entries are IDNs in
//!   the order they are mapped, without the control and status words (S-0-0134/0135, always
//!   first in the telegram and never in the lists). A master sizes the process data from
//!   these lists and the attributes of the IDNs in them (SOEM's `ecx_readIDNmap`);
//! - every IDN a PDO maps that the dictionary lacks (145 of Beckhoff's 147 drive ESIs name a
//!   dictionary file the corpus does not have), its attribute from the PDO entry's bit length.
//!
//! The drives are those the PDOs name (drive 0 at least). A drive number beyond them answers
//! its two configuration lists empty (no cyclic data: a master looping over the eight drive
//! numbers, as SOEM does, sizes nothing for it) and every other IDN with "invalid drive
//! number" (0x800A). Elements served: name, attribute, value and default (the value the
//! slave started with); unit, minimum, maximum and data state answer their "not existing"
//! errors. Writes of the value are stored; a configuration list takes only the list it
//! already holds (the simulated drive maps what its ESI maps), any other is refused as
//! write-protected (0x7005), as its attribute says. A read response longer than the mailbox
//! is sent in fragments (Incomplete set, bytes 2..=3 the fragments left); a fragmented write
//! is collected until its last fragment, which carries the IDN.
//!
//! Nothing a master sends can make this code panic; a message too short for the SoE header
//! or of an opcode the server does not take is the caller's mailbox error.

use std::collections::BTreeMap;

use ether_ros_protocol::al;
use ether_ros_protocol::sii::category::{RXPDO as SII_RXPDO, TXPDO as SII_TXPDO};
use ether_ros_protocol::soe::{self as facts, Header};

/// One IDN of the device's dictionary, as the slave spec carries it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct IdnSpec {
    /// The IDN (bit 15 P, bits 12..=14 parameter set, bits 0..=11 number).
    pub idn: u16,
    /// The IDN's name, as the SoE Information service returns it.
    pub name: String,
    /// The attribute element (`ether_ros_protocol::soe::attribute`).
    pub attribute: u32,
    /// Start value of the operation data, little endian; for a list IDN the whole element
    /// (current length, maximum length, items). Shorter than a fixed-length IDN's data: the
    /// rest is zero.
    pub value: Vec<u8>,
}

impl IdnSpec {
    /// An IDN of the ESI's dictionary: its attribute from the ETG.1000.6 data type code and
    /// bit length the ESI gives (conversion factor 1, no decimals, writable in every state).
    /// Integers, booleans and reals of 8, 16, 32 or 64 bits have fixed length; strings are
    /// lists of characters; anything longer than 64 bits (the IDN lists of Sercos, typed
    /// `DT_IDN_*` in Beckhoff's dictionaries) is a list of 2-byte items, which is what those
    /// lists hold.
    pub fn typed(idn: u16, name: String, data_type: u16, bits: u16, value: Vec<u8>) -> IdnSpec {
        use ether_ros_protocol::dtype::{by_code, Kind};
        let bits = u32::from(bits);
        let kind = by_code(data_type).map(|t| t.kind);
        let attribute = match kind {
            Some(Kind::String) => facts::list_attribute(1, facts::ATTR_TYPE_TEXT),
            Some(Kind::Bytes) => facts::list_attribute(1, facts::ATTR_TYPE_BINARY),
            _ if bits > 64 => facts::list_attribute(2, facts::ATTR_TYPE_BINARY),
            Some(Kind::Int) => facts::attribute(bits, facts::ATTR_TYPE_SIGNED),
            Some(Kind::Real) => facts::attribute(bits, facts::ATTR_TYPE_FLOAT),
            Some(Kind::Bool) => facts::attribute(bits, facts::ATTR_TYPE_BINARY),
            Some(Kind::Uint) | None => facts::attribute(bits, facts::ATTR_TYPE_UNSIGNED),
        };
        IdnSpec {
            idn,
            name,
            attribute,
            value,
        }
    }
}

#[derive(Clone, Debug)]
struct Idn {
    name: String,
    attribute: u32,
    value: Vec<u8>,
    default: Vec<u8>,
}

impl Idn {
    fn new(name: String, attribute: u32, mut value: Vec<u8>) -> Idn {
        match facts::attribute_data_len(attribute) {
            Some(n) => value.resize(n, 0),
            None => value = list_element(&value),
        }
        Idn {
            name,
            attribute,
            default: value.clone(),
            value,
        }
    }
}

/// A well-formed list element from `raw` (current length, maximum length, items): an empty
/// list when `raw` is shorter than the two lengths, the current length cut to the items
/// present and the maximum at least the current length.
fn list_element(raw: &[u8]) -> Vec<u8> {
    if raw.len() < facts::LIST_HEADER_LEN {
        return list(&[], 0);
    }
    let items = &raw[facts::LIST_HEADER_LEN..];
    let current = usize::from(u16::from_le_bytes([raw[0], raw[1]])).min(items.len());
    let maximum = usize::from(u16::from_le_bytes([raw[2], raw[3]])).max(current);
    list(&items[..current], maximum)
}

/// A list element holding `items` with room for `maximum` bytes.
fn list(items: &[u8], maximum: usize) -> Vec<u8> {
    let current = items.len().min(u16::MAX as usize);
    let maximum = maximum.clamp(current, u16::MAX as usize);
    let mut v = Vec::with_capacity(facts::LIST_HEADER_LEN + current);
    v.extend_from_slice(&(current as u16).to_le_bytes());
    v.extend_from_slice(&(maximum as u16).to_le_bytes());
    v.extend_from_slice(&items[..current]);
    v
}

/// A list of IDNs (two bytes each) as a list element.
fn idn_list(idns: &[u16], maximum_items: usize) -> Vec<u8> {
    let items: Vec<u8> = idns.iter().flat_map(|i| i.to_le_bytes()).collect();
    list(&items, maximum_items.max(idns.len()) * 2)
}

/// The attribute of a configuration list: IDNs, write-protected in every state (the simulated
/// drive's cyclic data is its ESI's).
const CONFIG_LIST_ATTRIBUTE: u32 = facts::list_attribute(2, facts::ATTR_TYPE_IDN)
    | facts::ATTR_WP_PREOP
    | facts::ATTR_WP_SAFEOP
    | facts::ATTR_WP_OP;

/// The "not existing" error of each element a read may address, in flag order.
const READ_ERRORS: [(u8, u16); 8] = [
    (facts::ELEMENT_DATA_STATE, facts::ERR_NO_DATA_STATE),
    (facts::ELEMENT_NAME, facts::ERR_NO_NAME),
    (facts::ELEMENT_ATTRIBUTE, facts::ERR_NONE),
    (facts::ELEMENT_UNIT, facts::ERR_NO_UNIT),
    (facts::ELEMENT_MINIMUM, facts::ERR_NO_MINIMUM),
    (facts::ELEMENT_MAXIMUM, facts::ERR_NO_MAXIMUM),
    (facts::ELEMENT_VALUE, facts::ERR_NONE),
    (facts::ELEMENT_DEFAULT, facts::ERR_NONE),
];

/// The "read only" error of each element but the value, for writes.
const WRITE_ERRORS: [(u8, u16); 7] = [
    (facts::ELEMENT_DATA_STATE, facts::ERR_NO_DATA_STATE),
    (facts::ELEMENT_NAME, facts::ERR_NAME_READ_ONLY),
    (facts::ELEMENT_ATTRIBUTE, facts::ERR_ATTRIBUTE_READ_ONLY),
    (facts::ELEMENT_UNIT, facts::ERR_UNIT_READ_ONLY),
    (facts::ELEMENT_MINIMUM, facts::ERR_MINIMUM_READ_ONLY),
    (facts::ELEMENT_MAXIMUM, facts::ERR_MAXIMUM_READ_ONLY),
    (facts::ELEMENT_DEFAULT, facts::ERR_DEFAULT_READ_ONLY),
];

/// The SoE server of one virtual slave.
#[derive(Debug, Default)]
pub struct SoeServer {
    /// Drive number -> its IDNs; `None`: the slave has no such drive.
    drives: [Option<BTreeMap<u16, Idn>>; facts::MAX_DRIVES as usize],
    /// Data of a fragmented write so far.
    write_fragments: Vec<u8>,
}

/// Drive number of a PDO: bits 12..=14 of its index.
fn pdo_drive(pdo_index: u16) -> usize {
    usize::from((pdo_index >> facts::IDN_SET_SHIFT) & 0x7)
}

impl SoeServer {
    /// The drives of a slave with dictionary `idns` and SII image `sii` (see the module
    /// documentation).
    pub fn new(idns: &[IdnSpec], sii: &[u8]) -> SoeServer {
        let rx = crate::sii::pdos(sii, SII_RXPDO);
        let tx = crate::sii::pdos(sii, SII_TXPDO);
        let mut server = SoeServer::default();
        let mut present = [false; facts::MAX_DRIVES as usize];
        present[0] = true;
        for p in rx.iter().chain(&tx) {
            present[pdo_drive(p.index)] = true;
        }
        let dictionary: BTreeMap<u16, Idn> = idns
            .iter()
            .map(|s| {
                (
                    s.idn,
                    Idn::new(s.name.clone(), s.attribute, s.value.clone()),
                )
            })
            .collect();
        for (d, here) in present.iter().enumerate() {
            if !here {
                continue;
            }
            let mut drive = dictionary.clone();
            for (pdos, list_idn, word) in [
                (&rx, facts::IDN_MDT_LIST, facts::IDN_CONTROL_WORD),
                (&tx, facts::IDN_AT_LIST, facts::IDN_STATUS_WORD),
            ] {
                let mut listed = Vec::new();
                for p in pdos.iter().filter(|p| pdo_drive(p.index) == d) {
                    for &(idn, _, bits) in &p.entries {
                        // Index 0 is padding; the word is always mapped, never listed.
                        if idn == 0 || bits == 0 {
                            continue;
                        }
                        drive.entry(idn).or_insert_with(|| {
                            let kind = if bits == 16 && idn == word {
                                facts::ATTR_TYPE_BINARY
                            } else {
                                facts::ATTR_TYPE_UNSIGNED
                            };
                            Idn::new(
                                facts::format_idn(idn),
                                facts::attribute(u32::from(bits), kind),
                                Vec::new(),
                            )
                        });
                        if idn != word {
                            listed.push(idn);
                        }
                    }
                }
                // Room for as many items as the dictionary's list has, if it says more.
                let room = dictionary
                    .get(&list_idn)
                    .and_then(|i| i.value.get(2..4))
                    .map_or(0, |m| usize::from(u16::from_le_bytes([m[0], m[1]])) / 2);
                let name = dictionary.get(&list_idn).map_or_else(
                    || {
                        if list_idn == facts::IDN_MDT_LIST {
                            "Configuration list of MDT".to_string()
                        } else {
                            "Configuration list of AT".to_string()
                        }
                    },
                    |i| i.name.clone(),
                );
                drive.insert(
                    list_idn,
                    Idn::new(name, CONFIG_LIST_ATTRIBUTE, idn_list(&listed, room)),
                );
            }
            server.drives[d] = Some(drive);
        }
        server
    }

    /// Forget a fragmented write in progress (the mailbox was reset, back in INIT).
    pub fn abandon_transfer(&mut self) {
        self.write_fragments.clear();
    }

    /// Whether the slave has drive `drive`.
    pub fn has_drive(&self, drive: u8) -> bool {
        self.drives
            .get(usize::from(drive))
            .is_some_and(|d| d.is_some())
    }

    /// The operation data of `idn` of `drive` (for a list the whole element).
    pub fn value(&self, drive: u8, idn: u16) -> Option<&[u8]> {
        let d = self.drives.get(usize::from(drive))?.as_ref()?;
        d.get(&idn).map(|i| i.value.as_slice())
    }

    /// Handle one SoE message (mailbox header stripped, trimmed to its length). Responses go
    /// to `out`, each at most `max_payload` bytes. `Err` is the mailbox error code the caller
    /// answers with instead (a message too short for the SoE header, an opcode a slave does
    /// not take).
    pub fn handle(
        &mut self,
        request: &[u8],
        al_state: u8,
        max_payload: usize,
        out: &mut Vec<Vec<u8>>,
    ) -> Result<(), u16> {
        use ether_ros_protocol::mailbox::{ERR_SERVICE_NOT_SUPPORTED, ERR_SIZE_TOO_SHORT};
        let Some(h) = Header::decode(request) else {
            return Err(ERR_SIZE_TOO_SHORT);
        };
        let data = &request[facts::HEADER_LEN..];
        match h.opcode {
            facts::OPCODE_READ_REQUEST => {
                self.read(&h, max_payload, out);
                Ok(())
            }
            facts::OPCODE_WRITE_REQUEST => {
                self.write(&h, data, al_state, out);
                Ok(())
            }
            _ => Err(ERR_SERVICE_NOT_SUPPORTED),
        }
    }

    fn read(&mut self, h: &Header, max_payload: usize, out: &mut Vec<Vec<u8>>) {
        let opcode = facts::OPCODE_READ_RESPONSE;
        if h.elements == 0 {
            out.push(error(opcode, h, facts::ERR_NO_ELEMENT));
            return;
        }
        let Some(drive) = self.drives[usize::from(h.drive)].as_ref() else {
            let list = h.idn == facts::IDN_MDT_LIST || h.idn == facts::IDN_AT_LIST;
            if list && h.elements == facts::ELEMENT_VALUE {
                out.push(response(opcode, h, false, h.idn, &list_element(&[])));
            } else {
                out.push(error(opcode, h, facts::ERR_INVALID_DRIVE));
            }
            return;
        };
        let Some(idn) = drive.get(&h.idn) else {
            out.push(error(opcode, h, facts::ERR_NO_IDN));
            return;
        };
        let mut data = Vec::new();
        for (flag, missing) in READ_ERRORS {
            if h.elements & flag == 0 {
                continue;
            }
            match flag {
                facts::ELEMENT_NAME => {
                    let name = idn.name.as_bytes();
                    data.extend_from_slice(&list(name, name.len()));
                }
                facts::ELEMENT_ATTRIBUTE => data.extend_from_slice(&idn.attribute.to_le_bytes()),
                facts::ELEMENT_VALUE => data.extend_from_slice(&idn.value),
                facts::ELEMENT_DEFAULT => data.extend_from_slice(&idn.default),
                _ => {
                    out.push(error(opcode, h, missing));
                    return;
                }
            }
        }
        // Fragments: all but the last have Incomplete set and count the fragments left where
        // the IDN goes; the last names the IDN.
        let room = max_payload.saturating_sub(facts::HEADER_LEN).max(1);
        let chunks: Vec<&[u8]> = if data.is_empty() {
            vec![&[]]
        } else {
            data.chunks(room).collect()
        };
        let n = chunks.len();
        for (k, chunk) in chunks.into_iter().enumerate() {
            let last = k + 1 == n;
            let field = if last {
                h.idn
            } else {
                (n - 1 - k).min(usize::from(u16::MAX)) as u16
            };
            out.push(response(opcode, h, !last, field, chunk));
        }
    }

    fn write(&mut self, h: &Header, data: &[u8], al_state: u8, out: &mut Vec<Vec<u8>>) {
        let opcode = facts::OPCODE_WRITE_RESPONSE;
        if h.incomplete {
            // Bytes 2..=3 count the fragments left; the IDN comes with the last one, which
            // alone is answered.
            self.write_fragments.extend_from_slice(data);
            return;
        }
        let mut value = std::mem::take(&mut self.write_fragments);
        value.extend_from_slice(data);
        if h.elements == 0 {
            out.push(error(opcode, h, facts::ERR_NO_ELEMENT));
            return;
        }
        let Some(drive) = self.drives[usize::from(h.drive)].as_mut() else {
            out.push(error(opcode, h, facts::ERR_INVALID_DRIVE));
            return;
        };
        let Some(idn) = drive.get_mut(&h.idn) else {
            out.push(error(opcode, h, facts::ERR_NO_IDN));
            return;
        };
        if let Some(&(_, code)) = WRITE_ERRORS.iter().find(|(f, _)| h.elements & f != 0) {
            out.push(error(opcode, h, code));
            return;
        }
        if let Err(code) = store(idn, h.idn, value, al_state) {
            out.push(error(opcode, h, code));
            return;
        }
        out.push(response(opcode, h, false, h.idn, &[]));
    }
}

/// Store a written value in `idn` (number `number`), or the error code why not.
fn store(idn: &mut Idn, number: u16, value: Vec<u8>, al_state: u8) -> Result<(), u16> {
    let config_list = number == facts::IDN_MDT_LIST || number == facts::IDN_AT_LIST;
    if config_list {
        // The list the drive already has is taken (a startup list repeating the ESI's
        // mapping); another would change the process data the ESC is set up for.
        let items = |v: &[u8]| v.get(facts::LIST_HEADER_LEN..).map(<[u8]>::to_vec);
        let current = u16::from_le_bytes([idn.value[0], idn.value[1]]);
        let written = value.get(..2).map(|b| u16::from_le_bytes([b[0], b[1]]));
        if written == Some(current) && items(&value) == items(&idn.value) {
            return Ok(());
        }
        return Err(facts::ERR_DATA_WRITE_PROTECTED);
    }
    let protected = match al_state & 0x0F {
        al::PREOP => idn.attribute & facts::ATTR_WP_PREOP,
        al::SAFEOP => idn.attribute & facts::ATTR_WP_SAFEOP,
        al::OP => idn.attribute & facts::ATTR_WP_OP,
        _ => 0,
    };
    if protected != 0 {
        return Err(facts::ERR_DATA_WRITE_PROTECTED);
    }
    match facts::attribute_data_len(idn.attribute) {
        Some(n) if value.len() < n => Err(facts::ERR_DATA_TOO_SHORT),
        Some(n) if value.len() > n => Err(facts::ERR_DATA_TOO_LONG),
        Some(_) => {
            idn.value = value;
            Ok(())
        }
        None => {
            if value.len() < facts::LIST_HEADER_LEN {
                return Err(facts::ERR_DATA_TOO_SHORT);
            }
            let current = usize::from(u16::from_le_bytes([value[0], value[1]]));
            let maximum = usize::from(u16::from_le_bytes([idn.value[2], idn.value[3]]));
            let items = &value[facts::LIST_HEADER_LEN..];
            if current > items.len() {
                return Err(facts::ERR_DATA_TOO_SHORT);
            }
            if current > maximum || items.len() > current {
                return Err(facts::ERR_DATA_TOO_LONG);
            }
            idn.value = list(items, maximum);
            Ok(())
        }
    }
}

/// A response: the request's drive and elements, `field` where the IDN goes, then `data`.
fn response(opcode: u8, req: &Header, incomplete: bool, field: u16, data: &[u8]) -> Vec<u8> {
    let h = Header {
        opcode,
        incomplete,
        error: false,
        drive: req.drive,
        elements: req.elements,
        idn: field,
    };
    let mut v = Vec::with_capacity(facts::HEADER_LEN + data.len());
    v.extend_from_slice(&h.encode());
    v.extend_from_slice(data);
    v
}

/// An error response: Error set, the error code as the last two bytes.
fn error(opcode: u8, req: &Header, code: u16) -> Vec<u8> {
    let h = Header {
        opcode,
        incomplete: false,
        error: true,
        drive: req.drive,
        elements: req.elements,
        idn: req.idn,
    };
    let mut v = h.encode().to_vec();
    v.extend_from_slice(&code.to_le_bytes());
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use ether_ros_protocol::mailbox::{ERR_SERVICE_NOT_SUPPORTED, ERR_SIZE_TOO_SHORT};

    /// A PDO of the SII: category, index, SyncManager, entries (IDN, bits).
    type Pdo<'a> = (u16, u16, u8, &'a [(u16, u8)]);

    /// An SII image (64 header words, then the categories) with `pdos`.
    fn sii(pdos: &[Pdo<'_>]) -> Vec<u8> {
        let mut image = vec![0u8; 128];
        for &(category, index, sm, entries) in pdos {
            let mut data = Vec::new();
            data.extend_from_slice(&index.to_le_bytes());
            data.extend_from_slice(&[entries.len() as u8, sm, 0, 0, 0, 0]);
            for &(idn, bits) in entries {
                data.extend_from_slice(&idn.to_le_bytes());
                data.extend_from_slice(&[0, 0, 0, bits, 0, 0]);
            }
            image.extend_from_slice(&category.to_le_bytes());
            image.extend_from_slice(&((data.len() / 2) as u16).to_le_bytes());
            image.extend_from_slice(&data);
        }
        image.extend_from_slice(&[0xFF, 0xFF]);
        image
    }

    /// A two-channel drive as Beckhoff's AX5206 ESI describes it: MDT 0x0018/0x1018 (control
    /// word, position command), AT 0x0010/0x1010 (status word, position feedback, following
    /// distance).
    fn two_channel() -> Vec<u8> {
        let mdt: &[(u16, u8)] = &[(134, 16), (47, 32)];
        let at: &[(u16, u8)] = &[(135, 16), (51, 32), (189, 32)];
        sii(&[
            (SII_RXPDO, 0x0018, 2, mdt),
            (SII_RXPDO, 0x1018, 2, mdt),
            (SII_TXPDO, 0x0010, 3, at),
            (SII_TXPDO, 0x1010, 3, at),
        ])
    }

    fn dictionary() -> Vec<IdnSpec> {
        vec![
            IdnSpec {
                idn: 1,
                name: "NC cycle time (TNcyc)".into(),
                attribute: facts::attribute(16, facts::ATTR_TYPE_UNSIGNED) | facts::ATTR_WP_OP,
                value: 1000u16.to_le_bytes().to_vec(),
            },
            IdnSpec {
                idn: facts::idn(true, 0, 10),
                name: "Feature flags".into(),
                attribute: facts::attribute(64, facts::ATTR_TYPE_HEX),
                value: vec![],
            },
            IdnSpec {
                idn: 47,
                name: "Position command value".into(),
                attribute: facts::attribute(32, facts::ATTR_TYPE_SIGNED),
                value: vec![],
            },
        ]
    }

    fn request(opcode: u8, drive: u8, elements: u8, idn: u16, data: &[u8]) -> Vec<u8> {
        let h = Header {
            opcode,
            incomplete: false,
            error: false,
            drive,
            elements,
            idn,
        };
        [&h.encode()[..], data].concat()
    }

    /// The one response to a request, as (header, data).
    fn ask(s: &mut SoeServer, req: &[u8], al_state: u8) -> (Header, Vec<u8>) {
        let mut out = Vec::new();
        s.handle(req, al_state, 122, &mut out).unwrap();
        assert_eq!(out.len(), 1, "{out:?}");
        (Header::decode(&out[0]).unwrap(), out[0][4..].to_vec())
    }

    fn read(s: &mut SoeServer, drive: u8, elements: u8, idn: u16) -> (Header, Vec<u8>) {
        let req = request(facts::OPCODE_READ_REQUEST, drive, elements, idn, &[]);
        ask(s, &req, al::PREOP)
    }

    fn u16s(b: &[u8]) -> Vec<u16> {
        b.chunks(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect()
    }

    #[test]
    fn the_configuration_lists_of_each_drive_come_from_its_pdos() {
        let mut s = SoeServer::new(&[], &two_channel());
        for drive in [0, 1] {
            let (h, data) = read(&mut s, drive, facts::ELEMENT_VALUE, facts::IDN_MDT_LIST);
            assert_eq!(
                (h.opcode, h.drive, h.error),
                (facts::OPCODE_READ_RESPONSE, drive, false)
            );
            assert_eq!(
                (h.elements, h.idn),
                (facts::ELEMENT_VALUE, facts::IDN_MDT_LIST)
            );
            // Current and maximum length in bytes, then the IDNs without the control word.
            assert_eq!(u16s(&data), [2, 2, 47]);
            let (_, data) = read(&mut s, drive, facts::ELEMENT_VALUE, facts::IDN_AT_LIST);
            assert_eq!(u16s(&data), [4, 4, 51, 189]);
        }
        // Each listed IDN's attribute gives its length, as a master sizes the telegram.
        let (_, data) = read(&mut s, 1, facts::ELEMENT_ATTRIBUTE, 189);
        let attribute = u32::from_le_bytes(data[..4].try_into().unwrap());
        assert_eq!(facts::attribute_data_len(attribute), Some(4));
        let (_, data) = read(&mut s, 0, facts::ELEMENT_ATTRIBUTE, facts::IDN_AT_LIST);
        let attribute = u32::from_le_bytes(data[..4].try_into().unwrap());
        assert_eq!(attribute & facts::ATTR_LIST, facts::ATTR_LIST);
        assert!(s.has_drive(1) && !s.has_drive(2));
    }

    #[test]
    fn a_drive_the_slave_lacks_has_empty_lists_and_no_other_idn() {
        let mut s = SoeServer::new(&dictionary(), &two_channel());
        for drive in 2..8 {
            for list_idn in [facts::IDN_MDT_LIST, facts::IDN_AT_LIST] {
                let (h, data) = read(&mut s, drive, facts::ELEMENT_VALUE, list_idn);
                assert!(!h.error);
                assert_eq!((h.drive, h.idn), (drive, list_idn));
                assert_eq!(u16s(&data), [0, 0]);
            }
            let (h, data) = read(&mut s, drive, facts::ELEMENT_VALUE, 1);
            assert!(h.error);
            assert_eq!(u16s(&data), [facts::ERR_INVALID_DRIVE]);
            let req = request(
                facts::OPCODE_WRITE_REQUEST,
                drive,
                facts::ELEMENT_VALUE,
                1,
                &[1, 0],
            );
            let (h, data) = ask(&mut s, &req, al::PREOP);
            assert!(h.error && h.opcode == facts::OPCODE_WRITE_RESPONSE);
            assert_eq!(u16s(&data), [facts::ERR_INVALID_DRIVE]);
        }
    }

    #[test]
    fn value_attribute_and_name_of_a_dictionary_idn() {
        let mut s = SoeServer::new(&dictionary(), &two_channel());
        let (h, data) = read(&mut s, 0, facts::ELEMENT_VALUE, 1);
        assert!(!h.error);
        assert_eq!(data, 1000u16.to_le_bytes());
        // A fixed-length value is as long as its attribute says, zero when the ESI gives none.
        let (_, data) = read(&mut s, 0, facts::ELEMENT_VALUE, 0x800A);
        assert_eq!(data, [0; 8]);
        let (_, data) = read(&mut s, 0, facts::ELEMENT_ATTRIBUTE, 1);
        assert_eq!(
            u32::from_le_bytes(data[..4].try_into().unwrap()),
            facts::attribute(16, facts::ATTR_TYPE_UNSIGNED) | facts::ATTR_WP_OP
        );
        // A name is a list of characters: current length, maximum length, the text.
        let (_, data) = read(&mut s, 1, facts::ELEMENT_NAME, 1);
        let text = b"NC cycle time (TNcyc)";
        assert_eq!(u16s(&data[..4]), [text.len() as u16, text.len() as u16]);
        assert_eq!(&data[4..], text);
        // Several elements at once come in flag order: attribute, then value.
        let both = facts::ELEMENT_ATTRIBUTE | facts::ELEMENT_VALUE;
        let (h, data) = read(&mut s, 0, both, 47);
        assert_eq!(h.elements, both);
        assert_eq!(data.len(), 8);
        // A PDO IDN the dictionary has keeps the dictionary's attribute (signed here).
        assert_eq!(
            u32::from_le_bytes(data[..4].try_into().unwrap()),
            facts::attribute(32, facts::ATTR_TYPE_SIGNED)
        );
    }

    #[test]
    fn missing_idns_and_elements_answer_their_error_codes() {
        let mut s = SoeServer::new(&dictionary(), &two_channel());
        let cases = [
            (facts::ELEMENT_VALUE, 4711, facts::ERR_NO_IDN),
            (facts::ELEMENT_UNIT, 1, facts::ERR_NO_UNIT),
            (facts::ELEMENT_MINIMUM, 1, facts::ERR_NO_MINIMUM),
            (facts::ELEMENT_MAXIMUM, 1, facts::ERR_NO_MAXIMUM),
            (0, 1, facts::ERR_NO_ELEMENT),
        ];
        for (elements, idn, code) in cases {
            let (h, data) = read(&mut s, 0, elements, idn);
            assert!(h.error, "{idn} {elements:#x}");
            assert_eq!((h.opcode, h.idn), (facts::OPCODE_READ_RESPONSE, idn));
            // The error code is the message's last two bytes.
            assert_eq!(u16s(&data), [code], "{idn} {elements:#x}");
        }
    }

    #[test]
    fn writes_are_stored_per_drive_within_the_attribute_s_rules() {
        let mut s = SoeServer::new(&dictionary(), &two_channel());
        let write = |drive: u8, idn: u16, data: &[u8]| {
            request(
                facts::OPCODE_WRITE_REQUEST,
                drive,
                facts::ELEMENT_VALUE,
                idn,
                data,
            )
        };
        // The ESI's init command: P-0-0010 (feature flags), 8 bytes.
        let flags = [0xFE, 0x7F, 0, 0, 0, 0, 0, 0];
        let (h, data) = ask(&mut s, &write(1, 0x800A, &flags), al::PREOP);
        assert!(!h.error && data.is_empty());
        assert_eq!(
            (h.opcode, h.drive, h.idn),
            (facts::OPCODE_WRITE_RESPONSE, 1, 0x800A)
        );
        assert_eq!(s.value(1, 0x800A), Some(&flags[..]));
        // Drive 0 keeps its own value.
        assert_eq!(s.value(0, 0x800A), Some(&[0u8; 8][..]));
        let refused = [
            (write(0, 1, &[1]), al::PREOP, facts::ERR_DATA_TOO_SHORT),
            (write(0, 1, &[1, 2, 3]), al::PREOP, facts::ERR_DATA_TOO_LONG),
            // S-0-0001 is write-protected in OP by its attribute.
            (
                write(0, 1, &[1, 2]),
                al::OP,
                facts::ERR_DATA_WRITE_PROTECTED,
            ),
            (write(0, 4711, &[1, 2]), al::PREOP, facts::ERR_NO_IDN),
            // Another MDT list than the ESI's.
            (
                write(0, 24, &[2, 0, 2, 0, 48, 0]),
                al::PREOP,
                facts::ERR_DATA_WRITE_PROTECTED,
            ),
            (
                request(
                    facts::OPCODE_WRITE_REQUEST,
                    0,
                    facts::ELEMENT_NAME,
                    1,
                    &[0; 4],
                ),
                al::PREOP,
                facts::ERR_NAME_READ_ONLY,
            ),
        ];
        for (req, state, code) in refused {
            let (h, data) = ask(&mut s, &req, state);
            assert!(h.error, "{req:?}");
            assert_eq!(u16s(&data), [code], "{req:?}");
        }
        // The list the drive has is taken (a startup list that repeats it).
        let (h, _) = ask(&mut s, &write(0, 24, &[2, 0, 2, 0, 47, 0]), al::PREOP);
        assert!(!h.error);
        assert_eq!(s.value(0, 1), Some(&1000u16.to_le_bytes()[..]));
    }

    #[test]
    fn long_responses_and_writes_go_in_fragments() {
        let long = IdnSpec {
            idn: 30,
            name: "x".repeat(300),
            attribute: facts::list_attribute(1, facts::ATTR_TYPE_TEXT),
            value: vec![],
        };
        let mut s = SoeServer::new(&[long], &two_channel());
        let mut out = Vec::new();
        let req = request(facts::OPCODE_READ_REQUEST, 0, facts::ELEMENT_NAME, 30, &[]);
        s.handle(&req, al::PREOP, 122, &mut out).unwrap();
        // 304 bytes (lengths and text) in 118-byte pieces: 3 fragments, 2 and 1 left, then
        // the last with the IDN.
        let heads: Vec<Header> = out.iter().map(|m| Header::decode(m).unwrap()).collect();
        assert_eq!(
            heads.iter().map(|h| h.incomplete).collect::<Vec<_>>(),
            [true, true, false]
        );
        assert_eq!(heads.iter().map(|h| h.idn).collect::<Vec<_>>(), [2, 1, 30]);
        assert!(out.iter().all(|m| m.len() <= 122));
        let data: Vec<u8> = out.iter().flat_map(|m| m[4..].to_vec()).collect();
        assert_eq!(u16s(&data[..4]), [300, 300]);
        assert_eq!(data.len(), 304);

        // A fragmented write: the fragments are collected, only the last is answered.
        let mut s = SoeServer::new(&dictionary(), &two_channel());
        let mut first = request(
            facts::OPCODE_WRITE_REQUEST,
            0,
            facts::ELEMENT_VALUE,
            1,
            &[0xFE],
        );
        first[0] |= facts::INCOMPLETE;
        let mut out = Vec::new();
        s.handle(&first, al::PREOP, 122, &mut out).unwrap();
        assert!(out.is_empty());
        let last = request(
            facts::OPCODE_WRITE_REQUEST,
            0,
            facts::ELEMENT_VALUE,
            1,
            &[0x7F],
        );
        let (h, _) = ask(&mut s, &last, al::PREOP);
        assert!(!h.error);
        assert_eq!(s.value(0, 1), Some(&[0xFE, 0x7F][..]));
    }

    #[test]
    fn short_messages_and_other_opcodes_are_the_caller_s_mailbox_errors() {
        let mut s = SoeServer::new(&[], &two_channel());
        let mut out = Vec::new();
        assert_eq!(
            s.handle(&[1, 0x40], al::PREOP, 122, &mut out),
            Err(ERR_SIZE_TOO_SHORT)
        );
        let note = request(facts::OPCODE_NOTIFICATION, 0, facts::ELEMENT_VALUE, 1, &[]);
        assert_eq!(
            s.handle(&note, al::PREOP, 122, &mut out),
            Err(ERR_SERVICE_NOT_SUPPORTED)
        );
        assert!(out.is_empty());
    }
}
