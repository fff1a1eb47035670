//! The SII EEPROM: the ESC's register interface to it (0x0500..=0x050F, ET1100 datasheet
//! section II, "EEPROM control/status") and the image's layout (ETG.2010): word addresses of
//! the header, category types and the CRC-8 of the configuration area.
//!
//! Control/status (0x0502, u16), bit by bit as the datasheet has them:
//! - bit 0 write enable (set in the same write as a write command),
//! - bit 5 EEPROM emulation by the PDI, bit 6 read size (1 = 8 bytes per read, 0 = 4),
//!   bit 7 address algorithm (1 = two address bytes, EEPROMs above 16 Kbit),
//! - bits 8..=10 command: 1 read, 2 write, 4 reload,
//! - bit 11 **checksum error** in the ESC configuration area (words 0..=6 against the CRC in
//!   word 7): the ESC did not take over the configuration area,
//! - bit 12 EEPROM loading status: 1 = not loaded, device information not available,
//! - bit 13 **error acknowledge/command**: the EEPROM did not acknowledge (an address past its
//!   end) or the command was invalid,
//! - bit 14 error write enable: a write command without write enable,
//! - bit 15 busy.
//!
//! The copies this crate replaced called bit 13 the checksum error and never looked at bit 11.

crate::named_constants! {
    /// Every bit and command, by name.
    pub const TABLE;
    /// SII configuration (0x0500) bit 0: the PDI owns the EEPROM (0 = EtherCAT).
    pub const CONFIG_PDI: u8 = 0x01;
    /// SII configuration bit 1: force the PDI to give up its access.
    pub const CONFIG_RESET_PDI_ACCESS: u8 = 0x02;
    /// Bit 0: write enable.
    pub const WRITE_ENABLE: u16 = 1 << 0;
    /// Bit 5: the PDI emulates the EEPROM.
    pub const EMULATION: u16 = 1 << 5;
    /// Bit 6: reads return 8 bytes (0: 4 bytes).
    pub const READ_8_BYTES: u16 = 1 << 6;
    /// Bit 7: two address bytes (EEPROMs larger than 16 Kbit).
    pub const TWO_ADDRESS_BYTES: u16 = 1 << 7;
    /// Command: read.
    pub const CMD_READ: u16 = 0x0100;
    /// Command: write.
    pub const CMD_WRITE: u16 = 0x0200;
    /// Command: reload the configuration area into the registers.
    pub const CMD_RELOAD: u16 = 0x0400;
    /// Bits 8..=10: the command.
    pub const CMD_MASK: u16 = 0x0700;
    /// Bit 11: checksum error in the ESC configuration area.
    pub const CHECKSUM_ERROR: u16 = 1 << 11;
    /// Bit 12: EEPROM not loaded, device information not available.
    pub const NOT_LOADED: u16 = 1 << 12;
    /// Bit 13: missing EEPROM acknowledge or invalid command.
    pub const COMMAND_ERROR: u16 = 1 << 13;
    /// Bit 14: write command without write enable.
    pub const WRITE_ERROR: u16 = 1 << 14;
    /// Bit 15: a command is being executed.
    pub const BUSY: u16 = 1 << 15;
    /// Bits 11..=14: every error indication.
    pub const ERROR_MASK: u16 = CHECKSUM_ERROR | NOT_LOADED | COMMAND_ERROR | WRITE_ERROR;
    /// The errors a command leaves behind (cleared by the next command): a read or write that
    /// failed. Checksum and loading status describe the configuration area, not the command.
    pub const COMMAND_ERRORS: u16 = COMMAND_ERROR | WRITE_ERROR;
}

