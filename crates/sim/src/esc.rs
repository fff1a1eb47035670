//! One virtual EtherCAT slave controller: 64 KiB of memory with the register file, SII,
//! SyncManagers, FMMUs, distributed clock, watchdog, and the slave application behind it
//! (AL state machine, mailbox/CoE, process-data copy, the device model).
//!
//! Every master access goes through `ecat_read`/`ecat_write`, which split it into register,
//! SyncManager and plain-memory segments and report whether the ESC accepted it (a refused
//! SyncManager access leaves the working counter alone, as on hardware).

use std::collections::VecDeque;

use ether_ros_protocol::reg::{self, dc, dl, sm as smr};
use ether_ros_protocol::sii::{category as sii_category, syncm, word as sii_word};
use ether_ros_protocol::{al, coe as coe_facts, mailbox};

use crate::coe::CoeServer;
use crate::dc::{encode_time_difference, DcClock};
use crate::device::DeviceApp;
use crate::fmmu::Fmmu;
use crate::foe::FoeServer;
use crate::od::ObjectDictionary;
use crate::pdo::PdoMap;
use crate::sii::{self, Sii};
use crate::sm::{SyncManager, ACT_ENABLE, ACT_REPEAT, WATCHDOG_TRIGGER};
use crate::soe::SoeServer;
use crate::spec::{MailboxSpec, SlaveSpec};

/// Size of the ESC's address space (registers and process RAM).
pub const MEM_SIZE: usize = 0x1_0000;
/// End of the register area: process RAM starts here.
pub const REGISTER_END: usize = reg::PDRAM as usize;
/// FMMUs an ESC of this simulator has (at most; the chip may have fewer).
pub const N_FMMU: usize = 8;
/// SyncManagers an ESC of this simulator has (at most; the chip may have fewer).
pub const N_SM: usize = 8;
/// Default watchdog divider (100 µs units) and process-data watchdog time (100 ms).
const DEFAULT_WD_DIVIDER: u16 = 0x09C2;
const DEFAULT_WD_TIME: u16 = 0x03E8;
/// DC time stamps and the system time advance in steps of the ESC's 100 MHz clock.
pub const DC_GRANULARITY_NS: u64 = 10;
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
    /// Frames that reached this slave before its last reset or topology change (the network
    /// adds those since: `Network::slave_frames`).
    pub frames: u64,
    /// Frames in which a logical datagram reached this slave's FMMUs (its process data went
    /// by): with groups at their own cycles, this is the slave's own exchange rate.
    pub process_data_frames: u64,
    /// Steps of the device model.
    pub device_steps: u64,
    /// Device steps skipped because the model was not due.
    pub device_steps_skipped: u64,
    /// SYNC0 events raised.
    pub sync0_events: u64,
    /// SYNC0 events whose device step started late.
    pub sync0_late_starts: u64,
    /// SYNC0 events a frame latched because the firmware's worker had not got to them yet.
    pub sync0_frame_latches: u64,
    /// Times the process data watchdog expired.
    pub watchdog_expirations: u64,
    /// Mailbox messages received from the master.
    pub mailbox_received: u64,
    /// Mailbox messages sent to the master.
    pub mailbox_sent: u64,
    /// Mailbox errors answered (unknown protocol, bad header, ...).
    pub mailbox_errors: u64,
    /// AL state transitions refused.
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
    // 0x0501 (PDI access state) belongs to the PDI: EtherCAT writes only 0x0500.
    (reg::SII_CONFIG, 1),
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

/// One virtual EtherCAT slave controller: its memory and registers, SyncManagers, FMMUs,
/// distributed clock, EEPROM, mailbox, object dictionary and the device model behind it.
pub struct Esc {
    /// The spec the slave was built from.
    pub spec: SlaveSpec,
    /// Position on the bus (auto-increment order).
    pub position: usize,
    mem: Box<[u8]>,
    /// The SyncManagers as the master configured them.
    pub sm: [SyncManager; N_SM],
    fmmus: Vec<Fmmu>,
    sii: Sii,
    /// The distributed clock (local time, SYNC0/1).
    pub dc: DcClock,
    pdram_end: usize,
    /// The object dictionary the CoE server and the device model share.
    pub od: ObjectDictionary,
    coe: CoeServer,
    /// The SoE server, for a slave whose SII announces SoE (word 0x1C bit 4).
    soe: Option<SoeServer>,
    /// The FoE server, for a slave whose SII announces FoE (word 0x1C bit 3).
    foe: Option<FoeServer>,
    /// The device model (firmware), None for a slave without one.
    pub device: Option<Box<dyn DeviceApp>>,
    /// The standard mailbox from the spec (used when the SII leaves it out).
    pub mailbox: Option<MailboxSpec>,
    boot_mailbox: Option<MailboxSpec>,
    mbx_queue: VecDeque<Vec<u8>>,
    mbx_last_rx_counter: u8,
    mbx_tx_counter: u8,
    mbx_last_sent: Vec<u8>,
    mbx_rx_pending: bool,
    /// The process-data SyncManagers (SII SyncM types 3 and 4, not virtual), each with the
    /// map of the PDOs it carries.
    pub pd_sms: Vec<PdSm>,
    /// The mailbox SyncManagers (SII SyncM types 1 and 2; 0 and 1 when the SII has none).
    mbx_sms: Vec<usize>,
    /// (index, subindex, bits) the device's own default mapping takes of a longer object:
    /// the one partial mapping it accepts (e.g. 16 bits of a 32-bit counter).
    partial_mappings: Vec<(u16, u8, u16)>,
    /// EEPROM access handed to the PDI (0x0501 bit 0): the master's SII commands are ignored.
    eeprom_at_pdi: bool,
    /// Deterministic jitter of the DC time stamps (xorshift state).
    dc_noise: u64,
    /// Current AL state (the protocol crate's `al` values).
    pub al_state: u8,
    /// AL status error flag (bit 4 of 0x0130).
    pub al_error: bool,
    /// AL status code (0x0134) of the last refused transition.
    pub al_code: u16,
    /// Host time of the current frame at this slave (frame time + propagation delay).
    pub now: u64,
    /// Bit p set when port p has a link and is open (set by the network's topology).
    pub open_ports: u8,
    /// Per port: ns after the frame's arrival at port 0 at which it comes back into that port
    /// (None: the port is closed). Latched by a write to 0x0900.
    pub port_return_ns: [Option<u64>; 4],
    /// Time (ns) of the next SYNC0 event, None when SYNC0 is off.
    pub sync0_next: Option<u64>,
    sync0_cycle: u64,
    /// A SYNC0 event has fired since SYNC0 was last activated: the application runs on its
    /// sync signal (SSC's `bDcRunning`).
    sync0_fired: bool,
    app_next_step: u64,
    wd_last_trigger: u64,
    /// The process data watchdog ran out (outputs are no longer valid).
    pub watchdog_expired: bool,
    outputs_since_safeop: bool,
    outputs_received: bool,
    /// Fault: refuse SAFEOP to OP (the `refuse_op` fault).
    pub refuse_op: bool,
    /// Host time at which a SAFEOP->OP request arrived that waits for valid outputs.
    op_pending_since: Option<u64>,
    /// Fault: the mailbox stops answering (the `stall_mailbox` fault).
    pub mailbox_stalled: bool,
    /// Counters of what the slave did, for the statistics.
    pub counters: SlaveCounters,
    /// A logical datagram of the current frame hit an FMMU.
    process_data_seen: bool,
    /// The firmware latches free-run process data around its steps (`set_firmware_latches`).
    firmware_latches: bool,
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
        let (pd_sms, mbx_sms) = process_sync_managers(&sii.image, mailbox.is_some());
        let soe = (w(sii_word::MBX_PROTOCOL) & mailbox::PROTOCOL_SOE != 0)
            .then(|| SoeServer::new(&spec.idns, &sii.image));
        let foe = (w(sii_word::MBX_PROTOCOL) & mailbox::PROTOCOL_FOE != 0)
            .then(|| FoeServer::new(&spec.foe));
        let partial_mappings = default_partial_mappings(&od, &sii.image);
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
            soe,
            foe,
            device: None,
            mailbox,
            boot_mailbox,
            mbx_queue: VecDeque::new(),
            mbx_last_rx_counter: 0,
            mbx_tx_counter: 0,
            mbx_last_sent: Vec::new(),
            mbx_rx_pending: false,
            pd_sms,
            mbx_sms,
            partial_mappings,
            eeprom_at_pdi: false,
            dc_noise: 0x9E37_79B9_7F4A_7C15 ^ ((position as u64 + 1) << 17),
            al_state: ether_ros_protocol::al::INIT,
            al_error: false,
            al_code: 0,
            now,
            open_ports: 1,
            port_return_ns: [None; 4],
            sync0_next: None,
            sync0_cycle: 0,
            sync0_fired: false,
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
            firmware_latches: false,
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

