//! ESC register map (ETG.1000.4 / Beckhoff ESC datasheet section II, ET1100) with the bit fields
//! of the registers master and simulator both read: ESC features, port descriptor, DL status,
//! SyncManagers, FMMUs, watchdogs, distributed clocks. AL control/status and the SII EEPROM
//! interface have modules of their own (`crate::al`, `crate::sii`).
//!
//! Addresses are offsets in the slave's 64 KiB physical memory; process-data RAM starts at
//! `PDRAM`.

crate::named_constants! {
    /// Every register address, by name.
    pub const TABLE;
    /// ESC type (u8); revision (0x0001) and build (0x0002..=0x0003) follow.
    pub const TYPE: u16 = 0x0000;
    /// ESC revision (u8).
    pub const REVISION: u16 = 0x0001;
    /// ESC build (u16).
    pub const BUILD: u16 = 0x0002;
    /// Number of supported FMMUs (u8).
    pub const FMMU_COUNT: u16 = 0x0004;
    /// Number of supported SyncManagers (u8).
    pub const SM_COUNT: u16 = 0x0005;
    /// Process-data RAM size in KiB (u8).
    pub const RAM_SIZE: u16 = 0x0006;
    /// Port descriptor (u8): two bits per port, see `port_desc`.
    pub const PORT_DESC: u16 = 0x0007;
    /// ESC features supported (u16), see `features`.
    pub const FEATURES: u16 = 0x0008;
    /// Configured station address (u16).
    pub const STATION_ADDRESS: u16 = 0x0010;
    /// Configured station alias (u16), loaded from SII word 4.
    pub const STATION_ALIAS: u16 = 0x0012;
    /// DL control (u32): forwarding rule (byte 0), loop control of ports 0..=3 (byte 1, two
    /// bits per port, 0 = automatic), see `dl`.
    pub const DL_CONTROL: u16 = 0x0100;
    /// DL control byte 1: loop control of ports 0..=3.
    pub const DL_CONTROL_LOOP: u16 = 0x0101;
    /// DL control byte 3: bit 0 enables the station alias for configured-address commands.
    pub const DL_CONTROL_ALIAS: u16 = 0x0103;
    /// DL status (u16): link and loop status per port, see `dl`.
    pub const DL_STATUS: u16 = 0x0110;
    /// AL control (u16): requested state + error acknowledge, see `crate::al`.
    pub const AL_CONTROL: u16 = 0x0120;
    /// AL status (u16): current state + error indication, see `crate::al`.
    pub const AL_STATUS: u16 = 0x0130;
    /// AL status code (u16), see `crate::al`.
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
    /// Lost link counters, one u8 per port (0x0310..=0x0313).
    pub const LOST_LINK_COUNTER: u16 = 0x0310;
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
    /// Watchdog counter PDI (u8).
    pub const WATCHDOG_COUNTER_PDI: u16 = 0x0443;
    /// SII EEPROM configuration (u8), see `crate::sii`.
    pub const SII_CONFIG: u16 = 0x0500;
    /// SII EEPROM PDI access state (u8).
    pub const SII_PDI_ACCESS: u16 = 0x0501;
    /// SII control/status (u16), see `crate::sii` for its bits.
    pub const SII_CONTROL: u16 = 0x0502;
    /// SII address (u32, word address).
    pub const SII_ADDRESS: u16 = 0x0504;
    /// SII data (4 or 8 bytes).
    pub const SII_DATA: u16 = 0x0508;
    /// MII management interface (0x0510..=0x0517).
    pub const MII_MANAGEMENT: u16 = 0x0510;
    /// First FMMU; FMMU n is at `FMMU0 + n·FMMU_LEN`, see `fmmu`.
    pub const FMMU0: u16 = 0x0600;
    /// Bytes per FMMU.
    pub const FMMU_LEN: u16 = 16;
    /// Most FMMUs an ESC can have.
    pub const MAX_FMMUS: u16 = 16;
    /// First SyncManager; SM n is at `SM0 + n·SM_LEN`, see `sm`.
    pub const SM0: u16 = 0x0800;
    /// Bytes per SyncManager.
    pub const SM_LEN: u16 = 8;
    /// Most SyncManagers an ESC can have.
    pub const MAX_SMS: u16 = 16;
    /// DC: port receive times, 4 x u32 (a write to port 0's latches all four).
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
    /// DC: speed counter difference (u16); a write to 0x0930 resets it.
    pub const DC_SPEED_COUNTER_DIFF: u16 = 0x0932;
    /// DC: time difference filter depth (u8).
    pub const DC_FILTER_DEPTH: u16 = 0x0934;
    /// DC: cyclic unit control (u8).
    pub const DC_CYCLIC_UNIT_CONTROL: u16 = 0x0980;
    /// DC: activation (u8), see `dc`.
    pub const DC_ACTIVATION: u16 = 0x0981;
    /// DC: SYNC0 status (u8).
    pub const DC_SYNC0_STATUS: u16 = 0x098E;
    /// DC: start time of cyclic operation (u64, system time).
    pub const DC_START_TIME: u16 = 0x0990;
    /// DC: SYNC0 cycle time (u32, ns).
    pub const DC_SYNC0_CYCLE: u16 = 0x09A0;
    /// DC: SYNC1 cycle time (u32, ns).
    pub const DC_SYNC1_CYCLE: u16 = 0x09A4;
    /// Digital I/O output data (4 bytes, ET1100/ET1200 with digital I/O PDI); a SyncManager
    /// may guard it (outputs then count for the process-data watchdog).
    pub const DIGITAL_OUTPUTS: u16 = 0x0F00;
    /// Bytes of digital I/O output data.
    pub const DIGITAL_OUTPUTS_LEN: u16 = 4;
    /// Start of process-data RAM; below it are the registers.
    pub const PDRAM: u16 = 0x1000;
}

