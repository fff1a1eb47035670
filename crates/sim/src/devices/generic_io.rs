//! A generic digital/analog I/O slave with its inputs wired back to its outputs.
//!
//! Object layout (the ESI `devices/generic_io.xml` must match it exactly):
//!
//! | Index  | Sub  | Name            | Type  | Bits | Direction    |
//! |--------|------|-----------------|-------|------|--------------|
//! | 0x7000 | 0x01 | DigitalOutput1  | BOOL  | 1    | RxPDO (out)  |
//! | 0x7000 | 0x02 | DigitalOutput2  | BOOL  | 1    | RxPDO (out)  |
//! | 0x7000 | ...  | ...             | BOOL  | 1    | RxPDO (out)  |
//! | 0x7000 | 0x08 | DigitalOutput8  | BOOL  | 1    | RxPDO (out)  |
//! | 0x7010 | 0x01 | AnalogOutput1   | INT16 | 16   | RxPDO (out)  |
//! | 0x7010 | 0x02 | AnalogOutput2   | INT16 | 16   | RxPDO (out)  |
//! | 0x6000 | 0x01 | DigitalInput1   | BOOL  | 1    | TxPDO (in)   |
//! | 0x6000 | ...  | ...             | BOOL  | 1    | TxPDO (in)   |
//! | 0x6000 | 0x08 | DigitalInput8   | BOOL  | 1    | TxPDO (in)   |
//! | 0x6010 | 0x01 | AnalogInput1    | INT16 | 16   | TxPDO (in)   |
//! | 0x6010 | 0x02 | AnalogInput2    | INT16 | 16   | TxPDO (in)   |
//!
//! Object names: 0x7000 "DigitalOutputs", 0x7010 "AnalogOutputs", 0x6000 "DigitalInputs",
//! 0x6010 "AnalogInputs" (records; subindex 0 holds the number of entries, UINT8). Process data:
//! 1 byte of digital outputs + 4 bytes of analog outputs (5 bytes) and the same 5 bytes of
//! inputs.
//!
//! Loopback model (period 1 ms):
//! - `DigitalInputN = DigitalOutputN` of the previous firmware period;
//! - `AnalogInputN` follows `AnalogOutputN` through a first-order lag (time constant
//!   `lag_ms`, default 10 ms) plus a deterministic triangle dither of ±`dither_counts`
//!   (default 2) with a 64 ms period, so a reader can tell a live input from a frozen one.
//! - Outputs not valid (not OP or watchdog): the outputs are taken as 0 (safe state), so the
//!   digital inputs drop to 0 and the analog inputs decay towards 0 (dither still on).

use crate::device::DeviceApp;
use crate::od::ObjectDictionary;

/// Firmware period: 1 ms.
pub const PERIOD_NS: u64 = 1_000_000;
/// Period of the triangle dither on the analog inputs.
const DITHER_PERIOD_NS: u64 = 64_000_000;

pub struct GenericIo {
    lag_s: f64,
    dither_counts: f64,
    analog: [f64; 2],
    digital: u8,
    last_time_ns: Option<u64>,
}

impl GenericIo {
    /// Parameters: `lag_ms` (>= 0) and `dither_counts` (>= 0).
    pub fn from_params(params: &[(String, f64)]) -> Result<Self, String> {
        let mut io = Self {
            lag_s: 0.010,
            dither_counts: 2.0,
            analog: [0.0; 2],
            digital: 0,
            last_time_ns: None,
        };
        for (name, value) in params {
            if !value.is_finite() || *value < 0.0 {
                return Err(format!(
                    "generic_io: parameter '{name}' must be a number >= 0, got {value}"
                ));
            }
            match name.as_str() {
                "lag_ms" => io.lag_s = value / 1000.0,
                "dither_counts" => io.dither_counts = *value,
                other => {
                    return Err(format!(
                        "generic_io: unknown parameter '{other}' (known: lag_ms, dither_counts)"
                    ))
                }
            }
        }
        Ok(io)
    }

    fn dither(&self, local_time_ns: u64) -> f64 {
        // Triangle from -1 to 1 and back over one period.
        let phase = (local_time_ns % DITHER_PERIOD_NS) as f64 / DITHER_PERIOD_NS as f64;
        let tri = if phase < 0.5 {
            4.0 * phase - 1.0
        } else {
            3.0 - 4.0 * phase
        };
        self.dither_counts * tri
    }
}

impl DeviceApp for GenericIo {
    fn period_ns(&self) -> u64 {
        PERIOD_NS
    }

    fn step(&mut self, od: &mut ObjectDictionary, local_time_ns: u64, outputs_valid: bool) {
        let dt = match self.last_time_ns {
            Some(last) if local_time_ns > last => (local_time_ns - last) as f64 * 1e-9,
            Some(_) => 0.0,
            None => PERIOD_NS as f64 * 1e-9,
        };
        self.last_time_ns = Some(local_time_ns);
        let (digital, analog_out) = if outputs_valid {
            let mut bits = 0u8;
            for i in 0..8u8 {
                if od.get_bool(0x7000, i + 1) {
                    bits |= 1 << i;
                }
            }
            (
                bits,
                [od.get_int(0x7010, 1) as f64, od.get_int(0x7010, 2) as f64],
            )
        } else {
            (0, [0.0; 2])
        };
        // Exact first-order lag over dt (stable for any step length).
        let f = if self.lag_s > 0.0 {
            1.0 - (-dt / self.lag_s).exp()
        } else {
            1.0
        };
        for (state, target) in self.analog.iter_mut().zip(analog_out) {
            *state += f * (target - *state);
        }
        // The digital inputs show the outputs as they were before this step (one period late).
        let shown = self.digital;
        self.digital = digital;
        for i in 0..8u8 {
            od.set_int(0x6000, i + 1, i64::from((shown >> i) & 1));
        }
        let dither = self.dither(local_time_ns);
        for (i, state) in self.analog.iter().enumerate() {
            let v = (state + dither).round().clamp(-32768.0, 32767.0) as i64;
            od.set_int(0x6010, i as u8 + 1, v);
        }
    }

