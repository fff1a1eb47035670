//! FMMU registers (0x0600 + 16·n) and the bit-level logical → physical mapping. The register
//! record's codec is the protocol crate's (`ether_ros_protocol::reg::fmmu::Record`).
//!
//! Layout: logical start (u32), length in bytes (u16), logical start bit (u8, 0..=7), logical
//! stop bit (u8, 0..=7), physical start (u16), physical start bit (u8), type (u8: bit 0 read,
//! bit 1 write), activate (u8, bit 0). The mapped logical bit range runs from
//! `start·8 + start_bit` to `(start + length − 1)·8 + stop_bit` inclusive and lands on
//! consecutive physical bits from `physical·8 + physical_bit`.

#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Fmmu {
    pub logical_start: u32,
    pub length: u16,
    pub logical_start_bit: u8,
    pub logical_stop_bit: u8,
    pub physical_start: u16,
    pub physical_start_bit: u8,
    pub read: bool,
    pub write: bool,
}

impl Fmmu {
    /// Decode an active FMMU from its 16 register bytes (None when inactive or empty): the
    /// protocol crate's record, with the bit numbers taken modulo 8 as the ESC does.
    pub fn decode(r: &[u8]) -> Option<Fmmu> {
        let rec = ether_ros_protocol::reg::fmmu::Record::decode(r)?;
        if !rec.enabled() {
            return None;
        }
        let f = Fmmu {
            logical_start: rec.logical_start,
            length: rec.length,
            logical_start_bit: rec.logical_start_bit & 7,
            logical_stop_bit: rec.logical_stop_bit & 7,
            physical_start: rec.physical_start,
            physical_start_bit: rec.physical_start_bit & 7,
            read: rec.kind & ether_ros_protocol::reg::fmmu::READ != 0,
            write: rec.kind & ether_ros_protocol::reg::fmmu::WRITE != 0,
        };
        if f.length == 0 || !(f.read || f.write) {
            return None;
        }
        Some(f)
    }

    /// First mapped logical bit.
    pub fn first_bit(&self) -> u64 {
        self.logical_start as u64 * 8 + self.logical_start_bit as u64
    }

    /// One past the last mapped logical bit.
    pub fn end_bit(&self) -> u64 {
        (self.logical_start as u64 + self.length as u64 - 1) * 8 + self.logical_stop_bit as u64 + 1
    }

    /// Byte-aligned on both sides: whole bytes map to whole bytes.
    pub fn byte_aligned(&self) -> bool {
        self.logical_start_bit == 0 && self.logical_stop_bit == 7 && self.physical_start_bit == 0
    }

    /// Physical bit address of logical bit `lb` (inside the mapping).
    pub fn physical_bit(&self, lb: u64) -> u64 {
        self.physical_start as u64 * 8 + self.physical_start_bit as u64 + (lb - self.first_bit())
    }
}
