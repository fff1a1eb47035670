//! The cyclic plan: which frames the RT thread sends, what each carries and how the loop runs.
//! The Python binding fills it from the plan dict (python/ether_ros/master/plan.py, the one place
//! that decides which datagram goes in which frame); `validate` names the key that is wrong and
//! `layout` lays every frame out once.

use crate::cia402::{AxisPlan, MAX_TRAJECTORY_CAPACITY};
use ether_ros_protocol::{
    self as wire, reg, Command, DatagramSlot, FrameBuilder, MASTER_MAC, MAX_FRAME_LEN,
};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// How the cycle orders its work: when outputs are taken and the frame goes out.
pub enum Order {
    /// Receive the previous reply, then send at once at wake-up: constant send instant, one
    /// cycle of latency (IgH's order).
    SendAtWake,
    /// Send at wake-up, wait for the reply inside the cycle (SOEM's order).
    SendThenWait,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// One datagram of a cyclic frame.
pub enum CyclicDatagram {
    /// FPWR 0x0910: the master's system time to the reference clock.
    DcWriteRef {
        /// Station address of the DC reference clock.
        station: u16,
    },
    /// FRMW 0x0910: the reference clock's time to every other DC slave.
    DcSync {
        /// Station address of the DC reference clock.
        station: u16,
    },
    /// LRW, LRD or LWR of `length` image bytes at `image_offset`.
    Logical {
        /// LRW, LRD or LWR.
        command: Logical,
        /// Logical start address.
        address: u32,
        /// Bytes of the datagram.
        length: usize,
        /// Where the bytes are in the process image.
        image_offset: usize,
        /// Working counter a good reply has.
        expected_wkc: u16,
    },
}

/// The logical commands of the process image. LRW reads and writes in one pass (working
/// counter +1 per slave read, +2 per slave written); devices that refuse LRW (ESC register
/// 0x0008 bit 9) get an LRD for their inputs and an LWR for their outputs (+1 each).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Logical {
    /// Logical read write (outputs and inputs in one datagram).
    Lrw,
    /// Logical read (inputs only).
    Lrd,
    /// Logical write (outputs only).
    Lwr,
}

impl Logical {
    /// The datagram command code of this logical command.
    pub fn command(self) -> Command {
        match self {
            Logical::Lrw => Command::Lrw,
            Logical::Lrd => Command::Lrd,
            Logical::Lwr => Command::Lwr,
        }
    }

    /// Does the frame carry image bytes to the slaves?
    pub fn writes(self) -> bool {
        self != Logical::Lrd
    }

    /// Does the reply carry image bytes back?
    pub fn reads(self) -> bool {
        self != Logical::Lwr
    }
}

/// One cyclic frame: its datagrams and how often it goes out.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FramePlan {
    /// The frame's datagrams, in order.
    pub datagrams: Vec<CyclicDatagram>,
    /// Sent in the cycles `cycle % every == 0` (a group running at 1/every of the base rate).
    pub every: u32,
    /// The group's own command watchdog (0: none): when no write touched this frame's output
    /// bytes (and no `feed_watchdog`) for this long, the frame carries the safe image's bytes.
    pub watchdog_ns: u64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// Which clock follows which in the distributed clock.
