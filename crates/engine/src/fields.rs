//! Output variables as bit fields of the process image, and how one is merged into the bytes
//! around it. `Engine::write_output_fields` uses this so that writers of different variables
//! (Python's `Bus`, a native command thread) each change only their own bits.

/// One output variable's new value: `bit_length` (1..=64) bits starting `bit_offset` bits from the
/// start of the process image (EtherCAT bit order: bit 0 is the least significant bit of byte 0,
/// values little-endian); `raw` holds the bits, unsigned, upper bits beyond bit_length must be 0.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OutputField {
    /// Bits from the start of the process image to the field's first bit.
    pub bit_offset: usize,
    /// Width of the field in bits (1..=64).
    pub bit_length: u32,
    /// The new value's bits, unsigned, right-aligned.
    pub raw: u64,
}

impl OutputField {
    /// The image bytes the field touches, as `first..end`; `None` when the end overflows.
    pub fn byte_span(&self) -> Option<(usize, usize)> {
        let end_bit = self.bit_offset.checked_add(self.bit_length as usize)?;
        Some((self.bit_offset / 8, end_bit.div_ceil(8)))
    }

    /// Why the field is malformed (length out of 1..=64, `raw` wider than the field), if it is.
    pub fn form_error(&self) -> Option<String> {
        if !(1..=64).contains(&self.bit_length) {
            return Some(format!("bit length {} is not in 1..=64", self.bit_length));
        }
        if self.bit_length < 64 && self.raw >> self.bit_length != 0 {
            return Some(format!(
                "raw value {:#x} does not fit in {} bit(s)",
                self.raw, self.bit_length
            ));
        }
        if self.byte_span().is_none() {
            return Some("the bit offset plus length overflows".into());
        }
        None
    }

    /// Put the field's bits into `bytes`, whose first element is image byte `base`, leaving
    /// every other bit alone. The field must be well formed and lie inside `bytes`.
    pub fn apply(&self, bytes: &mut [u8], base: usize) {
        // The protocol crate's bit-field codec (EtherCAT bit order, no allocation).
        let inside = ether_ros_protocol::value::write_bits(
            bytes,
            self.bit_offset - base * 8,
            self.bit_length,
            self.raw,
        );
        debug_assert!(inside, "a well-formed field inside `bytes`");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field(bit_offset: usize, bit_length: u32, raw: u64) -> OutputField {
        OutputField {
            bit_offset,
            bit_length,
            raw,
        }
    }

    /// Reference: set the field bit by bit (EtherCAT order, little-endian).
    fn apply_bitwise(f: &OutputField, bytes: &mut [u8]) {
        for i in 0..f.bit_length as usize {
            let b = f.bit_offset + i;
            let v = (f.raw >> i) & 1 == 1;
            if v {
                bytes[b / 8] |= 1 << (b % 8);
            } else {
                bytes[b / 8] &= !(1 << (b % 8));
            }
        }
    }

    #[test]
    fn fields_land_on_their_bits_and_leave_the_neighbours_alone() {
        let cases = [
            field(0, 1, 1),
            field(13, 1, 0),
            field(5, 3, 0b101),
            field(7, 12, 0xABC),
            field(16, 16, 0x1234),
            field(3, 16, 0xBEEF),
            field(8, 32, 0xDEAD_BEEF),
            field(11, 32, 0x8000_0001),
            field(0, 64, 0x0123_4567_89AB_CDEF),
            field(5, 64, u64::MAX - 6),
        ];
        for background in [0x00u8, 0xFF, 0x5A] {
            for f in cases {
                let mut got = vec![background; 10];
                let mut want = got.clone();
                f.apply(&mut got, 0);
                apply_bitwise(&f, &mut want);
                assert_eq!(got, want, "{f:?} on {background:#x}");
            }
        }
    }

    #[test]
    fn aligned_fields_are_little_endian() {
        let mut bytes = [0u8; 8];
        field(16, 16, 0x1234).apply(&mut bytes, 0);
        field(32, 32, 0xDEAD_BEEF).apply(&mut bytes, 0);
        assert_eq!(bytes, [0, 0, 0x34, 0x12, 0xEF, 0xBE, 0xAD, 0xDE]);
        let mut bytes = [0u8; 8];
        field(0, 64, 0x0102_0304_0506_0708).apply(&mut bytes, 0);
        assert_eq!(bytes, 0x0102_0304_0506_0708u64.to_le_bytes());
    }

    #[test]
    fn base_shifts_the_window() {
        // Image bytes 4..7 held in a 3-byte window: bit 35 is bit 3 of window byte 0.
        let mut window = [0u8; 3];
        field(35, 3, 0b111).apply(&mut window, 4);
        assert_eq!(window, [0b0011_1000, 0, 0]);
        assert_eq!(field(35, 3, 0).byte_span(), Some((4, 5)));
        assert_eq!(field(39, 2, 0).byte_span(), Some((4, 6)));
        assert_eq!(field(8, 16, 0).byte_span(), Some((1, 3)));
    }

    #[test]
    fn malformed_fields_are_named() {
        assert!(field(0, 0, 0).form_error().unwrap().contains("1..=64"));
        assert!(field(0, 65, 0).form_error().unwrap().contains("1..=64"));
        assert!(field(0, 3, 8).form_error().unwrap().contains("0x8"));
        assert!(field(usize::MAX, 8, 0)
            .form_error()
            .unwrap()
            .contains("overflows"));
        assert_eq!(field(0, 64, u64::MAX).form_error(), None);
        assert_eq!(field(0, 3, 7).form_error(), None);
    }
}
