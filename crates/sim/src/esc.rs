//! One virtual EtherCAT slave controller: 64 KiB of memory with the register file, SII,
//! SyncManagers, FMMUs, distributed clock, watchdog, and the slave application behind it
//! (AL state machine, mailbox/CoE, process-data copy, the device model).
//!
//! Every master access goes through `ecat_read`/`ecat_write`, which split it into register,
//! SyncManager and plain-memory segments and report whether the ESC accepted it (a refused
//! SyncManager access leaves the working counter alone, as on hardware).

use std::collections::VecDeque;

use ether_ros_protocol::reg::{self, dc, dl, sm as smr};
use ether_ros_protocol::sii::{category as sii_category, word as sii_word};
use ether_ros_protocol::{al, coe as coe_facts, mailbox};

use crate::coe::CoeServer;
use crate::dc::{encode_time_difference, DcClock};
use crate::device::DeviceApp;
use crate::fmmu::Fmmu;
use crate::od::ObjectDictionary;
use crate::pdo::PdoMap;
use crate::sii::{self, Sii};
use crate::sm::{SyncManager, ACT_ENABLE, ACT_REPEAT, WATCHDOG_TRIGGER};
use crate::spec::{MailboxSpec, SlaveSpec};

pub const MEM_SIZE: usize = 0x1_0000;
pub const REGISTER_END: usize = reg::PDRAM as usize;
pub const N_FMMU: usize = 8;
pub const N_SM: usize = 8;
/// Default watchdog divider (100 µs units) and process-data watchdog time (100 ms).
const DEFAULT_WD_DIVIDER: u16 = 0x09C2;
const DEFAULT_WD_TIME: u16 = 0x03E8;
/// Catch-up bound for device steps: beyond this the device skips ahead.
pub const MAX_CATCH_UP_NS: u64 = 100_000_000;
/// CoE emergency error codes of refused AL state transitions (ETG.1000.6).
use ether_ros_protocol::emergency::{
    PREOP_TO_SAFEOP_FAILED as EMERGENCY_PREOP_TO_SAFEOP,
    SAFEOP_TO_OP_FAILED as EMERGENCY_SAFEOP_TO_OP,
};
/// Mailbox messages queued at most for the master (older ones are kept, new ones dropped).
const MAILBOX_QUEUE_LIMIT: usize = 32;

/// Per-slave counters for `slave_info`.
#[derive(Clone, Debug, Default)]
pub struct SlaveCounters {
    pub frames: u64,
    /// Frames in which a logical datagram reached this slave's FMMUs (its process data went
    /// by): with groups at their own cycles, this is the slave's own exchange rate.
    pub process_data_frames: u64,
    pub device_steps: u64,
    pub device_steps_skipped: u64,
    pub sync0_events: u64,
    pub sync0_late_starts: u64,
    pub watchdog_expirations: u64,
    pub mailbox_received: u64,
    pub mailbox_sent: u64,
    pub mailbox_errors: u64,
    pub al_errors: u64,
}

/// A register address as an offset into the ESC memory.
const fn at(register: u16) -> usize {
    register as usize
}

/// Registers the master may write, as (first, bytes); special registers (SII control, FMMUs,
/// SMs, counters that clear on write) are handled by `register_write` itself.
const WRITABLE: [(u16, u16); 16] = [
    (reg::STATION_ADDRESS, 2),
    (reg::DL_CONTROL, 4),
    (reg::AL_CONTROL, 2),
    (reg::ECAT_EVENT_MASK, 4),
    (reg::WATCHDOG_DIVIDER, 2),
    (reg::WATCHDOG_TIME_PDI, 2),
    (reg::WATCHDOG_TIME_PD, 2),
    (reg::SII_CONFIG, 2),
    (reg::SII_ADDRESS, 12),
    (reg::MII_MANAGEMENT, 8),
    (reg::DC_SYSTEM_TIME_OFFSET, 12),
    (reg::DC_SPEED_COUNTER_START, 2),
    (reg::DC_FILTER_DEPTH, 2),
    (reg::DC_CYCLIC_UNIT_CONTROL, 2),
    (reg::DC_START_TIME, 8),
    (reg::DC_SYNC0_CYCLE, 10),
];

/// `WRITABLE` as one flag per register byte (built at compile time: one load per byte).
static WRITABLE_BYTES: [bool; REGISTER_END] = {
    let mut map = [false; REGISTER_END];
    let mut i = 0;
    while i < WRITABLE.len() {
        let (first, len) = WRITABLE[i];
        let mut k = 0;
        while k < len {
            map[(first + k) as usize] = true;
            k += 1;
        }
        i += 1;
    }
    map
};

/// Is a register byte writable by the master? (Special registers are handled by hooks.)
fn reg_writable(a: usize) -> bool {
    a < REGISTER_END && WRITABLE_BYTES[a]
}

fn overlaps(a: usize, len: usize, lo: usize, hi: usize) -> bool {
    a < hi && a + len > lo
}

/// End of the SyncManager registers this model has.
const SM_END: usize = at(reg::SM0) + N_SM * at(reg::SM_LEN);
/// End of the FMMU registers this model has.
const FMMU_END: usize = at(reg::FMMU0) + N_FMMU * at(reg::FMMU_LEN);

/// First register of SyncManager `k`.
const fn sm_base(k: usize) -> usize {
    at(reg::SM0) + k * at(reg::SM_LEN)
}

pub struct Esc {
    pub spec: SlaveSpec,
    pub position: usize,
    mem: Box<[u8]>,
    pub sm: [SyncManager; N_SM],
    fmmus: Vec<Fmmu>,
    sii: Sii,
    pub dc: DcClock,
    pdram_end: usize,
    pub od: ObjectDictionary,
    coe: CoeServer,
    pub device: Option<Box<dyn DeviceApp>>,
    pub mailbox: Option<MailboxSpec>,
    boot_mailbox: Option<MailboxSpec>,
    mbx_queue: VecDeque<Vec<u8>>,
    mbx_last_rx_counter: u8,
    mbx_tx_counter: u8,
    mbx_last_sent: Vec<u8>,
    mbx_rx_pending: bool,
    pub out_sm: usize,
    pub in_sm: usize,
    pub out_map: PdoMap,
    pub in_map: PdoMap,
    pub al_state: u8,
    pub al_error: bool,
    pub al_code: u16,
    /// Host time of the current frame at this slave (frame time + propagation delay).
    pub now: u64,
    /// Bit p set when port p has a link and is open (set by the network's topology).
    pub open_ports: u8,
    /// Per port: ns after the frame's arrival at port 0 at which it comes back into that port
    /// (None: the port is closed). Latched by a write to 0x0900.
    pub port_return_ns: [Option<u64>; 4],
    pub sync0_next: Option<u64>,
    sync0_cycle: u64,
    app_next_step: u64,
    wd_last_trigger: u64,
    pub watchdog_expired: bool,
    outputs_since_safeop: bool,
    outputs_received: bool,
    pub refuse_op: bool,
    /// Host time at which a SAFEOP->OP request arrived that waits for valid outputs.
    op_pending_since: Option<u64>,
    pub mailbox_stalled: bool,
    pub counters: SlaveCounters,
    /// A logical datagram of the current frame hit an FMMU.
    process_data_seen: bool,
}

