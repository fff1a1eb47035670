//! CoE object dictionary of a virtual slave: the values the device application reads and writes
//! and that the SDO server and the process-data mapping expose. Built from the ESI by the Python
//! front (one `EntrySpec` per subindex); values are little-endian byte strings as on the wire.

use std::collections::{BTreeMap, HashMap};

/// ETG.1000.6 data type codes: the protocol crate's (`ether_ros_protocol::dtype`).
pub mod dtype {
    use ether_ros_protocol::dtype::{by_code, Kind};
    pub use ether_ros_protocol::dtype::{
        BOOL, INT16, INT24, INT32, INT64, INT8, OCTET_STRING, REAL32, REAL64, UINT16, UINT24,
        UINT32, UINT64, UINT8, VISIBLE_STRING,
    };

    /// Signed integer types (their values are sign-extended when read as i64).
    pub fn is_signed(t: u16) -> bool {
        by_code(t).is_some_and(|d| d.kind == Kind::Int)
    }
}

/// Access rights per AL state group, as in ESI `<Access>`: ro, rw, wo.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// Read in every state, never written.
    ReadOnly,
    /// Read and written.
    ReadWrite,
    /// Written, never read.
    WriteOnly,
}

/// One subindex of the dictionary.
#[derive(Clone, Debug)]
pub struct Entry {
    /// Object index.
    pub index: u16,
    /// Subindex.
    pub subindex: u8,
    /// Name (SDO Information).
    pub name: String,
    /// CoE data type (the protocol crate's `dtype`).
    pub data_type: u16,
    /// Size in bits.
    pub bit_length: u16,
    /// Who may read and write it.
    pub access: Access,
    /// May be mapped into a PDO.
    pub pdo_mappable: bool,
    /// Current value, `ceil(bit_length / 8)` bytes, little endian.
    pub value: Vec<u8>,
}

/// One object (index) with its name and object code (7 VAR, 8 ARRAY, 9 RECORD).
#[derive(Clone, Debug)]
pub struct Object {
    /// Object index.
    pub index: u16,
    /// Name (SDO Information).
    pub name: String,
    /// Object code (VAR, ARRAY, RECORD).
    pub object_code: u8,
}

/// The dictionary. Lookups by (index, subindex) are O(1); iteration is in index order.
#[derive(Clone, Debug, Default)]
pub struct ObjectDictionary {
    objects: BTreeMap<u16, Object>,
    entries: Vec<Entry>,
    by_key: HashMap<(u16, u8), usize>,
}

impl ObjectDictionary {
    /// An empty dictionary.
    pub fn new() -> Self {
        Self::default()
    }

    /// Add an object (its entries are added with `add_entry`).
    pub fn add_object(&mut self, object: Object) {
        self.objects.insert(object.index, object);
    }

    /// Add or replace an entry. Its value is padded/truncated to the bit length.
    pub fn add_entry(&mut self, mut entry: Entry) {
        entry
            .value
            .resize((entry.bit_length as usize).div_ceil(8), 0);
        let key = (entry.index, entry.subindex);
        match self.by_key.get(&key) {
            Some(&i) => self.entries[i] = entry,
            None => {
                self.by_key.insert(key, self.entries.len());
                self.entries.push(entry);
            }
        }
    }

    /// Add a RECORD object: subindex 0 (the number of entries, read-only) and its PDO-mappable
    /// entries `(subindex, name, data_type, bit_length)`, all with `access`.
    pub fn add_record(
        &mut self,
        index: u16,
        name: &str,
        access: Access,
        entries: &[(u8, String, u16, u16)],
    ) {
        self.add_object(Object {
            index,
            name: name.to_string(),
            object_code: 9,
        });
        self.add_entry(Entry {
            index,
            subindex: 0,
            name: "SubIndex 000".to_string(),
            data_type: dtype::UINT8,
            bit_length: 8,
            access: Access::ReadOnly,
            pdo_mappable: false,
            value: vec![entries.len() as u8],
        });
        for (subindex, entry_name, data_type, bit_length) in entries {
            self.add_entry(Entry {
                index,
                subindex: *subindex,
                name: entry_name.clone(),
                data_type: *data_type,
                bit_length: *bit_length,
                access,
                pdo_mappable: true,
                value: vec![],
            });
        }
    }

    /// The object at `index`.
    pub fn object(&self, index: u16) -> Option<&Object> {
        self.objects.get(&index)
    }

    /// Every object, in index order.
    pub fn objects(&self) -> impl Iterator<Item = &Object> {
        self.objects.values()
    }

    /// The entry at `index:subindex`.
    pub fn entry(&self, index: u16, subindex: u8) -> Option<&Entry> {
        self.by_key
            .get(&(index, subindex))
            .map(|&i| &self.entries[i])
    }