/// Word addresses of the SII header (ETG.2010 table 2).
pub mod word {
    crate::named_constants! {
        /// Every word address, by name.
        pub const TABLE;
        /// PDI control (configuration area, words 0..=7).
        pub const PDI_CONTROL: u16 = 0x0000;
        /// PDI configuration.
        pub const PDI_CONFIG: u16 = 0x0001;
        /// SYNC impulse length.
        pub const SYNC_IMPULSE_LEN: u16 = 0x0002;
        /// PDI configuration 2.
        pub const PDI_CONFIG_2: u16 = 0x0003;
        /// Configured station alias.
        pub const CONFIGURED_ALIAS: u16 = 0x0004;
        /// Checksum (CRC-8 of words 0..=6 in the low byte).
        pub const CHECKSUM: u16 = 0x0007;
        /// Vendor ID (u32).
        pub const VENDOR_ID: u16 = 0x0008;
        /// Product code (u32).
        pub const PRODUCT_CODE: u16 = 0x000A;
        /// Revision number (u32).
        pub const REVISION: u16 = 0x000C;
        /// Serial number (u32).
        pub const SERIAL: u16 = 0x000E;
        /// Bootstrap receive mailbox offset.
        pub const BOOT_RX_MBX_OFFSET: u16 = 0x0014;
        /// Bootstrap receive mailbox size.
        pub const BOOT_RX_MBX_SIZE: u16 = 0x0015;
        /// Bootstrap send mailbox offset.
        pub const BOOT_TX_MBX_OFFSET: u16 = 0x0016;
        /// Bootstrap send mailbox size.
        pub const BOOT_TX_MBX_SIZE: u16 = 0x0017;
        /// Standard receive mailbox offset.
        pub const STD_RX_MBX_OFFSET: u16 = 0x0018;
        /// Standard receive mailbox size.
        pub const STD_RX_MBX_SIZE: u16 = 0x0019;
        /// Standard send mailbox offset.
        pub const STD_TX_MBX_OFFSET: u16 = 0x001A;
        /// Standard send mailbox size.
        pub const STD_TX_MBX_SIZE: u16 = 0x001B;
        /// Mailbox protocols supported.
        pub const MBX_PROTOCOL: u16 = 0x001C;
        /// EEPROM size (in KiBit − 1).
        pub const SIZE: u16 = 0x003E;
        /// Version.
        pub const VERSION: u16 = 0x003F;
        /// First category header.
        pub const FIRST_CATEGORY: u16 = 0x0040;
        /// Bytes of the configuration area the checksum covers (words 0..=6).
        pub const CHECKSUM_COVERS: u16 = 14;
    }
}

/// Category types (ETG.2010 table 3).
pub mod category {
    crate::named_constants! {
        /// Every category type, by name.
        pub const TABLE;
        /// No information.
        pub const NOP: u16 = 0;
        /// String repository.
        pub const STRINGS: u16 = 10;
        /// Data types.
        pub const DATA_TYPES: u16 = 20;
        /// General information.
        pub const GENERAL: u16 = 30;
        /// FMMUs to be used.
        pub const FMMU: u16 = 40;
        /// SyncManager configuration.
        pub const SYNCM: u16 = 41;
        /// TxPDO description.
        pub const TXPDO: u16 = 50;
        /// RxPDO description.
        pub const RXPDO: u16 = 51;
        /// Distributed clock.
        pub const DC: u16 = 60;
        /// End of the category list.
        pub const END: u16 = 0xFFFF;
    }
}

/// The SyncM category (ETG.2010): one 8-byte record per SyncManager — start (u16), length
/// (u16), control (u8), status (u8), enable (u8), type (u8).
pub mod syncm {
    crate::named_constants! {
        /// Every type and enable bit, by name.
        pub const TABLE;
        /// Type: unused or unknown.
        pub const TYPE_UNUSED: u8 = 0;
        /// Type: mailbox out (master to slave).
        pub const TYPE_MBOX_OUT: u8 = 1;
        /// Type: mailbox in (slave to master).
        pub const TYPE_MBOX_IN: u8 = 2;
        /// Type: process data outputs.
        pub const TYPE_OUTPUTS: u8 = 3;
        /// Type: process data inputs.
        pub const TYPE_INPUTS: u8 = 4;
        /// Enable bit 0: the SyncManager is enabled.
        pub const ENABLE: u8 = 0x01;
        /// Enable bit 1: fixed content (information for a configuration tool).
        pub const FIXED_CONTENT: u8 = 0x02;
        /// Enable bit 2: virtual SyncManager, no hardware resource (an FMMU maps its memory).
        pub const VIRTUAL: u8 = 0x04;
        /// Enable bit 3: enabled only in OP.
        pub const OP_ONLY: u8 = 0x08;
        /// Bytes of one record.
        pub const RECORD_LEN: usize = 8;
    }