impl Esc {
    /// Power on a slave at host time `now`. The device model is created by the caller.
    pub fn new(spec: SlaveSpec, position: usize, now: u64) -> Esc {
        let mut od = ObjectDictionary::new();
        for o in &spec.objects {
            od.add_object(o.clone());
        }
        for e in &spec.entries {
            od.add_entry(e.clone());
        }
        let sii = Sii::new(spec.sii.clone());
        let w = |n: u16| sii::word(&sii.image, n as usize);
        let mailbox = if w(sii_word::STD_RX_MBX_SIZE) != 0 && w(sii_word::STD_TX_MBX_SIZE) != 0 {
            Some(MailboxSpec {
                rx_offset: w(sii_word::STD_RX_MBX_OFFSET),
                rx_size: w(sii_word::STD_RX_MBX_SIZE),
                tx_offset: w(sii_word::STD_TX_MBX_OFFSET),
                tx_size: w(sii_word::STD_TX_MBX_SIZE),
            })
        } else {
            spec.mailbox
        };
        let boot_mailbox =
            if w(sii_word::BOOT_RX_MBX_SIZE) != 0 && w(sii_word::BOOT_TX_MBX_SIZE) != 0 {
                Some(MailboxSpec {
                    rx_offset: w(sii_word::BOOT_RX_MBX_OFFSET),
                    rx_size: w(sii_word::BOOT_RX_MBX_SIZE),
                    tx_offset: w(sii_word::BOOT_TX_MBX_OFFSET),
                    tx_size: w(sii_word::BOOT_TX_MBX_SIZE),
                })
            } else {
                None
            };
        // Process-data SyncManagers: from the SII SyncM category, else the usual layout.
        let sms = sii::sync_managers(&sii.image);
        let find = |kind: u8| sms.iter().position(|s| s.kind == kind);
        let (def_out, def_in) = if mailbox.is_some() { (2, 3) } else { (0, 1) };
        let out_sm = find(3).unwrap_or(def_out).min(N_SM - 1);
        let in_sm = find(4).unwrap_or(def_in).min(N_SM - 1);
        let chip = spec.esc.profile();
        let pdram_kib = if spec.pdram_kib == 0 {
            chip.ram_kib
        } else {
            spec.pdram_kib.clamp(1, 60)
        };
        let dc = DcClock::new(now, 0, spec.drift_ppm);
        let mut esc = Esc {
            position,
            mem: vec![0u8; MEM_SIZE].into_boxed_slice(),
            sm: Default::default(),
            fmmus: Vec::with_capacity(N_FMMU),
            sii,
            dc,
            pdram_end: REGISTER_END + pdram_kib as usize * 1024,
            od,
            coe: CoeServer::new(),
            device: None,
            mailbox,
            boot_mailbox,
            mbx_queue: VecDeque::new(),
            mbx_last_rx_counter: 0,
            mbx_tx_counter: 0,
            mbx_last_sent: Vec::new(),
            mbx_rx_pending: false,
            out_sm,
            in_sm,
            out_map: PdoMap::default(),
            in_map: PdoMap::default(),
            al_state: ether_ros_protocol::al::INIT,
            al_error: false,
            al_code: 0,
            now,
            open_ports: 1,
            port_return_ns: [None; 4],
            sync0_next: None,
            sync0_cycle: 0,
            app_next_step: 0,
            wd_last_trigger: now,
            watchdog_expired: false,
            outputs_since_safeop: false,
            outputs_received: false,
            refuse_op: false,
            op_pending_since: None,
            mailbox_stalled: false,
            counters: SlaveCounters::default(),
            process_data_seen: false,
            spec,
        };
        esc.power_on_registers();
        esc.apply_sm_enables();
        esc
    }

    fn put16(&mut self, a: u16, v: u16) {
        let a = a as usize;
        self.mem[a..a + 2].copy_from_slice(&v.to_le_bytes());
    }

    fn put32(&mut self, a: u16, v: u32) {
        let a = a as usize;
        self.mem[a..a + 4].copy_from_slice(&v.to_le_bytes());
    }

    fn put64(&mut self, a: u16, v: u64) {
        let a = a as usize;
        self.mem[a..a + 8].copy_from_slice(&v.to_le_bytes());
    }

    pub fn get16(&self, a: u16) -> u16 {
        let a = a as usize;
        u16::from_le_bytes([self.mem[a], self.mem[a + 1]])
    }

    pub fn get32(&self, a: u16) -> u32 {
        let a = a as usize;
        u32::from_le_bytes([
            self.mem[a],
            self.mem[a + 1],
            self.mem[a + 2],
            self.mem[a + 3],
        ])
    }

    pub fn get64(&self, a: u16) -> u64 {
        let a = a as usize;
        let mut b = [0u8; 8];
        b.copy_from_slice(&self.mem[a..a + 8]);
        u64::from_le_bytes(b)
    }

    fn power_on_registers(&mut self) {
        let chip = self.spec.esc.profile();
        self.mem[reg::TYPE as usize] = chip.type_code;
        self.mem[reg::TYPE as usize + 1] = chip.revision;
        self.put16(reg::BUILD, chip.build);
        self.mem[reg::FMMU_COUNT as usize] = chip.fmmus;
        self.mem[reg::SM_COUNT as usize] = chip.sync_managers;
        self.mem[reg::RAM_SIZE as usize] = ((self.pdram_end - REGISTER_END) / 1024) as u8;
        self.mem[reg::PORT_DESC as usize] = chip.port_descriptor;
        let mut features = chip.features(self.spec.dc_supported);
        if !self.spec.lrw_supported {
            features |= crate::chip::feature::LRW_NOT_SUPPORTED;
        }
        self.put16(reg::FEATURES, features);
        self.put16(reg::WATCHDOG_DIVIDER, DEFAULT_WD_DIVIDER);
        self.put16(reg::WATCHDOG_TIME_PDI, DEFAULT_WD_TIME);
        self.put16(reg::WATCHDOG_TIME_PD, DEFAULT_WD_TIME);
        self.put16(reg::WATCHDOG_STATUS_PD, 1);
        // DC time control loop defaults (datasheet): speed counter start 0x1000, Δ filter
        // depth 4 (16 values), speed counter filter depth 12.
        self.put16(
            reg::DC_SPEED_COUNTER_START,
            crate::dc::DEFAULT_SPEED_COUNTER_START,
        );
        self.mem[reg::DC_FILTER_DEPTH as usize] = 0x04;
        self.mem[reg::DC_FILTER_DEPTH as usize + 1] = 0x0C;
        self.load_eeprom();
        self.update_al_registers();
        self.update_dl_status();
    }

    /// Load the ESC configuration area from the EEPROM (power-on and reload command).
    fn load_eeprom(&mut self) {
        let mut status = self.sii.static_status();
        if self.sii.image.len() >= 16 && !self.sii.checksum_ok() {
            status |= sii::CHECKSUM_ERROR | sii::NOT_LOADED;
            self.put16(reg::SII_CONTROL, status);
            return;
        }
        let alias = if self.sii.image.len() >= 10 {
            sii::word(&self.sii.image, 4)
        } else {
            self.spec.alias
        };
        self.put16(reg::STATION_ALIAS, alias);
        let w0 = sii::word(&self.sii.image, 0);
        self.mem[reg::PDI_CONTROL as usize] = w0 as u8;
        self.mem[reg::ESC_CONFIG as usize] = (w0 >> 8) as u8;
        self.put16(reg::SII_CONTROL, status);
    }

    pub fn eeprom_loaded(&self) -> bool {
        self.get16(reg::SII_CONTROL) & sii::NOT_LOADED == 0
    }

    /// DL status (0x0110) from the ports' link state: an open port has its link and
    /// communication bits, a port without a link its loop closed (`dl::port_bits`); the PDI
    /// watchdog never expires; the PDI is operational once the EEPROM is loaded.
    pub fn update_dl_status(&mut self) {
        let mut s = dl::STATUS_PDI_WATCHDOG;
        if self.eeprom_loaded() {
            s |= dl::STATUS_PDI_OPERATIONAL;
        }
        for p in 0..4 {
            s |= dl::port_bits(p, self.open_ports & (1 << p) != 0);
        }
        self.put16(reg::DL_STATUS, s);
    }

