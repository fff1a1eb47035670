//! The slave controller chips the simulator can present: what each one shows in its identity
//! and capability registers (0x0000–0x0009) and how many FMMUs, SyncManagers and bytes of
//! process-data RAM it really has. Everything else of the register map is common to the three
//! (they all implement the ET1100 register set); `docs/simulator.md` has the table with the
//! sources.

/// ESC features (register 0x0008): the protocol crate's bits.
pub use ether_ros_protocol::reg::features as feature;

/// One selectable slave controller.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum EscChip {
    /// Beckhoff ET1100 (4 ports, 8 FMMUs, 8 SyncManagers, 8 KiB process RAM): the default.
    #[default]
    Et1100,
    /// Beckhoff ET1200 (3 ports, 3 FMMUs, 4 SyncManagers, 1 KiB process RAM).
    Et1200,
    /// Microchip LAN9252 (2 MII ports with PHYs, 3 FMMUs, 4 SyncManagers, 4 KiB process RAM).
    Lan9252,
}

/// What a chip presents in 0x0000–0x0009 and what it has.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChipProfile {
    /// 0x0000 Type.
    pub type_code: u8,
    /// 0x0001 Revision.
    pub revision: u8,
    /// 0x0002:0x0003 Build.
    pub build: u16,
    /// 0x0004 FMMUs supported.
    pub fmmus: u8,
    /// 0x0005 SyncManagers supported.
    pub sync_managers: u8,
    /// 0x0006 RAM size in KiB.
    pub ram_kib: u8,
    /// 0x0007 Port descriptor: two bits a port (00 not implemented, 01 not configured,
    /// 10 EBUS, 11 MII/RMII), port 0 in the low bits.
    pub port_descriptor: u8,
    /// 0x0008:0x0009 Features supported (with DC; `features(false)` clears the DC bits).
    pub features_with_dc: u16,
    /// Ports that exist (0..ports).
    pub ports: u8,
}

impl EscChip {
    /// Names accepted in the config (`sim.esc`) and the slave spec (`esc`).
    pub const NAMES: &'static [&'static str] = &["et1100", "et1200", "lan9252"];

    /// The chip of a name as specs and the CLI give it (`et1100`, `et1200`, `lan9252`); an error
    /// lists the names known.
    pub fn from_name(name: &str) -> Result<EscChip, String> {
        match name.to_ascii_lowercase().as_str() {
            "et1100" => Ok(EscChip::Et1100),
            "et1200" => Ok(EscChip::Et1200),
            "lan9252" => Ok(EscChip::Lan9252),
            other => Err(format!(
                "unknown ESC chip '{other}' (known: {})",
                Self::NAMES.join(", ")
            )),
        }
    }

    /// The chip's name as specs give it (lower case).
    pub fn name(self) -> &'static str {
        match self {
            EscChip::Et1100 => "et1100",
            EscChip::Et1200 => "et1200",
            EscChip::Lan9252 => "lan9252",
        }
    }

    /// What the chip has (ports, SyncManagers, FMMUs, process RAM): the limits a spec must fit.
    pub const fn profile(self) -> ChipProfile {
        use feature::*;
        // Every Beckhoff ASIC sets bits 2..=8: DC, 64-bit DC, both low-jitter/enhanced link
        // detection flavours, separate FCS errors and enhanced DC SYNC activation (0x01FC).
        const BECKHOFF: u16 = DC
            | DC_64BIT
            | LOW_JITTER_EBUS
            | ENHANCED_LINK_EBUS
            | ENHANCED_LINK_MII
            | SEPARATE_FCS_ERRORS
            | ENHANCED_DC_SYNC;
        match self {
            EscChip::Et1100 => ChipProfile {
                type_code: 0x11,
                revision: 0x00,
                build: 0x0002,
                fmmus: 8,
                sync_managers: 8,
                ram_kib: 8,
                // Ports 0 and 1 MII (the usual two-port slave), ports 2 and 3 EBUS.
                port_descriptor: 0b10_10_11_11,
                features_with_dc: BECKHOFF,
                ports: 4,
            },
            EscChip::Et1200 => ChipProfile {
                type_code: 0x12,
                revision: 0x00,
                build: 0x0001,
                fmmus: 3,
                sync_managers: 4,
                ram_kib: 1,
                // Port 0 MII, ports 1 and 2 EBUS, no port 3.
                port_descriptor: 0b00_10_10_11,
                features_with_dc: BECKHOFF,
                ports: 3,
            },
            EscChip::Lan9252 => ChipProfile {
                type_code: 0xC0,
                revision: 0x01,
                build: 0x0001,
                fmmus: 3,
                sync_managers: 4,
                ram_kib: 4,
                // Two MII ports (internal PHYs), no EBUS: the EBUS feature bits stay clear.
                port_descriptor: 0b00_00_11_11,
                features_with_dc: DC
                    | DC_64BIT
                    | ENHANCED_LINK_MII
                    | SEPARATE_FCS_ERRORS
                    | ENHANCED_DC_SYNC,
                ports: 2,
            },
        }
    }
}

impl ChipProfile {
    /// Register 0x0008 for a slave with or without distributed clocks.
    pub fn features(&self, dc: bool) -> u16 {
        use feature::*;
        if dc {
            self.features_with_dc
        } else {
            self.features_with_dc & !(DC | DC_64BIT | ENHANCED_DC_SYNC)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_is_named() {
        for name in EscChip::NAMES {
            assert_eq!(EscChip::from_name(name).unwrap().name(), *name);
        }
        assert_eq!(EscChip::from_name("ET1200").unwrap(), EscChip::Et1200);
        let err = EscChip::from_name("et9999").unwrap_err();
        assert!(err.contains("et9999") && err.contains("lan9252"), "{err}");
    }

    #[test]
    fn port_descriptor_matches_port_count() {
        for name in EscChip::NAMES {
            let p = EscChip::from_name(name).unwrap().profile();
            let implemented = (0..4)
                .filter(|k| (p.port_descriptor >> (2 * k)) & 0b11 != 0)
                .count();
            assert_eq!(implemented, p.ports as usize, "{name}");
        }
    }

    #[test]
    fn features_without_dc_clear_only_dc_bits() {
        let p = EscChip::Et1100.profile();
        assert_eq!(p.features(true), 0x01FC);
        assert_eq!(p.features(false), 0x0070 | 0x0080);
        assert_eq!(p.features(true) & feature::LRW_NOT_SUPPORTED, 0);
    }
}
