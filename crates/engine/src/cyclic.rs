//! The cyclic real-time loop. Everything it touches is allocated before the loop starts; per
//! cycle it makes only the cycle's own syscalls (clock_nanosleep, send, recvmsg/ppoll) and hands
//! data to Python through the lock-free structures of `handover`.

use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU32, AtomicU64, AtomicU8, Ordering};
use std::sync::Arc;

use ether_ros_protocol::{self as wire, MAX_FRAME_LEN};

use crate::cia402::{Axes, AxisExchange};
use crate::frames::{frame_index, reply_matches};
use crate::handover::{flags, Mailbox, SampleRecord, SampleRing, SeqBuffer};
use crate::plan::{CycleLayout, DcMode, Order, Plan};
use crate::stats::{FrameStats, Stats};
use ether_ros_link::clock::{now_ns, sleep_until};
use ether_ros_link::{Link, Received};

/// Cyclic frames carry indices 0x80..=0xFF (rotating, one per frame sent), acyclic ones
/// 0x00..=0x7F, so a reply tells at a glance which path it belongs to.
pub const CYCLIC_INDEX_BIT: u8 = 0x80;
/// Number of cyclic indices: at most two cycles of frames are in flight (send_at_wake), and
/// `plan::MAX_FRAMES` keeps them apart.
const CYCLIC_INDICES: usize = 128;
/// At most this many frames are read per receive pass beyond the cycle's own, so a flood cannot
/// hold the loop.
const MAX_EXTRA_FRAMES_PER_CYCLE: usize = 32;
/// Reset bit (beside the frame bits 0..32 of `Exchange::reset_pending`/`reset_done`): every
/// output range of the image.
pub const RESET_ALL: u64 = 1 << 32;
/// Copies of the output buffer tried per cycle when a write overlaps: a writer's copy takes
/// well under a microsecond, so a second try almost always gets a whole version.
const OUTPUT_READ_ATTEMPTS: usize = 3;

/// State shared by the engine and its RT thread for the engine's whole life.
#[derive(Default)]
pub struct Shared {
    pub stats: Stats,
    pub mailbox: Mailbox,
    pub panic: AtomicBool,
    pub stop: AtomicBool,
    /// True while the RT loop runs.
    pub alive: AtomicBool,
    pub reset_requested: AtomicBool,
    /// Last write_outputs / feed_watchdog, CLOCK_MONOTONIC ns.
    pub last_command_ns: AtomicI64,
    pub acyclic_index: AtomicU8,
    /// Cycle time of the running plan (for waiters), ns.
    pub cycle_ns: AtomicI64,
    /// Cyclic runs started so far (each Exchange gets the next number).
    pub runs: AtomicU64,
}

/// The buffers of one cyclic run, shared with Python.
pub struct Exchange {
    pub plan: Plan,
    /// Output ranges merged into runs (what `write_outputs` may touch).
    pub output_runs: Vec<(usize, usize)>,
    /// Written by Python (one writer at a time), read by the RT thread.
    pub outputs: SeqBuffer,
    /// The latest process image, written by the RT thread after every cycle.
    pub image: SeqBuffer,
    pub ring: SampleRing,
    /// Command, trajectory and status slots of the CiA 402 axes.
    pub axes: AxisExchange,
    /// Counters and round trip per cyclic frame, in plan order.
    pub frames: Box<[FrameStats]>,
    /// Per cyclic frame: the last write that touched its output bytes (or feed), ns.
    pub frame_commands: Box<[AtomicI64]>,
    /// Per cyclic frame: its output byte runs (what a write must touch to feed its watchdog).
    pub frame_outputs: Vec<Vec<(usize, usize)>>,
    /// Which cyclic run of the engine this is (1, 2, ...; 0 before `start_cyclic` numbers it).
    pub run: u64,
    /// Bit k: cyclic frame k's inputs in the image are stale (the last cycle's
    /// `SampleRecord::stale_mask`); all set until the first whole replies.
    pub stale_mask: AtomicU32,
    /// Resets owed to the output buffer (bit k: frame k's output bytes; `RESET_ALL`: every
    /// output range). The RT thread sets a bit when a watchdog trips; the next writer (under
    /// the output writer lock) puts the safe image's bytes there before its own write and
    /// clears the bit. Until then the RT thread sends the safe bytes for those frames: a
    /// command after a stop must not bring back what was commanded before it (ISO 13850:
    /// resetting a stop does not restart the machine), and a partial write to one slave must
    /// not re-activate the others.
    pub reset_pending: AtomicU64,
    /// Resets the writers applied since the RT thread last looked (same bits): the RT thread
    /// stops trusting its copy of the output buffer for those frames until it has read a
    /// version written after them.
    pub reset_done: AtomicU64,
}

