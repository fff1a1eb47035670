//! A tree of virtual ESCs processing EtherCAT frames as the hardware does: the frame walks the
//! slaves depth first in port order (0 → 3 → 1 → 2, see `topology`) and comes back to the
//! master; every datagram is handled at each slave's processing unit (the pass after port 0),
//! with the working-counter rules of ETG.1000.4 / the ESC datasheet. A line is the tree where
//! each slave hangs on port 1 of the previous one.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use ether_ros_protocol::{self as wire, reg, Addressing, Command};

use crate::esc::Esc;
use crate::faults::{Faults, Rng};
use crate::firmware::Roster;
use crate::pi_mutex::{PiGuard, PiMutex};
use crate::spec::SlaveSpec;
use crate::topology::{self, Node, Walk};

/// Most datagrams a frame can carry (each takes at least 12 bytes of a 1500-byte payload).
const MAX_DATAGRAMS: usize = 128;

/// Where time comes from: the host's monotonic clock, or a value tests set.
#[derive(Clone, Copy, Debug)]
pub enum Clock {
    /// CLOCK_MONOTONIC.
    Monotonic,
    /// A time (ns) the tests set and move.
    Manual(u64),
}

/// Network-wide counters.
#[derive(Clone, Debug, Default)]
pub struct NetStats {
    /// Frames received.
    pub frames_seen: u64,
    /// Frames answered.
    pub frames_answered: u64,
    /// Frames dropped by the drop fault.
    pub frames_dropped: u64,
    /// Frames corrupted by the corrupt fault.
    pub frames_corrupted: u64,
    /// Frames with a malformed EtherCAT header or datagram.
    pub frames_malformed: u64,
    /// Frames of another EtherType, ignored.
    pub frames_not_ethercat: u64,
    /// Datagrams processed.
    pub datagrams: u64,
    /// Datagrams with an unknown command.
    pub unknown_commands: u64,
    /// Datagrams per command code.
    pub per_command: [u64; 15],
    /// Polls without a frame.
    pub polls: u64,
    /// Answers the runner could not send.
    pub send_errors: u64,
    /// Longest gap between two frames received by the runner, and longest time one frame
    /// took from its receipt to its answer leaving (ns; the runner's own measurement).
    pub max_frame_gap_ns: u64,
    /// Longest time one frame took to process (ns).
    pub max_frame_ns: u64,
}

#[derive(Clone, Copy, Default)]
struct Slot {
    header: usize,
    data: usize,
    len: usize,
}

/// One datagram's addressing, decoded once per frame.
#[derive(Clone, Copy, Default)]
struct Route {
    cmd: Option<Command>,
    adp: u16,
    ado: u16,
    /// Walk position an auto-increment datagram addresses (the slave that sees ADP = 0).
    position: Option<usize>,
    /// Configured-address datagrams: the walk positions whose address matched, from the map
    /// (a range of `Network::fixed_hits`); None: ask each slave (the map may be out of date).
    fixed: Option<(usize, usize)>,
}

/// A slave controller behind its own lock: the frame path and the firmware worker that runs
/// its device (`crate::firmware`) take turns on it (priority inheritance: the frame thread
/// never waits behind a preempted worker).
pub type SlaveCell = Arc<PiMutex<Esc>>;

/// Lock a slave.
pub fn lock(cell: &SlaveCell) -> PiGuard<'_, Esc> {
    cell.lock()
}

/// Where each slave's device firmware runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FirmwareMode {
    /// In the frame path: every frame first advances every slave it reaches to its arrival
    /// time (deterministic: tests with a manual clock, the in-process link).
    Inline,
    /// On worker threads at its own clock (`crate::firmware`); the frame path does ESC work.
    Threads,
}

/// Who a datagram can reach, kept between frames: configured addresses and FMMU ranges per
/// walk position. Rebuilt after a frame wrote an addressing or FMMU register, or the slaves
/// or the topology changed.
#[derive(Default)]
struct AddressMaps {
    stale: bool,
    /// (station address or enabled alias, walk position), sorted.
    fixed: Vec<(u16, usize)>,
    /// (first logical bit, end bit, walk position) of every active FMMU, sorted.
    logical: Vec<(u64, u64, usize)>,
    /// Longest FMMU range in bits (bounds the search to the left).
    longest: u64,
}

