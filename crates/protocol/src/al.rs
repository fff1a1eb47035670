//! The application layer (AL) state machine as the registers show it (ETG.1000.6 §6.4.1):
//! AL control (0x0120) and AL status (0x0130) carry the state in bits 0..=3 and the error
//! acknowledge / error indication in bit 4; AL status code (0x0134) says why a slave refused or
//! left a state. The texts of the codes are ours, after ETG.1000.6 table 11.

crate::named_constants! {
    /// States and bits, by name.
    pub const TABLE;
    /// INIT.
    pub const INIT: u8 = 0x01;
    /// PRE-OPERATIONAL.
    pub const PREOP: u8 = 0x02;
    /// BOOTSTRAP.
    pub const BOOT: u8 = 0x03;
    /// SAFE-OPERATIONAL.
    pub const SAFEOP: u8 = 0x04;
    /// OPERATIONAL.
    pub const OP: u8 = 0x08;
    /// Bits 0..=3: the state.
    pub const STATE_MASK: u8 = 0x0F;
    /// Bit 4: error indication (status) / error acknowledge (control).
    pub const ERROR: u8 = 0x10;
    /// AL control bit 5: device identification request.
    pub const ID_REQUEST: u8 = 0x20;
}

/// The five states in the order of the state machine.
pub const STATES: [u8; 5] = [INIT, PREOP, BOOT, SAFEOP, OP];

/// Name of the state in bits 0..=3 of `value` (`None` for a code that is no state).
pub fn state_name(value: u8) -> Option<&'static str> {
    Some(match value & STATE_MASK {
        INIT => "INIT",
        PREOP => "PREOP",
        BOOT => "BOOT",
        SAFEOP => "SAFEOP",
        OP => "OP",
        _ => return None,
    })
}

/// The state a name denotes (`"SAFEOP"`, also `"SAFE-OP"`, any case).
pub fn state_from_name(name: &str) -> Option<u8> {
    let upper = name.trim().to_ascii_uppercase().replace(['-', '_'], "");
    Some(match upper.as_str() {
        "INIT" => INIT,
        "PREOP" => PREOP,
        "BOOT" | "BOOTSTRAP" => BOOT,
        "SAFEOP" => SAFEOP,
        "OP" => OP,
        _ => return None,
    })
}

/// AL status (0x0130, u16) decoded: the state reached and the error indication.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AlStatus {
    /// Bits 0..=3.
    pub state: u8,
    /// Bit 4: the slave refused a requested state or left one; the code says why.
    pub error: bool,
}

impl AlStatus {
    /// Decode the AL status register.
    pub const fn decode(raw: u16) -> AlStatus {
        AlStatus {
            state: (raw as u8) & STATE_MASK,
            error: raw as u8 & ERROR != 0,
        }
    }

    /// Encode into the AL status register.
    pub const fn encode(self) -> u16 {
        (self.state & STATE_MASK) as u16 | if self.error { ERROR as u16 } else { 0 }
    }
}

/// AL control (0x0120) value that requests `state`, acknowledging an error indication if `ack`.
pub const fn control(state: u8, ack: bool) -> u16 {
    (state & STATE_MASK) as u16 | if ack { ERROR as u16 } else { 0 }
}