impl Exchange {
    /// A command for the watchdogs of the frames whose output bytes `begin..end` touches.
    pub fn note_command(&self, begin: usize, end: usize, now_ns: i64) {
        for (k, runs) in self.frame_outputs.iter().enumerate() {
            if runs.iter().any(|&(o, l)| begin < o + l && o < end) {
                self.frame_commands[k].store(now_ns, Ordering::Release);
            }
        }
    }

    /// A command for every frame's watchdog (`feed_watchdog`, `start_cyclic`).
    pub fn note_command_all(&self, now_ns: i64) {
        for c in self.frame_commands.iter() {
            c.store(now_ns, Ordering::Release);
        }
    }

    /// Put the safe image's bytes over the output ranges of the pending resets and of `extra`
    /// (same bits as `reset_pending`), then tell the RT thread. Only under the output writer
    /// lock (the buffer's single writer). The bits are cleared only after the bytes are
    /// written, so no cycle takes the buffer as it was before the reset.
    pub fn apply_resets(&self, extra: u64) {
        let pending = self.reset_pending.load(Ordering::Acquire);
        let mask = pending | extra;
        if mask == 0 {
            return;
        }
        let safe = &self.plan.safe_image;
        if mask & RESET_ALL != 0 {
            for &(o, l) in &self.output_runs {
                self.outputs.write(o, &safe[o..o + l]);
            }
        } else {
            for (k, runs) in self.frame_outputs.iter().enumerate() {
                if mask & (1 << k) != 0 {
                    for &(o, l) in runs {
                        self.outputs.write(o, &safe[o..o + l]);
                    }
                }
            }
        }
        self.reset_done.fetch_or(mask, Ordering::AcqRel);
        self.reset_pending.fetch_and(!pending, Ordering::AcqRel);
    }

    /// Ok when image bytes `begin..end` lie inside one output run, else the refusal naming
    /// `what` and the ranges a write may touch.
    pub fn check_output_span(&self, begin: usize, end: usize, what: &str) -> Result<(), String> {
        if self
            .output_runs
            .iter()
            .any(|&(o, l)| begin >= o && end <= o + l)
        {
            return Ok(());
        }
        Err(format!(
            "{what} is outside the output ranges (offset, length) {:?} of the {}-byte image",
            self.plan.output_ranges, self.plan.image_len
        ))
    }

    pub fn new(plan: Plan, layout: &CycleLayout) -> Exchange {
        Exchange {
            frames: plan.frames.iter().map(|_| FrameStats::default()).collect(),
            frame_commands: plan.frames.iter().map(|_| AtomicI64::new(0)).collect(),
            frame_outputs: layout.frames.iter().map(|f| f.outputs.clone()).collect(),
            output_runs: layout.outputs.clone(),
            outputs: SeqBuffer::new(&plan.initial_image),
            image: SeqBuffer::new(&plan.initial_image),
            ring: SampleRing::new(plan.ring_capacity, plan.image_len),
            axes: AxisExchange::new(&plan.axes, plan.trajectory_capacity),
            run: 0,
            stale_mask: AtomicU32::new(u32::MAX),
            reset_pending: AtomicU64::new(0),
            reset_done: AtomicU64::new(0),
            plan,
        }
    }
}

/// PI controller that moves the master's wake-up so it falls on the reference clock's cycle
/// boundary (master_follows_ref).
struct DcFollower {
    locked: bool,
    integral: f64,
    /// Phase the wake-ups keep against the reference boundary (≤ 0: a little before it, clear
    /// of the kernel tick), chosen when locking.
    target: i64,
}

const DC_KP: f64 = 0.2;
const DC_KI: f64 = 0.02;

impl DcFollower {
    /// Correction (ns, added to the next wake-up) for a phase error `e` (ns, positive = the
    /// master is late with respect to the boundary).
    fn correct(&mut self, e: i64, cycle: i64) -> i64 {
        if !self.locked {
            // First measurement: jump straight onto the target, then track.
            self.locked = true;
            return -(e - self.target);
        }
        let e = e - self.target;
        let max_step = (cycle / 100).max(1_000);
        self.integral =
            (self.integral + e as f64).clamp(-(cycle as f64) * 50.0, cycle as f64 * 50.0);
        let c = -(DC_KP * e as f64 + DC_KI * self.integral);
        (c as i64).clamp(-max_step, max_step)
    }
}

/// Kernel ticks fire at multiples of the tick period in CLOCK_MONOTONIC (1, 4 or 10 ms for
/// HZ = 1000, 250, 100: all multiples of 1 ms). A timer that expires on the same instant waits
/// for the tick's own work, which costs every such cycle microseconds of wake-up latency.
const TICK_GRID_NS: i64 = 1_000_000;
/// Distance kept from tick instants.
const TICK_GUARD_NS: i64 = 20_000;