impl AddressMaps {
    fn rebuild(&mut self, slaves: &[SlaveCell], order: &[usize]) {
        self.fixed.clear();
        self.logical.clear();
        self.longest = 0;
        for (p, &k) in order.iter().enumerate() {
            let esc = lock(&slaves[k]);
            let station = esc.station_address();
            self.fixed.push((station, p));
            if esc.alias_enabled() && esc.alias() != station {
                self.fixed.push((esc.alias(), p));
            }
            for f in esc.fmmus() {
                let (a, b) = (f.first_bit(), f.end_bit());
                if b <= a {
                    // A stop bit before the start bit in a one-byte mapping: maps no bit.
                    continue;
                }
                self.logical.push((a, b, p));
                self.longest = self.longest.max(b - a);
            }
        }
        self.fixed.sort_unstable();
        self.logical.sort_unstable();
        self.stale = false;
    }

    /// Walk positions whose station address or alias is `adp`.
    fn fixed_positions(&self, adp: u16, out: &mut Vec<usize>) {
        let from = self.fixed.partition_point(|e| e.0 < adp);
        out.extend(
            self.fixed[from..]
                .iter()
                .take_while(|e| e.0 == adp)
                .map(|e| e.1),
        );
    }

    /// Walk positions with an FMMU overlapping logical bits `d0..d1`.
    fn logical_positions(&self, d0: u64, d1: u64, out: &mut Vec<usize>) {
        let from = self
            .logical
            .partition_point(|e| e.0.saturating_add(self.longest) <= d0);
        let to = self.logical.partition_point(|e| e.0 < d1);
        if from < to {
            out.extend(
                self.logical[from..to]
                    .iter()
                    .filter(|e| e.1 > d0)
                    .map(|e| e.2),
            );
        }
    }
}

/// Does writing `data` at register `ado` change who a datagram reaches? Station address and
/// alias, DL control (alias enable), the FMMUs, and an SII reload command (it loads the
/// alias from the EEPROM; the SII's read commands do not).
fn changes_addressing(ado: usize, data: &[u8]) -> bool {
    let hits = |start: u16, n: usize| {
        let start = start as usize;
        ado < start + n && ado + data.len() > start
    };
    let command = reg::SII_CONTROL as usize + 1;
    let reload = (ado..ado + data.len()).contains(&command)
        && (u16::from(data[command - ado]) << 8) & crate::sii::CMD_MASK == crate::sii::CMD_RELOAD;
    hits(reg::STATION_ADDRESS, 4)
        || hits(reg::DL_CONTROL, 4)
        || hits(reg::FMMU0, crate::esc::N_FMMU * reg::FMMU_LEN as usize)
        || reload
}

/// Bits on the wire per byte at 100 Mbit/s, as time: 80 ns.
const NS_PER_BYTE: u64 = 80;
/// What a frame occupies on the wire beside its bytes: preamble and start delimiter (8), FCS
/// (4) and the inter-frame gap (12), IEEE 802.3.
const FRAME_OVERHEAD_BYTES: u64 = 24;

/// The virtual bus: slaves in frame visiting order, the tree they form, the clock, the
/// injected faults and the statistics. Frames go through [`Network::process_frame`].
pub struct Network {
    slaves: Vec<SlaveCell>,
    /// Each slave's place in the tree (ports, delay, upstream), as the topology walk needs it;
    /// `link_down` from `faults.cut_links`.
    nodes: Vec<Node>,
    /// Where time comes from.
    pub clock: Clock,
    /// The faults injected now.
    pub faults: Faults,
    /// Random source of the probabilistic faults (seeded, so runs repeat).
    pub rng: Rng,
    /// Frame and datagram counters.
    pub stats: NetStats,
    /// The frame's path through the tree, recomputed when slaves or links change.
    walk: Walk,
    scratch: Vec<u8>,
    firmware: FirmwareMode,
    maps: AddressMaps,
    /// Walk positions the current frame reaches (scratch, no allocation per frame).
    touched: Vec<usize>,
    routes: Vec<Route>,
    fixed_hits: Vec<usize>,
    /// Frames that walked the tree so far, and the value when each slave's own count was last
    /// brought up to date (`counters.frames`; None: unreachable since then).
    frames_walked: u64,
    frames_since: Vec<Option<u64>>,
    /// Bumped whenever the slaves or their order change: the firmware workers pick up their
    /// share again.
    generation: Arc<AtomicU64>,
    /// The firmware workers' view of the slaves, while they run.
    roster: Option<Arc<Roster>>,
}

