//! Pre-resolved object-dictionary entries for a device's fixed set of objects.
//!
//! `ObjectDictionary::get_int`/`set_int` look every (index, subindex) up in a hash map; at
//! 10 kHz with two dozen objects per leg that lookup was three quarters of the firmware's cost.
//! A device resolves its entries' positions once and reads/writes them by position here, with
//! exactly the semantics of `get_int`/`set_int` (missing entries read 0 and ignore writes).

use crate::od::{dtype, Entry, ObjectDictionary};

/// Positions of a list of (index, subindex) keys in one dictionary.
#[derive(Clone, Debug, Default)]
pub struct OdSlots {
    positions: Vec<Option<usize>>,
    /// Number of entries of the dictionary the positions were resolved in (a cheap check that
    /// the same dictionary is passed again).
    resolved_for: Option<usize>,
}

impl OdSlots {
    /// Resolve `keys` in `od` unless already resolved for a dictionary of the same size.
    pub fn resolve(&mut self, od: &ObjectDictionary, keys: &[(u16, u8)]) {
        if self.resolved_for == Some(od.entries().len()) && self.positions.len() == keys.len() {
            return;
        }
        self.positions = keys.iter().map(|&(i, s)| od.position(i, s)).collect();
        self.resolved_for = Some(od.entries().len());
    }

    /// The integer value of key number `slot` (as `ObjectDictionary::get_int`).
    pub fn get(&self, od: &ObjectDictionary, slot: usize) -> i64 {
        match self.positions.get(slot).copied().flatten() {
            Some(pos) => read_int(od.entry_at(pos)),
            None => 0,
        }
    }

    /// Whether key number `slot` exists in the dictionary.
    pub fn has(&self, slot: usize) -> bool {
        self.positions.get(slot).copied().flatten().is_some()
    }

    /// Write key number `slot` (as `ObjectDictionary::set_int`).
    pub fn set(&self, od: &mut ObjectDictionary, slot: usize, value: i64) {
        if let Some(pos) = self.positions.get(slot).copied().flatten() {
            write_int(od.entry_at_mut(pos), value);
        }
    }
}

fn read_int(e: &Entry) -> i64 {
    let mut raw = [0u8; 8];
    let n = e.value.len().min(8);
    raw[..n].copy_from_slice(&e.value[..n]);
    let v = u64::from_le_bytes(raw);
    let bits = u32::from(e.bit_length).clamp(1, 64);
    if dtype::is_signed(e.data_type) && bits < 64 {
        let shift = 64 - bits;
        ((v << shift) as i64) >> shift
    } else if bits < 64 {
        (v & ((1u64 << bits) - 1)) as i64
    } else {
        v as i64
    }
}

fn write_int(e: &mut Entry, value: i64) {
    let bytes = value.to_le_bytes();
    let n = e.value.len().min(8);
    e.value[..n].copy_from_slice(&bytes[..n]);
    let bits = usize::from(e.bit_length);
    if bits % 8 != 0 && n > 0 {
        e.value[n - 1] &= (1u8 << (bits % 8)) - 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::od::{Access, Entry};

    fn entry(index: u16, subindex: u8, data_type: u16, bit_length: u16) -> Entry {
        Entry {
            index,
            subindex,
            name: String::new(),
            data_type,
            bit_length,
            access: Access::ReadWrite,
            pdo_mappable: true,
            value: vec![],
        }
    }

    #[test]
    fn slots_read_and_write_like_the_dictionary() {
        let mut od = ObjectDictionary::new();
        od.add_entry(entry(0x7000, 1, dtype::BOOL, 1));
        od.add_entry(entry(0x7000, 9, dtype::INT8, 8));
        od.add_entry(entry(0x6012, 1, dtype::UINT16, 16));
        od.add_entry(entry(0x6030, 1, dtype::INT32, 32));
        let keys = [
            (0x7000, 1),
            (0x7000, 9),
            (0x6012, 1),
            (0x6030, 1),
            (0x1234, 5),
        ];
        let mut slots = OdSlots::default();
        slots.resolve(&od, &keys);
        for value in [0i64, 1, -1, 3, 127, -128, 300, 65_535, 70_000, -2_000_000] {
            for (slot, &(index, sub)) in keys.iter().enumerate() {
                let mut reference = od.clone();
                reference.set_int(index, sub, value);
                slots.set(&mut od, slot, value);
                assert_eq!(od.get_bytes(index, sub), reference.get_bytes(index, sub));
                assert_eq!(
                    slots.get(&od, slot),
                    od.get_int(index, sub),
                    "{index:#x}:{sub}"
                );
            }
        }
        assert_eq!(slots.get(&od, 4), 0);
        assert!(slots.has(3) && !slots.has(4));
    }
}
