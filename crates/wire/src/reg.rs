//! ESC register map (ETG.1000.4 / Beckhoff ESC datasheet section II). Addresses are offsets in
//! the slave's 64 KiB physical memory; process-data RAM starts at `PDRAM`.

/// ESC type, revision, build (0x0000..=0x0005).
pub const TYPE: u16 = 0x0000;
/// Number of supported FMMUs (u8).
pub const FMMU_COUNT: u16 = 0x0004;
/// Number of supported SyncManagers (u8).
pub const SM_COUNT: u16 = 0x0005;
/// Process-data RAM size in KiB (u8).
pub const RAM_SIZE: u16 = 0x0006;
/// Port descriptor (u8).
pub const PORT_DESC: u16 = 0x0007;
/// ESC features supported (u16): bit 2 = DC supported, bit 3 = 64-bit DC.
pub const FEATURES: u16 = 0x0008;
/// Configured station address (u16).
pub const STATION_ADDRESS: u16 = 0x0010;
/// Configured station alias (u16), loaded from SII word 4.
pub const STATION_ALIAS: u16 = 0x0012;
/// DL control (u32): loop control per port.
pub const DL_CONTROL: u16 = 0x0100;
/// DL status (u16): link and loop status per port.
pub const DL_STATUS: u16 = 0x0110;
/// AL control (u16): requested state + error acknowledge (bit 4).
pub const AL_CONTROL: u16 = 0x0120;
/// AL status (u16): current state + error indication (bit 4).
pub const AL_STATUS: u16 = 0x0130;
/// AL status code (u16).
pub const AL_STATUS_CODE: u16 = 0x0134;
/// PDI control (u8).
pub const PDI_CONTROL: u16 = 0x0140;
/// ESC configuration (u8).
pub const ESC_CONFIG: u16 = 0x0141;
/// Event mask ECAT (u16).
pub const ECAT_EVENT_MASK: u16 = 0x0200;
/// Event request AL (u32).
pub const AL_EVENT_REQUEST: u16 = 0x0220;
/// RX error counters (0x0300..=0x030D).
pub const RX_ERROR_COUNTER: u16 = 0x0300;
/// Watchdog divider (u16), in 40 ns units minus 2.
pub const WATCHDOG_DIVIDER: u16 = 0x0400;
/// Watchdog time PDI (u16).
pub const WATCHDOG_TIME_PDI: u16 = 0x0410;
/// Watchdog time process data (u16), in divider units.
pub const WATCHDOG_TIME_PD: u16 = 0x0420;
/// Watchdog status process data (u16): bit 0 = 1 while not expired.
pub const WATCHDOG_STATUS_PD: u16 = 0x0440;
/// Watchdog counter process data (u8).
pub const WATCHDOG_COUNTER_PD: u16 = 0x0442;
/// SII EEPROM configuration (u8): bit 0 = PDI has access.
pub const SII_CONFIG: u16 = 0x0500;
/// SII EEPROM PDI access state (u8).
pub const SII_PDI_ACCESS: u16 = 0x0501;
/// SII control/status (u16): bit 8 read, 9 write, 10 reload, bit 6 read size (1 = 8 bytes),
/// bit 13 checksum error, bit 14 error command, bit 15 busy.
pub const SII_CONTROL: u16 = 0x0502;
/// SII address (u32, word address).
pub const SII_ADDRESS: u16 = 0x0504;
/// SII data (4 or 8 bytes).
pub const SII_DATA: u16 = 0x0508;
/// First FMMU; each FMMU is 16 bytes.
pub const FMMU0: u16 = 0x0600;
pub const FMMU_LEN: u16 = 16;
/// First SyncManager; each SM is 8 bytes: start (u16), length (u16), control (u8),
/// status (u8), activate (u8), PDI control (u8).
pub const SM0: u16 = 0x0800;
pub const SM_LEN: u16 = 8;
/// DC: port receive times, 4 x u32 (port 0 write latches all four).
pub const DC_RECEIVE_TIME_PORT0: u16 = 0x0900;
/// DC: local system time (u64). A write compares with the local time and drives the drift
/// control loop instead of setting the clock.
pub const DC_SYSTEM_TIME: u16 = 0x0910;
/// DC: receive time of the processing unit (u64).
pub const DC_RECEIVE_TIME_PU: u16 = 0x0918;
/// DC: system time offset (u64).
pub const DC_SYSTEM_TIME_OFFSET: u16 = 0x0920;
/// DC: system time delay (u32), propagation delay from the reference clock.
pub const DC_SYSTEM_TIME_DELAY: u16 = 0x0928;
/// DC: system time difference (u32): bit 31 sign, bits 0..=30 magnitude in ns.
pub const DC_SYSTEM_TIME_DIFF: u16 = 0x092C;
/// DC: speed counter start (u16).
pub const DC_SPEED_COUNTER_START: u16 = 0x0930;
/// DC: time difference filter depth (u8).
pub const DC_FILTER_DEPTH: u16 = 0x0934;
/// DC: cyclic unit control (u8).
pub const DC_CYCLIC_UNIT_CONTROL: u16 = 0x0980;
/// DC: activation (u8): bit 0 cyclic operation, bit 1 SYNC0, bit 2 SYNC1.
pub const DC_ACTIVATION: u16 = 0x0981;
/// DC: SYNC0 status (u8).
pub const DC_SYNC0_STATUS: u16 = 0x098E;
/// DC: start time of cyclic operation (u64, system time).
pub const DC_START_TIME: u16 = 0x0990;
/// DC: SYNC0 cycle time (u32, ns).
pub const DC_SYNC0_CYCLE: u16 = 0x09A0;
/// DC: SYNC1 cycle time (u32, ns).
pub const DC_SYNC1_CYCLE: u16 = 0x09A4;
/// Start of process-data RAM.
pub const PDRAM: u16 = 0x1000;