impl Default for Network {
    fn default() -> Self {
        Self::new()
    }
}

/// CLOCK_MONOTONIC in ns: the network's time base, and the runner's for delayed replies.
pub(crate) fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we own.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

impl Network {
    /// An empty network on the monotonic clock.
    pub fn new() -> Self {
        Network {
            slaves: Vec::new(),
            nodes: Vec::new(),
            clock: Clock::Monotonic,
            faults: Faults::default(),
            rng: Rng::new(1),
            stats: NetStats::default(),
            walk: Walk::default(),
            scratch: Vec::with_capacity(wire::MAX_FRAME_LEN),
            firmware: FirmwareMode::Inline,
            maps: AddressMaps::default(),
            touched: Vec::new(),
            routes: Vec::with_capacity(MAX_DATAGRAMS),
            fixed_hits: Vec::new(),
            frames_walked: 0,
            frames_since: Vec::new(),
            generation: Arc::new(AtomicU64::new(0)),
            roster: None,
        }
    }

    /// A network whose time only moves when the caller sets it (tests).
    pub fn with_manual_clock(start_ns: u64) -> Self {
        let mut n = Self::new();
        n.clock = Clock::Manual(start_ns);
        n
    }

    /// Current time (ns) on the network's clock.
    pub fn now(&self) -> u64 {
        match self.clock {
            Clock::Monotonic => monotonic_ns(),
            Clock::Manual(t) => t,
        }
    }

    /// Move a manual clock forward (no effect on a monotonic one).
    pub fn advance_clock(&mut self, ns: u64) {
        if let Clock::Manual(t) = self.clock {
            self.clock = Clock::Manual(t + ns);
        }
    }

    /// Number of slaves.
    pub fn len(&self) -> usize {
        self.slaves.len()
    }

    /// True when the network has no slave.
    pub fn is_empty(&self) -> bool {
        self.slaves.is_empty()
    }

