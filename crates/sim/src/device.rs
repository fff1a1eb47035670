//! The contract between a virtual slave controller and the firmware model running behind it.
//!
//! The ESC core copies received RxPDO data into the object dictionary before a control step and
//! copies the mapped TxPDO entries out of it afterwards, exactly as a slave stack such as SOES
//! does. A device therefore never sees frames or byte offsets: it reads its commands and writes
//! its feedback by (index, subindex), and works whatever PDO mapping the master chose.

use crate::od::ObjectDictionary;

/// A CoE emergency a firmware raises (ETG.1000.6 / CiA 301): error code, error register
/// (0x1001) and five manufacturer-specific bytes. The ESC sends it through the mailbox.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Emergency {
    /// CiA 301 emergency error code (the protocol crate's `emergency` table names them).
    pub error_code: u16,
    /// The error register (0x1001) sent with the code.
    pub error_register: u8,
    /// Manufacturer-specific data bytes of the emergency message.
    pub data: [u8; 5],
}

/// A slave's firmware model.
pub trait DeviceApp: Send {
    /// Period of the firmware's control loop in nanoseconds (the Laelaps leg: 100 µs, 10 kHz).
    fn period_ns(&self) -> u64;

    /// One control step at the slave's local time `local_time_ns` (its DC clock, with drift).
    /// `outputs_valid` is true only in OP with outputs not timed out by the process-data
    /// watchdog; when false the firmware must put its actuators into their safe state
    /// (no torque) and ignore the commanded values.
    fn step(&mut self, od: &mut ObjectDictionary, local_time_ns: u64, outputs_valid: bool);

    /// Power-on reset (fault injection "reset slave", or the simulator starting).
    fn reset(&mut self, od: &mut ObjectDictionary);

    /// Inject a device-level fault (the simulator's `drive_fault`): `fault` names it, `axis`
    /// (1-based) says where. Devices without injectable faults refuse.
    fn inject_fault(&mut self, fault: &str, axis: usize) -> Result<(), String> {
        let _ = axis;
        Err(format!(
            "this device model has no injectable faults (got '{fault}')"
        ))
    }

    /// The oldest CoE emergency raised and not yet taken (the ESC drains them after each
    /// step and queues them in the mailbox).
    fn take_emergency(&mut self) -> Option<Emergency> {
        None
    }

    /// Named physical state for tests, plots and the simulator front (SI units).
    fn probe(&self) -> Vec<(&'static str, f64)> {
        Vec::new()
    }
}