fn gcd(a: i64, b: i64) -> i64 {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

/// How much earlier than `t` to wake (0..=2 × guard) so that `t - δ + k·cycle` stays at least
/// the guard away from every tick instant, for every k. Waking a little before the DC boundary
/// only gives the frame more time before SYNC0; the DC time written is that of the actual
/// planned wake-up.
fn tick_clearance(t: i64, cycle: i64) -> i64 {
    let g = gcd(cycle, TICK_GRID_NS);
    let guard = TICK_GUARD_NS.min(g / 4);
    let r = t.rem_euclid(g);
    if r < guard {
        r + guard
    } else if r > g - guard {
        r - (g - guard)
    } else {
        0
    }
}

/// A cyclic frame on the wire, filed under its index.
#[derive(Clone, Copy, Debug)]
struct Pending {
    cycle: u64,
    /// Which frame of the plan.
    frame: usize,
    /// When it was handed to the link, CLOCK_MONOTONIC ns.
    tx_ns: i64,
}

/// `v` modulo `cycle`, folded into (-cycle/2, cycle/2].
fn fold_phase(v: u64, cycle: i64) -> i64 {
    let p = (v % cycle as u64) as i64;
    if p > cycle / 2 {
        p - cycle
    } else {
        p
    }
}

pub struct Cyclic {
    pub link: Box<dyn Link>,
    shared: Arc<Shared>,
    ex: Arc<Exchange>,
    layout: CycleLayout,
    /// One transmit buffer per cyclic frame, from the layout's templates.
    tx: Vec<Vec<u8>>,
    rx: Vec<u8>,
    image: Vec<u8>,
    live_out: Vec<u8>,
    scratch: Vec<u8>,
    out_version: u64,
    /// Bit k: `live_out` may hold frame k's output bytes as commanded before a stop (panic,
    /// a watchdog, a reset of the buffer): frame k carries the safe image's bytes until a copy
    /// of the buffer taken after the reset (and with no reset pending) replaces them.
    untrusted: u32,
    /// Every frame's bit.
    all_frames: u32,
    /// The axis stage (CiA 402 drives), run on the image before the frame is filled.
    axes: Axes,
    /// Cyclic frames whose reply is awaited, by index (low 7 bits): in send_at_wake the
    /// frames just sent and those of the previous cycle can all be in flight.
    pending: [Option<Pending>; CYCLIC_INDICES],
    /// The frame last sent under each index: a reply arriving after its frame was declared
    /// lost is counted late against that frame.
    sent_as: [usize; CYCLIC_INDICES],
    /// Frames of each cycle (slot `cycle % 2`) still awaiting their reply.
    outstanding: [usize; 2],
    /// Index of the next cyclic frame sent (low 7 bits).
    next_index: u8,
    /// Per frame, the cycle of the newest reply processed: an older reply arriving later is
    /// only counted.
    last_processed: Vec<Option<u64>>,
    cycle: u64,
    watchdog_tripped: bool,
    /// Per frame: its own watchdog has tripped (bit k).
    frame_watchdog_tripped: u32,
    dc: DcFollower,
    /// (reference clock time, our send time of that frame), from this cycle's reply.
    ref_sample: Option<(u64, i64)>,
    // Results of the current cycle.
    flags: u16,
    rtt_ns: u32,
    send_ns: u64,
    wkc: u16,
    /// Working counter of each frame's reply processed this cycle (bit k of `wkc_seen`): when
    /// two replies of one frame come in one cycle, the newer counts.
    frame_wkc: Vec<u16>,
    wkc_seen: u32,
    dc_diff_ns: i32,
    lost_mask: u32,
    /// Per frame: the cycle whose reply last came back whole (None: none yet).
    good_cycle: Vec<Option<u64>>,
    /// Per frame: its inputs are stale once the last whole reply is more than this many cycles
    /// old (two of the frame's periods: one reply lost in a row is not staleness yet).
    stale_after: Vec<u64>,
}

impl Cyclic {
    pub fn new(
        link: Box<dyn Link>,
        shared: Arc<Shared>,
        ex: Arc<Exchange>,
        layout: CycleLayout,
    ) -> Cyclic {
        let image = ex.plan.initial_image.clone();
        let mut axes = Axes::new(&ex.plan.axes, ex.plan.trajectory_capacity);
        // Each axis belongs to the frame that carries its controlword: that group's own
        // watchdog stops it.
        let frame_of: Vec<usize> = ex
            .plan
            .axes
            .iter()
            .map(|a| {
                let cw = a.map.controlword;
                layout
                    .frames
                    .iter()
                    .position(|f| f.outputs.iter().any(|&(o, l)| cw >= o && cw < o + l))
                    .unwrap_or(0)
            })
            .collect();
        axes.set_frames(&frame_of);
        Cyclic {
            link,
            tx: layout.frames.iter().map(|f| f.template.clone()).collect(),
            last_processed: vec![None; layout.frames.len()],
            frame_wkc: vec![0; layout.frames.len()],
            wkc_seen: 0,
            good_cycle: vec![None; layout.frames.len()],
            stale_after: layout.frames.iter().map(|f| 2 * f.every as u64).collect(),
            rx: vec![0u8; MAX_FRAME_LEN],
            live_out: image.clone(),
            scratch: image.clone(),
            image,
            out_version: u64::MAX,
            untrusted: 0,
            all_frames: ((1u64 << layout.frames.len()) - 1) as u32,
            axes,
            layout,
            shared,
            ex,
            pending: [None; CYCLIC_INDICES],
            sent_as: [0; CYCLIC_INDICES],
            outstanding: [0; 2],
            next_index: 0,
            cycle: 0,
            watchdog_tripped: false,
            frame_watchdog_tripped: 0,
            dc: DcFollower {
                locked: false,
                integral: 0.0,
                target: 0,
            },
            ref_sample: None,
            flags: 0,
            rtt_ns: 0,
            send_ns: 0,
            wkc: 0,
            dc_diff_ns: 0,
            lost_mask: 0,
        }
    }

    /// First wake-up: a little ahead, on a cycle boundary of DC system time.
    fn first_wake(&self) -> i64 {
        let plan = &self.ex.plan;
        let cycle = plan.cycle_ns as i64;
        let start = now_ns() + 2 * cycle;
        let sys = start + plan.dc.time_offset_ns;
        let boundary = start + (cycle - sys.rem_euclid(cycle)) % cycle;
        boundary - tick_clearance(boundary, cycle)
    }

    /// The loop. Returns when `shared.stop` is set.
    pub fn run(&mut self) {
        let plan_cycle = self.ex.plan.cycle_ns as i64;
        let order = self.ex.plan.order;
        let window = plan_cycle * 3 / 4;
        let mut planned = self.first_wake();
        let mut last_wake: Option<i64> = None;
        let mut carry_flags = 0u16;
        while !self.shared.stop.load(Ordering::Acquire) {
            sleep_until(planned);
            let t_wake = now_ns();
            if self.shared.reset_requested.load(Ordering::Acquire) {
                self.shared.stats.reset();
                self.ex.frames.iter().for_each(FrameStats::reset);
                self.shared.reset_requested.store(false, Ordering::Release);
            }
            self.flags = std::mem::take(&mut carry_flags);
            self.rtt_ns = 0;
            self.wkc = 0;
            self.wkc_seen = 0;
            self.dc_diff_ns = 0;
            self.lost_mask = 0;
            self.ref_sample = None;
            let t_sent = match order {
                Order::SendAtWake => {
                    // Nothing in the frame depends on the previous reply, so the frame goes
                    // first and the reply is read after: the earliest, steadiest send instant.
                    let t = self.build_and_send(t_wake, planned);
                    self.send_mailbox();
                    self.receive(0, false);
                    if let Some(prev) = self.cycle.checked_sub(1) {
                        self.check_lost(prev);
                    }
                    t
                }
                Order::SendThenWait => {
                    let t = self.build_and_send(t_wake, planned);
                    self.send_mailbox();
                    self.receive(planned + window, true);
                    self.receive(0, false);
                    self.check_lost(self.cycle);
                    t
                }
            };
            // An acyclic request gets its answer time plus this cycle's receive: with a cycle
            // longer than its timeout, the reply read at the next wake still counts.
            if self.shared.mailbox.expire(t_wake) {
                self.shared
                    .stats
                    .counters
                    .acyclic_timeouts
                    .fetch_add(1, Ordering::Relaxed);
            }
            // DC: the reply tells where the reference clock stands.
            let mut next = planned + plan_cycle;
            self.dc_update(&mut next, plan_cycle);
            self.ex.image.write(0, &self.image);
            let latency = t_wake - planned;
            let period = last_wake.map_or(0, |w| t_wake - w);
            last_wake = Some(t_wake);
            let record = SampleRecord {
                cycle: self.cycle,
                t_wake_ns: t_wake as u64,
                wake_latency_ns: latency,
                exec_ns: (t_sent - t_wake).clamp(0, u32::MAX as i64) as u32,
                period_ns: period.clamp(0, u32::MAX as i64) as u32,
                rtt_ns: self.rtt_ns,
                wkc: self.wkc,
                flags: self.flags,
                dc_diff_ns: self.dc_diff_ns,
                lost_mask: self.lost_mask,
                stale_mask: self.stale_mask(),
            };
            self.ex
                .stale_mask
                .store(record.stale_mask, Ordering::Release);
            self.account(&record);
            if !self.ex.ring.push(&record, &self.image) {
                self.shared
                    .stats
                    .counters
                    .samples_dropped
                    .fetch_add(1, Ordering::Relaxed);
            }
            self.cycle += 1;
            // Woke so late that the next wake-up is already past: skip whole cycles rather than
            // sending a burst of frames to catch up.
            let now = now_ns();
            if next <= now {
                let missed = (now - next) / plan_cycle + 1;
                next += missed * plan_cycle;
                self.shared
                    .stats
                    .counters
                    .overruns
                    .fetch_add(missed as u64, Ordering::Relaxed);
                carry_flags |= flags::OVERRUN;
            }
            planned = next;
        }
        self.shared.alive.store(false, Ordering::Release);
    }

    /// Bit k: frame k's inputs in the image are stale this cycle.
    fn stale_mask(&self) -> u32 {
        let mut mask = 0u32;
        for (k, (good, after)) in self.good_cycle.iter().zip(&self.stale_after).enumerate() {
            if good.is_none_or(|g| self.cycle.saturating_sub(g) > *after) {
                mask |= 1 << k;
            }
        }
        mask
    }

    fn account(&self, r: &SampleRecord) {
        let s = &self.shared.stats;
        s.counters.cycles.fetch_add(1, Ordering::Relaxed);
        if r.flags & flags::WKC_ERROR != 0 {
            s.counters.wkc_errors.fetch_add(1, Ordering::Relaxed);
        }
        s.wake_latency.record(r.wake_latency_ns.max(0) as u64);
        s.exec.record(r.exec_ns as u64);
        if r.period_ns > 0 {
            s.period.record(r.period_ns as u64);
        }
        if r.rtt_ns > 0 {
            s.rtt.record(r.rtt_ns as u64);
        }
        s.send.record(self.send_ns);
    }

    /// The frames of cycle `cycle` had their chance: those without a reply are lost.
    fn check_lost(&mut self, cycle: u64) {
        let slot = (cycle % 2) as usize;
        if self.outstanding[slot] == 0 {
            return;
        }
        self.outstanding[slot] = 0;
        for entry in self.pending.iter_mut() {
            let Some(p) = *entry else { continue };
            if p.cycle != cycle {
                continue;
            }
            *entry = None;
            self.flags |= flags::LOST;
            self.lost_mask |= 1 << p.frame;
            self.ex.frames[p.frame].lost.fetch_add(1, Ordering::Relaxed);
            self.shared
                .stats
                .counters
                .lost_frames
                .fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Read frames until every cyclic reply of this cycle is in (when `until_cyclic`) or
    /// nothing more arrives before `deadline_ns`.
    fn receive(&mut self, deadline_ns: i64, until_cyclic: bool) {
        let limit = self.tx.len() * 2 + MAX_EXTRA_FRAMES_PER_CYCLE;
        for _ in 0..limit {
            if until_cyclic && self.outstanding[(self.cycle % 2) as usize] == 0 {
                return;
            }
            let got = self.link.recv(&mut self.rx, deadline_ns);
            match got {
                Ok(Some(r)) => self.handle(r),
                Ok(None) | Err(_) => return,
            }
        }
    }

    /// Does `rx` have the datagram structure of cyclic frame `frame`?
    fn is_reply_to(&self, frame: usize, rx: &[u8]) -> bool {
        let f = &self.layout.frames[frame];
        reply_matches(&f.template[..f.len], rx, true)
    }

    fn handle(&mut self, r: Received) {
        let rx = &self.rx[..r.len];
        let index = frame_index(rx);
        let counters = &self.shared.stats.counters;
        match index {
            Some(i) if i & CYCLIC_INDEX_BIT != 0 => {
                let key = (i & !CYCLIC_INDEX_BIT) as usize;
                match self.pending[key] {
                    Some(p) if self.is_reply_to(p.frame, rx) => {
                        self.pending[key] = None;
                        let slot = (p.cycle % 2) as usize;
                        self.outstanding[slot] = self.outstanding[slot].saturating_sub(1);
                        if self.last_processed[p.frame].is_none_or(|c| p.cycle > c) {
                            self.last_processed[p.frame] = Some(p.cycle);
                            self.process_reply(r, p);
                        }
                    }
                    None if self.is_reply_to(self.sent_as[key], rx) => {
                        self.flags |= flags::LATE;
                        counters.late_frames.fetch_add(1, Ordering::Relaxed);
                        self.ex.frames[self.sent_as[key]]
                            .late
                            .fetch_add(1, Ordering::Relaxed);
                    }
                    _ => {
                        self.flags |= flags::UNMATCHED;
                        counters.unmatched_frames.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
            Some(_)
                if self
                    .shared
                    .mailbox
                    .sent_request()
                    .is_some_and(|req| reply_matches(req, rx, false)) =>
            {
                self.shared.mailbox.deliver(rx);
            }
            _ => {
                self.flags |= flags::UNMATCHED;
                counters.unmatched_frames.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// The reply to cyclic frame `p.frame`: inputs into the image, working counter of every
    /// logical datagram, DC time.
    fn process_reply(&mut self, r: Received, p: Pending) {
        let rx = &self.rx[..r.len];
        let layout = &self.layout.frames[p.frame];
        let stats = &self.ex.frames[p.frame];
        let rtt = (r.rx_ns - p.tx_ns).clamp(0, u32::MAX as i64) as u32;
        // The cycle's round trip is that of its slowest frame.
        self.rtt_ns = self.rtt_ns.max(rtt);
        stats.rtt.record(rtt as u64);
        let mut total = 0u16;
        let mut bad = false;
        for (slot, expected) in &layout.wkc {
            let w = wire::read_wkc(rx, slot);
            total = total.wrapping_add(w);
            bad |= w != *expected;
        }
        self.frame_wkc[p.frame] = total;
        self.wkc_seen |= 1 << p.frame;
        self.wkc = (0..self.frame_wkc.len())
            .filter(|k| self.wkc_seen & (1 << k) != 0)
            .fold(0u16, |sum, k| sum.wrapping_add(self.frame_wkc[k]));
        stats.last_wkc.store(total as u64, Ordering::Relaxed);
        if bad {
            self.flags |= flags::WKC_ERROR;
            stats.wkc_errors.fetch_add(1, Ordering::Relaxed);
        } else {
            self.good_cycle[p.frame] = Some(p.cycle);
            stats
                .last_good_ns
                .store(r.rx_ns.max(0) as u64, Ordering::Release);
            stats.last_good_cycle.store(p.cycle + 1, Ordering::Release);
        }
        for &(f, i, len) in &layout.inputs {
            self.image[i..i + len].copy_from_slice(&rx[f..f + len]);
        }
        if let Some(slot) = layout.dc_sync {
            if wire::read_wkc(rx, &slot) > 0 {
                let t = u64::from_le_bytes(rx[slot.data..slot.data + 8].try_into().unwrap());
                self.ref_sample = Some((t, p.tx_ns));
            }
        }
    }

    /// Fill the cyclic frame (outputs or the safe image, DC time, fresh index) and send it.
    /// Returns the time the frame was handed to the link.
    /// `t_planned`: the cycle's planned wake-up, the time the axis stage computes its targets
    /// for (on the cycle grid, whatever the wake-up's latency).
    fn build_and_send(&mut self, t_wake: i64, t_planned: i64) -> i64 {
        let plan = &self.ex.plan;
        let panic = self.shared.panic.load(Ordering::Acquire);
        let stale = plan.watchdog_ns > 0
            && t_wake - self.shared.last_command_ns.load(Ordering::Acquire)
                > plan.watchdog_ns as i64;
        if stale && !self.watchdog_tripped {
            self.shared
                .stats
                .counters
                .watchdog_trips
                .fetch_add(1, Ordering::Relaxed);
            // The commands from before the trip are void: the next writer resets the buffer
            // to the safe image before its own write (an atomic flag: no lock, no syscall).
            self.ex.reset_pending.fetch_or(RESET_ALL, Ordering::AcqRel);
        }
        self.watchdog_tripped = stale;
        if panic {
            self.flags |= flags::PANIC;
        }
        if stale {
            self.flags |= flags::WATCHDOG;
        }
        // Resets owed or done since the last cycle: `live_out` is not to be trusted for those
        // frames until it is refreshed. Pending first, then done: a writer marks a reset done
        // before it clears the pending bit, so one of the two is seen.
        let frames_of = |bits: u64, all: u32| {
            if bits & RESET_ALL != 0 {
                all
            } else {
                bits as u32 & all
            }
        };
        let pending = frames_of(
            self.ex.reset_pending.load(Ordering::Acquire),
            self.all_frames,
        );
        let done = frames_of(
            self.ex.reset_done.swap(0, Ordering::AcqRel),
            self.all_frames,
        );
        self.untrusted |= pending | done;
        if panic || stale {
            // The buffer is not read while stopped: what `live_out` holds is from before.
            self.untrusted = self.all_frames;
        } else {
            let v = self.ex.outputs.version();
            if v != self.out_version {
                // A write in progress leaves the previous complete version in place.
                for _ in 0..OUTPUT_READ_ATTEMPTS {
                    if let Some(v) = self.ex.outputs.try_read(&mut self.scratch) {
                        std::mem::swap(&mut self.live_out, &mut self.scratch);
                        self.out_version = v;
                        // Read after every reset whose bit was seen above: only the resets
                        // still owed keep their frames on the safe image.
                        self.untrusted = pending;
                        break;
                    }
                }
            } else {
                // Unchanged since the copy was taken: every reset seen above (a write) came
                // before that copy.
                self.untrusted = pending;
            }
        }
        let source = if panic || stale {
            &plan.safe_image
        } else {
            &self.live_out
        };
        for &(o, l) in &self.layout.outputs {
            self.image[o..o + l].copy_from_slice(&source[o..o + l]);
        }
        if !(panic || stale) && self.untrusted != 0 {
            for (k, layout) in self.layout.frames.iter().enumerate() {
                if self.untrusted & (1 << k) != 0 {
                    for &(o, l) in &layout.outputs {
                        self.image[o..o + l].copy_from_slice(&plan.safe_image[o..o + l]);
                    }
                }
            }
        }
        // The groups' own watchdogs, decided before the axis stage so that the axes of a
        // stale group get their stop: its output bytes from the safe image (in the image too,
        // so the samples show what went out), the axes' objects from the axis stage.
        for (k, layout) in self.layout.frames.iter().enumerate() {
            if !self.cycle.is_multiple_of(layout.every as u64) {
                continue;
            }
            let wd = layout.watchdog_ns as i64;
            let group_stale =
                wd > 0 && t_wake - self.ex.frame_commands[k].load(Ordering::Acquire) > wd;
            let bit = 1u32 << k;
            if group_stale {
                if self.frame_watchdog_tripped & bit == 0 {
                    self.ex.frames[k]
                        .watchdog_trips
                        .fetch_add(1, Ordering::Relaxed);
                    // This group's commands from before the trip are void (see above).
                    self.ex.reset_pending.fetch_or(bit as u64, Ordering::AcqRel);
                }
                self.flags |= flags::WATCHDOG;
                for &(o, l) in &layout.outputs {
                    self.image[o..o + l].copy_from_slice(&plan.safe_image[o..o + l]);
                }
            }
            self.frame_watchdog_tripped =
                (self.frame_watchdog_tripped & !bit) | if group_stale { bit } else { 0 };
        }
        // The axes own their controlwords and targets: on panic or watchdog they put the
        // configured stop there instead of the safe image's bytes, in this same frame (a
        // group's watchdog holds between the cycles its frame goes out).
        let moving = self.axes.step(
            &mut self.image,
            t_planned,
            plan.cycle_ns as i64,
            panic || stale,
            self.frame_watchdog_tripped,
            &self.ex.axes,
        );
        if moving != 0 && !panic {
            // A trajectory in progress is a command being carried out: it feeds the
            // watchdogs of the bus and of the frames its axes are in, so a commander that
            // waits for it (or went quiet after sending it) does not stop it half-way.
            self.shared.last_command_ns.store(t_wake, Ordering::Release);
            for (k, c) in self.ex.frame_commands.iter().enumerate() {
                if moving & (1 << k) != 0 {
                    c.store(t_wake, Ordering::Release);
                }
            }
        }
        // The frames due this cycle go out back to back; the round trip of each starts as it
        // is handed to the link (a synchronous in-process link answers before `send` returns),
        // execution time ends when the last `send` returned.
        let mut t_sent = now_ns();
        let mut send_ns = 0;
        for k in 0..self.tx.len() {
            let layout = &self.layout.frames[k];
            if !self.cycle.is_multiple_of(layout.every as u64) {
                continue;
            }
            let frame = &mut self.tx[k];
            for &(f, i, l) in &layout.writes {
                frame[f..f + l].copy_from_slice(&self.image[i..i + l]);
            }
            let key = self.next_index as usize;
            self.next_index = (self.next_index + 1) % CYCLIC_INDICES as u8;
            let index = CYCLIC_INDEX_BIT | key as u8;
            for slot in &layout.slots {
                frame[slot.header + 1] = index;
                frame[slot.wkc..slot.wkc + 2].fill(0);
            }
            if let Some(slot) = layout.dc_sync {
                frame[slot.data..slot.data + 8].fill(0);
            }
            let t_handed = now_ns();
            if let Some(d) = layout.dc_write {
                // The master's system time as the frame leaves, not at the planned wake-up:
                // the reference clock's drift loop then sees the transit time only, without
                // this cycle's wake-up and build jitter.
                let t = (t_handed + plan.dc.time_offset_ns) as u64;
                frame[d..d + 8].copy_from_slice(&t.to_le_bytes());
            }
            let sent = self.link.send(&frame[..layout.len]);
            t_sent = now_ns();
            send_ns += (t_sent - t_handed).max(0) as u64;
            // An index still filed belongs to a frame two cycles old that check_lost already
            // handled; overwriting it is what a reply-less slot means.
            self.pending[key] = None;
            match sent {
                Ok(()) => {
                    self.pending[key] = Some(Pending {
                        cycle: self.cycle,
                        frame: k,
                        tx_ns: t_handed,
                    });
                    self.sent_as[key] = k;
                    self.outstanding[(self.cycle % 2) as usize] += 1;
                    self.ex.frames[k].sent.fetch_add(1, Ordering::Relaxed);
                }
                Err(_) => {
                    self.flags |= flags::SEND_ERROR;
                    self.shared
                        .stats
                        .counters
                        .send_errors
                        .fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        self.send_ns = send_ns;
        t_sent
    }

    /// Send a pending acyclic request in its own frame, right after the cyclic one.
    fn send_mailbox(&mut self) {
        let mailbox = &self.shared.mailbox;
        if let Some(req) = mailbox.take() {
            // A failed send is not retried here: the request times out and `transact` retries.
            let _ = self.link.send(req);
            mailbox.mark_sent(now_ns());
            self.flags |= flags::ACYCLIC;
            self.shared
                .stats
                .counters
                .acyclic_frames
                .fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Distributed clocks after this cycle's reply: record the difference and, when the master
    /// follows the reference clock, move the next wake-up `next` onto its cycle boundary.
    fn dc_update(&mut self, next: &mut i64, cycle: i64) {
        let dc = self.ex.plan.dc;
        let Some((ref_time, tx_ns)) = self.ref_sample else {
            return;
        };
        // Offset of the reference clock against CLOCK_MONOTONIC, measured at our send instant
        // (the frame passes the reference a few µs later: a constant the boundary absorbs).
        let offset = ref_time.wrapping_sub(tx_ns as u64);
        match dc.mode {
            DcMode::Off => {}
            DcMode::RefFollowsMaster => {
                let master_sys = (tx_ns + dc.time_offset_ns) as u64;
                let diff = ref_time.wrapping_sub(master_sys) as i64;
                self.dc_diff_ns = diff.clamp(i32::MIN as i64, i32::MAX as i64) as i32;
            }
            DcMode::MasterFollowsRef => {
                let phase = fold_phase((*next as u64).wrapping_add(offset), cycle);
                if !self.dc.locked {
                    // Where the boundary falls in CLOCK_MONOTONIC decides the tick clearance.
                    self.dc.target = -tick_clearance(*next - phase, cycle);
                }
                self.dc_diff_ns = (phase - self.dc.target) as i32;
                let c = self.dc.correct(phase, cycle);
                if c != 0 {
                    *next += c;
                    self.flags |= flags::DC_ADJUSTED;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wake_ups_keep_clear_of_kernel_ticks() {
        for cycle in [400_000i64, 1_000_000, 250_000, 2_000_000, 125_000] {
            for t in (0..3_000_000i64).step_by(7_919) {
                let d = tick_clearance(t, cycle);
                assert!((0..=2 * TICK_GUARD_NS).contains(&d));
                for k in 0..20 {
                    let r = (t - d + k * cycle).rem_euclid(TICK_GRID_NS);
                    let distance = r.min(TICK_GRID_NS - r);
                    assert!(distance >= TICK_GUARD_NS.min(gcd(cycle, TICK_GRID_NS) / 4));
                }
            }
        }
        // Already clear: no change.
        assert_eq!(tick_clearance(100_000, 400_000), 0);
        // 200 µs + k·400 µs reaches 1 ms: moved.
        assert_eq!(tick_clearance(200_000, 400_000), TICK_GUARD_NS);
    }

    #[test]
    fn phase_folds_around_the_boundary() {
        assert_eq!(fold_phase(1_000_100, 1_000), 100);
        assert_eq!(fold_phase(1_000_900, 1_000), -100);
        assert_eq!(fold_phase(1_000_500, 1_000), 500);
    }

    #[test]
    fn follower_jumps_once_then_steps_within_bounds() {
        let mut f = DcFollower {
            locked: false,
            integral: 0.0,
            target: 0,
        };
        assert_eq!(f.correct(300_000, 1_000_000), -300_000);
        let c = f.correct(300_000, 1_000_000);
        assert_eq!(c, -10_000);
        let c = f.correct(100, 1_000_000);
        assert!(c < 0 && c > -10_000);
    }
}
