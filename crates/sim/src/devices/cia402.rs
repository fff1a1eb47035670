//! A CiA 402 servo drive (IEC 61800-7-201 / ETG.6010) with one or more axes: the power drive
//! state machine, the modes CSP, CSV, CST, PP, PV and HM, following-error supervision, fault
//! handling with CoE emergencies, and behind each axis a motor + gear + load (`servo_motor`).
//!
//! The drive finds its axes in the object dictionary: axis n (0-based) owns the standard
//! objects at `index + n·0x800` (0x6040, 0x6840, ...), as in devices/servo_drive.xml. It reads
//! its commands and configuration from and writes its feedback to those objects, so it works
//! with whatever PDO mapping the master chose; the ESC latches the mapped outputs at SYNC0 in
//! DC mode (on the frame in free run), and the drive runs its own 8 kHz loop in between.
//!
//! Units: positions in motor encoder increments (0x608F: counts per motor revolution),
//! velocities in increments/s, accelerations in increments/s², torques in per mille of the
//! motor rated torque 0x6076 (mNm). One joint revolution is `counts_per_rev · gear_ratio`
//! increments. What is modelled and what is not: docs/cia402-simulator.md.

use super::od_slots::OdSlots;
use super::period_clock::PeriodClock;
use super::servo_motor::{limit, Cascade, Mechanics, MotorParams};
use crate::device::{DeviceApp, Emergency};
use crate::od::{dtype, Access, Entry, ObjectDictionary};
use ether_ros_protocol::cia402::object;

/// Drive loop period: 8 kHz (position and velocity loops).
pub const PERIOD_NS: u64 = 125_000;
/// Physics steps per drive period (62.5 µs each).
const SUBSTEPS: u32 = 2;
/// Longest stretch of time one `step` catches up on (100 ms).
const MAX_CATCH_UP_PERIODS: u64 = 800;
/// Axes a drive may have (objects up to 0x6040 + 7·0x800 = 0x9840; eight is ETG.6010's limit).
pub const MAX_AXES: usize = object::MAX_AXES as usize;
/// Object index distance between axes (ETG.6010 multi-axis layout).
pub const AXIS_OFFSET: u16 = object::AXIS_OFFSET;
/// Motor speed under which a stop (quick stop, fault reaction, halt) counts as done, rad/s.
const STANDSTILL_SPEED: f64 = 0.5;
/// Interpolation period when 0x60C2 holds no usable value, s.
const DEFAULT_INTERPOLATION_S: f64 = 1e-3;

/// The objects of one axis (index at axis 1), resolved once into `OdSlots` (slot = position),
/// with the value the drive uses when the dictionary lacks the object (a vendor ESI without it):
/// the defaults of devices/servo_drive.xml.
const AXIS_KEYS: [(u16, u8, i64); 47] = [
    (object::CONTROLWORD, 0, 0),                           // 0
    (object::MODES_OF_OPERATION, 0, 0),                    // 1
    (object::TARGET_POSITION, 0, 0),                       // 2
    (object::TARGET_VELOCITY, 0, 0),                       // 3
    (object::TARGET_TORQUE, 0, 0),                         // 4
    (object::STATUSWORD, 0, 0),                            // 5
    (object::MODES_OF_OPERATION_DISPLAY, 0, 0),            // 6
    (object::POSITION_ACTUAL, 0, 0),                       // 7
    (object::VELOCITY_ACTUAL, 0, 0),                       // 8
    (object::TORQUE_ACTUAL, 0, 0),                         // 9
    (object::ERROR_CODE, 0, 0),                            // 10
    (object::FOLLOWING_ERROR_ACTUAL, 0, 0),                // 11
    (object::FOLLOWING_ERROR_WINDOW, 0, 16_384),           // 12
    (object::FOLLOWING_ERROR_TIMEOUT, 0, 10),              // 13 (ms)
    (object::SUPPORTED_MODES, 0, 0x3A5),                   // 14
    (object::MOTOR_RATED_TORQUE, 0, 200),                  // 15 (mNm)
    (object::MAX_TORQUE, 0, 3000),                         // 16 (per mille)
    (object::MAX_MOTOR_SPEED, 0, 6000),                    // 17 (rpm)
    (object::QUICK_STOP_OPTION, 0, 2),                     // 18
    (object::QUICK_STOP_DECELERATION, 0, 1_638_400),       // 19
    (object::SOFTWARE_POSITION_LIMIT, 1, i32::MIN as i64), // 20 min
    (object::SOFTWARE_POSITION_LIMIT, 2, i32::MAX as i64), // 21 max
    (object::INTERPOLATION_TIME_PERIOD, 1, 1),             // 22 value
    (object::INTERPOLATION_TIME_PERIOD, 2, -3),            // 23 index
    (object::PROFILE_VELOCITY, 0, 16_384),                 // 24
    (object::PROFILE_ACCELERATION, 0, 163_840),            // 25
    (object::PROFILE_DECELERATION, 0, 163_840),            // 26
    (object::HOMING_METHOD, 0, 37),                        // 27
    (object::HOME_OFFSET, 0, 0),                           // 28
    (object::POSITION_WINDOW, 0, 163),                     // 29
    (object::VELOCITY_WINDOW, 0, 1_638),                   // 30
    (object::POSITION_ENCODER_RESOLUTION, 1, 16_384),      // 31 increments
    (object::POSITION_ENCODER_RESOLUTION, 2, 1),           // 32 motor revolutions
    (object::GEAR_RATIO, 1, 50),                           // 33 motor revolutions
    (object::GEAR_RATIO, 2, 1),                            // 34 shaft revolutions
    (object::VELOCITY_OFFSET, 0, 0),                       // 35
    (object::TORQUE_OFFSET, 0, 0),                         // 36 (per mille)
    (object::TOUCH_PROBE_FUNCTION, 0, 0),                  // 37
    (object::TOUCH_PROBE_STATUS, 0, 0),                    // 38
    (object::TOUCH_PROBE_1_POSITIVE, 0, 0),                // 39
    (object::TOUCH_PROBE_1_NEGATIVE, 0, 0),                // 40
    (object::DIGITAL_INPUTS, 0, 0),                        // 41
    (object::DIGITAL_OUTPUTS, 1, 0),                       // 42 physical outputs
    (object::DIGITAL_OUTPUTS, 2, 0xFFFF_0000),             // 43 bit mask
    (object::HOMING_SPEEDS, 1, 16_384),                    // 44 search for the switch
    (object::HOMING_SPEEDS, 2, 4_096),                     // 45 search for zero
    (object::HOMING_ACCELERATION, 0, 163_840),             // 46
];
/// Data type and bit length of each `AXIS_KEYS` object (as in devices/servo_drive.xml).
const AXIS_TYPES: [(u16, u16); 47] = [
    (dtype::UINT16, 16), // 0x6040:0
    (dtype::INT8, 8),    // 0x6060:0
    (dtype::INT32, 32),  // 0x607A:0
    (dtype::INT32, 32),  // 0x60FF:0
    (dtype::INT16, 16),  // 0x6071:0
    (dtype::UINT16, 16), // 0x6041:0
    (dtype::INT8, 8),    // 0x6061:0
    (dtype::INT32, 32),  // 0x6064:0
    (dtype::INT32, 32),  // 0x606C:0
    (dtype::INT16, 16),  // 0x6077:0
    (dtype::UINT16, 16), // 0x603F:0
    (dtype::INT32, 32),  // 0x60F4:0
    (dtype::UINT32, 32), // 0x6065:0
    (dtype::UINT16, 16), // 0x6066:0
    (dtype::UINT32, 32), // 0x6502:0
    (dtype::UINT32, 32), // 0x6076:0
    (dtype::UINT16, 16), // 0x6072:0
    (dtype::UINT32, 32), // 0x6080:0
    (dtype::INT16, 16),  // 0x605A:0
    (dtype::UINT32, 32), // 0x6085:0
    (dtype::INT32, 32),  // 0x607D:1
    (dtype::INT32, 32),  // 0x607D:2
    (dtype::UINT8, 8),   // 0x60C2:1
    (dtype::INT8, 8),    // 0x60C2:2
    (dtype::UINT32, 32), // 0x6081:0
    (dtype::UINT32, 32), // 0x6083:0
    (dtype::UINT32, 32), // 0x6084:0
    (dtype::INT8, 8),    // 0x6098:0
    (dtype::INT32, 32),  // 0x607C:0
    (dtype::UINT32, 32), // 0x6067:0
    (dtype::UINT16, 16), // 0x606D:0
    (dtype::UINT32, 32), // 0x608F:1
    (dtype::UINT32, 32), // 0x608F:2
    (dtype::UINT32, 32), // 0x6091:1
    (dtype::UINT32, 32), // 0x6091:2
    (dtype::INT32, 32),  // 0x60B1:0
    (dtype::INT16, 16),  // 0x60B2:0
    (dtype::UINT16, 16), // 0x60B8:0
    (dtype::UINT16, 16), // 0x60B9:0
    (dtype::INT32, 32),  // 0x60BA:0
    (dtype::INT32, 32),  // 0x60BB:0
    (dtype::UINT32, 32), // 0x60FD:0
    (dtype::UINT32, 32), // 0x60FE:1
    (dtype::UINT32, 32), // 0x60FE:2
    (dtype::UINT32, 32), // 0x6099:1
    (dtype::UINT32, 32), // 0x6099:2
    (dtype::UINT32, 32), // 0x609A:0
];

/// The dictionary of a drive with `axes` axes as devices/servo_drive.xml describes it (the axis
/// objects and 0x1001), for tests and for running the model without an ESI.
pub fn dictionary(axes: usize) -> ObjectDictionary {
    let mut od = ObjectDictionary::new();
    let mut add = |index: u16, subindex: u8, data_type: u16, bits: u16, value: i64| {
        od.add_entry(Entry {
            index,
            subindex,
            name: String::new(),
            data_type,
            bit_length: bits,
            access: Access::ReadWrite,
            pdo_mappable: true,
            value: value.to_le_bytes()[..usize::from(bits / 8)].to_vec(),
        });
    };
    for n in 0..axes.min(MAX_AXES) as u16 {
        for ((index, sub, value), (t, bits)) in AXIS_KEYS.into_iter().zip(AXIS_TYPES) {
            add(index + n * AXIS_OFFSET, sub, t, bits, value);
        }
    }
    add(ERROR_REGISTER[0].0, ERROR_REGISTER[0].1, dtype::UINT8, 8, 0);
    od
}

mod slot {
    pub const CONTROLWORD: usize = 0;
    pub const MODE: usize = 1;
    pub const TARGET_POSITION: usize = 2;
    pub const TARGET_VELOCITY: usize = 3;
    pub const TARGET_TORQUE: usize = 4;
    pub const STATUSWORD: usize = 5;
    pub const MODE_DISPLAY: usize = 6;
    pub const POSITION_ACTUAL: usize = 7;
    pub const VELOCITY_ACTUAL: usize = 8;
    pub const TORQUE_ACTUAL: usize = 9;
    pub const ERROR_CODE: usize = 10;
    pub const FOLLOWING_ERROR: usize = 11;
    pub const FE_WINDOW: usize = 12;
    pub const FE_TIMEOUT: usize = 13;
    pub const SUPPORTED_MODES: usize = 14;
    pub const RATED_TORQUE: usize = 15;
    pub const MAX_TORQUE: usize = 16;
    pub const MAX_SPEED: usize = 17;
    pub const QS_OPTION: usize = 18;
    pub const QS_DECEL: usize = 19;
    pub const SW_LIMIT_MIN: usize = 20;
    pub const SW_LIMIT_MAX: usize = 21;
    pub const INTERP_VALUE: usize = 22;
    pub const INTERP_INDEX: usize = 23;
    pub const PROFILE_VELOCITY: usize = 24;
    pub const PROFILE_ACCEL: usize = 25;
    pub const PROFILE_DECEL: usize = 26;
    pub const HOMING_METHOD: usize = 27;
    pub const HOME_OFFSET: usize = 28;
    pub const POSITION_WINDOW: usize = 29;
    pub const VELOCITY_WINDOW: usize = 30;
    pub const ENCODER_INCREMENTS: usize = 31;
    pub const ENCODER_REVOLUTIONS: usize = 32;
    pub const GEAR_MOTOR: usize = 33;
    pub const GEAR_SHAFT: usize = 34;
    pub const VELOCITY_OFFSET: usize = 35;
    pub const TORQUE_OFFSET: usize = 36;
    pub const PROBE_FUNCTION: usize = 37;
    pub const PROBE_STATUS: usize = 38;
    pub const PROBE_POSITIVE: usize = 39;
    pub const PROBE_NEGATIVE: usize = 40;
    pub const DIGITAL_INPUTS: usize = 41;
    pub const DIGITAL_OUTPUTS: usize = 42;
    pub const DIGITAL_OUTPUTS_MASK: usize = 43;
    pub const HOMING_SPEED_SWITCH: usize = 44;
    pub const HOMING_SPEED_ZERO: usize = 45;
    pub const HOMING_ACCEL: usize = 46;
}
/// The device's error register (CiA 301), shared by the axes.
const ERROR_REGISTER: [(u16, u8); 1] = [(ether_ros_protocol::coe::ERROR_REGISTER, 0)];

/// The standard's facts — modes, statusword and controlword bits, the states and their
/// coding, the device control commands — are the protocol crate's.
pub use ether_ros_protocol::cia402::{cw, sw, Command, State};

/// Modes of operation (0x6060 values), and the ones this model implements.
pub mod mode {
    pub use ether_ros_protocol::cia402::mode::*;