    pub fn update_al_registers(&mut self) {
        let status = al::AlStatus {
            state: self.al_state,
            error: self.al_error,
        }
        .encode();
        self.put16(reg::AL_STATUS, status);
        self.put16(reg::AL_STATUS_CODE, self.al_code);
    }

    pub fn station_address(&self) -> u16 {
        self.get16(reg::STATION_ADDRESS)
    }

    pub fn alias(&self) -> u16 {
        self.get16(reg::STATION_ALIAS)
    }

    /// DL control bit 24: the alias may be used for configured-address commands.
    /// FMMUs the chip has (0x0004); the registers of the others read 0 and ignore writes.
    fn fmmu_count(&self) -> usize {
        (self.mem[reg::FMMU_COUNT as usize] as usize).min(N_FMMU)
    }

    /// SyncManagers the chip has (0x0005).
    fn sm_count(&self) -> usize {
        (self.mem[reg::SM_COUNT as usize] as usize).min(N_SM)
    }

    pub fn alias_enabled(&self) -> bool {
        self.mem[at(reg::DL_CONTROL_ALIAS)] & 1 != 0
    }

    /// Does a configured-address datagram with ADP `adp` address this slave?
    pub fn matches_fixed(&self, adp: u16) -> bool {
        adp == self.station_address() || (self.alias_enabled() && adp == self.alias())
    }

    pub fn sii_image(&self) -> &[u8] {
        &self.sii.image
    }

    pub fn set_sii_busy_ns(&mut self, ns: u64) {
        self.sii.busy_ns = ns;
    }

    pub fn local_time(&self) -> u64 {
        self.dc.local(self.now)
    }

    pub fn system_time(&self) -> u64 {
        self.dc
            .local(self.now)
            .wrapping_add(self.get64(reg::DC_SYSTEM_TIME_OFFSET))
    }

    /// Raw memory, for diagnostics and tests (no side effects).
    pub fn memory(&self) -> &[u8] {
        &self.mem
    }

    // ------------------------------------------------------------------ master accesses

    /// Find the segment starting at `a`: its length (at most `len`) and the SyncManager
    /// guarding it, if any.
    fn segment(&self, a: usize, len: usize) -> (usize, Option<usize>) {
        let mut end = (a + len).min(MEM_SIZE);
        for (n, s) in self.sm.iter().enumerate() {
            if !s.configured() {
                continue;
            }
            let (ss, se) = (s.start as usize, s.start as usize + s.len as usize);
            if a >= ss && a < se {
                return (se.min(end) - a, Some(n));
            }
            if ss > a && ss < end {
                end = ss;
            }
        }
        if a < REGISTER_END && end > REGISTER_END {
            end = REGISTER_END;
        }
        (end - a, None)
    }

    /// Master read of `out.len()` bytes at `addr` (OR-ed into `out` when `or`). Returns false
    /// when a SyncManager refused the access.
    pub fn ecat_read(&mut self, addr: usize, out: &mut [u8], or: bool) -> bool {
        let mut ok = true;
        let mut cur = 0;
        while cur < out.len() {
            let a = addr + cur;
            if a >= MEM_SIZE {
                break;
            }
            let (n, sm) = self.segment(a, out.len() - cur);
            let seg = &mut out[cur..cur + n];
            match sm {
                Some(k) => ok &= self.sm_read(k, a, seg, or),
                None if a < REGISTER_END => self.register_read(a, seg, or),
                None => {
                    for (i, o) in seg.iter_mut().enumerate() {
                        let v = if a + i < self.pdram_end {
                            self.mem[a + i]
                        } else {
                            0
                        };
                        *o = if or { *o | v } else { v };
                    }
                }
            }
            cur += n;
        }
        ok
    }

    /// Master write of `data` at `addr`. Returns false when a SyncManager refused it.
    pub fn ecat_write(&mut self, addr: usize, data: &[u8]) -> bool {
        let mut ok = true;
        let mut cur = 0;
        while cur < data.len() {
            let a = addr + cur;
            if a >= MEM_SIZE {
                break;
            }
            let (n, sm) = self.segment(a, data.len() - cur);
            let seg = &data[cur..cur + n];
            match sm {
                Some(k) => ok &= self.sm_write(k, a, seg),
                None if a < REGISTER_END => self.register_write(a, seg),
                None => {
                    let end = (a + n).min(self.pdram_end);
                    if a < end {
                        self.mem[a..end].copy_from_slice(&seg[..end - a]);
                    }
                }
            }
            cur += n;
        }
        ok
    }

    /// The byte the master would read at `addr`, without side effects (bit-level writes
    /// read-modify-write through this).
    pub fn peek(&self, addr: usize) -> u8 {
        if addr >= MEM_SIZE {
            return 0;
        }
        for s in &self.sm {
            if s.configured() && s.contains(addr) && !s.is_mailbox() {
                return s.buffered_peek(addr - s.start as usize);
            }
        }
        if addr >= REGISTER_END && addr >= self.pdram_end {
            return 0;
        }
        self.mem[addr]
    }

    fn sm_read(&mut self, k: usize, a: usize, seg: &mut [u8], or: bool) -> bool {
        let s = &mut self.sm[k];
        if s.pdi_disabled {
            return false;
        }
        let off = a - s.start as usize;
        let last = off + seg.len() >= s.len as usize;
        if s.is_mailbox() {
            if s.ecat_writes() || !s.full {
                return false;
            }
            for (i, o) in seg.iter_mut().enumerate() {
                let v = self.mem[a + i];
                *o = if or { *o | v } else { v };
            }
            if last {
                s.full = false;
            }
        } else {
            s.buffered_read(off, seg, or);
        }
        true
    }

    fn sm_write(&mut self, k: usize, a: usize, seg: &[u8]) -> bool {
        let s = &mut self.sm[k];
        if s.pdi_disabled || !s.ecat_writes() {
            return false;
        }
        let off = a - s.start as usize;
        if s.is_mailbox() {
            if s.full {
                return false;
            }
            self.mem[a..a + seg.len()].copy_from_slice(seg);
            if off + seg.len() >= s.len as usize {
                s.full = true;
                self.mbx_rx_pending = true;
            }
        } else if s.buffered_write(off, seg) {
            let wd = s.control & WATCHDOG_TRIGGER != 0;
            if k == self.out_sm {
                self.outputs_since_safeop = true;
                self.outputs_received = true;
            }
            if wd {
                self.wd_last_trigger = self.now;
                self.watchdog_expired = false;
                self.put16(reg::WATCHDOG_STATUS_PD, 1);
            }
        }
        true
    }

    fn refresh_registers(&mut self, a: usize, len: usize) {
        if overlaps(a, len, at(reg::SM0), SM_END) {
            for k in 0..N_SM {
                let base = sm_base(k);
                self.mem[base + at(smr::STATUS)] = self.sm[k].status();
                self.mem[base + at(smr::PDI_CONTROL)] = self.sm[k].pdi_control();
            }
        }
        if overlaps(a, len, at(reg::DC_SYSTEM_TIME), at(reg::DC_SYSTEM_TIME) + 8) {
            let t = self.system_time();
            self.put64(reg::DC_SYSTEM_TIME, t);
        }
        if overlaps(a, len, at(reg::SII_CONTROL), at(reg::SII_CONTROL) + 2)
            && !self.sii.busy(self.now)
        {
            let v = self.get16(reg::SII_CONTROL) & !sii::BUSY;
            self.put16(reg::SII_CONTROL, v);
        }
    }