    /// One SyncManager of the SyncM category.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct Record {
        /// Physical start address.
        pub start: u16,
        /// Length in bytes (the default size).
        pub length: u16,
        /// Control byte (as register 0x0804).
        pub control: u8,
        /// Status (0).
        pub status: u8,
        /// Enable byte: `ENABLE`, `FIXED_CONTENT`, `VIRTUAL`, `OP_ONLY`.
        pub enable: u8,
        /// Type: `TYPE_*`.
        pub kind: u8,
    }

    impl Record {
        /// The 8 bytes.
        pub const fn encode(&self) -> [u8; RECORD_LEN] {
            crate::le::window(
                self.start,
                self.length,
                [self.control, self.status, self.enable, self.kind],
            )
        }

        /// Decode the first 8 bytes of `data` (`None` when shorter).
        pub fn decode(data: &[u8]) -> Option<Record> {
            let r = data.get(..RECORD_LEN)?;
            Some(Record {
                start: crate::le::u16_at(r, 0),
                length: crate::le::u16_at(r, 2),
                control: r[4],
                status: r[5],
                enable: r[6],
                kind: r[7],
            })
        }

        /// The records of a SyncM category's data (a trailing partial record is ignored).
        pub fn decode_all(data: &[u8]) -> impl Iterator<Item = Record> + '_ {
            data.chunks_exact(RECORD_LEN).filter_map(Record::decode)
        }
    }
}

/// The General category (ETG.2010 table 5, 32 bytes): string indices, the mailbox protocols'
/// details, flags, the E-bus current and the physical ports.
pub mod general {
    crate::named_constants! {
        /// Every offset and bit, by name.
        pub const TABLE;
        /// Byte 0: string index of the group.
        pub const GROUP: usize = 0;
        /// Byte 1: string index of the image.
        pub const IMAGE: usize = 1;
        /// Byte 2: string index of the order number.
        pub const ORDER: usize = 2;
        /// Byte 3: string index of the device name.
        pub const NAME: usize = 3;
        /// Byte 5: CoE details.
        pub const COE_DETAILS: usize = 5;
        /// Byte 6: FoE details.
        pub const FOE_DETAILS: usize = 6;
        /// Byte 7: EoE details.
        pub const EOE_DETAILS: usize = 7;
        /// Byte 11: flags.
        pub const FLAGS: usize = 11;
        /// Bytes 12..=13: current consumption on the E-bus in mA (i16; negative: feeds it).
        pub const CURRENT_ON_EBUS: usize = 12;
        /// Byte 14: string index of the group again (for older masters).
        pub const GROUP_COPY: usize = 14;
        /// Bytes 16..=17: physical ports, 4 bits each (`PORT_*`).
        pub const PHYSICAL_PORTS: usize = 16;
        /// Bytes of the category.
        pub const LEN: usize = 32;
        /// Bytes a master needs to read it (up to the physical ports).
        pub const MIN_LEN: usize = 18;
        /// CoE details bit 0: SDO supported.
        pub const COE_SDO: u8 = 0x01;
        /// CoE details bit 1: SDO Information.
        pub const COE_SDO_INFO: u8 = 0x02;
        /// CoE details bit 2: PDO assignment.
        pub const COE_PDO_ASSIGN: u8 = 0x04;
        /// CoE details bit 3: PDO configuration.
        pub const COE_PDO_CONFIG: u8 = 0x08;
        /// CoE details bit 4: PDO upload at startup.
        pub const COE_UPLOAD_AT_STARTUP: u8 = 0x10;
        /// CoE details bit 5: SDO complete access.
        pub const COE_COMPLETE_ACCESS: u8 = 0x20;
        /// Flags bit 0: enable SAFEOP.
        pub const FLAG_ENABLE_SAFEOP: u8 = 0x01;
        /// Flags bit 1: enable not LRW.
        pub const FLAG_NOT_LRW: u8 = 0x02;
        /// Physical port: not used.
        pub const PORT_NONE: u8 = 0x0;
        /// Physical port: MII.
        pub const PORT_MII: u8 = 0x1;
        /// Physical port: E-bus.
        pub const PORT_EBUS: u8 = 0x3;
        /// Physical port: fast hot connect (MII).
        pub const PORT_FAST_HOT_CONNECT: u8 = 0x4;
    }
}