    /// The modes this model implements.
    pub const IMPLEMENTED: [i8; 6] = [PP, PV, HM, CSP, CSV, CST];

    /// The 0x6502 mask of a mode (bit 0 PP ... bit 9 CST), None for modes without one.
    pub fn supported_mask(m: i8) -> Option<u32> {
        supported_bit(m).map(|b| 1u32 << b)
    }
}

/// The controlword transitions of the state diagram (IEC 61800-7-201, transitions 2–12, 15,
/// 16): `(transition number, next state)` for `controlword` (with `previous` for the fault
/// reset edge) in `state`, or None to stay. `quick_stop_stays` is true for quick stop option
/// codes 5–8 (transition 16 allowed). Transitions 0, 1, 13, 14 and the automatic 12 are not
/// caused by the controlword and are made by the drive itself.
pub fn transition(
    state: State,
    controlword: u16,
    previous: u16,
    quick_stop_stays: bool,
) -> Option<(u8, State)> {
    use Command::*;
    use State::*;
    let fault_reset = controlword & cw::FAULT_RESET != 0 && previous & cw::FAULT_RESET == 0;
    match (state, Command::decode(controlword)) {
        (Fault, _) if fault_reset => Some((15, SwitchOnDisabled)),
        (SwitchOnDisabled, Shutdown) => Some((2, ReadyToSwitchOn)),
        (ReadyToSwitchOn, SwitchOn | EnableOperation) => Some((3, SwitchedOn)),
        (ReadyToSwitchOn, DisableVoltage | QuickStop) => Some((7, SwitchOnDisabled)),
        (SwitchedOn, EnableOperation) => Some((4, OperationEnabled)),
        (SwitchedOn, Shutdown) => Some((6, ReadyToSwitchOn)),
        (SwitchedOn, DisableVoltage | QuickStop) => Some((10, SwitchOnDisabled)),
        (OperationEnabled, SwitchOn) => Some((5, SwitchedOn)),
        (OperationEnabled, Shutdown) => Some((8, ReadyToSwitchOn)),
        (OperationEnabled, DisableVoltage) => Some((9, SwitchOnDisabled)),
        (OperationEnabled, QuickStop) => Some((11, QuickStopActive)),
        (QuickStopActive, DisableVoltage) => Some((12, SwitchOnDisabled)),
        (QuickStopActive, EnableOperation) if quick_stop_stays => Some((16, OperationEnabled)),
        _ => None,
    }
}

/// How the drive stops (quick stop option code 0x605A, fault reaction).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StopRamp {
    /// Power stage off at once: the motor coasts.
    Coast,
    /// Ramp the speed down at this deceleration (rad/s², motor).
    Decelerate(f64),
    /// Stop at the torque limit.
    TorqueLimit,
}

/// The ramp and whether the drive stays in Quick stop active afterwards, for a quick stop
/// option code; `profile` and `quick` are 0x6084 and 0x6085 in rad/s².
pub fn quick_stop_ramp(code: i64, profile: f64, quick: f64) -> (StopRamp, bool) {
    let decel = |d: f64| {
        if d > 0.0 {
            StopRamp::Decelerate(d)
        } else {
            StopRamp::TorqueLimit
        }
    };
    match code {
        0 => (StopRamp::Coast, false),
        1 => (decel(profile), false),
        3 | 4 => (StopRamp::TorqueLimit, false),
        5 => (decel(profile), true),
        6 => (decel(quick), true),
        7 | 8 => (StopRamp::TorqueLimit, true),
        // 2, and manufacturer-specific (negative) or reserved codes: the quick stop ramp.
        _ => (decel(quick), false),
    }
}

/// Faults the drive knows (detected or injected).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DriveFault {
    /// Over-current in the power stage (CiA 402 error code 0x2310).
    OverCurrent,
    /// Encoder signal lost (error code 0x7305).
    Encoder,
    /// DC link under-voltage (error code 0x3220).
    UnderVoltage,
    /// Following error beyond the configured window (error code 0x8611).
    FollowingError,
    /// Process data stopped (not OP, or the watchdog expired) while the power stage was on.
    Communication,
}

impl DriveFault {
    /// Names accepted by `inject_fault` (the simulator's `drive_fault`).
    pub const INJECTABLE: [(&'static str, DriveFault); 4] = [
        ("over_current", DriveFault::OverCurrent),
        ("encoder", DriveFault::Encoder),
        ("under_voltage", DriveFault::UnderVoltage),
        ("following_error", DriveFault::FollowingError),
    ];

    /// The error code (0x603F, CiA 402 / CiA 301 tables).
    pub fn error_code(self) -> u16 {
        match self {
            DriveFault::OverCurrent => 0x2310,
            DriveFault::Encoder => 0x7305,
            DriveFault::UnderVoltage => 0x3220,
            DriveFault::FollowingError => 0x8611,
            DriveFault::Communication => 0x8130,
        }
    }

    /// Error register bits (0x1001): generic error plus current, voltage, communication or
    /// device profile specific.
    pub fn error_register(self) -> u8 {
        0x01 | match self {
            DriveFault::OverCurrent => 0x02,
            DriveFault::UnderVoltage => 0x04,
            DriveFault::Communication => 0x10,
            DriveFault::Encoder | DriveFault::FollowingError => 0x20,
        }
    }

    /// The fault reaction: faults that leave the drive unable to control the motor (no
    /// current, no DC link, no position) switch the power stage off at once; the others stop
    /// on the quick stop ramp first.
    fn reaction(self, quick: f64) -> StopRamp {
        match self {
            DriveFault::OverCurrent | DriveFault::Encoder | DriveFault::UnderVoltage => {
                StopRamp::Coast
            }
            DriveFault::FollowingError | DriveFault::Communication => {
                quick_stop_ramp(2, quick, quick).0
            }
        }
    }
}

/// Simulation parameters of a `cia402` slave (`sim.params`), the same for every axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cia402Config {
    /// The motor model of every axis.
    pub motor: MotorParams,
    /// Where the home and limit switches sit.
    pub switches: Switches,
}

/// Where the drive's switches sit, as joint angles (rad): the home switch is active from
/// `home` upwards; the limit switches at ±`limit` (0: none).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Switches {
    /// Joint angle (rad) from which the home switch is active.
    pub home: f64,
    /// Joint angle magnitude (rad) of the limit switches (0: none).
    pub limit: f64,
}

impl Default for Switches {
    fn default() -> Self {
        Switches {
            home: 0.05,
            limit: 0.0,
        }
    }
}

impl Cia402Config {
    /// Names accepted in `sim.params`.
    pub const PARAMS: &'static [&'static str] = &[
        "motor_inertia_kg_m2",
        "load_inertia_kg_m2",
        "viscous_friction_nm_s_per_rad",
        "coulomb_friction_nm",
        "encoder_counts_per_rev",
        "gear_ratio",
        "rated_torque_nm",
        "velocity_loop_hz",
        "position_loop_hz",
        "home_switch_rad",
        "limit_switch_rad",
    ];

    /// The configuration from the bus config's `sim.params`; an unknown or invalid parameter is
    /// an error naming it.
    pub fn from_params(params: &[(String, f64)]) -> Result<Self, String> {
        let mut m = MotorParams::default();
        let mut switches = Switches::default();
        for (name, value) in params {
            let v = *value;
            match name.as_str() {
                "home_switch_rad" if v.is_finite() => {
                    switches.home = v;
                    continue;
                }
                "limit_switch_rad" if v.is_finite() && v >= 0.0 => {
                    switches.limit = v;
                    continue;
                }
                "home_switch_rad" | "limit_switch_rad" => {
                    return Err(format!(
                        "cia402: parameter '{name}' must be a finite number{}, got {v}",
                        if name == "limit_switch_rad" {
                            " >= 0"
                        } else {
                            ""
                        }
                    ))
                }
                _ => {}
            }
            let positive = matches!(
                name.as_str(),
                "motor_inertia_kg_m2"
                    | "encoder_counts_per_rev"
                    | "gear_ratio"
                    | "rated_torque_nm"
                    | "velocity_loop_hz"
                    | "position_loop_hz"
            );
            if !v.is_finite() || v < 0.0 || (positive && v == 0.0) {
                let want = if positive { "> 0" } else { ">= 0" };
                return Err(format!(
                    "cia402: parameter '{name}' must be a number {want}, got {v}"
                ));
            }
            match name.as_str() {
                "motor_inertia_kg_m2" => m.motor_inertia = v,
                "load_inertia_kg_m2" => m.load_inertia = v,
                "viscous_friction_nm_s_per_rad" => m.viscous_friction = v,
                "coulomb_friction_nm" => m.coulomb_friction = v,
                "encoder_counts_per_rev" if v.fract() == 0.0 && v <= f64::from(u32::MAX) => {
                    m.counts_per_rev = v
                }
                "gear_ratio" => m.gear_ratio = v,
                "rated_torque_nm" => m.rated_torque = v,
                "velocity_loop_hz" => m.velocity_loop_hz = v,
                "position_loop_hz" => m.position_loop_hz = v,
                "encoder_counts_per_rev" => {
                    return Err(format!(
                        "cia402: parameter 'encoder_counts_per_rev' must be a whole number of \
                         increments (1..2^32-1), got {v}"
                    ))
                }
                other => {
                    return Err(format!(
                        "cia402: unknown parameter '{other}' (known: {})",
                        Self::PARAMS.join(", ")
                    ))
                }
            }
        }
        // The loops run at 8 kHz: a velocity loop faster than ~1/10 of it would be unstable.
        let max_hz = 1e9 / PERIOD_NS as f64 / 10.0;
        if m.velocity_loop_hz > max_hz || m.position_loop_hz > m.velocity_loop_hz {
            return Err(format!(
                "cia402: loop bandwidths must satisfy position_loop_hz <= velocity_loop_hz <= \
                 {max_hz} (got {} and {})",
                m.position_loop_hz, m.velocity_loop_hz
            ));
        }
        Ok(Self { motor: m, switches })
    }
}

/// The commands and settings of one axis, read from the dictionary once per `step`.
#[derive(Clone, Copy, Debug, Default)]
struct Inputs {
    controlword: u16,
    mode: i8,
    target_position: i64,
    target_velocity: i64,
    target_torque: i64,
    fe_window: i64,
    fe_timeout_s: f64,
    supported_modes: u32,
    rated_torque_nm: f64,
    max_torque_permille: f64,
    max_speed: f64,
    quick_stop_option: i64,
    quick_stop_decel: f64,
    sw_limits: Option<(i64, i64)>,
    interpolation_s: f64,
    profile_velocity: f64,
    profile_accel: f64,
    profile_decel: f64,
    homing_method: i64,
    home_offset: i64,
    position_window: f64,
    velocity_window: f64,
    /// 0x60B1 (motor rad/s) and 0x60B2 (per mille): feed-forward added to the commands.
    velocity_offset: f64,
    torque_offset_permille: f64,
    probe_function: u16,
    /// 0x60FE:1 masked by 0x60FE:2.
    digital_outputs: u32,
    /// 0x6099:1, :2 (motor rad/s) and 0x609A (motor rad/s²).
    homing_speed_switch: f64,
    homing_speed_zero: f64,
    homing_accel: f64,
}

impl Inputs {
    /// Read the axis's objects; speeds and accelerations converted to rad/s (motor).
    fn read(od: &ObjectDictionary, slots: &OdSlots, m: &MotorParams) -> Inputs {
        let s = Fallback(slots);
        let per_rad = m.counts_per_rad();
        let (min, max) = (s.get(od, slot::SW_LIMIT_MIN), s.get(od, slot::SW_LIMIT_MAX));
        let interp = s.get(od, slot::INTERP_VALUE) as f64
            * 10f64.powi(s.get(od, slot::INTERP_INDEX).clamp(-9, 2) as i32);
        let rated_mnm = s.get(od, slot::RATED_TORQUE);
        Inputs {
            controlword: s.get(od, slot::CONTROLWORD) as u16,
            mode: s.get(od, slot::MODE) as i8,
            target_position: s.get(od, slot::TARGET_POSITION),
            target_velocity: s.get(od, slot::TARGET_VELOCITY),
            target_torque: s.get(od, slot::TARGET_TORQUE),
            fe_window: s.get(od, slot::FE_WINDOW),
            fe_timeout_s: s.get(od, slot::FE_TIMEOUT) as f64 * 1e-3,
            supported_modes: s.get(od, slot::SUPPORTED_MODES) as u32,
            rated_torque_nm: if rated_mnm > 0 {
                rated_mnm as f64 * 1e-3
            } else {
                m.rated_torque
            },
            max_torque_permille: s.get(od, slot::MAX_TORQUE) as f64,
            // 0x6080 is in rpm of the motor.
            max_speed: s.get(od, slot::MAX_SPEED) as f64 * std::f64::consts::TAU / 60.0,
            quick_stop_option: s.get(od, slot::QS_OPTION),
            quick_stop_decel: s.get(od, slot::QS_DECEL) as f64 / per_rad,
            sw_limits: (min < max).then_some((min, max)),
            interpolation_s: if interp > 0.0 && interp <= 1.0 {
                interp
            } else {
                DEFAULT_INTERPOLATION_S
            },
            profile_velocity: s.get(od, slot::PROFILE_VELOCITY) as f64 / per_rad,
            profile_accel: s.get(od, slot::PROFILE_ACCEL) as f64 / per_rad,
            profile_decel: s.get(od, slot::PROFILE_DECEL) as f64 / per_rad,
            homing_method: s.get(od, slot::HOMING_METHOD),
            home_offset: s.get(od, slot::HOME_OFFSET),
            position_window: s.get(od, slot::POSITION_WINDOW) as f64 / per_rad,
            velocity_window: s.get(od, slot::VELOCITY_WINDOW) as f64 / per_rad,
            velocity_offset: s.get(od, slot::VELOCITY_OFFSET) as f64 / per_rad,
            torque_offset_permille: s.get(od, slot::TORQUE_OFFSET) as f64,
            probe_function: s.get(od, slot::PROBE_FUNCTION) as u16,
            digital_outputs: (s.get(od, slot::DIGITAL_OUTPUTS)
                & s.get(od, slot::DIGITAL_OUTPUTS_MASK)) as u32,
            homing_speed_switch: s.get(od, slot::HOMING_SPEED_SWITCH) as f64 / per_rad,
            homing_speed_zero: s.get(od, slot::HOMING_SPEED_ZERO) as f64 / per_rad,
            homing_accel: s.get(od, slot::HOMING_ACCEL) as f64 / per_rad,
        }
    }