    /// The entry at `index:subindex`, to change it.
    pub fn entry_mut(&mut self, index: u16, subindex: u8) -> Option<&mut Entry> {
        self.by_key
            .get(&(index, subindex))
            .map(|&i| &mut self.entries[i])
    }

    /// Entries of one object, in subindex order.
    pub fn entries_of(&self, index: u16) -> Vec<&Entry> {
        let mut v: Vec<&Entry> = self.entries.iter().filter(|e| e.index == index).collect();
        v.sort_by_key(|e| e.subindex);
        v
    }

    /// The raw value (little endian) of `index:subindex`.
    pub fn get_bytes(&self, index: u16, subindex: u8) -> Option<&[u8]> {
        self.entry(index, subindex).map(|e| e.value.as_slice())
    }

    /// Set raw bytes; returns false when the entry does not exist. Extra bytes are ignored and
    /// missing ones are zero, so a value never changes an entry's size.
    pub fn set_bytes(&mut self, index: u16, subindex: u8, bytes: &[u8]) -> bool {
        match self.entry_mut(index, subindex) {
            Some(e) => {
                let n = e.value.len();
                for (i, b) in e.value.iter_mut().enumerate() {
                    *b = if i < bytes.len() && i < n {
                        bytes[i]
                    } else {
                        0
                    };
                }
                true
            }
            None => false,
        }
    }

    /// Read an integer or bool entry as i64 (sign-extended for signed types). Missing: 0.
    pub fn get_int(&self, index: u16, subindex: u8) -> i64 {
        let Some(e) = self.entry(index, subindex) else {
            return 0;
        };
        let mut raw = [0u8; 8];
        let n = e.value.len().min(8);
        raw[..n].copy_from_slice(&e.value[..n]);
        let v = u64::from_le_bytes(raw);
        let bits = (e.bit_length as u32).clamp(1, 64);
        if dtype::is_signed(e.data_type) && bits < 64 {
            let shift = 64 - bits;
            ((v << shift) as i64) >> shift
        } else if bits < 64 {
            (v & ((1u64 << bits) - 1)) as i64
        } else {
            v as i64
        }
    }

    /// Write an integer or bool entry, truncated to its bit length. Missing entries are ignored.
    pub fn set_int(&mut self, index: u16, subindex: u8, value: i64) {
        if let Some(e) = self.entry_mut(index, subindex) {
            let bytes = value.to_le_bytes();
            let n = e.value.len().min(8);
            e.value[..n].copy_from_slice(&bytes[..n]);
            let bits = e.bit_length as usize;
            if !bits.is_multiple_of(8) && n > 0 {
                e.value[n - 1] &= (1u8 << (bits % 8)) - 1;
            }
        }
    }

    /// The value of `index:subindex` read as a boolean (false when absent).
    pub fn get_bool(&self, index: u16, subindex: u8) -> bool {
        self.get_int(index, subindex) & 1 != 0
    }

    /// Every entry, in index and subindex order.
    pub fn entries(&self) -> &[Entry] {
        &self.entries
    }

    /// Position of an entry in `entries()`, stable until the dictionary is rebuilt: lets the
    /// process-data copy skip the hash lookup every cycle.
    pub fn position(&self, index: u16, subindex: u8) -> Option<usize> {
        self.by_key.get(&(index, subindex)).copied()
    }

    /// Entry at a position from `position()`. Panics on a position not from this dictionary.
    pub fn entry_at(&self, position: usize) -> &Entry {
        &self.entries[position]
    }

    /// Mutable entry at a position from `position()`.
    pub fn entry_at_mut(&mut self, position: usize) -> &mut Entry {
        &mut self.entries[position]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(index: u16, sub: u8, t: u16, bits: u16) -> Entry {
        Entry {
            index,
            subindex: sub,
            name: format!("e{index:04x}:{sub}"),
            data_type: t,
            bit_length: bits,
            access: Access::ReadWrite,
            pdo_mappable: true,
            value: vec![],
        }
    }

    #[test]
    fn signed_values_round_trip_and_truncate() {
        let mut od = ObjectDictionary::new();
        od.add_entry(entry(0x6010, 1, dtype::INT16, 16));
        od.add_entry(entry(0x7000, 1, dtype::BOOL, 1));
        od.set_int(0x6010, 1, -1234);
        assert_eq!(od.get_int(0x6010, 1), -1234);
        assert_eq!(od.get_bytes(0x6010, 1), Some(&(-1234i16).to_le_bytes()[..]));
        od.set_int(0x7000, 1, 3);
        assert_eq!(od.get_int(0x7000, 1), 1);
        assert!(od.get_bool(0x7000, 1));
        assert_eq!(od.get_int(0x1234, 1), 0);
        assert!(!od.set_bytes(0x1234, 1, &[1]));
    }
}
