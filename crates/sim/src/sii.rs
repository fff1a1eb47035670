//! The SII EEPROM behind a virtual ESC and its register interface (0x0500..=0x050F).
//!
//! The register's bits and the CRC-8 of the configuration area are `ether_ros_protocol::sii`'s
//! (ET1100 datasheet section II, 0x0502). Like the chip, the virtual EEPROM sets bit 13
//! (`COMMAND_ERROR`) for a read or write past its end and for an invalid command, bit 14
//! (`WRITE_ERROR`) for a write without write enable, and bits 11 and 12 (`CHECKSUM_ERROR`,
//! `NOT_LOADED`) when a reload finds the configuration area's checksum wrong.
//!
//! A command executes at once; the busy bit stays set for `busy_ns` afterwards so masters that
//! poll it are exercised (0 by default).

use ether_ros_protocol::sii::{category, pdo, syncm, word as sii_word};
pub use ether_ros_protocol::sii::{
    checksum, BUSY, CHECKSUM_ERROR, CMD_MASK, CMD_READ, CMD_RELOAD, CMD_WRITE, COMMAND_ERROR,
    ERROR_MASK, NOT_LOADED, READ_8_BYTES, TWO_ADDRESS_BYTES, WRITE_ENABLE, WRITE_ERROR,
};

/// Word `w` of an SII image (0 when outside).
pub fn word(image: &[u8], w: usize) -> u16 {
    match (image.get(2 * w), image.get(2 * w + 1)) {
        (Some(&lo), Some(&hi)) => u16::from_le_bytes([lo, hi]),
        _ => 0,
    }
}

/// The categories of an SII image: (type, data) pairs from word 0x40 on, until the end marker
/// (the protocol crate's walk; the type without bit 15).
pub fn categories(image: &[u8]) -> Vec<(u16, &[u8])> {
    ether_ros_protocol::sii::categories(image)
        .map(|c| (c.kind & 0x7fff, c.data))
        .collect()
}

/// One SyncManager of the SII SyncM category.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SiiSyncManager {
    /// Physical start address of the SyncManager.
    pub start: u16,
    /// Length in bytes.
    pub len: u16,
    /// Control register value (mode and direction).
    pub control: u8,
    /// Enable bits (bit 0 enabled).
    pub enable: u8,
    /// 1 mailbox out, 2 mailbox in, 3 process data out, 4 process data in (0 unused).
    pub kind: u8,
}

/// The SyncManagers of the SyncM categories (the protocol crate's record codec).
pub fn sync_managers(image: &[u8]) -> Vec<SiiSyncManager> {
    let mut v = Vec::new();
    for (kind, data) in categories(image) {
        if kind == category::SYNCM {
            v.extend(syncm::Record::decode_all(data).map(|r| SiiSyncManager {
                start: r.start,
                len: r.length,
                control: r.control,
                enable: r.enable,
                kind: r.kind,
            }));
        }
    }
    v
}

/// One PDO of the SII TxPDO (50) / RxPDO (51) categories: its SyncManager and entries
/// (index, subindex, bit length).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SiiPdo {
    /// PDO index (0x1600.. RxPDO, 0x1A00.. TxPDO).
    pub index: u16,
    /// SyncManager the PDO is assigned to.
    pub sync_manager: u8,
    /// Its entries: (index, subindex, bit length).
    pub entries: Vec<(u16, u8, u16)>,
}

/// The PDOs of the categories of type `category` (the protocol crate's record codec); a PDO
/// whose entry list runs past its category keeps the entries that are there.
pub fn pdos(image: &[u8], category: u16) -> Vec<SiiPdo> {
    let mut v = Vec::new();
    for (kind, data) in categories(image) {
        if kind != category {
            continue;
        }
        let mut p = 0;
        while let Some(record) = pdo::Record::decode(&data[p..]) {
            let mut entries = Vec::new();
            let mut q = p + pdo::RECORD_LEN;
            for _ in 0..record.entries {
                let Some(e) = pdo::Entry::decode(&data[q..]) else {
                    break;
                };
                entries.push((e.index, e.subindex, u16::from(e.bit_length)));
                q += pdo::RECORD_LEN;
            }
            v.push(SiiPdo {
                index: record.index,
                sync_manager: record.sync_manager,
                entries,
            });
            p = q;
        }
    }
    v
}