/// The FMMU category (ETG.2010 table 6): one byte per FMMU saying what it is for.
pub mod fmmu_usage {
    crate::named_constants! {
        /// Every usage, by name.
        pub const TABLE;
        /// Not used.
        pub const UNUSED: u8 = 0;
        /// Process data outputs.
        pub const OUTPUTS: u8 = 1;
        /// Process data inputs.
        pub const INPUTS: u8 = 2;
        /// The mailbox state (the SM1 status bit read by a logical command).
        pub const MBOX_STATE: u8 = 3;
        /// Padding of an odd count (the category is whole words): not an FMMU.
        pub const PADDING: u8 = 0xFF;
    }
}

/// The TxPDO and RxPDO categories (ETG.2010 tables 8 and 9): per PDO an 8-byte record, then an
/// 8-byte record per entry.
pub mod pdo {
    crate::named_constants! {
        /// Every flag, by name.
        pub const TABLE;
        /// PDO flags bit 0: mandatory.
        pub const FLAG_MANDATORY: u16 = 0x0001;
        /// PDO flags bit 1: assigned by default (a SyncManager is given).
        pub const FLAG_DEFAULT: u16 = 0x0002;
        /// PDO flags bit 4: fixed content.
        pub const FLAG_FIXED: u16 = 0x0010;
        /// The SyncManager of a PDO not assigned by default.
        pub const NO_SM: u8 = 0xFF;
        /// Bytes of a PDO record and of an entry record.
        pub const RECORD_LEN: usize = 8;
    }

    /// The record of one PDO: index (u16), number of entries (u8), SyncManager (u8, `NO_SM`
    /// when not assigned by default), synchronization (u8), name string index (u8), flags (u16).
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct Record {
        /// PDO index (0x1600.., 0x1A00..).
        pub index: u16,
        /// Number of entry records after this one.
        pub entries: u8,
        /// SyncManager it is assigned to by default, or `NO_SM`.
        pub sync_manager: u8,
        /// Synchronization (reserved, 0).
        pub synchronization: u8,
        /// String index of its name (0: none).
        pub name: u8,
        /// `FLAG_*`.
        pub flags: u16,
    }

    impl Record {
        /// The 8 bytes.
        pub const fn encode(&self) -> [u8; RECORD_LEN] {
            let i = self.index.to_le_bytes();
            let f = self.flags.to_le_bytes();
            [
                i[0],
                i[1],
                self.entries,
                self.sync_manager,
                self.synchronization,
                self.name,
                f[0],
                f[1],
            ]
        }

        /// Decode the first 8 bytes of `data` (`None` when shorter).
        pub fn decode(data: &[u8]) -> Option<Record> {
            let r = data.get(..RECORD_LEN)?;
            Some(Record {
                index: crate::le::u16_at(r, 0),
                entries: r[2],
                sync_manager: r[3],
                synchronization: r[4],
                name: r[5],
                flags: crate::le::u16_at(r, 6),
            })
        }
    }

    /// The record of one PDO entry: index (u16), subindex (u8), name string index (u8), data
    /// type (u8, the low byte of the CoE type code), bit length (u8), flags (u16, reserved).
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct Entry {
        /// Object index (0 for a gap).
        pub index: u16,
        /// Object subindex.
        pub subindex: u8,
        /// String index of its name (0: none).
        pub name: u8,
        /// Data type code (low byte).
        pub data_type: u8,
        /// Length in bits.
        pub bit_length: u8,
        /// Flags (reserved, 0).
        pub flags: u16,
    }

    impl Entry {
        /// The 8 bytes.
        pub const fn encode(&self) -> [u8; RECORD_LEN] {
            let i = self.index.to_le_bytes();
            let f = self.flags.to_le_bytes();
            [
                i[0],
                i[1],
                self.subindex,
                self.name,
                self.data_type,
                self.bit_length,
                f[0],
                f[1],
            ]
        }

        /// Decode the first 8 bytes of `data` (`None` when shorter).
        pub fn decode(data: &[u8]) -> Option<Entry> {
            let r = data.get(..RECORD_LEN)?;
            Some(Entry {
                index: crate::le::u16_at(r, 0),
                subindex: r[2],
                name: r[3],
                data_type: r[4],
                bit_length: r[5],
                flags: crate::le::u16_at(r, 6),
            })
        }
    }