pub enum DcMode {
    /// No distributed clock.
    Off,
    /// The reference clock is steered to the master's clock.
    RefFollowsMaster,
    /// The master's cycle is steered to the reference clock.
    MasterFollowsRef,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// The distributed clock part of the plan.
pub struct DcPlan {
    /// Which clock follows which.
    pub mode: DcMode,
    /// DC system time = CLOCK_MONOTONIC + time_offset_ns.
    pub time_offset_ns: i64,
    /// Shift of SYNC0 against the cycle start (ns).
    pub sync0_shift_ns: i64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// The scheduling policy of the RT thread.
pub enum Policy {
    /// SCHED_FIFO at `priority`.
    Fifo,
    /// SCHED_DEADLINE with `runtime_ns` per cycle.
    Deadline,
    /// SCHED_OTHER (no real-time guarantee; tests and development).
    Other,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// How the RT thread is set up.
pub struct RtPlan {
    /// Scheduling policy.
    pub policy: Policy,
    /// SCHED_FIFO priority (0: none).
    pub priority: i32,
    /// CPU to pin the thread to (None: any).
    pub cpu: Option<usize>,
    /// SCHED_DEADLINE runtime per cycle (ns).
    pub runtime_ns: u64,
    /// Lock the process's memory (mlockall) so the cycle never faults a page in.
    pub lock_memory: bool,
}

#[derive(Clone, Debug, PartialEq)]
/// Everything a cyclic run needs, fixed when it starts: the cycle, the frames, the image and
/// its initial and safe contents, the DC and RT setup, the axes. Built from Python's typed
/// contracts and checked by `validate`.
pub struct Plan {
    /// Cycle time (ns).
    pub cycle_ns: u64,
    /// How the cycle orders its work.
    pub order: Order,
    /// The cyclic frames, all sent back to back at the cycle's wake-up (those due).
    pub frames: Vec<FramePlan>,
    /// Bytes of the process image.
    pub image_len: usize,
    /// (offset, length) of the output bytes in the image.
    pub output_ranges: Vec<(usize, usize)>,
    /// The image the first cycle sends.
    pub initial_image: Vec<u8>,
    /// The outputs a stop (panic, watchdog) sends.
    pub safe_image: Vec<u8>,
    /// The distributed clock setup.
    pub dc: DcPlan,
    /// The RT thread setup.
    pub rt: RtPlan,
    /// 0 = off.
    pub watchdog_ns: u64,
    /// Samples the ring to Python holds.
    pub ring_capacity: usize,
    /// CiA 402 axes driven by the axis stage of the cycle (docs/cia402.md).
    pub axes: Vec<AxisPlan>,
    /// Points per axis trajectory (preallocated).
    pub trajectory_capacity: usize,
}

/// Shortest cycle accepted: below this the loop's own work would not fit.
pub const MIN_CYCLE_NS: u64 = 20_000;
/// Longest cycle accepted (1 s): longer ones are a unit mistake.
pub const MAX_CYCLE_NS: u64 = 1_000_000_000;
/// Largest sample ring accepted.
pub const MAX_RING: usize = 1 << 20;
/// Most cyclic frames per plan: two cycles of frames in flight need distinct indices among the
/// 128 cyclic ones, and a sample's `lost_mask` has a bit per frame.
pub const MAX_FRAMES: usize = 32;
/// Slowest frame: once every this many base cycles.
pub const MAX_EVERY: u32 = 10_000;

/// Where one frame's datagrams sit, and which frame bytes map to which image bytes.
#[derive(Clone, Debug, Default)]
pub struct FrameLayout {
    /// The frame with everything fixed filled in (headers); data is refreshed every cycle.
    pub template: Vec<u8>,
    /// Bytes of the frame.
    pub len: usize,
    /// Sent every this many cycles.
    pub every: u32,
    /// The frame's own watchdog (ns; 0: none).
    pub watchdog_ns: u64,
    /// Where each datagram sits in the frame.
    pub slots: Vec<DatagramSlot>,
    /// (frame offset, image offset, length) of every LRW/LWR datagram: image to frame.
    pub writes: Vec<(usize, usize, usize)>,
    /// Slot and expected working counter of every logical datagram.
    pub wkc: Vec<(DatagramSlot, u16)>,
    /// (frame offset, image offset, length) of input bytes: copied from the reply to the image.
    pub inputs: Vec<(usize, usize, usize)>,
    /// (image offset, length) of the output bytes this frame carries.
    pub outputs: Vec<(usize, usize)>,
    /// Frame offset of the 8 data bytes of the FPWR 0x0910 datagram.
    pub dc_write: Option<usize>,
    /// Slot of the FRMW 0x0910 datagram.
    pub dc_sync: Option<DatagramSlot>,
}

/// The layout of the whole cycle: every frame, and the image's output ranges.
#[derive(Clone, Debug, Default)]
pub struct CycleLayout {
    /// Every frame's layout, in plan order.
    pub frames: Vec<FrameLayout>,
    /// Image output ranges (image offset, length), merged into runs.
    pub outputs: Vec<(usize, usize)>,
}

impl Plan {
    /// Check the plan; the error names the offending key.
    pub fn validate(&self) -> Result<(), String> {
        if !(MIN_CYCLE_NS..=MAX_CYCLE_NS).contains(&self.cycle_ns) {
            return Err(format!(
                "cycle_ns = {} is outside {MIN_CYCLE_NS}..={MAX_CYCLE_NS}",
                self.cycle_ns
            ));
        }
        if self.frames.is_empty() || self.frames.len() > MAX_FRAMES {
            return Err(format!(
                "frames holds {} frames: the plan needs 1..={MAX_FRAMES}",
                self.frames.len()
            ));
        }
        for (k, f) in self.frames.iter().enumerate() {
            if f.datagrams.is_empty() {
                return Err(format!("frames[{k}] has no datagram"));
            }
            if !(1..=MAX_EVERY).contains(&f.every) {
                return Err(format!(
                    "frames[{k}].every = {} must be 1..={MAX_EVERY}",
                    f.every
                ));
            }
        }
        for (name, img) in [
            ("initial_image", &self.initial_image),
            ("safe_image", &self.safe_image),
        ] {
            if img.len() != self.image_len {
                return Err(format!(
                    "{name} is {} bytes long but image_len is {}",
                    img.len(),
                    self.image_len
                ));
            }
        }
        for (i, &(off, len)) in self.output_ranges.iter().enumerate() {
            if !matches!(off.checked_add(len), Some(end) if end <= self.image_len) {
                return Err(format!(
                    "output_ranges[{i}] = ({off}, {len}) runs past image_len {}",
                    self.image_len
                ));
            }
        }
        let mut covered = vec![false; self.image_len];
        let mut sync = false;
        for (k, f) in self.frames.iter().enumerate() {
            for (i, d) in f.datagrams.iter().enumerate() {
                let at = format!("frames[{k}].datagrams[{i}]");
                match *d {
                    CyclicDatagram::Logical {
                        length,
                        image_offset,
                        ..
                    } => {
                        if length == 0 || length > wire::MAX_DATAGRAM_DATA {
                            return Err(format!(
                                "{at}.length = {length} must be 1..={}",
                                wire::MAX_DATAGRAM_DATA
                            ));
                        }
                        if image_offset + length > self.image_len {
                            return Err(format!(
                                "{at}: image_offset {image_offset} + length {length} runs past \
                                 image_len {}",
                                self.image_len
                            ));
                        }
                        for c in &mut covered[image_offset..image_offset + length] {
                            if *c {
                                return Err(format!(
                                    "{at} overlaps another logical datagram in the image"
                                ));
                            }
                            *c = true;
                        }
                    }
                    CyclicDatagram::DcWriteRef { .. } | CyclicDatagram::DcSync { .. } => {
                        // The DC datagrams go out every cycle, ahead of the process data.
                        if k != 0 || f.every != 1 {
                            return Err(format!(
                                "{at} is a DC datagram: those belong in frames[0], sent every \
                                 cycle"
                            ));
                        }
                        if matches!(d, CyclicDatagram::DcSync { .. }) {
                            sync = true;
                        } else if self.dc.mode != DcMode::RefFollowsMaster {
                            return Err(format!(
                                "{at} is dc_write_ref but dc.mode is not ref_follows_master"
                            ));
                        }
                    }
                }
            }
        }
        if self.dc.mode == DcMode::MasterFollowsRef && !sync {
            return Err(
                "dc.mode = master_follows_ref needs a dc_sync datagram to read the \
                        reference clock"
                    .into(),
            );
        }
        if self.ring_capacity == 0 || self.ring_capacity > MAX_RING {
            return Err(format!(
                "ring_capacity = {} must be 1..={MAX_RING}",
                self.ring_capacity
            ));
        }
        if self.rt.policy == Policy::Fifo && !(1..=99).contains(&self.rt.priority) {
            return Err(format!(
                "rt.priority = {} must be 1..=99 for fifo",
                self.rt.priority
            ));
        }
        if self.rt.policy == Policy::Deadline
            && !(1024..=self.cycle_ns).contains(&self.rt.runtime_ns)
        {
            return Err(format!(
                "rt.runtime_ns = {} must be 1024..=cycle_ns ({}) for deadline",
                self.rt.runtime_ns, self.cycle_ns
            ));
        }
        let layout = self.layout()?;
        self.validate_axes(&layout)
    }