    fn register_read(&mut self, a: usize, seg: &mut [u8], or: bool) {
        self.refresh_registers(a, seg.len());
        for (i, o) in seg.iter_mut().enumerate() {
            let v = self.mem[a + i];
            *o = if or { *o | v } else { v };
        }
        // SYNC0 status clears on read.
        if overlaps(
            a,
            seg.len(),
            at(reg::DC_SYNC0_STATUS),
            at(reg::DC_SYNC0_STATUS) + 1,
        ) {
            self.mem[at(reg::DC_SYNC0_STATUS)] = 0;
        }
    }

    fn register_write(&mut self, a: usize, seg: &[u8]) {
        let len = seg.len();
        // SyncManager configuration bytes are locked while the SM is enabled, unless the same
        // write disables it.
        let mut sm_config_ok = [true; N_SM];
        if overlaps(a, len, at(reg::SM0), SM_END) {
            for (k, ok) in sm_config_ok.iter_mut().enumerate() {
                let act_addr = sm_base(k) + at(smr::ACTIVATE);
                let new_act = if act_addr >= a && act_addr < a + len {
                    seg[act_addr - a]
                } else {
                    self.sm[k].activate
                };
                *ok = !self.sm[k].configured() || new_act & ACT_ENABLE == 0;
            }
        }
        let mut sii_cmd: Option<u16> = None;
        for (i, &v) in seg.iter().enumerate() {
            let r = a + i;
            match r {
                // Error and watchdog counters clear on any write.
                _ if (at(reg::RX_ERROR_COUNTER)..at(reg::LOST_LINK_COUNTER) + 4).contains(&r)
                    || (at(reg::WATCHDOG_COUNTER_PD)..=at(reg::WATCHDOG_COUNTER_PDI))
                        .contains(&r) =>
                {
                    self.mem[r] = 0
                }
                _ if r == at(reg::SII_CONTROL) => {
                    let c = self.get16(reg::SII_CONTROL);
                    sii_cmd = Some((c & 0xff00) | v as u16);
                }
                _ if r == at(reg::SII_CONTROL) + 1 => {
                    let lo = sii_cmd.unwrap_or(0) & 0x00ff;
                    sii_cmd = Some(lo | ((v as u16) << 8));
                }
                // FMMUs the chip does not have ignore writes (not in WRITABLE either).
                _ if (at(reg::FMMU0)..FMMU_END).contains(&r)
                    && (r - at(reg::FMMU0)) / at(reg::FMMU_LEN) < self.fmmu_count() =>
                {
                    self.mem[r] = v;
                }
                _ if (at(reg::SM0)..SM_END).contains(&r) => {
                    let k = (r - at(reg::SM0)) / at(reg::SM_LEN);
                    if k >= self.sm_count() {
                        continue;
                    }
                    // Start, length and control are locked while enabled; activate is not;
                    // status and PDI control are the slave's.
                    let offset = ((r - at(reg::SM0)) % at(reg::SM_LEN)) as u16;
                    match offset {
                        smr::START..=smr::CONTROL if sm_config_ok[k] => self.mem[r] = v,
                        smr::ACTIVATE => self.mem[r] = v,
                        _ => {}
                    }
                }
                _ if reg_writable(r) => self.mem[r] = v,
                _ => {}
            }
        }
        // Hooks, in register order.
        if overlaps(a, len, at(reg::AL_CONTROL), at(reg::AL_CONTROL) + 2) {
            let ctl = self.get16(reg::AL_CONTROL);
            self.request_state(ctl);
        }
        if let Some(ctl) = sii_cmd {
            self.sii_command(ctl);
        }
        if overlaps(a, len, at(reg::FMMU0), FMMU_END) {
            self.fmmus.clear();
            for k in 0..N_FMMU {
                let base = at(reg::FMMU0) + k * at(reg::FMMU_LEN);
                if let Some(f) = Fmmu::decode(&self.mem[base..base + at(reg::FMMU_LEN)]) {
                    self.fmmus.push(f);
                }
            }
        }
        if overlaps(a, len, at(reg::SM0), SM_END) {
            for k in 0..N_SM {
                let base = sm_base(k);
                if overlaps(a, len, base, base + at(reg::SM_LEN)) {
                    self.sm_configured(k);
                }
            }
        }
        let dc_register = |r: u16, n: usize| overlaps(a, len, at(r), at(r) + n);
        if dc_register(reg::DC_RECEIVE_TIME_PORT0, 4) {
            self.latch_receive_times();
        }
        if dc_register(reg::DC_SYSTEM_TIME, 8) {
            self.system_time_compare(a, seg);
        }
        if dc_register(reg::DC_SPEED_COUNTER_START, 2) {
            self.dc.reset_loop(self.now);
        }
        if dc_register(reg::DC_ACTIVATION, 1) {
            self.dc_activation();
        }
    }

    fn sii_command(&mut self, ctl: u16) {
        let cur = self.get16(reg::SII_CONTROL);
        if self.sii.busy(self.now) {
            return;
        }
        if ctl & sii::CMD_MASK == 0 {
            // Writing no command clears the error bits.
            self.put16(reg::SII_CONTROL, cur & !(sii::ERROR_MASK | sii::CMD_MASK));
            return;
        }
        let address = self.get32(reg::SII_ADDRESS);
        let mut data = [0u8; 8];
        data.copy_from_slice(&self.mem[at(reg::SII_DATA)..at(reg::SII_DATA) + 8]);
        let mut status = self.sii.execute(ctl, address, &mut data, self.now);
        if ctl & sii::CMD_MASK == sii::CMD_READ {
            self.mem[at(reg::SII_DATA)..at(reg::SII_DATA) + 8].copy_from_slice(&data);
        }
        if ctl & sii::CMD_MASK == sii::CMD_RELOAD && status & sii::CHECKSUM_ERROR == 0 {
            self.load_eeprom();
        }
        status &= !sii::CMD_MASK;
        if self.sii.busy(self.now) {
            status |= sii::BUSY | (ctl & sii::CMD_MASK);
        }
        self.put16(reg::SII_CONTROL, status);
    }

    fn sm_configured(&mut self, k: usize) {
        let base = sm_base(k);
        let field = |offset: u16| base + at(offset);
        let start =
            u16::from_le_bytes([self.mem[field(smr::START)], self.mem[field(smr::START) + 1]]);
        let len = u16::from_le_bytes([
            self.mem[field(smr::LENGTH)],
            self.mem[field(smr::LENGTH) + 1],
        ]);
        let control = self.mem[field(smr::CONTROL)];
        let activate = self.mem[field(smr::ACTIVATE)];
        let s = &mut self.sm[k];
        let changed = s.start != start || s.len != len || s.control != control;
        let enabling = activate & ACT_ENABLE != 0 && s.activate & ACT_ENABLE == 0;
        let repeat_toggled = (activate ^ s.activate) & ACT_REPEAT != 0;
        s.start = start;
        s.len = len;
        s.control = control;
        s.activate = activate;
        if changed || enabling || activate & ACT_ENABLE == 0 {
            s.reset_buffers();
        }
        if repeat_toggled && s.is_mailbox() && !s.ecat_writes() {
            self.mailbox_repeat(k);
        }
    }

    // ------------------------------------------------------------------ distributed clock

