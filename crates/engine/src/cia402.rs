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

mod motion;
mod records;

pub use motion::{
    blend, braking_speed, limit_torque, limit_velocity, sample_trajectory, sample_velocity,
    CstLimiter, Interpolator, StopRamp,
};
pub use records::{
    status_flags, AxisCommand, AxisExchange, AxisGate, AxisStatus, Point, COMMAND_LEN, POINT_LEN,
    STATUS_LEN, TRAJECTORY_HEADER,
};

use crate::handover::SeqBuffer;

/// The standard's facts — controlword and statusword bits, device control commands, the
/// states and their statusword coding, the modes — are the protocol crate's.
pub use ether_ros_protocol::cia402::{command, cw, sw, Mode, State as DriveState};

/// The state a statusword shows; codings the standard leaves undefined count as Not Ready to
/// Switch On (nothing is enabled).
pub fn drive_state(statusword: u16) -> DriveState {
    DriveState::from_statusword(statusword).unwrap_or(DriveState::NotReadyToSwitchOn)
}

/// Which kind of setpoint a mode takes (None: homing takes none).
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
/// What a setpoint command sets: the code travels in the command slot (`AxisCommand::setpoint_kind`).
pub enum SetpointKind {
    /// A position setpoint (position modes).
    Position = 1,
    /// A velocity setpoint (velocity modes).
    Velocity = 2,
    /// A torque setpoint (torque modes).
    Torque = 3,
}