    fn validate_axes(&self, layout: &CycleLayout) -> Result<(), String> {
        if self.axes.is_empty() {
            return Ok(());
        }
        if !(1..=MAX_TRAJECTORY_CAPACITY).contains(&self.trajectory_capacity) {
            return Err(format!(
                "trajectory_capacity = {} must be 1..={MAX_TRAJECTORY_CAPACITY}",
                self.trajectory_capacity
            ));
        }
        let mut owned = vec![false; self.image_len];
        for (i, a) in self.axes.iter().enumerate() {
            if self.axes[..i].iter().any(|b| b.name == a.name) {
                return Err(format!("axes[{i}]: the name {} is used twice", a.name));
            }
            a.validate(self.image_len, &layout.outputs)
                .map_err(|e| format!("axes[{i}]: {e}"))?;
            for (name, out, off, size) in a.map.objects() {
                if !out {
                    continue;
                }
                for o in &mut owned[off..off + size] {
                    if *o {
                        return Err(format!(
                            "axes[{i}]: {name} at byte {off} overlaps another axis's output"
                        ));
                    }
                    *o = true;
                }
            }
        }
        Ok(())
    }

    /// Lay every cyclic frame out once; the RT thread only refreshes data and indices.
    pub fn layout(&self) -> Result<CycleLayout, String> {
        let mut is_output = vec![false; self.image_len];
        for &(off, len) in &self.output_ranges {
            is_output[off..off + len].iter_mut().for_each(|o| *o = true);
        }
        let frames = self
            .frames
            .iter()
            .enumerate()
            .map(|(k, f)| lay_out_frame(k, f, &is_output))
            .collect::<Result<_, _>>()?;
        Ok(CycleLayout {
            frames,
            outputs: merge_ranges(&is_output, true),
        })
    }