    /// One PDO of a category with its entries.
    #[derive(Clone, Debug, PartialEq, Eq)]
    pub struct Pdo {
        /// The PDO's record.
        pub record: Record,
        /// Its entries, in order.
        pub entries: Vec<Entry>,
    }

    /// A PDO category that ends inside a PDO's entry list: the index of that PDO.
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub struct Truncated {
        /// The PDO whose entries run past the category.
        pub index: u16,
    }

    /// The PDOs of a TxPDO or RxPDO category's data. Trailing bytes shorter than a PDO record
    /// are ignored; a PDO whose entries run past the data is an error.
    pub fn decode_all(data: &[u8]) -> Result<Vec<Pdo>, Truncated> {
        let mut out = Vec::new();
        let mut off = 0;
        while let Some(record) = Record::decode(&data[off..]) {
            off += RECORD_LEN;
            let mut entries = Vec::with_capacity(usize::from(record.entries));
            for _ in 0..record.entries {
                let entry = Entry::decode(&data[off..]).ok_or(Truncated {
                    index: record.index,
                })?;
                entries.push(entry);
                off += RECORD_LEN;
            }
            out.push(Pdo { record, entries });
        }
        Ok(out)
    }
}

/// The DC category (ETG.2010 table 11): one 24-byte record per DC operation mode.
pub mod dc {
    /// Bytes of one record.
    pub const RECORD_LEN: usize = 24;

    /// One DC operation mode: cycle time of SYNC0 (u32, ns), shift of SYNC0 (i32, ns), shift
    /// of SYNC1 (i32, ns), SYNC1 cycle factor (u16), AssignActivate (u16), SYNC0 cycle factor
    /// (u16), name and description string indices (u8 each), 4 reserved bytes.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct Record {
        /// SYNC0 cycle time in ns.
        pub cycle_time_sync0: u32,
        /// SYNC0 shift in ns.
        pub shift_time_sync0: i32,
        /// SYNC1 shift in ns.
        pub shift_time_sync1: i32,
        /// SYNC1 cycle factor.
        pub sync1_cycle_factor: u16,
        /// The AssignActivate word (register 0x0980).
        pub assign_activate: u16,
        /// SYNC0 cycle factor.
        pub sync0_cycle_factor: u16,
        /// String index of the mode's name.
        pub name: u8,
        /// String index of its description.
        pub description: u8,
    }

    impl Record {
        /// The 24 bytes.
        pub fn encode(&self) -> [u8; RECORD_LEN] {
            let mut b = [0u8; RECORD_LEN];
            b[0..4].copy_from_slice(&self.cycle_time_sync0.to_le_bytes());
            b[4..8].copy_from_slice(&self.shift_time_sync0.to_le_bytes());
            b[8..12].copy_from_slice(&self.shift_time_sync1.to_le_bytes());
            b[12..14].copy_from_slice(&self.sync1_cycle_factor.to_le_bytes());
            b[14..16].copy_from_slice(&self.assign_activate.to_le_bytes());
            b[16..18].copy_from_slice(&self.sync0_cycle_factor.to_le_bytes());
            b[18] = self.name;
            b[19] = self.description;
            b
        }

        /// Decode the first 24 bytes of `data` (`None` when shorter).
        pub fn decode(data: &[u8]) -> Option<Record> {
            let r = data.get(..RECORD_LEN)?;
            let u16_at = |i: usize| crate::le::u16_at(r, i);
            let u32_at = |i: usize| crate::le::u32_at(r, i);
            Some(Record {
                cycle_time_sync0: u32_at(0),
                shift_time_sync0: u32_at(4) as i32,
                shift_time_sync1: u32_at(8) as i32,
                sync1_cycle_factor: u16_at(12),
                assign_activate: u16_at(14),
                sync0_cycle_factor: u16_at(16),
                name: r[18],
                description: r[19],
            })
        }
    }
}

/// One category of an SII image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Category<'a> {
    /// Byte offset of its header in the image.
    pub offset: usize,
    /// Its type (`category::*`; vendor categories as they are).
    pub kind: u16,
    /// Its data (the size word's number of words).
    pub data: &'a [u8],
}

