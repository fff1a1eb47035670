//! A tree of virtual ESCs processing EtherCAT frames as the hardware does: the frame walks the
//! slaves depth first in port order (0 → 3 → 1 → 2, see `topology`) and comes back to the
//! master; every datagram is handled at each slave's processing unit (the pass after port 0),
//! with the working-counter rules of ETG.1000.4 / the ESC datasheet. A line is the tree where
//! each slave hangs on port 1 of the previous one.

use ether_ros_protocol::{self as wire, Command};

use crate::esc::Esc;
use crate::faults::{Faults, Rng};
use crate::spec::SlaveSpec;
use crate::topology::{self, Node, Walk};

/// Most datagrams a frame can carry (each takes at least 12 bytes of a 1500-byte payload).
const MAX_DATAGRAMS: usize = 128;

/// Where time comes from: the host's monotonic clock, or a value tests set.
#[derive(Clone, Copy, Debug)]
pub enum Clock {
    Monotonic,
    Manual(u64),
}

/// Network-wide counters.
#[derive(Clone, Debug, Default)]
pub struct NetStats {
    pub frames_seen: u64,
    pub frames_answered: u64,
    pub frames_dropped: u64,
    pub frames_corrupted: u64,
    pub frames_malformed: u64,
    pub frames_not_ethercat: u64,
    pub datagrams: u64,
    pub unknown_commands: u64,
    pub per_command: [u64; 15],
    pub polls: u64,
    pub send_errors: u64,
}

#[derive(Clone, Copy, Default)]
struct Slot {
    header: usize,
    data: usize,
    len: usize,
}

pub struct Network {
    pub slaves: Vec<Esc>,
    pub clock: Clock,
    pub faults: Faults,
    pub rng: Rng,
    pub stats: NetStats,
    /// The frame's path through the tree, recomputed when slaves or links change.
    walk: Walk,
    scratch: Vec<u8>,
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
    pub fn new() -> Self {
        Network {
            slaves: Vec::new(),
            clock: Clock::Monotonic,
            faults: Faults::default(),
            rng: Rng::new(1),
            stats: NetStats::default(),
            walk: Walk::default(),
            scratch: Vec::with_capacity(wire::MAX_FRAME_LEN),
        }
    }

    /// A network whose time only moves when the caller sets it (tests).
    pub fn with_manual_clock(start_ns: u64) -> Self {
        let mut n = Self::new();
        n.clock = Clock::Manual(start_ns);
        n
    }

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