/// ESC configuration (0x0141, loaded from the EEPROM).
pub mod esc_config {
    crate::named_constants! {
        /// Every bit, by name.
        pub const TABLE;
        /// Bit 0: device emulation: the ESC copies AL control to AL status (a slave without
        /// application processor, e.g. a digital I/O terminal).
        pub const DEVICE_EMULATION: u8 = 0x01;
    }
}

/// Address of register `offset` (`sm::STATUS`, ...) of SyncManager `n`.
pub const fn sm(n: u16, offset: u16) -> u16 {
    SM0 + n * SM_LEN + offset
}

/// Address of register `offset` (`fmmu::TYPE`, ...) of FMMU `n`.
pub const fn fmmu(n: u16, offset: u16) -> u16 {
    FMMU0 + n * FMMU_LEN + offset
}

/// ESC features supported (0x0008, ESC datasheet section II, "ESC Features supported").
/// Bits 9..=11 are "not supported"/"fixed" flags: 0 means the feature is there.
pub mod features {
    crate::named_constants! {
        /// Every bit, by name.
        pub const TABLE;
        /// Bit 0: FMMU operation byte-oriented only (0: bit-oriented).
        pub const FMMU_BYTE_ORIENTED: u16 = 1 << 0;
        /// Bit 2: distributed clocks available.
        pub const DC: u16 = 1 << 2;
        /// Bit 3: the DC time is 64 bits wide.
        pub const DC_64BIT: u16 = 1 << 3;
        /// Bit 4: low-jitter EBUS.
        pub const LOW_JITTER_EBUS: u16 = 1 << 4;
        /// Bit 5: enhanced link detection on EBUS ports.
        pub const ENHANCED_LINK_EBUS: u16 = 1 << 5;
        /// Bit 6: enhanced link detection on MII ports.
        pub const ENHANCED_LINK_MII: u16 = 1 << 6;
        /// Bit 7: FCS errors counted separately from other receive errors.
        pub const SEPARATE_FCS_ERRORS: u16 = 1 << 7;
        /// Bit 8: enhanced DC SYNC activation (0x0981 bits 3..=7, 0x0984).
        pub const ENHANCED_DC_SYNC: u16 = 1 << 8;
        /// Bit 9: LRW not supported (the master uses LRD + LWR).
        pub const LRW_NOT_SUPPORTED: u16 = 1 << 9;
        /// Bit 10: BRW, APRW, FPRW not supported.
        pub const READ_WRITE_NOT_SUPPORTED: u16 = 1 << 10;
        /// Bit 11: fixed FMMU/SyncManager configuration.
        pub const FIXED_FMMU_SM: u16 = 1 << 11;
    }
}

