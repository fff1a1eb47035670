//! The SII EEPROM: the ESC's register interface to it (0x0500..=0x050F, ET1100 datasheet
//! section II, "EEPROM control/status") and the image's layout (ETG.2010): word addresses of
//! the header, category types and the CRC-8 of the configuration area.
//!
//! Control/status (0x0502, u16), bit by bit as the datasheet has them:
//! - bit 0 write enable (set in the same write as a write command),
//! - bit 5 EEPROM emulation by the PDI, bit 6 read size (1 = 8 bytes per read, 0 = 4),
//!   bit 7 address algorithm (1 = two address bytes, EEPROMs above 16 Kbit),
//! - bits 8..=10 command: 1 read, 2 write, 4 reload,
//! - bit 11 **checksum error** in the ESC configuration area (words 0..=6 against the CRC in
//!   word 7): the ESC did not take over the configuration area,
//! - bit 12 EEPROM loading status: 1 = not loaded, device information not available,
//! - bit 13 **error acknowledge/command**: the EEPROM did not acknowledge (an address past its
//!   end) or the command was invalid,
//! - bit 14 error write enable: a write command without write enable,
//! - bit 15 busy.
//!
//! The copies this crate replaced called bit 13 the checksum error and never looked at bit 11.

crate::named_constants! {
    /// Every bit and command, by name.
    pub const TABLE;
    /// SII configuration (0x0500) bit 0: the PDI owns the EEPROM (0 = EtherCAT).
    pub const CONFIG_PDI: u8 = 0x01;
    /// SII configuration bit 1: force the PDI to give up its access.
    pub const CONFIG_RESET_PDI_ACCESS: u8 = 0x02;
    /// Bit 0: write enable.
    pub const WRITE_ENABLE: u16 = 1 << 0;
    /// Bit 5: the PDI emulates the EEPROM.
    pub const EMULATION: u16 = 1 << 5;
    /// Bit 6: reads return 8 bytes (0: 4 bytes).
    pub const READ_8_BYTES: u16 = 1 << 6;
    /// Bit 7: two address bytes (EEPROMs larger than 16 Kbit).
    pub const TWO_ADDRESS_BYTES: u16 = 1 << 7;
    /// Command: read.
    pub const CMD_READ: u16 = 0x0100;
    /// Command: write.
    pub const CMD_WRITE: u16 = 0x0200;
    /// Command: reload the configuration area into the registers.
    pub const CMD_RELOAD: u16 = 0x0400;
    /// Bits 8..=10: the command.
    pub const CMD_MASK: u16 = 0x0700;
    /// Bit 11: checksum error in the ESC configuration area.
    pub const CHECKSUM_ERROR: u16 = 1 << 11;
    /// Bit 12: EEPROM not loaded, device information not available.
    pub const NOT_LOADED: u16 = 1 << 12;
    /// Bit 13: missing EEPROM acknowledge or invalid command.
    pub const COMMAND_ERROR: u16 = 1 << 13;
    /// Bit 14: write command without write enable.
    pub const WRITE_ERROR: u16 = 1 << 14;
    /// Bit 15: a command is being executed.
    pub const BUSY: u16 = 1 << 15;
    /// Bits 11..=14: every error indication.
    pub const ERROR_MASK: u16 = CHECKSUM_ERROR | NOT_LOADED | COMMAND_ERROR | WRITE_ERROR;
    /// The errors a command leaves behind (cleared by the next command): a read or write that
    /// failed. Checksum and loading status describe the configuration area, not the command.
    pub const COMMAND_ERRORS: u16 = COMMAND_ERROR | WRITE_ERROR;
}

/// Word addresses of the SII header (ETG.2010 table 2).
pub mod word {
    crate::named_constants! {
        /// Every word address, by name.
        pub const TABLE;
        /// PDI control (configuration area, words 0..=7).
        pub const PDI_CONTROL: u16 = 0x0000;
        /// PDI configuration.
        pub const PDI_CONFIG: u16 = 0x0001;
        /// SYNC impulse length.
        pub const SYNC_IMPULSE_LEN: u16 = 0x0002;
        /// PDI configuration 2.
        pub const PDI_CONFIG_2: u16 = 0x0003;
        /// Configured station alias.
        pub const CONFIGURED_ALIAS: u16 = 0x0004;
        /// Checksum (CRC-8 of words 0..=6 in the low byte).
        pub const CHECKSUM: u16 = 0x0007;
        /// Vendor ID (u32).
        pub const VENDOR_ID: u16 = 0x0008;
        /// Product code (u32).
        pub const PRODUCT_CODE: u16 = 0x000A;
        /// Revision number (u32).
        pub const REVISION: u16 = 0x000C;
        /// Serial number (u32).
        pub const SERIAL: u16 = 0x000E;
        /// Bootstrap receive mailbox offset.
        pub const BOOT_RX_MBX_OFFSET: u16 = 0x0014;
        /// Bootstrap receive mailbox size.
        pub const BOOT_RX_MBX_SIZE: u16 = 0x0015;
        /// Bootstrap send mailbox offset.
        pub const BOOT_TX_MBX_OFFSET: u16 = 0x0016;
        /// Bootstrap send mailbox size.
        pub const BOOT_TX_MBX_SIZE: u16 = 0x0017;
        /// Standard receive mailbox offset.
        pub const STD_RX_MBX_OFFSET: u16 = 0x0018;
        /// Standard receive mailbox size.
        pub const STD_RX_MBX_SIZE: u16 = 0x0019;
        /// Standard send mailbox offset.
        pub const STD_TX_MBX_OFFSET: u16 = 0x001A;
        /// Standard send mailbox size.
        pub const STD_TX_MBX_SIZE: u16 = 0x001B;
        /// Mailbox protocols supported.
        pub const MBX_PROTOCOL: u16 = 0x001C;
        /// EEPROM size (in KiBit − 1).
        pub const SIZE: u16 = 0x003E;
        /// Version.
        pub const VERSION: u16 = 0x003F;
        /// First category header.
        pub const FIRST_CATEGORY: u16 = 0x0040;
        /// Bytes of the configuration area the checksum covers (words 0..=6).
        pub const CHECKSUM_COVERS: u16 = 14;
    }
}