    fn latch_receive_times(&mut self) {
        if !self.spec.dc_supported {
            return;
        }
        // Port 0 latches at the processing unit's entry; every other open port when the
        // frame comes back into it from its branch. Closed ports keep their old value.
        let t0 = self.dc.local(self.now);
        self.put32(reg::DC_RECEIVE_TIME_PORT0, t0 as u32);
        for p in 1..4u16 {
            if let Some(back) = self.port_return_ns[p as usize] {
                let t = self.dc.local(self.now + back);
                self.put32(reg::DC_RECEIVE_TIME_PORT0 + 4 * p, t as u32);
            }
        }
        self.put64(reg::DC_RECEIVE_TIME_PU, t0);
    }

    fn system_time_compare(&mut self, a: usize, seg: &[u8]) {
        if !self.spec.dc_supported {
            return;
        }
        // Rebuild the written value from the bytes that landed on 0x0910..0x0918.
        let mut v = [0u8; 8];
        let mut n = 0;
        for (i, &b) in seg.iter().enumerate() {
            let r = a + i;
            let time = at(reg::DC_SYSTEM_TIME);
            if (time..time + 8).contains(&r) {
                v[r - time] = b;
                n = n.max(r - time + 1);
            }
        }
        let received = u64::from_le_bytes(v);
        let delay = self.get32(reg::DC_SYSTEM_TIME_DELAY) as u64;
        let local_sys = self.system_time();
        let diff: i64 = if n <= 4 {
            (local_sys as u32).wrapping_sub((received.wrapping_add(delay)) as u32) as i32 as i64
        } else {
            local_sys.wrapping_sub(received.wrapping_add(delay)) as i64
        };
        let depth = self.mem[reg::DC_FILTER_DEPTH as usize] & 0x0f;
        let speed = self.get16(reg::DC_SPEED_COUNTER_START) & 0x7fff;
        let filtered = self.dc.compare(self.now, diff, depth, speed);
        self.put32(reg::DC_SYSTEM_TIME_DIFF, encode_time_difference(filtered));
    }

    fn dc_activation(&mut self) {
        let act = self.mem[reg::DC_ACTIVATION as usize];
        let cycle = self.get32(reg::DC_SYNC0_CYCLE) as u64;
        let sync0 = dc::ACTIVATE_CYCLIC | dc::ACTIVATE_SYNC0;
        if !self.spec.dc_supported || act & sync0 != sync0 || cycle == 0 {
            self.sync0_next = None;
            self.sync0_cycle = 0;
            return;
        }
        let start = self.get64(reg::DC_START_TIME);
        let now = self.system_time();
        let next = if start >= now {
            start
        } else {
            // A start time in the past: a real ESC would wait for the 32-bit wrap; we start at
            // the next cycle boundary instead and count it.
            self.counters.sync0_late_starts += 1;
            start.saturating_add((now - start).div_ceil(cycle).saturating_mul(cycle))
        };
        self.sync0_cycle = cycle;
        self.sync0_next = Some(next);
    }

    pub fn sync0_active(&self) -> bool {
        self.sync0_next.is_some()
    }

    // ------------------------------------------------------------------ logical addressing

    /// Process a logical datagram (`data` covers logical bytes from `laddr`). `incoming` holds
    /// the data as it arrived when the command both reads and writes. Returns the working
    /// counter increment (LRW: +1 read, +2 write; LRD, LWR: +1).
    pub fn logical(
        &mut self,
        laddr: u32,
        data: &mut [u8],
        reads: bool,
        writes: bool,
        incoming: &mut Vec<u8>,
    ) -> u16 {
        if self.fmmus.is_empty() || data.is_empty() {
            return 0;
        }
        let rw = reads && writes;
        if rw && !self.spec.lrw_supported {
            // 0x0008 bit 9: this ESC ignores LRW; the working counter stays as it came.
            return 0;
        }
        let d0 = laddr as u64 * 8;
        let d1 = d0 + data.len() as u64 * 8;
        let mut any = false;
        for f in &self.fmmus {
            if f.first_bit() < d1 && f.end_bit() > d0 && ((f.read && reads) || (f.write && writes))
            {
                any = true;
                break;
            }
        }
        if !any {
            return 0;
        }
        self.process_data_seen = true;
        if rw {
            incoming.clear();
            incoming.extend_from_slice(data);
        }
        let (mut read_ok, mut write_ok) = (false, false);
        // The FMMUs as they were when the datagram arrived: a logical write that lands on the
        // FMMU registers themselves reconfigures them for the next datagram, not this one
        // (and never shortens the list being walked). A copy on the stack: no allocation.
        let mut fmmus = [Fmmu::default(); N_FMMU];
        let n = self.fmmus.len().min(N_FMMU);
        fmmus[..n].copy_from_slice(&self.fmmus[..n]);
        // Reads first, then writes from the incoming data: a byte read and written through
        // the same logical address is exchanged, as the ESC does on the fly.
        for f in &fmmus[..n] {
            if f.read && reads {
                read_ok |= self.fmmu_read(f, d0, d1, data);
            }
        }
        for f in &fmmus[..n] {
            if f.write && writes {
                let src: &[u8] = if rw { incoming } else { data };
                write_ok |= self.fmmu_write(f, d0, d1, src);
            }
        }
        // ESC datasheet, "Working counter": LRW counts +1 for a read and +2 for a write; LRD
        // and LWR count +1 each.
        let write_increment = if rw { 2 } else { 1 };
        read_ok as u16 + write_increment * write_ok as u16
    }

    fn fmmu_read(&mut self, f: &Fmmu, d0: u64, d1: u64, data: &mut [u8]) -> bool {
        let lo = f.first_bit().max(d0);
        let hi = f.end_bit().min(d1);
        if lo >= hi {
            return false;
        }
        if f.byte_aligned() {
            let phys = f.physical_bit(lo) / 8;
            let off = ((lo - d0) / 8) as usize;
            let n = ((hi - lo) / 8) as usize;
            return self.ecat_read(phys as usize, &mut data[off..off + n], false);
        }
        let mut ok = true;
        let mut lb = lo;
        while lb < hi {
            let pb = f.physical_bit(lb);
            let pbit = pb % 8;
            let n = (8 - pbit).min(hi - lb);
            let mut b = [0u8; 1];
            ok &= self.ecat_read((pb / 8) as usize, &mut b, false);
            for k in 0..n {
                let bit = (b[0] >> (pbit + k)) & 1;
                let fb = (lb + k - d0) as usize;
                let d = &mut data[fb / 8];
                *d = (*d & !(1 << (fb % 8))) | (bit << (fb % 8));
            }
            lb += n;
        }
        ok
    }

    fn fmmu_write(&mut self, f: &Fmmu, d0: u64, d1: u64, src: &[u8]) -> bool {
        let lo = f.first_bit().max(d0);
        let hi = f.end_bit().min(d1);
        if lo >= hi {
            return false;
        }
        if f.byte_aligned() {
            let phys = f.physical_bit(lo) / 8;
            let off = ((lo - d0) / 8) as usize;
            let n = ((hi - lo) / 8) as usize;
            return self.ecat_write(phys as usize, &src[off..off + n]);
        }
        let mut ok = true;
        let mut lb = lo;
        while lb < hi {
            let pb = f.physical_bit(lb);
            let pbit = pb % 8;
            let n = (8 - pbit).min(hi - lb);
            let addr = (pb / 8) as usize;
            let mut v = self.peek(addr);
            for k in 0..n {
                let fb = (lb + k - d0) as usize;
                let bit = (src[fb / 8] >> (fb % 8)) & 1;
                let p = pbit + k;
                v = (v & !(1 << p)) | (bit << p);
            }
            ok &= self.ecat_write(addr, &[v]);
            lb += n;
        }
        ok
    }

    // ------------------------------------------------------------------ AL state machine