impl SetpointKind {
    /// The kind of a command slot code; None for 0 (a trajectory) and unknown codes.
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
/// What the engine commands the drive when the axis is to stop (disable, panic, watchdog).
pub enum OnStop {
    /// Controlword "quick stop": the drive ramps down per its 0x605A quick stop option code.
    QuickStop,
    /// Controlword "disable voltage": the power stage switches off at once.
    Disable,
}

impl OnStop {
    fn controlword(self) -> u16 {
        match self {
            OnStop::QuickStop => command::QUICK_STOP,
            OnStop::Disable => command::DISABLE_VOLTAGE,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// What happens after the drive reports a fault.
pub enum FaultReset {
    /// Reset and re-enable after a back-off, at most `fault_retries` times in a row.
    Auto,
    /// Stay in Fault until a reset is asked for.
    Manual,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
/// Whether an axis that stopped by itself may resume without a deliberate enable.
pub enum Restart {
    /// After a panic, a watchdog stop, a fault (reset automatically or not) or any other stop
    /// the drive made by itself, the axis stays out of Operation Enabled until an explicit
    /// enable (IEC 60204-1: no restart without a deliberate action).
    Manual,
    /// The axis goes back to Operation Enabled by itself once the cause is gone, unless it is
    /// outside its position limits then.
    Auto,
}

/// The velocity a mode change (or an enable) starts the new mode's quiet stop from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ModeChangeVelocity {
    /// The actual velocity: the axis decelerates from it at `deceleration`.
    Actual,
    /// Zero: the drive stops the axis as fast as it can.
    Zero,
}

/// Byte offsets in the process image of the axis's objects (None: not mapped). Sizes are the
/// standard's: controlword/statusword/error code u16, modes i8, positions, velocities and the
/// following error i32, torques i16.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AxisMap {
    /// Controlword (0x6040).
    pub controlword: usize,
    /// Statusword (0x6041).
    pub statusword: usize,
    /// Modes of operation (0x6060).
    pub mode: Option<usize>,
    /// Modes of operation display (0x6061).
    pub mode_display: Option<usize>,
    /// Target position (0x607A).
    pub target_position: Option<usize>,
    /// Target velocity (0x60FF).
    pub target_velocity: Option<usize>,
    /// Target torque (0x6071).
    pub target_torque: Option<usize>,
    /// Position actual value (0x6064).
    pub position: Option<usize>,
    /// Velocity actual value (0x606C).
    pub velocity: Option<usize>,
    /// Torque actual value (0x6077).
    pub torque: Option<usize>,
    /// Error code (0x603F).
    pub error_code: Option<usize>,
    /// Following error actual value (0x60F4).
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
    /// Lowest position (SI).
    pub position_min: f64,
    /// Highest position (SI).
    pub position_max: f64,
    /// Largest |velocity|; also bounds the CSP target's step per cycle.
    pub velocity_max: f64,
    /// Largest |torque| (SI).
    pub torque_max: f64,
}

#[derive(Clone, Debug, PartialEq)]
/// Everything the RT thread needs to drive one CiA 402 axis: where its objects are in the
/// image, its scaling, limits and policies. Built once from the configuration.
pub struct AxisPlan {
    /// The axis name, for messages and statistics.
    pub name: String,
    /// Where the axis's objects sit in the process image.
    pub map: AxisMap,
    /// The mode commanded at start.
    pub mode: Mode,
    /// SI units per raw position unit: position = raw × position_scale + position_offset.
    pub position_scale: f64,
    /// SI position of raw position 0.
    pub position_offset: f64,
    /// SI units per raw velocity unit.
    pub velocity_scale: f64,
    /// SI units per raw torque unit.
    pub torque_scale: f64,
    /// The limits setpoints are clamped to.
    pub limits: Limits,
    /// Deceleration (SI/s², > 0) of the quiet stop a mode change or an enable starts with, and
    /// of the braking envelope before the position limits in csv, pv and cst; ∞: at once.
    pub deceleration: f64,
    /// Largest change of the commanded velocity (SI/s², > 0): every hand-over (a new
    /// trajectory, setpoints after a trajectory, a jump of the setpoint) is joined from the
    /// commanded state within it, in csp (the targets' second difference) and csv (the velocity
    /// target's step); ∞: only the velocity limit bounds the step.
    pub max_acceleration: f64,
    /// How fast the axis may be moving for a mode change to be accepted.
    pub mode_change_velocity: ModeChangeVelocity,
    /// Whether the axis may resume by itself after a stop it did not command.
    pub restart: Restart,
    /// |following error| above this (SI) sets the status flag; 0 = not checked.
    pub following_error_window: f64,
    /// What the engine commands the drive when the axis is to stop.
    pub on_stop: OnStop,
    /// What happens after a fault.
    pub fault_reset: FaultReset,
    /// Automatic resets in a row before giving up (auto policy).
    pub fault_retries: u32,
    /// Wait before the first automatic reset; doubled for every further one.
    pub fault_backoff_ns: i64,
    /// Longest span a CSP setpoint is interpolated over (the time since the previous one,
    /// capped at this).
    pub interpolation_max_ns: i64,
}

/// `AxisCommand::setpoint_kind` of a trajectory (its points are in the axis's slot).
pub const TRAJECTORY_COMMAND: u8 = 0;
/// `AxisCommand::setpoint_kind` of a quiet stop (`Engine::axis_stop`).
pub const STOP_COMMAND: u8 = 4;

/// Points per axis trajectory unless the plan says otherwise.
pub const DEFAULT_TRAJECTORY_CAPACITY: usize = 1024;
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
            ("deceleration", self.deceleration),
            ("max_acceleration", self.max_acceleration),
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

    fn inside_limits(&self, position: f64) -> bool {
        (self.limits.position_min..=self.limits.position_max).contains(&position)
    }
}

fn saturate_i32(v: f64) -> i32 {
    v.round().clamp(i32::MIN as f64, i32::MAX as f64) as i32
}

fn saturate_i16(v: f64) -> i16 {
    v.round().clamp(i16::MIN as f64, i16::MAX as f64) as i16
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

/// A target written now takes effect this many cycles after the actual values it is computed
/// from were sampled (the inputs read were latched a cycle or two ago, the drive latches the
/// target at its next SYNC0 and, in csp, interpolates over one more period): position targets
/// that follow a moving axis, and the braking envelope, look that far ahead.
const COMMAND_LATENCY_CYCLES: f64 = 3.0;
/// Cycles after a homing start before the drive's homing bits count: the statuswords of the
/// frames in flight were latched before the drive saw the start.
const HOMING_ACK_CYCLES: u32 = 5;
/// Operation Enabled this long without a fault gives the automatic reset its retries back.
const FAULT_RETRY_RESET_NS: i64 = 2_000_000_000;

/// The drive as read from the process image this cycle (SI units where it has them).
#[derive(Clone, Copy, Debug)]
struct Feedback {
    statusword: u16,
    state: DriveState,
    position_raw: i32,
    position: f64,
    velocity_raw: i32,
    velocity: f64,
    mode_display: i8,
    error_code: u16,
}

/// The controller of one axis: RT-thread state between cycles.
pub struct AxisController {
    /// The axis's plan (fixed for the run).
    pub plan: AxisPlan,
    command: AxisCommand,
    /// The mode of the previous cycle's command: a change starts the new mode afresh.
    mode_commanded: Mode,
    /// Trajectory points loaded for a command that has not started yet (capacity + 1: room
    /// for the point the start splices in).
    staged: Vec<Point>,
    staged_len: usize,
    staged_seq: Option<u64>,
    point_bytes: Vec<u8>,
    /// The running trajectory: `points[points_first..points_len]`, times from `trajectory_start`.
    points: Vec<Point>,
    points_first: usize,
    points_len: usize,
    trajectory_start: i64,
    trajectory_running: bool,
    /// The last trajectory ran to its end (until the next command).
    trajectory_done: bool,
    /// The trajectory `stopped_seq` ended before its end without a newer command (until the
    /// next command): `status_flags::TRAJECTORY_STOPPED`.
    trajectory_stopped: bool,
    stopped_seq: u64,
    /// This cycle ended the trajectory with this seq early (for `Axes::step`, which stops the
    /// other axes it was given together with).
    stop_event: Option<u64>,
    cursor: usize,
    interpolator: Interpolator,
    /// The quiet stop a mode change or an enable starts with (until the first command).
    ramp: Option<StopRamp>,
    /// The old mode's quiet stop while the drive has not shown the new mode yet.
    switch_ramp: Option<StopRamp>,
    /// The first running cycle after an enable or a mode change has yet to come.
    entry_pending: bool,
    /// Last position target written (SI) and the velocity the axis is commanded to have.
    target_position: f64,
    desired_velocity: f64,
    /// csp: the velocity of the last target step as it went on the wire ((target − the one
    /// before) / cycle): what the acceleration limit bounds the change of (`blend`).
    step_velocity: f64,
    /// cst: the velocity limit and braking envelope on the predicted speed.
    cst: CstLimiter,
    /// The last velocity or torque setpoint of the current mode (SI).
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
    /// The axis stopped by itself (panic, watchdog, fault, the drive left Operation Enabled)
    /// while wanted enabled: the `enable_count` of that moment. A restart needs a newer one
    /// (restart: manual), or the axis inside its limits (restart: auto).
    stopped_at: Option<u32>,
    previous_state: DriveState,
    was_halted: bool,
    enable_count_seen: u32,
    enable_wanted_before: bool,
    /// pp: a new set-point waits for the drive's acknowledge.
    pp_new_setpoint: bool,
    /// hm: the last homing start taken over, a run under way and its cycles so far.
    homing_seen: u32,
    homing_active: bool,
    homing_cycles: u32,
    /// What the controller published last cycle.
    pub status: AxisStatus,
}

impl AxisController {
    /// A controller for `plan`, with room for trajectories of `trajectory_capacity` points.
    pub fn new(plan: AxisPlan, trajectory_capacity: usize) -> AxisController {
        let command = AxisCommand::initial(plan.mode);
        AxisController {
            command,
            mode_commanded: plan.mode,
            staged: vec![Point::default(); trajectory_capacity + 1],
            staged_len: 0,
            staged_seq: None,
            point_bytes: vec![0; TRAJECTORY_HEADER + trajectory_capacity * POINT_LEN],
            points: vec![Point::default(); trajectory_capacity + 1],
            points_first: 0,
            points_len: 0,
            trajectory_start: 0,
            trajectory_running: false,
            trajectory_done: false,
            trajectory_stopped: false,
            stopped_seq: 0,
            stop_event: None,
            cursor: 0,
            interpolator: Interpolator::default(),
            ramp: None,
            switch_ramp: None,
            entry_pending: true,
            target_position: 0.0,
            desired_velocity: 0.0,
            step_velocity: 0.0,
            cst: CstLimiter::default(),
            setpoint_value: 0.0,
            seq_seen: 0,
            reset_seen: 0,
            reset_pending: false,
            reset_phase: 0,
            in_fault: false,
            fault_since: 0,
            retries: 0,
            operation_enabled_since: None,
            stopped_at: None,
            previous_state: DriveState::NotReadyToSwitchOn,
            was_halted: false,
            enable_count_seen: 0,
            enable_wanted_before: false,
            pp_new_setpoint: false,
            homing_seen: 0,
            homing_active: false,
            homing_cycles: 0,
            status: AxisStatus::default(),
            plan,
        }
    }

    /// The trajectory command waiting to start (its seq), if any.
    fn pending_trajectory(&self) -> Option<u64> {
        let c = &self.command;
        (c.setpoint_kind == TRAJECTORY_COMMAND && c.seq != self.seq_seen && c.seq != 0)
            .then_some(c.seq)
    }

    /// Load the points of a pending trajectory from the axis's slot (a write in progress or
    /// points of another command: try again next cycle).
    fn stage_trajectory(&mut self, slot: &SeqBuffer) {
        let Some(seq) = self.pending_trajectory() else {
            return;
        };
        if self.staged_seq == Some(seq) {
            return;
        }
        let n = (self.command.trajectory_len as usize).min(self.staged.len() - 1);
        let bytes = &mut self.point_bytes[..TRAJECTORY_HEADER + n * POINT_LEN];
        let header = |b: &[u8]| u64::from_le_bytes(b[..TRAJECTORY_HEADER].try_into().unwrap());
        if slot.try_read(bytes).is_some() && header(bytes) == seq && n > 0 {
            for (p, b) in self.staged[..n]
                .iter_mut()
                .zip(bytes[TRAJECTORY_HEADER..].chunks_exact(POINT_LEN))
            {
                *p = Point::decode(b);
            }
            self.staged_len = n;
            self.staged_seq = Some(seq);
        }
    }

    fn read_feedback(&self, io: &[u8]) -> Feedback {
        let map = self.plan.map;
        let statusword = read_u16(io, map.statusword);
        let position_raw = map.position.map_or(0, |o| read_i32(io, o));
        let velocity_raw = map.velocity.map_or(0, |o| read_i32(io, o));
        Feedback {
            statusword,
            state: drive_state(statusword),
            position_raw,
            position: self.plan.position_si(position_raw),
            velocity_raw,
            velocity: velocity_raw as f64 * self.plan.velocity_scale,
            mode_display: map
                .mode_display
                .map_or(self.command.mode as i8, |o| io[o] as i8),
            error_code: map.error_code.map_or(0, |o| read_u16(io, o)),
        }
    }

    /// Faults: count each, note its code, decide on resets. Returns true on the cycle a fault
    /// begins.
    fn supervise_faults(&mut self, fb: &Feedback, now: i64, halt: bool) -> bool {
        let cmd = self.command;
        let st = &mut self.status;
        if cmd.reset_count != self.reset_seen {
            // A reset asked for gives the automatic reset its retries back; it resets a fault
            // that is there now, not one that may come later.
            self.reset_seen = cmd.reset_count;
            self.reset_pending = fb.state.is_fault();
            self.retries = 0;
        }
        let mut began = false;
        if fb.state.is_fault() {
            if !self.in_fault {
                self.in_fault = true;
                began = true;
                self.fault_since = now;
                st.faults += 1;
                st.last_fault_code = fb.error_code;
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
        if fb.state == DriveState::OperationEnabled {
            let since = *self.operation_enabled_since.get_or_insert(now);
            if now - since >= FAULT_RETRY_RESET_NS {
                self.retries = 0;
            }
        } else {
            self.operation_enabled_since = None;
        }
        began
    }

    /// Deliberate restart: is the axis kept out of Operation Enabled until an explicit enable?
    fn restart_blocked(&mut self, fb: &Feedback, halt: bool, fault_began: bool) -> bool {
        let cmd = self.command;
        // The enable count the previous cycle saw: an enable that arrives with the end of a
        // halt (an axis command feeds the watchdog, so it ends a watchdog stop) is newer.
        let before = self.enable_count_seen;
        self.enable_count_seen = cmd.enable_count;
        let was_wanted = self.enable_wanted_before;
        self.enable_wanted_before = cmd.enable;
        if !cmd.enable {
            self.stopped_at = None;
        } else {
            // Stops the axis made without being asked: panic or watchdog (when it begins,
            // while it lasts and when it ends), a fault that hit an axis wanted enabled, the
            // drive leaving Operation Enabled by itself. An enable given before the stop or
            // while it lasted does not restart the axis after it.
            let left_by_itself = self.previous_state == DriveState::OperationEnabled
                && fb.state != DriveState::OperationEnabled
                && !halt;
            let fault_stop = fault_began && was_wanted && before == cmd.enable_count;
            let halt_edge = halt != self.was_halted;
            if halt_edge || fault_stop || left_by_itself || halt && self.stopped_at.is_none() {
                self.stopped_at = Some(before);
            }
        }
        self.was_halted = halt;
        self.previous_state = fb.state;
        match self.stopped_at {
            Some(c) if c != cmd.enable_count => {
                self.stopped_at = None; // enabled explicitly since
                false
            }
            Some(_) if fb.state == DriveState::OperationEnabled && !halt => {
                // Never left (a stop request that came and went before the drive acted).
                self.stopped_at = None;
                false
            }
            Some(_) => {
                self.plan.restart == Restart::Manual || !self.plan.inside_limits(fb.position)
            }
            None => false,
        }
    }

    /// The first running cycle of a mode (after a mode change or an enable): start from the
    /// actual state, with a quiet stop from the actual (or zero) velocity.
    fn enter_mode(&mut self, fb: &Feedback, dt: f64) {
        self.entry_pending = false;
        let vmax = self.plan.limits.velocity_max;
        // After a mode change: where the old motion's quiet stop is now (the drive may have
        // been following it for a cycle or two already). After an enable: the actual state,
        // the position where the axis is when the drive takes the first target.
        let (p0, v0) = match self.switch_ramp.take() {
            Some(r) => (r.position, r.velocity),
            None => (
                fb.position + fb.velocity * dt * COMMAND_LATENCY_CYCLES,
                match self.plan.mode_change_velocity {
                    ModeChangeVelocity::Actual => fb.velocity.clamp(-vmax, vmax),
                    ModeChangeVelocity::Zero => 0.0,
                },
            ),
        };
        self.interpolator.reset(p0);
        self.target_position = p0;
        self.setpoint_value = 0.0;
        self.cst.restart();
        self.desired_velocity = 0.0;
        self.step_velocity = v0;
        self.trajectory_running = false;
        self.ramp = match self.command.mode {
            Mode::CyclicPosition | Mode::CyclicVelocity | Mode::ProfileVelocity if v0 != 0.0 => {
                Some(StopRamp {
                    position: p0,
                    velocity: v0,
                })
            }
            _ => None,
        };
    }

    /// Start the staged trajectory: it continues from the state the axis is commanded to have
    /// now (a point spliced in at this cycle), points already past are dropped.
    fn start_trajectory(&mut self, now: i64, cycle_ns: i64, fb: &Feedback) {
        std::mem::swap(&mut self.points, &mut self.staged);
        let len = self.staged_len;
        self.staged_seq = None;
        self.trajectory_start = self.command.t_ns;
        // The spliced point is the target sent last cycle, at that cycle's time. Points not after
        // this cycle are past or present (trimmed): a first point at "now" (time 0 of a goal
        // stamped now, taken over in the cycle it was sent) is the state the client believed
        // the axis to be in — possibly stale — and the axis's commanded state replaces it, so a
        // hand-over never steers back to it (issue 24).
        let t_splice = now - cycle_ns - self.trajectory_start;
        let t_now = now - self.trajectory_start;
        let mut k = self.points[..len]
            .iter()
            .position(|p| p.t_ns > t_now)
            .unwrap_or(len);
        if k == len {
            // Over already: its end, reached at the velocity limit's pace from here.
            k = len - 1;
            self.points[k].t_ns = t_splice + 2 * cycle_ns;
            self.points[k].velocity = 0.0;
        }
        let first = if k == 0 {
            self.points.copy_within(0..len, 1);
            self.points_len = len + 1;
            0
        } else {
            self.points_len = len;
            k - 1
        };
        let position = match setpoint_kind(self.command.mode) {
            Some(SetpointKind::Position) => self.target_position,
            _ => fb.position,
        };
        self.points[first] = Point {
            t_ns: t_splice.min(self.points[first + 1].t_ns - 1),
            position,
            velocity: self.desired_velocity,
        };
        self.points_first = first;
        self.cursor = 0;
        self.trajectory_running = true;
        self.trajectory_done = false;
        self.ramp = None;
    }

    /// A setpoint command of `kind` taken over in the running mode.
    fn apply_setpoint(&mut self, kind: SetpointKind, cycle_ns: i64) {
        let cmd = self.command;
        if self.trajectory_running || self.ramp.is_some() {
            // The interpolation continues from the target the trajectory or ramp reached.
            self.interpolator.reset(self.target_position);
        }
        self.trajectory_running = false;
        self.trajectory_done = false;
        self.ramp = None;
        match (kind, cmd.mode) {
            (SetpointKind::Position, Mode::ProfilePosition) => {
                // The drive plans the motion itself and latches the target with the new
                // set-point bit: hand it over whole, not interpolated.
                self.interpolator.reset(cmd.value);
                self.pp_new_setpoint = true;
            }
            (SetpointKind::Position, _) => {
                self.interpolator.push(
                    cmd.value,
                    cmd.t_ns,
                    cycle_ns,
                    self.plan.interpolation_max_ns,
                );
            }
            _ => self.setpoint_value = cmd.value,
        }
    }

    /// A quiet stop asked for: from the state the axis is commanded to have, decelerate to rest
    /// at `deceleration` (csp, csv, pv: a ramp; pp: a set-point where that ramp ends; cst: zero
    /// torque), then hold. Ends a trajectory or a setpoint stream.
    fn quiet_stop(&mut self) {
        let ramp = StopRamp {
            position: self.target_position,
            velocity: self.desired_velocity,
        };
        self.trajectory_running = false;
        self.trajectory_done = false;
        self.setpoint_value = 0.0;
        self.interpolator.reset(self.target_position);
        self.ramp = None;
        match self.command.mode {
            Mode::CyclicPosition | Mode::CyclicVelocity | Mode::ProfileVelocity => {
                self.ramp = (ramp.velocity != 0.0).then_some(ramp);
            }
            Mode::ProfilePosition => {
                let rest = ramp
                    .rest_position(self.plan.deceleration)
                    .clamp(self.plan.limits.position_min, self.plan.limits.position_max);
                self.interpolator.reset(rest);
                self.pp_new_setpoint = true;
            }
            Mode::CyclicTorque | Mode::Homing => {}
        }
    }

    /// Another axis of the trajectory `seq` left the state it needs (`stop_event`): this one
    /// must not go on with it alone. Running it: a quiet stop from the state it is commanded to
    /// have (never a jump). Not started yet: it never starts (a quiet stop ends whatever ran
    /// before it, as the new command would have).
    fn stop_with_peer(&mut self, seq: u64) {
        if self.trajectory_running && self.seq_seen == seq {
            self.quiet_stop();
        } else if self.pending_trajectory() == Some(seq) {
            self.seq_seen = seq;
            self.staged_seq = None;
            self.quiet_stop();
        } else {
            return;
        }
        self.trajectory_stopped = true;
        self.stopped_seq = seq;
    }

    /// One cycle: read the drive from `io` (inputs last received), write controlword, mode and
    /// targets into `io`'s outputs. `halt`: panic or watchdog, the stop is forced. `start_ok`:
    /// a pending trajectory may start (its points, and those of every axis that shares it,
    /// are loaded).
    pub fn step(&mut self, io: &mut [u8], now: i64, cycle_ns: i64, halt: bool, start_ok: bool) {
        let fb = self.read_feedback(io);
        let cmd = self.command;
        // The trajectory running or waiting to start before this cycle: if this cycle ends it
        // without its end or a newer command, the axes it was given with must stop too.
        let running_seq = self.trajectory_running.then_some(self.seq_seen);
        let pending_seq = self.pending_trajectory();
        let dt = cycle_ns as f64 * 1e-9;
        let vmax = self.plan.limits.velocity_max;
        // Where the axis will be when the drive takes a target written now (moving, it is
        // ahead of the position read).
        let ahead = fb.position + fb.velocity * dt * COMMAND_LATENCY_CYCLES;
        if cmd.mode != self.mode_commanded {
            // A new mode starts from the actual state once the drive shows it. Until then the
            // drive runs the old mode: its targets make a quiet stop from the actual state.
            self.mode_commanded = cmd.mode;
            self.entry_pending = true;
            self.trajectory_running = false;
            self.ramp = None;
            self.pp_new_setpoint = false;
            // The old motion continues open loop from here (a target re-read from the moving
            // axis every cycle would chase it through the loop's latency).
            let (position, velocity) = if fb.mode_display == Mode::CyclicPosition as i8 {
                (self.target_position, self.desired_velocity)
            } else {
                (ahead, fb.velocity)
            };
            self.switch_ramp = Some(StopRamp {
                position,
                velocity: match self.plan.mode_change_velocity {
                    ModeChangeVelocity::Actual => velocity.clamp(-vmax, vmax),
                    ModeChangeVelocity::Zero => 0.0,
                },
            });
        }
        let mode_reached = fb.mode_display == cmd.mode as i8;
        let fault_began = self.supervise_faults(&fb, now, halt);
        let blocked = self.restart_blocked(&fb, halt, fault_began);
        let enable = cmd.enable && !halt && !blocked;

        // The controlword.
        let mut cw = if fb.state == DriveState::Fault && self.reset_pending {
            // Rising edge of bit 7: one cycle low, then high until the drive leaves Fault.
            if self.reset_phase == 0 {
                self.reset_phase = 1;
                command::DISABLE_VOLTAGE
            } else {
                self.reset_phase = 2;
                command::FAULT_RESET
            }
        } else if !enable {
            self.plan.on_stop.controlword()
        } else {
            match fb.state {
                DriveState::SwitchOnDisabled => command::SHUTDOWN,
                DriveState::ReadyToSwitchOn => command::SWITCH_ON,
                DriveState::SwitchedOn | DriveState::OperationEnabled => command::ENABLE_OPERATION,
                // Back through Switch On Disabled (transition 12) and up again.
                DriveState::QuickStopActive => command::DISABLE_VOLTAGE,
                DriveState::NotReadyToSwitchOn
                | DriveState::FaultReactionActive
                | DriveState::Fault => command::DISABLE_VOLTAGE,
            }
        };

        // Targets. Until the drive runs the commanded mode in Operation Enabled, every target
        // follows the actual state, so neither an enable nor a mode change moves the axis.
        let running = fb.state == DriveState::OperationEnabled && enable && mode_reached;
        // Enabled, only the mode display is not there yet: commands wait for it.
        let waiting_for_mode = fb.state == DriveState::OperationEnabled && enable && !mode_reached;
        let limits = self.plan.limits;
        let decel = self.plan.deceleration;
        let mut velocity_target = 0.0;
        let mut torque_target = 0.0;
        let mut limit_active = false;
        let mut idle = true;
        if !running {
            self.target_position = fb.position;
            self.desired_velocity = 0.0;
            self.step_velocity = 0.0;
            if !waiting_for_mode {
                // Commands given while the axis cannot run are dropped, so that enabling
                // never starts a motion that was asked for before.
                self.seq_seen = cmd.seq;
                self.switch_ramp = None;
            } else {
                // The drive still shows the old mode: its targets continue from where they
                // were with a quiet stop (a position mode's target would otherwise fall
                // behind the moving axis, a velocity mode's drop to zero at once).
                let r = self.switch_ramp.get_or_insert(StopRamp {
                    position: fb.position,
                    velocity: 0.0,
                });
                r.advance(decel, dt);
                // The drive takes whichever target its new mode uses in the cycle it
                // switches: both continue the old motion.
                self.target_position = r.position;
                velocity_target = r.velocity;
                self.desired_velocity = r.velocity;
                self.step_velocity = r.velocity;
            }
            // Whatever ran ends; the mode starts afresh from the actual state once it runs.
            self.setpoint_value = 0.0;
            self.cst.restart();
            self.entry_pending = true;
            self.interpolator.reset(self.target_position);
            self.trajectory_running = false;
            self.ramp = None;
            self.pp_new_setpoint = false;
        } else {
            if self.entry_pending {
                self.enter_mode(&fb, dt);
            }
            if cmd.seq != self.seq_seen {
                match SetpointKind::from_code(cmd.setpoint_kind) {
                    // A trajectory starts once its points (and those of every axis it was
                    // given together with) are loaded.
                    None if cmd.setpoint_kind == TRAJECTORY_COMMAND
                        && start_ok
                        && self.staged_seq == Some(cmd.seq) =>
                    {
                        self.seq_seen = cmd.seq;
                        if matches!(cmd.mode, Mode::CyclicPosition | Mode::CyclicVelocity) {
                            self.start_trajectory(now, cycle_ns, &fb);
                        }
                    }
                    None if cmd.setpoint_kind == STOP_COMMAND => {
                        self.seq_seen = cmd.seq;
                        self.quiet_stop();
                    }
                    None => {}
                    Some(kind) => {
                        self.seq_seen = cmd.seq;
                        self.trajectory_done = false;
                        if setpoint_kind(cmd.mode) == Some(kind) {
                            self.apply_setpoint(kind, cycle_ns);
                        }
                    }
                }
            }
            let st = &mut self.status;
            let amax = self.plan.max_acceleration;
            // A quiet stop is a motion of its own at `deceleration` from the commanded state:
            // the acceleration limit does not slow it down.
            let stopping = self.ramp.is_some();
            match cmd.mode {
                Mode::CyclicPosition | Mode::ProfilePosition => {
                    let (wanted, velocity) = if self.trajectory_running {
                        let (p, v, done) = sample_trajectory(
                            &self.points[self.points_first..self.points_len],
                            now - self.trajectory_start,
                            &mut self.cursor,
                        );
                        self.trajectory_running = !done;
                        self.trajectory_done = done;
                        if done {
                            self.interpolator.reset(p);
                        }
                        (p, v)
                    } else if let Some(r) = self.ramp.as_mut() {
                        r.advance(decel, dt);
                        let (p, v) = (r.position, r.velocity);
                        if v == 0.0 {
                            self.ramp = None;
                            self.interpolator.reset(p);
                        }
                        (p, v)
                    } else {
                        (self.interpolator.value(now), self.interpolator.slope(now))
                    };
                    // Outside the limits (enabled there), only motion back inside is allowed.
                    let lo = limits.position_min.min(self.target_position);
                    let hi = limits.position_max.max(self.target_position);
                    let mut p = wanted.clamp(lo, hi);
                    if cmd.mode == Mode::CyclicPosition {
                        // No step larger than the velocity limit allows in one cycle of the
                        // engine's clock (a late wake-up does not make the step larger), and
                        // no change of the step's velocity beyond the acceleration limit's:
                        // whatever the target source, it is joined from the commanded state.
                        let a = if stopping { f64::INFINITY } else { amax };
                        let (q, _) = blend(
                            self.target_position,
                            self.step_velocity,
                            p,
                            velocity,
                            limits.velocity_max,
                            a,
                            dt,
                        );
                        p = q.clamp(lo, hi);
                        self.step_velocity = (p - self.target_position) / dt;
                    }
                    let clamped = p != wanted;
                    if clamped {
                        st.position_clamps += 1;
                        limit_active = true;
                    }
                    // Clamped, the target moves as the clamp lets it: that is its velocity.
                    self.desired_velocity = if clamped {
                        (p - self.target_position) / dt
                    } else {
                        velocity
                    };
                    self.target_position = p;
                    idle = !self.trajectory_running
                        && self.ramp.is_none()
                        && !self.pp_new_setpoint
                        && self.interpolator.at_rest(now)
                        && !clamped;
                }
                Mode::CyclicVelocity | Mode::ProfileVelocity => {
                    let v = if self.trajectory_running {
                        let (v, done) = sample_velocity(
                            &self.points[self.points_first..self.points_len],
                            now - self.trajectory_start,
                            &mut self.cursor,
                        );
                        self.trajectory_running = !done;
                        self.trajectory_done = done;
                        v
                    } else if let Some(r) = self.ramp.as_mut() {
                        r.advance(decel, dt);
                        let v = r.velocity;
                        if v == 0.0 {
                            self.ramp = None;
                        }
                        v
                    } else {
                        self.setpoint_value
                    };
                    let mut v_out = v.clamp(-limits.velocity_max, limits.velocity_max);
                    if v_out != v {
                        st.velocity_clamps += 1;
                    }
                    if !stopping && amax.is_finite() {
                        // Every change of the velocity target within the acceleration limit.
                        let dv = amax * dt;
                        let joined =
                            v_out.clamp(self.desired_velocity - dv, self.desired_velocity + dv);
                        if joined != v_out {
                            limit_active = true;
                            v_out = joined;
                        }
                    }
                    let braked = limit_velocity(
                        v_out,
                        ahead,
                        limits.position_min,
                        limits.position_max,
                        decel,
                    );
                    if braked != v_out {
                        st.position_clamps += 1;
                        limit_active = true;
                        v_out = braked;
                    }
                    velocity_target = v_out;
                    self.desired_velocity = v_out;
                    self.target_position = ahead;
                    idle = !self.trajectory_running && v_out == 0.0;
                }
                Mode::CyclicTorque => {
                    let t = self.setpoint_value;
                    let mut t_out = t.clamp(-limits.torque_max, limits.torque_max);
                    if t_out != t {
                        st.torque_clamps += 1;
                    }
                    // The velocity limit holds in cst too, and the braking envelope before the
                    // position limits: on the speed predicted for when the torque takes effect
                    // (the drive's latency; `CstLimiter`), faded below a bound, braking above.
                    let (braked, cut) = self.cst.step(
                        fb.position,
                        t_out,
                        (limits.position_min, limits.position_max),
                        decel,
                        limits.velocity_max,
                        if limits.torque_max.is_finite() {
                            limits.torque_max
                        } else {
                            t_out.abs().max(1e-9)
                        },
                        COMMAND_LATENCY_CYCLES as usize,
                        dt,
                    );
                    if cut {
                        if self.cst.near_velocity_limit(limits.velocity_max) {
                            st.velocity_clamps += 1;
                        } else {
                            st.position_clamps += 1;
                        }
                        limit_active = true;
                        t_out = braked;
                    }
                    torque_target = t_out;
                    self.desired_velocity = 0.0;
                    self.target_position = ahead;
                    idle = t_out == 0.0;
                }
                Mode::Homing => {
                    self.target_position = fb.position;
                    self.desired_velocity = 0.0;
                }
            }
            match cmd.mode {
                Mode::ProfilePosition => {
                    if fb.statusword & sw::MODE_12 != 0 {
                        self.pp_new_setpoint = false;
                    }
                    if self.pp_new_setpoint {
                        cw |= cw::NEW_SETPOINT | cw::CHANGE_SET_IMMEDIATELY;
                    }
                }
                Mode::Homing => {
                    if cmd.homing_count != self.homing_seen {
                        self.homing_seen = cmd.homing_count;
                        self.homing_active = true;
                        self.homing_cycles = 0;
                    }
                    if self.homing_active {
                        // Homing operation start (bit 4) until the drive reports the end; the
                        // statuswords of the first cycles predate the start.
                        cw |= cw::NEW_SETPOINT;
                        self.homing_cycles = self.homing_cycles.saturating_add(1);
                        let attained = fb.statusword & sw::MODE_12 != 0
                            && fb.statusword & sw::TARGET_REACHED != 0;
                        let error = fb.statusword & sw::MODE_13 != 0;
                        if self.homing_cycles > HOMING_ACK_CYCLES && (attained || error) {
                            self.homing_active = false;
                            self.status.homing_runs = self.status.homing_runs.wrapping_add(1);
                        }
                    }
                }
                _ => {}
            }
        }
        if !running {
            // A homing start asked for while the axis cannot run is dropped.
            self.homing_seen = cmd.homing_count;
            self.homing_active = false;
        }

        // Into the image.
        let map = self.plan.map;
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

        // A trajectory ended early: running, it stopped without reaching its end while no newer
        // command came (a mode change, the drive leaving Operation Enabled, a disable, a halt);
        // pending, it was dropped because the axis could not run.
        self.stop_event = match (running_seq, pending_seq) {
            (Some(s), _)
                if !self.trajectory_running && !self.trajectory_done && self.seq_seen == s =>
            {
                Some(s)
            }
            (_, Some(s)) if !running && self.seq_seen == s => Some(s),
            _ => None,
        };
        if let Some(s) = self.stop_event {
            self.trajectory_stopped = true;
            self.stopped_seq = s;
        } else if self.seq_seen != self.stopped_seq {
            self.trajectory_stopped = false;
        }

        // Status.
        let st = &mut self.status;
        let torque_raw = map.torque.map_or(0, |o| read_i16(io, o));
        let following_raw = map
            .following_error
            .map_or(target_raw.wrapping_sub(fb.position_raw), |o| {
                read_i32(io, o)
            });
        st.statusword = fb.statusword;
        st.controlword = cw;
        st.state = fb.state as u8;
        st.mode_display = fb.mode_display;
        st.error_code = fb.error_code;
        st.position_raw = fb.position_raw;
        st.velocity_raw = fb.velocity_raw;
        st.torque_raw = torque_raw;
        st.following_error_raw = following_raw;
        st.target_position_raw = target_raw;
        st.position = fb.position;
        st.velocity = fb.velocity;
        st.torque = torque_raw as f64 * self.plan.torque_scale;
        st.following_error = following_raw as f64 * self.plan.position_scale;
        st.target_position = self.target_position;
        st.desired_velocity = self.desired_velocity;
        st.target_velocity = velocity_target;
        st.target_torque = torque_target;
        st.command_seq = self.seq_seen;
        let window = self.plan.following_error_window;
        let in_homing = fb.mode_display == Mode::Homing as i8;
        let mut f = 0;
        let pairs = [
            (self.trajectory_running, status_flags::TRAJECTORY_ACTIVE),
            (self.trajectory_done, status_flags::TRAJECTORY_DONE),
            (cmd.enable, status_flags::ENABLE_WANTED),
            (mode_reached, status_flags::MODE_REACHED),
            (
                window > 0.0
                    && fb.state == DriveState::OperationEnabled
                    && st.following_error.abs() > window,
                status_flags::FOLLOWING_ERROR,
            ),
            (
                fb.state.is_fault()
                    && self.plan.fault_reset == FaultReset::Auto
                    && self.retries >= self.plan.fault_retries
                    && !self.reset_pending,
                status_flags::RETRIES_EXHAUSTED,
            ),
            (halt, status_flags::HALTED),
            (
                !self.plan.inside_limits(fb.position),
                status_flags::OUTSIDE_LIMITS,
            ),
            (blocked, status_flags::RESTART_BLOCKED),
            (limit_active, status_flags::LIMIT_ACTIVE),
            (!running || idle && !self.homing_active, status_flags::IDLE),
            (self.homing_active, status_flags::HOMING_ACTIVE),
            (self.trajectory_stopped, status_flags::TRAJECTORY_STOPPED),
            (
                in_homing && !self.homing_active && fb.statusword & sw::MODE_12 != 0,
                status_flags::HOMING_ATTAINED,
            ),
            (
                in_homing && !self.homing_active && fb.statusword & sw::MODE_13 != 0,
                status_flags::HOMING_ERROR,
            ),
        ];
        for (on, bit) in pairs {
            if on {
                f |= bit;
            }
        }
        st.flags = f;
    }
}

/// The axis stage of the cycle: every axis's controller plus the buffers they are fed from and
/// publish into, preallocated.
pub struct Axes {
    /// One controller per axis, in plan order.
    pub controllers: Vec<AxisController>,
    command_bytes: Vec<u8>,
    command_version: u64,
    /// Per axis: a pending trajectory may start this cycle.
    start_ok: Vec<bool>,
    /// Per axis: the cyclic frame that carries its controlword (its group's watchdog halts it).
    frame_of: Vec<usize>,
    status_bytes: Vec<u8>,
    cycle: u64,
}

impl Axes {
    /// The stage for the axes of `plans`, every buffer allocated here (never in the cycle).
    pub fn new(plans: &[AxisPlan], trajectory_capacity: usize) -> Axes {
        Axes {
            controllers: plans
                .iter()
                .map(|p| AxisController::new(p.clone(), trajectory_capacity))
                .collect(),
            command_bytes: vec![0; plans.len() * COMMAND_LEN],
            command_version: u64::MAX,
            start_ok: vec![false; plans.len()],
            frame_of: vec![0; plans.len()],
            status_bytes: vec![0; plans.len() * STATUS_LEN],
            cycle: 0,
        }
    }

    /// Which cyclic frame carries each axis's outputs (for the groups' own watchdogs).
    pub fn set_frames(&mut self, frame_of: &[usize]) {
        for (f, &k) in self.frame_of.iter_mut().zip(frame_of) {
            *f = k;
        }
    }

    /// True when the plan has no axis (the stage does nothing).
    pub fn is_empty(&self) -> bool {
        self.controllers.is_empty()
    }

    /// Take over the newest complete commands (a write in progress: keep the previous ones).
    fn refresh_commands(&mut self, ex: &AxisExchange) {
        if ex.commands.version() == self.command_version {
            return;
        }
        if let Some(v) = ex.commands.try_read(&mut self.command_bytes) {
            self.command_version = v;
            for (c, b) in self
                .controllers
                .iter_mut()
                .zip(self.command_bytes.chunks_exact(COMMAND_LEN))
            {
                c.command = AxisCommand::decode(b);
            }
        }
    }

    /// Run every axis for this cycle and publish their status. `halt`: panic or the bus
    /// watchdog; `stale_frames`: bit k when frame k's own watchdog has tripped (its axes are
    /// stopped too). Returns bit k set when an axis of frame k runs a trajectory (a command in
    /// progress: it feeds the watchdogs).
    pub fn step(
        &mut self,
        io: &mut [u8],
        now: i64,
        cycle_ns: i64,
        halt: bool,
        stale_frames: u32,
        ex: &AxisExchange,
    ) -> u32 {
        if self.controllers.is_empty() {
            return 0;
        }
        self.refresh_commands(ex);
        for (c, slot) in self.controllers.iter_mut().zip(&ex.trajectories) {
            c.stage_trajectory(slot);
        }
        // A trajectory given to several axes at once starts on all of them in the same cycle:
        // only when every one of them has its points.
        for (i, ok) in self.start_ok.iter_mut().enumerate() {
            *ok = self.controllers[i].pending_trajectory().is_some_and(|seq| {
                self.controllers
                    .iter()
                    .all(|c| c.pending_trajectory() != Some(seq) || c.staged_seq == Some(seq))
            });
        }
        let mut active = 0u32;
        for (i, c) in self.controllers.iter_mut().enumerate() {
            let frame = self.frame_of[i];
            let group_halt = frame < 32 && stale_frames & (1 << frame) != 0;
            c.step(io, now, cycle_ns, halt || group_halt, self.start_ok[i]);
            if c.status.flags & status_flags::TRAJECTORY_ACTIVE != 0 && frame < 32 {
                active |= 1 << frame;
            }
        }
        // A trajectory given to several axes is one motion: when one of them leaves it early
        // (a mode change, a disable, a fault...), the others make a quiet stop from the next
        // cycle on instead of going on alone (issue 24). No allocation: a pass per event, and
        // events are rare.
        for i in 0..self.controllers.len() {
            if let Some(seq) = self.controllers[i].stop_event {
                for (j, c) in self.controllers.iter_mut().enumerate() {
                    if j != i {
                        c.stop_with_peer(seq);
                        if c.stopped_seq == seq && c.trajectory_stopped {
                            c.status.flags = (c.status.flags & !status_flags::TRAJECTORY_ACTIVE)
                                | status_flags::TRAJECTORY_STOPPED;
                        }
                    }
                }
            }
        }
        for (i, c) in self.controllers.iter_mut().enumerate() {
            c.status.cycle = self.cycle;
            c.status
                .encode(&mut self.status_bytes[i * STATUS_LEN..(i + 1) * STATUS_LEN]);
            let gate = AxisGate {
                state: c.status.state,
                flags: c.status.flags,
                error_code: c.status.error_code,
                last_fault_code: c.status.last_fault_code,
                published: true,
            };
            if let Some(g) = ex.gates.get(i) {
                g.store(gate.pack(), std::sync::atomic::Ordering::Release);
            }
        }
        ex.status.write(0, &self.status_bytes);
        self.cycle += 1;
        active
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
        s.statusword_bits()
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
            deceleration: f64::INFINITY,
            max_acceleration: f64::INFINITY,
            mode_change_velocity: ModeChangeVelocity::Actual,
            restart: Restart::Auto,
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
        /// The drive's position (raw, unrounded) and velocity (raw/s): in Operation Enabled it
        /// follows the position target in csp, the velocity target in csv, and accelerates
        /// at `TORQUE_GAIN` raw/s² per raw torque in cst; disabled it stands.
        position: f64,
        velocity: f64,
        /// Mode-specific statusword bits the drive shows besides its state (homing, pp).
        extra_sw: u16,
        /// cst: raw/s² per raw torque, and the torques written still on their way to the
        /// drive (a torque acts this many cycles later than the next).
        torque_gain: f64,
        torque_delay: std::collections::VecDeque<i16>,
        /// Inputs that stay stale (the position read repeats) in the cycles k with
        /// k % n == 0 for an n of these (a loaded host's late frames).
        stale_every: &'static [i64],
    }

    const CYCLE: i64 = 1_000_000;
    const TORQUE_GAIN: f64 = 100.0;

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
                position: position_raw as f64,
                velocity: 0.0,
                extra_sw: 0,
                torque_gain: TORQUE_GAIN,
                torque_delay: Default::default(),
                stale_every: &[],
            }
        }

        fn send(&mut self) {
            let mut b = [0u8; COMMAND_LEN];
            self.command.encode(&mut b);
            self.ex.commands.write(0, &b);
        }

        fn cycle(&mut self, halt: bool) {
            let word = statusword(self.state) | self.extra_sw;
            self.io[SW..SW + 2].copy_from_slice(&word.to_le_bytes());
            let k = self.now / CYCLE;
            if !self.stale_every.iter().any(|n| k % n == 0) {
                self.io[POS..POS + 4].copy_from_slice(&self.position_raw.to_le_bytes());
            }
            self.io[VEL..VEL + 4].copy_from_slice(&(self.velocity.round() as i32).to_le_bytes());
            self.io[ERR..ERR + 2].copy_from_slice(&self.error.to_le_bytes());
            self.axes
                .step(&mut self.io, self.now, CYCLE, halt, 0, &self.ex);
            let cw = read_u16(&self.io, CW);
            let target = read_i32(&self.io, TPOS);
            self.targets.push(target);
            let dt = CYCLE as f64 * 1e-9;
            if self.state == DriveState::OperationEnabled {
                match self.io[MODE_D] as i8 {
                    8 | 1 => {
                        self.velocity = (target as f64 - self.position) / dt;
                        self.position = target as f64;
                    }
                    9 | 3 => {
                        self.velocity = read_i32(&self.io, TVEL) as f64;
                        self.position += self.velocity * dt;
                    }
                    10 => {
                        self.torque_delay.push_back(read_i16(&self.io, TTRQ));
                        let torque = self.torque_delay.pop_front().unwrap_or(0);
                        self.velocity += torque as f64 * self.torque_gain * dt;
                        self.position += self.velocity * dt;
                    }
                    _ => self.velocity = 0.0,
                }
            } else {
                self.velocity = 0.0;
            }
            self.position_raw = self.position.round() as i32;
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
    fn undefined_statuswords_count_as_not_ready() {
        // The coding is the protocol crate's (tested there); what it leaves undefined enables
        // nothing here.
        assert_eq!(drive_state(0x0001), DriveState::NotReadyToSwitchOn);
        assert_eq!(drive_state(0x0027 | 0xFF90), DriveState::OperationEnabled);
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
        assert_eq!(read_u16(&b.io, CW), command::FAULT_RESET);
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
                command::QUICK_STOP,
                DriveState::QuickStopActive,
            ),
            (
                OnStop::Disable,
                command::DISABLE_VOLTAGE,
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
        b.command.value = -3.0;
        b.send();
        // Until the axis's gain is known the torque rises over `CST_RISE_CYCLES`.
        b.run(60);
        assert_eq!(read_i16(&b.io, TTRQ), -200);
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
        io[SW..SW + 2].copy_from_slice(&(0x0027u16 | sw::MODE_12).to_le_bytes());
        b.axes.step(&mut io, b.now, CYCLE, false, 0, &b.ex);
        assert_eq!(read_u16(&io, CW) & 0x0010, 0);
    }

    fn enabled(plan: AxisPlan, position_raw: i32) -> Bench {
        let mut b = Bench::new(plan, DriveState::SwitchOnDisabled, position_raw);
        b.command.enable = true;
        b.command.enable_count += 1;
        b.send();
        b.run(10);
        assert_eq!(b.state, DriveState::OperationEnabled);
        b
    }

    fn command(b: &mut Bench, kind: SetpointKind, value: f64) {
        b.command.seq += 1;
        b.command.setpoint_kind = kind as u8;
        b.command.value = value;
        b.command.t_ns = b.now;
        b.send();
    }

    fn set_mode(b: &mut Bench, mode: Mode) {
        b.command.mode = mode;
        b.send();
    }

    /// Run until the drive stands still (at most `max` cycles); the position (raw).
    fn settle(b: &mut Bench, max: usize) -> f64 {
        for _ in 0..max {
            b.cycle(false);
            if b.velocity.abs() < 1e-9 && b.status().flags & status_flags::IDLE != 0 {
                break;
            }
        }
        b.position
    }

    #[test]
    fn a_mode_change_starts_from_the_actual_state() {
        // 10 rad/s² deceleration: from 1 rad/s a quiet stop takes 0.05 rad (50 raw).
        let mut p = plan();
        p.deceleration = 10.0;
        let mut b = enabled(p, 0);
        set_mode(&mut b, Mode::CyclicVelocity);
        command(&mut b, SetpointKind::Velocity, 1.0);
        b.run(300);
        // Moving at 1 rad/s (1000 raw/s): the position target followed the actual position
        // (where the axis is when the drive can take the target: three cycles on).
        assert!((b.velocity - 1000.0).abs() < 1e-6, "{}", b.velocity);
        let st = b.status();
        assert!((st.target_position - (st.position + 0.003)).abs() < 1e-9);
        let (p0, n) = (b.position, b.targets.len());
        // To csp without a command: a quiet stop from the actual state, never a jump.
        set_mode(&mut b, Mode::CyclicPosition);
        let rest = settle(&mut b, 500);
        // From where the axis is when the drive takes the target (3 cycles at 1 raw/cycle
        // ahead of the position read), 50 raw to stop.
        assert!((rest - (p0 + 53.0)).abs() <= 2.0, "rest {rest} from {p0}");
        let steps: Vec<i32> = b.targets[n..].windows(2).map(|w| w[1] - w[0]).collect();
        assert!(steps.iter().all(|&d| (0..=2).contains(&d)), "{steps:?}");
        // To cst: torque from zero; the position target follows the actual position.
        set_mode(&mut b, Mode::CyclicTorque);
        b.run(3);
        assert_eq!(read_i16(&b.io, TTRQ), 0);
        command(&mut b, SetpointKind::Torque, -1.0);
        b.run(100);
        assert!(b.velocity < -500.0);
        let st = b.status();
        let ahead = st.position + st.velocity * 0.003;
        assert!((st.target_position - ahead).abs() < 1e-6);
        // To csv at -0.9 rad/s or so: the velocity target starts at the actual velocity and
        // ramps to zero at the deceleration.
        let v0 = b.velocity;
        set_mode(&mut b, Mode::CyclicVelocity);
        b.cycle(false);
        b.cycle(false);
        let first = read_i32(&b.io, TVEL) as f64;
        // Two cycles of the ramp at 10 raw/s per cycle, and the velocity actual's rounding.
        assert!((first - v0).abs() <= 21.0, "{first} vs {v0}");
        let rest = settle(&mut b, 500);
        assert_eq!(read_i32(&b.io, TVEL), 0);
        assert!(rest < b.targets[b.targets.len() - 1] as f64 + 1.0);
        // A setpoint given after a mode change of the same kind as the old mode's is not
        // taken as the new mode's: the old velocity setpoint is no torque.
        command(&mut b, SetpointKind::Velocity, 0.5);
        b.run(5);
        set_mode(&mut b, Mode::CyclicTorque);
        b.run(5);
        assert_eq!(read_i16(&b.io, TTRQ), 0);
    }

    #[test]
    fn mode_change_velocity_zero_stops_at_once() {
        let mut p = plan();
        p.deceleration = 10.0;
        p.mode_change_velocity = ModeChangeVelocity::Zero;
        let mut b = enabled(p, 0);
        set_mode(&mut b, Mode::CyclicVelocity);
        command(&mut b, SetpointKind::Velocity, 1.0);
        b.run(100);
        let p0 = b.position;
        set_mode(&mut b, Mode::CyclicPosition);
        let rest = settle(&mut b, 100);
        assert!((rest - p0).abs() <= 2.0, "{rest} vs {p0}");
    }

    #[test]
    fn position_limits_hold_in_the_velocity_and_torque_modes() {
        // Limits ±10 rad, 5 rad/s max, braking at 10 rad/s² (the bench's drive makes
        // 20 rad/s² at the torque limit: the deceleration must be one the axis can do). A µrad
        // encoder: cst acts on the velocity from the positions read.
        let mut p = plan();
        p.deceleration = 10.0;
        p.position_scale = 1e-6;
        p.velocity_scale = 1e-6;
        let mut b = enabled(p, 8_000_000);
        b.torque_gain = TORQUE_GAIN * 1000.0;
        set_mode(&mut b, Mode::CyclicVelocity);
        command(&mut b, SetpointKind::Velocity, 5.0);
        let mut top = 0.0f64;
        for _ in 0..1500 {
            b.cycle(false);
            top = top.max(b.position);
        }
        assert!(top <= 10_000_000.0 + 1000.0, "{top}");
        assert!(b.position > 9_900_000.0, "it went close: {}", b.position);
        assert_eq!(read_i32(&b.io, TVEL), 0);
        let st = b.status();
        assert!(st.position_clamps > 0 && st.flags & status_flags::LIMIT_ACTIVE != 0);
        // Inward is never cut.
        command(&mut b, SetpointKind::Velocity, -2.0);
        b.run(3);
        assert_eq!(read_i32(&b.io, TVEL), -2_000_000);
        b.run(500);
        // Torque outward: the axis is braked before the limit.
        set_mode(&mut b, Mode::CyclicTorque);
        command(&mut b, SetpointKind::Torque, 2.0);
        let mut top = f64::MIN;
        for _ in 0..3000 {
            b.cycle(false);
            top = top.max(b.position);
        }
        assert!(top <= 10_000_000.0 + 10_000.0, "{top}");
        assert!(b.velocity.abs() < 200_000.0, "{}", b.velocity);
    }

    #[test]
    fn a_stop_ends_the_trajectory_and_the_enable_after_it_holds_still() {
        let mut p = plan();
        p.restart = Restart::Manual;
        let mut b = enabled(p, 0);
        let pts = [
            Point {
                t_ns: 0,
                position: 0.0,
                velocity: 0.0,
            },
            Point {
                t_ns: 1_000_000_000,
                position: 1.0,
                velocity: 0.0,
            },
        ];
        b.command.seq += 1;
        write_points(&b.ex, 0, b.command.seq, &pts);
        b.command.setpoint_kind = 0;
        b.command.trajectory_len = 2;
        b.command.t_ns = b.now;
        b.send();
        b.run(300);
        b.cycle(true);
        b.run(10);
        let here = b.position_raw;
        assert_eq!(b.status().flags & status_flags::TRAJECTORY_ACTIVE, 0);
        b.command.enable_count += 1;
        b.send();
        b.run(300);
        assert_eq!(b.state, DriveState::OperationEnabled);
        assert_eq!(b.position_raw, here, "the trajectory did not resume");
    }

    #[test]
    fn a_quiet_stop_decelerates_from_the_commanded_motion() {
        // csv at 1 rad/s, then a stop: the velocity target ramps to 0 at 10 rad/s² (0.1 s).
        let mut p = plan();
        p.deceleration = 10.0;
        let mut b = enabled(p, 0);
        set_mode(&mut b, Mode::CyclicVelocity);
        command(&mut b, SetpointKind::Velocity, 1.0);
        b.run(50);
        b.command.seq += 1;
        b.command.setpoint_kind = STOP_COMMAND;
        b.send();
        b.cycle(false);
        let first = read_i32(&b.io, TVEL);
        assert!((985..1000).contains(&first), "{first}");
        b.run(120);
        assert_eq!(read_i32(&b.io, TVEL), 0);
        assert_ne!(b.status().flags & status_flags::IDLE, 0);
        // csp on a trajectory at speed: the targets decelerate, no step back, then hold.
        set_mode(&mut b, Mode::CyclicPosition);
        b.run(5);
        command(&mut b, SetpointKind::Position, 3.0);
        b.run(200);
        let n = b.targets.len();
        b.command.seq += 1;
        b.command.setpoint_kind = STOP_COMMAND;
        b.send();
        b.run(2000);
        // It moved at the velocity limit (5 raw per cycle), then 0.5 s of ramp at 10 rad/s².
        let steps: Vec<i32> = b.targets[n..].windows(2).map(|w| w[1] - w[0]).collect();
        assert_eq!(steps[0], 5, "{steps:?}");
        assert!(steps.iter().all(|&d| d >= 0), "{steps:?}");
        assert!(
            steps.windows(2).all(|w| w[1] <= w[0] + 1),
            "decelerating: {steps:?}"
        );
        let travelled = b.targets[b.targets.len() - 1] - b.targets[n];
        assert!(
            (1230..1270).contains(&travelled),
            "5 rad/s to rest at 10 rad/s²: {travelled}"
        );
    }

    #[test]
    fn homing_starts_only_when_asked_and_ends_on_the_drives_report() {
        let mut p = plan();
        p.mode = Mode::Homing;
        let mut b = enabled(p, 0);
        assert_eq!(
            read_u16(&b.io, CW) & cw::NEW_SETPOINT,
            0,
            "no homing by itself"
        );
        // The drive still shows an old "homing attained": it does not end the new run.
        b.extra_sw = sw::MODE_12 | sw::TARGET_REACHED;
        b.command.homing_count += 1;
        b.send();
        for _ in 0..HOMING_ACK_CYCLES {
            b.cycle(false);
            assert_ne!(read_u16(&b.io, CW) & cw::NEW_SETPOINT, 0);
            assert_ne!(b.status().flags & status_flags::HOMING_ACTIVE, 0);
        }
        b.extra_sw = 0; // homing in progress
        b.run(20);
        assert_ne!(read_u16(&b.io, CW) & cw::NEW_SETPOINT, 0);
        b.extra_sw = sw::MODE_12 | sw::TARGET_REACHED; // attained
        b.run(2);
        assert_eq!(read_u16(&b.io, CW) & cw::NEW_SETPOINT, 0);
        let st = b.status();
        assert_eq!(st.flags & status_flags::HOMING_ACTIVE, 0);
        assert_ne!(st.flags & status_flags::HOMING_ATTAINED, 0);
        assert_eq!(st.homing_runs, 1);
        // An error ends a run too.
        b.extra_sw = 0;
        b.command.homing_count += 1;
        b.send();
        b.run(10);
        b.extra_sw = sw::MODE_13;
        b.run(2);
        let st = b.status();
        assert_eq!(st.flags & status_flags::HOMING_ACTIVE, 0);
        assert_ne!(st.flags & status_flags::HOMING_ERROR, 0);
    }

    #[test]
    fn csp_steps_are_limited_per_cycle_of_the_engine_clock() {
        let mut b = enabled(plan(), 0);
        command(&mut b, SetpointKind::Position, 5.0);
        b.run(5);
        // A late wake-up: 20 ms since the previous cycle. The step stays 5 rad/s × 1 ms.
        b.now += 20 * CYCLE;
        b.run(3);
        let steps: Vec<i32> = b.targets.windows(2).map(|w| w[1] - w[0]).collect();
        assert!(steps.iter().all(|&d| d.abs() <= 5), "{steps:?}");
    }

    #[test]
    fn restart_manual_waits_for_an_explicit_enable() {
        let mut p = plan();
        p.restart = Restart::Manual;
        let mut b = enabled(p, 0);
        // Panic, then released: stays out of Operation Enabled, blocked.
        b.cycle(true);
        b.cycle(true);
        b.run(20);
        assert_ne!(b.state, DriveState::OperationEnabled);
        assert_ne!(b.status().flags & status_flags::RESTART_BLOCKED, 0);
        // An enable given while halted does not count.
        b.command.enable_count += 1;
        b.send();
        b.cycle(true);
        b.run(20);
        assert_ne!(b.state, DriveState::OperationEnabled);
        // The explicit enable after it does.
        b.command.enable_count += 1;
        b.send();
        b.run(10);
        assert_eq!(b.state, DriveState::OperationEnabled);
        assert_eq!(b.status().flags & status_flags::RESTART_BLOCKED, 0);
        // A fault, reset automatically: the fault is gone, the axis stays disabled.
        b.state = DriveState::Fault;
        b.error = 0x7305;
        b.run(100);
        assert_eq!(b.status().fault_resets, 1);
        assert_eq!(b.state, DriveState::SwitchOnDisabled);
        assert_ne!(b.status().flags & status_flags::RESTART_BLOCKED, 0);
        b.command.enable_count += 1;
        b.send();
        b.run(10);
        assert_eq!(b.state, DriveState::OperationEnabled);
        // An enable that arrives with the end of a watchdog stop (the command fed it) counts.
        b.cycle(true);
        b.run(5);
        b.command.enable_count += 1;
        b.send();
        b.run(10);
        assert_eq!(b.state, DriveState::OperationEnabled);
        // The drive leaving Operation Enabled by itself blocks too.
        b.state = DriveState::SwitchOnDisabled;
        b.run(20);
        assert_eq!(b.state, DriveState::SwitchOnDisabled);
    }

    #[test]
    fn restart_auto_never_re_enables_outside_the_limits() {
        let mut b = enabled(plan(), 0);
        b.cycle(true);
        b.run(10);
        assert_eq!(
            b.state,
            DriveState::OperationEnabled,
            "auto: back by itself"
        );
        // Outside the limits (a drive moved by hand while in fault): the automatic reset
        // resets the fault but does not enable.
        b.state = DriveState::Fault;
        b.position = 12_000.0;
        b.position_raw = 12_000;
        b.run(100);
        assert_eq!(b.state, DriveState::SwitchOnDisabled);
        let st = b.status();
        assert!(st.fault_resets >= 1);
        assert_ne!(st.flags & status_flags::OUTSIDE_LIMITS, 0);
        assert_ne!(st.flags & status_flags::RESTART_BLOCKED, 0);
        // An explicit enable outside the limits is allowed; then only motion back inside.
        b.command.enable_count += 1;
        b.send();
        b.run(10);
        assert_eq!(b.state, DriveState::OperationEnabled);
        command(&mut b, SetpointKind::Position, 10.0);
        b.run(1000);
        assert_eq!(b.position_raw, 10_000);
    }

    /// Two axes in one image (the second at +IMG) for the multi-axis hand-over.
    fn two_axes() -> (Axes, AxisExchange, Vec<u8>) {
        let a = plan();
        let mut b = plan();
        b.name = "j2".into();
        let shift = |o: Option<usize>| o.map(|o| o + IMG);
        b.map = AxisMap {
            controlword: CW + IMG,
            statusword: SW + IMG,
            mode: shift(a.map.mode),
            mode_display: shift(a.map.mode_display),
            target_position: shift(a.map.target_position),
            target_velocity: shift(a.map.target_velocity),
            target_torque: shift(a.map.target_torque),
            position: shift(a.map.position),
            velocity: shift(a.map.velocity),
            torque: None,
            error_code: shift(a.map.error_code),
            following_error: None,
        };
        let plans = [a, b];
        let mut io = vec![0u8; 2 * IMG];
        for base in [0, IMG] {
            io[base + SW..base + SW + 2]
                .copy_from_slice(&statusword(DriveState::OperationEnabled).to_le_bytes());
            io[base + MODE_D] = 8;
        }
        (Axes::new(&plans, 8), AxisExchange::new(&plans, 8), io)
    }

    fn write_points(ex: &AxisExchange, axis: usize, seq: u64, pts: &[Point]) {
        let mut bytes = vec![0u8; TRAJECTORY_HEADER + pts.len() * POINT_LEN];
        bytes[..8].copy_from_slice(&seq.to_le_bytes());
        for (p, c) in pts
            .iter()
            .zip(bytes[TRAJECTORY_HEADER..].chunks_exact_mut(POINT_LEN))
        {
            p.encode(c);
        }
        ex.trajectories[axis].write(0, &bytes);
    }

    #[test]
    fn a_trajectory_for_several_axes_starts_in_one_cycle() {
        let (mut axes, ex, mut io) = two_axes();
        let mut now = 1_000_000_000;
        let mut cmds = [AxisCommand::initial(Mode::CyclicPosition); 2];
        let send = |cmds: &[AxisCommand; 2]| {
            let mut b = vec![0u8; 2 * COMMAND_LEN];
            cmds[0].encode(&mut b[..COMMAND_LEN]);
            cmds[1].encode(&mut b[COMMAND_LEN..]);
            ex.commands.write(0, &b);
        };
        for c in &mut cmds {
            c.enable = true;
            c.enable_count = 1;
        }
        send(&cmds);
        axes.step(&mut io, now, CYCLE, false, 0, &ex);
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
        ];
        // The commands of both axes, but the points of only one: neither starts.
        for c in &mut cmds {
            c.seq = 7;
            c.setpoint_kind = 0;
            c.t_ns = now;
            c.trajectory_len = 2;
        }
        write_points(&ex, 0, 7, &pts);
        send(&cmds);
        for _ in 0..5 {
            now += CYCLE;
            assert_eq!(axes.step(&mut io, now, CYCLE, false, 0, &ex), 0);
        }
        assert!(axes.controllers.iter().all(|c| c.status.command_seq != 7));
        // The second axis's points arrive: both start in this cycle (the bit of frame 0).
        write_points(&ex, 1, 7, &pts);
        now += CYCLE;
        assert_eq!(axes.step(&mut io, now, CYCLE, false, 0, &ex), 1);
        for c in &axes.controllers {
            assert_eq!(c.status.command_seq, 7);
            assert_ne!(c.status.flags & status_flags::TRAJECTORY_ACTIVE, 0);
        }
        let (a, b) = (&axes.controllers[0].status, &axes.controllers[1].status);
        assert_eq!(a.target_position_raw, b.target_position_raw);
    }

    /// Two axes in csp (deceleration 10 rad/s²) on one trajectory from 0 to 2 rad over 1 s,
    /// half-way through (3 rad/s): the commands, the image and the time.
    fn two_axes_half_way() -> (Axes, AxisExchange, Vec<u8>, [AxisCommand; 2], i64) {
        let (mut axes, ex, mut io) = two_axes();
        for c in &mut axes.controllers {
            c.plan.deceleration = 10.0;
        }
        let mut now = 1_000_000_000;
        let mut cmds = [AxisCommand::initial(Mode::CyclicPosition); 2];
        for c in &mut cmds {
            c.enable = true;
            c.enable_count = 1;
        }
        send_two(&ex, &cmds);
        axes.step(&mut io, now, CYCLE, false, 0, &ex);
        let pts = [
            Point {
                t_ns: 0,
                position: 0.0,
                velocity: 0.0,
            },
            Point {
                t_ns: 1_000_000_000,
                position: 2.0,
                velocity: 0.0,
            },
        ];
        for c in &mut cmds {
            c.seq = 7;
            c.setpoint_kind = 0;
            c.t_ns = now;
            c.trajectory_len = 2;
        }
        write_points(&ex, 0, 7, &pts);
        write_points(&ex, 1, 7, &pts);
        send_two(&ex, &cmds);
        for _ in 0..500 {
            now += CYCLE;
            axes.step(&mut io, now, CYCLE, false, 0, &ex);
        }
        for c in &axes.controllers {
            assert_ne!(c.status.flags & status_flags::TRAJECTORY_ACTIVE, 0);
            assert_eq!(c.status.flags & status_flags::TRAJECTORY_STOPPED, 0);
        }
        (axes, ex, io, cmds, now)
    }

    fn send_two(ex: &AxisExchange, cmds: &[AxisCommand; 2]) {
        let mut b = vec![0u8; 2 * COMMAND_LEN];
        cmds[0].encode(&mut b[..COMMAND_LEN]);
        cmds[1].encode(&mut b[COMMAND_LEN..]);
        ex.commands.write(0, &b);
    }

    /// The second axis's position targets (raw) over `n` more cycles.
    fn second_axis_targets(
        axes: &mut Axes,
        ex: &AxisExchange,
        io: &mut [u8],
        now: &mut i64,
        n: usize,
    ) -> Vec<i32> {
        (0..n)
            .map(|_| {
                *now += CYCLE;
                axes.step(io, *now, CYCLE, false, 0, ex);
                read_i32(io, TPOS + IMG)
            })
            .collect()
    }

    /// The other axis of the trajectory decelerates from the motion it had (3 rad/s, 3 raw a
    /// cycle) at 10 rad/s² to rest and holds: no step larger than before, none backwards.
    fn assert_quiet_stop(targets: &[i32]) {
        let steps: Vec<i32> = targets.windows(2).map(|w| w[1] - w[0]).collect();
        assert!(steps[0] <= 3 && steps[0] >= 2, "{steps:?}");
        assert!(steps.iter().all(|&d| d >= 0), "{steps:?}");
        assert!(steps.windows(2).all(|w| w[1] <= w[0] + 1), "{steps:?}");
        assert!(
            steps[steps.len() - 50..].iter().all(|&d| d == 0),
            "holds: {steps:?}"
        );
        // 3 rad/s to rest at 10 rad/s²: 0.45 rad.
        let travelled = targets[targets.len() - 1] - targets[0];
        assert!((400..500).contains(&travelled), "{travelled}");
    }

    #[test]
    fn a_mode_change_of_one_axis_stops_the_others_of_its_trajectory() {
        let (mut axes, ex, mut io, mut cmds, mut now) = two_axes_half_way();
        let before = read_i32(&io, TPOS + IMG);
        cmds[0].mode = Mode::CyclicVelocity;
        send_two(&ex, &cmds);
        let targets = second_axis_targets(&mut axes, &ex, &mut io, &mut now, 400);
        for c in &axes.controllers {
            assert_eq!(c.status.flags & status_flags::TRAJECTORY_ACTIVE, 0);
            assert_eq!(c.status.flags & status_flags::TRAJECTORY_DONE, 0);
            assert_ne!(c.status.flags & status_flags::TRAJECTORY_STOPPED, 0);
            assert_eq!(c.status.command_seq, 7);
        }
        let mut all = vec![before];
        all.extend(targets);
        assert_quiet_stop(&all);
        // The next command clears the flag.
        cmds[1].seq = 8;
        cmds[1].setpoint_kind = SetpointKind::Position as u8;
        cmds[1].value = 0.5;
        cmds[1].t_ns = now;
        send_two(&ex, &cmds);
        second_axis_targets(&mut axes, &ex, &mut io, &mut now, 2);
        let flags = axes.controllers[1].status.flags;
        assert_eq!(flags & status_flags::TRAJECTORY_STOPPED, 0);
        assert_ne!(
            axes.controllers[0].status.flags & status_flags::TRAJECTORY_STOPPED,
            0
        );
    }

    #[test]
    fn a_disabled_or_halted_axis_stops_the_others_of_its_trajectory() {
        for how in ["disable", "fault", "halt"] {
            let (mut axes, ex, mut io, mut cmds, mut now) = two_axes_half_way();
            let before = read_i32(&io, TPOS + IMG);
            let mut all = vec![before];
            match how {
                "disable" => {
                    cmds[0].enable = false;
                    send_two(&ex, &cmds);
                }
                "fault" => {
                    io[SW..SW + 2].copy_from_slice(&statusword(DriveState::Fault).to_le_bytes());
                }
                _ => {
                    // Only the first axis's frame is stale (its group's watchdog).
                    axes.set_frames(&[1, 0]);
                    now += CYCLE;
                    axes.step(&mut io, now, CYCLE, false, 0b10, &ex);
                    all.push(read_i32(&io, TPOS + IMG));
                }
            }
            all.extend(second_axis_targets(&mut axes, &ex, &mut io, &mut now, 400));
            for c in &axes.controllers {
                assert_ne!(
                    c.status.flags & status_flags::TRAJECTORY_STOPPED,
                    0,
                    "{how}"
                );
                assert_eq!(c.status.flags & status_flags::TRAJECTORY_ACTIVE, 0, "{how}");
            }
            assert_quiet_stop(&all);
        }
    }

    #[test]
    fn a_trajectory_that_ends_or_is_replaced_is_not_stopped() {
        let (mut axes, ex, mut io, mut cmds, mut now) = two_axes_half_way();
        second_axis_targets(&mut axes, &ex, &mut io, &mut now, 600);
        for c in &axes.controllers {
            assert_ne!(c.status.flags & status_flags::TRAJECTORY_DONE, 0);
            assert_eq!(c.status.flags & status_flags::TRAJECTORY_STOPPED, 0);
        }
        // A quiet stop asked for (a newer command) is no early end either.
        let (mut axes, ex, mut io, _, mut now) = two_axes_half_way();
        for c in &mut cmds {
            c.seq = 8;
            c.setpoint_kind = STOP_COMMAND;
        }
        send_two(&ex, &cmds);
        second_axis_targets(&mut axes, &ex, &mut io, &mut now, 10);
        for c in &axes.controllers {
            assert_eq!(c.status.flags & status_flags::TRAJECTORY_STOPPED, 0);
            assert_eq!(c.status.command_seq, 8);
        }
    }

    #[test]
    fn a_new_trajectory_splices_in_from_the_commanded_state() {
        let mut b = enabled(plan(), 0);
        // 0 → 1 rad in 1 s (Hermite, at rest at both ends).
        let first = [
            Point {
                t_ns: 0,
                position: 0.0,
                velocity: 0.0,
            },
            Point {
                t_ns: 1_000_000_000,
                position: 1.0,
                velocity: 0.0,
            },
        ];
        b.command.seq += 1;
        write_points(&b.ex, 0, b.command.seq, &first);
        b.command.setpoint_kind = 0;
        b.command.trajectory_len = 2;
        b.command.t_ns = b.now;
        b.send();
        b.run(500);
        // Half way at full speed (1.5 rad/s): a new trajectory to 0.2 rad whose first point
        // lies in the past (trimmed) and whose start is now.
        let second = [
            Point {
                t_ns: 0,
                position: 9.0,
                velocity: 0.0,
            },
            Point {
                t_ns: 400_000_000,
                position: 0.2,
                velocity: 0.0,
            },
        ];
        b.command.seq += 1;
        write_points(&b.ex, 0, b.command.seq, &second);
        b.command.t_ns = b.now - 10 * CYCLE;
        b.send();
        let n = b.targets.len();
        b.run(600);
        // No jump: the steps around the splice continue at the speed it had (1.5 raw/cycle)
        // and change by little per cycle; the end is the new trajectory's.
        let steps: Vec<i32> = b.targets[n - 3..n + 5]
            .windows(2)
            .map(|w| w[1] - w[0])
            .collect();
        assert!(steps.iter().all(|&d| (1..=2).contains(&d)), "{steps:?}");
        assert_eq!(*b.targets.last().unwrap(), 200);
        assert_eq!(b.status().position_clamps, 0);
    }

    /// An axis in µrad (so that the targets' second differences show the acceleration):
    /// ±10 rad, 3 rad/s, 20 rad/s² of acceleration and deceleration.
    fn fine_plan() -> AxisPlan {
        let mut p = plan();
        p.position_scale = 1e-6;
        p.velocity_scale = 1e-6;
        p.limits.velocity_max = 3.0;
        p.deceleration = 20.0;
        p.max_acceleration = 20.0;
        p
    }

    /// Send a trajectory starting `ago` ns before now.
    fn follow(b: &mut Bench, ago: i64, pts: &[Point]) {
        let t_ns = b.now - ago;
        b.command.seq += 1;
        write_points(&b.ex, 0, b.command.seq, pts);
        b.command.setpoint_kind = TRAJECTORY_COMMAND;
        b.command.trajectory_len = pts.len() as u32;
        b.command.t_ns = t_ns;
        b.send();
    }

    fn pt(t_s: f64, position: f64, velocity: f64) -> Point {
        Point {
            t_ns: (t_s * 1e9) as i64,
            position,
            velocity,
        }
    }

    /// The largest |velocity step| (rad/s) and |velocity| (rad/s) of the fine axis's targets,
    /// from the raw targets written (what goes on the wire).
    fn wire_motion(targets: &[i32]) -> (f64, f64) {
        let dt = CYCLE as f64 * 1e-9;
        let v: Vec<f64> = targets
            .windows(2)
            .map(|w| (w[1] - w[0]) as f64 * 1e-6 / dt)
            .collect();
        let step = v
            .windows(2)
            .map(|w| (w[1] - w[0]).abs())
            .fold(0.0, f64::max);
        (step, v.iter().map(|x| x.abs()).fold(0.0, f64::max))
    }

    /// One cycle of the acceleration limit, plus the raw targets' rounding (±0.5 µrad each,
    /// 2 µrad in a second difference).
    const STEP_BOUND: f64 = 20.0 * 1e-3 + 2e-6 / 1e-3;

    #[test]
    fn a_preempting_trajectory_from_a_stale_state_is_joined_within_the_limits() {
        let mut b = enabled(fine_plan(), 0);
        follow(&mut b, 0, &[pt(0.0, 0.0, 0.0), pt(1.0, 1.0, 0.0)]);
        b.run(500);
        // Half way at 1.5 rad/s: a goal built from the state of 120 ms ago (its first point,
        // at "now", lies 0.17 rad behind the axis) going on to 0.8 rad.
        let stale = b.targets[b.targets.len() - 120] as f64 * 1e-6;
        let here = *b.targets.last().unwrap();
        follow(&mut b, 0, &[pt(0.0, stale, 1.5), pt(0.5, 0.8, 0.0)]);
        let n = b.targets.len();
        b.run(1500);
        let targets = &b.targets[n - 3..];
        let (step, speed) = wire_motion(targets);
        assert!(
            step <= STEP_BOUND,
            "velocity step {step} rad/s in one cycle"
        );
        assert!(speed <= 3.0 + 1e-3, "{speed}");
        // Never back towards the stale point: the targets only go forward, from where the axis
        // was commanded to be, and end on the new goal.
        assert!(targets.windows(2).all(|w| w[1] >= w[0]), "it went back");
        assert!(targets[3] >= here);
        assert_eq!(*b.targets.last().unwrap(), 800_000);
    }

    #[test]
    fn a_trajectory_started_in_the_past_is_joined_within_the_limits() {
        let mut b = enabled(fine_plan(), 0);
        b.run(10);
        // Stamped 0.9 s ago: the path is 0.9 s into a 0 → 2 rad move over 2 s.
        let n = b.targets.len();
        follow(
            &mut b,
            900_000_000,
            &[pt(0.0, 0.0, 0.0), pt(1.0, 1.0, 1.5), pt(2.0, 2.0, 0.0)],
        );
        b.run(3000);
        let (step, speed) = wire_motion(&b.targets[n - 2..]);
        assert!(
            step <= STEP_BOUND,
            "velocity step {step} rad/s in one cycle"
        );
        assert!(speed <= 3.0 + 1e-3, "{speed}");
        assert_eq!(*b.targets.last().unwrap(), 2_000_000);
        // Wholly in the past: its end, reached within the limits.
        let n = b.targets.len();
        follow(
            &mut b,
            5_000_000_000,
            &[pt(0.0, 2.0, 0.0), pt(1.0, -1.0, 0.0)],
        );
        b.run(3000);
        let (step, speed) = wire_motion(&b.targets[n - 2..]);
        assert!(step <= STEP_BOUND && speed <= 3.0 + 1e-3, "{step} {speed}");
        assert_eq!(*b.targets.last().unwrap(), -1_000_000);
    }

    #[test]
    fn setpoints_after_a_trajectory_are_joined_within_the_limits() {
        let mut b = enabled(fine_plan(), 0);
        follow(&mut b, 0, &[pt(0.0, 0.0, 0.0), pt(1.0, 1.0, 0.0)]);
        b.run(500);
        let n = b.targets.len();
        // A joint command back to 0.1 rad in the middle of the motion, then one far away.
        command(&mut b, SetpointKind::Position, 0.1);
        b.run(1500);
        assert_eq!(*b.targets.last().unwrap(), 100_000);
        command(&mut b, SetpointKind::Position, -2.0);
        b.run(2500);
        assert_eq!(*b.targets.last().unwrap(), -2_000_000);
        let (step, speed) = wire_motion(&b.targets[n - 2..]);
        assert!(step <= STEP_BOUND && speed <= 3.0 + 1e-3, "{step} {speed}");
        // Without an acceleration limit the same command is one velocity-limited jump.
        let mut p = fine_plan();
        p.max_acceleration = f64::INFINITY;
        let mut b = enabled(p, 0);
        command(&mut b, SetpointKind::Position, 1.0);
        let n = b.targets.len();
        b.run(5);
        assert_eq!(b.targets[n + 1] - b.targets[n], 3_000);
    }

    #[test]
    fn a_velocity_target_changes_within_the_acceleration_limit() {
        let mut p = fine_plan();
        p.velocity_scale = 1e-3;
        let mut b = enabled(p, 0);
        set_mode(&mut b, Mode::CyclicVelocity);
        b.run(5);
        command(&mut b, SetpointKind::Velocity, 3.0);
        let mut v = vec![];
        for _ in 0..300 {
            b.cycle(false);
            v.push(read_i32(&b.io, TVEL));
        }
        // 20 rad/s² at 1 ms: 20 mrad/s per cycle, 3 rad/s after 150 cycles.
        assert!(v.windows(2).all(|w| (w[1] - w[0]).abs() <= 20), "{v:?}");
        assert_eq!(*v.last().unwrap(), 3_000);
        assert!(v[100] < 3_000);
    }

    #[test]
    fn cst_holds_the_velocity_limit_and_rests_at_a_position_limit_without_chatter() {
        // plan(): 5 rad/s; the bench's drive makes 20 rad/s² at 2 N·m. The velocity cst acts
        // on comes from the positions read: a µrad encoder (as real joints have), not plan()'s
        // mrad, whose count steps would be most of a cycle's motion.
        let mut p = plan();
        p.deceleration = 10.0;
        p.limits.position_max = 4.0;
        p.position_scale = 1e-6;
        p.velocity_scale = 1e-6;
        let mut b = enabled(p, 0);
        b.torque_gain = TORQUE_GAIN * 1000.0;
        set_mode(&mut b, Mode::CyclicTorque);
        b.run(5);
        command(&mut b, SetpointKind::Torque, 2.0);
        let mut top_speed = 0.0f64;
        let mut velocities = vec![];
        for _ in 0..4000 {
            b.cycle(false);
            top_speed = top_speed.max(b.velocity.abs() * 1e-6);
            velocities.push(b.velocity * 1e-6);
        }
        assert!(top_speed <= 5.0, "{top_speed} rad/s against the limit of 5");
        assert!(top_speed > 4.5, "it went near the limit: {top_speed}");
        assert!(b.status().velocity_clamps > 0);
        // Held at the position limit by the same outward torque: at rest, no chatter.
        assert!(
            b.position <= 4.005e6 && b.position > 3.99e6,
            "{}",
            b.position
        );
        let last = &velocities[velocities.len() - 1000..];
        assert!(
            last.iter().all(|v| v.abs() < 0.05),
            "it chatters: {:?}",
            &last[..20]
        );
    }

    /// A drive as the simulator's arm joints: 8 N·m takes the axis from rest to its velocity
    /// limit of 3 rad/s in about 7 cycles, and a torque written acts one to five cycles later;
    /// the inputs are stale in some cycles.
    /// Holding the limit then needs the speed predicted for when the torque takes effect.
    #[test]
    fn cst_holds_the_velocity_limit_against_a_fast_drive_with_latency() {
        for delay in [1usize, 2, 3, 4, 5] {
            let mut p = fine_plan();
            p.position_scale = 7.67e-6;
            p.velocity_scale = 7.67e-6;
            p.limits.torque_max = 8.0;
            p.limits.position_min = -2.0;
            p.limits.position_max = 2.0;
            let mut b = enabled(p, (-1.8 / 7.67e-6) as i32);
            // 457 rad/s² at 8 N·m (800 raw).
            b.torque_gain = 457.0 / 7.67e-6 / 800.0;
            b.torque_delay = std::iter::repeat_n(0, delay).collect();
            // Stale inputs now and then (the position read repeats), as on a loaded host.
            b.stale_every = &[7, 11];
            set_mode(&mut b, Mode::CyclicTorque);
            b.run(5);
            command(&mut b, SetpointKind::Torque, 8.0);
            let mut positions = vec![];
            for _ in 0..3000 {
                b.cycle(false);
                positions.push(b.position_raw as f64 * 7.67e-6);
            }
            let speed: Vec<f64> = positions
                .windows(11)
                .map(|w| (w[10] - w[0]).abs() / 0.01)
                .collect();
            let top = speed.iter().cloned().fold(0.0, f64::max);
            assert!(top <= 3.0 * 1.05, "delay {delay}: {top} rad/s against 3");
            assert!(top > 2.4, "delay {delay}: it never went fast ({top})");
            assert!(b.status().velocity_clamps > 0);
            let last = &positions[positions.len() - 1000..];
            let hi = last.iter().cloned().fold(f64::MIN, f64::max);
            let lo = last.iter().cloned().fold(f64::MAX, f64::min);
            assert!(hi <= 2.02 && lo > 1.95, "delay {delay}: {lo}..{hi}");
            let still = speed[speed.len() - 990..]
                .iter()
                .cloned()
                .fold(0.0, f64::max);
            assert!(
                still < 0.1,
                "delay {delay}: it chatters at the limit ({still})"
            );
        }
    }

    #[test]
    fn the_axis_gate_is_published_every_cycle() {
        let mut b = Bench::new(plan(), DriveState::SwitchOnDisabled, 0);
        let gate =
            |b: &Bench| AxisGate::unpack(b.ex.gates[0].load(std::sync::atomic::Ordering::Acquire));
        assert!(!gate(&b).published);
        b.cycle(false);
        let g = gate(&b);
        assert!(g.published && g.state == DriveState::SwitchOnDisabled as u8);
        b.command.enable = true;
        b.send();
        b.run(10);
        let g = gate(&b);
        assert_eq!(g.state, DriveState::OperationEnabled as u8);
        assert_ne!(g.flags & status_flags::ENABLE_WANTED, 0);
        assert_eq!(g.flags, b.status().flags);
        let w = AxisGate {
            state: 7,
            flags: 0xABCD,
            error_code: 0x7500,
            last_fault_code: 0x2310,
            published: true,
        };
        assert_eq!(AxisGate::unpack(w.pack()), w);
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
            enable_count: 3,
            homing_count: 4,
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
            homing_runs: 7,
            command_seq: 6,
            desired_velocity: -0.5,
            target_velocity: 0.75,
            target_torque: -1.5,
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