    /// Slave `k`, locked (panics when there is none: tests; see `try_slave`).
    pub fn slave(&self, k: usize) -> PiGuard<'_, Esc> {
        lock(&self.slaves[k])
    }

    /// Slave `k`, locked, if there is one.
    pub fn try_slave(&self, k: usize) -> Option<PiGuard<'_, Esc>> {
        self.slaves.get(k).map(lock)
    }

    /// The slaves' cells (the firmware workers share them).
    pub fn cells(&self) -> &[SlaveCell] {
        &self.slaves
    }

    /// Changes whenever the slaves change (added, reset): workers reload their share.
    pub fn generation(&self) -> Arc<AtomicU64> {
        self.generation.clone()
    }

    /// Where the device firmware runs (frame thread or workers).
    pub fn firmware_mode(&self) -> FirmwareMode {
        self.firmware
    }

    /// Run the device firmware inline (in the frame path) or leave it to worker threads
    /// (`crate::firmware::Workers`, started by the runner).
    pub fn set_firmware_mode(&mut self, mode: FirmwareMode) {
        self.firmware = mode;
        self.maps.stale = true;
        for cell in &self.slaves {
            lock(cell).set_firmware_latches(mode == FirmwareMode::Threads);
        }
    }

    fn changed(&mut self) {
        if let Some(r) = &self.roster {
            r.update(self.slaves.clone());
        }
        self.generation.fetch_add(1, Ordering::Release);
    }

    /// Keep `roster` up to date with the slaves (the runner's workers read it).
    pub fn set_roster(&mut self, roster: Arc<Roster>) {
        self.roster = Some(roster);
    }

    /// Forget the firmware workers' roster (the runner stops its workers).
    pub fn clear_roster(&mut self) {
        self.roster = None;
    }

    /// Frames that reached slave `k` (its own count since its last reset).
    pub fn slave_frames(&self, k: usize) -> u64 {
        let base = self.slaves.get(k).map_or(0, |c| lock(c).counters.frames);
        let since = self.frames_since.get(k).copied().flatten();
        base + since.map_or(0, |s| self.frames_walked - s)
    }

    /// Bring every slave's frame count up to date (before the set of reachable slaves changes).
    fn settle_frame_counts(&mut self) {
        for (k, since) in self.frames_since.iter_mut().enumerate() {
            if let Some(s) = since.take() {
                if self.frames_walked > s {
                    lock(&self.slaves[k]).counters.frames += self.frames_walked - s;
                }
            }
        }
    }

    /// Append a slave; returns its index. It hangs on `spec.upstream` (default: port 1 of the
    /// previous slave), and slaves must be added in the order the frame visits them (their
    /// auto-increment order). The device model is created from the spec's `device` and
    /// `params`; a device the chosen chip cannot carry is refused with the reason
    /// (`SlaveSpec::check_emulatable`).
    pub fn add_slave(&mut self, mut spec: SlaveSpec) -> Result<usize, crate::SpecError> {
        use crate::SpecError;
        spec.check_emulatable()
            .map_err(|m| SpecError::new("sii", m))?;
        let pos = self.slaves.len();
        spec.upstream = self
            .check_upstream(&spec, pos)
            .map_err(|m| SpecError::new("upstream", m))?;
        let device = crate::devices::create(&spec.device, &spec.params, &spec.loopback_links)
            .map_err(|m| SpecError::new("device", m))?;
        let now = self.now();
        let mut esc = Esc::new(spec, pos, now);
        esc.device = device;
        if let Some(d) = esc.device.as_mut() {
            d.reset(&mut esc.od);
        }
        esc.set_firmware_latches(self.firmware == FirmwareMode::Threads);
        let spec_upstream = esc.spec.upstream;
        let name = esc.spec.name.clone();
        self.nodes.push(Node {
            ports: esc.spec.esc.profile().ports,
            delay_ns: esc.spec.delay_ns,
            upstream: spec_upstream,
            link_down: false,
        });
        if let Some(next) = topology::listed_out_of_order(&self.nodes) {
            self.nodes.pop();
            let (parent, port) = spec_upstream.expect("not the first slave");
            return Err(SpecError::new(
                "upstream",
                format!(
                    "slave '{name}' on port {port} of '{}': the frame reaches it before '{}' \
                     (ports are visited in the order 0, 3, 1, 2), so it must be listed before it",
                    lock(&self.slaves[parent]).spec.name,
                    lock(&self.slaves[next]).spec.name
                ),
            ));
        }
        self.slaves.push(Arc::new(PiMutex::new(esc)));
        self.frames_since.push(None);
        self.update_topology();
        self.changed();
        Ok(pos)
    }

    /// The upstream connection of slave `pos` (default: the previous slave's port 1), checked:
    /// an earlier slave, a port its chip has, not already taken.
    fn check_upstream(&self, spec: &SlaveSpec, pos: usize) -> Result<Option<(usize, u8)>, String> {
        if pos == 0 {
            return match spec.upstream {
                None => Ok(None),
                Some(_) => Err(format!(
                    "slave '{}': the first slave is connected to the master, not to a slave",
                    spec.name
                )),
            };
        }
        let (parent, port) = spec.upstream.unwrap_or((pos - 1, 1));
        let Some(p) = self.try_slave(parent) else {
            return Err(format!(
                "slave '{}': parent index {parent} is not an earlier slave (0..{})",
                spec.name,
                pos - 1
            ));
        };
        let ports = p.spec.esc.profile().ports;
        if port == 0 || port >= ports {
            return Err(format!(
                "slave '{}': '{}' ({}) has no port {port} to connect to (ports 1..{})",
                spec.name,
                p.spec.name,
                p.spec.esc.name(),
                ports - 1
            ));
        }
        let parent_name = p.spec.name.clone();
        drop(p);
        if let Some(other) = self.slave_on_port(parent, port) {
            return Err(format!(
                "slave '{}': port {port} of '{parent_name}' is taken by '{}'",
                spec.name,
                lock(&self.slaves[other]).spec.name
            ));
        }
        Ok(Some((parent, port)))
    }

    /// Index of the slave on `port` of slave `parent` (None: nothing attached there).
    pub fn slave_on_port(&self, parent: usize, port: u8) -> Option<usize> {
        self.nodes
            .iter()
            .position(|n| n.upstream == Some((parent, port)))
    }

    /// Cut (or mend) the link into slave `k`'s port 0.
    pub fn set_link_cut(&mut self, k: usize, cut: bool) {
        self.faults.cut_links.retain(|&c| c != k);
        if cut {
            self.faults.cut_links.push(k);
        }
        self.update_topology();
    }

    /// Every link up again: the master's and every cut inside the bus.
    pub fn mend_all_links(&mut self) {
        self.faults.link_down = false;
        if !self.faults.cut_links.is_empty() {
            self.faults.cut_links.clear();
            self.update_topology();
        }
    }

    /// Power-cycle one slave: registers back to their defaults, device reset.
    pub fn reset_slave(&mut self, pos: usize) -> bool {
        let now = self.now();
        let Some(cell) = self.slaves.get(pos) else {
            return false;
        };
        {
            let mut old = lock(cell);
            let spec = old.spec.clone();
            let device = old.device.take();
            let mut esc = Esc::new(spec, pos, now);
            esc.device = device;
            if let Some(d) = esc.device.as_mut() {
                d.reset(&mut esc.od);
            }
            esc.set_firmware_latches(self.firmware == FirmwareMode::Threads);
            if let (Some(&ports), Some(&back)) = (
                self.walk.open_ports.get(pos),
                self.walk.port_return.get(pos),
            ) {
                esc.open_ports = ports;
                esc.port_return_ns = back;
                esc.update_dl_status();
            }
            *old = esc;
        }
        if let Some(since) = self.frames_since.get_mut(pos) {
            // The new slave counts from zero.
            *since = since.map(|_| self.frames_walked);
        }
        self.update_topology();
        self.changed();
        true
    }

    /// Inject a fault into the firmware model of slave `pos` (e.g. a CiA 402 drive fault on
    /// one axis); an error names what is wrong (no slave, no model, unknown fault, no axis).
    pub fn inject_device_fault(
        &mut self,
        pos: usize,
        fault: &str,
        axis: usize,
    ) -> Result<(), String> {
        let Some(mut esc) = self.try_slave(pos) else {
            return Err(format!("no slave at position {pos}"));
        };
        let name = esc.spec.name.clone();
        match esc.device.as_mut() {
            Some(d) => d
                .inject_fault(fault, axis)
                .map_err(|e| format!("slave {pos} ({name}): {e}")),
            None => Err(format!(
                "slave {pos} ({name}) runs no firmware model (device 'none')"
            )),
        }
    }

    /// Recompute the frame's walk and every slave's port states from the tree and the cut
    /// links.
    pub fn update_topology(&mut self) {
        self.settle_frame_counts();
        for (k, n) in self.nodes.iter_mut().enumerate() {
            n.link_down = self.faults.cut_links.contains(&k);
        }
        let old = std::mem::replace(&mut self.walk, Walk::compute(&self.nodes));
        for (k, cell) in self.slaves.iter().enumerate() {
            // Only slaves whose ports changed (adding a slave to a line changes one).
            let same = old.open_ports.get(k) == Some(&self.walk.open_ports[k])
                && old.port_return.get(k) == Some(&self.walk.port_return[k]);
            if same {
                continue;
            }
            let mut s = lock(cell);
            s.open_ports = self.walk.open_ports[k];
            s.port_return_ns = self.walk.port_return[k];
            s.update_dl_status();
        }
        for &k in &self.walk.order {
            self.frames_since[k] = Some(self.frames_walked);
        }
        self.touched = Vec::with_capacity(self.slaves.len() * crate::esc::N_FMMU + MAX_DATAGRAMS);
        self.fixed_hits = Vec::with_capacity(self.slaves.len() * MAX_DATAGRAMS.min(8));
        self.maps.stale = true;
    }

    /// Slaves the frame reaches, in auto-increment order.
    pub fn visit_order(&self) -> &[usize] {
        &self.walk.order
    }

    /// The modelled wire for a frame of `len` bytes (without FCS): (ns it occupies the
    /// master's 100 Mbit/s link, ns its last bit takes to come back through the slaves).
    pub fn wire_time(&self, len: usize) -> (u64, u64) {
        let bytes = (len.max(wire::MIN_FRAME_LEN) as u64) + FRAME_OVERHEAD_BYTES;
        (bytes * NS_PER_BYTE, self.walk.round_trip)
    }

    /// Advance every slave's application to now (device steps, SYNC0, watchdog, mailbox) —
    /// called by the runner when no frame arrives (firmware inline).
    pub fn poll(&mut self) {
        let now = self.now();
        self.poll_at(now);
    }

    /// Advance device models, SYNC0 and watchdogs to `now` without a frame.
    pub fn poll_at(&mut self, now: u64) {
        self.stats.polls += 1;
        for (k, cell) in self.slaves.iter().enumerate() {
            let mut s = lock(cell);
            s.advance(now + self.walk.arrival[k]);
            s.service_mailbox();
        }
    }

    /// Process one frame in place at the current time. Returns true when an answer goes back
    /// (the frame then holds it), false when the frame is dropped or not ours.
    pub fn process_frame(&mut self, frame: &mut [u8]) -> bool {
        let now = self.now();
        self.process_frame_at(frame, now)
    }

    /// Process `frame` in place at time `now`; true when it is answered.
    pub fn process_frame_at(&mut self, frame: &mut [u8], now: u64) -> bool {
        self.stats.frames_seen += 1;
        let end = match wire::check_frame(frame) {
            Ok(e) => e,
            Err(wire::WireError::NotEthercat) => {
                self.stats.frames_not_ethercat += 1;
                return false;
            }
            Err(_) => {
                self.stats.frames_malformed += 1;
                return false;
            }
        };
        let mut slots = [Slot::default(); MAX_DATAGRAMS];
        let Some(n) = parse_datagrams(frame, end, &mut slots) else {
            self.stats.frames_malformed += 1;
            return false;
        };
        let dropped = self.faults.should_drop(&mut self.rng);
        if dropped && (self.faults.drop_outbound || self.faults.link_down) {
            self.stats.frames_dropped += 1;
            return false;
        }
        for s in &slots[..n] {
            self.stats.datagrams += 1;
            match Command::from_u8(frame[s.header]) {
                Some(c) => self.stats.per_command[c as usize] += 1,
                None => self.stats.unknown_commands += 1,
            }
        }
        self.frames_walked += 1;
        self.route(frame, &slots[..n]);
        let reached = self.walk.order.len();
        for i in 0..self.touched.len() {
            let p = self.touched[i];
            let k = self.walk.order[p];
            let t = now + self.walk.arrival[k];
            let mut esc = lock(&self.slaves[k]);
            match self.firmware {
                FirmwareMode::Inline => esc.advance(t),
                FirmwareMode::Threads => esc.frame_catch_up(t),
            }
            esc.before_frame();
            for (s, r) in slots[..n].iter().zip(&self.routes) {
                let addressed = match (r.cmd.map(Command::addressing), r.fixed) {
                    (Some(Addressing::Fixed), Some((a, b))) => {
                        self.fixed_hits[a..b].binary_search(&p).is_ok()
                    }
                    (Some(Addressing::Fixed), None) => esc.matches_fixed(r.adp),
                    _ => r.position == Some(p),
                };
                process_datagram(&mut esc, frame, s, r, addressed, &mut self.scratch);
            }
            esc.after_frame();
        }
        // Every slave the frame passed incremented the ADP of auto-increment and broadcast
        // datagrams.
        for (s, r) in slots[..n].iter().zip(&self.routes) {
            if matches!(
                r.cmd.map(Command::addressing),
                Some(Addressing::AutoIncrement | Addressing::Broadcast)
            ) {
                let adp = r.adp.wrapping_add(reached as u16);
                frame[s.header + 2..s.header + 4].copy_from_slice(&adp.to_le_bytes());
            }
        }
        if self.maps.stale && self.firmware == FirmwareMode::Threads {
            // This frame changed addresses or FMMUs: the next one routes with the new maps.
            self.maps.rebuild(&self.slaves, &self.walk.order);
        }
        if dropped {
            self.stats.frames_dropped += 1;
            return false;
        }
        if self.faults.maybe_corrupt(&mut self.rng, frame) {
            self.stats.frames_corrupted += 1;
        }
        // Every frame that passed an EtherCAT processing unit has the locally administered bit
        // of its source MAC set (SOURCE_MAC[1] = 1, ESC datasheet section I, "Frame
        // processing"): set, not toggled, so a master may send with it set already.
        frame[6] |= 0x02;
        self.stats.frames_answered += 1;
        true
    }

    /// Decode each datagram's addressing and collect the walk positions the frame reaches
    /// (`touched`, in walk order): with the firmware inline every reachable slave (each
    /// advances to the frame's time); otherwise only the slaves a datagram addresses, from
    /// the maps — every slave for broadcasts, ARMW/FRMW, and frames that change addressing.
    fn route(&mut self, frame: &[u8], slots: &[Slot]) {
        let threads = self.firmware == FirmwareMode::Threads;
        if self.maps.stale && threads {
            self.maps.rebuild(&self.slaves, &self.walk.order);
        }
        let reached = self.walk.order.len();
        self.routes.clear();
        self.touched.clear();
        self.fixed_hits.clear();
        let mut all = !threads;
        // Set once a datagram of this frame rewrites addressing registers: the maps no longer
        // tell who the following datagrams reach.
        let mut readdressed = !threads;
        for s in slots {
            let h = s.header;
            let cmd = Command::from_u8(frame[h]);
            let address =
                u32::from_le_bytes([frame[h + 2], frame[h + 3], frame[h + 4], frame[h + 5]]);
            let (adp, ado) = wire::split_address(address);
            let mut route = Route {
                cmd,
                adp,
                ado,
                position: None,
                fixed: None,
            };
            let Some(c) = cmd else {
                self.routes.push(route);
                continue;
            };
            if c.writes()
                && c.addressing() != Addressing::Logical
                && changes_addressing(ado as usize, &frame[s.data..s.data + s.len])
            {
                // Who the later datagrams reach may change within this frame.
                self.maps.stale = true;
                all = true;
                readdressed = true;
            }
            if c.addressing() == Addressing::AutoIncrement {
                let p = adp.wrapping_neg() as usize;
                route.position = (p < reached).then_some(p);
            }
            if c.addressing() == Addressing::Fixed && !readdressed {
                let from = self.fixed_hits.len();
                self.maps.fixed_positions(adp, &mut self.fixed_hits);
                route.fixed = Some((from, self.fixed_hits.len()));
            }
            match c {
                Command::Nop => {}
                // Read at the addressed slave, written at every other one.
                Command::Armw | Command::Frmw => all = true,
                _ => match c.addressing() {
                    Addressing::AutoIncrement => self.touched.extend(route.position),
                    Addressing::Fixed => match route.fixed {
                        Some((a, b)) => self.touched.extend_from_slice(&self.fixed_hits[a..b]),
                        None => all = true,
                    },
                    Addressing::Broadcast => all = true,
                    Addressing::Logical => {
                        let d0 = address as u64 * 8;
                        self.maps
                            .logical_positions(d0, d0 + s.len as u64 * 8, &mut self.touched);
                    }
                    Addressing::None => {}
                },
            }
            self.routes.push(route);
        }
        if all {
            self.touched.clear();
            self.touched.extend(0..reached);
        } else {
            self.touched.sort_unstable();
            self.touched.dedup();
        }
    }

    /// Delay to apply before sending an answer (µs), from the fault settings.
    pub fn reply_delay_us(&self) -> u64 {
        self.faults.delay_us
    }
}