/// The header of a category (`kind`, size in words) followed by `data`, padded to whole
/// words with a zero byte.
pub fn encode_category(kind: u16, data: &[u8], out: &mut Vec<u8>) {
    let words = data.len().div_ceil(2);
    out.extend_from_slice(&kind.to_le_bytes());
    out.extend_from_slice(&(words.min(u16::MAX as usize) as u16).to_le_bytes());
    out.extend_from_slice(data);
    if data.len() % 2 == 1 {
        out.push(0);
    }
}

/// The categories of an SII image from word 0x40 on, up to the end marker. The list stops
/// early where a category's header or data runs past the image (a master may have read only
/// the first part of the EEPROM).
pub fn categories(image: &[u8]) -> Categories<'_> {
    Categories {
        image,
        pos: 2 * word::FIRST_CATEGORY as usize,
    }
}

/// Iterator of [`categories`].
#[derive(Clone, Debug)]
pub struct Categories<'a> {
    image: &'a [u8],
    pos: usize,
}

impl<'a> Iterator for Categories<'a> {
    type Item = Category<'a>;

    fn next(&mut self) -> Option<Category<'a>> {
        let h = self.image.get(self.pos..self.pos + 4)?;
        let kind = u16::from_le_bytes([h[0], h[1]]);
        if kind == category::END {
            self.pos = self.image.len();
            return None;
        }
        let start = self.pos + 4;
        let end = start + 2 * usize::from(u16::from_le_bytes([h[2], h[3]]));
        let data = self.image.get(start..end)?;
        let offset = self.pos;
        self.pos = end;
        Some(Category { offset, kind, data })
    }
}

/// Whether `image` holds the whole category list up to its end marker. A list that runs on
/// past `max_bytes` counts as complete (a broken list: the reader stops and the decoder says
/// what is wrong).
pub fn list_complete(image: &[u8], max_bytes: usize) -> bool {
    let mut pos = 2 * word::FIRST_CATEGORY as usize;
    loop {
        let Some(k) = image.get(pos..pos + 2) else {
            return false;
        };
        if u16::from_le_bytes([k[0], k[1]]) == category::END {
            return true;
        }
        let Some(w) = image.get(pos + 2..pos + 4) else {
            return false;
        };
        pos += 4 + 2 * usize::from(u16::from_le_bytes([w[0], w[1]]));
        if pos > max_bytes {
            return true;
        }
    }
}

