//! CiA 402 (IEC 61800-7-201) drives as joints: the axis stage of the cycle.
//!
//! For every axis of the plan the RT thread, once per cycle and before the frame is built,
//! reads the drive's statusword and actual values from the process image (the inputs last
//! received), decides the controlword (the standard's power state machine: fault reset →
//! shutdown → switch on → enable operation, or the configured stop), the mode of operation and
//! the targets (interpolated setpoints or a timed trajectory, clamped to the limits), and writes
//! them into the image's outputs. Commands come from other threads through one seqlock slot per
//! axis (and one per trajectory); the status of all axes goes out through one seqlock buffer.
//! Everything is sized when the plan is accepted: the stage never allocates.
//!
//! Units: the engine works in SI (rad or m, /s, N·m or N): position = raw × position_scale +
//! position_offset, velocity = raw × velocity_scale, torque = raw × torque_scale.

use crate::handover::SeqBuffer;

/// Controlword commands and bits (the standard's "device control commands"): the protocol
/// crate's (`ether_ros_protocol::cia402`).
pub mod word {
    pub use ether_ros_protocol::cia402::command::{
        DISABLE_VOLTAGE, ENABLE_OPERATION, FAULT_RESET, QUICK_STOP, SHUTDOWN, SWITCH_ON,
    };
    /// Bit 5 in pp: change set immediately.
    pub use ether_ros_protocol::cia402::cw::CHANGE_SET_IMMEDIATELY as CHANGE_IMMEDIATELY;
    /// Bit 4 in pp (new set-point) and hm (homing operation start).
    pub use ether_ros_protocol::cia402::cw::NEW_SETPOINT as OPERATION_BIT4;
    /// Statusword bit 12 in pp: set-point acknowledge.
    pub use ether_ros_protocol::cia402::sw::MODE_12 as SETPOINT_ACK;
}

/// Modes of operation (0x6060 values): the protocol crate's.
pub use ether_ros_protocol::cia402::Mode;
/// The power states of the drive, decoded from the statusword: the protocol crate's.
pub use ether_ros_protocol::cia402::State as DriveState;