    /// Torque limit, Nm (0x6072 per mille of 0x6076).
    fn max_torque(&self) -> f64 {
        self.max_torque_permille * 1e-3 * self.rated_torque_nm
    }

    fn quick_stop(&self) -> (StopRamp, bool) {
        quick_stop_ramp(
            self.quick_stop_option,
            self.profile_decel,
            self.quick_stop_decel,
        )
    }

    fn mode_supported(&self, m: i8) -> bool {
        mode::IMPLEMENTED.contains(&m)
            && mode::supported_mask(m).is_some_and(|b| self.supported_modes & b != 0)
    }
}

/// Reads an axis object, or its default when the dictionary lacks it.
struct Fallback<'a>(&'a OdSlots);

impl Fallback<'_> {
    fn get(&self, od: &ObjectDictionary, slot: usize) -> i64 {
        if self.0.has(slot) {
            self.0.get(od, slot)
        } else {
            AXIS_KEYS[slot].2
        }
    }
}

/// The position reference of CSP: the target positions, which arrive once per cycle, joined
/// by straight lines over the interpolation period (0x60C2), with the line's slope as velocity
/// feed-forward.
#[derive(Clone, Copy, Debug, Default)]
struct Interpolator {
    from: f64,
    to: f64,
    elapsed: f64,
    period: f64,
    last_target: i64,
}

impl Interpolator {
    fn start(&mut self, from: f64, to: f64, target: i64, period: f64) {
        *self = Interpolator {
            from,
            to,
            elapsed: 0.0,
            period,
            last_target: target,
        };
    }

    /// Reference position and velocity after `dt` more seconds.
    fn advance(&mut self, dt: f64) -> (f64, f64) {
        self.elapsed += dt;
        if self.elapsed >= self.period {
            (self.to, 0.0)
        } else {
            let slope = (self.to - self.from) / self.period;
            (self.from + slope * self.elapsed, slope)
        }
    }
}

/// One step of a profile towards `goal` (PP): the speed follows min(v_max, √(2·d·distance))
/// towards the goal, changing at `accel` when speeding up and `decel` when slowing down —
/// a trapezoid (a triangle for short moves). Returns the new (position, speed).
fn profile_step(
    pos: f64,
    speed: f64,
    goal: f64,
    v_max: f64,
    accel: f64,
    decel: f64,
    dt: f64,
) -> (f64, f64) {
    let distance = goal - pos;
    let braking = if decel > 0.0 {
        (2.0 * decel * distance.abs()).sqrt()
    } else {
        v_max // no deceleration limit: stop at once at the goal
    };
    let desired = distance.signum() * v_max.min(braking);
    let speed = ramp(speed, desired, accel, decel, dt);
    let next = pos + speed * dt;
    if (goal - next) * distance <= 0.0 {
        (goal, 0.0) // arrived (or would pass the goal this step)
    } else {
        (next, speed)
    }
}

/// Move `speed` towards `target` by at most `accel·dt` when its magnitude grows and
/// `decel·dt` when it shrinks (a zero rate means: at once).
fn ramp(speed: f64, target: f64, accel: f64, decel: f64, dt: f64) -> f64 {
    let speeding_up = target.abs() > speed.abs() && target * speed >= 0.0;
    let rate = if speeding_up { accel } else { decel };
    if rate <= 0.0 {
        return target;
    }
    let step = rate * dt;
    speed + (target - speed).clamp(-step, step)
}

/// Fixed-capacity queue of emergencies (no allocation while the drive runs).
#[derive(Clone, Copy, Debug, Default)]
struct EmergencyQueue {
    items: [Emergency; 16],
    head: usize,
    len: usize,
}

impl EmergencyQueue {
    /// Append; when full the new one is dropped (as the ESC's mailbox queue does).
    fn push(&mut self, e: Emergency) {
        if self.len < self.items.len() {
            self.items[(self.head + self.len) % self.items.len()] = e;
            self.len += 1;
        }
    }

    fn pop(&mut self) -> Option<Emergency> {
        (self.len > 0).then(|| {
            let e = self.items[self.head];
            self.head = (self.head + 1) % self.items.len();
            self.len -= 1;
            e
        })
    }
}

/// What a stop (quick stop, fault reaction, halt) is doing.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Stop {
    ramp: StopRamp,
    /// The speed reference being ramped to zero, rad/s.
    speed: f64,
    done: bool,
}

/// Touch probe 1 (0x60B8 function, 0x60B9 status, 0x60BA/0x60BB positions at its edges).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct TouchProbe {
    /// The function word of the previous period (edges of its enable bits re-arm).
    function: u16,
    positive_stored: bool,
    negative_stored: bool,
    positive: i64,
    negative: i64,
}

/// Touch probe function bits (CiA 402 0x60B8).
mod probe_fn {
    pub const ENABLE: u16 = 1 << 0;
    pub const CONTINUOUS: u16 = 1 << 1;
    /// Bits 2-3 = 01: the zero impulse (index pulse) of the encoder; 00: touch probe input 1
    /// (here: the home switch).
    pub const SOURCE_INDEX: u16 = 1 << 2;
    pub const POSITIVE_EDGE: u16 = 1 << 4;
    pub const NEGATIVE_EDGE: u16 = 1 << 5;
}

/// Touch probe status bits (0x60B9).
mod probe_status {
    pub const ENABLED: u16 = 1 << 0;
    pub const POSITIVE_STORED: u16 = 1 << 1;
    pub const NEGATIVE_STORED: u16 = 1 << 2;
}

/// Digital input bits (0x60FD); bits 16-31 are the manufacturer's (outputs 16-31 of 0x60FE,
/// wired back).
mod din {
    pub const NEGATIVE_LIMIT: u32 = 1 << 0;
    pub const POSITIVE_LIMIT: u32 = 1 << 1;
    pub const HOME_SWITCH: u32 = 1 << 2;
    pub const MANUFACTURER: u32 = 0xFFFF_0000;
}

/// A homing run on the index pulse (33, 34) or the home switch (19) under way.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Homing {
    /// +1 or -1: the direction of the search.
    direction: f64,
    speed: f64,
    /// Looking for the event (true), or stopping after it.
    searching: bool,
    /// The home switch's level at the start (method 19).
    switch_at_start: bool,
    /// Bit 4 dropped before the end: the run stops without homing attained.
    interrupted: bool,
}

/// One axis: its state machine, mode, reference generators and mechanics.
#[derive(Clone, Debug)]
struct Axis {
    number: u8,
    state: State,
    mechanics: Mechanics,
    cascade: Cascade,
    /// Active mode (0x6061).
    mode: i8,
    previous_controlword: u16,
    /// Position reference (demand), rad, and its velocity, rad/s.
    demand: f64,
    demand_speed: f64,
    interpolator: Interpolator,
    /// PP: the target being moved to, one buffered set-point, the acknowledge bit.
    pp_goal: Option<f64>,
    pp_last_goal: f64,
    pp_buffered: Option<f64>,
    setpoint_acknowledge: bool,
    /// HM: homing attained / homing error.
    homing_attained: bool,
    homing_error: bool,
    stop: Option<Stop>,
    quick_stop_stays: bool,
    fault: Option<DriveFault>,
    /// Following error latched (statusword bit 13 in CSP/PP) and time spent outside the window.
    following_error: bool,
    fe_outside_s: f64,
    /// Increments added to the encoder's count (homing sets it); the reported position.
    position_offset: i64,
    /// The encoder's count while it is faulted (the reported position freezes).
    frozen_position: Option<i64>,
    torque: f64,
    /// The torque or speed limit cut the command in the last period.
    limit_active: bool,
    /// The last target was cut to the software position limits.
    target_limited: bool,
    target_reached: bool,
    remote: bool,
    switches: Switches,
    probe: TouchProbe,
    homing: Option<Homing>,
    /// The encoder's index (zero impulse) count at the previous period: floor(count / CPR).
    index_revolution: i64,
    home_switch: bool,
    digital_inputs: u32,
}

impl Axis {
    fn new(number: u8, params: MotorParams, switches: Switches) -> Self {
        Axis {
            number,
            state: State::NotReadyToSwitchOn,
            mechanics: Mechanics::new(params),
            cascade: Cascade::default(),
            mode: mode::NONE,
            previous_controlword: 0,
            demand: 0.0,
            demand_speed: 0.0,
            interpolator: Interpolator::default(),
            pp_goal: None,
            pp_last_goal: 0.0,
            pp_buffered: None,
            setpoint_acknowledge: false,
            homing_attained: false,
            homing_error: false,
            stop: None,
            quick_stop_stays: false,
            fault: None,
            following_error: false,
            fe_outside_s: 0.0,
            position_offset: 0,
            frozen_position: None,
            torque: 0.0,
            limit_active: false,
            target_limited: false,
            target_reached: false,
            remote: false,
            switches,
            probe: TouchProbe::default(),
            homing: None,
            index_revolution: 0,
            home_switch: false,
            digital_inputs: 0,
        }
    }

    fn params(&self) -> &MotorParams {
        &self.mechanics.params
    }

    /// The encoder's reading, increments (before the homing offset).
    fn encoder_count(&self) -> i64 {
        (self.mechanics.angle * self.params().counts_per_rad()).floor() as i64
    }

    /// Position actual value (0x6064), increments.
    fn position_actual(&self) -> i64 {
        self.frozen_position
            .unwrap_or_else(|| self.encoder_count())
            .wrapping_add(self.position_offset)
    }

    /// The measured motor angle the loops use (encoder resolution), rad.
    fn measured_angle(&self) -> f64 {
        (self.position_actual() - self.position_offset) as f64 / self.params().counts_per_rad()
    }

    /// A position in increments (0x607A frame) as a motor angle, rad.
    fn to_angle(&self, increments: i64) -> f64 {
        (increments - self.position_offset) as f64 / self.params().counts_per_rad()
    }

    fn to_increments(&self, angle: f64) -> f64 {
        angle * self.params().counts_per_rad() + self.position_offset as f64
    }

    /// A target position within the software position limits (bit 11 when cut).
    fn limited_target(&mut self, target: i64, inp: &Inputs) -> i64 {
        match inp.sw_limits {
            Some((min, max)) if !(min..=max).contains(&target) => {
                self.target_limited = true;
                target.clamp(min, max)
            }
            _ => {
                self.target_limited = false;
                target
            }
        }
    }

    /// A mode change: the new mode starts from the motor's position and speed, the loops
    /// keep their state (no jump, no torque step).
    fn continue_here(&mut self) {
        self.demand = self.measured_angle();
        self.demand_speed = self.mechanics.speed;
        self.pp_goal = None;
        self.pp_last_goal = self.demand;
        self.pp_buffered = None;
        self.fe_outside_s = 0.0;
    }

    /// Is the axis at or beyond a software position limit (0x607D) in the direction of
    /// `direction` (> 0: towards max)? Motion that way is refused in the velocity and torque
    /// modes (statusword bit 11).
    fn at_software_limit(&self, inp: &Inputs, direction: f64) -> bool {
        match inp.sw_limits {
            Some((min, max)) => {
                let p = self.position_actual();
                direction > 0.0 && p >= max || direction < 0.0 && p <= min
            }
            None => false,
        }
    }

    /// Start from where the motor is, at rest: no jump on enabling.
    fn hold_here(&mut self) {
        self.demand = self.measured_angle();
        self.demand_speed = 0.0;
        self.cascade.reset();
        self.pp_goal = None;
        self.pp_last_goal = self.demand;
        self.pp_buffered = None;
        self.fe_outside_s = 0.0;
    }

    fn raise(&mut self, fault: DriveFault, inp: &Inputs, out: &mut EmergencyQueue) {
        if self.fault.is_some() {
            return; // the first fault is reported; later ones add nothing until the reset
        }
        self.fault = Some(fault);
        if fault == DriveFault::FollowingError {
            self.following_error = true;
        }
        if fault == DriveFault::Encoder {
            self.frozen_position = Some(self.encoder_count());
        }
        let powered = matches!(self.state, State::OperationEnabled | State::QuickStopActive);
        self.state = State::FaultReactionActive;
        self.stop = Some(Stop {
            ramp: if powered {
                fault.reaction(inp.quick_stop_decel)
            } else {
                StopRamp::Coast
            },
            speed: self.mechanics.speed,
            done: false,
        });
        out.push(Emergency {
            error_code: fault.error_code(),
            error_register: fault.error_register(),
            data: [self.number, 0, 0, 0, 0],
        });
    }

    fn fault_reset(&mut self, out: &mut EmergencyQueue) {
        self.fault = None;
        self.following_error = false;
        self.frozen_position = None;
        // CiA 301: an emergency with code 0x0000 tells that the error is gone.
        out.push(Emergency {
            error_code: 0,
            error_register: 0,
            data: [self.number, 0, 0, 0, 0],
        });
    }