/// Port descriptor (0x0007): two bits per port (port p at bits 2p..=2p+1).
pub mod port_desc {
    crate::named_constants! {
        /// Every value, by name.
        pub const TABLE;
        /// The port is not implemented.
        pub const NOT_IMPLEMENTED: u8 = 0b00;
        /// The port is not configured (SII EEPROM).
        pub const NOT_CONFIGURED: u8 = 0b01;
        /// EBUS.
        pub const EBUS: u8 = 0b10;
        /// MII / RMII / RGMII.
        pub const MII: u8 = 0b11;
    }

    /// The two bits of port `port`.
    pub const fn port(descriptor: u8, port: u8) -> u8 {
        (descriptor >> (2 * port)) & 0b11
    }

    /// The descriptor with port `port` set to `kind`.
    pub const fn with_port(descriptor: u8, port: u8, kind: u8) -> u8 {
        (descriptor & !(0b11 << (2 * port))) | ((kind & 0b11) << (2 * port))
    }
}

/// DL control (0x0100) and DL status (0x0110).
pub mod dl {
    crate::named_constants! {
        /// Every bit, by name.
        pub const TABLE;
        /// DL status bit 0: PDI operational (EEPROM loaded).
        pub const STATUS_PDI_OPERATIONAL: u16 = 1 << 0;
        /// DL status bit 1: PDI watchdog status (1 = reloaded in time).
        pub const STATUS_PDI_WATCHDOG: u16 = 1 << 1;
        /// DL status bit 2: enhanced link detection active.
        pub const STATUS_ENHANCED_LINK: u16 = 1 << 2;
        /// DL status bit 4 + p: physical link on port p.
        pub const STATUS_LINK_PORT0: u16 = 1 << 4;
        /// DL status bit 8 + 2p: loop of port p closed.
        pub const STATUS_LOOP_PORT0: u16 = 1 << 8;
        /// DL status bit 9 + 2p: communication established on port p.
        pub const STATUS_COMM_PORT0: u16 = 1 << 9;
        /// DL control loop setting of a port (two bits): automatic.
        pub const LOOP_AUTO: u8 = 0b00;
        /// Loop setting: auto close.
        pub const LOOP_AUTO_CLOSE: u8 = 0b01;
        /// Loop setting: always open.
        pub const LOOP_OPEN: u8 = 0b10;
        /// Loop setting: always closed.
        pub const LOOP_CLOSED: u8 = 0b11;
    }

    /// DL status: port `p` has a physical link.
    pub const fn link(status: u16, p: u8) -> bool {
        status & (STATUS_LINK_PORT0 << p) != 0
    }

    /// DL status: the loop of port `p` is closed (frames turn back inside the ESC).
    pub const fn loop_closed(status: u16, p: u8) -> bool {
        status & (STATUS_LOOP_PORT0 << (2 * p)) != 0
    }

    /// DL status: communication is established on port `p`.
    pub const fn communication(status: u16, p: u8) -> bool {
        status & (STATUS_COMM_PORT0 << (2 * p)) != 0
    }

    /// The DL status bits of port `p` for a link that is up or down (loop open when up, closed
    /// when down, as under automatic loop control).
    pub const fn port_bits(p: u8, up: bool) -> u16 {
        if up {
            (STATUS_LINK_PORT0 << p) | (STATUS_COMM_PORT0 << (2 * p))
        } else {
            STATUS_LOOP_PORT0 << (2 * p)
        }
    }

    /// Ports whose loop is open and whose communication is established (bit p = port p): the
    /// ports a frame leaves through to another slave.
    pub const fn open_ports(status: u16) -> u8 {
        let mut mask = 0u8;
        let mut p = 0;
        while p < 4 {
            if communication(status, p) && !loop_closed(status, p) {
                mask |= 1 << p;
            }
            p += 1;
        }
        mask
    }
}

