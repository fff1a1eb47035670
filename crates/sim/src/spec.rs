//! Description of one virtual slave, built by the Python front from the bus config and the ESI
//! (see `docs/simulator.md` for the dict keys that map onto these fields).

use ether_ros_protocol::sii::syncm;

use crate::chip::EscChip;
use crate::od::{Entry, Object};
use crate::soe::IdnSpec;

/// Standard (or bootstrap) mailbox placement.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MailboxSpec {
    /// Physical address of the receive mailbox (SM0, master to slave).
    pub rx_offset: u16,
    /// Size of the receive mailbox in bytes.
    pub rx_size: u16,
    /// Physical address of the send mailbox (SM1, slave to master).
    pub tx_offset: u16,
    /// Size of the send mailbox in bytes.
    pub tx_size: u16,
}

/// Why the network refused a slave: the spec's field that is wrong (`"sii"`, `"upstream"`,
/// `"device"`) and the reason in words. The Python binding raises it as `InvalidRequest` with
/// the field as data, so a caller learns which part of the spec to fix without parsing text.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SpecError {
    /// The field of [`SlaveSpec`] that cannot be carried out.
    pub field: &'static str,
    /// What is wrong, naming the slave.
    pub message: String,
}

impl SpecError {
    /// A refusal of `field` with `message`.
    pub fn new(field: &'static str, message: impl Into<String>) -> SpecError {
        SpecError {
            field,
            message: message.into(),
        }
    }
}

impl std::fmt::Display for SpecError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for SpecError {}

#[derive(Clone, Debug)]
/// Everything the simulator needs to build one virtual slave: identity, SII image, object
/// dictionary, device model and its wiring. The Python binding's `SlaveSpec` fills it.
pub struct SlaveSpec {
    /// The slave's name, used in messages and by the control socket.
    pub name: String,
    /// Vendor id (informational: the master reads the identity from the SII).
    pub vendor_id: u32,
    /// Product code (informational, as `vendor_id`).
    pub product_code: u32,
    /// Revision number (informational, as `vendor_id`).
    pub revision: u32,
    /// Serial number (informational, as `vendor_id`).
    pub serial: u32,
    /// Used only when the SII image is too short to carry the alias (word 4).
    pub alias: u16,
    /// The SII EEPROM image.
    pub sii: Vec<u8>,
    /// The CoE objects of the dictionary.
    pub objects: Vec<Object>,
    /// The CoE entries of the dictionary with their defaults.
    pub entries: Vec<Entry>,
    /// The IDN dictionary of a drive with SoE (the same for each of its drives); the SoE
    /// server adds the configuration lists and the IDNs the PDOs map.
    pub idns: Vec<IdnSpec>,
    /// The device model that runs the slave's firmware (`devices::create`).
    pub device: String,
    /// Parameters of the device model (`sim.params`).
    pub params: Vec<(String, f64)>,
    /// Drift of the slave's local clock (ppm).
    pub drift_ppm: f64,
    /// One-way delay of the link into this slave's port 0 (cable and the upstream slave's
    /// forwarding), ns.
    pub delay_ns: u64,
    /// Where port 0 is connected: `(index of the parent slave, parent's port 1..=3)`. None:
    /// the previous slave's port 1 (a line), or the master for the first slave.
    pub upstream: Option<(usize, u8)>,
    /// The ESC has distributed clocks.
    pub dc_supported: bool,
    /// PREOP to SAFEOP is refused unless SYNC0 is active with a cycle time.
    pub dc_required: bool,
    /// Standard mailbox; when None it is taken from SII words 0x18..=0x1B (if non-zero).
    pub mailbox: Option<MailboxSpec>,
    /// Process-data RAM in KiB; 0 means the chip's own size (register 0x0006).
    pub pdram_kib: u8,
    /// The slave controller chip whose registers the ESC presents.
    pub esc: EscChip,
    /// How long a SAFEOP->OP request stays pending while the slave waits for valid outputs
    /// (the ESI's `<SafeopOpTimeout>`), before it is refused with AL status 0x0019.
    pub safeop_op_timeout_ms: u32,
    /// Output → input pairs of the `loopback` device model.
    pub loopback_links: Vec<crate::devices::loopback::Link>,
    /// False: the ESC reports "LRW not supported" (0x0008 bit 9) and does not process LRW
    /// (no data, no working counter), as such ESCs do; the master must use LRD + LWR.
    pub lrw_supported: bool,
    /// The FoE server's store, for a slave whose SII announces FoE (word 0x1C bit 3).
    pub foe: crate::foe::FoeSpec,
}