    /// Controlword, mode and set-point handling, once per step with valid outputs.
    fn command(&mut self, inp: &Inputs, out: &mut EmergencyQueue) {
        let cw_now = inp.controlword;
        let rising = |bit: u16| cw_now & bit != 0 && self.previous_controlword & bit == 0;
        let new_setpoint = rising(cw::NEW_SETPOINT);
        if let Some((number, next)) = transition(
            self.state,
            cw_now,
            self.previous_controlword,
            self.quick_stop_stays,
        ) {
            self.enter(number, next, inp, out);
        }
        self.previous_controlword = cw_now;
        if inp.mode != self.mode && inp.mode_supported(inp.mode) {
            // A mode change is bumpless: the new mode starts from the present position and
            // speed.
            self.mode = inp.mode;
            self.continue_here();
            self.homing = None;
            self.homing_attained = false;
            self.homing_error = false;
            self.setpoint_acknowledge = false;
            if self.mode == mode::CSP {
                let target = self.limited_target(inp.target_position, inp);
                let to = self.to_angle(target);
                self.interpolator
                    .start(self.demand, to, inp.target_position, inp.interpolation_s);
            }
        }
        if self.state != State::OperationEnabled {
            self.setpoint_acknowledge = cw_now & cw::NEW_SETPOINT != 0 && self.setpoint_acknowledge;
            return;
        }
        match self.mode {
            mode::CSP if inp.target_position != self.interpolator.last_target => {
                let target = self.limited_target(inp.target_position, inp);
                let to = self.to_angle(target);
                self.interpolator
                    .start(self.demand, to, inp.target_position, inp.interpolation_s);
            }
            mode::PP => self.pp_command(inp, new_setpoint),
            mode::HM if new_setpoint => self.home(inp),
            // Bit 4 dropped while homing: interrupted (stops, not attained).
            mode::HM if cw_now & cw::NEW_SETPOINT == 0 => {
                if let Some(run) = self.homing.as_mut() {
                    run.searching = false;
                    run.interrupted = true;
                }
            }
            _ => {}
        }
    }

    /// PP set-point handshake: a rising "new set-point" is taken (and acknowledged) at once
    /// when "change set immediately" is set or the axis is idle, else kept as the one buffered
    /// set-point; the acknowledge drops with the master's "new set-point".
    fn pp_command(&mut self, inp: &Inputs, new_setpoint: bool) {
        if inp.controlword & cw::NEW_SETPOINT == 0 {
            self.setpoint_acknowledge = false;
            return;
        }
        if !new_setpoint || self.setpoint_acknowledge {
            return;
        }
        // Relative moves count from the previous target (IEC 61800-7-201 PP, bit 6).
        let base = if inp.controlword & cw::RELATIVE != 0 {
            self.to_increments(self.pp_last_goal).round() as i64
        } else {
            0
        };
        let target = self.limited_target(base.saturating_add(inp.target_position), inp);
        let goal = self.to_angle(target);
        if self.pp_goal.is_none() || inp.controlword & cw::CHANGE_SET_IMMEDIATELY != 0 {
            self.pp_goal = Some(goal);
        } else if self.pp_buffered.is_none() {
            self.pp_buffered = Some(goal);
        } else {
            return; // buffer full: not acknowledged
        }
        self.pp_last_goal = goal;
        self.setpoint_acknowledge = true;
        self.target_reached = false;
    }

    /// HM, homing operation start (bit 4 rising): methods 35 and 37 home on the current position
    /// (it becomes the home offset 0x607C) at once; 33 and 34 search the index pulse (the
    /// encoder's zero impulse, once per motor revolution) at 0x6099:2 in the negative or
    /// positive direction; 19 searches the edge of the home switch at 0x6099:1, upwards while
    /// it is off and downwards while it is on; the position at the event becomes the home
    /// offset, then the axis stops at 0x609A and holds. Other methods are a homing error.
    fn home(&mut self, inp: &Inputs) {
        self.homing_attained = false;
        self.homing_error = false;
        self.homing = None;
        self.hold_here();
        match inp.homing_method {
            35 | 37 => {
                let raw = self.position_actual() - self.position_offset;
                self.position_offset = inp.home_offset - raw;
                self.homing_attained = true;
            }
            33 | 34 | 19 => {
                let on = self.home_switch;
                let (direction, speed) = match inp.homing_method {
                    33 => (-1.0, inp.homing_speed_zero),
                    34 => (1.0, inp.homing_speed_zero),
                    _ => (if on { -1.0 } else { 1.0 }, inp.homing_speed_switch),
                };
                self.homing = Some(Homing {
                    direction,
                    speed,
                    searching: true,
                    switch_at_start: on,
                    interrupted: false,
                });
            }
            _ => self.homing_error = true,
        }
    }

    /// One period of a homing run: the search ramps up to its speed, the event (index pulse
    /// or switch edge, found by `sense`) sets the home position, then the axis ramps to rest
    /// and holds (homing attained). A limit switch on the way is a homing error.
    fn run_homing(&mut self, inp: &Inputs, dt: f64) -> f64 {
        let Some(mut run) = self.homing else {
            self.demand_speed = 0.0;
            return self.position_control(inp, 0.0, dt);
        };
        if self.digital_inputs & (din::NEGATIVE_LIMIT | din::POSITIVE_LIMIT) != 0 && run.searching {
            run.searching = false;
            self.homing_error = true;
        }
        let target = if run.searching {
            run.direction * run.speed
        } else {
            0.0
        };
        self.demand_speed = ramp(
            self.demand_speed,
            target,
            inp.homing_accel,
            inp.homing_accel,
            dt,
        );
        self.demand += self.demand_speed * dt;
        let torque = self.position_control(inp, self.demand_speed, dt);
        if !run.searching
            && self.demand_speed == 0.0
            && self.mechanics.speed.abs() < STANDSTILL_SPEED
        {
            self.homing = None;
            self.homing_attained = !self.homing_error && !run.interrupted;
            self.hold_here();
        } else {
            self.homing = Some(run);
        }
        torque
    }

    /// The encoder's index pulse and the switches this period, after the mechanics moved:
    /// homing events, the touch probe, the digital inputs.
    fn sense(&mut self, inp: &Inputs, method: i64) {
        let cpr = self.params().counts_per_rev as i64;
        let count = self.encoder_count();
        let revolution = count.div_euclid(cpr.max(1));
        // The count where the index pulse was crossed this period (the revolution boundary).
        let index_at = (revolution != self.index_revolution)
            .then(|| revolution.max(self.index_revolution) * cpr);
        self.index_revolution = revolution;
        let joint = self.mechanics.angle / self.params().gear_ratio;
        let switch = joint >= self.switches.home;
        let switch_edge = switch != self.home_switch;
        self.home_switch = switch;
        let limit = self.switches.limit;
        let mut inputs = inp.digital_outputs & din::MANUFACTURER;
        if switch {
            inputs |= din::HOME_SWITCH;
        }
        if limit > 0.0 && joint <= -limit {
            inputs |= din::NEGATIVE_LIMIT;
        }
        if limit > 0.0 && joint >= limit {
            inputs |= din::POSITIVE_LIMIT;
        }
        self.digital_inputs = inputs;
        // Homing: the event sets the home position there.
        if let Some(run) = self.homing.as_mut().filter(|r| r.searching) {
            let event = match method {
                33 | 34 => index_at,
                19 if switch_edge && switch != run.switch_at_start => Some(count),
                _ => None,
            };
            if let Some(at) = event {
                self.position_offset = inp.home_offset - at;
                run.searching = false;
            }
        }
        // Touch probe 1 on the home switch (input 1) or the index pulse.
        let f = inp.probe_function;
        let p = &mut self.probe;
        let rising = |bit: u16| f & bit != 0 && p.function & bit == 0;
        if f & probe_fn::ENABLE == 0 {
            *p = TouchProbe::default();
        } else {
            if rising(probe_fn::ENABLE) || rising(probe_fn::POSITIVE_EDGE) {
                p.positive_stored = false;
            }
            if rising(probe_fn::ENABLE) || rising(probe_fn::NEGATIVE_EDGE) {
                p.negative_stored = false;
            }
            let continuous = f & probe_fn::CONTINUOUS != 0;
            let (positive, negative) = if f & probe_fn::SOURCE_INDEX != 0 {
                (index_at.is_some(), false)
            } else {
                (switch_edge && switch, switch_edge && !switch)
            };
            let position = count.wrapping_add(self.position_offset);
            if positive && f & probe_fn::POSITIVE_EDGE != 0 && (continuous || !p.positive_stored) {
                p.positive = index_at.map_or(position, |at| at.wrapping_add(self.position_offset));
                p.positive_stored = true;
            }
            if negative && f & probe_fn::NEGATIVE_EDGE != 0 && (continuous || !p.negative_stored) {
                p.negative = position;
                p.negative_stored = true;
            }
        }
        p.function = f;
    }

    fn probe_status(&self) -> u16 {
        let p = &self.probe;
        let mut status = 0;
        if p.function & probe_fn::ENABLE != 0 {
            status |= probe_status::ENABLED;
        }
        if p.positive_stored {
            status |= probe_status::POSITIVE_STORED;
        }
        if p.negative_stored {
            status |= probe_status::NEGATIVE_STORED;
        }
        status
    }

    /// Enter `next` by the controlword transition `number`.
    fn enter(&mut self, number: u8, next: State, inp: &Inputs, out: &mut EmergencyQueue) {
        match number {
            15 => self.fault_reset(out),
            4 | 16 => {
                self.hold_here();
                self.stop = None;
                if self.mode == mode::CSP {
                    // CSP follows the command value from the first cycle on: the drive moves
                    // to 0x607A (the master sets it to 0x6064 before enabling).
                    let target = self.limited_target(inp.target_position, inp);
                    let to = self.to_angle(target);
                    self.interpolator.start(
                        self.demand,
                        to,
                        inp.target_position,
                        inp.interpolation_s,
                    );
                }
            }
            11 => {
                let (ramp, stays) = inp.quick_stop();
                self.quick_stop_stays = stays;
                self.stop = Some(Stop {
                    ramp,
                    speed: self.mechanics.speed,
                    done: false,
                });
            }
            _ => {}
        }
        self.state = next;
        if !matches!(next, State::OperationEnabled | State::QuickStopActive) {
            self.stop = None;
        }
    }

    /// One drive period: the automatic transitions, the active mode's control, the stop
    /// ramps, following-error supervision, then the mechanics.
    fn tick(&mut self, inp: &Inputs, dt: f64, out: &mut EmergencyQueue) {
        self.limit_active = false;
        if self.state == State::NotReadyToSwitchOn {
            self.state = State::SwitchOnDisabled; // transition 1: initialisation done
        }
        let torque = match self.state {
            State::OperationEnabled => self.run_mode(inp, dt, out),
            State::QuickStopActive | State::FaultReactionActive => self.run_stop(inp, dt),
            _ => 0.0,
        };
        if self.stop.is_some_and(|s| s.done) {
            match self.state {
                State::FaultReactionActive => {
                    self.state = State::Fault; // transition 14
                    self.stop = None;
                }
                State::QuickStopActive if !self.quick_stop_stays => {
                    self.state = State::SwitchOnDisabled; // transition 12 (automatic)
                    self.stop = None;
                }
                _ => {}
            }
        }
        self.torque = torque;
        let sub = dt / f64::from(SUBSTEPS);
        for _ in 0..SUBSTEPS {
            self.mechanics.advance(sub, torque);
        }
        self.sense(inp, inp.homing_method);
    }

    /// Torque of the position loop on `demand` (+ `feed_forward`) through the velocity loop.
    fn position_control(&mut self, inp: &Inputs, feed_forward: f64, dt: f64) -> f64 {
        let error = self.demand - self.measured_angle();
        let (speed, cut) =
            Cascade::position_loop(self.params(), error, feed_forward, inp.max_speed);
        self.limit_active |= cut;
        self.velocity_control(inp, speed, dt)
    }

    /// `torque` plus the torque offset 0x60B2, within the torque limit.
    fn with_torque_offset(&mut self, inp: &Inputs, torque: f64) -> f64 {
        if inp.torque_offset_permille == 0.0 {
            return torque;
        }
        let (torque, cut) = limit(
            torque + inp.torque_offset_permille * 1e-3 * inp.rated_torque_nm,
            inp.max_torque(),
        );
        self.limit_active |= cut;
        torque
    }

    fn velocity_control(&mut self, inp: &Inputs, speed: f64, dt: f64) -> f64 {
        let (speed, cut) = limit(speed, inp.max_speed);
        let params = *self.params();
        let cmd =
            self.cascade
                .velocity_loop(&params, speed, self.mechanics.speed, inp.max_torque(), dt);
        self.limit_active |= cut || cmd.limited;
        cmd.torque
    }