/// CRC-8 of the SII configuration area (words 0..=6): polynomial x⁸+x²+x+1 (0x07), initial
/// value 0xFF, no reflection, no final XOR. The result goes into the low byte of word 7.
pub const fn checksum(bytes: &[u8]) -> u8 {
    let mut crc: u8 = 0xFF;
    let mut i = 0;
    while i < bytes.len() {
        crc ^= bytes[i];
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x80 != 0 {
                (crc << 1) ^ 0x07
            } else {
                crc << 1
            };
            bit += 1;
        }
        i += 1;
    }
    crc
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checksum_is_crc8_poly_07_init_ff() {
        // The check value of CRC-8/poly 0x07/init 0xFF/no reflection over "123456789" is 0xFB
        // (the catalogue's CRC-8/ROHC reflects; this one does not).
        assert_eq!(checksum(b"123456789"), 0xFB);
        assert_eq!(checksum(&[]), 0xFF);
        let area = [0x80u8, 0x0c, 0x00, 0x6e, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0];
        let mut flipped = area;
        flipped[0] ^= 1;
        assert_ne!(checksum(&area), checksum(&flipped));
    }

    #[test]
    fn error_bits_are_the_datasheets() {
        // ET1100 datasheet section II, 0x0502: 11 checksum, 12 not loaded, 13 acknowledge or
        // command, 14 write enable; SOEM's EC_ESTAT_EMASK is the same 0x7800.
        assert_eq!(CHECKSUM_ERROR, 0x0800);
        assert_eq!(COMMAND_ERROR, 0x2000);
        assert_eq!(WRITE_ERROR, 0x4000);
        assert_eq!(ERROR_MASK, 0x7800);
        assert_eq!(COMMAND_ERRORS & CHECKSUM_ERROR, 0);
    }

    /// An image with the 128-byte header and `cats` after it.
    fn image(cats: &[(u16, &[u8])], end: bool) -> Vec<u8> {
        let mut v = vec![0u8; 2 * word::FIRST_CATEGORY as usize];
        for (kind, data) in cats {
            encode_category(*kind, data, &mut v);
        }
        if end {
            v.extend_from_slice(&category::END.to_le_bytes());
        }
        v
    }

    #[test]
    fn categories_walk_to_the_end_marker_and_stop_at_a_short_read() {
        let img = image(
            &[(category::GENERAL, &[1; 32]), (category::FMMU, &[1, 2, 3])],
            true,
        );
        // ETG.2010: header words type and size in words; odd data padded to a word.
        assert_eq!(&img[128..132], &[30, 0, 16, 0]);
        assert_eq!(&img[164..168], &[40, 0, 2, 0]);
        assert_eq!(&img[168..172], &[1, 2, 3, 0]);
        let cats: Vec<_> = categories(&img).collect();
        assert_eq!(cats.len(), 2);
        assert_eq!(
            (cats[0].offset, cats[0].kind, cats[0].data.len()),
            (128, 30, 32)
        );
        assert_eq!(
            (cats[1].offset, cats[1].kind, cats[1].data),
            (164, 40, &[1, 2, 3, 0][..])
        );
        assert!(list_complete(&img, 65536));
        // Cut inside the second category: the first is there, the list is not complete.
        assert_eq!(categories(&img[..170]).count(), 1);
        assert!(!list_complete(&img[..170], 65536));
        assert!(!list_complete(&img[..129], 65536));
        // A list running on past the limit counts as complete (broken, not waiting).
        let open = image(&[(category::STRINGS, &[0; 300])], false);
        assert!(list_complete(&open, 200));
        assert!(!list_complete(&open, 65536));
    }

    #[test]
    fn syncm_record_byte_image() {
        // SM2 outputs at 0x1100, 4 bytes, control 0x64, enabled, type 3 (ETG.2010 table 7).
        let r = syncm::Record {
            start: 0x1100,
            length: 4,
            control: 0x64,
            status: 0,
            enable: syncm::ENABLE,
            kind: syncm::TYPE_OUTPUTS,
        };
        assert_eq!(r.encode(), [0x00, 0x11, 0x04, 0x00, 0x64, 0x00, 0x01, 0x03]);
        let two: Vec<u8> = [r.encode(), r.encode()].concat();
        assert_eq!(
            syncm::Record::decode_all(&two[..15]).collect::<Vec<_>>(),
            vec![r]
        );
    }

    #[test]
    fn pdo_records_byte_image_and_truncation() {
        let p = pdo::Record {
            index: 0x1A00,
            entries: 2,
            sync_manager: 3,
            synchronization: 0,
            name: 5,
            flags: pdo::FLAG_MANDATORY | pdo::FLAG_DEFAULT,
        };
        assert_eq!(p.encode(), [0x00, 0x1A, 2, 3, 0, 5, 0x03, 0x00]);
        let e = pdo::Entry {
            index: 0x6000,
            subindex: 1,
            name: 6,
            data_type: 0x07,
            bit_length: 32,
            flags: 0,
        };
        assert_eq!(e.encode(), [0x00, 0x60, 1, 6, 0x07, 32, 0, 0]);
        let data = [p.encode(), e.encode(), e.encode()].concat();
        let pdos = pdo::decode_all(&data).unwrap();
        assert_eq!(pdos.len(), 1);
        assert_eq!(pdos[0].record, p);
        assert_eq!(pdos[0].entries, vec![e, e]);
        assert_eq!(
            pdo::decode_all(&data[..20]),
            Err(pdo::Truncated { index: 0x1A00 })
        );
    }

    #[test]
    fn dc_record_round_trips() {
        let r = dc::Record {
            cycle_time_sync0: 1_000_000,
            shift_time_sync0: -5000,
            shift_time_sync1: 7,
            sync1_cycle_factor: 1,
            assign_activate: 0x0300,
            sync0_cycle_factor: 1,
            name: 2,
            description: 3,
        };
        let b = r.encode();
        assert_eq!(&b[0..4], &1_000_000u32.to_le_bytes());
        assert_eq!(&b[14..16], &[0x00, 0x03]);
        assert_eq!(&b[20..], &[0, 0, 0, 0]);
        assert_eq!(dc::Record::decode(&b), Some(r));
        assert_eq!(dc::Record::decode(&b[..23]), None);
    }
}