    /// Is `[offset, offset+len)` inside one output range?
    pub fn output_range_containing(&self, offset: usize, len: usize) -> Option<(usize, usize)> {
        self.output_ranges
            .iter()
            .copied()
            .find(|&(o, l)| offset >= o && offset + len <= o + l)
    }
}

/// Frame `k` laid out: headers in a template, and the frame ↔ image byte maps.
fn lay_out_frame(k: usize, f: &FramePlan, is_output: &[bool]) -> Result<FrameLayout, String> {
    let mut buf = vec![0u8; MAX_FRAME_LEN];
    let mut slots = Vec::new();
    {
        let mut b = FrameBuilder::new(&mut buf, MASTER_MAC).map_err(|e| e.to_string())?;
        for (i, d) in f.datagrams.iter().enumerate() {
            let (cmd, address, len) = match *d {
                CyclicDatagram::DcWriteRef { station } => (
                    Command::Fpwr,
                    wire::fixed_address(station, reg::DC_SYSTEM_TIME),
                    8,
                ),
                CyclicDatagram::DcSync { station } => (
                    Command::Frmw,
                    wire::fixed_address(station, reg::DC_SYSTEM_TIME),
                    8,
                ),
                CyclicDatagram::Logical {
                    command,
                    address,
                    length,
                    ..
                } => (command.command(), address, length),
            };
            let slot = b.push(cmd, 0x80, address, None, len).map_err(|e| {
                format!("frames[{k}].datagrams[{i}] does not fit in one Ethernet frame: {e}")
            })?;
            slots.push(slot);
        }
        let len = b.finish();
        buf.truncate(len.max(wire::MIN_FRAME_LEN));
    }
    let mut layout = FrameLayout {
        len: buf.len(),
        every: f.every,
        watchdog_ns: f.watchdog_ns,
        ..Default::default()
    };
    for (d, slot) in f.datagrams.iter().zip(&slots) {
        match *d {
            CyclicDatagram::DcWriteRef { .. } => layout.dc_write = Some(slot.data),
            CyclicDatagram::DcSync { .. } => layout.dc_sync = Some(*slot),
            CyclicDatagram::Logical {
                command,
                length,
                image_offset,
                expected_wkc,
                ..
            } => {
                layout.wkc.push((*slot, expected_wkc));
                if command.writes() {
                    layout.writes.push((slot.data, image_offset, length));
                    for (off, len) in
                        merge_ranges(&is_output[image_offset..image_offset + length], true)
                    {
                        layout.outputs.push((image_offset + off, len));
                    }
                }
                if command.reads() {
                    for (off, len) in
                        merge_ranges(&is_output[image_offset..image_offset + length], false)
                    {
                        layout
                            .inputs
                            .push((slot.data + off, image_offset + off, len));
                    }
                }
            }
        }
    }
    layout.slots = slots;
    layout.template = buf;
    Ok(layout)
}

/// Runs of `flags[i] == want` as (offset, length).
fn merge_ranges(flags: &[bool], want: bool) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = None;
    for (i, &f) in flags.iter().chain([&!want]).enumerate() {
        match (f == want, start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                out.push((s, i - s));
                start = None;
            }
            _ => {}
        }
    }
    out
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub fn logical(
        command: Logical,
        image_offset: usize,
        length: usize,
        wkc: u16,
    ) -> CyclicDatagram {
        CyclicDatagram::Logical {
            command,
            address: 0x10000 + image_offset as u32,
            length,
            image_offset,
            expected_wkc: wkc,
        }
    }