/// AL states as in AL control/status bits 0..=3.
pub mod al {
    pub const INIT: u8 = 0x01;
    pub const PREOP: u8 = 0x02;
    pub const BOOT: u8 = 0x03;
    pub const SAFEOP: u8 = 0x04;
    pub const OP: u8 = 0x08;
    /// Error indication (status) / acknowledge (control).
    pub const ERROR: u8 = 0x10;

    pub fn name(state: u8) -> &'static str {
        match state & 0x0f {
            INIT => "INIT",
            PREOP => "PREOP",
            BOOT => "BOOT",
            SAFEOP => "SAFEOP",
            OP => "OP",
            _ => "UNKNOWN",
        }
    }
}

/// AL status codes (ETG.1000.6 table 11) the simulator raises and the master explains.
pub mod al_code {
    pub const NO_ERROR: u16 = 0x0000;
    pub const UNSPECIFIED: u16 = 0x0001;
    pub const INVALID_REQUESTED_STATE: u16 = 0x0011;
    pub const UNKNOWN_REQUESTED_STATE: u16 = 0x0012;
    pub const BOOTSTRAP_NOT_SUPPORTED: u16 = 0x0013;
    pub const INVALID_MAILBOX_CONFIG: u16 = 0x0016;
    pub const INVALID_SM_CONFIG: u16 = 0x0017;
    pub const NO_VALID_INPUTS: u16 = 0x0018;
    pub const NO_VALID_OUTPUTS: u16 = 0x0019;
    pub const SYNCHRONIZATION_ERROR: u16 = 0x001A;
    pub const SM_WATCHDOG: u16 = 0x001B;
    pub const INVALID_SM_TYPES: u16 = 0x001C;
    pub const INVALID_OUTPUT_CONFIG: u16 = 0x001D;
    pub const INVALID_INPUT_CONFIG: u16 = 0x001E;
    pub const INVALID_WATCHDOG_CONFIG: u16 = 0x001F;
    pub const SLAVE_NEEDS_COLD_START: u16 = 0x0020;
    pub const SLAVE_NEEDS_INIT: u16 = 0x0021;
    pub const SLAVE_NEEDS_PREOP: u16 = 0x0022;
    pub const SLAVE_NEEDS_SAFEOP: u16 = 0x0023;
    pub const INVALID_INPUT_MAPPING: u16 = 0x0024;
    pub const INVALID_OUTPUT_MAPPING: u16 = 0x0025;
    pub const INCONSISTENT_SETTINGS: u16 = 0x0026;
    pub const FREERUN_NOT_SUPPORTED: u16 = 0x0027;
    pub const SYNCMODE_NOT_SUPPORTED: u16 = 0x0028;
    pub const INVALID_DC_SYNC_CONFIG: u16 = 0x0030;
    pub const INVALID_DC_LATCH_CONFIG: u16 = 0x0031;
    pub const PLL_ERROR: u16 = 0x0032;
    pub const DC_SYNC_IO_ERROR: u16 = 0x0033;
    pub const DC_SYNC_TIMEOUT: u16 = 0x0034;
    pub const DC_INVALID_SYNC_CYCLE_TIME: u16 = 0x0035;
    pub const MBX_COE: u16 = 0x0042;
    pub const EEPROM_NO_ACCESS: u16 = 0x0050;
    pub const EEPROM_ERROR: u16 = 0x0051;
}

