//! Process-data mapping of a virtual slave: which object-dictionary entries sit at which bit
//! of the SyncManager buffers, computed from the current PDO assignment (0x1C12/0x1C13) and
//! mapping objects (0x16xx/0x1Axx), or from the SII PDO categories when the slave has no CoE.
//! The ESC core uses it to check the SyncManager sizes on PREOP→SAFEOP and to copy data
//! between the buffers and the dictionary.

use crate::od::ObjectDictionary;

/// One mapped entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MapItem {
    pub index: u16,
    pub subindex: u8,
    pub bits: u16,
    /// Bit offset in the SyncManager buffer.
    pub offset: u32,
    /// Position of the entry in the dictionary (None for gaps or entries the OD lacks).
    pub entry: Option<usize>,
}

#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PdoMap {
    pub items: Vec<MapItem>,
    pub bits: u32,
}

impl PdoMap {
    pub fn bytes(&self) -> usize {
        (self.bits as usize).div_ceil(8)
    }

    /// Place the next entry right after the ones already mapped.
    fn append(&mut self, index: u16, subindex: u8, bits: u16, entry: Option<usize>) {
        self.items.push(MapItem {
            index,
            subindex,
            bits,
            offset: self.bits,
            entry,
        });
        self.bits += bits as u32;
    }
}

/// Why a mapping is not usable.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MappingError;

/// Build the map from the assignment object `assign` (0x1C10 + SM number). Returns None when
/// the dictionary has no such object (no CoE). A mapped entry that does not exist or has
/// another bit length is an error (gaps, index 0, are allowed) — except a shorter mapping of
/// an object the device's own default maps that way (`partial`: (index, subindex, bits)),
/// which takes the object's low bits.
pub fn from_od(
    od: &ObjectDictionary,
    assign: u16,
    partial: &[(u16, u8, u16)],
) -> Option<Result<PdoMap, MappingError>> {
    od.entry(assign, 0)?;
    let mut map = PdoMap::default();
    let n_pdos = od.get_int(assign, 0).clamp(0, 254) as u8;
    for k in 1..=n_pdos {
        let pdo = od.get_int(assign, k) as u16;
        if od.entry(pdo, 0).is_none() {
            return Some(Err(MappingError));
        }
        let n = od.get_int(pdo, 0).clamp(0, 254) as u8;
        for s in 1..=n {
            let raw = od.get_int(pdo, s) as u32;
            let index = (raw >> 16) as u16;
            let subindex = (raw >> 8) as u8;
            let bits = (raw & 0xff) as u16;
            let entry = if index == 0 {
                None
            } else {
                let Some(pos) = od.position(index, subindex) else {
                    return Some(Err(MappingError));
                };
                let e = od.entry_at(pos);
                if e.bit_length != bits && !partial.contains(&(index, subindex, bits)) {
                    return Some(Err(MappingError));
                }
                Some(pos)
            };
            map.append(index, subindex, bits, entry);
        }
    }
    Some(Ok(map))
}

/// Build the map from SII PDO entries (index, subindex, bits); entries the OD lacks are carried
/// without a place to store them. The SII is the device's own default, so an entry of another
/// length than its object maps the object's low bits (the copy stays inside both).
pub fn from_entries(od: &ObjectDictionary, entries: &[(u16, u8, u16)]) -> PdoMap {
    let mut map = PdoMap::default();
    for &(index, subindex, bits) in entries {
        let entry = if index == 0 {
            None
        } else {
            od.position(index, subindex)
        };
        map.append(index, subindex, bits, entry);
    }
    map
}

/// Copy `n` bits from `src` at bit `so` to `dst` at bit `do_` (LSB first, as EtherCAT packs).
/// Bits outside either slice are skipped.
pub fn copy_bits(src: &[u8], so: usize, dst: &mut [u8], do_: usize, n: usize) {
    if so.is_multiple_of(8) && do_.is_multiple_of(8) && n.is_multiple_of(8) {
        let (s, d, len) = (so / 8, do_ / 8, n / 8);
        let len = len
            .min(src.len().saturating_sub(s))
            .min(dst.len().saturating_sub(d));
        dst[d..d + len].copy_from_slice(&src[s..s + len]);
        return;
    }
    for i in 0..n {
        let (sb, db) = (so + i, do_ + i);
        let (Some(&s), Some(d)) = (src.get(sb / 8), dst.get_mut(db / 8)) else {
            continue;
        };
        let bit = (s >> (sb % 8)) & 1;
        *d = (*d & !(1 << (db % 8))) | (bit << (db % 8));
    }
}

/// SyncManager buffer → dictionary (outputs).
pub fn buffer_to_od(map: &PdoMap, buf: &[u8], od: &mut ObjectDictionary) {
    for it in &map.items {
        if let Some(pos) = it.entry {
            let e = od.entry_at_mut(pos);
            copy_bits(buf, it.offset as usize, &mut e.value, 0, it.bits as usize);
        }
    }
}

/// Dictionary → SyncManager buffer (inputs).
pub fn od_to_buffer(map: &PdoMap, od: &ObjectDictionary, buf: &mut [u8]) {
    for it in &map.items {
        if let Some(pos) = it.entry {
            let e = od.entry_at(pos);
            copy_bits(&e.value, 0, buf, it.offset as usize, it.bits as usize);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bit_copies_land_lsb_first() {
        let mut d = [0u8; 2];
        copy_bits(&[0b101], 0, &mut d, 6, 3);
        assert_eq!(d, [0b0100_0000, 0b1]);
        let mut e = [0u8; 1];
        copy_bits(&d, 6, &mut e, 0, 3);
        assert_eq!(e, [0b101]);
        let mut f = [0u8; 3];
        copy_bits(&[1, 2], 0, &mut f, 8, 16);
        assert_eq!(f, [0, 1, 2]);
    }
}
