//! The records the axis stage exchanges with other threads, as fixed-size little-endian bytes:
//! the command of every axis (one seqlock buffer for all axes, so a multi-axis command is
//! taken over in one cycle), each axis's trajectory points, and the status of every axis.

use super::{AxisPlan, Mode};
use crate::handover::SeqBuffer;
use std::sync::atomic::AtomicU64;

/// What the command slot of an axis holds (the latest of each request).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisCommand {
    /// Wanted in Operation Enabled (false: the `on_stop` command).
    pub enable: bool,
    /// The mode of operation wanted.
    pub mode: Mode,
    /// Incremented for every fault reset asked for.
    pub reset_count: u32,
    /// Incremented for every setpoint or trajectory (one number for the whole engine, so the
    /// axes of one multi-axis trajectory share it): the newest wins.
    pub seq: u64,
    /// 0: the last command is a trajectory, else a SetpointKind code.
    pub setpoint_kind: u8,
    /// The setpoint value (SI) of a setpoint command.
    pub value: f64,
    /// When the setpoint arrived (CLOCK_MONOTONIC ns), or the trajectory's start.
    pub t_ns: i64,
    /// Points in the axis's trajectory slot for a trajectory command.
    pub trajectory_len: u32,
    /// Incremented by every explicit enable: the deliberate action a blocked restart waits for.
    pub enable_count: u32,
    /// Incremented by every request to start homing (mode hm).
    pub homing_count: u32,
}

/// Encoded size of an AxisCommand.
pub const COMMAND_LEN: usize = 48;

impl AxisCommand {
    /// The command an axis starts with: disabled, in `mode`, nothing to follow.
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
            enable_count: 0,
            homing_count: 0,
        }
    }

    /// Write the command into its slot bytes `b`.
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
        b[36..40].copy_from_slice(&self.enable_count.to_le_bytes());
        b[40..44].copy_from_slice(&self.homing_count.to_le_bytes());
        b[44..48].fill(0);
    }

    /// Read a command from its slot bytes `b`.
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
            enable_count: u32_at(36),
            homing_count: u32_at(40),
        }
    }
}

/// One trajectory point: `t_ns` after the trajectory's start, position and velocity (SI).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Point {
    /// Time after the trajectory's start (ns).
    pub t_ns: i64,
    /// Position (SI).
    pub position: f64,
    /// Velocity (SI).
    pub velocity: f64,
}

/// Bytes of one trajectory point: t (ns since start) i64, position f64, velocity f64.
pub const POINT_LEN: usize = 24;
/// The trajectory slot starts with the `seq` of the command the points belong to (u64), so the
/// RT thread never runs one command with another's points.
pub const TRAJECTORY_HEADER: usize = 8;

impl Point {
    /// Write the point into its slot bytes `b`.
    pub fn encode(&self, b: &mut [u8]) {
        b[0..8].copy_from_slice(&self.t_ns.to_le_bytes());
        b[8..16].copy_from_slice(&self.position.to_le_bytes());
        b[16..24].copy_from_slice(&self.velocity.to_le_bytes());
    }

    /// Read a point from its slot bytes `b`.
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
    /// The actual position is outside `position_limits`.
    pub const OUTSIDE_LIMITS: u16 = 1 << 7;
    /// Wanted enabled, but kept out of Operation Enabled until an explicit enable (restart:
    /// manual after a panic, a watchdog stop or a fault; or an axis outside its limits).
    pub const RESTART_BLOCKED: u16 = 1 << 8;
    /// A position limit cut the command this cycle (clamp, or braking in csv/pv/cst).
    pub const LIMIT_ACTIVE: u16 = 1 << 9;
    /// The axis needs no live commander: not enabled, or holding still (position mode with
    /// the target at rest, zero velocity or torque) and no trajectory running.
    pub const IDLE: u16 = 1 << 10;
    /// Homing: the drive reports homing attained (hm, statusword bit 12 with target reached).
    pub const HOMING_ATTAINED: u16 = 1 << 11;
    /// Homing: the drive reports a homing error (hm, statusword bit 13).
    pub const HOMING_ERROR: u16 = 1 << 12;
    /// Homing was started and is in progress (neither attained nor error yet).
    pub const HOMING_ACTIVE: u16 = 1 << 13;
    /// The last trajectory ended before its end without a newer command: the axis left the
    /// state it needs (mode change, disable, fault, quick stop, panic, watchdog) or another
    /// axis of the same trajectory did (this one then makes a quiet stop). Until the next
    /// command, so a caller waiting for the trajectory learns it will not end by itself.
    pub const TRAJECTORY_STOPPED: u16 = 1 << 14;
}

