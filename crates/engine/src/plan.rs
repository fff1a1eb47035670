//! The cyclic plan: what the RT thread puts in every frame and how it runs. The Python binding
//! fills it from the plan dict (python/ether_ros/master/plan.py); `validate` names the key that
//! is wrong.

use crate::cia402::{AxisPlan, MAX_TRAJECTORY_CAPACITY};
use ether_ros_wire::{
    self as wire, reg, Command, DatagramSlot, FrameBuilder, MASTER_MAC, MAX_FRAME_LEN,
};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Order {
    /// Receive the previous reply, then send at once at wake-up: constant send instant, one
    /// cycle of latency (IgH's order).
    SendAtWake,
    /// Send at wake-up, wait for the reply inside the cycle (SOEM's order).
    SendThenWait,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CyclicDatagram {
    /// FPWR 0x0910: the master's system time to the reference clock.
    DcWriteRef { station: u16 },
    /// FRMW 0x0910: the reference clock's time to every other DC slave.
    DcSync { station: u16 },
    /// LRW of `length` image bytes at `image_offset`.
    Lrw {
        address: u32,
        length: usize,
        image_offset: usize,
        expected_wkc: u16,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DcMode {
    Off,
    RefFollowsMaster,
    MasterFollowsRef,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DcPlan {
    pub mode: DcMode,
    /// DC system time = CLOCK_MONOTONIC + time_offset_ns.
    pub time_offset_ns: i64,
    pub sync0_shift_ns: i64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Policy {
    Fifo,
    Deadline,
    Other,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RtPlan {
    pub policy: Policy,
    pub priority: i32,
    pub cpu: Option<usize>,
    pub runtime_ns: u64,
    pub lock_memory: bool,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    pub cycle_ns: u64,
    pub order: Order,
    pub datagrams: Vec<CyclicDatagram>,
    pub image_len: usize,
    pub output_ranges: Vec<(usize, usize)>,
    pub initial_image: Vec<u8>,
    pub safe_image: Vec<u8>,
    pub dc: DcPlan,
    pub rt: RtPlan,
    /// 0 = off.
    pub watchdog_ns: u64,
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

/// Where the cyclic datagrams sit in the frame, and which frame bytes map to which image bytes.
#[derive(Clone, Debug, Default)]
pub struct FrameLayout {
    /// The frame with everything fixed filled in (headers); data is refreshed every cycle.
    pub template: Vec<u8>,
    pub len: usize,
    pub slots: Vec<DatagramSlot>,
    /// (frame offset, image offset, length) of every LRW datagram.
    pub lrw: Vec<(usize, usize, usize)>,
    /// Expected working counter per LRW datagram, same order as `lrw`.
    pub lrw_wkc: Vec<(DatagramSlot, u16)>,
    /// (frame offset, image offset, length) of input bytes: copied from the reply to the image.
    pub inputs: Vec<(usize, usize, usize)>,
    /// Image output ranges (image offset, length).
    pub outputs: Vec<(usize, usize)>,
    /// Frame offset of the 8 data bytes of the FPWR 0x0910 datagram.
    pub dc_write: Option<usize>,
    /// Frame offset and slot of the FRMW 0x0910 datagram.
    pub dc_sync: Option<DatagramSlot>,
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
        if self.datagrams.is_empty() {
            return Err("datagrams is empty: the cyclic frame needs at least one datagram".into());
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
        for (i, d) in self.datagrams.iter().enumerate() {
            match *d {
                CyclicDatagram::Lrw {
                    length,
                    image_offset,
                    ..
                } => {
                    if length == 0 || length > wire::MAX_DATAGRAM_DATA {
                        return Err(format!(
                            "datagrams[{i}].length = {length} must be 1..={}",
                            wire::MAX_DATAGRAM_DATA
                        ));
                    }
                    if image_offset + length > self.image_len {
                        return Err(format!(
                            "datagrams[{i}]: image_offset {image_offset} + length {length} runs \
                             past image_len {}",
                            self.image_len
                        ));
                    }
                    for c in &mut covered[image_offset..image_offset + length] {
                        if *c {
                            return Err(format!(
                                "datagrams[{i}] overlaps another LRW datagram in the image"
                            ));
                        }
                        *c = true;
                    }
                }
                CyclicDatagram::DcWriteRef { .. } => {
                    if self.dc.mode != DcMode::RefFollowsMaster {
                        return Err(format!(
                            "datagrams[{i}] is dc_write_ref but dc.mode is not ref_follows_master"
                        ));
                    }
                }
                CyclicDatagram::DcSync { .. } => sync = true,
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

    fn validate_axes(&self, layout: &FrameLayout) -> Result<(), String> {
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

    /// Lay the cyclic frame out once; the RT thread only refreshes data and indices.
    pub fn layout(&self) -> Result<FrameLayout, String> {
        let mut buf = vec![0u8; MAX_FRAME_LEN];
        let mut slots = Vec::new();
        {
            let mut b = FrameBuilder::new(&mut buf, MASTER_MAC).map_err(|e| e.to_string())?;
            for (i, d) in self.datagrams.iter().enumerate() {
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
                    CyclicDatagram::Lrw {
                        address, length, ..
                    } => (Command::Lrw, address, length),
                };
                let slot = b.push(cmd, 0x80, address, None, len).map_err(|e| {
                    format!("datagrams[{i}] does not fit in one Ethernet frame: {e}")
                })?;
                slots.push(slot);
            }
            let len = b.finish();
            buf.truncate(len.max(wire::MIN_FRAME_LEN));
        }
        let mut layout = FrameLayout {
            len: buf.len(),
            ..Default::default()
        };
        let mut is_output = vec![false; self.image_len];
        for &(off, len) in &self.output_ranges {
            is_output[off..off + len].iter_mut().for_each(|o| *o = true);
        }
        layout.outputs = merge_ranges(&is_output, true);
        for (d, slot) in self.datagrams.iter().zip(&slots) {
            match *d {
                CyclicDatagram::DcWriteRef { .. } => layout.dc_write = Some(slot.data),
                CyclicDatagram::DcSync { .. } => layout.dc_sync = Some(*slot),
                CyclicDatagram::Lrw {
                    length,
                    image_offset,
                    expected_wkc,
                    ..
                } => {
                    layout.lrw.push((slot.data, image_offset, length));
                    layout.lrw_wkc.push((*slot, expected_wkc));
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
        layout.slots = slots;
        layout.template = buf;
        Ok(layout)
    }

    /// Is `[offset, offset+len)` inside one output range?
    pub fn output_range_containing(&self, offset: usize, len: usize) -> Option<(usize, usize)> {
        self.output_ranges
            .iter()
            .copied()
            .find(|&(o, l)| offset >= o && offset + len <= o + l)
    }
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

    /// Two slaves, 4 output + 2 input bytes each, DC reference at station 0x1001.
    pub fn sample_plan() -> Plan {
        Plan {
            cycle_ns: 1_000_000,
            order: Order::SendAtWake,
            datagrams: vec![
                CyclicDatagram::DcWriteRef { station: 0x1001 },
                CyclicDatagram::DcSync { station: 0x1001 },
                CyclicDatagram::Lrw {
                    address: 0x10000,
                    length: 12,
                    image_offset: 0,
                    expected_wkc: 6,
                },
            ],
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

    #[test]
    fn layout_maps_inputs_and_outputs() {
        let p = sample_plan();
        p.validate().unwrap();
        let l = p.layout().unwrap();
        assert_eq!(l.slots.len(), 3);
        assert_eq!(l.outputs, vec![(0, 4), (6, 4)]);
        let d = l.lrw[0].0;
        assert_eq!(l.inputs, vec![(d + 4, 4, 2), (d + 10, 10, 2)]);
        assert_eq!(l.dc_write, Some(l.slots[0].data));
        assert_eq!(l.dc_sync, Some(l.slots[1]));
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
        p.datagrams.push(CyclicDatagram::Lrw {
            address: 0,
            length: 1400,
            image_offset: 0,
            expected_wkc: 1,
        });
        p.image_len = 1400;
        p.initial_image = vec![0; 1400];
        p.safe_image = vec![0; 1400];
        let e = p.validate().unwrap_err();
        assert!(e.contains("datagrams[3]"), "{e}");
    }
}