    fn run_mode(&mut self, inp: &Inputs, dt: f64, out: &mut EmergencyQueue) -> f64 {
        let halt = inp.controlword & cw::HALT != 0;
        match self.mode {
            mode::CSP => {
                let (demand, speed) = self.interpolator.advance(dt);
                self.demand = demand;
                self.demand_speed = speed;
                // 0x60B1 and 0x60B2 add to the velocity and torque commands (feed-forward).
                let torque = self.position_control(inp, speed + inp.velocity_offset, dt);
                self.supervise_following_error(inp, dt, out);
                self.with_torque_offset(inp, torque)
            }
            mode::CSV => {
                let mut speed = inp.target_velocity as f64 / self.params().counts_per_rad();
                self.target_limited = self.at_software_limit(inp, speed);
                if self.target_limited {
                    speed = 0.0;
                }
                self.demand_speed = speed;
                let torque = self.velocity_control(inp, speed + inp.velocity_offset, dt);
                self.with_torque_offset(inp, torque)
            }
            mode::CST => {
                let (mut torque, cut) = limit(
                    (inp.target_torque as f64 + inp.torque_offset_permille)
                        * 1e-3
                        * inp.rated_torque_nm,
                    inp.max_torque(),
                );
                self.limit_active |= cut;
                // At a software limit, pushing or moving outward: the velocity loop stops the
                // motor there instead (a drive's limit stop).
                let speed = self.mechanics.speed;
                self.target_limited =
                    self.at_software_limit(inp, torque) || self.at_software_limit(inp, speed);
                if self.target_limited {
                    torque = self.velocity_control(inp, 0.0, dt);
                }
                torque
            }
            mode::PP => {
                let v_max = if inp.max_speed > 0.0 {
                    inp.profile_velocity.min(inp.max_speed)
                } else {
                    inp.profile_velocity
                };
                if halt || self.pp_goal.is_none() {
                    // Halt, or no target yet (entered moving, from another mode): stop at the
                    // profile deceleration.
                    self.demand_speed = ramp(
                        self.demand_speed,
                        0.0,
                        inp.profile_accel,
                        inp.profile_decel,
                        dt,
                    );
                    self.demand += self.demand_speed * dt;
                } else if let Some(goal) = self.pp_goal {
                    let (p, v) = profile_step(
                        self.demand,
                        self.demand_speed,
                        goal,
                        v_max,
                        inp.profile_accel,
                        inp.profile_decel,
                        dt,
                    );
                    (self.demand, self.demand_speed) = (p, v);
                    if p == goal && v == 0.0 {
                        self.pp_goal = self.pp_buffered.take();
                    }
                }
                let torque = self.position_control(inp, self.demand_speed, dt);
                self.supervise_following_error(inp, dt, out);
                let settled = (self.demand - self.measured_angle()).abs() <= inp.position_window;
                self.target_reached = if halt {
                    self.demand_speed == 0.0
                } else {
                    self.pp_goal.is_none() && settled
                };
                torque
            }
            mode::PV => {
                let mut target = if halt {
                    0.0
                } else {
                    inp.target_velocity as f64 / self.params().counts_per_rad()
                };
                self.target_limited = self.at_software_limit(inp, target);
                if self.target_limited {
                    target = 0.0;
                }
                self.demand_speed = ramp(
                    self.demand_speed,
                    target,
                    inp.profile_accel,
                    inp.profile_decel,
                    dt,
                );
                self.target_reached = (self.mechanics.speed - target).abs() <= inp.velocity_window;
                self.velocity_control(inp, self.demand_speed, dt)
            }
            // HM: a homing run moves the axis; otherwise (and with no mode) it holds. Target
            // reached: no run under way (attained, interrupted or not started).
            mode::HM => {
                self.target_reached = self.homing.is_none();
                self.run_homing(inp, dt)
            }
            _ => {
                self.target_reached = false;
                self.demand_speed = 0.0;
                self.position_control(inp, 0.0, dt)
            }
        }
    }

    /// Quick stop and fault reaction: ramp the speed down, then hold (or switch off).
    fn run_stop(&mut self, inp: &Inputs, dt: f64) -> f64 {
        let Some(mut stop) = self.stop else {
            return 0.0;
        };
        let torque = if stop.done {
            // Quick stop active with option codes 5–8: stand still at the stop position.
            self.position_control(inp, 0.0, dt)
        } else {
            let torque = match stop.ramp {
                StopRamp::Coast => {
                    stop.done = true;
                    0.0
                }
                StopRamp::Decelerate(d) => {
                    stop.speed = ramp(stop.speed, 0.0, d, d, dt);
                    self.velocity_control(inp, stop.speed, dt)
                }
                StopRamp::TorqueLimit => {
                    stop.speed = 0.0;
                    self.velocity_control(inp, 0.0, dt)
                }
            };
            if stop.speed == 0.0 && self.mechanics.speed.abs() < STANDSTILL_SPEED {
                stop.done = true;
                self.hold_here();
            }
            torque
        };
        self.stop = Some(stop);
        torque
    }

    /// CSP/PP: |demand − actual| beyond 0x6065 for longer than 0x6066 is a following error
    /// fault (0x8611). A window of 0xFFFFFFFF switches the supervision off.
    fn supervise_following_error(&mut self, inp: &Inputs, dt: f64, out: &mut EmergencyQueue) {
        if inp.fe_window >= i64::from(u32::MAX) {
            self.fe_outside_s = 0.0;
            return;
        }
        let error = self.to_increments(self.demand) - self.position_actual() as f64;
        if error.abs() > inp.fe_window as f64 {
            self.fe_outside_s += dt;
            if self.fe_outside_s > inp.fe_timeout_s {
                self.raise(DriveFault::FollowingError, inp, out);
            }
        } else {
            self.fe_outside_s = 0.0;
        }
    }

    /// Statusword of the present state and mode.
    fn statusword(&self, voltage: bool) -> u16 {
        let mut word = self.state.statusword_bits();
        if voltage {
            word |= sw::VOLTAGE_ENABLED;
        }
        if self.remote {
            word |= sw::REMOTE;
        }
        if self.limit_active || self.target_limited {
            word |= sw::INTERNAL_LIMIT;
        }
        let enabled = self.state == State::OperationEnabled;
        let halted = enabled && self.previous_controlword & cw::HALT != 0;
        match self.mode {
            mode::CSP | mode::CSV | mode::CST if enabled && !halted => word |= sw::MODE_12,
            mode::PP if self.setpoint_acknowledge => word |= sw::MODE_12,
            mode::PV if enabled && self.mechanics.speed.abs() < STANDSTILL_SPEED => {
                word |= sw::MODE_12
            }
            mode::HM if self.homing_attained => word |= sw::MODE_12,
            _ => {}
        }
        let mode_13 = match self.mode {
            mode::CSP | mode::PP => self.following_error,
            mode::HM => self.homing_error,
            _ => false,
        };
        if mode_13 {
            word |= sw::MODE_13;
        }
        let reached = match self.state {
            State::OperationEnabled => {
                matches!(self.mode, mode::PP | mode::PV | mode::HM) && self.target_reached
            }
            State::QuickStopActive => self.stop.is_some_and(|s| s.done),
            _ => false,
        };
        if reached {
            word |= sw::TARGET_REACHED;
        }
        word
    }

    fn write(&self, od: &mut ObjectDictionary, s: &OdSlots, inp: &Inputs) {
        let per_rad = self.params().counts_per_rad();
        let voltage = self.fault != Some(DriveFault::UnderVoltage);
        s.set(od, slot::STATUSWORD, i64::from(self.statusword(voltage)));
        s.set(od, slot::MODE_DISPLAY, i64::from(self.mode));
        s.set(od, slot::POSITION_ACTUAL, self.position_actual());
        s.set(od, slot::DIGITAL_INPUTS, i64::from(self.digital_inputs));
        s.set(od, slot::PROBE_STATUS, i64::from(self.probe_status()));
        s.set(od, slot::PROBE_POSITIVE, self.probe.positive);
        s.set(od, slot::PROBE_NEGATIVE, self.probe.negative);
        s.set(
            od,
            slot::VELOCITY_ACTUAL,
            saturate(self.mechanics.speed * per_rad, i32::MIN, i32::MAX),
        );
        s.set(
            od,
            slot::TORQUE_ACTUAL,
            saturate(
                self.torque / inp.rated_torque_nm * 1e3,
                i16::MIN.into(),
                i16::MAX.into(),
            ),
        );
        s.set(
            od,
            slot::ERROR_CODE,
            self.fault.map_or(0, |f| i64::from(f.error_code())),
        );
        let following = if matches!(self.mode, mode::CSP | mode::PP | mode::HM)
            && self.state == State::OperationEnabled
        {
            self.to_increments(self.demand) - self.position_actual() as f64
        } else {
            0.0
        };
        s.set(
            od,
            slot::FOLLOWING_ERROR,
            saturate(following, i32::MIN, i32::MAX),
        );
    }
}

fn saturate(value: f64, lo: i32, hi: i32) -> i64 {
    value.round().clamp(f64::from(lo), f64::from(hi)) as i64
}

macro_rules! probe_names {
    ($($n:literal),*) => {
        [$([
            concat!("axis", $n, "_position_rad"),
            concat!("axis", $n, "_velocity_rad_s"),
            concat!("axis", $n, "_torque_nm"),
            concat!("axis", $n, "_motor_torque_nm"),
            concat!("axis", $n, "_demand_position_rad"),
            concat!("axis", $n, "_state"),
            concat!("axis", $n, "_mode"),
            concat!("axis", $n, "_error_code"),
            concat!("axis", $n, "_statusword"),
            concat!("axis", $n, "_torque_limit_nm"),
        ]),*]
    };
}

/// Probe names per axis (joint side: position, velocity, torque through the gear).
const PROBE_NAMES: [[&str; 10]; MAX_AXES] = probe_names!("1", "2", "3", "4", "5", "6", "7", "8");

/// The drive: up to `MAX_AXES` axes found in the dictionary.
pub struct Cia402Drive {
    config: Cia402Config,
    axes: Vec<Axis>,
    axis_count: usize,
    slots: Vec<OdSlots>,
    keys: Vec<[(u16, u8); AXIS_KEYS.len()]>,
    device_slots: OdSlots,
    inputs: [Inputs; MAX_AXES],
    clock: PeriodClock,
    emergencies: EmergencyQueue,
    /// Size of the dictionary the slots were resolved in.
    resolved_for: Option<usize>,
}

impl Cia402Drive {
    /// A drive with the axes and parameters of `config`, in its power-on state.
    pub fn new(config: Cia402Config) -> Self {
        let keys = (0..MAX_AXES)
            .map(|n| AXIS_KEYS.map(|(i, s, _)| (i + n as u16 * AXIS_OFFSET, s)))
            .collect();
        Self {
            config,
            axes: (0..MAX_AXES)
                .map(|n| Axis::new(n as u8 + 1, config.motor, config.switches))
                .collect(),
            axis_count: 0,
            slots: vec![OdSlots::default(); MAX_AXES],
            keys,
            device_slots: OdSlots::default(),
            inputs: [Inputs::default(); MAX_AXES],
            clock: PeriodClock::default(),
            emergencies: EmergencyQueue::default(),
            resolved_for: None,
        }
    }

    /// Axes present in `od`: 0x6040 + n·0x800 for n = 0, 1, ... (contiguous).
    fn count_axes(od: &ObjectDictionary) -> usize {
        (0..MAX_AXES)
            .take_while(|&n| od.position(0x6040 + n as u16 * AXIS_OFFSET, 0).is_some())
            .count()
    }

    fn resolve(&mut self, od: &ObjectDictionary) {
        if self.resolved_for == Some(od.entries().len()) {
            return;
        }
        self.resolved_for = Some(od.entries().len());
        self.axis_count = Self::count_axes(od);
        for n in 0..self.axis_count {
            self.slots[n].resolve(od, &self.keys[n]);
        }
        self.device_slots.resolve(od, &ERROR_REGISTER);
    }

    /// Number of axes found in the dictionary (0 before the first reset/step).
    pub fn axis_count(&self) -> usize {
        self.axis_count
    }

    /// State of axis `n` (0-based), for tests.
    pub fn state(&self, n: usize) -> State {
        self.axes[n].state
    }

    /// Motor angle (rad) and speed (rad/s) of axis `n`, for tests.
    pub fn motor(&self, n: usize) -> (f64, f64) {
        (self.axes[n].mechanics.angle, self.axes[n].mechanics.speed)
    }

    fn write_feedback(&self, od: &mut ObjectDictionary) {
        let mut register = 0u8;
        for n in 0..self.axis_count {
            let axis = &self.axes[n];
            axis.write(od, &self.slots[n], &self.inputs[n]);
            register |= axis.fault.map_or(0, |f| f.error_register());
        }
        self.device_slots.set(od, 0, i64::from(register));
    }

    /// Write what the model knows of its hardware into the dictionary (encoder resolution,
    /// gear ratio, rated torque): the master reads the truth there.
    fn publish_hardware(&self, od: &mut ObjectDictionary) {
        let m = &self.config.motor;
        for s in &self.slots[..self.axis_count] {
            s.set(od, slot::ENCODER_INCREMENTS, m.counts_per_rev as i64);
            s.set(od, slot::ENCODER_REVOLUTIONS, 1);
            // The gear ratio as a fraction with 1000 shaft revolutions (3 decimals).
            let (motor, shaft) = if m.gear_ratio.fract() == 0.0 {
                (m.gear_ratio as i64, 1)
            } else {
                ((m.gear_ratio * 1000.0).round() as i64, 1000)
            };
            s.set(od, slot::GEAR_MOTOR, motor);
            s.set(od, slot::GEAR_SHAFT, shaft);
            s.set(
                od,
                slot::RATED_TORQUE,
                (m.rated_torque * 1e3).round() as i64,
            );
        }
    }
}

impl DeviceApp for Cia402Drive {
    fn period_ns(&self) -> u64 {
        PERIOD_NS
    }