    fn reset(&mut self, od: &mut ObjectDictionary) {
        self.analog = [0.0; 2];
        self.digital = 0;
        self.last_time_ns = None;
        for i in 0..8u8 {
            od.set_int(0x6000, i + 1, 0);
        }
        od.set_int(0x6010, 1, 0);
        od.set_int(0x6010, 2, 0);
    }

    fn probe(&self) -> Vec<(&'static str, f64)> {
        vec![
            ("digital_outputs", f64::from(self.digital)),
            ("analog_1", self.analog[0]),
            ("analog_2", self.analog[1]),
        ]
    }
}

/// Build the generic I/O dictionary (the tests build a fresh one to check it).
#[cfg(test)]
pub fn object_dictionary() -> ObjectDictionary {
    use crate::od::{dtype, Access};
    let mut od = ObjectDictionary::new();
    let objects: [(u16, &str, &str, u16, u16, u8, Access); 4] = [
        (
            0x7000,
            "DigitalOutputs",
            "DigitalOutput",
            dtype::BOOL,
            1,
            8,
            Access::ReadWrite,
        ),
        (
            0x7010,
            "AnalogOutputs",
            "AnalogOutput",
            dtype::INT16,
            16,
            2,
            Access::ReadWrite,
        ),
        (
            0x6000,
            "DigitalInputs",
            "DigitalInput",
            dtype::BOOL,
            1,
            8,
            Access::ReadOnly,
        ),
        (
            0x6010,
            "AnalogInputs",
            "AnalogInput",
            dtype::INT16,
            16,
            2,
            Access::ReadOnly,
        ),
    ];
    for (index, object_name, entry_name, data_type, bits, count, access) in objects {
        let entries: Vec<_> = (1..=count)
            .map(|sub| (sub, format!("{entry_name}{sub}"), data_type, bits))
            .collect();
        od.add_record(index, object_name, access, &entries);
    }
    od
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(io: &mut GenericIo, od: &mut ObjectDictionary, from_ms: u64, to_ms: u64, valid: bool) {
        for ms in from_ms..to_ms {
            io.step(od, ms * PERIOD_NS, valid);
        }
    }

    #[test]
    fn digital_inputs_follow_outputs_one_period_late() {
        let mut od = object_dictionary();
        let mut io = GenericIo::from_params(&[]).unwrap();
        od.set_int(0x7000, 1, 1);
        od.set_int(0x7000, 8, 1);
        io.step(&mut od, 0, true);
        assert_eq!(od.get_int(0x6000, 1), 0);
        io.step(&mut od, PERIOD_NS, true);
        assert_eq!(od.get_int(0x6000, 1), 1);
        assert_eq!(od.get_int(0x6000, 8), 1);
        assert_eq!(od.get_int(0x6000, 2), 0);
        run(&mut io, &mut od, 2, 4, false);
        assert_eq!(od.get_int(0x6000, 1), 0, "safe state clears the loopback");
    }

    #[test]
    fn analog_inputs_lag_the_outputs_and_dither() {
        let mut od = object_dictionary();
        let mut io = GenericIo::from_params(&[("lag_ms".into(), 10.0)]).unwrap();
        od.set_int(0x7010, 1, 10_000);
        od.set_int(0x7010, 2, -2_000);
        run(&mut io, &mut od, 0, 11, true);
        let after_one_tau = od.get_int(0x6010, 1);
        assert!((6_000..7_000).contains(&after_one_tau), "{after_one_tau}");
        run(&mut io, &mut od, 11, 200, true);
        assert!((od.get_int(0x6010, 1) - 10_000).abs() <= 2);
        assert!((od.get_int(0x6010, 2) + 2_000).abs() <= 2);
        let mut seen = std::collections::BTreeSet::new();
        for ms in 200..264 {
            io.step(&mut od, ms * PERIOD_NS, true);
            seen.insert(od.get_int(0x6010, 1));
        }
        assert!(seen.len() >= 4, "dither visible: {seen:?}");
        run(&mut io, &mut od, 264, 400, false);
        assert!(
            od.get_int(0x6010, 1).abs() <= 2,
            "decays to 0 when outputs are not valid"
        );
    }

    #[test]
    fn bad_parameters_are_named() {
        let err = GenericIo::from_params(&[("gain".into(), 1.0)])
            .err()
            .unwrap();
        assert!(err.contains("'gain'"), "{err}");
        let err = GenericIo::from_params(&[("lag_ms".into(), -1.0)])
            .err()
            .unwrap();
        assert!(err.contains("'lag_ms'"), "{err}");
    }
}