    /// The master wrote AL control.
    pub fn request_state(&mut self, ctl: u16) {
        use ether_ros_protocol::al::*;
        let requested = ctl as u8 & STATE_MASK;
        let ack = ctl as u8 & ERROR != 0;
        if self.al_error {
            if !ack {
                // An error must be acknowledged before the slave follows a new request.
                return;
            }
            self.al_error = false;
            self.al_code = NO_ERROR;
        }
        if !matches!(requested, INIT | PREOP | BOOT | SAFEOP | OP) {
            self.fail(UNKNOWN_REQUESTED_STATE);
            return;
        }
        let cur = self.al_state;
        // Any new request replaces a SAFEOP->OP request still waiting for outputs.
        let was_pending = self.op_pending_since.take();
        if requested == cur {
            self.update_al_registers();
            return;
        }
        if (cur, requested) == (SAFEOP, OP) && !self.refuse_op && self.waits_for_outputs() {
            // As real slave stacks do: the request stays pending (AL status SAFEOP, no error)
            // until the first valid outputs arrive or the ESI's SAFEOP->OP timeout runs out.
            // Masters that request OP first and start the cyclic exchange afterwards
            // (ethercrab) depend on this.
            self.op_pending_since = Some(was_pending.unwrap_or(self.now));
            self.update_al_registers();
            return;
        }
        let result = match (cur, requested) {
            (_, INIT) => Ok(()),
            (INIT, PREOP) => self.check_mailbox(self.mailbox, false),
            (INIT, BOOT) => self.check_mailbox(self.boot_mailbox, true),
            (PREOP, SAFEOP) => self.check_process_data(),
            (SAFEOP, OP) => self.check_op(),
            (OP, SAFEOP) | (OP, PREOP) | (SAFEOP, PREOP) => Ok(()),
            _ => Err(INVALID_REQUESTED_STATE),
        };
        match result {
            Ok(()) => self.enter_state(requested),
            Err(code) => {
                // CoE emergency codes of the state machine (ETG.1000.6): 0xA000 is a refused
                // PREOP → SAFEOP, 0xA001 a refused SAFEOP → OP.
                let emergency = if (cur, requested) == (SAFEOP, OP) {
                    EMERGENCY_SAFEOP_TO_OP
                } else {
                    EMERGENCY_PREOP_TO_SAFEOP
                };
                self.fail_with_emergency(code, emergency);
            }
        }
    }

    /// Set the error indication with `code`, staying in the current state.
    pub fn fail(&mut self, code: u16) {
        self.fail_with_emergency(code, EMERGENCY_PREOP_TO_SAFEOP);
    }

    /// `fail`, sending the CoE emergency `emergency` (with the AL status code) when the slave
    /// has a mailbox.
    fn fail_with_emergency(&mut self, code: u16, emergency: u16) {
        self.al_error = true;
        self.al_code = code;
        self.counters.al_errors += 1;
        self.update_al_registers();
        if self.mailbox.is_some() && self.al_state != ether_ros_protocol::al::INIT {
            // CoE emergency "state machine transition error" carrying the AL status code.
            let c = code.to_le_bytes();
            let generic = ether_ros_protocol::emergency::ERROR_REGISTER_GENERIC;
            let msg = CoeServer::emergency(emergency, generic, [c[0], c[1], 0, 0, 0]);
            self.queue_mailbox(mailbox::TYPE_COE, msg);
        }
    }

    fn enter_state(&mut self, state: u8) {
        use ether_ros_protocol::al::*;
        let prev = self.al_state;
        self.al_state = state;
        self.apply_sm_enables();
        if state == INIT {
            self.mbx_queue.clear();
            self.mbx_rx_pending = false;
            self.mbx_last_rx_counter = 0;
            self.coe = CoeServer::new();
            for k in 0..N_SM {
                if self.sm[k].is_mailbox() {
                    self.sm[k].full = false;
                }
            }
        }
        if state == SAFEOP && prev == PREOP {
            self.outputs_since_safeop = false;
            self.outputs_received = false;
        }
        if state == OP {
            self.wd_last_trigger = self.now;
            self.watchdog_expired = false;
            self.put16(reg::WATCHDOG_STATUS_PD, 1);
        }
        self.update_al_registers();
    }

    /// The slave application enables the mailbox SyncManagers from PREOP on and the
    /// process-data ones in SAFEOP and OP (PDI control bit 0), as SOES-style stacks do.
    fn apply_sm_enables(&mut self) {
        use ether_ros_protocol::al::*;
        let state = self.al_state;
        let mbx_on = state != INIT;
        let pd_on = matches!(state, SAFEOP | OP);
        let mbx_sms: &[usize] = if self.mailbox.is_some() || self.boot_mailbox.is_some() {
            &[0, 1]
        } else {
            &[]
        };
        for &k in mbx_sms {
            self.sm[k].pdi_disabled = !mbx_on;
        }
        for k in [self.out_sm, self.in_sm] {
            if !mbx_sms.contains(&k) {
                self.sm[k].pdi_disabled = !pd_on;
            }
        }
    }

    fn check_mailbox(&self, mbx: Option<MailboxSpec>, boot: bool) -> Result<(), u16> {
        use ether_ros_protocol::al::*;
        let Some(m) = mbx else {
            return if boot {
                Err(BOOTSTRAP_NOT_SUPPORTED)
            } else {
                Ok(())
            };
        };
        let (s0, s1) = (&self.sm[0], &self.sm[1]);
        let ok0 = s0.configured()
            && s0.start == m.rx_offset
            && s0.len == m.rx_size
            && s0.control & (smr::MODE_MASK | smr::DIR_MASK) == smr::MODE_MAILBOX | smr::DIR_WRITE;
        let ok1 = s1.configured()
            && s1.start == m.tx_offset
            && s1.len == m.tx_size
            && s1.control & (smr::MODE_MASK | smr::DIR_MASK) == smr::MODE_MAILBOX | smr::DIR_READ;
        if ok0 && ok1 {
            Ok(())
        } else {
            Err(INVALID_MAILBOX_CONFIG)
        }
    }

    /// Recompute the process-data maps from the dictionary (or the SII).
    fn build_maps(&mut self) -> Result<(), u16> {
        use ether_ros_protocol::al::*;
        let out = match crate::pdo::from_od(&self.od, coe_facts::RXPDO_ASSIGN) {
            Some(Ok(m)) => m,
            Some(Err(_)) => return Err(INVALID_OUTPUT_MAPPING),
            None => self.sii_map(sii_category::RXPDO, self.out_sm),
        };
        let inp = match crate::pdo::from_od(&self.od, coe_facts::TXPDO_ASSIGN) {
            Some(Ok(m)) => m,
            Some(Err(_)) => return Err(INVALID_INPUT_MAPPING),
            None => self.sii_map(sii_category::TXPDO, self.in_sm),
        };
        self.out_map = out;
        self.in_map = inp;
        Ok(())
    }

    fn sii_map(&self, category: u16, sm: usize) -> PdoMap {
        let mut entries = Vec::new();
        for p in sii::pdos(&self.sii.image, category) {
            if p.sync_manager as usize == sm {
                entries.extend(p.entries.iter().copied());
            }
        }
        crate::pdo::from_entries(&self.od, &entries)
    }