/// Which kind of setpoint a mode takes (None for homing).
pub fn setpoint_kind(mode: Mode) -> Option<SetpointKind> {
    match mode {
        Mode::ProfilePosition | Mode::CyclicPosition => Some(SetpointKind::Position),
        Mode::ProfileVelocity | Mode::CyclicVelocity => Some(SetpointKind::Velocity),
        Mode::CyclicTorque => Some(SetpointKind::Torque),
        Mode::Homing => None,
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum SetpointKind {
    Position = 1,
    Velocity = 2,
    Torque = 3,
}

impl SetpointKind {
    pub fn from_code(code: u8) -> Option<SetpointKind> {
        Some(match code {
            1 => SetpointKind::Position,
            2 => SetpointKind::Velocity,
            3 => SetpointKind::Torque,
            _ => return None,
        })
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OnStop {
    /// Controlword "quick stop": the drive ramps down per its 0x605A quick stop option code.
    QuickStop,
    /// Controlword "disable voltage": the power stage switches off at once.
    Disable,
}

impl OnStop {
    fn controlword(self) -> u16 {
        match self {
            OnStop::QuickStop => word::QUICK_STOP,
            OnStop::Disable => word::DISABLE_VOLTAGE,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultReset {
    /// Reset and re-enable after a back-off, at most `fault_retries` times in a row.
    Auto,
    /// Stay in Fault until a reset is asked for.
    Manual,
}

/// Byte offsets in the process image of the axis's objects (None: not mapped). Sizes are the
/// standard's: controlword/statusword/error code u16, modes i8, positions, velocities and the
/// following error i32, torques i16.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AxisMap {
    pub controlword: usize,
    pub statusword: usize,
    pub mode: Option<usize>,
    pub mode_display: Option<usize>,
    pub target_position: Option<usize>,
    pub target_velocity: Option<usize>,
    pub target_torque: Option<usize>,
    pub position: Option<usize>,
    pub velocity: Option<usize>,
    pub torque: Option<usize>,
    pub error_code: Option<usize>,
    pub following_error: Option<usize>,
}

impl AxisMap {
    /// (name, output?, offset, size) of every mapped object.
    pub fn objects(&self) -> Vec<(&'static str, bool, usize, usize)> {
        let mut v = vec![
            ("controlword", true, self.controlword, 2),
            ("statusword", false, self.statusword, 2),
        ];
        let opt = [
            ("mode", true, self.mode, 1),
            ("mode_display", false, self.mode_display, 1),
            ("target_position", true, self.target_position, 4),
            ("target_velocity", true, self.target_velocity, 4),
            ("target_torque", true, self.target_torque, 2),
            ("position", false, self.position, 4),
            ("velocity", false, self.velocity, 4),
            ("torque", false, self.torque, 2),
            ("error_code", false, self.error_code, 2),
            ("following_error", false, self.following_error, 4),
        ];
        for (name, out, off, size) in opt {
            if let Some(o) = off {
                v.push((name, out, o, size));
            }
        }
        v
    }
}

/// Limits in SI units; setpoints outside are clamped (and counted).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    pub position_min: f64,
    pub position_max: f64,
    /// Largest |velocity|; also bounds the CSP target's step per cycle.
    pub velocity_max: f64,
    pub torque_max: f64,
}

#[derive(Clone, Debug, PartialEq)]
pub struct AxisPlan {
    pub name: String,
    pub map: AxisMap,
    /// The mode commanded at start.
    pub mode: Mode,
    pub position_scale: f64,
    pub position_offset: f64,
    pub velocity_scale: f64,
    pub torque_scale: f64,
    pub limits: Limits,
    /// |following error| above this (SI) sets the status flag; 0 = not checked.
    pub following_error_window: f64,
    pub on_stop: OnStop,
    pub fault_reset: FaultReset,
    /// Automatic resets in a row before giving up (auto policy).
    pub fault_retries: u32,
    /// Wait before the first automatic reset; doubled for every further one.
    pub fault_backoff_ns: i64,
    /// Longest span a CSP setpoint is interpolated over (the time since the previous one,
    /// capped at this).
    pub interpolation_max_ns: i64,
}

/// Points per axis trajectory unless the plan says otherwise.
pub const DEFAULT_TRAJECTORY_CAPACITY: usize = 1024;
/// Bytes of one trajectory point: t (ns since start) i64, position f64, velocity f64.
pub const POINT_LEN: usize = 24;
/// The trajectory slot starts with the `seq` of the command the points belong to (u64), so the
/// RT thread never runs one command with another's points.
pub const TRAJECTORY_HEADER: usize = 8;
/// Largest trajectory capacity accepted.
pub const MAX_TRAJECTORY_CAPACITY: usize = 1 << 16;

impl AxisPlan {
    /// Check the axis; the error names the axis and what is wrong.
    pub fn validate(&self, image_len: usize, outputs: &[(usize, usize)]) -> Result<(), String> {
        let n = &self.name;
        let finite_positive = |v: f64| v.is_finite() && v > 0.0;
        for (key, v) in [
            ("position_scale", self.position_scale),
            ("velocity_scale", self.velocity_scale),
            ("torque_scale", self.torque_scale),
        ] {
            if !finite_positive(v) {
                return Err(format!("axis {n}: {key} = {v} must be a positive number"));
            }
        }
        let l = &self.limits;
        if l.position_min.is_nan() || l.position_max.is_nan() || l.position_min > l.position_max {
            return Err(format!(
                "axis {n}: position limits [{}, {}] are not min <= max",
                l.position_min, l.position_max
            ));
        }
        for (key, v) in [
            ("velocity_max", l.velocity_max),
            ("torque_max", l.torque_max),
        ] {
            if v.is_nan() || v <= 0.0 {
                return Err(format!("axis {n}: {key} = {v} must be positive"));
            }
        }
        if !self.position_offset.is_finite()
            || self.following_error_window.is_nan()
            || self.following_error_window < 0.0
            || self.fault_backoff_ns < 0
            || self.interpolation_max_ns <= 0
        {
            return Err(format!(
                "axis {n}: position_offset must be finite, following_error_window >= 0, \
                 fault_backoff_ns >= 0 and interpolation_max_ns > 0"
            ));
        }
        let needs = match setpoint_kind(self.mode) {
            Some(SetpointKind::Position) => self.map.target_position,
            Some(SetpointKind::Velocity) => self.map.target_velocity,
            Some(SetpointKind::Torque) => self.map.target_torque,
            None => Some(0),
        };
        if needs.is_none() {
            return Err(format!(
                "axis {n}: mode {:?} needs its target object mapped",
                self.mode
            ));
        }
        for (name, out, off, size) in self.map.objects() {
            if off + size > image_len {
                return Err(format!(
                    "axis {n}: {name} at byte {off} runs past image_len {image_len}"
                ));
            }
            let inside = outputs
                .iter()
                .any(|&(o, l)| off >= o && off + size <= o + l);
            if out != inside {
                let want = if out { "an output" } else { "an input" };
                return Err(format!(
                    "axis {n}: {name} at byte {off} must lie in {want} range"
                ));
            }
        }
        Ok(())
    }

    fn to_raw_position(&self, si: f64) -> i32 {
        saturate_i32((si - self.position_offset) / self.position_scale)
    }

    fn position_si(&self, raw: i32) -> f64 {
        raw as f64 * self.position_scale + self.position_offset
    }
}

fn saturate_i32(v: f64) -> i32 {
    v.round().clamp(i32::MIN as f64, i32::MAX as f64) as i32
}

fn saturate_i16(v: f64) -> i16 {
    v.round().clamp(i16::MIN as f64, i16::MAX as f64) as i16
}

/// What the command slot of an axis holds (the latest of each request).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisCommand {
    /// Wanted in Operation Enabled (false: the `on_stop` command).
    pub enable: bool,
    pub mode: Mode,
    /// Incremented for every fault reset asked for.
    pub reset_count: u32,
    /// Incremented for every setpoint or trajectory: the newest wins.
    pub seq: u64,
    /// 0: the last command is a trajectory, else a SetpointKind code.
    pub setpoint_kind: u8,
    pub value: f64,
    /// When the setpoint arrived (CLOCK_MONOTONIC ns), or the trajectory's start.
    pub t_ns: i64,
    pub trajectory_len: u32,
}

/// Encoded size of an AxisCommand.
pub const COMMAND_LEN: usize = 40;

impl AxisCommand {
    pub fn initial(mode: Mode) -> AxisCommand {
        AxisCommand {
            enable: false,
            mode,
            reset_count: 0,
            seq: 0,
            setpoint_kind: 0,
            value: 0.0,
            t_ns: 0,
            trajectory_len: 0,
        }
    }

    pub fn encode(&self, b: &mut [u8]) {
        b[0] = self.enable as u8;
        b[1] = self.mode as i8 as u8;
        b[2] = self.setpoint_kind;
        b[3] = 0;
        b[4..8].copy_from_slice(&self.reset_count.to_le_bytes());
        b[8..16].copy_from_slice(&self.seq.to_le_bytes());
        b[16..24].copy_from_slice(&self.value.to_le_bytes());
        b[24..32].copy_from_slice(&self.t_ns.to_le_bytes());
        b[32..36].copy_from_slice(&self.trajectory_len.to_le_bytes());
        b[36..40].fill(0);
    }

    pub fn decode(b: &[u8]) -> AxisCommand {
        let u32_at = |i: usize| u32::from_le_bytes(b[i..i + 4].try_into().unwrap());
        let u64_at = |i: usize| u64::from_le_bytes(b[i..i + 8].try_into().unwrap());
        AxisCommand {
            enable: b[0] != 0,
            mode: Mode::from_code(b[1] as i8).unwrap_or(Mode::CyclicPosition),
            setpoint_kind: b[2],
            reset_count: u32_at(4),
            seq: u64_at(8),
            value: f64::from_bits(u64_at(16)),
            t_ns: u64_at(24) as i64,
            trajectory_len: u32_at(32),
        }
    }
}

/// One trajectory point: `t_ns` after the trajectory's start, position and velocity (SI).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Point {
    pub t_ns: i64,
    pub position: f64,
    pub velocity: f64,
}

impl Point {
    pub fn encode(&self, b: &mut [u8]) {
        b[0..8].copy_from_slice(&self.t_ns.to_le_bytes());
        b[8..16].copy_from_slice(&self.position.to_le_bytes());
        b[16..24].copy_from_slice(&self.velocity.to_le_bytes());
    }

    pub fn decode(b: &[u8]) -> Point {
        let u64_at = |i: usize| u64::from_le_bytes(b[i..i + 8].try_into().unwrap());
        Point {
            t_ns: u64_at(0) as i64,
            position: f64::from_bits(u64_at(8)),
            velocity: f64::from_bits(u64_at(16)),
        }
    }
}

/// Status flags of an axis (AxisStatus::flags).
pub mod status_flags {
    /// Operation Enabled is wanted.
    pub const ENABLE_WANTED: u16 = 1 << 0;
    /// The drive shows the commanded mode (0x6061 = 0x6060).
    pub const MODE_REACHED: u16 = 1 << 1;
    /// A trajectory is being executed.
    pub const TRAJECTORY_ACTIVE: u16 = 1 << 2;
    /// The last trajectory has run to its end.
    pub const TRAJECTORY_DONE: u16 = 1 << 3;
    /// |following error| > following_error_window.
    pub const FOLLOWING_ERROR: u16 = 1 << 4;
    /// The automatic fault reset gave up (retries used up); a manual reset clears it.
    pub const RETRIES_EXHAUSTED: u16 = 1 << 5;
    /// The stop (panic, watchdog) is forced on the axis.
    pub const HALTED: u16 = 1 << 6;
}

/// What the RT thread publishes about an axis every cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AxisStatus {
    pub cycle: u64,
    pub statusword: u16,
    pub controlword: u16,
    pub state: u8,
    pub mode_display: i8,
    pub flags: u16,
    pub error_code: u16,
    /// The error code seen when the last fault was detected.
    pub last_fault_code: u16,
    pub position_raw: i32,
    pub velocity_raw: i32,
    pub torque_raw: i16,
    pub following_error_raw: i32,
    pub target_position_raw: i32,
    pub position: f64,
    pub velocity: f64,
    pub torque: f64,
    pub following_error: f64,
    /// The position target sent this cycle (SI).
    pub target_position: f64,
    pub position_clamps: u32,
    pub velocity_clamps: u32,
    pub torque_clamps: u32,
    pub faults: u32,
    pub fault_resets: u32,
    /// `seq` of the last command taken over.
    pub command_seq: u64,
}

/// Encoded size of an AxisStatus.
pub const STATUS_LEN: usize = 120;

impl AxisStatus {
    pub fn encode(&self, b: &mut [u8]) {
        b[0..8].copy_from_slice(&self.cycle.to_le_bytes());
        b[8..10].copy_from_slice(&self.statusword.to_le_bytes());
        b[10..12].copy_from_slice(&self.controlword.to_le_bytes());
        b[12] = self.state;
        b[13] = self.mode_display as u8;
        b[14..16].copy_from_slice(&self.flags.to_le_bytes());
        b[16..18].copy_from_slice(&self.error_code.to_le_bytes());
        b[18..20].copy_from_slice(&self.last_fault_code.to_le_bytes());
        b[20..24].copy_from_slice(&self.position_raw.to_le_bytes());
        b[24..28].copy_from_slice(&self.velocity_raw.to_le_bytes());
        b[28..30].copy_from_slice(&self.torque_raw.to_le_bytes());
        b[30..32].fill(0);
        b[32..36].copy_from_slice(&self.following_error_raw.to_le_bytes());
        b[36..40].copy_from_slice(&self.target_position_raw.to_le_bytes());
        b[40..48].copy_from_slice(&self.position.to_le_bytes());
        b[48..56].copy_from_slice(&self.velocity.to_le_bytes());
        b[56..64].copy_from_slice(&self.torque.to_le_bytes());
        b[64..72].copy_from_slice(&self.following_error.to_le_bytes());
        b[72..80].copy_from_slice(&self.target_position.to_le_bytes());
        b[80..84].copy_from_slice(&self.position_clamps.to_le_bytes());
        b[84..88].copy_from_slice(&self.velocity_clamps.to_le_bytes());
        b[88..92].copy_from_slice(&self.torque_clamps.to_le_bytes());
        b[92..96].copy_from_slice(&self.faults.to_le_bytes());
        b[96..100].copy_from_slice(&self.fault_resets.to_le_bytes());
        b[100..104].fill(0);
        b[104..112].copy_from_slice(&self.command_seq.to_le_bytes());
        b[112..120].fill(0);
    }

    pub fn decode(b: &[u8]) -> AxisStatus {
        let u16_at = |i: usize| u16::from_le_bytes(b[i..i + 2].try_into().unwrap());
        let u32_at = |i: usize| u32::from_le_bytes(b[i..i + 4].try_into().unwrap());
        let u64_at = |i: usize| u64::from_le_bytes(b[i..i + 8].try_into().unwrap());
        let f64_at = |i: usize| f64::from_bits(u64_at(i));
        AxisStatus {
            cycle: u64_at(0),
            statusword: u16_at(8),
            controlword: u16_at(10),
            state: b[12],
            mode_display: b[13] as i8,
            flags: u16_at(14),
            error_code: u16_at(16),
            last_fault_code: u16_at(18),
            position_raw: u32_at(20) as i32,
            velocity_raw: u32_at(24) as i32,
            torque_raw: u16_at(28) as i16,
            following_error_raw: u32_at(32) as i32,
            target_position_raw: u32_at(36) as i32,
            position: f64_at(40),
            velocity: f64_at(48),
            torque: f64_at(56),
            following_error: f64_at(64),
            target_position: f64_at(72),
            position_clamps: u32_at(80),
            velocity_clamps: u32_at(84),
            torque_clamps: u32_at(88),
            faults: u32_at(92),
            fault_resets: u32_at(96),
            command_seq: u64_at(104),
        }
    }
}

/// The hand-over buffers of all axes for one cyclic run (shared by the engine and the RT
/// thread): one command slot and one trajectory slot per axis, one status buffer for all.
pub struct AxisExchange {
    pub commands: Vec<SeqBuffer>,
    pub trajectories: Vec<SeqBuffer>,
    pub status: SeqBuffer,
    pub trajectory_capacity: usize,
}

impl AxisExchange {
    pub fn new(axes: &[AxisPlan], trajectory_capacity: usize) -> AxisExchange {
        let mut cmd = [0u8; COMMAND_LEN];
        AxisExchange {
            commands: axes
                .iter()
                .map(|a| {
                    AxisCommand::initial(a.mode).encode(&mut cmd);
                    SeqBuffer::new(&cmd)
                })
                .collect(),
            trajectories: axes
                .iter()
                .map(|_| {
                    SeqBuffer::new(&vec![
                        0u8;
                        TRAJECTORY_HEADER + trajectory_capacity * POINT_LEN
                    ])
                })
                .collect(),
            status: SeqBuffer::new(&vec![0u8; axes.len() * STATUS_LEN]),
            trajectory_capacity,
        }
    }
}

/// Linear interpolation between the last two setpoints by their arrival times: a setpoint is
/// reached one arrival interval after it arrived (so a stream of setpoints gives a smooth
/// path, delayed by one command period), then held.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Interpolator {
    from: f64,
    to: f64,
    /// Arrival of `to`.
    t_to: i64,
    span: i64,
    /// Arrival of the previous setpoint (None: no setpoint since the reset).
    last_arrival: Option<i64>,
}

impl Interpolator {
    /// Hold `value` (no motion) until the next setpoint.
    pub fn reset(&mut self, value: f64) {
        *self = Interpolator {
            from: value,
            to: value,
            ..Default::default()
        };
    }

    pub fn value(&self, t: i64) -> f64 {
        if self.span <= 0 || t >= self.t_to + self.span {
            return self.to;
        }
        let f = ((t - self.t_to) as f64 / self.span as f64).clamp(0.0, 1.0);
        self.from + (self.to - self.from) * f
    }

    /// A new setpoint `to` arrived at `t`: move there over the interval since the previous
    /// one (at least `min_span`, at most `max_span`), starting from where we are now.
    pub fn push(&mut self, to: f64, t: i64, min_span: i64, max_span: i64) {
        let from = self.value(t);
        let span = self
            .last_arrival
            .map_or(min_span, |prev| (t - prev).clamp(min_span, max_span));
        *self = Interpolator {
            from,
            to,
            t_to: t,
            span,
            last_arrival: Some(t),
        };
    }
}

/// Cubic Hermite position and its velocity at time `t` (ns since start) on the trajectory
/// `points` (sorted by time, first at t ≥ 0); `cursor` remembers the segment (time only moves
/// forward). Before the first point: the first point; after the last: the last point's
/// position with velocity 0.
pub fn sample_trajectory(points: &[Point], t: i64, cursor: &mut usize) -> (f64, f64, bool) {
    let Some(last) = points.last() else {
        return (0.0, 0.0, true);
    };
    if t >= last.t_ns {
        return (last.position, 0.0, true);
    }
    let first = points[0];
    if t <= first.t_ns {
        return (first.position, first.velocity, false);
    }
    while *cursor + 1 < points.len() && points[*cursor + 1].t_ns <= t {
        *cursor += 1;
    }
    let a = points[*cursor];
    let b = points[(*cursor + 1).min(points.len() - 1)];
    let h = (b.t_ns - a.t_ns) as f64 * 1e-9;
    if h <= 0.0 {
        return (b.position, b.velocity, false);
    }
    let s = (t - a.t_ns) as f64 * 1e-9 / h;
    let (s2, s3) = (s * s, s * s * s);
    let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
    let h10 = s3 - 2.0 * s2 + s;
    let h01 = -2.0 * s3 + 3.0 * s2;
    let h11 = s3 - s2;
    let p = h00 * a.position + h10 * h * a.velocity + h01 * b.position + h11 * h * b.velocity;
    let d00 = 6.0 * s2 - 6.0 * s;
    let d10 = 3.0 * s2 - 4.0 * s + 1.0;
    let d01 = -6.0 * s2 + 6.0 * s;
    let d11 = 3.0 * s2 - 2.0 * s;
    let v = (d00 * a.position + d01 * b.position) / h + d10 * a.velocity + d11 * b.velocity;
    (p, v, false)
}

fn read_u16(io: &[u8], off: usize) -> u16 {
    u16::from_le_bytes([io[off], io[off + 1]])
}

fn read_i32(io: &[u8], off: usize) -> i32 {
    i32::from_le_bytes(io[off..off + 4].try_into().unwrap())
}

fn read_i16(io: &[u8], off: usize) -> i16 {
    read_u16(io, off) as i16
}

/// The controller of one axis: RT-thread state between cycles.
pub struct AxisController {
    pub plan: AxisPlan,
    command: AxisCommand,
    command_bytes: [u8; COMMAND_LEN],
    command_version: u64,
    /// Trajectory points copied out of the slot (capacity fixed at start).
    points: Vec<Point>,
    point_bytes: Vec<u8>,
    points_len: usize,
    /// The trajectory `seq` whose points are loaded (waiting for a consistent copy otherwise).
    trajectory_seq: Option<u64>,
    trajectory_running: bool,
    cursor: usize,
    interpolator: Interpolator,
    /// Last targets written (SI).
    target_position: f64,
    setpoint_value: f64,
    /// Setpoint command already taken over.
    seq_seen: u64,
    reset_seen: u32,
    reset_pending: bool,
    /// Fault reset: 0 bit 7 low for a cycle, then high until the fault is gone.
    reset_phase: u8,
    in_fault: bool,
    fault_since: i64,
    retries: u32,
    operation_enabled_since: Option<i64>,
    /// When the previous cycle ran (for the CSP step limit).
    last_step_ns: Option<i64>,
    /// pp: a new set-point waits for the drive's acknowledge.
    pp_new_setpoint: bool,
    pub status: AxisStatus,
}

/// Operation Enabled this long without a fault gives the automatic reset its retries back.
const FAULT_RETRY_RESET_NS: i64 = 2_000_000_000;

impl AxisController {
    pub fn new(plan: AxisPlan, trajectory_capacity: usize) -> AxisController {
        let command = AxisCommand::initial(plan.mode);
        AxisController {
            command,
            command_bytes: [0; COMMAND_LEN],
            command_version: u64::MAX,
            points: vec![Point::default(); trajectory_capacity],
            point_bytes: vec![0; TRAJECTORY_HEADER + trajectory_capacity * POINT_LEN],
            points_len: 0,
            trajectory_seq: None,
            trajectory_running: false,
            cursor: 0,
            interpolator: Interpolator::default(),
            target_position: 0.0,
            setpoint_value: 0.0,
            seq_seen: 0,
            reset_seen: 0,
            reset_pending: false,
            reset_phase: 0,
            in_fault: false,
            fault_since: 0,
            retries: 0,
            operation_enabled_since: None,
            pp_new_setpoint: false,
            last_step_ns: None,
            status: AxisStatus::default(),
            plan,
        }
    }

    /// Take over a newer command from the slot (a write in progress: keep the previous one).
    fn refresh_command(&mut self, slot: &SeqBuffer) {
        if slot.version() == self.command_version {
            return;
        }
        if let Some(v) = slot.try_read(&mut self.command_bytes) {
            self.command_version = v;
            self.command = AxisCommand::decode(&self.command_bytes);
        }
    }

    /// Load the trajectory's points when the command names a new one.
    fn refresh_trajectory(&mut self, slot: &SeqBuffer) {
        let c = &self.command;
        if c.setpoint_kind != 0 || self.trajectory_seq == Some(c.seq) {
            return;
        }
        let n = (c.trajectory_len as usize).min(self.points.len());
        let header = |b: &[u8]| u64::from_le_bytes(b[..TRAJECTORY_HEADER].try_into().unwrap());
        if slot.try_read(&mut self.point_bytes).is_some() && header(&self.point_bytes) == c.seq {
            for (p, b) in self.points[..n]
                .iter_mut()
                .zip(self.point_bytes[TRAJECTORY_HEADER..].chunks_exact(POINT_LEN))
            {
                *p = Point::decode(b);
            }
            self.points_len = n;
            self.cursor = 0;
            self.trajectory_seq = Some(c.seq);
        }
    }

    /// One cycle: read the drive from `io` (inputs last received), write controlword, mode and
    /// targets into `io`'s outputs. `halt`: panic or watchdog, the stop is forced.
    pub fn step(
        &mut self,
        io: &mut [u8],
        now: i64,
        cycle_ns: i64,
        halt: bool,
        slots: (&SeqBuffer, &SeqBuffer),
    ) {
        self.refresh_command(slots.0);
        self.refresh_trajectory(slots.1);
        let map = self.plan.map;
        let sw = read_u16(io, map.statusword);
        let state = DriveState::decode(sw);
        let position_raw = map.position.map_or(0, |o| read_i32(io, o));
        let position = self.plan.position_si(position_raw);
        let mode_display = map
            .mode_display
            .map_or(self.command.mode as i8, |o| io[o] as i8);
        let error_code = map.error_code.map_or(0, |o| read_u16(io, o));
        let mode_reached = mode_display == self.command.mode as i8;
        let cmd = self.command;
        let st = &mut self.status;

        // Faults: count each, note its code, and decide on resets.
        if cmd.reset_count != self.reset_seen {
            self.reset_seen = cmd.reset_count;
            self.reset_pending = true;
            self.retries = 0;
        }
        if state.is_fault() {
            if !self.in_fault {
                self.in_fault = true;
                self.fault_since = now;
                st.faults += 1;
                st.last_fault_code = error_code;
            }
            let auto = self.plan.fault_reset == FaultReset::Auto && cmd.enable && !halt;
            let backoff = self
                .plan
                .fault_backoff_ns
                .saturating_mul(1 << self.retries.min(20));
            if auto
                && !self.reset_pending
                && self.retries < self.plan.fault_retries
                && now - self.fault_since >= backoff
            {
                self.reset_pending = true;
                self.retries += 1;
            }
        } else if self.in_fault {
            self.in_fault = false;
            if self.reset_phase > 0 {
                st.fault_resets += 1;
            }
            self.reset_pending = false;
            self.reset_phase = 0;
        }
        if state == DriveState::OperationEnabled {
            let since = *self.operation_enabled_since.get_or_insert(now);
            if now - since >= FAULT_RETRY_RESET_NS {
                self.retries = 0;
            }
        } else {
            self.operation_enabled_since = None;
        }

        // The controlword.
        let enable = cmd.enable && !halt;
        let mut cw = if state == DriveState::Fault && self.reset_pending {
            // Rising edge of bit 7: one cycle low, then high until the drive leaves Fault.
            if self.reset_phase == 0 {
                self.reset_phase = 1;
                word::DISABLE_VOLTAGE
            } else {
                self.reset_phase = 2;
                word::FAULT_RESET
            }
        } else if !enable {
            self.plan.on_stop.controlword()
        } else {
            match state {
                DriveState::SwitchOnDisabled => word::SHUTDOWN,
                DriveState::ReadyToSwitchOn => word::SWITCH_ON,
                DriveState::SwitchedOn | DriveState::OperationEnabled => word::ENABLE_OPERATION,
                // Back through Switch On Disabled (transition 12) and up again.
                DriveState::QuickStopActive => word::DISABLE_VOLTAGE,
                DriveState::NotReadyToSwitchOn
                | DriveState::FaultReactionActive
                | DriveState::Fault => word::DISABLE_VOLTAGE,
            }
        };

        // Targets: the actual position until the drive is enabled in the commanded mode, so
        // enabling never moves the axis; then the setpoints.
        let running = state == DriveState::OperationEnabled && enable && mode_reached;
        // Enabled, only the mode display is not there yet: commands wait for it.
        let waiting_for_mode = state == DriveState::OperationEnabled && enable && !mode_reached;
        let mut velocity_target = 0.0;
        let mut torque_target = 0.0;
        if !running {
            if !waiting_for_mode {
                // Commands given while the axis cannot run are dropped, so that enabling
                // never starts a motion that was asked for before.
                self.target_position = position;
                self.seq_seen = cmd.seq;
                self.setpoint_value = 0.0;
            }
            self.interpolator.reset(self.target_position);
            self.trajectory_running = false;
            self.pp_new_setpoint = false;
            st.flags &= !status_flags::TRAJECTORY_ACTIVE;
        } else {
            let limits = self.plan.limits;
            if cmd.seq != self.seq_seen {
                match SetpointKind::from_code(cmd.setpoint_kind) {
                    // A trajectory starts once its points are loaded.
                    None if self.trajectory_seq == Some(cmd.seq) => {
                        self.seq_seen = cmd.seq;
                        self.trajectory_running = true;
                        self.cursor = 0;
                    }
                    None => {}
                    Some(kind) => {
                        self.seq_seen = cmd.seq;
                        self.trajectory_running = false;
                        if kind == SetpointKind::Position && cmd.mode == Mode::ProfilePosition {
                            // The drive plans the motion itself and latches the target with
                            // the new set-point bit: hand it over whole, not interpolated.
                            self.interpolator.reset(cmd.value);
                            self.pp_new_setpoint = true;
                        } else if kind == SetpointKind::Position {
                            self.interpolator.push(
                                cmd.value,
                                cmd.t_ns,
                                cycle_ns,
                                self.plan.interpolation_max_ns,
                            );
                        } else {
                            self.setpoint_value = cmd.value;
                        }
                    }
                }
            }
            let mut flags_traj = 0;
            if self.trajectory_running {
                let (p, v, done) = sample_trajectory(
                    &self.points[..self.points_len],
                    now - cmd.t_ns,
                    &mut self.cursor,
                );
                flags_traj = if done {
                    status_flags::TRAJECTORY_DONE
                } else {
                    status_flags::TRAJECTORY_ACTIVE
                };
                match setpoint_kind(cmd.mode) {
                    Some(SetpointKind::Position) => self.interpolator.reset(p),
                    Some(SetpointKind::Velocity) => self.setpoint_value = v,
                    _ => {}
                }
            }
            st.flags = (st.flags
                & !(status_flags::TRAJECTORY_ACTIVE | status_flags::TRAJECTORY_DONE))
                | flags_traj;
            match cmd.mode {
                Mode::CyclicPosition | Mode::ProfilePosition => {
                    let wanted = self.interpolator.value(now);
                    // Outside the limits (enabled there), only motion back inside is allowed.
                    let lo = limits.position_min.min(self.target_position);
                    let hi = limits.position_max.max(self.target_position);
                    let mut p = wanted.clamp(lo, hi);
                    if cmd.mode == Mode::CyclicPosition {
                        // No step larger than the velocity limit allows since the last cycle
                        // (a late wake-up may have skipped one: the path still moved on).
                        let elapsed = self
                            .last_step_ns
                            .map_or(cycle_ns, |t| (now - t).max(cycle_ns));
                        let step = limits.velocity_max * elapsed as f64 * 1e-9;
                        p = p.clamp(self.target_position - step, self.target_position + step);
                    }
                    if p != wanted {
                        st.position_clamps += 1;
                    }
                    self.target_position = p;
                }
                Mode::CyclicVelocity | Mode::ProfileVelocity => {
                    let v = self.setpoint_value;
                    velocity_target = v.clamp(-limits.velocity_max, limits.velocity_max);
                    if velocity_target != v {
                        st.velocity_clamps += 1;
                    }
                }
                Mode::CyclicTorque => {
                    let t = self.setpoint_value;
                    torque_target = t.clamp(-limits.torque_max, limits.torque_max);
                    if torque_target != t {
                        st.torque_clamps += 1;
                    }
                }
                Mode::Homing => {}
            }
            match cmd.mode {
                Mode::ProfilePosition => {
                    if sw & word::SETPOINT_ACK != 0 {
                        self.pp_new_setpoint = false;
                    }
                    if self.pp_new_setpoint {
                        cw |= word::OPERATION_BIT4 | word::CHANGE_IMMEDIATELY;
                    }
                }
                Mode::Homing => cw |= word::OPERATION_BIT4,
                _ => {}
            }
        }

        self.last_step_ns = Some(now);

        // Into the image.
        io[map.controlword..map.controlword + 2].copy_from_slice(&cw.to_le_bytes());
        if let Some(o) = map.mode {
            io[o] = cmd.mode as i8 as u8;
        }
        let target_raw = self.plan.to_raw_position(self.target_position);
        if let Some(o) = map.target_position {
            io[o..o + 4].copy_from_slice(&target_raw.to_le_bytes());
        }
        if let Some(o) = map.target_velocity {
            let raw = saturate_i32(velocity_target / self.plan.velocity_scale);
            io[o..o + 4].copy_from_slice(&raw.to_le_bytes());
        }
        if let Some(o) = map.target_torque {
            let raw = saturate_i16(torque_target / self.plan.torque_scale);
            io[o..o + 2].copy_from_slice(&raw.to_le_bytes());
        }

        // Status.
        let velocity_raw = map.velocity.map_or(0, |o| read_i32(io, o));
        let torque_raw = map.torque.map_or(0, |o| read_i16(io, o));
        let following_raw = map
            .following_error
            .map_or(target_raw.wrapping_sub(position_raw), |o| read_i32(io, o));
        st.statusword = sw;
        st.controlword = cw;
        st.state = state as u8;
        st.mode_display = mode_display;
        st.error_code = error_code;
        st.position_raw = position_raw;
        st.velocity_raw = velocity_raw;
        st.torque_raw = torque_raw;
        st.following_error_raw = following_raw;
        st.target_position_raw = target_raw;
        st.position = position;
        st.velocity = velocity_raw as f64 * self.plan.velocity_scale;
        st.torque = torque_raw as f64 * self.plan.torque_scale;
        st.following_error = following_raw as f64 * self.plan.position_scale;
        st.target_position = self.target_position;
        st.command_seq = cmd.seq;
        let window = self.plan.following_error_window;
        let mut f = st.flags & (status_flags::TRAJECTORY_ACTIVE | status_flags::TRAJECTORY_DONE);
        if cmd.enable {
            f |= status_flags::ENABLE_WANTED;
        }
        if mode_reached {
            f |= status_flags::MODE_REACHED;
        }
        if window > 0.0
            && state == DriveState::OperationEnabled
            && st.following_error.abs() > window
        {
            f |= status_flags::FOLLOWING_ERROR;
        }
        if state.is_fault()
            && self.plan.fault_reset == FaultReset::Auto
            && self.retries >= self.plan.fault_retries
            && !self.reset_pending
        {
            f |= status_flags::RETRIES_EXHAUSTED;
        }
        if halt {
            f |= status_flags::HALTED;
        }
        st.flags = f;
    }
}

/// The axis stage of the cycle: every axis's controller plus the status bytes, preallocated.
pub struct Axes {
    pub controllers: Vec<AxisController>,
    status_bytes: Vec<u8>,
    cycle: u64,
}

impl Axes {
    pub fn new(plans: &[AxisPlan], trajectory_capacity: usize) -> Axes {
        Axes {
            controllers: plans
                .iter()
                .map(|p| AxisController::new(p.clone(), trajectory_capacity))
                .collect(),
            status_bytes: vec![0; plans.len() * STATUS_LEN],
            cycle: 0,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.controllers.is_empty()
    }

    /// Run every axis for this cycle and publish their status.
    pub fn step(&mut self, io: &mut [u8], now: i64, cycle_ns: i64, halt: bool, ex: &AxisExchange) {
        if self.controllers.is_empty() {
            return;
        }
        for (i, c) in self.controllers.iter_mut().enumerate() {
            c.step(
                io,
                now,
                cycle_ns,
                halt,
                (&ex.commands[i], &ex.trajectories[i]),
            );
            c.status.cycle = self.cycle;
            c.status
                .encode(&mut self.status_bytes[i * STATUS_LEN..(i + 1) * STATUS_LEN]);
        }
        ex.status.write(0, &self.status_bytes);
        self.cycle += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The drive side of the standard's transition table: the state a drive in `s` goes to on
    /// controlword `cw` (previous controlword `prev`, for the fault reset's rising edge).
    /// Quick stop option code 2 style: Quick Stop Active stays until disable voltage.
    fn drive(s: DriveState, cw: u16, prev: u16) -> DriveState {
        use DriveState::*;
        let bits = cw & 0x8F;
        let disable_voltage = cw & 0x02 == 0;
        let quick_stop = cw & 0x06 == 0x02;
        let shutdown = cw & 0x87 == 0x06;
        let switch_on = cw & 0x8F == 0x07;
        let enable_op = bits == 0x0F;
        match s {
            NotReadyToSwitchOn => SwitchOnDisabled, // 1: automatic
            SwitchOnDisabled if shutdown => ReadyToSwitchOn, // 2
            ReadyToSwitchOn if switch_on => SwitchedOn, // 3
            ReadyToSwitchOn if enable_op => SwitchedOn, // 3 (4 follows next cycle)
            ReadyToSwitchOn if disable_voltage || quick_stop => SwitchOnDisabled, // 7
            SwitchedOn if enable_op => OperationEnabled, // 4
            SwitchedOn if shutdown => ReadyToSwitchOn, // 6
            SwitchedOn if disable_voltage || quick_stop => SwitchOnDisabled, // 10
            OperationEnabled if switch_on => SwitchedOn, // 5
            OperationEnabled if shutdown => ReadyToSwitchOn, // 8
            OperationEnabled if quick_stop => QuickStopActive, // 11
            OperationEnabled if disable_voltage => SwitchOnDisabled, // 9
            QuickStopActive if disable_voltage && !quick_stop => SwitchOnDisabled, // 12
            QuickStopActive if enable_op => OperationEnabled, // 16
            FaultReactionActive => Fault,           // 14
            Fault if cw & 0x80 != 0 && prev & 0x80 == 0 => SwitchOnDisabled, // 15
            other => other,
        }
    }

    fn statusword(s: DriveState) -> u16 {
        use DriveState::*;
        match s {
            NotReadyToSwitchOn => 0x0000,
            SwitchOnDisabled => 0x0040,
            ReadyToSwitchOn => 0x0021,
            SwitchedOn => 0x0023,
            OperationEnabled => 0x0027,
            QuickStopActive => 0x0007,
            FaultReactionActive => 0x000F,
            Fault => 0x0008,
        }
    }

    const CW: usize = 0;
    const MODE: usize = 2;
    const TPOS: usize = 3;
    const TVEL: usize = 7;
    const TTRQ: usize = 11;
    const SW: usize = 13;
    const MODE_D: usize = 15;
    const POS: usize = 16;
    const VEL: usize = 20;
    const ERR: usize = 24;
    const IMG: usize = 26;

    fn plan() -> AxisPlan {
        AxisPlan {
            name: "j1".into(),
            map: AxisMap {
                controlword: CW,
                statusword: SW,
                mode: Some(MODE),
                mode_display: Some(MODE_D),
                target_position: Some(TPOS),
                target_velocity: Some(TVEL),
                target_torque: Some(TTRQ),
                position: Some(POS),
                velocity: Some(VEL),
                torque: None,
                error_code: Some(ERR),
                following_error: None,
            },
            mode: Mode::CyclicPosition,
            position_scale: 0.001,
            position_offset: 0.0,
            velocity_scale: 0.001,
            torque_scale: 0.01,
            limits: Limits {
                position_min: -10.0,
                position_max: 10.0,
                velocity_max: 5.0,
                torque_max: 2.0,
            },
            following_error_window: 0.0,
            on_stop: OnStop::QuickStop,
            fault_reset: FaultReset::Auto,
            fault_retries: 2,
            fault_backoff_ns: 10_000_000,
            interpolation_max_ns: 100_000_000,
        }
    }

    /// One axis against the reference drive: the drive follows the controlword with the
    /// standard's table and, in Operation Enabled, its position follows the target.
    struct Bench {
        axes: Axes,
        ex: AxisExchange,
        io: Vec<u8>,
        state: DriveState,
        prev_cw: u16,
        position_raw: i32,
        now: i64,
        command: AxisCommand,
        error: u16,
        /// Targets written while the drive was not moving on its own.
        targets: Vec<i32>,
    }

    const CYCLE: i64 = 1_000_000;

    impl Bench {
        fn new(plan: AxisPlan, state: DriveState, position_raw: i32) -> Bench {
            let ex = AxisExchange::new(std::slice::from_ref(&plan), 8);
            Bench {
                command: AxisCommand::initial(plan.mode),
                axes: Axes::new(&[plan], 8),
                ex,
                io: vec![0; IMG],
                state,
                prev_cw: 0,
                position_raw,
                now: 1_000_000_000,
                error: 0,
                targets: Vec::new(),
            }
        }

        fn send(&mut self) {
            let mut b = [0u8; COMMAND_LEN];
            self.command.encode(&mut b);
            self.ex.commands[0].write(0, &b);
        }

        fn cycle(&mut self, halt: bool) {
            self.io[SW..SW + 2].copy_from_slice(&statusword(self.state).to_le_bytes());
            self.io[POS..POS + 4].copy_from_slice(&self.position_raw.to_le_bytes());
            self.io[ERR..ERR + 2].copy_from_slice(&self.error.to_le_bytes());
            self.axes
                .step(&mut self.io, self.now, CYCLE, halt, &self.ex);
            let cw = read_u16(&self.io, CW);
            let target = read_i32(&self.io, TPOS);
            self.targets.push(target);
            if self.state == DriveState::OperationEnabled {
                self.position_raw = target;
            }
            self.io[MODE_D] = self.io[MODE];
            self.state = drive(self.state, cw, self.prev_cw);
            self.prev_cw = cw;
            self.now += CYCLE;
        }

        fn run(&mut self, n: usize) {
            for _ in 0..n {
                self.cycle(false);
            }
        }

        fn status(&self) -> AxisStatus {
            AxisStatus::decode(&self.ex.status.read())
        }
    }

    #[test]
    fn statusword_decoding_follows_the_standard() {
        use DriveState::*;
        for s in [
            NotReadyToSwitchOn,
            SwitchOnDisabled,
            ReadyToSwitchOn,
            SwitchedOn,
            OperationEnabled,
            QuickStopActive,
            FaultReactionActive,
            Fault,
        ] {
            // Manufacturer and mode bits (4, 7–15) do not change the state.
            assert_eq!(DriveState::decode(statusword(s)), s);
            assert_eq!(DriveState::decode(statusword(s) | 0xFF90), s, "{s:?}");
        }
        // Bit 5 (quick stop) is "don't care" in Switch On Disabled and Fault.
        assert_eq!(DriveState::decode(0x0060), SwitchOnDisabled);
        assert_eq!(DriveState::decode(0x0028), Fault);
    }

    #[test]
    fn enables_from_every_state_without_moving() {
        use DriveState::*;
        for start in [
            NotReadyToSwitchOn,
            SwitchOnDisabled,
            ReadyToSwitchOn,
            SwitchedOn,
            QuickStopActive,
            FaultReactionActive,
            Fault,
        ] {
            let mut b = Bench::new(plan(), start, 12_345);
            b.command.enable = true;
            b.send();
            b.run(40);
            assert_eq!(b.state, OperationEnabled, "from {start:?}");
            // Never a target other than the actual position: no jump on enabling.
            assert!(
                b.targets.iter().all(|&t| t == 12_345),
                "from {start:?}: {:?}",
                b.targets
            );
            let st = b.status();
            assert_eq!(st.state, OperationEnabled as u8);
            assert_ne!(st.flags & status_flags::MODE_REACHED, 0);
            assert_eq!(b.io[MODE] as i8, 8);
        }
    }

    #[test]
    fn fault_reset_is_a_rising_edge_of_bit_7() {
        let mut b = Bench::new(plan(), DriveState::Fault, 0);
        b.prev_cw = 0x80; // the drive saw bit 7 high already: no edge without a low cycle
        b.command.enable = true;
        b.command.reset_count = 1;
        b.send();
        b.cycle(false);
        assert_eq!(read_u16(&b.io, CW), 0x0000);
        b.cycle(false);
        assert_eq!(read_u16(&b.io, CW), word::FAULT_RESET);
        assert_eq!(b.state, DriveState::SwitchOnDisabled);
        b.run(5);
        assert_eq!(b.state, DriveState::OperationEnabled);
        assert_eq!(b.status().fault_resets, 1);
    }

    #[test]
    fn auto_reset_backs_off_and_gives_up_after_the_retries() {
        let mut b = Bench::new(plan(), DriveState::SwitchOnDisabled, 0);
        b.command.enable = true;
        b.send();
        b.run(10);
        assert_eq!(b.state, DriveState::OperationEnabled);
        // A fault that resets fine: back in Operation Enabled after the back-off (10 ms).
        b.state = DriveState::Fault;
        b.error = 0x7500;
        b.run(5);
        assert_eq!(b.state, DriveState::Fault, "waits for the back-off");
        b.run(20);
        assert_eq!(b.state, DriveState::OperationEnabled);
        let st = b.status();
        assert_eq!(
            (st.faults, st.last_fault_code, st.fault_resets),
            (1, 0x7500, 1)
        );
        // A fault that comes back at every enable: at most fault_retries (2) resets in a row;
        // the first fault's reset already used one (no 2 s in Operation Enabled in between).
        for _ in 0..500 {
            if b.state == DriveState::OperationEnabled {
                b.state = DriveState::FaultReactionActive;
            }
            b.cycle(false);
        }
        let st = b.status();
        assert_eq!((st.faults, st.fault_resets), (3, 2));
        assert_eq!(b.state, DriveState::Fault);
        assert_ne!(b.status().flags & status_flags::RETRIES_EXHAUSTED, 0);
        // A manual reset gives the retries back.
        b.command.reset_count += 1;
        b.send();
        b.run(3);
        assert_ne!(b.state, DriveState::Fault);
    }

    #[test]
    fn manual_policy_waits_for_the_reset() {
        let mut p = plan();
        p.fault_reset = FaultReset::Manual;
        let mut b = Bench::new(p, DriveState::Fault, 0);
        b.command.enable = true;
        b.send();
        b.run(100);
        assert_eq!(b.state, DriveState::Fault);
        b.command.reset_count = 1;
        b.send();
        b.run(10);
        assert_eq!(b.state, DriveState::OperationEnabled);
    }

    #[test]
    fn halt_puts_the_stop_on_the_wire_at_once() {
        for (on_stop, cw, after) in [
            (
                OnStop::QuickStop,
                word::QUICK_STOP,
                DriveState::QuickStopActive,
            ),
            (
                OnStop::Disable,
                word::DISABLE_VOLTAGE,
                DriveState::SwitchOnDisabled,
            ),
        ] {
            let mut p = plan();
            p.on_stop = on_stop;
            let mut b = Bench::new(p, DriveState::SwitchOnDisabled, 0);
            b.command.enable = true;
            b.send();
            b.run(10);
            b.cycle(true);
            assert_eq!(read_u16(&b.io, CW), cw);
            assert_eq!(b.state, after);
            assert_ne!(b.status().flags & status_flags::HALTED, 0);
            // Released: enables again.
            b.run(10);
            assert_eq!(b.state, DriveState::OperationEnabled);
        }
    }

    #[test]
    fn setpoints_are_interpolated_by_arrival_and_held() {
        let mut b = Bench::new(plan(), DriveState::SwitchOnDisabled, 0);
        b.command.enable = true;
        b.send();
        b.run(10);
        // Setpoints every 4 cycles, 0.004 rad apart: 1 mrad = 1 raw per cycle after the first.
        for k in 1..=5 {
            b.command.seq += 1;
            b.command.setpoint_kind = SetpointKind::Position as u8;
            b.command.value = 0.004 * k as f64;
            b.command.t_ns = b.now;
            b.send();
            b.run(4);
        }
        let tail: Vec<i32> = b.targets[b.targets.len() - 12..].to_vec();
        assert_eq!(tail, (8..20).collect::<Vec<i32>>());
        // Held once they stop.
        b.run(10);
        assert_eq!(*b.targets.last().unwrap(), 20);
        assert_eq!(b.status().position_clamps, 0);
    }

    #[test]
    fn setpoints_are_clamped_and_counted() {
        let mut b = Bench::new(plan(), DriveState::SwitchOnDisabled, 0);
        b.command.enable = true;
        b.send();
        b.run(10);
        // Beyond the position limit (10 rad), and a step the velocity limit cannot make at once.
        b.command.seq += 1;
        b.command.setpoint_kind = SetpointKind::Position as u8;
        b.command.value = 50.0;
        b.command.t_ns = b.now;
        b.send();
        b.run(3000);
        // 5 rad/s × 1 ms = 5 raw per cycle at most; ends at the limit.
        let steps: Vec<i32> = b.targets.windows(2).map(|w| w[1] - w[0]).collect();
        assert!(steps.iter().all(|&s| s.abs() <= 5), "{steps:?}");
        assert_eq!(*b.targets.last().unwrap(), 10_000);
        assert!(b.status().position_clamps >= 2000);
        // Velocity and torque limits in their modes.
        b.command.mode = Mode::CyclicVelocity;
        b.command.seq += 1;
        b.command.setpoint_kind = SetpointKind::Velocity as u8;
        b.command.value = -9.0;
        b.send();
        b.run(3);
        assert_eq!(read_i32(&b.io, TVEL), -5000);
        assert!(b.status().velocity_clamps >= 1);
        b.command.mode = Mode::CyclicTorque;
        b.command.seq += 1;
        b.command.setpoint_kind = SetpointKind::Torque as u8;
        b.command.value = 3.0;
        b.send();
        b.run(3);
        assert_eq!(read_i16(&b.io, TTRQ), 200);
        assert!(b.status().torque_clamps >= 1);
    }

    #[test]
    fn targets_wait_for_the_mode_display() {
        let mut b = Bench::new(plan(), DriveState::SwitchOnDisabled, 0);
        b.command.enable = true;
        b.send();
        b.run(10);
        b.command.mode = Mode::CyclicVelocity;
        b.command.seq += 1;
        b.command.setpoint_kind = SetpointKind::Velocity as u8;
        b.command.value = 1.0;
        b.send();
        // First cycle: 0x6060 = 9 written, 0x6061 still shows 8: no velocity target yet.
        b.cycle(false);
        assert_eq!(b.io[MODE], 9);
        assert_eq!(read_i32(&b.io, TVEL), 0);
        b.cycle(false);
        assert_eq!(read_i32(&b.io, TVEL), 1000);
    }

    #[test]
    fn trajectories_run_on_the_engine_clock() {
        let mut b = Bench::new(plan(), DriveState::SwitchOnDisabled, 0);
        b.command.enable = true;
        b.send();
        b.run(10);
        // 0 → 0.1 rad in 100 ms → 0.05 rad at 200 ms, velocity 0 at the points.
        let pts = [
            Point {
                t_ns: 0,
                position: 0.0,
                velocity: 0.0,
            },
            Point {
                t_ns: 100_000_000,
                position: 0.1,
                velocity: 0.0,
            },
            Point {
                t_ns: 200_000_000,
                position: 0.05,
                velocity: 0.0,
            },
        ];
        let mut bytes = vec![0u8; TRAJECTORY_HEADER + 8 * POINT_LEN];
        for (p, c) in pts
            .iter()
            .zip(bytes[TRAJECTORY_HEADER..].chunks_exact_mut(POINT_LEN))
        {
            p.encode(c);
        }
        b.command.seq += 1;
        bytes[..8].copy_from_slice(&b.command.seq.to_le_bytes());
        b.ex.trajectories[0].write(0, &bytes);
        b.command.setpoint_kind = 0;
        b.command.trajectory_len = 3;
        b.command.t_ns = b.now + 10 * CYCLE;
        let start = b.targets.len() + 10;
        b.send();
        b.run(270);
        let at = |ms: usize| b.targets[start + ms];
        assert_eq!(at(0), 0);
        assert_eq!(at(50), 50, "half way at half time (symmetric Hermite)");
        assert_eq!(at(100), 100);
        assert_eq!(at(150), 75);
        assert_eq!(at(200), 50);
        assert_eq!(at(250), 50, "held at the last point");
        assert_ne!(b.status().flags & status_flags::TRAJECTORY_DONE, 0);
    }

    #[test]
    fn profile_position_hands_the_target_over_with_the_new_setpoint_bit() {
        let mut p = plan();
        p.mode = Mode::ProfilePosition;
        let mut b = Bench::new(p, DriveState::SwitchOnDisabled, 0);
        b.command.enable = true;
        b.send();
        b.run(10);
        b.command.seq += 1;
        b.command.setpoint_kind = SetpointKind::Position as u8;
        b.command.value = 2.0;
        b.command.t_ns = b.now;
        b.send();
        b.cycle(false);
        // The whole target with bit 4 (new set-point) and bit 5 (change immediately) at once.
        assert_eq!(read_i32(&b.io, TPOS), 2000);
        assert_eq!(read_u16(&b.io, CW), 0x000F | 0x0030);
        b.cycle(false);
        assert_eq!(
            read_u16(&b.io, CW) & 0x0010,
            0x0010,
            "held until acknowledged"
        );
        // The drive acknowledges (statusword bit 12): bit 4 drops.
        let mut io = b.io.clone();
        io[SW..SW + 2].copy_from_slice(&(0x0027u16 | word::SETPOINT_ACK).to_le_bytes());
        b.axes.step(&mut io, b.now, CYCLE, false, &b.ex);
        assert_eq!(read_u16(&io, CW) & 0x0010, 0);
    }

    #[test]
    fn interpolator_holds_and_spans_by_arrival() {
        let mut i = Interpolator::default();
        i.reset(1.0);
        assert_eq!(i.value(123), 1.0);
        i.push(2.0, 1000, 10, 10_000);
        assert_eq!(i.value(1000), 1.0);
        assert_eq!(i.value(1005), 1.5);
        assert_eq!(i.value(1010), 2.0);
        i.push(4.0, 2000, 10, 10_000);
        // Span 1000 (since the previous arrival): half-way at +500.
        assert_eq!(i.value(2500), 3.0);
        assert_eq!(i.value(9999), 4.0);
        // A long pause is capped at max_span.
        i.push(5.0, 100_000, 10, 10_000);
        assert_eq!(i.value(110_000), 5.0);
    }

    #[test]
    fn records_round_trip() {
        let c = AxisCommand {
            enable: true,
            mode: Mode::CyclicTorque,
            reset_count: 7,
            seq: 99,
            setpoint_kind: 3,
            value: -1.25,
            t_ns: 123_456_789,
            trajectory_len: 12,
        };
        let mut b = [0u8; COMMAND_LEN];
        c.encode(&mut b);
        assert_eq!(AxisCommand::decode(&b), c);
        let s = AxisStatus {
            cycle: 5,
            statusword: 0x1237,
            controlword: 0x000F,
            state: 4,
            mode_display: -3,
            flags: 0x41,
            error_code: 0x8611,
            last_fault_code: 0x7500,
            position_raw: -5,
            velocity_raw: 6,
            torque_raw: -7,
            following_error_raw: 8,
            target_position_raw: -9,
            position: 1.5,
            velocity: -2.5,
            torque: 3.5,
            following_error: 0.25,
            target_position: 1.75,
            position_clamps: 1,
            velocity_clamps: 2,
            torque_clamps: 3,
            faults: 4,
            fault_resets: 5,
            command_seq: 6,
        };
        let mut b = [0u8; STATUS_LEN];
        s.encode(&mut b);
        assert_eq!(AxisStatus::decode(&b), s);
    }

    #[test]
    fn bad_axes_are_refused_by_name() {
        let outs = [(0usize, 13usize)];
        assert_eq!(plan().validate(IMG, &outs), Ok(()));
        let mut p = plan();
        p.position_scale = 0.0;
        assert!(p
            .validate(IMG, &outs)
            .unwrap_err()
            .contains("position_scale"));
        let mut p = plan();
        p.limits.position_min = 20.0;
        assert!(p.validate(IMG, &outs).unwrap_err().contains("min <= max"));
        let mut p = plan();
        p.limits.velocity_max = f64::NAN;
        assert!(p.validate(IMG, &outs).unwrap_err().contains("velocity_max"));
        let mut p = plan();
        p.map.statusword = 2;
        assert!(p.validate(IMG, &outs).unwrap_err().contains("statusword"));
        let mut p = plan();
        p.map.target_position = None;
        assert!(p.validate(IMG, &outs).unwrap_err().contains("target"));
    }
}