/// SyncManager registers (8 bytes at `SM0 + n·SM_LEN`) and their bits.
pub mod sm {
    crate::named_constants! {
        /// Every offset and bit, by name.
        pub const TABLE;
        /// Physical start address (u16).
        pub const START: u16 = 0;
        /// Length in bytes (u16).
        pub const LENGTH: u16 = 2;
        /// Control (u8).
        pub const CONTROL: u16 = 4;
        /// Status (u8, read only).
        pub const STATUS: u16 = 5;
        /// Activate (u8).
        pub const ACTIVATE: u16 = 6;
        /// PDI control (u8, read only for the master).
        pub const PDI_CONTROL: u16 = 7;
        /// Control bits 0..=1: operation mode three-buffered.
        pub const MODE_BUFFERED: u8 = 0x00;
        /// Control bits 0..=1: operation mode mailbox (one buffer with handshake).
        pub const MODE_MAILBOX: u8 = 0x02;
        /// Control bits 0..=1 mask.
        pub const MODE_MASK: u8 = 0x03;
        /// Control bits 2..=3: the master reads (ECAT read, PDI write).
        pub const DIR_READ: u8 = 0x00;
        /// Control bits 2..=3: the master writes (ECAT write, PDI read).
        pub const DIR_WRITE: u8 = 0x04;
        /// Control bits 2..=3 mask.
        pub const DIR_MASK: u8 = 0x0C;
        /// Control bit 4: interrupt in ECAT event request register.
        pub const ECAT_EVENT: u8 = 0x10;
        /// Control bit 5: interrupt in AL event request register (PDI).
        pub const PDI_EVENT: u8 = 0x20;
        /// Control bit 6: watchdog trigger.
        pub const WATCHDOG: u8 = 0x40;
        /// Status bit 3: mailbox full (one-buffer mode).
        pub const STATUS_MAILBOX_FULL: u8 = 0x08;
        /// Status bits 4..=5: last buffer written (three-buffer mode).
        pub const STATUS_BUFFER_MASK: u8 = 0x30;
        /// Activate bit 0: SyncManager enabled.
        pub const ACTIVATE_ENABLE: u8 = 0x01;
        /// Activate bit 1: repeat request (toggled by the master); PDI control bit 1 is the
        /// slave's repeat acknowledge.
        pub const REPEAT: u8 = 0x02;
        /// PDI control bit 0: the PDI deactivated the SyncManager.
        pub const PDI_DEACTIVATE: u8 = 0x01;
    }

    /// The 8 register bytes of one SyncManager (ET1100 datasheet section II, 0x0800): start
    /// (u16), length (u16), control (u8), status (u8, read only), activate (u8), PDI control
    /// (u8, read only for the master). The master writes it, the simulator's ESC reads it.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct Record {
        /// Physical start address of the window in the ESC's memory.
        pub start: u16,
        /// Length of the window in bytes.
        pub length: u16,
        /// Control: mode, direction, interrupts, watchdog (`MODE_*`, `DIR_*`, ...).
        pub control: u8,
        /// Status (read only; written as 0).
        pub status: u8,
        /// Activate: `ACTIVATE_ENABLE`, `REPEAT`.
        pub activate: u8,
        /// PDI control (read only for the master; written as 0).
        pub pdi_control: u8,
    }

    impl Record {
        /// Bytes of the record.
        pub const LEN: usize = super::SM_LEN as usize;

        /// The record the master writes: `control`, enabled or not, status and PDI control 0.
        pub const fn new(start: u16, length: u16, control: u8, enable: bool) -> Record {
            Record {
                start,
                length,
                control,
                status: 0,
                activate: if enable { ACTIVATE_ENABLE } else { 0 },
                pdi_control: 0,
            }
        }

        /// Whether activate bit 0 (enable) is set.
        pub const fn enabled(&self) -> bool {
            self.activate & ACTIVATE_ENABLE != 0
        }

        /// The 8 register bytes.
        pub const fn encode(&self) -> [u8; Record::LEN] {
            crate::le::window(
                self.start,
                self.length,
                [self.control, self.status, self.activate, self.pdi_control],
            )
        }

        /// Decode the first 8 bytes of `data` (`None` when shorter).
        pub fn decode(data: &[u8]) -> Option<Record> {
            let r = data.get(..Record::LEN)?;
            Some(Record {
                start: crate::le::u16_at(r, 0),
                length: crate::le::u16_at(r, 2),
                control: r[4],
                status: r[5],
                activate: r[6],
                pdi_control: r[7],
            })
        }
    }
}