    fn check_process_data(&mut self) -> Result<(), u16> {
        use ether_ros_protocol::al::*;
        self.build_maps()?;
        let check = |s: &SyncManager, bytes: usize, control: u8| {
            if bytes == 0 {
                !s.configured()
            } else {
                s.configured()
                    && s.len as usize == bytes
                    && s.control & (smr::MODE_MASK | smr::DIR_MASK) == control
            }
        };
        if !check(
            &self.sm[self.out_sm],
            self.out_map.bytes(),
            smr::MODE_BUFFERED | smr::DIR_WRITE,
        ) {
            return Err(INVALID_OUTPUT_CONFIG);
        }
        if !check(
            &self.sm[self.in_sm],
            self.in_map.bytes(),
            smr::MODE_BUFFERED | smr::DIR_READ,
        ) {
            return Err(INVALID_INPUT_CONFIG);
        }
        if self.spec.dc_required && !self.sync0_active() {
            return Err(INVALID_DC_SYNC_CONFIG);
        }
        Ok(())
    }

    fn check_op(&self) -> Result<(), u16> {
        use ether_ros_protocol::al::*;
        if self.refuse_op {
            return Err(SYNCHRONIZATION_ERROR);
        }
        if self.waits_for_outputs() {
            return Err(NO_VALID_OUTPUTS);
        }
        Ok(())
    }

    /// The slave has outputs but none arrived since SAFEOP.
    fn waits_for_outputs(&self) -> bool {
        self.out_map.bytes() > 0 && !self.outputs_since_safeop
    }

    /// Is a SAFEOP->OP request waiting for outputs? (for tests and `slave_info`)
    pub fn op_request_pending(&self) -> bool {
        self.op_pending_since.is_some()
    }

    /// A pending SAFEOP->OP request: go to OP once outputs arrived, refuse it when the
    /// timeout ran out (AL status 0x0019 "no valid outputs", emergency 0xA001).
    fn resolve_pending_op(&mut self) {
        let Some(since) = self.op_pending_since else {
            return;
        };
        if self.al_state != ether_ros_protocol::al::SAFEOP || self.al_error {
            self.op_pending_since = None;
            return;
        }
        if !self.waits_for_outputs() {
            self.op_pending_since = None;
            self.enter_state(ether_ros_protocol::al::OP);
            return;
        }
        let timeout = u64::from(self.spec.safeop_op_timeout_ms) * 1_000_000;
        if self.now.saturating_sub(since) > timeout {
            self.op_pending_since = None;
            self.fail_with_emergency(
                ether_ros_protocol::al::NO_VALID_OUTPUTS,
                EMERGENCY_SAFEOP_TO_OP,
            );
        }
    }

    // ------------------------------------------------------------------ mailbox

    fn queue_mailbox(&mut self, kind: u8, payload: Vec<u8>) {
        if self.mbx_queue.len() < MAILBOX_QUEUE_LIMIT {
            let mut msg = Vec::with_capacity(mailbox::HEADER_LEN + payload.len());
            let header = mailbox::Header {
                length: payload.len() as u16,
                address: 0,
                channel: 0,
                mbx_type: kind,
                counter: 0,
            };
            msg.extend_from_slice(&header.encode());
            msg.extend_from_slice(&payload);
            self.mbx_queue.push_back(msg);
        }
    }

    fn mailbox_error(&mut self, detail: u16) {
        self.counters.mailbox_errors += 1;
        let mut p = Vec::with_capacity(4);
        p.extend_from_slice(&mailbox::ERROR_REPLY_TYPE.to_le_bytes());
        p.extend_from_slice(&detail.to_le_bytes());
        self.queue_mailbox(mailbox::TYPE_ERR, p);
    }

    /// The slave application's mailbox work: consume a full write mailbox, fill an empty read
    /// mailbox from the queue.
    pub fn service_mailbox(&mut self) {
        if self.mailbox_stalled || self.mailbox.is_none() && self.boot_mailbox.is_none() {
            return;
        }
        if self.mbx_rx_pending && self.sm[0].full {
            self.mbx_rx_pending = false;
            let start = (self.sm[0].start as usize).min(MEM_SIZE);
            let end = (start + self.sm[0].len as usize).min(MEM_SIZE);
            let area = &self.mem[start..end];
            let len = area.len();
            let (msg_len, kind, counter) = match mailbox::Header::decode(area) {
                Some(h) => (h.length as usize, h.mbx_type, h.counter),
                None => (0, 0, 0),
            };
            self.sm[0].full = false;
            self.counters.mailbox_received += 1;
            let repeated = counter != 0 && counter == self.mbx_last_rx_counter;
            self.mbx_last_rx_counter = counter;
            if len < mailbox::HEADER_LEN || msg_len + mailbox::HEADER_LEN > len {
                self.mailbox_error(mailbox::ERR_INVALID_SIZE);
            } else if msg_len < 2 && kind == mailbox::TYPE_COE {
                self.mailbox_error(mailbox::ERR_SIZE_TOO_SHORT);
            } else if repeated {
                // A retry of the message already handled: ignore it.
            } else if kind == mailbox::TYPE_COE {
                let mut out = Vec::new();
                let max_payload = (self.sm[1].len as usize).saturating_sub(mailbox::HEADER_LEN);
                let data_start = start + mailbox::HEADER_LEN;
                let request = self.mem[data_start..data_start + msg_len].to_vec();
                self.coe
                    .handle(&request, &mut self.od, self.al_state, max_payload, &mut out);
                for p in out {
                    self.queue_mailbox(mailbox::TYPE_COE, p);
                }
            } else {
                self.mailbox_error(mailbox::ERR_UNSUPPORTED_PROTOCOL);
            }
        }
        let s1 = &self.sm[1];
        if !self.mbx_queue.is_empty() && s1.enabled() && s1.is_mailbox() && !s1.full {
            if let Some(mut msg) = self.mbx_queue.pop_front() {
                self.mbx_tx_counter = self.mbx_tx_counter % 7 + 1;
                if let Some(mut header) = mailbox::Header::decode(&msg) {
                    header.counter = self.mbx_tx_counter;
                    msg[..mailbox::HEADER_LEN].copy_from_slice(&header.encode());
                }
                self.place_in_read_mailbox(&msg);
                self.mbx_last_sent = msg;
                self.counters.mailbox_sent += 1;
            }
        }
    }

    fn place_in_read_mailbox(&mut self, msg: &[u8]) {
        let (start, len) = (self.sm[1].start as usize, self.sm[1].len as usize);
        let end = (start + len).min(MEM_SIZE);
        let area = &mut self.mem[start..end];
        area.fill(0);
        let n = msg.len().min(area.len());
        area[..n].copy_from_slice(&msg[..n]);
        self.sm[1].full = true;
    }

    /// The master toggled the repeat request of the read mailbox: put the last message back
    /// and acknowledge.
    fn mailbox_repeat(&mut self, k: usize) {
        if self.mailbox_stalled {
            return;
        }
        if !self.mbx_last_sent.is_empty() {
            let msg = std::mem::take(&mut self.mbx_last_sent);
            self.place_in_read_mailbox(&msg);
            self.mbx_last_sent = msg;
        }
        self.sm[k].repeat_ack = self.sm[k].activate & ACT_REPEAT != 0;
    }

    pub fn mailbox_queue_len(&self) -> usize {
        self.mbx_queue.len()
    }

    // ------------------------------------------------------------------ application side

    fn outputs_valid(&self) -> bool {
        self.al_state == ether_ros_protocol::al::OP
            && !self.watchdog_expired
            && self.outputs_received
    }

    /// SM buffer of outputs → dictionary (only in OP: SAFEOP keeps outputs safe).
    pub fn latch_outputs(&mut self) {
        if self.al_state != ether_ros_protocol::al::OP {
            return;
        }
        let k = self.out_sm;
        if let Some(buf) = self.sm[k].pdi_take() {
            crate::pdo::buffer_to_od(&self.out_map, buf, &mut self.od);
        }
    }