    fn frame(datagrams: Vec<CyclicDatagram>) -> FramePlan {
        FramePlan {
            datagrams,
            every: 1,
            watchdog_ns: 0,
        }
    }

    /// Two slaves, 4 output + 2 input bytes each, DC reference at station 0x1001.
    pub fn sample_plan() -> Plan {
        Plan {
            cycle_ns: 1_000_000,
            order: Order::SendAtWake,
            frames: vec![frame(vec![
                CyclicDatagram::DcWriteRef { station: 0x1001 },
                CyclicDatagram::DcSync { station: 0x1001 },
                logical(Logical::Lrw, 0, 12, 6),
            ])],
            image_len: 12,
            output_ranges: vec![(0, 4), (6, 4)],
            initial_image: vec![0; 12],
            safe_image: vec![0xEE; 12],
            dc: DcPlan {
                mode: DcMode::RefFollowsMaster,
                time_offset_ns: 0,
                sync0_shift_ns: 0,
            },
            rt: RtPlan {
                policy: Policy::Other,
                priority: 0,
                cpu: None,
                runtime_ns: 0,
                lock_memory: false,
            },
            watchdog_ns: 0,
            ring_capacity: 64,
            axes: Vec::new(),
            trajectory_capacity: 16,
        }
    }

    /// `n` slaves of 600 output + 600 input bytes, one LRW per slave, each in its own frame
    /// (two would not fit in one), the DC datagrams in the first.
    fn big_plan(n: usize) -> Plan {
        let mut p = sample_plan();
        p.frames = (0..n)
            .map(|k| frame(vec![logical(Logical::Lrw, k * 1200, 1200, 3)]))
            .collect();
        p.frames[0]
            .datagrams
            .insert(0, CyclicDatagram::DcSync { station: 0x1001 });
        p.frames[0]
            .datagrams
            .insert(0, CyclicDatagram::DcWriteRef { station: 0x1001 });
        p.image_len = n * 1200;
        p.output_ranges = (0..n).map(|k| (k * 1200, 600)).collect();
        p.initial_image = vec![0; p.image_len];
        p.safe_image = vec![0; p.image_len];
        p
    }

    #[test]
    fn layout_maps_inputs_and_outputs() {
        let p = sample_plan();
        p.validate().unwrap();
        let l = p.layout().unwrap();
        let f = &l.frames[0];
        assert_eq!(f.slots.len(), 3);
        assert_eq!(l.outputs, vec![(0, 4), (6, 4)]);
        let d = f.writes[0].0;
        assert_eq!(f.inputs, vec![(d + 4, 4, 2), (d + 10, 10, 2)]);
        assert_eq!(f.dc_write, Some(f.slots[0].data));
        assert_eq!(f.dc_sync, Some(f.slots[1]));
    }

