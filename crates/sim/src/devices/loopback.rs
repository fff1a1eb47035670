//! The generic firmware model for any ESI without a model of its own: every output (an
//! RxPDO-mapped entry) is copied to the input (a TxPDO-mapped entry) it is paired with; inputs
//! without a partner keep their value. The pairs come from the Python front
//! (`ether_ros.sim.spec.loopback_pairs`: the n-th output entry with the first free input entry
//! of the same type and size, in the ESI's PDO order), so the model knows nothing of the
//! device and works whatever PDO mapping the master chose.

use crate::device::DeviceApp;
use crate::od::ObjectDictionary;

/// Firmware period: fast enough that a looped-back value is back within a typical cycle.
const PERIOD_NS: u64 = 250_000;

/// One output → input link: (output index, subindex, input index, subindex).
pub type Link = (u16, u8, u16, u8);

pub struct Loopback {
    links: Vec<Link>,
    /// Scratch for one value, so a step allocates nothing after the first.
    value: Vec<u8>,
}

impl Loopback {
    pub fn new(links: &[Link]) -> Loopback {
        Loopback {
            links: links.to_vec(),
            value: Vec::new(),
        }
    }
}

impl DeviceApp for Loopback {
    fn period_ns(&self) -> u64 {
        PERIOD_NS
    }

    fn step(&mut self, od: &mut ObjectDictionary, _local_time_ns: u64, outputs_valid: bool) {
        if !outputs_valid {
            // No valid outputs (not OP, or the watchdog expired): inputs hold their last value.
            return;
        }
        for &(oi, os, ii, is) in &self.links {
            let Some(out) = od.get_bytes(oi, os) else {
                continue;
            };
            self.value.clear();
            self.value.extend_from_slice(out);
            od.set_bytes(ii, is, &self.value);
        }
    }

    fn reset(&mut self, _od: &mut ObjectDictionary) {}

    fn probe(&self) -> Vec<(&'static str, f64)> {
        vec![("links", self.links.len() as f64)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::od::{Access, Entry};

    fn entry(index: u16, subindex: u8, bits: u16) -> Entry {
        Entry {
            index,
            subindex,
            name: String::new(),
            data_type: 7,
            bit_length: bits,
            access: Access::ReadWrite,
            pdo_mappable: true,
            value: vec![0; (bits as usize).div_ceil(8)],
        }
    }

    #[test]
    fn valid_outputs_are_copied_and_held_otherwise() {
        let mut od = ObjectDictionary::new();
        for e in [
            entry(0x7000, 1, 32),
            entry(0x6000, 1, 32),
            entry(0x6000, 2, 16),
        ] {
            od.add_entry(e);
        }
        let mut app = Loopback::new(&[(0x7000, 1, 0x6000, 1)]);
        od.set_int(0x7000, 1, 0x1234_5678);
        od.set_int(0x6000, 2, 77);
        app.step(&mut od, 0, false);
        assert_eq!(od.get_int(0x6000, 1), 0, "not valid yet");
        app.step(&mut od, 0, true);
        assert_eq!(od.get_int(0x6000, 1), 0x1234_5678);
        od.set_int(0x7000, 1, 1);
        app.step(&mut od, 0, false);
        assert_eq!(
            od.get_int(0x6000, 1),
            0x1234_5678,
            "held without valid outputs"
        );
        assert_eq!(
            od.get_int(0x6000, 2),
            77,
            "an input without partner keeps its value"
        );
    }

    #[test]
    fn links_to_missing_entries_are_skipped() {
        let mut od = ObjectDictionary::new();
        od.add_entry(entry(0x6000, 1, 8));
        let mut app = Loopback::new(&[(0x7000, 1, 0x6000, 1), (0x7001, 1, 0x6001, 1)]);
        app.step(&mut od, 0, true);
        assert_eq!(od.get_int(0x6000, 1), 0);
    }
}