impl Default for SlaveSpec {
    fn default() -> Self {
        SlaveSpec {
            name: String::new(),
            vendor_id: 0,
            product_code: 0,
            revision: 0,
            serial: 0,
            alias: 0,
            sii: Vec::new(),
            objects: Vec::new(),
            entries: Vec::new(),
            idns: Vec::new(),
            device: "none".into(),
            params: Vec::new(),
            drift_ppm: 0.0,
            delay_ns: 500,
            upstream: None,
            dc_supported: true,
            dc_required: false,
            mailbox: None,
            pdram_kib: 0,
            esc: EscChip::Et1100,
            safeop_op_timeout_ms: 10_000,
            loopback_links: Vec::new(),
            lrw_supported: true,
            foe: crate::foe::FoeSpec::default(),
        }
    }
}

/// SII categories: the FMMU usage list (one byte per FMMU the device uses), the TxPDOs
/// (inputs) and RxPDOs (outputs).
use ether_ros_protocol::sii::category::{
    FMMU as SII_CATEGORY_FMMU, RXPDO as SII_CATEGORY_RXPDO, TXPDO as SII_CATEGORY_TXPDO,
};

impl SlaveSpec {
    /// Whether the chosen chip can carry the device the SII describes, checked the way the
    /// hardware would fail: more SyncManagers or FMMUs than the chip has, or a SyncManager
    /// window outside its process RAM (a buffered SyncManager takes three buffers of its
    /// length, ESC datasheet section I, "3-buffer mode"). The error names what does not fit.
    pub fn check_emulatable(&self) -> Result<(), String> {
        let chip = self.esc.profile();
        let chip_name = self.esc.name().to_uppercase();
        let sms = crate::sii::sync_managers(&self.sii);
        if sms.len() > chip.sync_managers as usize {
            return Err(format!(
                "cannot emulate: the device describes {} SyncManagers, the {chip_name} has {}",
                sms.len(),
                chip.sync_managers
            ));
        }
        let fmmus: usize = crate::sii::categories(&self.sii)
            .iter()
            .filter(|(kind, _)| *kind == SII_CATEGORY_FMMU)
            .map(|(_, data)| {
                data.iter()
                    .filter(|&&usage| usage != 0 && usage != 0xFF)
                    .count()
            })
            .sum();
        if fmmus > chip.fmmus as usize {
            return Err(format!(
                "cannot emulate: the device uses {fmmus} FMMUs, the {chip_name} has {}",
                chip.fmmus
            ));
        }
        let ram_kib = if self.pdram_kib == 0 {
            chip.ram_kib
        } else {
            self.pdram_kib
        };
        let ram_end = 0x1000 + 1024 * u32::from(ram_kib);
        let rx = crate::sii::pdos(&self.sii, SII_CATEGORY_RXPDO);
        let tx = crate::sii::pdos(&self.sii, SII_CATEGORY_TXPDO);
        for (n, sm) in sms.iter().enumerate() {
            // Unused, or virtual (SII enable bit 2: an FMMU maps ESC memory, no SM is used).
            if sm.kind == syncm::TYPE_UNUSED || sm.enable & syncm::VIRTUAL != 0 {
                continue;
            }
            // A process-data SyncManager without a default length is as long as its PDOs.
            let pdos = match sm.kind {
                syncm::TYPE_OUTPUTS => &rx,
                syncm::TYPE_INPUTS => &tx,
                _ => &Vec::new(),
            };
            let pdo_bits: u32 = pdos
                .iter()
                .filter(|p| usize::from(p.sync_manager) == n)
                .flat_map(|p| p.entries.iter().map(|e| u32::from(e.2)))
                .sum();
            let len = u32::from(sm.len).max(pdo_bits.div_ceil(8));
            let buffered = sm.control & 0x03 == 0;
            // The digital output registers (0x0F00..0x0F03) take an SM of their own size.
            if crate::sm::window_allowed(sm.start, len.min(0xFFFF) as u16) && sm.start < 0x1000 {
                continue;
            }
            let end = u32::from(sm.start) + len * if buffered { 3 } else { 1 };
            if u32::from(sm.start) < 0x1000 || end > ram_end {
                return Err(format!(
                    "cannot emulate: SyncManager {n} (0x{:04X}, {len} bytes{}) does not fit the \
                     {chip_name}'s {ram_kib} KiB process RAM (0x1000..0x{ram_end:04X})",
                    sm.start,
                    if buffered { " x 3 buffers" } else { "" },
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal SII: 64 words of header, then the given categories and the end marker.
    fn sii(categories: &[(u16, Vec<u8>)]) -> Vec<u8> {
        let mut image = vec![0u8; 128];
        for (kind, data) in categories {
            image.extend_from_slice(&kind.to_le_bytes());
            image.extend_from_slice(&((data.len() / 2) as u16).to_le_bytes());
            image.extend_from_slice(data);
        }
        image.extend_from_slice(&[0xFF, 0xFF]);
        image
    }

    fn sm(start: u16, len: u16, control: u8, kind: u8) -> Vec<u8> {
        let [s0, s1] = start.to_le_bytes();
        let [l0, l1] = len.to_le_bytes();
        vec![s0, s1, l0, l1, control, 0, 1, kind]
    }

    fn spec(esc: EscChip, sms: &[Vec<u8>], fmmus: &[u8]) -> SlaveSpec {
        let mut cats = vec![(41, sms.concat())];
        if !fmmus.is_empty() {
            let mut f = fmmus.to_vec();
            f.resize(f.len().div_ceil(2) * 2, 0);
            cats.push((40, f));
        }
        SlaveSpec {
            esc,
            sii: sii(&cats),
            ..SlaveSpec::default()
        }
    }

    #[test]
    fn a_small_device_fits_every_chip() {
        let sms = [
            sm(0x1000, 128, 0x26, 1),
            sm(0x1080, 128, 0x22, 2),
            sm(0x1100, 32, 0x64, 3),
            sm(0x1180, 32, 0x20, 4),
        ];
        for chip in [EscChip::Et1100, EscChip::Et1200, EscChip::Lan9252] {
            spec(chip, &sms, &[1, 2, 3]).check_emulatable().unwrap();
        }
    }

    #[test]
    fn too_many_sync_managers_or_fmmus_are_refused_with_the_counts() {
        let sms: Vec<Vec<u8>> = (0..6).map(|n| sm(0x1000 + n * 0x40, 8, 0x64, 0)).collect();
        spec(EscChip::Et1100, &sms, &[]).check_emulatable().unwrap();
        let e = spec(EscChip::Et1200, &sms, &[])
            .check_emulatable()
            .unwrap_err();
        assert_eq!(
            e,
            "cannot emulate: the device describes 6 SyncManagers, the ET1200 has 4"
        );
        let e = spec(EscChip::Lan9252, &[], &[1, 2, 3, 3])
            .check_emulatable()
            .unwrap_err();
        assert_eq!(
            e,
            "cannot emulate: the device uses 4 FMMUs, the LAN9252 has 3"
        );
    }

    #[test]
    fn a_buffered_sync_manager_needs_three_buffers_of_ram() {
        // 300 bytes of outputs at 0x1100: 900 bytes buffered, beyond the ET1200's 1 KiB.
        let sms = [sm(0x1100, 300, 0x64, 3)];
        spec(EscChip::Et1100, &sms, &[]).check_emulatable().unwrap();
        let e = spec(EscChip::Et1200, &sms, &[])
            .check_emulatable()
            .unwrap_err();
        assert!(
            e.contains("SyncManager 0 (0x1100, 300 bytes x 3 buffers)"),
            "{e}"
        );
        assert!(
            e.contains("ET1200's 1 KiB process RAM (0x1000..0x1400)"),
            "{e}"
        );
        // A mailbox SyncManager (one buffer) of the same size fits.
        spec(EscChip::Et1200, &[sm(0x1100, 300, 0x26, 1)], &[])
            .check_emulatable()
            .unwrap();
        // Below 0x1000 is the register space, never process RAM.
        let e = spec(EscChip::Et1100, &[sm(0x0F00, 8, 0x26, 1)], &[])
            .check_emulatable()
            .unwrap_err();
        assert!(e.contains("does not fit"), "{e}");
    }
}