    /// Append a slave; returns its index. It hangs on `spec.upstream` (default: port 1 of the
    /// previous slave), and slaves must be added in the order the frame visits them (their
    /// auto-increment order). The device model is created from the spec's `device` and
    /// `params`; a device the chosen chip cannot carry is refused with the reason
    /// (`SlaveSpec::check_emulatable`).
    pub fn add_slave(&mut self, mut spec: SlaveSpec) -> Result<usize, String> {
        spec.check_emulatable()?;
        let pos = self.slaves.len();
        spec.upstream = self.check_upstream(&spec, pos)?;
        let device = crate::devices::create(&spec.device, &spec.params, &spec.loopback_links)?;
        let now = self.now();
        let mut esc = Esc::new(spec, pos, now);
        esc.device = device;
        if let Some(d) = esc.device.as_mut() {
            d.reset(&mut esc.od);
        }
        self.slaves.push(esc);
        if let Some(next) = topology::listed_out_of_order(&self.nodes()) {
            let esc = self.slaves.pop().expect("just pushed");
            let (parent, port) = esc.spec.upstream.expect("not the first slave");
            return Err(format!(
                "slave '{}' on port {port} of '{}': the frame reaches it before '{}' (ports \
                 are visited in the order 0, 3, 1, 2), so it must be listed before it",
                esc.spec.name, self.slaves[parent].spec.name, self.slaves[next].spec.name
            ));
        }
        self.update_topology();
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
        let Some(p) = self.slaves.get(parent) else {
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
        if let Some(other) = self
            .slaves
            .iter()
            .find(|s| s.spec.upstream == Some((parent, port)))
        {
            return Err(format!(
                "slave '{}': port {port} of '{}' is taken by '{}'",
                spec.name, p.spec.name, other.spec.name
            ));
        }
        Ok(Some((parent, port)))
    }

    /// The slaves as the topology walk sees them.
    fn nodes(&self) -> Vec<Node> {
        self.slaves
            .iter()
            .enumerate()
            .map(|(k, s)| Node {
                ports: s.spec.esc.profile().ports,
                delay_ns: s.spec.delay_ns,
                upstream: s.spec.upstream,
                link_down: self.faults.cut_links.contains(&k),
            })
            .collect()
    }

    /// Index of the slave on `port` of slave `parent` (None: nothing attached there).
    pub fn slave_on_port(&self, parent: usize, port: u8) -> Option<usize> {
        self.slaves
            .iter()
            .position(|s| s.spec.upstream == Some((parent, port)))
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
        let Some(old) = self.slaves.get_mut(pos) else {
            return false;
        };
        let spec = old.spec.clone();
        let device = old.device.take();
        let mut esc = Esc::new(spec, pos, now);
        esc.device = device;
        if let Some(d) = esc.device.as_mut() {
            d.reset(&mut esc.od);
        }
        self.slaves[pos] = esc;
        self.update_topology();
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
        let Some(esc) = self.slaves.get_mut(pos) else {
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
        self.walk = Walk::compute(&self.nodes());
        for (k, s) in self.slaves.iter_mut().enumerate() {
            s.open_ports = self.walk.open_ports[k];
            s.port_return_ns = self.walk.port_return[k];
            s.update_dl_status();
        }
    }

    /// Slaves the frame reaches, in auto-increment order.
    pub fn visit_order(&self) -> &[usize] {
        &self.walk.order
    }

    /// Advance every slave's application to now (device steps, SYNC0, watchdog, mailbox) —
    /// called by the runner when no frame arrives.
    pub fn poll(&mut self) {
        let now = self.now();
        self.poll_at(now);
    }

    pub fn poll_at(&mut self, now: u64) {
        self.stats.polls += 1;
        for (k, s) in self.slaves.iter_mut().enumerate() {
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
        for &k in &self.walk.order {
            let esc = &mut self.slaves[k];
            esc.advance(now + self.walk.arrival[k]);
            esc.before_frame();
            for s in &slots[..n] {
                process_datagram(esc, frame, s, &mut self.scratch);
            }
            esc.after_frame();
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

/// One datagram at one slave.
fn process_datagram(esc: &mut Esc, frame: &mut [u8], s: &Slot, scratch: &mut Vec<u8>) {
    let Some(cmd) = Command::from_u8(frame[s.header]) else {
        return;
    };
    let h = s.header;
    let address = u32::from_le_bytes([frame[h + 2], frame[h + 3], frame[h + 4], frame[h + 5]]);
    let (adp, ado) = wire::split_address(address);
    let wkc_at = s.data + s.len;
    let mut wkc = u16::from_le_bytes([frame[wkc_at], frame[wkc_at + 1]]);
    let data = &mut frame[s.data..s.data + s.len];
    let ado = ado as usize;
    use Command::*;
    match cmd {
        Nop => return,
        Aprd | Apwr | Aprw | Armw | Brd | Bwr | Brw => {
            let addressed = matches!(cmd, Brd | Bwr | Brw) || adp == 0;
            // Auto-increment and broadcast: every slave increments ADP.
            let next = (adp.wrapping_add(1) as u32) | ((ado as u32) << 16);
            wkc = wkc.wrapping_add(physical(esc, cmd, addressed, ado, data, scratch));
            frame[h + 2..h + 6].copy_from_slice(&next.to_le_bytes());
        }
        Fprd | Fpwr | Fprw | Frmw => {
            let addressed = esc.matches_fixed(adp);
            wkc = wkc.wrapping_add(physical(esc, cmd, addressed, ado, data, scratch));
        }
        Lrd | Lwr | Lrw => {
            let reads = cmd != Lwr;
            let writes = cmd != Lrd;
            wkc = wkc.wrapping_add(esc.logical(address, data, reads, writes, scratch));
        }
    }
    frame[wkc_at..wkc_at + 2].copy_from_slice(&wkc.to_le_bytes());
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