crate::coded_texts! {
    /// AL status codes by name.
    pub const CODES: u16;
    /// AL status codes with their texts.
    pub const CODE_TEXTS;
    /// No error.
    NO_ERROR = 0x0000, "no error";
    /// Unspecified error.
    UNSPECIFIED = 0x0001, "unspecified error";
    /// No memory.
    NO_MEMORY = 0x0002, "no memory";
    /// Invalid device setup.
    INVALID_DEVICE_SETUP = 0x0003, "invalid device setup";
    /// Invalid requested state change.
    INVALID_REQUESTED_STATE = 0x0011, "invalid requested state change";
    /// Unknown requested state.
    UNKNOWN_REQUESTED_STATE = 0x0012, "unknown requested state";
    /// Bootstrap not supported.
    BOOTSTRAP_NOT_SUPPORTED = 0x0013, "bootstrap state not supported";
    /// No valid firmware.
    NO_VALID_FIRMWARE = 0x0014, "no valid firmware";
    /// Invalid mailbox configuration (bootstrap).
    INVALID_BOOT_MAILBOX_CONFIG = 0x0015, "invalid mailbox configuration (bootstrap)";
    /// Invalid mailbox configuration.
    INVALID_MAILBOX_CONFIG = 0x0016, "invalid mailbox configuration";
    /// Invalid SyncManager configuration.
    INVALID_SM_CONFIG = 0x0017, "invalid SyncManager configuration";
    /// No valid inputs available.
    NO_VALID_INPUTS = 0x0018, "no valid inputs available";
    /// No valid outputs.
    NO_VALID_OUTPUTS = 0x0019, "no valid outputs";
    /// Synchronization error.
    SYNCHRONIZATION_ERROR = 0x001A, "synchronization error";
    /// SyncManager watchdog.
    SM_WATCHDOG = 0x001B, "SyncManager watchdog expired (no process data from the master)";
    /// Invalid SyncManager types.
    INVALID_SM_TYPES = 0x001C, "invalid SyncManager types";
    /// Invalid output configuration.
    INVALID_OUTPUT_CONFIG = 0x001D, "invalid output configuration";
    /// Invalid input configuration.
    INVALID_INPUT_CONFIG = 0x001E, "invalid input configuration";
    /// Invalid watchdog configuration.
    INVALID_WATCHDOG_CONFIG = 0x001F, "invalid watchdog configuration";
    /// Slave needs cold start.
    SLAVE_NEEDS_COLD_START = 0x0020, "slave needs a cold start";
    /// Slave needs INIT.
    SLAVE_NEEDS_INIT = 0x0021, "slave needs INIT";
    /// Slave needs PREOP.
    SLAVE_NEEDS_PREOP = 0x0022, "slave needs PREOP";
    /// Slave needs SAFEOP.
    SLAVE_NEEDS_SAFEOP = 0x0023, "slave needs SAFEOP";
    /// Invalid input mapping.
    INVALID_INPUT_MAPPING = 0x0024, "invalid input mapping";
    /// Invalid output mapping.
    INVALID_OUTPUT_MAPPING = 0x0025, "invalid output mapping";
    /// Inconsistent settings.
    INCONSISTENT_SETTINGS = 0x0026, "inconsistent settings";
    /// Free-run not supported.
    FREERUN_NOT_SUPPORTED = 0x0027, "free-run mode not supported";
    /// Synchronization mode not supported.
    SYNCMODE_NOT_SUPPORTED = 0x0028, "synchronization mode not supported";
    /// Free-run needs 3-buffer mode.
    FREERUN_NEEDS_3_BUFFER = 0x0029, "free-run needs 3-buffer mode";
    /// Background watchdog.
    BACKGROUND_WATCHDOG = 0x002A, "background watchdog";
    /// No valid inputs and outputs.
    NO_VALID_INPUTS_AND_OUTPUTS = 0x002B, "no valid inputs and outputs";
    /// Fatal sync error.
    FATAL_SYNC_ERROR = 0x002C, "fatal synchronization error";
    /// No sync error.
    NO_SYNC_ERROR = 0x002D, "no SYNC error";
    /// Cycle time too small.
    CYCLE_TIME_TOO_SMALL = 0x002E, "cycle time too small";
    /// Invalid DC SYNC configuration.
    INVALID_DC_SYNC_CONFIG = 0x0030, "invalid DC SYNC configuration";
    /// Invalid DC latch configuration.
    INVALID_DC_LATCH_CONFIG = 0x0031, "invalid DC latch configuration";
    /// PLL error.
    PLL_ERROR = 0x0032, "PLL error (DC not locked)";
    /// DC SYNC I/O error.
    DC_SYNC_IO_ERROR = 0x0033, "DC SYNC I/O error";
    /// DC SYNC timeout.
    DC_SYNC_TIMEOUT = 0x0034, "DC SYNC timeout";
    /// DC invalid SYNC cycle time.
    DC_INVALID_SYNC_CYCLE_TIME = 0x0035, "invalid DC SYNC cycle time";
    /// DC SYNC0 cycle time.
    DC_SYNC0_CYCLE_TIME = 0x0036, "DC SYNC0 cycle time does not fit the application";
    /// DC SYNC1 cycle time.
    DC_SYNC1_CYCLE_TIME = 0x0037, "DC SYNC1 cycle time does not fit the application";
    /// Mailbox AoE.
    MBX_AOE = 0x0041, "mailbox error (AoE)";
    /// Mailbox EoE.
    MBX_EOE = 0x0042, "mailbox error (EoE)";
    /// Mailbox CoE (0x0043; the copy in the old `wire` crate said 0x0042, which is EoE).
    MBX_COE = 0x0043, "mailbox error (CoE)";
    /// Mailbox FoE.
    MBX_FOE = 0x0044, "mailbox error (FoE)";
    /// Mailbox SoE.
    MBX_SOE = 0x0045, "mailbox error (SoE)";
    /// Mailbox VoE.
    MBX_VOE = 0x004F, "mailbox error (VoE)";
    /// EEPROM no access.
    EEPROM_NO_ACCESS = 0x0050, "EEPROM not accessible";
    /// EEPROM error.
    EEPROM_ERROR = 0x0051, "EEPROM error";
    /// External hardware not ready.
    EXTERNAL_HARDWARE_NOT_READY = 0x0052, "external hardware not ready";
    /// Slave restarted locally.
    SLAVE_RESTARTED_LOCALLY = 0x0060, "slave restarted locally";
    /// Device identification value updated.
    DEVICE_ID_UPDATED = 0x0061, "device identification value updated";
    /// Detected module ident list does not match.
    MODULE_ID_MISMATCH = 0x0070, "detected module ident list does not match";
    /// Application controller available.
    APPLICATION_CONTROLLER = 0x00F0, "application controller not available";
}