    /// The 16-bit little-endian value at address `a` as stored.
    pub fn get16(&self, a: u16) -> u16 {
        let a = a as usize;
        u16::from_le_bytes([self.mem[a], self.mem[a + 1]])
    }

    /// The 32-bit little-endian value at address `a` as stored.
    pub fn get32(&self, a: u16) -> u32 {
        let a = a as usize;
        u32::from_le_bytes([
            self.mem[a],
            self.mem[a + 1],
            self.mem[a + 2],
            self.mem[a + 3],
        ])
    }

    /// The 64-bit little-endian value at address `a` as stored.
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

    /// True once the EEPROM content was loaded into the registers (the SII control register's
    /// not-loaded bit is clear).
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

    /// Write the AL state, error flag and status code into their registers (after a change).
    pub fn update_al_registers(&mut self) {
        let status = al::AlStatus {
            state: self.al_state,
            error: self.al_error,
        }
        .encode();
        self.put16(reg::AL_STATUS, status);
        self.put16(reg::AL_STATUS_CODE, self.al_code);
    }

    /// Configured station address (0x0010).
    pub fn station_address(&self) -> u16 {
        self.get16(reg::STATION_ADDRESS)
    }

    /// Station alias (0x0012).
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

    /// True when the alias is activated (DL control's alias bit), so configured-address
    /// datagrams may use it.
    pub fn alias_enabled(&self) -> bool {
        self.mem[at(reg::DL_CONTROL_ALIAS)] & 1 != 0
    }

    /// Does a configured-address datagram with ADP `adp` address this slave?
    pub fn matches_fixed(&self, adp: u16) -> bool {
        adp == self.station_address() || (self.alias_enabled() && adp == self.alias())
    }

    /// The EEPROM image.
    pub fn sii_image(&self) -> &[u8] {
        &self.sii.image
    }

    /// Make each EEPROM read take `ns` (0: answer at once), to test a master's busy polling.
    pub fn set_sii_busy_ns(&mut self, ns: u64) {
        self.sii.busy_ns = ns;
    }

    /// Local time of the distributed clock (ns).
    pub fn local_time(&self) -> u64 {
        self.dc.local(self.now)
    }

    /// System time of the distributed clock (ns, local time plus offset).
    pub fn system_time(&self) -> u64 {
        self.dc
            .local(self.now)
            .wrapping_add(self.get64(reg::DC_SYSTEM_TIME_OFFSET))
    }

    /// The active FMMUs (the network's logical address map is built from them).
    pub fn fmmus(&self) -> &[Fmmu] {
        &self.fmmus
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
        let process_data = self.pd_sms.iter().any(|p| p.number == k && p.output);
        let completed = if s.is_mailbox() {
            if s.full {
                return false;
            }
            self.mem[a..a + seg.len()].copy_from_slice(seg);
            let last = off + seg.len() >= s.len as usize;
            if last {
                s.full = true;
                // A mailbox-mode SM carrying process data (one buffer) is no mailbox.
                self.mbx_rx_pending |= !process_data;
            }
            last
        } else {
            s.buffered_write(off, seg)
        };
        if completed && process_data {
            let wd = s.control & WATCHDOG_TRIGGER != 0;
            self.outputs_since_safeop = true;
            self.outputs_received = true;
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
            let t = self.system_time() / DC_GRANULARITY_NS * DC_GRANULARITY_NS;
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
            // ESC datasheet, 0x0930 "speed counter start": a write resets the speed counter
            // difference (0x0932) and the filtered system time difference (0x092C).
            self.dc.reset_loop(self.now);
            self.put32(reg::DC_SYSTEM_TIME_DIFF, 0);
            self.put16(reg::DC_SPEED_COUNTER_DIFF, 0);
        }
        if overlaps(
            a,
            len,
            reg::SII_CONFIG as usize,
            reg::SII_CONFIG as usize + 1,
        ) {
            self.eeprom_access();
        }
        if dc_register(reg::DC_ACTIVATION, 1) {
            self.dc_activation();
        }
    }