    /// Dictionary → SM buffer of inputs (SAFEOP and OP).
    pub fn latch_inputs(&mut self) {
        if !matches!(
            self.al_state,
            ether_ros_protocol::al::SAFEOP | ether_ros_protocol::al::OP
        ) {
            return;
        }
        let k = self.in_sm;
        if !self.sm[k].enabled() || self.in_map.bits == 0 {
            return;
        }
        let (map, od) = (&self.in_map, &self.od);
        self.sm[k].pdi_publish(|buf| crate::pdo::od_to_buffer(map, od, buf));
    }

    /// Advance the application to host time `host`: device steps at the device period and
    /// SYNC0 events in order, bounded catch-up, and the process-data watchdog.
    pub fn advance(&mut self, host: u64) {
        self.now = host;
        let local_now = self.dc.local(host);
        let period = self.device.as_ref().map(|d| d.period_ns().max(1_000));
        if self.app_next_step == 0 {
            self.app_next_step = local_now;
        }
        // Bound the catch-up.
        let horizon = local_now.saturating_sub(MAX_CATCH_UP_NS);
        if let Some(p) = period {
            if self.app_next_step < horizon {
                let skipped = (horizon - self.app_next_step).div_ceil(p);
                self.counters.device_steps_skipped += skipped;
                self.app_next_step = self.app_next_step.saturating_add(skipped.saturating_mul(p));
            }
        }
        // SYNC0 runs in system time; schedule it in local time (the offset may have changed).
        let offset = self.get64(reg::DC_SYSTEM_TIME_OFFSET);
        let cycle = self.sync0_cycle.max(1);
        let mut sync_local = self.sync0_next.map(|s| s.wrapping_sub(offset));
        if let Some(n) = sync_local {
            if n < horizon {
                let skip = (horizon - n).div_ceil(cycle);
                sync_local = Some(n.saturating_add(skip.saturating_mul(cycle)));
            }
        }
        // Never loop forever on absurd settings: past this many events, skip to now.
        let mut budget = 4 * MAX_CATCH_UP_NS / 1_000;
        loop {
            let next_dev = if period.is_some() {
                self.app_next_step
            } else {
                u64::MAX
            };
            let next_sync = sync_local.unwrap_or(u64::MAX);
            let t = next_dev.min(next_sync);
            if t > local_now {
                break;
            }
            if budget == 0 {
                if let Some(p) = period {
                    self.app_next_step = local_now.saturating_add(p);
                }
                sync_local = sync_local.map(|_| local_now.saturating_add(cycle));
                break;
            }
            budget -= 1;
            if next_sync <= next_dev {
                self.latch_outputs();
                self.latch_inputs();
                self.mem[reg::DC_SYNC0_STATUS as usize] = 1;
                self.counters.sync0_events += 1;
                sync_local = Some(next_sync.saturating_add(cycle));
            } else {
                let valid = self.outputs_valid();
                if let Some(d) = self.device.as_mut() {
                    d.step(&mut self.od, t, valid);
                }
                self.send_device_emergencies();
                self.counters.device_steps += 1;
                self.app_next_step = self
                    .app_next_step
                    .saturating_add(period.unwrap_or(u64::MAX));
            }
        }
        self.sync0_next = sync_local.map(|n| n.wrapping_add(offset));
        self.check_watchdog();
        // Time passes for a pending SAFEOP->OP request too (its timeout), before the frame's
        // datagrams read the AL status.
        self.resolve_pending_op();
    }

    /// Queue the CoE emergencies the firmware raised (a slave with a mailbox, past INIT, as
    /// for the state machine's own emergencies); they are dropped otherwise.
    fn send_device_emergencies(&mut self) {
        while let Some(e) = self.device.as_mut().and_then(|d| d.take_emergency()) {
            if self.mailbox.is_some() && self.al_state != ether_ros_protocol::al::INIT {
                let msg = CoeServer::emergency(e.error_code, e.error_register, e.data);
                self.queue_mailbox(mailbox::TYPE_COE, msg);
            }
        }
    }

    fn watchdog_ns(&self) -> u64 {
        let divider = self.get16(reg::WATCHDOG_DIVIDER) as u64;
        let time = self.get16(reg::WATCHDOG_TIME_PD) as u64;
        (divider + 2) * 40 * time
    }

    fn check_watchdog(&mut self) {
        let s = &self.sm[self.out_sm];
        let armed = s.enabled() && s.control & WATCHDOG_TRIGGER != 0 && !s.is_mailbox();
        let wd = self.watchdog_ns();
        if !armed || wd == 0 || self.watchdog_expired {
            return;
        }
        if self.now.saturating_sub(self.wd_last_trigger) > wd {
            self.watchdog_expired = true;
            self.counters.watchdog_expirations += 1;
            self.put16(reg::WATCHDOG_STATUS_PD, 0);
            let c = self.mem[reg::WATCHDOG_COUNTER_PD as usize];
            self.mem[reg::WATCHDOG_COUNTER_PD as usize] = c.saturating_add(1);
            if self.al_state == ether_ros_protocol::al::OP {
                self.enter_state(ether_ros_protocol::al::SAFEOP);
                self.fail(ether_ros_protocol::al::SM_WATCHDOG);
            }
        }
    }

    /// Per-frame work before the datagrams: free-run input latch.
    pub fn before_frame(&mut self) {
        self.counters.frames += 1;
        if !self.sync0_active() {
            self.latch_inputs();
        }
    }

    /// Per-frame work after the datagrams: free-run output latch and the mailbox.
    pub fn after_frame(&mut self) {
        if std::mem::take(&mut self.process_data_seen) {
            self.counters.process_data_frames += 1;
        }
        if !self.sync0_active() {
            self.latch_outputs();
        }
        self.resolve_pending_op();
        self.service_mailbox();
    }

    pub fn probe(&self) -> Vec<(&'static str, f64)> {
        self.device.as_ref().map(|d| d.probe()).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The CoE error code of the emergency queued last (mailbox header 6 + CoE header 2).
    fn last_emergency_code(esc: &Esc) -> Option<u16> {
        let msg = esc.mbx_queue.back()?;
        Some(u16::from_le_bytes([msg[8], msg[9]]))
    }

    fn slave_with_mailbox() -> Esc {
        let spec = SlaveSpec {
            dc_supported: true,
            dc_required: true,
            mailbox: Some(MailboxSpec {
                rx_offset: 0x1000,
                rx_size: 128,
                tx_offset: 0x1080,
                tx_size: 128,
            }),
            ..Default::default()
        };
        Esc::new(spec, 0, 0)
    }

    #[test]
    fn refused_safeop_to_op_sends_emergency_a001() {
        let mut esc = slave_with_mailbox();
        esc.al_state = ether_ros_protocol::al::SAFEOP;
        esc.refuse_op = true;
        esc.request_state(ether_ros_protocol::al::OP as u16);
        assert_eq!(esc.al_code, ether_ros_protocol::al::SYNCHRONIZATION_ERROR);
        assert_eq!(last_emergency_code(&esc), Some(0xA001));
    }

    #[test]
    fn refused_preop_to_safeop_sends_emergency_a000() {
        let mut esc = slave_with_mailbox();
        esc.al_state = ether_ros_protocol::al::PREOP;
        // The slave needs SYNC0, which is not running: SAFEOP is refused.
        esc.request_state(ether_ros_protocol::al::SAFEOP as u16);
        assert_eq!(esc.al_code, ether_ros_protocol::al::INVALID_DC_SYNC_CONFIG);
        assert_eq!(last_emergency_code(&esc), Some(0xA000));
    }
}