/// FMMU registers (16 bytes at `FMMU0 + n·FMMU_LEN`) and their bits.
pub mod fmmu {
    crate::named_constants! {
        /// Every offset and bit, by name.
        pub const TABLE;
        /// Logical start address (u32).
        pub const LOGICAL_START: u16 = 0;
        /// Length in bytes (u16).
        pub const LENGTH: u16 = 4;
        /// Logical start bit (u8).
        pub const LOGICAL_START_BIT: u16 = 6;
        /// Logical stop bit (u8).
        pub const LOGICAL_STOP_BIT: u16 = 7;
        /// Physical start address (u16).
        pub const PHYSICAL_START: u16 = 8;
        /// Physical start bit (u8).
        pub const PHYSICAL_START_BIT: u16 = 10;
        /// Type (u8): bit 0 read, bit 1 write.
        pub const TYPE: u16 = 11;
        /// Activate (u8): bit 0.
        pub const ACTIVATE: u16 = 12;
        /// Type bit 0: slave memory is read into the frame (inputs).
        pub const READ: u8 = 0x01;
        /// Type bit 1: the frame is written into slave memory (outputs).
        pub const WRITE: u8 = 0x02;
        /// Activate bit 0: the FMMU is enabled.
        pub const ACTIVATE_ENABLE: u8 = 0x01;
    }

    /// The 16 register bytes of one FMMU (ET1100 datasheet section II, 0x0600): logical start
    /// (u32), length in bytes (u16), logical start bit (u8), logical stop bit (u8), physical
    /// start (u16), physical start bit (u8), type (u8), activate (u8), 3 reserved bytes. The
    /// master writes it, the simulator's ESC reads it.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct Record {
        /// Logical start address.
        pub logical_start: u32,
        /// Length in bytes of the logical range.
        pub length: u16,
        /// First bit (0..=7) of the first logical byte.
        pub logical_start_bit: u8,
        /// Last bit (0..=7) of the last logical byte.
        pub logical_stop_bit: u8,
        /// Physical start address in the ESC's memory.
        pub physical_start: u16,
        /// First bit (0..=7) of the first physical byte.
        pub physical_start_bit: u8,
        /// Type: `READ` (inputs), `WRITE` (outputs) or both.
        pub kind: u8,
        /// Activate: `ACTIVATE_ENABLE`.
        pub activate: u8,
    }

    impl Record {
        /// Bytes of the record.
        pub const LEN: usize = super::FMMU_LEN as usize;

        /// Whether activate bit 0 (enable) is set.
        pub const fn enabled(&self) -> bool {
            self.activate & ACTIVATE_ENABLE != 0
        }

        /// The 16 register bytes (the reserved ones 0).
        pub const fn encode(&self) -> [u8; Record::LEN] {
            let ls = self.logical_start.to_le_bytes();
            let l = self.length.to_le_bytes();
            let ps = self.physical_start.to_le_bytes();
            [
                ls[0],
                ls[1],
                ls[2],
                ls[3],
                l[0],
                l[1],
                self.logical_start_bit,
                self.logical_stop_bit,
                ps[0],
                ps[1],
                self.physical_start_bit,
                self.kind,
                self.activate,
                0,
                0,
                0,
            ]
        }

        /// Decode the first 13 bytes of `data` (the reserved bytes are not read; `None` when
        /// shorter). The fields are taken as they are, bit numbers included.
        pub fn decode(data: &[u8]) -> Option<Record> {
            let r = data.get(..ACTIVATE as usize + 1)?;
            Some(Record {
                logical_start: crate::le::u32_at(r, 0),
                length: crate::le::u16_at(r, 4),
                logical_start_bit: r[6],
                logical_stop_bit: r[7],
                physical_start: crate::le::u16_at(r, 8),
                physical_start_bit: r[10],
                kind: r[11],
                activate: r[12],
            })
        }
    }
}

/// Distributed clocks bits.
pub mod dc {
    crate::named_constants! {
        /// Every bit, by name.
        pub const TABLE;
        /// Activation (0x0981) bit 0: cyclic operation.
        pub const ACTIVATE_CYCLIC: u8 = 0x01;
        /// Activation bit 1: SYNC0 output.
        pub const ACTIVATE_SYNC0: u8 = 0x02;
        /// Activation bit 2: SYNC1 output.
        pub const ACTIVATE_SYNC1: u8 = 0x04;
        /// System time difference (0x092C) bit 31: the local copy is smaller than the received
        /// time; bits 0..=30 are the magnitude in ns.
        pub const DIFF_SIGN: u32 = 1 << 31;
    }