    fn sii_command(&mut self, ctl: u16) {
        let cur = self.get16(reg::SII_CONTROL);
        if self.sii.busy(self.now) || self.eeprom_at_pdi {
            // While the PDI has the EEPROM (0x0501 bit 0), EtherCAT's commands do nothing.
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

    /// The master wrote 0x0500: the slave application (PDI) takes the EEPROM as soon as it is
    /// offered and gives it back when the offer is withdrawn; "force ECAT access" takes it
    /// from the PDI at once (ESC datasheet, 0x0500/0x0501).
    fn eeprom_access(&mut self) {
        let cfg = self.mem[reg::SII_CONFIG as usize];
        let to_pdi = cfg & ether_ros_protocol::sii::CONFIG_PDI != 0
            && cfg & ether_ros_protocol::sii::CONFIG_RESET_PDI_ACCESS == 0;
        self.eeprom_at_pdi = to_pdi;
        self.mem[reg::SII_PDI_ACCESS as usize] = to_pdi as u8;
        // Bit 1 is a command, not a state.
        self.mem[reg::SII_CONFIG as usize] =
            cfg & !ether_ros_protocol::sii::CONFIG_RESET_PDI_ACCESS;
    }

    /// True when the PDI holds the EEPROM interface (EEPROM configuration): the master cannot
    /// read it then.
    pub fn eeprom_at_pdi(&self) -> bool {
        self.eeprom_at_pdi
    }

    fn sm_configured(&mut self, k: usize) {
        let base = sm_base(k);
        let field = |offset: u16| base + at(offset);
        // The master's record, read with the protocol crate's codec.
        let Some(record) = smr::Record::decode(&self.mem[field(smr::START)..]) else {
            return;
        };
        let (start, len, control, activate) =
            (record.start, record.length, record.control, record.activate);
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
        let t0 = self.stamp(self.dc.local(self.now));
        self.put32(reg::DC_RECEIVE_TIME_PORT0, t0 as u32);
        for p in 1..4u16 {
            if let Some(back) = self.port_return_ns[p as usize] {
                let t = self.stamp(self.dc.local(self.now + back));
                self.put32(reg::DC_RECEIVE_TIME_PORT0 + 4 * p, t as u32);
            }
        }
        self.put64(reg::DC_RECEIVE_TIME_PU, t0);
    }

    /// A time stamp as the ESC takes it: on its 10 ns clock, at a phase of that clock the
    /// frame's arrival does not control (the PHY's and the clock domain crossing's jitter),
    /// so two stamps of one instant differ by 0 or 10 ns.
    fn stamp(&mut self, t: u64) -> u64 {
        let mut x = self.dc_noise;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.dc_noise = x;
        let phase = (x >> 33) % DC_GRANULARITY_NS;
        (t + phase) / DC_GRANULARITY_NS * DC_GRANULARITY_NS
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
        let local_sys = self.stamp(self.system_time());
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
        self.sync0_fired = false;
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

    /// True while SYNC0 events are scheduled.
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
        if self.device_emulation() {
            // ESC datasheet, 0x0141 bit 0 "device emulation": a slave without application
            // processor (digital I/O terminals: PDI 0x04) has the ESC copy AL control to AL
            // status; nothing is checked.
            self.op_pending_since = None;
            if requested != self.al_state {
                if requested == SAFEOP && self.al_state == PREOP {
                    // The process data still flows by the SII's PDOs (digital I/O).
                    let _ = self.build_maps();
                }
                self.enter_state(requested);
            } else {
                self.update_al_registers();
            }
            return;
        }
        let cur = self.al_state;
        // Any new request replaces a SAFEOP->OP request still waiting for outputs.
        let was_pending = self.op_pending_since.take();
        if requested == cur {
            self.update_al_registers();
            return;
        }
        if (cur, requested) == (SAFEOP, OP) && !self.refuse_op && self.op_waits() {
            // As real slave stacks do: the request stays pending (AL status SAFEOP, no error)
            // until the first valid outputs arrive and, with SYNC0 active, the first SYNC0
            // event has fired, or the ESI's SAFEOP->OP timeout runs out. Masters that request
            // OP first and start the cyclic exchange afterwards (ethercrab) depend on this.
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

    /// ESC configuration 0x0141 bit 0 (from the EEPROM's ConfigData): the ESC itself
    /// answers AL control, there is no slave application to check anything.
    pub fn device_emulation(&self) -> bool {
        self.mem[reg::ESC_CONFIG as usize] & reg::esc_config::DEVICE_EMULATION != 0
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
            if let Some(soe) = self.soe.as_mut() {
                soe.abandon_transfer();
            }
            if let Some(foe) = self.foe.as_mut() {
                // Out of BOOT the device restarts: a firmware written there takes effect.
                foe.restart(&mut self.od, prev == BOOT);
            }
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
        let has_mailbox = self.mailbox.is_some() || self.boot_mailbox.is_some();
        if has_mailbox {
            for &k in &self.mbx_sms {
                self.sm[k].pdi_disabled = !mbx_on;
            }
        }
        for p in &self.pd_sms {
            if !(has_mailbox && self.mbx_sms.contains(&p.number)) {
                self.sm[p.number].pdi_disabled = !pd_on;
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

    /// Recompute the process-data maps from the dictionary: the PDO assignment of SM n is
    /// object 0x1C10 + n (ETG.1000.6); without it, the SII's PDOs of that SM.
    fn build_maps(&mut self) -> Result<(), u16> {
        use ether_ros_protocol::al::*;
        for i in 0..self.pd_sms.len() {
            let (n, output) = (self.pd_sms[i].number, self.pd_sms[i].output);
            let assign = coe_facts::SM_PDO_ASSIGN + n as u16;
            let map = match crate::pdo::from_od(&self.od, assign, &self.partial_mappings) {
                Some(Ok(m)) => m,
                Some(Err(_)) if output => return Err(INVALID_OUTPUT_MAPPING),
                Some(Err(_)) => return Err(INVALID_INPUT_MAPPING),
                None => self.sii_map(
                    if output {
                        sii_category::RXPDO
                    } else {
                        sii_category::TXPDO
                    },
                    n,
                ),
            };
            self.pd_sms[i].map = map;
        }
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

    /// Does SM `p` hold what its PDOs need: enabled with their length, mode and direction.
    /// An SM without data is not checked (as SOES does: a master may leave it enabled with
    /// the SII's length, as SOEM does); an OpOnly SM may still be disabled before OP.
    fn pd_sm_ok(&self, p: &PdSm, op: bool) -> bool {
        let s = &self.sm[p.number];
        let bytes = p.map.bytes();
        let control = p.control & (smr::MODE_MASK | smr::DIR_MASK);
        if bytes == 0 {
            return true;
        }
        if p.op_only && !op && !s.configured() {
            return true;
        }
        s.configured()
            && s.len as usize == bytes
            && s.control & (smr::MODE_MASK | smr::DIR_MASK) == control
    }

    fn check_process_data(&mut self) -> Result<(), u16> {
        use ether_ros_protocol::al::*;
        self.build_maps()?;
        for p in &self.pd_sms {
            if !self.pd_sm_ok(p, false) {
                return Err(if p.output {
                    INVALID_OUTPUT_CONFIG
                } else {
                    INVALID_INPUT_CONFIG
                });
            }
        }
        if self.spec.dc_required && !self.sync0_active() {
            return Err(INVALID_DC_SYNC_CONFIG);
        }
        Ok(())
    }

    /// Output bytes of all process-data SMs (their maps as of the last PREOP -> SAFEOP).
    pub fn output_bytes(&self) -> usize {
        self.pd_sms
            .iter()
            .filter(|p| p.output)
            .map(|p| p.map.bytes())
            .sum()
    }

    /// Bytes of process data the slave sends (its input SyncManagers).
    pub fn input_bytes(&self) -> usize {
        self.pd_sms
            .iter()
            .filter(|p| !p.output)
            .map(|p| p.map.bytes())
            .sum()
    }

    fn check_op(&self) -> Result<(), u16> {
        use ether_ros_protocol::al::*;
        if self.refuse_op {
            return Err(SYNCHRONIZATION_ERROR);
        }
        for p in &self.pd_sms {
            if !self.pd_sm_ok(p, true) {
                return Err(if p.output {
                    INVALID_OUTPUT_CONFIG
                } else {
                    INVALID_INPUT_CONFIG
                });
            }
        }
        if self.waits_for_outputs() {
            return Err(NO_VALID_OUTPUTS);
        }
        Ok(())
    }

    /// The slave has outputs (in SMs enabled before OP) but none arrived since SAFEOP.
    fn waits_for_outputs(&self) -> bool {
        let outputs = self
            .pd_sms
            .iter()
            .any(|p| p.output && !p.op_only && p.map.bytes() > 0);
        outputs && !self.outputs_since_safeop
    }

    /// A slave synchronised to SYNC0 whose SYNC0 has not fired yet (its start time lies
    /// ahead). Its application runs on the sync signal: until the first event it has neither
    /// taken outputs nor written inputs, so a one-buffer input SM stays empty and the master's
    /// read of it fails (working counter −1). The Beckhoff slave stack code (SSC,
    /// `StartOutputHandler`) keeps SAFEOP->OP pending while DC synchronisation is active
    /// until its PLL runs on the SYNC0 events; the OP it confirms is one with input data.
    fn waits_for_sync(&self) -> bool {
        self.sync0_active() && !self.sync0_fired
    }

    /// What a SAFEOP->OP request waits for: outputs, or the first SYNC0 event.
    fn op_waits(&self) -> bool {
        self.waits_for_outputs() || self.waits_for_sync()
    }

    /// Is a SAFEOP->OP request waiting for outputs? (for tests and `slave_info`)
    pub fn op_request_pending(&self) -> bool {
        self.op_pending_since.is_some()
    }

    /// A pending SAFEOP->OP request: go to OP once outputs arrived (and SYNC0 runs, if active),
    /// refuse it when the timeout ran out (AL status 0x0019 "no valid outputs", or 0x002D "no
    /// SYNC error" when only SYNC0 is missing; emergency 0xA001).
    fn resolve_pending_op(&mut self) {
        let Some(since) = self.op_pending_since else {
            return;
        };
        if self.al_state != ether_ros_protocol::al::SAFEOP || self.al_error {
            self.op_pending_since = None;
            return;
        }
        if !self.op_waits() {
            self.op_pending_since = None;
            self.enter_state(ether_ros_protocol::al::OP);
            return;
        }
        let timeout = u64::from(self.spec.safeop_op_timeout_ms) * 1_000_000;
        if self.now.saturating_sub(since) > timeout {
            self.op_pending_since = None;
            // No outputs is the usual reason; with outputs but a SYNC0 that never fired the
            // slave saw no sync signal (AL status 0x002D).
            let code = if self.waits_for_outputs() {
                ether_ros_protocol::al::NO_VALID_OUTPUTS
            } else {
                ether_ros_protocol::al::NO_SYNC_ERROR
            };
            self.fail_with_emergency(code, EMERGENCY_SAFEOP_TO_OP);
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
            } else if self.al_state == ether_ros_protocol::al::BOOT && kind != mailbox::TYPE_FOE {
                // ETG.1000.6: the bootstrap mailbox carries FoE only.
                self.mailbox_error(mailbox::ERR_UNSUPPORTED_PROTOCOL);
            } else if kind == mailbox::TYPE_FOE && self.foe.is_some() {
                self.service_foe(start, msg_len);
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
            } else if kind == mailbox::TYPE_SOE && self.soe.is_some() {
                let mut out = Vec::new();
                let max_payload = (self.sm[1].len as usize).saturating_sub(mailbox::HEADER_LEN);
                let data_start = start + mailbox::HEADER_LEN;
                let request = self.mem[data_start..data_start + msg_len].to_vec();
                let handled = self.soe.as_mut().map_or(Ok(()), |soe| {
                    soe.handle(&request, self.al_state, max_payload, &mut out)
                });
                match handled {
                    Ok(()) => {
                        for p in out {
                            self.queue_mailbox(mailbox::TYPE_SOE, p);
                        }
                    }
                    Err(code) => self.mailbox_error(code),
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

    /// An FoE message of `msg_len` bytes in the write mailbox at `start` (crate::foe).
    fn service_foe(&mut self, start: usize, msg_len: usize) {
        let data_start = start + mailbox::HEADER_LEN;
        let request = self.mem[data_start..data_start + msg_len].to_vec();
        let (rx, tx) = (self.sm[0].len as usize, self.sm[1].len as usize);
        let mut out = Vec::new();
        let handled = self.foe.as_mut().map_or(Ok(()), |foe| {
            foe.handle(&request, self.al_state, rx, tx, &mut out)
        });
        match handled {
            Ok(()) => {
                for p in out {
                    self.queue_mailbox(mailbox::TYPE_FOE, p);
                }
            }
            Err(code) => self.mailbox_error(code),
        }
    }

    /// The FoE server, for a slave whose SII announces FoE.
    pub fn foe(&self) -> Option<&FoeServer> {
        self.foe.as_ref()
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

    /// Messages waiting in the send mailbox queue.
    pub fn mailbox_queue_len(&self) -> usize {
        self.mbx_queue.len()
    }

    // ------------------------------------------------------------------ application side

    fn outputs_valid(&self) -> bool {
        self.al_state == ether_ros_protocol::al::OP
            && !self.watchdog_expired
            && self.outputs_received
    }

    /// SM buffers of outputs → dictionary (only in OP: SAFEOP keeps outputs safe). An SM on
    /// the ESC's digital output registers (0x0F00..0x0F03) drives them too; a one-buffer SM is
    /// emptied in SAFEOP as well.
    pub fn latch_outputs(&mut self) {
        self.latch_output_sms(false);
    }

    /// The one-buffer output SMs only. The slave reads such a buffer as soon as the master has
    /// filled it: its PDI gets an event for every write, which is what one-buffer mode is for.
    /// The frame empties them even where SYNC0 or the firmware's own step latches the buffered
    /// ones; left full until then, the master's next write would be refused (a full one-buffer
    /// SM does not take a write: working counter −2) whenever two frames fall in one period.
    fn latch_one_buffer_outputs(&mut self) {
        self.latch_output_sms(true);
    }

    fn latch_output_sms(&mut self, one_buffer_only: bool) {
        let op = self.al_state == ether_ros_protocol::al::OP;
        if !op && self.al_state != ether_ros_protocol::al::SAFEOP {
            return;
        }
        for p in &self.pd_sms {
            if !p.output {
                continue;
            }
            let s = &mut self.sm[p.number];
            if one_buffer_only && !s.is_mailbox() {
                continue;
            }
            let start = s.start as usize;
            if s.is_mailbox() {
                // One buffer: the slave reads it once the master has filled it, so the master
                // may write again; in SAFEOP it reads and drops it (outputs stay safe).
                if s.full {
                    if op {
                        let end = (start + s.len as usize).min(MEM_SIZE);
                        crate::pdo::buffer_to_od(&p.map, &self.mem[start..end], &mut self.od);
                    }
                    s.full = false;
                }
                continue;
            }
            if !op {
                continue;
            }
            if let Some(buf) = s.pdi_take() {
                crate::pdo::buffer_to_od(&p.map, buf, &mut self.od);
                if (DIGITAL_OUTPUTS..DIGITAL_OUTPUTS_END).contains(&start) {
                    let n = buf.len().min(DIGITAL_OUTPUTS_END - start);
                    self.mem[start..start + n].copy_from_slice(&buf[..n]);
                }
            }
        }
    }

    /// Dictionary → SM buffers of inputs (SAFEOP and OP).
    pub fn latch_inputs(&mut self) {
        if !matches!(
            self.al_state,
            ether_ros_protocol::al::SAFEOP | ether_ros_protocol::al::OP
        ) {
            return;
        }
        for p in &self.pd_sms {
            let s = &mut self.sm[p.number];
            if p.output || !s.enabled() || p.map.bits == 0 {
                continue;
            }
            let (map, od) = (&p.map, &self.od);
            if s.is_mailbox() {
                // One buffer: the slave fills it when the master has read the last one.
                if !s.full {
                    let start = s.start as usize;
                    let end = (start + s.len as usize).min(MEM_SIZE);
                    crate::pdo::od_to_buffer(map, od, &mut self.mem[start..end]);
                    s.full = true;
                }
                continue;
            }
            s.pdi_publish(|buf| crate::pdo::od_to_buffer(map, od, buf));
        }
    }

    /// Advance the application to host time `host`: device steps at the device period and
    /// SYNC0 events in order, bounded catch-up, and the process-data watchdog.
    pub fn advance(&mut self, host: u64) {
        self.now = host;
        self.run_events(host, true, u64::MAX);
        self.check_watchdog();
        // Time passes for a pending SAFEOP->OP request too (its timeout), before the frame's
        // datagrams read the AL status.
        self.resolve_pending_op();
    }

    /// The firmware's own clock (a worker thread, `crate::firmware`): what `advance` does,
    /// then the mailbox, so emergencies the device raised reach the read mailbox without
    /// waiting for a frame. At most `chunk_ns` of simulated time is run (from the first event
    /// due) so that a firmware far behind lets the frame path in between; returns whether it
    /// has caught up with `host`. The deadlines (watchdog, pending SAFEOP->OP) are those of
    /// `host`: a firmware running behind sees the watchdog as it is now.
    pub fn advance_firmware(&mut self, host: u64, chunk_ns: u64) -> bool {
        self.now = host;
        let caught_up = self.run_events(host, true, chunk_ns);
        self.check_watchdog();
        self.resolve_pending_op();
        self.service_mailbox();
        caught_up
    }

    /// A frame reaches this slave while its firmware runs on a worker thread: only what the
    /// frame must see done by now. SYNC0 events already due are latched here if the worker
    /// has not got to them yet, so the frame reads the inputs of the last SYNC0, exactly as in
    /// simulated time; device steps are left to the worker, and so are the deadlines (the
    /// watchdog, a pending SAFEOP->OP timeout), which it meets at their own instant.
    pub fn frame_catch_up(&mut self, host: u64) {
        self.now = host;
        if self.sync0_due(host) {
            self.counters.sync0_frame_latches += 1;
            self.run_events(host, false, u64::MAX);
        }
    }

    /// Is a SYNC0 event at or before host time `host` still to be latched?
    fn sync0_due(&self, host: u64) -> bool {
        match self.sync0_next {
            Some(next) => {
                let offset = self.get64(reg::DC_SYSTEM_TIME_OFFSET);
                next.wrapping_sub(offset) <= self.dc.local(host)
            }
            None => false,
        }
    }

    /// Host time (CLOCK_MONOTONIC ns, from `host` on) of the next thing the firmware side has
    /// to do, and whether it must happen at that instant (`true`: a SYNC0 event, the watchdog
    /// running out, a pending SAFEOP->OP request timing out) or is a device step (`false`,
    /// which a worker may run a little later with its exact simulated time). None: nothing is
    /// scheduled. Local times are turned into host time at the nominal rate: the worker may
    /// wake a few ns early and look again.
    pub fn next_firmware_event(&self, host: u64) -> Option<(u64, bool)> {
        let local_now = self.dc.local(host);
        let to_host = |local: u64| host.saturating_add(local.saturating_sub(local_now));
        let mut exact: Option<u64> = None;
        let mut consider = |t: u64| exact = Some(exact.map_or(t, |n: u64| n.min(t)));
        if let Some(s) = self.sync0_next {
            let offset = self.get64(reg::DC_SYSTEM_TIME_OFFSET);
            consider(to_host(s.wrapping_sub(offset)));
        }
        let armed = self.watchdog_armed();
        let wd = self.watchdog_ns();
        if armed && wd > 0 && !self.watchdog_expired {
            consider(self.wd_last_trigger.saturating_add(wd + 1));
        }
        if let Some(since) = self.op_pending_since {
            let timeout = u64::from(self.spec.safeop_op_timeout_ms) * 1_000_000;
            consider(since.saturating_add(timeout + 1));
        }
        let step = self.device.as_ref().map(|_| to_host(self.app_next_step));
        match (exact, step) {
            (Some(e), Some(s)) if s < e => Some((s, false)),
            (Some(e), _) => Some((e, true)),
            (None, Some(s)) => Some((s, false)),
            (None, None) => None,
        }
    }

    /// The firmware latches process data itself (worker threads): in free run its outputs
    /// are taken before and its inputs published after each device step, instead of on each
    /// frame. A slave without firmware keeps the ESC's own latch on the frame (the digital
    /// I/O of a simple terminal).
    pub fn set_firmware_latches(&mut self, on: bool) {
        self.firmware_latches = on;
    }

    /// Does the frame latch this slave's process data in free run?
    fn frame_latches(&self) -> bool {
        let firmware_does = self.firmware_latches && self.device.is_some();
        !self.sync0_active() && !firmware_does
    }

    /// Device steps and SYNC0 events up to host time `host`, in time order (without `steps`,
    /// SYNC0 events only: the frame path's catch-up, the device steps stay due), at most
    /// `chunk_ns` of local time from the first one due; true when nothing due is left.
    fn run_events(&mut self, host: u64, steps: bool, chunk_ns: u64) -> bool {
        let local_now = self.dc.local(host);
        let period = self.device.as_ref().map(|d| d.period_ns().max(1_000));
        if self.app_next_step == 0 {
            self.app_next_step = local_now;
        }
        // Bound the catch-up.
        let horizon = local_now.saturating_sub(MAX_CATCH_UP_NS);
        if let (Some(p), true) = (period, steps) {
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
        // The firmware latches around its own steps in free run (worker threads).
        let step_latches = self.firmware_latches && self.sync0_next.is_none();
        let first = match period {
            Some(_) if steps => self.app_next_step,
            _ => u64::MAX,
        }
        .min(sync_local.unwrap_or(u64::MAX));
        let until = local_now.min(first.saturating_add(chunk_ns));
        // Never loop forever on absurd settings: past this many events, skip to now.
        let mut budget = 4 * MAX_CATCH_UP_NS / 1_000;
        loop {
            let next_dev = match period {
                Some(_) if steps => self.app_next_step,
                _ => u64::MAX,
            };
            let next_sync = sync_local.unwrap_or(u64::MAX);
            let t = next_dev.min(next_sync);
            if t > until {
                break;
            }
            if budget == 0 {
                if let (Some(p), true) = (period, steps) {
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
                self.sync0_fired = true;
                sync_local = Some(next_sync.saturating_add(cycle));
            } else {
                if step_latches {
                    self.latch_outputs();
                }
                let valid = self.outputs_valid();
                if let Some(d) = self.device.as_mut() {
                    d.step(&mut self.od, t, valid);
                }
                if step_latches {
                    self.latch_inputs();
                }
                self.send_device_emergencies();
                self.counters.device_steps += 1;
                self.app_next_step = self
                    .app_next_step
                    .saturating_add(period.unwrap_or(u64::MAX));
            }
        }
        self.sync0_next = sync_local.map(|n| n.wrapping_add(offset));
        until == local_now
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

    /// The process-data watchdog runs on the output SMs that trigger it (control bit 6).
    fn watchdog_armed(&self) -> bool {
        self.pd_sms.iter().any(|p| {
            let s = &self.sm[p.number];
            p.output && s.enabled() && s.control & WATCHDOG_TRIGGER != 0 && !s.is_mailbox()
        })
    }

    fn watchdog_ns(&self) -> u64 {
        let divider = self.get16(reg::WATCHDOG_DIVIDER) as u64;
        let time = self.get16(reg::WATCHDOG_TIME_PD) as u64;
        (divider + 2) * 40 * time
    }

    fn check_watchdog(&mut self) {
        let armed = self.watchdog_armed();
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
            // The outputs go to their safe state (outputs_valid is false now). A slave
            // application leaves OP; under device emulation there is none to do it.
            if self.al_state == ether_ros_protocol::al::OP && !self.device_emulation() {
                self.enter_state(ether_ros_protocol::al::SAFEOP);
                self.fail(ether_ros_protocol::al::SM_WATCHDOG);
            }
        }
    }

    /// Per-frame work before the datagrams: free-run input latch.
    pub fn before_frame(&mut self) {
        if self.frame_latches() {
            self.latch_inputs();
        }
    }

    /// Per-frame work after the datagrams: free-run output latch and the mailbox.
    pub fn after_frame(&mut self) {
        if std::mem::take(&mut self.process_data_seen) {
            self.counters.process_data_frames += 1;
        }
        if self.frame_latches() {
            self.latch_outputs();
        } else {
            self.latch_one_buffer_outputs();
        }
        self.resolve_pending_op();
        self.service_mailbox();
    }

    /// Named values of the device model and the ESC, for `SimNetwork.probe`.
    pub fn probe(&self) -> Vec<(&'static str, f64)> {
        self.device.as_ref().map(|d| d.probe()).unwrap_or_default()
    }
}

/// The ESC's digital output registers (0x0F00..0x0F03): a SyncManager may guard them, so
/// that outputs written there count for the process-data watchdog (ET1100/ET1200 digital I/O).
const DIGITAL_OUTPUTS: usize = reg::DIGITAL_OUTPUTS as usize;
const DIGITAL_OUTPUTS_END: usize = DIGITAL_OUTPUTS + reg::DIGITAL_OUTPUTS_LEN as usize;

/// One process-data SyncManager of the slave and the map of the PDOs it carries.
#[derive(Clone, Debug, Default)]
pub struct PdSm {
    /// SyncManager number.
    pub number: usize,
    /// Master → slave (SII type 3); else slave → master (type 4).
    pub output: bool,
    /// Enabled only in OP (SII enable bit 3): it may stay disabled in SAFEOP.
    pub op_only: bool,
    /// Mode and direction (control bits 0..3) the slave expects: buffered or one buffer.
    pub control: u8,
    /// The PDOs it carries and where their entries are in the buffer.
    pub map: PdoMap,
}

/// The process-data SyncManagers and the mailbox SyncManagers of an SII. Without a SyncM
/// category the usual layout: SM2/SM3 behind a mailbox at SM0/SM1, else SM0/SM1.
fn process_sync_managers(image: &[u8], mailbox: bool) -> (Vec<PdSm>, Vec<usize>) {
    let sms = sii::sync_managers(image);
    if sms.is_empty() {
        let (o, i) = if mailbox { (2, 3) } else { (0, 1) };
        let pd = vec![
            PdSm {
                number: o,
                output: true,
                control: 0x04,
                ..Default::default()
            },
            PdSm {
                number: i,
                output: false,
                control: 0x00,
                ..Default::default()
            },
        ];
        return (pd, vec![0, 1]);
    }
    let mut pd = Vec::new();
    let mut mbx = Vec::new();
    for (n, s) in sms.iter().enumerate().take(N_SM) {
        match s.kind {
            syncm::TYPE_MBOX_OUT | syncm::TYPE_MBOX_IN => mbx.push(n),
            syncm::TYPE_OUTPUTS | syncm::TYPE_INPUTS if s.enable & syncm::VIRTUAL == 0 => {
                let output = s.kind == syncm::TYPE_OUTPUTS;
                // The direction follows the type; the mode (buffered or one buffer) the SII.
                let direction = if output { 0x04 } else { 0x00 };
                pd.push(PdSm {
                    number: n,
                    output,
                    op_only: s.enable & syncm::OP_ONLY != 0,
                    control: (s.control & 0x03) | direction,
                    map: PdoMap::default(),
                })
            }
            _ => {}
        }
    }
    if mbx.is_empty() {
        mbx = vec![0, 1];
    }
    (pd, mbx)
}

/// A PDO mapping object: 0x1600..=0x17FF (RxPDOs) or 0x1A00..=0x1BFF (TxPDOs).
fn is_mapping_object(index: u16) -> bool {
    use ether_ros_protocol::coe::{RXPDO_MAPPING, TXPDO_MAPPING};
    (RXPDO_MAPPING..RXPDO_MAPPING + 0x200).contains(&index)
        || (TXPDO_MAPPING..TXPDO_MAPPING + 0x200).contains(&index)
}

/// The (index, subindex, bits) the device's own defaults (its mapping objects 0x1600..0x1BFF
/// and its SII PDOs) map with another length than their object's: those mappings it accepts
/// (e.g. 16 bits of a 32-bit counter; the copy takes the object's low bits).
fn default_partial_mappings(od: &ObjectDictionary, image: &[u8]) -> Vec<(u16, u8, u16)> {
    let mut out = Vec::new();
    let mut consider = |index: u16, sub: u8, bits: u16| {
        if index == 0 {
            return;
        }
        if let Some(e) = od.entry(index, sub) {
            if bits != e.bit_length && !out.contains(&(index, sub, bits)) {
                out.push((index, sub, bits));
            }
        }
    };
    for o in od.objects() {
        if !is_mapping_object(o.index) {
            continue;
        }
        let n = od.get_int(o.index, 0).clamp(0, 254) as u8;
        for s in 1..=n {
            let raw = od.get_int(o.index, s) as u32;
            consider((raw >> 16) as u16, (raw >> 8) as u8, (raw & 0xff) as u16);
        }
    }
    for category in [
        ether_ros_protocol::sii::category::TXPDO,
        ether_ros_protocol::sii::category::RXPDO,
    ] {
        for p in sii::pdos(image, category) {
            for &(index, sub, bits) in &p.entries {
                consider(index, sub, bits);
            }
        }
    }
    out
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

    /// An SII image: the configuration area (word 0: PDI control and ESC configuration, with
    /// its checksum), then a SyncM category (start, length, control, enable, type per SM) and
    /// the end marker.
    fn image(esc_config: u8, sms: &[(u16, u16, u8, u8, u8)]) -> Vec<u8> {
        let mut head = vec![0u8; 128];
        head[0] = 0x04;
        head[1] = esc_config;
        head[14] = sii::checksum(&head[..14]);
        let mut cat = Vec::new();
        for &(start, len, control, enable, kind) in sms {
            cat.extend_from_slice(&start.to_le_bytes());
            cat.extend_from_slice(&len.to_le_bytes());
            cat.extend_from_slice(&[control, 0, enable, kind]);
        }
        head.extend_from_slice(&41u16.to_le_bytes());
        head.extend_from_slice(&((cat.len() / 2) as u16).to_le_bytes());
        head.extend_from_slice(&cat);
        head.extend_from_slice(&[0xff, 0xff]);
        head
    }

    fn slave(esc_config: u8, sms: &[(u16, u16, u8, u8, u8)]) -> Esc {
        let spec = SlaveSpec {
            sii: image(esc_config, sms),
            ..Default::default()
        };
        Esc::new(spec, 0, 0)
    }

    /// The master's SM register write: start, length, control, status, activate.
    fn configure_sm(esc: &mut Esc, k: usize, start: u16, len: u16, control: u8) {
        let mut w = start.to_le_bytes().to_vec();
        w.extend_from_slice(&len.to_le_bytes());
        w.extend_from_slice(&[control, 0, 1, 0]);
        esc.ecat_write(0x0800 + 8 * k, &w);
    }

    #[test]
    fn an_input_only_slave_without_mailbox_takes_its_sm0_as_inputs() {
        // EL1008: one SM, inputs at 0x1000, no mailbox. The simulator took SM0 for outputs
        // and refused SAFEOP with 0x001D.
        let mut esc = slave(0x00, &[(0x1000, 1, 0x00, 0x01, 4)]);
        esc.od.add_entry(crate::od::Entry {
            index: 0x6000,
            subindex: 1,
            name: "Input".into(),
            data_type: crate::od::dtype::UINT8,
            bit_length: 8,
            access: crate::od::Access::ReadOnly,
            pdo_mappable: true,
            value: vec![0x5A],
        });
        // Its SII has no PDO category here: the map comes from the dictionary's 0x1C10.
        esc.od.add_entry(crate::od::Entry {
            index: 0x1C10,
            subindex: 0,
            name: "n".into(),
            data_type: crate::od::dtype::UINT8,
            bit_length: 8,
            access: crate::od::Access::ReadOnly,
            pdo_mappable: false,
            value: vec![1],
        });
        esc.od.add_entry(crate::od::Entry {
            index: 0x1C10,
            subindex: 1,
            name: "pdo".into(),
            data_type: crate::od::dtype::UINT16,
            bit_length: 16,
            access: crate::od::Access::ReadOnly,
            pdo_mappable: false,
            value: 0x1A00u16.to_le_bytes().to_vec(),
        });
        for (sub, v) in [(0u8, 1u32), (1, 0x6000_0108)] {
            esc.od.add_entry(crate::od::Entry {
                index: 0x1A00,
                subindex: sub,
                name: "m".into(),
                data_type: crate::od::dtype::UINT32,
                bit_length: if sub == 0 { 8 } else { 32 },
                access: crate::od::Access::ReadOnly,
                pdo_mappable: false,
                value: v.to_le_bytes()[..if sub == 0 { 1 } else { 4 }].to_vec(),
            });
        }
        esc.request_state(ether_ros_protocol::al::PREOP as u16);
        configure_sm(&mut esc, 0, 0x1000, 1, 0x00);
        esc.request_state(ether_ros_protocol::al::SAFEOP as u16);
        assert_eq!(
            (esc.al_state, esc.al_code),
            (ether_ros_protocol::al::SAFEOP, 0)
        );
        esc.latch_inputs();
        let mut b = [0u8; 1];
        assert!(esc.ecat_read(0x1000, &mut b, false));
        assert_eq!(b, [0x5A]);
    }

    /// A slave with one input byte (0x6000:1 = 0x5A, PDO 0x1A00 assigned to SM0) in an SM
    /// with the given control byte at 0x1000, in SAFEOP.
    fn input_slave_in_safeop(control: u8) -> Esc {
        let mut esc = slave(0x00, &[(0x1000, 1, control, 0x01, 4)]);
        let mut add = |index: u16, subindex: u8, bits: u16, value: Vec<u8>| {
            esc.od.add_entry(crate::od::Entry {
                index,
                subindex,
                name: format!("{index:04x}:{subindex}"),
                data_type: crate::od::dtype::UINT32,
                bit_length: bits,
                access: crate::od::Access::ReadOnly,
                pdo_mappable: index == 0x6000,
                value,
            });
        };
        add(0x6000, 1, 8, vec![0x5A]);
        add(0x1C10, 0, 8, vec![1]);
        add(0x1C10, 1, 16, 0x1A00u16.to_le_bytes().to_vec());
        add(0x1A00, 0, 8, vec![1]);
        add(0x1A00, 1, 32, 0x6000_0108u32.to_le_bytes().to_vec());
        esc.request_state(ether_ros_protocol::al::PREOP as u16);
        configure_sm(&mut esc, 0, 0x1000, 1, control);
        esc.request_state(ether_ros_protocol::al::SAFEOP as u16);
        assert_eq!(
            (esc.al_state, esc.al_code),
            (ether_ros_protocol::al::SAFEOP, 0)
        );
        esc
    }

    #[test]
    fn a_sync0_slave_confirms_op_once_its_sync0_has_fired() {
        // Beckhoff AX5000 under ethercrab: SYNC0 starts 50 ms after the master configured
        // it, the master requests OP and exchanges process data at once. The drive's inputs
        // are in a one-buffer SM (ControlByte 0x22), written on SYNC0: a slave that entered
        // OP before its first SYNC0 had nothing in it, and each LRW missed the input read
        // (working counter -1) until SYNC0 started.
        let mut esc = input_slave_in_safeop(0x22);
        let start = esc.system_time() + 50_000_000;
        esc.ecat_write(reg::DC_SYNC0_CYCLE as usize, &1_000_000u32.to_le_bytes());
        esc.ecat_write(reg::DC_START_TIME as usize, &start.to_le_bytes());
        esc.ecat_write(
            reg::DC_ACTIVATION as usize,
            &[dc::ACTIVATE_CYCLIC | dc::ACTIVATE_SYNC0],
        );
        assert!(esc.sync0_active());
        esc.request_state(ether_ros_protocol::al::OP as u16);
        // Pending in SAFEOP: no SYNC0 yet, so no inputs either.
        assert_eq!(esc.al_state, ether_ros_protocol::al::SAFEOP);
        assert!(esc.op_request_pending() && !esc.al_error);
        let mut b = [0u8; 1];
        assert!(!esc.ecat_read(0x1000, &mut b, false));
        esc.advance(esc.now + 49_000_000);
        assert_eq!(esc.al_state, ether_ros_protocol::al::SAFEOP);
        // The first SYNC0 fills the input buffer and lets OP be confirmed.
        esc.advance(esc.now + 2_000_000);
        assert_eq!(esc.al_state, ether_ros_protocol::al::OP);
        assert!(esc.ecat_read(0x1000, &mut b, false));
        assert_eq!(b, [0x5A]);
    }

    #[test]
    fn a_sync0_that_never_fires_refuses_op_with_no_sync_error() {
        let mut esc = input_slave_in_safeop(0x22);
        let start = esc.system_time() + 60_000_000_000;
        esc.ecat_write(reg::DC_SYNC0_CYCLE as usize, &1_000_000u32.to_le_bytes());
        esc.ecat_write(reg::DC_START_TIME as usize, &start.to_le_bytes());
        esc.ecat_write(
            reg::DC_ACTIVATION as usize,
            &[dc::ACTIVATE_CYCLIC | dc::ACTIVATE_SYNC0],
        );
        esc.request_state(ether_ros_protocol::al::OP as u16);
        let timeout = u64::from(esc.spec.safeop_op_timeout_ms) * 1_000_000;
        esc.advance(esc.now + timeout + 1_000_000);
        assert!(esc.al_error);
        assert_eq!(esc.al_code, ether_ros_protocol::al::NO_SYNC_ERROR);
    }

    #[test]
    fn device_emulation_copies_al_control_to_al_status() {
        // 0x0141 bit 0 (ConfigData "0401"): no application checks the SyncManagers.
        let mut esc = slave(0x01, &[(0x0F00, 1, 0x44, 0x09, 3)]);
        assert!(esc.device_emulation());
        for state in [
            ether_ros_protocol::al::PREOP,
            ether_ros_protocol::al::SAFEOP,
            ether_ros_protocol::al::OP,
        ] {
            esc.request_state(state as u16);
            assert_eq!((esc.al_state, esc.al_error), (state, false));
        }
    }

    #[test]
    fn an_sm_on_the_digital_output_registers_drives_them_in_op() {
        // EL2008: SM0 at 0x0F00, enabled only in OP (SII enable bit 3).
        let mut esc = slave(0x01, &[(0x0F00, 1, 0x44, 0x09, 3)]);
        esc.request_state(ether_ros_protocol::al::PREOP as u16);
        esc.request_state(ether_ros_protocol::al::SAFEOP as u16);
        configure_sm(&mut esc, 0, 0x0F00, 1, 0x44);
        esc.request_state(ether_ros_protocol::al::OP as u16);
        assert!(esc.ecat_write(0x0F00, &[0xA5]));
        esc.latch_outputs();
        assert_eq!(esc.memory()[0x0F00], 0xA5);
    }

    #[test]
    fn a_one_buffer_output_sm_takes_every_frame_while_sync0_latches() {
        // SMC EX250: outputs in one-buffer mode (ControlByte 0x46) on 0x0F00. With SYNC0
        // latching the buffered SMs, a master whose frames jitter sends two in one SYNC0
        // period: the slave has read the first (its PDI event), so the second is taken too.
        let mut esc = slave(0x01, &[(0x0F00, 1, 0x46, 0x09, 3)]);
        esc.request_state(ether_ros_protocol::al::PREOP as u16);
        esc.request_state(ether_ros_protocol::al::SAFEOP as u16);
        configure_sm(&mut esc, 0, 0x0F00, 1, 0x46);
        esc.request_state(ether_ros_protocol::al::OP as u16);
        esc.sync0_next = Some(u64::MAX); // SYNC0 runs and has not fired yet
        assert!(!esc.frame_latches());
        for v in [0xA5, 0x5A, 0x3C] {
            assert!(
                esc.ecat_write(0x0F00, &[v]),
                "the write of {v:#04x} was refused"
            );
            esc.after_frame();
            assert_eq!(esc.memory()[0x0F00], v);
        }
    }

    #[test]
    fn a_virtual_sm_takes_no_hardware_sm() {
        // EL1252: a virtual SM at 0x09AE (SII enable bit 2) is mapped by an FMMU only.
        let esc = slave(
            0x01,
            &[(0x1000, 1, 0x22, 0x01, 4), (0x09AE, 34, 0x00, 0x04, 4)],
        );
        assert_eq!(
            esc.pd_sms
                .iter()
                .map(|p| (p.number, p.output, p.control))
                .collect::<Vec<_>>(),
            vec![(0, false, 0x02)]
        );
    }

    #[test]
    fn speed_counter_start_write_resets_the_difference_registers() {
        // ESC datasheet 0x0930: a write resets 0x092C (system time difference) and 0x0932
        // (speed counter difference).
        let mut esc = slave(0x00, &[]);
        esc.ecat_write(0x0910, &5_000_000u64.to_le_bytes());
        assert_ne!(esc.get32(reg::DC_SYSTEM_TIME_DIFF), 0);
        esc.put16(reg::DC_SPEED_COUNTER_DIFF, 7);
        esc.ecat_write(0x0930, &0x1000u16.to_le_bytes());
        assert_eq!(esc.get32(reg::DC_SYSTEM_TIME_DIFF), 0);
        assert_eq!(esc.get16(reg::DC_SPEED_COUNTER_DIFF), 0);
    }

    #[test]
    fn dc_time_stamps_are_on_the_10_ns_clock_with_jitter() {
        let mut esc = slave(0x00, &[]);
        let mut seen = std::collections::BTreeSet::new();
        for k in 0..200u64 {
            esc.now = 1_000_000 + k * 1_000_003;
            esc.ecat_write(0x0900, &[0]);
            let t = esc.get32(reg::DC_RECEIVE_TIME_PORT0) as u64;
            assert_eq!(t % DC_GRANULARITY_NS, 0);
            // Within one clock step of the true local time.
            let local = esc.dc.local(esc.now);
            assert!(
                t.abs_diff(local & 0xffff_ffff) <= DC_GRANULARITY_NS,
                "{t} {local}"
            );
            seen.insert((t as i64 - (local & 0xffff_ffff) as i64).signum());
        }
        assert!(seen.len() > 1, "no jitter: {seen:?}");
    }

    #[test]
    fn eeprom_offered_to_the_pdi_ignores_the_master_until_taken_back() {
        let mut esc = slave(0x00, &[]);
        let read = |esc: &mut Esc| {
            esc.ecat_write(0x0504, &0x08u32.to_le_bytes());
            esc.ecat_write(0x0502, &0x0100u16.to_le_bytes());
            esc.memory()[0x0508..0x0510].to_vec()
        };
        let before = read(&mut esc);
        // Offered to the PDI (0x0500 = 1): the application takes it (0x0501 bit 0).
        esc.ecat_write(0x0500, &[0x01]);
        assert!(esc.eeprom_at_pdi() && esc.memory()[0x0501] & 1 == 1);
        esc.mem[0x0508..0x0510].fill(0xEE);
        assert_eq!(read(&mut esc), vec![0xEE; 8]);
        // "Force ECAT access" (0x0500 = 2) takes it back at once.
        esc.ecat_write(0x0500, &[0x02]);
        assert!(!esc.eeprom_at_pdi() && esc.memory()[0x0501] == 0);
        assert_eq!(read(&mut esc), before);
        // 0x0501 belongs to the PDI: EtherCAT cannot write it.
        esc.ecat_write(0x0501, &[0x01]);
        assert_eq!(esc.memory()[0x0501], 0);
    }
}