/// The EEPROM and the state of its register interface.
#[derive(Clone, Debug)]
pub struct Sii {
    /// The EEPROM contents (16-bit words, little endian).
    pub image: Vec<u8>,
    /// How long one EEPROM read keeps the interface busy (ns); 0: answers at once.
    pub busy_ns: u64,
    busy_until: u64,
}

impl Sii {
    /// An EEPROM holding `image`.
    pub fn new(mut image: Vec<u8>) -> Self {
        if image.len() % 2 == 1 {
            image.push(0xff);
        }
        Sii {
            image,
            busy_ns: 0,
            busy_until: 0,
        }
    }

    /// The checksum of words 0..=6 matches word 7.
    pub fn checksum_ok(&self) -> bool {
        let covered = sii_word::CHECKSUM_COVERS as usize;
        self.image.len() >= 16 && checksum(&self.image[..covered]) == self.image[covered]
    }

    /// Static bits of the status register for this EEPROM.
    pub fn static_status(&self) -> u16 {
        let mut s = READ_8_BYTES;
        if self.image.len() > 2048 {
            s |= TWO_ADDRESS_BYTES;
        }
        s
    }

    /// True while a read started earlier is still in progress at `now`.
    pub fn busy(&self, now: u64) -> bool {
        now < self.busy_until
    }

    /// Execute a command written to 0x0502 with the address and data registers as they are
    /// now. Returns the new status word and, for reads, fills `data` (8 bytes).
    pub fn execute(&mut self, control: u16, address: u32, data: &mut [u8; 8], now: u64) -> u16 {
        let mut status = self.static_status();
        let cmd = control & CMD_MASK;
        let byte = (address as usize).saturating_mul(2);
        match cmd {
            0 => return status,
            CMD_READ => {
                if byte >= self.image.len() {
                    status |= COMMAND_ERROR;
                } else {
                    for (i, d) in data.iter_mut().enumerate() {
                        *d = self.image.get(byte + i).copied().unwrap_or(0xff);
                    }
                }
            }
            CMD_WRITE => {
                if control & WRITE_ENABLE == 0 {
                    status |= WRITE_ERROR;
                } else if byte + 1 >= self.image.len() {
                    status |= COMMAND_ERROR;
                } else {
                    self.image[byte] = data[0];
                    self.image[byte + 1] = data[1];
                }
            }
            CMD_RELOAD => {
                if !self.checksum_ok() {
                    status |= CHECKSUM_ERROR | NOT_LOADED;
                }
            }
            // The datasheet's bit 13 ("missing acknowledge or invalid command"); this model
            // used to set bit 14, which is the write-enable error.
            _ => status |= COMMAND_ERROR,
        }
        self.busy_until = now.saturating_add(self.busy_ns);
        status | (control & CMD_MASK)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_pad_and_out_of_range_errors() {
        let mut s = Sii::new(vec![1, 2, 3, 4, 5, 6]);
        let mut d = [0u8; 8];
        let st = s.execute(CMD_READ, 1, &mut d, 0);
        assert_eq!(st & COMMAND_ERROR, 0);
        assert_eq!(d, [3, 4, 5, 6, 0xff, 0xff, 0xff, 0xff]);
        let st = s.execute(CMD_READ, 3, &mut d, 0);
        assert_ne!(
            st & COMMAND_ERROR,
            0,
            "past the end: no acknowledge (bit 13)"
        );
        d[0] = 9;
        d[1] = 8;
        assert_ne!(s.execute(CMD_WRITE, 0, &mut d, 0) & WRITE_ERROR, 0);
        assert_eq!(
            s.execute(CMD_WRITE | WRITE_ENABLE, 0, &mut d, 0) & ERROR_MASK,
            0
        );
        assert_eq!(&s.image[..2], &[9, 8]);
        // An invalid command (3 is neither read 1, write 2 nor reload 4) is bit 13, not the
        // write-enable error of bit 14 (ET1100 datasheet section II, 0x0502).
        let st = s.execute(0x0300, 0, &mut d, 0);
        assert_eq!(st & ERROR_MASK, COMMAND_ERROR);
    }
}