    /// The signed system time difference (local − received, ns) of register 0x092C.
    pub const fn difference_ns(raw: u32) -> i64 {
        let magnitude = (raw & !DIFF_SIGN) as i64;
        if raw & DIFF_SIGN != 0 {
            -magnitude
        } else {
            magnitude
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn registers_of_sync_managers_and_fmmus() {
        assert_eq!(sm(0, sm::STATUS), 0x0805);
        assert_eq!(sm(1, sm::STATUS), 0x080D);
        assert_eq!(sm(1, sm::ACTIVATE), 0x080E);
        assert_eq!(sm(1, sm::PDI_CONTROL), 0x080F);
        assert_eq!(fmmu(2, fmmu::TYPE), 0x062B);
    }

    #[test]
    fn dl_status_per_port() {
        // Ports 0 and 1 up (link + communication), 2 and 3 down (loop closed): an EK1100 in a line.
        let status = dl::port_bits(0, true)
            | dl::port_bits(1, true)
            | dl::port_bits(2, false)
            | dl::port_bits(3, false);
        assert_eq!(status, 0x5A30);
        assert_eq!(dl::open_ports(status), 0b0011);
        assert!(dl::link(status, 1) && !dl::link(status, 2));
        assert!(dl::loop_closed(status, 3) && !dl::loop_closed(status, 0));
    }

    #[test]
    fn port_descriptor_two_bits_per_port() {
        let d = port_desc::with_port(0, 3, port_desc::EBUS);
        assert_eq!(d, 0b1000_0000);
        assert_eq!(port_desc::port(0x0F, 1), port_desc::MII);
    }

    #[test]
    fn dc_difference_is_sign_and_magnitude() {
        assert_eq!(dc::difference_ns(5), 5);
        assert_eq!(dc::difference_ns(dc::DIFF_SIGN | 5), -5);
    }

    #[test]
    fn sm_record_byte_image() {
        // The usual SM2 of an EL2004-like slave: 1 byte at 0x0F00, buffered, master writes,
        // PDI event, watchdog (0x64), enabled: 00 0F 01 00 64 00 01 00.
        let r = sm::Record::new(0x0F00, 1, 0x64, true);
        assert_eq!(r.encode(), [0x00, 0x0F, 0x01, 0x00, 0x64, 0x00, 0x01, 0x00]);
        assert_eq!(sm::Record::decode(&r.encode()), Some(r));
        assert!(r.enabled());
        assert!(!sm::Record::new(0x1000, 0, 0x20, false).enabled());
        assert_eq!(sm::Record::decode(&[0; 7]), None);
        // Each field at the offset the register map names.
        let all = sm::Record {
            start: 0x0102,
            length: 0x0304,
            control: 5,
            status: 6,
            activate: 7,
            pdi_control: 8,
        }
        .encode();
        assert_eq!(all[sm::START as usize], 0x02);
        assert_eq!(all[sm::LENGTH as usize], 0x04);
        assert_eq!(all[sm::CONTROL as usize], 5);
        assert_eq!(all[sm::STATUS as usize], 6);
        assert_eq!(all[sm::ACTIVATE as usize], 7);
        assert_eq!(all[sm::PDI_CONTROL as usize], 8);
    }

    #[test]
    fn fmmu_record_byte_image() {
        // Outputs: logical 0x00010000, 2 bytes, bits 0..7, to physical 0x1000, write, enabled.
        let r = fmmu::Record {
            logical_start: 0x0001_0000,
            length: 2,
            logical_start_bit: 0,
            logical_stop_bit: 7,
            physical_start: 0x1000,
            physical_start_bit: 0,
            kind: fmmu::WRITE,
            activate: fmmu::ACTIVATE_ENABLE,
        };
        assert_eq!(
            r.encode(),
            [0, 0, 1, 0, 2, 0, 0, 7, 0x00, 0x10, 0, 2, 1, 0, 0, 0]
        );
        assert_eq!(fmmu::Record::decode(&r.encode()), Some(r));
        assert_eq!(fmmu::Record::decode(&r.encode()[..13]), Some(r));
        assert_eq!(fmmu::Record::decode(&r.encode()[..12]), None);
        let enc = r.encode();
        assert_eq!(enc[fmmu::LOGICAL_STOP_BIT as usize], 7);
        assert_eq!(enc[fmmu::PHYSICAL_START as usize], 0x00);
        assert_eq!(enc[fmmu::TYPE as usize], fmmu::WRITE);
        assert_eq!(enc[fmmu::ACTIVATE as usize], 1);
    }
}