    fn step(&mut self, od: &mut ObjectDictionary, local_time_ns: u64, outputs_valid: bool) {
        let run = self
            .clock
            .due(local_time_ns, PERIOD_NS, MAX_CATCH_UP_PERIODS);
        if run == 0 {
            return;
        }
        self.resolve(od);
        let dt = PERIOD_NS as f64 * 1e-9;
        for n in 0..self.axis_count {
            let inp = Inputs::read(od, &self.slots[n], &self.config.motor);
            self.inputs[n] = inp;
            let axis = &mut self.axes[n];
            axis.remote = outputs_valid;
            if outputs_valid {
                axis.command(&inp, &mut self.emergencies);
            } else if matches!(axis.state, State::OperationEnabled | State::QuickStopActive) {
                // The master's commands stopped while the motor was under control.
                axis.raise(DriveFault::Communication, &inp, &mut self.emergencies);
            }
            for _ in 0..run {
                axis.tick(&inp, dt, &mut self.emergencies);
            }
        }
        self.write_feedback(od);
    }

    fn reset(&mut self, od: &mut ObjectDictionary) {
        *self = Self::new(self.config);
        self.resolve(od);
        self.publish_hardware(od);
        for n in 0..self.axis_count {
            self.inputs[n] = Inputs::read(od, &self.slots[n], &self.config.motor);
        }
        self.write_feedback(od);
    }

    fn inject_fault(&mut self, fault: &str, axis: usize) -> Result<(), String> {
        let Some(&(_, kind)) = DriveFault::INJECTABLE.iter().find(|(n, _)| *n == fault) else {
            let known: Vec<&str> = DriveFault::INJECTABLE.iter().map(|(n, _)| *n).collect();
            return Err(format!(
                "unknown drive fault '{fault}' (known: {})",
                known.join(", ")
            ));
        };
        if axis == 0 || axis > self.axis_count {
            return Err(format!(
                "drive fault '{fault}': no axis {axis} (this drive has axes 1..={})",
                self.axis_count
            ));
        }
        let inp = self.inputs[axis - 1];
        self.axes[axis - 1].raise(kind, &inp, &mut self.emergencies);
        Ok(())
    }

    fn take_emergency(&mut self) -> Option<Emergency> {
        self.emergencies.pop()
    }

