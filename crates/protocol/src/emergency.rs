//! Emergency error codes (CiA 301 classes, refined for drives by CiA 402 / IEC 61800-7-201,
//! and ETG.1000.6's EtherCAT state machine codes) with their texts: what a slave reports in a
//! CoE emergency message and a drive in 0x603F. A code missing from the table is described by
//! its class (0xFFF0, then 0xFF00, then 0xF000 of it); 0xFF00..=0xFFFF are the manufacturer's.

crate::named_constants! {
    /// The codes the project raises itself, by name.
    pub const TABLE;
    /// Error reset or no error.
    pub const NO_ERROR: u16 = 0x0000;
    /// ETG.1000.6: the transition PREOP → SAFEOP failed.
    pub const PREOP_TO_SAFEOP_FAILED: u16 = 0xA000;
    /// ETG.1000.6: the transition SAFEOP → OP failed.
    pub const SAFEOP_TO_OP_FAILED: u16 = 0xA001;
    /// CiA 301 error register (0x1001) bit 0: generic error.
    pub const ERROR_REGISTER_GENERIC: u8 = 0x01;
}

/// Codes with their texts, in ascending order.
pub const CODES: &[(u16, &str)] = &[
    (0x0000, "no error"),
    (0x1000, "generic error"),
    (0x2000, "current"),
    (0x2100, "current on the device input side"),
    (0x2110, "short circuit / earth leakage (input)"),
    (0x2200, "current inside the device"),
    (0x2211, "internal current no. 1"),
    (0x2214, "over-current in the device"),
    (0x2220, "continuous over-current (device)"),
    (0x2230, "short circuit / earth leakage (device)"),
    (0x2300, "current on the device output side"),
    (0x2310, "continuous over-current"),
    (0x2311, "continuous over-current no. 1"),
    (0x2312, "continuous over-current no. 2"),
    (0x2320, "short circuit / earth leakage (motor side)"),
    (0x2330, "earth leakage (motor side)"),
    (0x2340, "short circuit (motor side)"),
    (0x3000, "voltage"),
    (0x3100, "mains voltage"),
    (0x3110, "mains over-voltage"),
    (0x3120, "mains under-voltage"),
    (0x3130, "phase failure"),
    (0x3200, "voltage inside the device"),
    (0x3210, "DC link over-voltage"),
    (0x3220, "DC link under-voltage"),
    (0x3230, "load error"),
    (0x3300, "output voltage"),
    (0x3310, "output over-voltage"),
    (0x4000, "temperature"),
    (0x4100, "ambient temperature"),
    (0x4110, "excess ambient temperature"),
    (0x4200, "device temperature"),
    (0x4210, "excess temperature in the device"),
    (0x4300, "drive temperature"),
    (0x4310, "excess drive temperature"),
    (0x4400, "supply temperature"),
    (0x5000, "device hardware"),
    (0x5100, "supply (device hardware)"),
    (0x5112, "supply low voltage (+24 V)"),
    (0x5200, "control (device hardware)"),
    (0x5210, "measurement circuit"),
    (0x5400, "power section"),
    (0x5410, "output stages"),
    (0x5441, "contact 1 (safe torque off)"),
    (0x5500, "data storage"),
    (0x5530, "flash memory"),
    (0x6000, "device software"),
    (0x6100, "internal software"),
    (0x6200, "user software"),
    (0x6300, "data set"),
    (0x6320, "parameter error"),
    (0x7000, "additional modules"),
    (0x7100, "power (additional modules)"),
    (0x7110, "brake chopper"),
    (0x7120, "motor"),
    (0x7121, "motor blocked"),
    (0x7122, "motor error or commutation malfunction"),
    (0x7200, "measurement circuit (additional modules)"),
    (0x7300, "sensor"),
    (0x7301, "tacho fault"),
    (0x7303, "resolver 1 fault"),
    (0x7304, "resolver 2 fault"),
    (0x7305, "incremental encoder 1 fault"),
    (0x7306, "incremental encoder 2 fault"),
    (0x7310, "speed sensor"),
    (0x7320, "position sensor"),
    (0x7500, "communication (additional modules)"),
    (0x7600, "data storage (additional modules)"),
    (0x8000, "monitoring"),
    (0x8100, "communication"),
    (0x8110, "CAN overrun"),
    (0x8120, "CAN in error passive mode"),
    (0x8130, "life guard or heartbeat error"),
    (0x8140, "recovered from bus off"),
    (0x8200, "protocol error"),
    (0x8210, "PDO not processed due to length error"),
    (0x8220, "PDO length exceeded"),
    (0x8300, "torque control"),
    (0x8311, "excess torque"),
    (0x8400, "velocity (speed) controller"),
    (0x8500, "position controller"),
    (0x8600, "positioning controller"),
    (0x8611, "following error"),
    (0x8612, "reference limit"),
    (0x8700, "sync controller"),
    (0x8800, "winding controller"),
    (0x9000, "external error"),
    (
        0xA000,
        "EtherCAT state machine: transition PREOP to SAFEOP failed",
    ),
    (
        0xA001,
        "EtherCAT state machine: transition SAFEOP to OP failed",
    ),
    (0xF000, "additional functions"),
    (0xF001, "deceleration"),
    (0xF002, "sub-synchronous run"),
    (0xF003, "stroke operation"),
    (0xF004, "control"),
    (0xFF00, "manufacturer specific"),
];

/// First code of the EtherCAT state machine codes: they are exact meanings (a failed
/// transition), not classes, so no other code falls back to them.
const ETHERCAT_STATE_MACHINE: u16 = 0xA000;
/// First manufacturer-specific code.
const MANUFACTURER: u16 = 0xFF00;

/// The text of an emergency error code: the exact entry, else its class (`0x2399`: "current on
/// the device output side"), else "unknown error".
pub fn text(code: u16) -> &'static str {
    if let Some(t) = crate::lookup(CODES, code) {
        return t;
    }
    if code >= MANUFACTURER {
        return "manufacturer specific";
    }
    if code & 0xF000 == ETHERCAT_STATE_MACHINE {
        return "EtherCAT state machine";
    }
    for mask in [0xFFF0, 0xFF00, 0xF000] {
        let class = code & mask;
        if class != 0 {
            if let Some(t) = crate::lookup(CODES, class) {
                return t;
            }
        }
    }
    "unknown error"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_codes_classes_and_manufacturer_codes() {
        assert_eq!(text(0x2310), "continuous over-current");
        assert_eq!(text(0x2399), "current on the device output side");
        assert_eq!(text(0x4999), "temperature");
        assert_eq!(
            text(0xA000),
            "EtherCAT state machine: transition PREOP to SAFEOP failed"
        );
        assert_eq!(text(0xA010), "EtherCAT state machine");
        assert_eq!(text(0xFF42), "manufacturer specific");
        assert_eq!(text(0x0042), "unknown error");
        assert!(
            CODES.windows(2).all(|w| w[0].0 < w[1].0),
            "ascending, each code once"
        );
    }
}