/// What the RT thread publishes about an axis every cycle.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AxisStatus {
    /// The cycle the status is of.
    pub cycle: u64,
    /// Statusword as read.
    pub statusword: u16,
    /// Controlword as sent.
    pub controlword: u16,
    /// Drive state decoded from the statusword (`DriveState` code).
    pub state: u8,
    /// Modes of operation display as read.
    pub mode_display: i8,
    /// Status flags (`status_flags`).
    pub flags: u16,
    /// Error code (0x603F) as read.
    pub error_code: u16,
    /// The error code seen when the last fault was detected.
    pub last_fault_code: u16,
    /// Position actual value, raw.
    pub position_raw: i32,
    /// Velocity actual value, raw.
    pub velocity_raw: i32,
    /// Torque actual value, raw.
    pub torque_raw: i16,
    /// Following error, raw.
    pub following_error_raw: i32,
    /// Position target sent this cycle, raw.
    pub target_position_raw: i32,
    /// Position (SI).
    pub position: f64,
    /// Velocity (SI).
    pub velocity: f64,
    /// Torque (SI).
    pub torque: f64,
    /// Following error (SI).
    pub following_error: f64,
    /// The position target sent this cycle (SI).
    pub target_position: f64,
    /// Position setpoints clamped to the limits so far.
    pub position_clamps: u32,
    /// Velocity setpoints clamped so far.
    pub velocity_clamps: u32,
    /// Torque setpoints clamped so far.
    pub torque_clamps: u32,
    /// Faults the drive reported so far.
    pub faults: u32,
    /// Fault resets sent so far.
    pub fault_resets: u32,
    /// Homing runs ended (attained or error) so far.
    pub homing_runs: u32,
    /// `seq` of the last command taken over.
    pub command_seq: u64,
    /// The velocity the axis is commanded to have this cycle (SI): the trajectory's or the
    /// interpolation's slope in a position mode, the velocity target in a velocity mode.
    pub desired_velocity: f64,
    /// The velocity and torque targets sent this cycle (SI; 0 when not mapped or not used).
    pub target_velocity: f64,
    /// The torque target sent this cycle (SI; 0 when not mapped or not used).
    pub target_torque: f64,
}

/// Encoded size of an AxisStatus.
pub const STATUS_LEN: usize = 144;

impl AxisStatus {
    /// Write the status into its buffer bytes `b`.
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
        b[100..104].copy_from_slice(&self.homing_runs.to_le_bytes());
        b[104..112].copy_from_slice(&self.command_seq.to_le_bytes());
        b[112..120].copy_from_slice(&self.desired_velocity.to_le_bytes());
        b[120..128].copy_from_slice(&self.target_velocity.to_le_bytes());
        b[128..136].copy_from_slice(&self.target_torque.to_le_bytes());
        b[136..144].fill(0);
    }

    /// Read a status from its buffer bytes `b`.
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
            homing_runs: u32_at(100),
            command_seq: u64_at(104),
            desired_velocity: f64_at(112),
            target_velocity: f64_at(120),
            target_torque: f64_at(128),
        }
    }
}

/// What a command path must know of an axis before it hands the axis a setpoint (is it in a
/// state to move?), published by the RT thread every cycle in one atomic word per axis: read
/// without a lock and without allocating (the native joint command path reads it for every
/// command, `AxisExchange::gates`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AxisGate {
    /// The drive's state (`DriveState` as u8).
    pub state: u8,
    /// `status_flags` of the cycle.
    pub flags: u16,
    /// The drive's error code (0x603F) of the cycle.
    pub error_code: u16,
    /// The code of the drive's last fault, kept after the fault is reset (names a stop).
    pub last_fault_code: u16,
    /// False until the RT thread has run the axis once.
    pub published: bool,
}

impl AxisGate {
    /// The gate as the one atomic word the RT thread stores (state, flags, codes, published).
    pub fn pack(self) -> u64 {
        self.state as u64
            | (self.flags as u64) << 8
            | (self.error_code as u64) << 24
            | (self.last_fault_code as u64) << 40
            | (self.published as u64) << 63
    }

    /// The gate a word from `pack` holds.
    pub fn unpack(w: u64) -> AxisGate {
        AxisGate {
            state: w as u8,
            flags: (w >> 8) as u16,
            error_code: (w >> 24) as u16,
            last_fault_code: (w >> 40) as u16,
            published: w >> 63 != 0,
        }
    }
}

/// The hand-over buffers of all axes for one cyclic run (shared by the engine and the RT
/// thread): the commands of all axes in one buffer (a multi-axis command is one write, taken
/// over in one cycle), one trajectory slot per axis, one status buffer for all.
pub struct AxisExchange {
    /// The commands of all axes (one write per multi-axis command).
    pub commands: SeqBuffer,
    /// One trajectory slot per axis.
    pub trajectories: Vec<SeqBuffer>,
    /// The statuses of all axes, written by the RT thread every cycle.
    pub status: SeqBuffer,
    /// `AxisGate::pack` per axis, stored by the RT thread every cycle.
    pub gates: Box<[AtomicU64]>,
    /// Points a trajectory slot holds.
    pub trajectory_capacity: usize,
}

impl AxisExchange {
    /// The buffers for `axes`, each slot with room for `trajectory_capacity` points.
    pub fn new(axes: &[AxisPlan], trajectory_capacity: usize) -> AxisExchange {
        let mut commands = vec![0u8; axes.len() * COMMAND_LEN];
        for (a, b) in axes.iter().zip(commands.chunks_exact_mut(COMMAND_LEN)) {
            AxisCommand::initial(a.mode).encode(b);
        }
        AxisExchange {
            commands: SeqBuffer::new(&commands),
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
            gates: axes.iter().map(|_| AtomicU64::new(0)).collect(),
            trajectory_capacity,
        }
    }

    /// Number of axes.
    pub fn len(&self) -> usize {
        self.trajectories.len()
    }

    /// True when there is no axis.
    pub fn is_empty(&self) -> bool {
        self.trajectories.is_empty()
    }
}