/// Codes from here on are the vendor's own.
pub const FIRST_VENDOR_CODE: u16 = 0x8000;

/// Words for an AL status code into `out` (vendor codes and unknown codes say so).
pub fn write_code_text(code: u16, out: &mut impl core::fmt::Write) -> core::fmt::Result {
    match crate::lookup(CODE_TEXTS, code) {
        Some(text) => out.write_str(text),
        None if code >= FIRST_VENDOR_CODE => write!(out, "vendor-specific error 0x{code:04X}"),
        None => write!(out, "unknown AL status code 0x{code:04X}"),
    }
}

/// Words for an AL status code.
pub fn code_text(code: u16) -> String {
    let mut s = String::new();
    let _ = write_code_text(code, &mut s);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_register_round_trips() {
        let s = AlStatus::decode(0x0014);
        assert_eq!(
            s,
            AlStatus {
                state: SAFEOP,
                error: true
            }
        );
        assert_eq!(s.encode(), 0x0014);
        assert_eq!(control(OP, false), 0x0008);
        assert_eq!(control(PREOP, true), 0x0012);
        assert_eq!(state_name(0x18), Some("OP"));
        assert_eq!(state_name(0x05), None);
        assert_eq!(state_from_name("safe-op"), Some(SAFEOP));
    }

    #[test]
    fn mailbox_codes_follow_etg_1000_6_table_11() {
        // AoE, EoE, CoE, FoE, SoE in protocol order from 0x0041; VoE is 0x004F.
        assert_eq!(
            [MBX_AOE, MBX_EOE, MBX_COE, MBX_FOE, MBX_SOE],
            [0x41, 0x42, 0x43, 0x44, 0x45]
        );
        assert_eq!(code_text(MBX_COE), "mailbox error (CoE)");
    }

    #[test]
    fn texts_of_known_vendor_and_unknown_codes() {
        assert_eq!(
            code_text(0x001B),
            "SyncManager watchdog expired (no process data from the master)"
        );
        assert_eq!(code_text(0x8001), "vendor-specific error 0x8001");
        assert_eq!(code_text(0x0099), "unknown AL status code 0x0099");
        let mut codes: Vec<u16> = CODE_TEXTS.iter().map(|(c, _)| *c).collect();
        codes.dedup();
        assert_eq!(codes.len(), CODE_TEXTS.len(), "every code once, in order");
    }
}
