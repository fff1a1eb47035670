//! Description of one virtual slave, built by the Python front from the bus config and the ESI
//! (see `docs/simulator.md` for the dict keys that map onto these fields).

use crate::chip::EscChip;
use crate::od::{Entry, Object};

/// Standard (or bootstrap) mailbox placement.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MailboxSpec {
    pub rx_offset: u16,
    pub rx_size: u16,
    pub tx_offset: u16,
    pub tx_size: u16,
}

#[derive(Clone, Debug)]
pub struct SlaveSpec {
    pub name: String,
    pub vendor_id: u32,
    pub product_code: u32,
    pub revision: u32,
    pub serial: u32,
    /// Used only when the SII image is too short to carry the alias (word 4).
    pub alias: u16,
    pub sii: Vec<u8>,
    pub objects: Vec<Object>,
    pub entries: Vec<Entry>,
    pub device: String,
    pub params: Vec<(String, f64)>,
    pub drift_ppm: f64,
    pub delay_ns: u64,
    pub dc_supported: bool,
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
            device: "none".into(),
            params: Vec::new(),
            drift_ppm: 0.0,
            delay_ns: 500,
            dc_supported: true,
            dc_required: false,
            mailbox: None,
            pdram_kib: 0,
            esc: EscChip::Et1100,
            safeop_op_timeout_ms: 10_000,
            loopback_links: Vec::new(),
            lrw_supported: true,
        }
    }
}