    #[test]
    fn an_image_larger_than_a_frame_is_laid_out_over_several_frames() {
        let p = big_plan(3);
        p.validate().unwrap();
        let l = p.layout().unwrap();
        assert_eq!(l.frames.len(), 3);
        for (k, f) in l.frames.iter().enumerate() {
            assert!(f.len <= MAX_FRAME_LEN);
            assert_eq!(f.writes.len(), 1);
            let (frame_off, image_off, len) = f.writes[0];
            assert_eq!((image_off, len), (k * 1200, 1200));
            assert_eq!(f.inputs, vec![(frame_off + 600, k * 1200 + 600, 600)]);
            assert_eq!(f.wkc.len(), 1);
            assert_eq!(f.dc_sync.is_some(), k == 0);
        }
        // The same datagrams in one frame do not fit: the error names the datagram.
        let mut one = big_plan(2);
        let second = one.frames.pop().unwrap();
        one.frames[0].datagrams.extend(second.datagrams);
        let e = one.validate().unwrap_err();
        assert!(e.contains("frames[0].datagrams[3] does not fit"), "{e}");
    }

    #[test]
    fn lrd_and_lwr_map_only_their_direction() {
        let mut p = sample_plan();
        // Slave 1 by LRW (bytes 0..6: 4 out, 2 in); slave 2 by LWR (6..10) and LRD (10..12).
        p.frames[0].datagrams.pop();
        p.frames[0].datagrams.extend([
            logical(Logical::Lrw, 0, 6, 3),
            logical(Logical::Lwr, 6, 4, 1),
            logical(Logical::Lrd, 10, 2, 1),
        ]);
        p.validate().unwrap();
        let f = &p.layout().unwrap().frames[0];
        assert_eq!(f.wkc.len(), 3);
        assert_eq!(f.writes.len(), 2, "LRW and LWR carry outputs");
        assert_eq!(f.writes[1].1..f.writes[1].1 + f.writes[1].2, 6..10);
        let lrd = f.slots[4].data;
        assert_eq!(f.inputs, vec![(f.slots[2].data + 4, 4, 2), (lrd, 10, 2)]);
        assert_eq!(f.template[f.slots[3].header], Command::Lwr as u8);
        assert_eq!(f.template[f.slots[4].header], Command::Lrd as u8);
    }

    #[test]
    fn bad_plans_name_the_key() {
        let mut p = sample_plan();
        p.safe_image.pop();
        assert!(p.validate().unwrap_err().contains("safe_image"));
        let mut p = sample_plan();
        p.output_ranges.push((10, 4));
        assert!(p.validate().unwrap_err().contains("output_ranges[2]"));
        let mut p = sample_plan();
        p.dc.mode = DcMode::Off;
        assert!(p.validate().unwrap_err().contains("dc_write_ref"));
        let mut p = sample_plan();
        p.cycle_ns = 10;
        assert!(p.validate().unwrap_err().contains("cycle_ns"));
        let mut p = sample_plan();
        p.frames[0]
            .datagrams
            .push(logical(Logical::Lrw, 0, 1400, 1));
        p.image_len = 1400;
        p.initial_image = vec![0; 1400];
        p.safe_image = vec![0; 1400];
        let e = p.validate().unwrap_err();
        assert!(e.contains("frames[0].datagrams[3]"), "{e}");
        // DC datagrams only in the first frame, which goes out every cycle.
        let mut p = big_plan(2);
        let dc = p.frames[0].datagrams.remove(0);
        p.frames[1].datagrams.push(dc);
        let e = p.validate().unwrap_err();
        assert!(e.contains("frames[1].datagrams[1] is a DC datagram"), "{e}");
        let mut p = big_plan(2);
        p.frames[0].every = 2;
        assert!(p
            .validate()
            .unwrap_err()
            .contains("frames[0].datagrams[0] is a DC"));
        let mut p = big_plan(2);
        p.frames[1].every = 0;
        assert!(p.validate().unwrap_err().contains("frames[1].every = 0"));
        let mut p = big_plan(2);
        p.frames.push(frame(vec![]));
        assert!(p
            .validate()
            .unwrap_err()
            .contains("frames[2] has no datagram"));
        let p = big_plan(MAX_FRAMES + 1);
        assert!(p.validate().unwrap_err().contains("frames holds 33 frames"));
    }
}