/// Category types (ETG.2010 table 3).
pub mod category {
    crate::named_constants! {
        /// Every category type, by name.
        pub const TABLE;
        /// No information.
        pub const NOP: u16 = 0;
        /// String repository.
        pub const STRINGS: u16 = 10;
        /// Data types.
        pub const DATA_TYPES: u16 = 20;
        /// General information.
        pub const GENERAL: u16 = 30;
        /// FMMUs to be used.
        pub const FMMU: u16 = 40;
        /// SyncManager configuration.
        pub const SYNCM: u16 = 41;
        /// TxPDO description.
        pub const TXPDO: u16 = 50;
        /// RxPDO description.
        pub const RXPDO: u16 = 51;
        /// Distributed clock.
        pub const DC: u16 = 60;
        /// End of the category list.
        pub const END: u16 = 0xFFFF;
    }
}

/// The SyncM category (ETG.2010): one 8-byte record per SyncManager — start (u16), length
/// (u16), control (u8), status (u8), enable (u8), type (u8).
pub mod syncm {
    crate::named_constants! {
        /// Every type and enable bit, by name.
        pub const TABLE;
        /// Type: unused or unknown.
        pub const TYPE_UNUSED: u8 = 0;
        /// Type: mailbox out (master to slave).
        pub const TYPE_MBOX_OUT: u8 = 1;
        /// Type: mailbox in (slave to master).
        pub const TYPE_MBOX_IN: u8 = 2;
        /// Type: process data outputs.
        pub const TYPE_OUTPUTS: u8 = 3;
        /// Type: process data inputs.
        pub const TYPE_INPUTS: u8 = 4;
        /// Enable bit 0: the SyncManager is enabled.
        pub const ENABLE: u8 = 0x01;
        /// Enable bit 1: fixed content (information for a configuration tool).
        pub const FIXED_CONTENT: u8 = 0x02;
        /// Enable bit 2: virtual SyncManager, no hardware resource (an FMMU maps its memory).
        pub const VIRTUAL: u8 = 0x04;
        /// Enable bit 3: enabled only in OP.
        pub const OP_ONLY: u8 = 0x08;
    }
}

/// CRC-8 of the SII configuration area (words 0..=6): polynomial x⁸+x²+x+1 (0x07), initial
/// value 0xFF, no reflection, no final XOR. The result goes into the low byte of word 7.
pub const fn checksum(bytes: &[u8]) -> u8 {
    let mut crc: u8 = 0xFF;
    let mut i = 0;
    while i < bytes.len() {
        crc ^= bytes[i];
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x80 != 0 {
                (crc << 1) ^ 0x07
            } else {
                crc << 1
            };
            bit += 1;
        }
        i += 1;
    }
    crc
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checksum_is_crc8_poly_07_init_ff() {
        // The check value of CRC-8/poly 0x07/init 0xFF/no reflection over "123456789" is 0xFB
        // (the catalogue's CRC-8/ROHC reflects; this one does not).
        assert_eq!(checksum(b"123456789"), 0xFB);
        assert_eq!(checksum(&[]), 0xFF);
        let area = [0x80u8, 0x0c, 0x00, 0x6e, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0];
        let mut flipped = area;
        flipped[0] ^= 1;
        assert_ne!(checksum(&area), checksum(&flipped));
    }

    #[test]
    fn error_bits_are_the_datasheets() {
        // ET1100 datasheet section II, 0x0502: 11 checksum, 12 not loaded, 13 acknowledge or
        // command, 14 write enable; SOEM's EC_ESTAT_EMASK is the same 0x7800.
        assert_eq!(CHECKSUM_ERROR, 0x0800);
        assert_eq!(COMMAND_ERROR, 0x2000);
        assert_eq!(WRITE_ERROR, 0x4000);
        assert_eq!(ERROR_MASK, 0x7800);
        assert_eq!(COMMAND_ERRORS & CHECKSUM_ERROR, 0);
    }
}