/// Locate every datagram; None when one runs past the frame (the frame is then not answered,
/// as a real ESC invalidates a frame whose length fields are inconsistent).
fn parse_datagrams(frame: &[u8], end: usize, slots: &mut [Slot; MAX_DATAGRAMS]) -> Option<usize> {
    let mut pos = wire::ETH_HEADER_LEN + wire::ECAT_HEADER_LEN;
    let mut n = 0;
    while pos < end {
        if n == MAX_DATAGRAMS || pos + wire::DATAGRAM_HEADER_LEN > end {
            return None;
        }
        let lenword = u16::from_le_bytes([frame[pos + 6], frame[pos + 7]]);
        let len = (lenword & 0x07ff) as usize;
        let data = pos + wire::DATAGRAM_HEADER_LEN;
        if data + len + wire::WKC_LEN > end {
            return None;
        }
        slots[n] = Slot {
            header: pos,
            data,
            len,
        };
        n += 1;
        pos = data + len + wire::WKC_LEN;
        if lenword & 0x8000 == 0 {
            break;
        }
    }
    Some(n)
}

/// One datagram at one slave; `addressed`: the slave is the one a position or configured
/// address names (broadcasts address every slave, logical datagrams go by the FMMUs).
fn process_datagram(
    esc: &mut Esc,
    frame: &mut [u8],
    s: &Slot,
    r: &Route,
    addressed: bool,
    scratch: &mut Vec<u8>,
) {
    let Some(cmd) = r.cmd else {
        return;
    };
    let h = s.header;
    let wkc_at = s.data + s.len;
    let mut wkc = u16::from_le_bytes([frame[wkc_at], frame[wkc_at + 1]]);
    let ado = r.ado as usize;
    use Command::*;
    let increment = match cmd {
        Nop => return,
        Aprd | Apwr | Aprw | Armw | Brd | Bwr | Brw => {
            // Auto-increment: the slave that sees ADP = 0 (the network writes the ADP every
            // slave incremented once the frame has passed them all).
            let addressed = addressed || matches!(cmd, Brd | Bwr | Brw);
            let data = &mut frame[s.data..s.data + s.len];
            physical(esc, cmd, addressed, ado, data, scratch)
        }
        Fprd | Fpwr | Fprw | Frmw => {
            let data = &mut frame[s.data..s.data + s.len];
            physical(esc, cmd, addressed, ado, data, scratch)
        }
        Lrd | Lwr | Lrw => {
            let address =
                u32::from_le_bytes([frame[h + 2], frame[h + 3], frame[h + 4], frame[h + 5]]);
            let data = &mut frame[s.data..s.data + s.len];
            esc.logical(address, data, cmd != Lwr, cmd != Lrd, scratch)
        }
    };
    if increment != 0 {
        wkc = wkc.wrapping_add(increment);
        frame[wkc_at..wkc_at + 2].copy_from_slice(&wkc.to_le_bytes());
    }
}

/// Physical access of a position/station/broadcast command; returns the WKC increment.
fn physical(
    esc: &mut Esc,
    cmd: Command,
    addressed: bool,
    ado: usize,
    data: &mut [u8],
    scratch: &mut Vec<u8>,
) -> u16 {
    use Command::*;
    match cmd {
        Armw | Frmw => {
            // Read at the addressed slave, write at all others.
            if addressed {
                esc.ecat_read(ado, data, false) as u16
            } else {
                esc.ecat_write(ado, data) as u16
            }
        }
        _ if !addressed => 0,
        Aprd | Fprd => esc.ecat_read(ado, data, false) as u16,
        Brd => esc.ecat_read(ado, data, true) as u16,
        Apwr | Fpwr | Bwr => esc.ecat_write(ado, data) as u16,
        Aprw | Fprw | Brw => {
            scratch.clear();
            scratch.extend_from_slice(data);
            let r = esc.ecat_read(ado, data, cmd == Brw);
            let w = esc.ecat_write(ado, scratch);
            r as u16 + 2 * w as u16
        }
        Nop | Lrd | Lwr | Lrw => 0,
    }
}