    fn probe(&self) -> Vec<(&'static str, f64)> {
        let mut values = vec![("axes", self.axis_count as f64)];
        for (n, names) in PROBE_NAMES.iter().enumerate().take(self.axis_count) {
            let a = &self.axes[n];
            let gear = a.params().gear_ratio;
            let inp = &self.inputs[n];
            values.extend([
                (names[0], a.mechanics.angle / gear),
                (names[1], a.mechanics.speed / gear),
                (names[2], a.torque * gear),
                (names[3], a.torque),
                (names[4], a.demand / gear),
                (names[5], f64::from(a.state as u8)),
                (names[6], f64::from(a.mode)),
                (names[7], a.fault.map_or(0.0, |f| f64::from(f.error_code()))),
                (
                    names[8],
                    f64::from(a.statusword(a.fault != Some(DriveFault::UnderVoltage))),
                ),
                (names[9], inp.max_torque() * gear),
            ]);
        }
        values
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::TAU;

    const CPR: i64 = 16_384;

    /// A drive on its dictionary, stepped the way the ESC does (every drive period).
    struct Bench {
        drive: Cia402Drive,
        od: ObjectDictionary,
        now: u64,
        valid: bool,
    }

    impl Bench {
        fn new(axes: usize) -> Bench {
            Bench::with(axes, Cia402Config::from_params(&[]).unwrap())
        }

        fn with(axes: usize, config: Cia402Config) -> Bench {
            let mut b = Bench {
                drive: Cia402Drive::new(config),
                od: dictionary(axes),
                now: 1_000_000,
                valid: true,
            };
            b.drive.reset(&mut b.od);
            b.run_ms(1.0);
            b
        }

        fn run_ms(&mut self, ms: f64) {
            let periods = (ms * 1e6 / PERIOD_NS as f64).round() as u64;
            for _ in 0..periods {
                self.now += PERIOD_NS;
                self.drive.step(&mut self.od, self.now, self.valid);
            }
        }

        fn get(&self, axis: usize, index: u16, sub: u8) -> i64 {
            self.od.get_int(index + axis as u16 * AXIS_OFFSET, sub)
        }

        fn set(&mut self, axis: usize, index: u16, sub: u8, value: i64) {
            self.od
                .set_int(index + axis as u16 * AXIS_OFFSET, sub, value);
        }

        /// Write the controlword and let one master cycle (1 ms) pass.
        fn cw(&mut self, axis: usize, word: u16) {
            self.set(axis, 0x6040, 0, i64::from(word));
            self.run_ms(1.0);
        }

        fn statusword(&self, axis: usize) -> u16 {
            self.get(axis, 0x6041, 0) as u16
        }

        fn state(&self, axis: usize) -> State {
            State::from_statusword(self.statusword(axis)).expect("a valid state coding")
        }

        fn position(&self, axis: usize) -> i64 {
            self.get(axis, 0x6064, 0)
        }

        /// Shutdown, switch on, enable operation in `m` with the target at the actual position.
        fn enable(&mut self, axis: usize, m: i8) {
            self.set(axis, 0x6060, 0, i64::from(m));
            let here = self.position(axis);
            self.set(axis, 0x607A, 0, here);
            for word in [0x06, 0x07, 0x0F] {
                self.cw(axis, word);
            }
            assert_eq!(self.state(axis), State::OperationEnabled);
        }

        fn emergencies(&mut self) -> Vec<Emergency> {
            std::iter::from_fn(|| self.drive.take_emergency()).collect()
        }
    }

    // ---------------------------------------------------------------- state machine

    /// IEC 61800-7-201, state transitions caused by the controlword: (from, controlword,
    /// transition, to). Quick stop option code 2 (the default): no transition 16.
    const TRANSITIONS: [(State, u16, u8, State); 16] = {
        use State::*;
        [
            (SwitchOnDisabled, 0x06, 2, ReadyToSwitchOn),
            (ReadyToSwitchOn, 0x07, 3, SwitchedOn),
            (ReadyToSwitchOn, 0x0F, 3, SwitchedOn),
            (SwitchedOn, 0x0F, 4, OperationEnabled),
            (OperationEnabled, 0x07, 5, SwitchedOn),
            (SwitchedOn, 0x06, 6, ReadyToSwitchOn),
            (ReadyToSwitchOn, 0x00, 7, SwitchOnDisabled),
            (ReadyToSwitchOn, 0x02, 7, SwitchOnDisabled),
            (OperationEnabled, 0x06, 8, ReadyToSwitchOn),
            (OperationEnabled, 0x00, 9, SwitchOnDisabled),
            (SwitchedOn, 0x00, 10, SwitchOnDisabled),
            (SwitchedOn, 0x02, 10, SwitchOnDisabled),
            (OperationEnabled, 0x02, 11, QuickStopActive),
            (QuickStopActive, 0x00, 12, SwitchOnDisabled),
            (QuickStopActive, 0x01, 12, SwitchOnDisabled),
            (Fault, 0x80, 15, SwitchOnDisabled),
        ]
    };
    const ALL_STATES: [State; 8] = [
        State::NotReadyToSwitchOn,
        State::SwitchOnDisabled,
        State::ReadyToSwitchOn,
        State::SwitchedOn,
        State::OperationEnabled,
        State::QuickStopActive,
        State::FaultReactionActive,
        State::Fault,
    ];
    /// One controlword per command, plus fault reset.
    const WORDS: [u16; 7] = [0x00, 0x02, 0x06, 0x07, 0x0F, 0x80, 0x8F];

    #[test]
    fn controlword_transitions_are_exactly_the_standards_table() {
        for (from, word, number, to) in TRANSITIONS {
            assert_eq!(
                transition(from, word, 0, false),
                Some((number, to)),
                "{from:?} + {word:#06x}"
            );
        }
        // Every other (state, command) pair leaves the state alone.
        for state in ALL_STATES {
            for word in WORDS {
                let listed = TRANSITIONS.iter().find(|&&(f, w, _, _)| {
                    f == state
                        && if f == State::Fault {
                            word & 0x80 != 0 // any fault reset edge
                        } else {
                            Command::decode(w) == Command::decode(word)
                        }
                });
                let expected = listed.map(|&(_, _, number, to)| (number, to));
                assert_eq!(
                    transition(state, word, 0, false),
                    expected,
                    "{state:?} {word:#x}"
                );
            }
        }
        // Transition 16 only with quick stop option codes 5..8.
        let qsa = State::QuickStopActive;
        assert_eq!(transition(qsa, 0x0F, 0, false), None);
        assert_eq!(
            transition(qsa, 0x0F, 0, true),
            Some((16, State::OperationEnabled))
        );
        // Fault reset acts on the rising edge of bit 7 only.
        assert_eq!(transition(State::Fault, 0x80, 0x80, false), None);
    }

    #[test]
    fn the_drive_walks_every_transition_with_the_standard_statuswords() {
        let mut b = Bench::new(1);
        assert_eq!(
            b.drive.state(0),
            State::SwitchOnDisabled,
            "transitions 0 and 1"
        );
        // (controlword, expected state, expected statusword with voltage and remote bits).
        let walk: [(u16, State, u16); 13] = [
            (0x06, State::ReadyToSwitchOn, 0x0231),  // 2
            (0x07, State::SwitchedOn, 0x0233),       // 3
            (0x0F, State::OperationEnabled, 0x0237), // 4
            (0x07, State::SwitchedOn, 0x0233),       // 5
            (0x06, State::ReadyToSwitchOn, 0x0231),  // 6
            (0x00, State::SwitchOnDisabled, 0x0250), // 7
            (0x06, State::ReadyToSwitchOn, 0x0231),
            // 3 then 4 in the next drive period: "enable operation" from Ready to switch on.
            (0x0F, State::OperationEnabled, 0x0237),
            (0x06, State::ReadyToSwitchOn, 0x0231), // 8
            (0x07, State::SwitchedOn, 0x0233),
            (0x02, State::SwitchOnDisabled, 0x0250), // 10 (quick stop)
            (0x06, State::ReadyToSwitchOn, 0x0231),
            (0x02, State::SwitchOnDisabled, 0x0250), // 7 (quick stop)
        ];
        for (word, state, status) in walk {
            b.cw(0, word);
            assert_eq!(b.drive.state(0), state, "after {word:#06x}");
            assert_eq!(b.statusword(0), status, "statusword after {word:#06x}");
        }
        b.enable(0, mode::CSP);
        b.cw(0, 0x00); // 9
        assert_eq!(b.state(0), State::SwitchOnDisabled);
        b.enable(0, mode::CSP);
        b.cw(0, 0x02); // 11, then 12 once stopped (option code 2)
        b.run_ms(5.0);
        assert_eq!(b.state(0), State::SwitchOnDisabled);
    }

    #[test]
    fn statusword_bits_remote_voltage_and_follows_command() {
        let mut b = Bench::new(1);
        b.enable(0, mode::CSP);
        let word = b.statusword(0);
        assert_eq!(word & 0x6F, 0x27);
        assert_ne!(word & sw::VOLTAGE_ENABLED, 0);
        assert_ne!(word & sw::REMOTE, 0, "controlword processed");
        assert_ne!(
            word & sw::MODE_12,
            0,
            "CSP: drive follows the command value"
        );
        assert_eq!(word & (sw::FAULT | sw::MODE_13 | sw::WARNING), 0);
        b.valid = false; // not OP: the controlword is no longer processed
        b.run_ms(1.0);
        assert_eq!(b.statusword(0) & sw::REMOTE, 0);
    }

    #[test]
    fn mode_display_mirrors_supported_modes_only() {
        let mut b = Bench::new(1);
        assert_eq!(b.get(0, 0x6061, 0), 0, "no mode at power-on");
        for m in mode::IMPLEMENTED {
            b.set(0, 0x6060, 0, i64::from(m));
            b.run_ms(1.0);
            assert_eq!(b.get(0, 0x6061, 0), i64::from(m));
        }
        // VL (2), profile torque (4), IP (7) and a manufacturer mode (-1) are not supported.
        for m in [2, 4, 7, -1] {
            b.set(0, 0x6060, 0, m);
            b.run_ms(1.0);
            assert_eq!(
                b.get(0, 0x6061, 0),
                i64::from(mode::CST),
                "mode {m} refused"
            );
        }
        // A mode whose 0x6502 bit is cleared is not supported either.
        b.set(0, 0x6502, 0, 0x3A5 & !(1 << 7));
        b.set(0, 0x6060, 0, i64::from(mode::CSP));
        b.run_ms(1.0);
        assert_eq!(b.get(0, 0x6061, 0), i64::from(mode::CST));
    }

    #[test]
    fn enabling_with_target_at_actual_does_not_move_the_axis() {
        let mut b = Bench::new(1);
        // Somewhere away from zero first (CSV), then disabled.
        b.enable(0, mode::CSV);
        b.set(0, 0x60FF, 0, 2 * CPR);
        b.run_ms(200.0);
        b.set(0, 0x60FF, 0, 0);
        b.run_ms(200.0);
        b.cw(0, 0x06);
        b.run_ms(50.0);
        let start = b.position(0);
        assert!(start > CPR / 4, "moved: {start}");
        b.enable(0, mode::CSP);
        let mut worst = 0;
        for _ in 0..100 {
            b.run_ms(1.0);
            worst = worst.max((b.position(0) - start).abs());
        }
        assert!(worst <= 2, "moved {worst} increments on enable");
        assert!(
            b.get(0, 0x6077, 0).abs() < 100,
            "torque {}",
            b.get(0, 0x6077, 0)
        );
    }

    #[test]
    fn enabling_csp_with_a_far_target_trips_the_following_error() {
        let mut b = Bench::new(1);
        b.set(0, 0x6060, 0, i64::from(mode::CSP));
        b.set(0, 0x607A, 0, 20 * CPR); // the master forgot to copy 0x6064
        for word in [0x06, 0x07, 0x0F] {
            b.cw(0, word);
        }
        b.run_ms(30.0);
        assert_eq!(b.get(0, 0x603F, 0), 0x8611);
        // The fault reaction brakes on the quick stop ramp (at most 1 s from full speed).
        assert_eq!(b.state(0), State::FaultReactionActive);
        b.run_ms(1100.0);
        assert_eq!(b.state(0), State::Fault);
    }

    // ---------------------------------------------------------------- quick stop

    fn moving_at(b: &mut Bench, counts_per_s: i64) {
        b.enable(0, mode::CSV);
        b.set(0, 0x60FF, 0, counts_per_s);
        b.run_ms(300.0);
        let v = b.get(0, 0x606C, 0);
        assert!(
            (v - counts_per_s).abs() < counts_per_s.abs() / 50,
            "at speed: {v}"
        );
    }

    #[test]
    fn quick_stop_ramps_down_at_0x6085_then_switches_on_disabled() {
        let mut b = Bench::new(1);
        moving_at(&mut b, 20 * CPR); // 20 motor rev/s
        b.cw(0, 0x0B); // quick stop (bit 2 low)
        assert_eq!(b.state(0), State::QuickStopActive);
        assert_eq!(b.statusword(0) & sw::QUICK_STOP, 0, "bit 5 is active low");
        // 0x6085 = 100 rev/s²: from 20 rev/s the stop takes 200 ms.
        b.run_ms(99.0);
        let v = b.get(0, 0x606C, 0) as f64 / CPR as f64;
        assert!((v - 10.0).abs() < 1.0, "half way: {v} rev/s");
        assert_eq!(b.state(0), State::QuickStopActive);
        b.run_ms(120.0);
        assert_eq!(
            b.state(0),
            State::SwitchOnDisabled,
            "transition 12 once stopped"
        );
        assert_eq!(b.get(0, 0x606C, 0).abs(), 0);
    }

    #[test]
    fn quick_stop_option_6_stays_and_transition_16_re_enables() {
        let mut b = Bench::new(1);
        b.set(0, 0x605A, 0, 6);
        moving_at(&mut b, 5 * CPR);
        b.cw(0, 0x0B);
        b.run_ms(200.0);
        assert_eq!(b.state(0), State::QuickStopActive);
        assert_ne!(b.statusword(0) & sw::TARGET_REACHED, 0, "stopped");
        let held = b.position(0);
        b.run_ms(100.0);
        assert!((b.position(0) - held).abs() <= 2, "holds position");
        b.set(0, 0x60FF, 0, 0);
        b.cw(0, 0x0F);
        assert_eq!(b.state(0), State::OperationEnabled);
    }

    #[test]
    fn quick_stop_option_0_switches_off_at_once_and_the_motor_coasts() {
        let mut b = Bench::new(1);
        b.set(0, 0x605A, 0, 0);
        moving_at(&mut b, 5 * CPR);
        b.set(0, 0x6040, 0, 0x0B);
        b.run_ms(0.25);
        assert_eq!(b.state(0), State::SwitchOnDisabled);
        // Coasting: only friction slows the motor, (τc + b·ω)/J ≈ 1480 rad/s² here...
        let before = b.position(0);
        b.run_ms(5.0);
        let v = b.get(0, 0x606C, 0) as f64 / CPR as f64;
        assert!((3.5..4.3).contains(&v), "coasting at {v} rev/s");
        // ...and the position keeps being reported while disabled.
        assert!(b.position(0) > before + CPR / 100);
        assert_eq!(b.get(0, 0x6077, 0), 0, "no torque");
    }

    // ---------------------------------------------------------------- faults

    #[test]
    fn following_error_faults_with_8611_bit_13_and_an_emergency() {
        let mut b = Bench::new(1);
        b.set(0, 0x6072, 0, 100); // weak: 10 % of rated torque
        b.enable(0, mode::CSP);
        b.emergencies();
        let start = b.position(0);
        // A ramp far faster than the weak motor can follow.
        for k in 1..=40 {
            b.set(0, 0x607A, 0, start + k * CPR / 4);
            b.run_ms(1.0);
            if b.state(0) == State::Fault {
                break;
            }
        }
        b.run_ms(50.0);
        assert_eq!(b.state(0), State::Fault);
        let word = b.statusword(0);
        assert_ne!(word & sw::FAULT, 0);
        assert_ne!(word & sw::MODE_13, 0, "CSP following error bit");
        assert_eq!(b.get(0, 0x603F, 0), 0x8611);
        assert_eq!(b.od.get_int(0x1001, 0), 0x21);
        let e = b.emergencies();
        assert_eq!(e.len(), 1, "{e:?}");
        assert_eq!(
            (e[0].error_code, e[0].error_register, e[0].data[0]),
            (0x8611, 0x21, 1)
        );
    }

    #[test]
    fn fault_reset_on_the_rising_edge_of_bit_7() {
        let mut b = Bench::new(1);
        b.enable(0, mode::CSP);
        b.drive.inject_fault("over_current", 1).unwrap();
        b.run_ms(1.0);
        assert_eq!(b.state(0), State::Fault, "over current: power off at once");
        assert_eq!(b.get(0, 0x603F, 0), 0x2310);
        // Bit 7 already high when the fault came: no edge, no reset.
        let mut b2 = Bench::new(1);
        b2.cw(0, 0x80);
        b2.drive.inject_fault("under_voltage", 1).unwrap();
        b2.run_ms(2.0);
        assert_eq!(b2.state(0), State::Fault);
        assert_eq!(
            b2.statusword(0) & sw::VOLTAGE_ENABLED,
            0,
            "no DC link voltage"
        );
        b2.run_ms(5.0);
        assert_eq!(b2.state(0), State::Fault, "a held bit 7 resets nothing");
        b2.cw(0, 0x00);
        b2.cw(0, 0x80);
        assert_eq!(b2.state(0), State::SwitchOnDisabled);
        assert_eq!(b2.get(0, 0x603F, 0), 0);
        assert_ne!(b2.statusword(0) & sw::VOLTAGE_ENABLED, 0);
        // The first drive: a reset edge clears, then it enables again.
        b.cw(0, 0x00);
        b.cw(0, 0x80);
        assert_eq!(b.state(0), State::SwitchOnDisabled);
        b.cw(0, 0x00);
        b.enable(0, mode::CSP);
    }

    #[test]
    fn injected_encoder_fault_freezes_the_position_and_sends_emergencies() {
        let mut b = Bench::new(2);
        b.enable(1, mode::CSV);
        b.set(1, 0x60FF, 0, CPR);
        b.run_ms(100.0);
        b.emergencies();
        b.drive.inject_fault("encoder", 2).unwrap();
        b.run_ms(1.0);
        assert_eq!(b.state(1), State::Fault);
        assert_eq!(b.get(1, 0x603F, 0), 0x7305);
        assert_eq!(b.od.get_int(0x1001, 0), 0x21);
        assert_eq!(b.state(0), State::SwitchOnDisabled, "axis 1 untouched");
        let frozen = b.position(1);
        b.run_ms(20.0);
        assert_eq!(b.position(1), frozen, "no encoder, no position");
        let e = b.emergencies();
        assert_eq!(e.len(), 1);
        assert_eq!(
            (e[0].error_code, e[0].error_register, e[0].data[0]),
            (0x7305, 0x21, 2)
        );
        b.cw(1, 0x80);
        assert_eq!(b.state(1), State::SwitchOnDisabled);
        assert_eq!(b.od.get_int(0x1001, 0), 0);
        let e = b.emergencies();
        assert_eq!(e.len(), 1, "the error-reset emergency");
        assert_eq!((e[0].error_code, e[0].error_register), (0, 0));
        // Injection errors name what is wrong.
        let err = b.drive.inject_fault("encoder", 3).unwrap_err();
        assert!(err.contains("no axis 3") && err.contains("1..=2"), "{err}");
        let err = b.drive.inject_fault("overheat", 1).unwrap_err();
        assert!(
            err.contains("'overheat'") && err.contains("over_current"),
            "{err}"
        );
    }

    #[test]
    fn losing_the_outputs_while_enabled_is_a_communication_fault() {
        let mut b = Bench::new(1);
        b.enable(0, mode::CSP);
        b.valid = false;
        b.run_ms(20.0);
        assert_eq!(b.state(0), State::Fault);
        assert_eq!(b.get(0, 0x603F, 0), 0x8130);
        // Switched on (no torque) is kept without a fault.
        let mut b = Bench::new(1);
        b.cw(0, 0x06);
        b.cw(0, 0x07);
        b.valid = false;
        b.run_ms(5.0);
        assert_eq!(b.state(0), State::SwitchedOn);
    }

    // ---------------------------------------------------------------- modes and physics

    #[test]
    fn csp_follows_a_ramp_within_a_bound() {
        let mut b = Bench::new(1);
        b.enable(0, mode::CSP);
        let start = b.position(0);
        // 0.5 joint rad/s = 25 motor rad/s, 1 ms cycle, for 0.4 s then hold.
        let per_ms = 25.0 * CPR as f64 / TAU / 1000.0;
        let mut worst = 0i64;
        for k in 1..=400 {
            let target = start + (k as f64 * per_ms).round() as i64;
            b.set(0, 0x607A, 0, target);
            b.run_ms(1.0);
            if k > 20 {
                // One interpolation period behind the target plus a small loop error.
                let lag = target - b.position(0);
                worst = worst.max((lag - per_ms.round() as i64).abs());
            }
            worst = worst.max(b.get(0, 0x60F4, 0).abs() - 50);
        }
        assert!(worst < 100, "worst deviation {worst} increments");
        let goal = start + (400.0 * per_ms).round() as i64;
        b.run_ms(100.0);
        assert!(
            (b.position(0) - goal).abs() <= 3,
            "settles on the last target"
        );
        assert_eq!(b.state(0), State::OperationEnabled);
    }

    #[test]
    fn cst_torque_accelerates_the_load_as_j_alpha_equals_tau_minus_friction() {
        let mut b = Bench::new(1);
        let p = MotorParams::default();
        b.enable(0, mode::CST);
        b.set(0, 0x6071, 0, 500); // 50 % of 0.2 Nm
        b.run_ms(1.0);
        let (_, w0) = b.drive.motor(0);
        b.run_ms(20.0);
        let (_, w1) = b.drive.motor(0);
        let alpha = (w1 - w0) / 0.020;
        let w_mean = (w0 + w1) / 2.0;
        let expected = (0.1 - p.coulomb_friction - p.viscous_friction * w_mean) / p.inertia();
        assert!(
            (alpha - expected).abs() / expected < 0.01,
            "α {alpha} vs {expected}"
        );
        assert_eq!(b.get(0, 0x6077, 0), 500);
        // Beyond 0x6072 the torque is limited and bit 11 says so.
        b.set(0, 0x6071, 0, 5000);
        b.run_ms(1.0);
        assert_eq!(b.get(0, 0x6077, 0), 3000);
        assert_ne!(b.statusword(0) & sw::INTERNAL_LIMIT, 0);
    }

    #[test]
    fn csv_reaches_the_target_velocity() {
        let mut b = Bench::new(1);
        moving_at(&mut b, -3 * CPR);
    }

    #[test]
    fn pp_handshake_and_trapezoidal_profile() {
        let mut b = Bench::new(1);
        b.enable(0, mode::PP);
        let start = b.position(0);
        b.set(0, 0x607A, 0, start + 4 * CPR);
        b.cw(0, 0x1F); // new set-point
        let word = b.statusword(0);
        assert_ne!(word & sw::MODE_12, 0, "set-point acknowledged");
        assert_eq!(word & sw::TARGET_REACHED, 0);
        b.cw(0, 0x0F);
        assert_eq!(
            b.statusword(0) & sw::MODE_12,
            0,
            "acknowledge follows bit 4 down"
        );
        // 4 rev at 1 rev/s with 10 rev/s² ramps: 0.1 s up, 3.9 s cruise... check cruise speed.
        b.run_ms(1000.0);
        let v = b.get(0, 0x606C, 0);
        assert!(
            (v - CPR).abs() < CPR / 50,
            "cruise at the profile velocity: {v}"
        );
        b.run_ms(3500.0);
        assert!((b.position(0) - (start + 4 * CPR)).abs() <= CPR / 100);
        assert_ne!(b.statusword(0) & sw::TARGET_REACHED, 0);
        // Relative move from the previous target.
        b.set(0, 0x607A, 0, -CPR);
        b.cw(0, 0x5F);
        b.cw(0, 0x4F);
        b.run_ms(2500.0);
        assert!((b.position(0) - (start + 3 * CPR)).abs() <= CPR / 100);
    }

    #[test]
    fn pv_ramps_to_the_target_velocity() {
        let mut b = Bench::new(1);
        b.enable(0, mode::PV);
        b.set(0, 0x60FF, 0, 5 * CPR);
        b.run_ms(250.0); // 10 rev/s² ramp: half way to 5 rev/s
        let v = b.get(0, 0x606C, 0) as f64 / CPR as f64;
        assert!((v - 2.5).abs() < 0.3, "ramping: {v}");
        assert_eq!(b.statusword(0) & sw::TARGET_REACHED, 0);
        b.run_ms(500.0);
        assert_ne!(b.statusword(0) & sw::TARGET_REACHED, 0, "velocity reached");
    }

    #[test]
    fn homing_on_the_current_position_sets_the_home_offset() {
        let mut b = Bench::new(1);
        b.set(0, 0x607C, 0, 12_345);
        b.enable(0, mode::HM);
        b.cw(0, 0x1F);
        assert_eq!(b.position(0), 12_345);
        let word = b.statusword(0);
        assert_ne!(word & sw::MODE_12, 0, "homing attained");
        assert_ne!(word & sw::TARGET_REACHED, 0);
        // CSP continues in the new frame without a jump.
        b.cw(0, 0x0F);
        b.set(0, 0x607A, 0, 12_345);
        b.set(0, 0x6060, 0, i64::from(mode::CSP));
        b.run_ms(50.0);
        assert!((b.position(0) - 12_345).abs() <= 2);
        // An unsupported method is a homing error.
        b.set(0, 0x6098, 0, 1);
        b.set(0, 0x6060, 0, i64::from(mode::HM));
        b.cw(0, 0x0F);
        b.cw(0, 0x1F);
        assert_ne!(b.statusword(0) & sw::MODE_13, 0);
    }

    #[test]
    fn software_position_limits_cut_the_target() {
        let mut b = Bench::new(1);
        b.set(0, 0x607D, 1, -1000);
        b.set(0, 0x607D, 2, 1000);
        b.enable(0, mode::CSP);
        b.set(0, 0x607A, 0, 5000);
        b.run_ms(100.0);
        assert!((b.position(0) - 1000).abs() <= 3);
        assert_ne!(b.statusword(0) & sw::INTERNAL_LIMIT, 0);
    }

    #[test]
    fn software_position_limits_hold_in_the_velocity_and_torque_modes() {
        // CSV towards max: stops at the limit (the speed is cut there, bit 11), then moves
        // back in when asked.
        let mut b = Bench::new(1);
        b.set(0, 0x607D, 1, -20_000);
        b.set(0, 0x607D, 2, 20_000);
        b.enable(0, mode::CSV);
        b.set(0, 0x60FF, 0, 50_000);
        b.run_ms(1000.0);
        let p = b.position(0);
        assert!((20_000..21_000).contains(&p), "{p}");
        assert!(b.get(0, 0x606C, 0).abs() < 500);
        assert_ne!(b.statusword(0) & sw::INTERNAL_LIMIT, 0);
        b.set(0, 0x60FF, 0, -50_000);
        b.run_ms(100.0);
        assert!(b.position(0) < p - 1000);
        // CST: an outward torque at the limit is refused, the motor stopped there.
        b.set(0, 0x60FF, 0, 0);
        b.set(0, 0x6060, 0, i64::from(mode::CST));
        b.set(0, 0x6071, 0, -100);
        b.run_ms(3000.0);
        let p = b.position(0);
        assert!(p > -22_000, "{p}");
        assert_ne!(b.statusword(0) & sw::INTERNAL_LIMIT, 0);
    }

    #[test]
    fn a_mode_change_continues_from_the_present_speed() {
        // PV at speed, then PP without a target: the profile stops at 0x6084, no jump.
        let mut b = Bench::new(1);
        b.enable(0, mode::PV);
        b.set(0, 0x60FF, 0, 16_384);
        b.run_ms(500.0);
        let v0 = b.get(0, 0x606C, 0);
        assert!((v0 - 16_384).abs() < 400, "{v0}");
        let p0 = b.position(0);
        b.set(0, 0x6060, 0, i64::from(mode::PP));
        b.run_ms(400.0);
        // 1 rev/s at 10 rev/s²: 0.1 s and 819 increments to stop.
        let p1 = b.position(0);
        assert!((p1 - p0 - 819).abs() < 200, "{}", p1 - p0);
        assert!(b.get(0, 0x606C, 0).abs() < 200);
    }

    /// Enable in HM with `method`, start homing (bit 4) and wait for the run to end.
    fn home_with(b: &mut Bench, method: i64, home_offset: i64) {
        b.set(0, 0x6098, 0, method);
        b.set(0, 0x607C, 0, home_offset);
        // One motor revolution per second to the index or the switch.
        b.set(0, 0x6099, 1, CPR);
        b.set(0, 0x6099, 2, CPR);
        b.enable(0, mode::HM);
        b.cw(0, 0x1F);
        for _ in 0..2000 {
            b.run_ms(5.0);
            if b.statusword(0) & sw::TARGET_REACHED != 0 {
                break;
            }
        }
    }

    #[test]
    fn homing_on_the_index_pulse_in_either_direction() {
        for (method, direction) in [(34, 1), (33, -1)] {
            let mut b = Bench::new(1);
            // Somewhere inside a motor revolution (the index is at multiples of 16384).
            b.enable(0, mode::CSV);
            b.set(0, 0x60FF, 0, 30_000);
            b.run_ms(200.0);
            b.set(0, 0x60FF, 0, 0);
            b.run_ms(300.0);
            b.cw(0, 0x06);
            let before = b.drive.motor(0).0 * CPR as f64 / TAU;
            home_with(&mut b, method, 1000);
            let word = b.statusword(0);
            assert_ne!(word & sw::MODE_12, 0, "{method}: homing attained");
            assert_eq!(word & sw::MODE_13, 0, "{method}: no homing error");
            // The index the run stopped at: the next multiple of the counts per revolution.
            let count = (b.drive.motor(0).0 * CPR as f64 / TAU).floor() as i64;
            let index = if direction > 0 {
                (before / CPR as f64).ceil() as i64 * CPR
            } else {
                (before / CPR as f64).floor() as i64 * CPR
            };
            assert!(
                (count - index).abs() < CPR / 2,
                "{method}: {count} vs index {index}"
            );
            assert_eq!(b.position(0), 1000 + count - index, "{method}");
            // Holding there.
            let here = b.position(0);
            b.run_ms(100.0);
            assert!((b.position(0) - here).abs() <= 2);
        }
    }

    #[test]
    fn homing_on_the_home_switch_edge() {
        // The home switch is on from 0.05 rad at the joint (2.5 rad at the motor) upwards.
        let mut b = Bench::new(1);
        home_with(&mut b, 19, 0);
        assert_ne!(b.statusword(0) & sw::MODE_12, 0);
        // Home is the switch's edge: the position there is 0, the axis a little beyond it.
        let edge = (0.05 * 50.0 * CPR as f64 / TAU) as i64;
        let count = (b.drive.motor(0).0 * CPR as f64 / TAU).floor() as i64;
        assert!(
            (b.position(0) - (count - edge)).abs() <= 20,
            "{} {count}",
            b.position(0)
        );
        assert_ne!(b.get(0, 0x60FD, 0) & 0b100, 0, "the home switch is on");
        // A method the drive lacks: homing error, nothing moves.
        let mut b = Bench::new(1);
        home_with(&mut b, 1, 0);
        assert_ne!(b.statusword(0) & sw::MODE_13, 0);
        assert_eq!(b.position(0), 0);
    }

    #[test]
    fn touch_probe_latches_the_index_pulse_and_the_home_switch() {
        let mut b = Bench::new(1);
        // Probe 1 on the index pulse, positive edge, first event only.
        b.set(0, 0x60B8, 0, 0x0001 | 0x0004 | 0x0010);
        b.enable(0, mode::CSV);
        b.set(0, 0x60FF, 0, 30_000);
        b.run_ms(1000.0);
        assert_eq!(
            b.get(0, 0x60B9, 0) & 0b11,
            0b11,
            "enabled, positive edge stored"
        );
        let latched = b.get(0, 0x60BA, 0);
        assert_eq!(latched % CPR, 0, "at the index: {latched}");
        b.run_ms(1000.0);
        assert_eq!(b.get(0, 0x60BA, 0), latched, "first event only");
        // Re-armed on the home switch (input 1), both edges, continuous.
        b.set(0, 0x60B8, 0, 0x0001 | 0x0002 | 0x0010 | 0x0020);
        b.set(0, 0x60FF, 0, 0);
        b.run_ms(10.0);
        b.set(0, 0x60B8, 0, 0);
        b.run_ms(1.0);
        b.set(0, 0x60B8, 0, 0x0001 | 0x0002 | 0x0010 | 0x0020);
        b.set(0, 0x60FF, 0, -60_000);
        b.run_ms(3000.0);
        assert_ne!(
            b.get(0, 0x60B9, 0) & 0b100,
            0,
            "the switch went off (negative edge)"
        );
        let edge = (0.05 * 50.0 * CPR as f64 / TAU) as i64;
        assert!(
            (b.get(0, 0x60BB, 0) - edge).abs() < 200,
            "{}",
            b.get(0, 0x60BB, 0)
        );
    }

    #[test]
    fn digital_outputs_are_wired_to_the_inputs_and_offsets_feed_forward() {
        let mut b = Bench::new(1);
        b.set(0, 0x60FE, 1, 0x0005_0001);
        b.run_ms(1.0);
        // Outputs 16-31 come back as inputs 16-31 (bit 0 is masked off by 0x60FE:2).
        assert_eq!(b.get(0, 0x60FD, 0) & 0xFFFF_0000, 0x0005_0000);
        // 0x60B1 adds to the velocity command (CSV at target 0 moves at the offset).
        b.enable(0, mode::CSV);
        b.set(0, 0x60B1, 0, 16_384);
        b.run_ms(300.0);
        assert!((b.get(0, 0x606C, 0) - 16_384).abs() < 400);
        // 0x60B2 adds to the torque (CST at target 0 accelerates).
        b.set(0, 0x60B1, 0, 0);
        b.set(0, 0x6060, 0, i64::from(mode::CST));
        b.set(0, 0x60B2, 0, 200);
        let v0 = b.get(0, 0x606C, 0);
        b.run_ms(50.0);
        assert!(b.get(0, 0x606C, 0) > v0 + 1000);
    }

    #[test]
    fn limit_switches_show_in_the_inputs() {
        let params = [("limit_switch_rad".to_string(), 0.02)];
        let config = Cia402Config::from_params(&params).unwrap();
        let mut b = Bench::with(1, config);
        b.enable(0, mode::CSV);
        b.set(0, 0x60FF, 0, 60_000);
        b.run_ms(1000.0);
        assert_ne!(b.get(0, 0x60FD, 0) & 0b010, 0, "positive limit switch");
        assert_eq!(b.get(0, 0x60FD, 0) & 0b001, 0);
    }

    #[test]
    fn axes_are_found_in_the_dictionary_and_hardware_published() {
        let params = [
            ("gear_ratio".to_string(), 9.5),
            ("encoder_counts_per_rev".to_string(), 4096.0),
        ];
        let b = Bench::with(2, Cia402Config::from_params(&params).unwrap());
        assert_eq!(b.drive.axis_count(), 2);
        for axis in 0..2 {
            assert_eq!(b.get(axis, 0x608F, 1), 4096);
            assert_eq!(
                (b.get(axis, 0x6091, 1), b.get(axis, 0x6091, 2)),
                (9500, 1000)
            );
        }
        let probe = b.drive.probe();
        assert!(probe.contains(&("axes", 2.0)));
        assert!(probe.iter().any(|(n, _)| *n == "axis2_position_rad"));
    }

    #[test]
    fn bad_parameters_are_named() {
        let bad =
            |name: &str, v: f64| Cia402Config::from_params(&[(name.to_string(), v)]).unwrap_err();
        assert!(bad("gear_ratio", 0.0).contains("'gear_ratio' must be a number > 0"));
        assert!(bad("coulomb_friction_nm", -1.0).contains("'coulomb_friction_nm'"));
        assert!(bad("encoder_counts_per_rev", 100.5).contains("whole number"));
        assert!(bad("velocity_loop_hz", 2000.0).contains("velocity_loop_hz"));
        assert!(bad("stiffness", 1.0).contains("unknown parameter 'stiffness'"));
    }

    #[test]
    fn defaults_match_the_esi() {
        // The ESI's default of each VAR object (subindex 0) is the drive's fallback default.
        let esi = include_str!("../../../../devices/servo_drive.xml");
        let device = &esi[..esi.find("ServoDrive2").expect("second device")];
        for ((index, sub, default), (_, bits)) in AXIS_KEYS.into_iter().zip(AXIS_TYPES) {
            if sub != 0 {
                continue;
            }
            let at = device
                .find(&format!("<Index>#x{index:04X}</Index>"))
                .unwrap_or_else(|| panic!("{index:#06x} missing in the ESI"));
            let rest = &device[at..];
            let data = &rest[rest.find("<DefaultData>").unwrap() + 13..];
            let hex = &data[..data.find('<').unwrap()];
            let mut raw = [0u8; 8];
            for (k, byte) in raw.iter_mut().enumerate().take(hex.len() / 2) {
                *byte = u8::from_str_radix(&hex[2 * k..2 * k + 2], 16).unwrap();
            }
            let value = u64::from_le_bytes(raw);
            let shift = 64 - u32::from(bits);
            let want = (default << shift >> shift) as u64 & (u64::MAX >> shift);
            assert_eq!(value, want, "{index:#06x}");
        }
    }

    #[test]
    fn a_vendor_dictionary_with_few_objects_uses_the_defaults() {
        // Only what a minimal CSP drive maps (like tests/data/esi/servo_vendor_style.xml).
        let mut b = Bench::new(1);
        let keep = [0x6040, 0x6041, 0x6060, 0x6061, 0x607A, 0x6064];
        let mut od = ObjectDictionary::new();
        for e in b.od.entries() {
            if keep.contains(&e.index) {
                od.add_entry(e.clone());
            }
        }
        b.od = od;
        b.drive.reset(&mut b.od);
        b.run_ms(1.0);
        b.enable(0, mode::CSP);
        let start = b.position(0);
        b.set(0, 0x607A, 0, start + 1000);
        b.run_ms(100.0);
        assert!((b.position(0) - (start + 1000)).abs() <= 3);
    }
}