/// Mailbox header types (ETG.1000.4 table 29).
pub mod mbx {
    pub const HEADER_LEN: usize = 6;
    pub const TYPE_ERR: u8 = 0x00;
    pub const TYPE_AOE: u8 = 0x01;
    pub const TYPE_EOE: u8 = 0x02;
    pub const TYPE_COE: u8 = 0x03;
    pub const TYPE_FOE: u8 = 0x04;
    pub const TYPE_SOE: u8 = 0x05;
    pub const TYPE_VOE: u8 = 0x0f;
}

/// SII EEPROM word addresses and category types (ETG.2010).
pub mod sii {
    pub const PDI_CONTROL: u16 = 0x0000;
    pub const CONFIGURED_ALIAS: u16 = 0x0004;
    pub const CHECKSUM: u16 = 0x0007;
    pub const VENDOR_ID: u16 = 0x0008;
    pub const PRODUCT_CODE: u16 = 0x000A;
    pub const REVISION: u16 = 0x000C;
    pub const SERIAL: u16 = 0x000E;
    pub const BOOT_RX_MBX_OFFSET: u16 = 0x0014;
    pub const BOOT_RX_MBX_SIZE: u16 = 0x0015;
    pub const BOOT_TX_MBX_OFFSET: u16 = 0x0016;
    pub const BOOT_TX_MBX_SIZE: u16 = 0x0017;
    pub const STD_RX_MBX_OFFSET: u16 = 0x0018;
    pub const STD_RX_MBX_SIZE: u16 = 0x0019;
    pub const STD_TX_MBX_OFFSET: u16 = 0x001A;
    pub const STD_TX_MBX_SIZE: u16 = 0x001B;
    pub const MBX_PROTOCOL: u16 = 0x001C;
    pub const SIZE: u16 = 0x003E;
    pub const VERSION: u16 = 0x003F;
    pub const FIRST_CATEGORY: u16 = 0x0040;
    pub const CAT_NOP: u16 = 0;
    pub const CAT_STRINGS: u16 = 10;
    pub const CAT_DATA_TYPES: u16 = 20;
    pub const CAT_GENERAL: u16 = 30;
    pub const CAT_FMMU: u16 = 40;
    pub const CAT_SYNCM: u16 = 41;
    pub const CAT_TXPDO: u16 = 50;
    pub const CAT_RXPDO: u16 = 51;
    pub const CAT_DC: u16 = 60;
    pub const CAT_END: u16 = 0xffff;
}
