//! The Laelaps II leg firmware (one EtherCAT slave per leg), as described in the thesis: it reads
//! the outputs of Table 4.1, runs a semi-elliptical toe trajectory (eq. 4.5) through inverse
//! kinematics (eqs. 4.2–4.3) and a PIV controller per joint at 10 kHz, and reports the inputs of
//! Table 4.2. Behind it, `leg_physics` simulates the motors and the leg. See docs/laelaps.md.
//!
//! Object dictionary (index:subindex, type):
//! outputs 0x7000:01 State_Machine (bool: 0 Configurational, 1 Operational), 0x7000:09
//! Transition_time (int8, s), 0x7012:01 FilterBandwidth (uint16, Hz), 0x7020:01..06 Kp100_knee,
//! Kd1000_knee, Ki100_knee, Kp100_hip, Kd1000_hip, Ki100_hip (int16), 0x7030:01..07
//! x_cntr_traj1000 (mm), y_cntr_traj1000 (mm), a_ellipse100 (cm), b_ellipse100 (cm), traj_freq100
//! (Hz/100), phase_deg (deg), FlatnessParam100 (/100) (int16); 0x7000:02..08, 0x7010 and 0x7014
//! are not read (as in the thesis).
//! inputs 0x6010:01/02 hip_angle / desired_hip_angle (int16, deg·100), 0x6012:01 Time (uint16,
//! s), 0x6014:01/02 knee_angle / desired_knee_angle (int16, deg·100), 0x6020:01/02 PWM10000_knee /
//! PWM10000_hip (int16, %·100), 0x6030:01/02 velocity_knee1000 / velocity_hip1000 (int32,
//! rad/s·1000).

use super::leg_kinematics::{forward, inverse, JointAngles};
use super::leg_physics::{LegParams, LegPhysics};
use super::od_slots::OdSlots;
use super::period_clock::PeriodClock;
use super::trajectory::{Trajectory, TrajectoryParams};
use crate::device::DeviceApp;
use crate::od::ObjectDictionary;

/// The objects the firmware reads and writes, resolved once into `OdSlots` (slot = position in
/// this list): commands first (Table 4.1), then feedback (Table 4.2).
const OD_KEYS: [(u16, u8); 25] = [
    (0x7000, 1), // 0 State_Machine
    (0x7000, 9), // 1 Transition_time
    (0x7012, 1), // 2 FilterBandwidth
    (0x7020, 1), // 3..8 Kp100_knee, Kd1000_knee, Ki100_knee, Kp100_hip, Kd1000_hip, Ki100_hip
    (0x7020, 2),
    (0x7020, 3),
    (0x7020, 4),
    (0x7020, 5),
    (0x7020, 6),
    (0x7030, 1), // 9..15 x_cntr, y_cntr, a, b, freq, phase, flatness
    (0x7030, 2),
    (0x7030, 3),
    (0x7030, 4),
    (0x7030, 5),
    (0x7030, 6),
    (0x7030, 7),
    (0x6010, 1), // 16 hip_angle
    (0x6010, 2), // 17 desired_hip_angle
    (0x6012, 1), // 18 Time
    (0x6014, 1), // 19 knee_angle
    (0x6014, 2), // 20 desired_knee_angle
    (0x6020, 1), // 21 PWM10000_knee
    (0x6020, 2), // 22 PWM10000_hip
    (0x6030, 1), // 23 velocity_knee1000
    (0x6030, 2), // 24 velocity_hip1000
];
const SLOT_GAINS: usize = 3;
const SLOT_TRAJECTORY: usize = 9;
const SLOT_FEEDBACK: usize = 16;

/// Control period: 10 kHz (Table 6.1).
pub const PERIOD_NS: u64 = 100_000;
/// Longest stretch of time one `step` catches up on; beyond it the firmware "loses" time
/// (a stalled simulator must not spend seconds computing the past).
const MAX_CATCH_UP_PERIODS: u64 = 1_000;
/// Physics steps per control period. One is enough: the stiffest mode (the floor spring against
/// the leg's effective mass) has ω·dt < 0.02, far inside semi-implicit Euler's stability limit.
const SUBSTEPS: u32 = 1;
/// Motor encoder counts per motor revolution (500-line quadrature encoder, 4x decoding).
pub const ENCODER_COUNTS_PER_REV: f64 = 2_000.0;

/// What the firmware is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Outputs not valid (not OP or watchdog): motors off, commands ignored.
    Off,
    /// State_Machine = 0: hold the pose, accept parameters.
    Configurational,
    /// State_Machine = 1: follow the trajectory.
    Operational,
}

/// Per-joint PIV controller state.
#[derive(Clone, Copy, Debug, Default)]
struct Piv {
    integral_deg_s: f64,
}

/// Gains of one joint as the firmware uses them (Table 4.1 record 0x7020, scaled):
/// `kp` = Kp100/100, the position gain in 1/s (deg/s of velocity command per deg of error);
/// `kv` = Kd1000/1000, the velocity gain in % per deg/s (Table 4.1: "Velocity gain");
/// `ki` = Ki100/100, the integral gain in % per deg·s.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Gains {
    /// Proportional gain of the joint controller.
    pub kp: f64,
    /// Velocity (derivative) gain of the joint controller.
    pub kv: f64,
    /// Integral gain of the joint controller.
    pub ki: f64,
}

impl Piv {
    /// The PIV law (Proportional position loop, Integral, Velocity loop), cascaded as its name
    /// says: the position error makes a velocity command `kp·e`, the velocity gain turns the
    /// velocity error into PWM, and the integral of the position error is added:
    /// `PWM% = kv·(kp·e - ω) + ki·∫e dt`, angles in deg, clamped to the limit; the integral
    /// stops growing while the output saturates in the direction of the error.
    ///
    /// (Read as a parallel `Kp·e - Kd·ω` instead, Table 6.1's gains would saturate the PWM at
    /// 0.5° of error with a velocity term some twenty times too weak to damp the leg's
    /// reflected rotor inertia (damping ratio ≈ 0.04): the loop becomes a relay that chatters
    /// between the limits. See docs/laelaps.md, "Control".)
    fn update(&mut self, g: Gains, err_deg: f64, vel_deg_s: f64, dt: f64, limit: f64) -> f64 {
        let output = |integral: f64| g.kv * (g.kp * err_deg - vel_deg_s) + g.ki * integral;
        let unclamped = output(self.integral_deg_s);
        let saturated = unclamped.abs() >= limit && unclamped.signum() == err_deg.signum();
        if !saturated {
            self.integral_deg_s += err_deg * dt;
        }
        output(self.integral_deg_s).clamp(-limit, limit)
    }
}

/// First-order low-pass on the differentiated encoder angle.
#[derive(Clone, Copy, Debug, Default)]
struct VelocityFilter {
    last_angle: Option<f64>,
    value: f64,
}

impl VelocityFilter {
    /// `bandwidth_hz` 0 turns the filter off (raw difference quotient).
    fn update(&mut self, angle: f64, dt: f64, bandwidth_hz: f64) -> f64 {
        let raw = match self.last_angle {
            Some(last) => (angle - last) / dt,
            None => 0.0,
        };
        self.last_angle = Some(angle);
        if bandwidth_hz <= 0.0 {
            self.value = raw;
        } else {
            let wc_dt = std::f64::consts::TAU * bandwidth_hz * dt;
            self.value += wc_dt / (1.0 + wc_dt) * (raw - self.value);
        }
        self.value
    }
}

/// The commands read from the object dictionary once per `step`.
#[derive(Clone, Copy, Debug)]
struct Commands {
    operational: bool,
    transition_s: f64,
    filter_hz: f64,
    knee: Gains,
    hip: Gains,
    trajectory: TrajectoryParams,
}

impl Commands {
    fn read(od: &ObjectDictionary, slots: &OdSlots) -> Self {
        let gains = |first: usize| Gains {
            kp: slots.get(od, first) as f64 / 100.0,
            kv: slots.get(od, first + 1) as f64 / 1000.0,
            ki: slots.get(od, first + 2) as f64 / 100.0,
        };
        let mut raw = [0i64; 7];
        for (i, v) in raw.iter_mut().enumerate() {
            *v = slots.get(od, SLOT_TRAJECTORY + i);
        }
        Self {
            operational: slots.get(od, 0) & 1 != 0,
            transition_s: slots.get(od, 1).max(0) as f64,
            filter_hz: slots.get(od, 2) as f64,
            knee: gains(SLOT_GAINS),
            hip: gains(SLOT_GAINS + 3),
            trajectory: TrajectoryParams::from_raw(raw),
        }
    }
}

/// Device parameters from the bus config (`sim.params`).
#[derive(Clone, Copy, Debug)]
pub struct LaelapsLegConfig {
    /// Geometry and dynamics of the leg.
    pub leg: LegParams,
    /// Initial toe position (m) at power-on; default: standing on the floor below the hip.
    pub initial_x: f64,
    /// Initial toe height (m) at power-on; None: on the floor.
    pub initial_y: Option<f64>,
    /// The treadmill belt runs at this factor times the trot's mean stance speed 4·a·f
    /// (0: the floor stands still).
    pub treadmill_speed_factor: f64,
}

impl LaelapsLegConfig {
    /// Names accepted in `sim.params`.
    pub const PARAMS: &'static [&'static str] = &[
        "floor_y_m",
        "floor_stiffness_n_per_m",
        "floor_damping_n_s_per_m",
        "floor_friction",
        "body_load_n",
        "treadmill_speed_factor",
        "thigh_mass_kg",
        "shank_mass_kg",
        "initial_toe_x_m",
        "initial_toe_y_m",
    ];

    /// The configuration from the bus config's `sim.params`; an unknown or invalid parameter is
    /// an error naming it.
    pub fn from_params(params: &[(String, f64)]) -> Result<Self, String> {
        let mut c = Self {
            leg: LegParams::default(),
            initial_x: 0.0,
            initial_y: None,
            treadmill_speed_factor: 1.0,
        };
        for (name, value) in params {
            let v = *value;
            if !v.is_finite() {
                return Err(format!(
                    "laelaps_leg: parameter '{name}' is not a finite number"
                ));
            }
            match name.as_str() {
                "floor_y_m" => c.leg.floor_y = v,
                "floor_stiffness_n_per_m" => c.leg.floor_stiffness = v.max(0.0),
                "floor_damping_n_s_per_m" => c.leg.floor_damping = v.max(0.0),
                "floor_friction" => c.leg.floor_friction = v.max(0.0),
                "body_load_n" => c.leg.body_load = v.max(0.0),
                "treadmill_speed_factor" => c.treadmill_speed_factor = v.max(0.0),
                "thigh_mass_kg" if v > 0.0 => c.leg.thigh_mass = v,
                "shank_mass_kg" if v > 0.0 => c.leg.shank_mass = v,
                "initial_toe_x_m" => c.initial_x = v,
                "initial_toe_y_m" => c.initial_y = Some(v),
                "thigh_mass_kg" | "shank_mass_kg" => {
                    return Err(format!(
                        "laelaps_leg: parameter '{name}' must be > 0, got {v}"
                    ))
                }
                other => {
                    return Err(format!(
                        "laelaps_leg: unknown parameter '{other}' (known: {})",
                        Self::PARAMS.join(", ")
                    ))
                }
            }
        }
        let y = c.initial_y.unwrap_or(c.leg.floor_y.min(0.599));
        if inverse(c.initial_x, y).is_none() {
            return Err(format!(
                "laelaps_leg: initial toe position ({}, {y}) m is outside the leg's workspace",
                c.initial_x
            ));
        }
        Ok(c)
    }

    fn initial_pose(&self) -> JointAngles {
        let y = self.initial_y.unwrap_or(self.leg.floor_y.min(0.599));
        inverse(self.initial_x, y).expect("checked in from_params")
    }
}

/// The leg firmware plus its physics.
pub struct LaelapsLeg {
    config: LaelapsLegConfig,
    physics: LegPhysics,
    trajectory: Trajectory,
    mode: Mode,
    /// Toe point held in Configurational state and blended from when entering Operational.
    hold_point: (f64, f64),
    /// Time into the blend from `hold_point` onto the trajectory, s, and its length.
    blend_elapsed_s: f64,
    blend_s: f64,
    desired: JointAngles,
    desired_point: (f64, f64),
    measured: JointAngles,
    velocity: [f64; 2],
    pwm: [f64; 2],
    piv: [Piv; 2],
    filters: [VelocityFilter; 2],
    clock: PeriodClock,
    firmware_time_s: f64,
    unreachable_points: u64,
    /// The commands of the last step with valid outputs (for `probe`).
    last_commands: Option<Commands>,
    slots: OdSlots,
}

impl LaelapsLeg {
    /// A leg in its power-on state with `config`.
    pub fn new(config: LaelapsLegConfig) -> Self {
        let q = config.initial_pose();
        let toe = forward(q);
        Self {
            config,
            physics: LegPhysics::new(config.leg, q),
            trajectory: Trajectory::at_point(toe.0, toe.1),
            mode: Mode::Off,
            hold_point: toe,
            blend_elapsed_s: 0.0,
            blend_s: 0.0,
            desired: q,
            desired_point: toe,
            measured: q,
            velocity: [0.0; 2],
            pwm: [0.0; 2],
            piv: [Piv::default(); 2],
            filters: [VelocityFilter::default(); 2],
            clock: PeriodClock::default(),
            firmware_time_s: 0.0,
            unreachable_points: 0,
            last_commands: None,
            slots: OdSlots::default(),
        }
    }

    /// The control mode the master last selected.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The leg's physics model (state of the joints and the toe), for probes and tests.
    pub fn physics(&self) -> &LegPhysics {
        &self.physics
    }

    /// The trajectory the leg's controller follows, for probes and tests.
    pub fn trajectory(&self) -> &Trajectory {
        &self.trajectory
    }

    /// Measured (encoder) and desired joint angles, rad.
    pub fn measured(&self) -> JointAngles {
        self.measured
    }

    /// The joint angles the controller aims at now.
    pub fn desired(&self) -> JointAngles {
        self.desired
    }

    /// PWM commands (%), hip then knee.
    pub fn pwm(&self) -> [f64; 2] {
        self.pwm
    }

    /// Filtered joint velocities (rad/s), hip then knee.
    pub fn velocity(&self) -> [f64; 2] {
        self.velocity
    }

    fn encoder(angle: f64, ratio: f64) -> f64 {
        let step = std::f64::consts::TAU / (ENCODER_COUNTS_PER_REV * ratio);
        (angle / step).round() * step
    }

    /// Hold the pose the leg is in now (entering Configurational, or motors back on).
    fn hold_current_pose(&mut self) {
        self.hold_point = forward(self.measured);
        self.desired = self.measured;
        self.desired_point = self.hold_point;
        self.piv = [Piv::default(); 2];
    }

    /// One 100 µs control period: sensors, state machine, trajectory, IK, PIV.
    fn control_tick(&mut self, cmd: Option<&Commands>, dt: f64) {
        let hip_ratio = self.physics.hip.ratio;
        let knee_ratio = self.physics.knee.ratio;
        self.measured = JointAngles {
            theta1: Self::encoder(self.physics.q.theta1, hip_ratio),
            theta2: Self::encoder(self.physics.q.theta2, knee_ratio),
        };
        let bandwidth = cmd.map_or(0.0, |c| c.filter_hz);
        self.velocity = [
            self.filters[0].update(self.measured.theta1, dt, bandwidth),
            self.filters[1].update(self.measured.theta2, dt, bandwidth),
        ];
        let Some(cmd) = cmd else {
            self.mode = Mode::Off;
            self.pwm = [0.0; 2];
            self.piv = [Piv::default(); 2];
            self.desired = self.measured;
            self.desired_point = forward(self.measured);
            return;
        };
        if !cmd.operational {
            if self.mode != Mode::Configurational {
                self.mode = Mode::Configurational;
                self.hold_current_pose();
            }
            // Parameters are accepted (and validated) but nothing moves: no transition needed.
            self.trajectory.set_now(cmd.trajectory);
        } else {
            if self.mode != Mode::Operational {
                if self.mode == Mode::Off {
                    self.hold_current_pose();
                }
                self.mode = Mode::Operational;
                self.hold_point = self.desired_point;
                self.blend_elapsed_s = 0.0;
                self.blend_s = cmd.transition_s;
                self.trajectory.restart_phase();
            }
            self.trajectory.offer(cmd.trajectory, cmd.transition_s);
            self.trajectory.advance(dt);
            let mut point = self.trajectory.point();
            if self.blend_elapsed_s < self.blend_s {
                self.blend_elapsed_s += dt;
                let f = (self.blend_elapsed_s / self.blend_s).min(1.0);
                point.0 = self.hold_point.0 + (point.0 - self.hold_point.0) * f;
                point.1 = self.hold_point.1 + (point.1 - self.hold_point.1) * f;
            }
            // An unreachable point is not served: the last valid one stays (thesis §4.2.2.6).
            match inverse(point.0, point.1) {
                Some(q) => {
                    self.desired = q;
                    self.desired_point = point;
                }
                None => self.unreachable_points += 1,
            }
        }
        let err_hip = (self.desired.theta1 - self.measured.theta1).to_degrees();
        let err_knee = (self.desired.theta2 - self.measured.theta2).to_degrees();
        let hip_limit = self.physics.hip.pwm_limit_pct;
        let knee_limit = self.physics.knee.pwm_limit_pct;
        let v = [self.velocity[0].to_degrees(), self.velocity[1].to_degrees()];
        self.pwm = [
            self.piv[0].update(cmd.hip, err_hip, v[0], dt, hip_limit),
            self.piv[1].update(cmd.knee, err_knee, v[1], dt, knee_limit),
        ];
    }

    /// The treadmill belt's velocity along x, m/s: while the legs trot, the operator runs it at
    /// the gait's mean stance speed, 4·a·f backwards (the toe covers 2a in half a period), so
    /// the robot stays in place; it follows a and f through their transitions. Standing (or
    /// not in Operational state) it stands still.
    fn belt_velocity(&self) -> f64 {
        if self.mode != Mode::Operational {
            return 0.0;
        }
        let t = self.trajectory.current();
        -4.0 * t.a * t.freq_hz * self.config.treadmill_speed_factor
    }

    fn write_feedback(&self, od: &mut ObjectDictionary) {
        let centi_deg = |a: f64| (a.to_degrees() * 100.0).round().clamp(-32768.0, 32767.0) as i64;
        let milli = |v: f64| (v * 1000.0).round().clamp(i32::MIN as f64, i32::MAX as f64) as i64;
        let values = [
            centi_deg(self.measured.theta1),
            centi_deg(self.desired.theta1),
            (self.firmware_time_s as u64 % 65_536) as i64,
            centi_deg(self.measured.theta2),
            centi_deg(self.desired.theta2),
            (self.pwm[1] * 100.0).round() as i64,
            (self.pwm[0] * 100.0).round() as i64,
            milli(self.velocity[1]),
            milli(self.velocity[0]),
        ];
        for (i, v) in values.into_iter().enumerate() {
            self.slots.set(od, SLOT_FEEDBACK + i, v);
        }
    }
}

impl DeviceApp for LaelapsLeg {
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
        self.slots.resolve(od, &OD_KEYS);
        let cmd = outputs_valid.then(|| Commands::read(od, &self.slots));
        if cmd.is_some() {
            self.last_commands = cmd;
        }
        let dt = PERIOD_NS as f64 * 1e-9;
        for _ in 0..run {
            self.control_tick(cmd.as_ref(), dt);
            self.physics.belt_vx = self.belt_velocity();
            self.physics.advance(dt, self.pwm[0], self.pwm[1], SUBSTEPS);
            self.firmware_time_s += dt;
        }
        self.write_feedback(od);
    }

    fn reset(&mut self, od: &mut ObjectDictionary) {
        *self = Self::new(self.config);
        self.slots.resolve(od, &OD_KEYS);
        self.write_feedback(od);
    }

    fn probe(&self) -> Vec<(&'static str, f64)> {
        let toe = forward(self.physics.q);
        let mut values = vec![
            ("hip_angle_rad", self.physics.q.theta1),
            ("knee_angle_rad", self.physics.q.theta2),
            ("measured_hip_angle_rad", self.measured.theta1),
            ("measured_knee_angle_rad", self.measured.theta2),
            ("desired_hip_angle_rad", self.desired.theta1),
            ("desired_knee_angle_rad", self.desired.theta2),
            ("toe_x_m", toe.0),
            ("toe_y_m", toe.1),
            ("desired_toe_x_m", self.desired_point.0),
            ("desired_toe_y_m", self.desired_point.1),
            ("pwm_hip", self.pwm[0]),
            ("pwm_knee", self.pwm[1]),
            ("velocity_hip_rad_s", self.velocity[0]),
            ("velocity_knee_rad_s", self.velocity[1]),
            ("true_velocity_hip_rad_s", self.physics.w[0]),
            ("true_velocity_knee_rad_s", self.physics.w[1]),
            ("current_hip_a", self.physics.hip.current(self.pwm[0])),
            ("current_knee_a", self.physics.knee.current(self.pwm[1])),
            ("contact_force_n", self.physics.contact_force()),
            ("floor_y_m", self.physics.floor_y),
            ("belt_velocity_m_s", self.physics.belt_vx),
            ("mode", self.mode as u8 as f64),
            ("firmware_time_s", self.firmware_time_s),
            ("rejected_trajectories", self.trajectory.rejected() as f64),
            ("unreachable_points", self.unreachable_points as f64),
            ("traj_a_m", self.trajectory.current().a),
            ("traj_b_m", self.trajectory.current().b),
        ];
        // What the firmware last received (0 before the first valid outputs).
        let c = self.last_commands;
        let t = c.map(|c| c.trajectory);
        values.extend([
            (
                "cmd_state_machine",
                c.map_or(0.0, |c| f64::from(u8::from(c.operational))),
            ),
            ("cmd_transition_time_s", c.map_or(0.0, |c| c.transition_s)),
            ("cmd_filter_bandwidth_hz", c.map_or(0.0, |c| c.filter_hz)),
            ("cmd_kp_hip", c.map_or(0.0, |c| c.hip.kp)),
            ("cmd_kp_knee", c.map_or(0.0, |c| c.knee.kp)),
            ("cmd_x_c_m", t.map_or(0.0, |t| t.x_c)),
            ("cmd_y_c_m", t.map_or(0.0, |t| t.y_c)),
            ("cmd_a_m", t.map_or(0.0, |t| t.a)),
            ("cmd_b_m", t.map_or(0.0, |t| t.b)),
            ("cmd_freq_hz", t.map_or(0.0, |t| t.freq_hz)),
        ]);
        values
    }
}

/// The Laelaps II dictionary of Tables 4.1/4.2 (the same objects the ESI describes), for tests
/// and for running the firmware without an ESI.
pub fn object_dictionary() -> ObjectDictionary {
    use crate::od::{dtype, Access};
    type Sub = (u8, &'static str, u16, u16);
    let b = |s: u8, n: &'static str| -> Sub { (s, n, dtype::BOOL, 1) };
    let i16e = |s: u8, n: &'static str| -> Sub { (s, n, dtype::INT16, 16) };
    let objects: Vec<(u16, &str, Vec<Sub>)> = vec![
        (
            0x7000,
            "Buttons",
            vec![
                b(1, "State_Machine"),
                b(2, "Initialize_clock"),
                b(3, "Initialize_angles"),
                b(4, "Inverse_Kinematics"),
                b(5, "Blue_LED"),
                b(6, "Red_LED"),
                b(7, "Button1"),
                b(8, "Button2"),
                (9, "Transition_time", dtype::INT8, 8),
            ],
        ),
        (
            0x7010,
            "Desired_x_value",
            vec![(1, "Desired_x_value", dtype::INT32, 32)],
        ),
        (
            0x7012,
            "TargetMode",
            vec![(1, "FilterBandwidth", dtype::UINT16, 16)],
        ),
        (
            0x7014,
            "Desired_y_value",
            vec![(1, "Desired_y_value", dtype::INT32, 32)],
        ),
        (
            0x7020,
            "ControlGains",
            vec![
                i16e(1, "Kp100_knee"),
                i16e(2, "Kd1000_knee"),
                i16e(3, "Ki100_knee"),
                i16e(4, "Kp100_hip"),
                i16e(5, "Kd1000_hip"),
                i16e(6, "Ki100_hip"),
            ],
        ),
        (
            0x7030,
            "TrajectoryParameters",
            vec![
                i16e(1, "x_cntr_traj1000"),
                i16e(2, "y_cntr_traj1000"),
                i16e(3, "a_ellipse100"),
                i16e(4, "b_ellipse100"),
                i16e(5, "traj_freq100"),
                i16e(6, "phase_deg"),
                i16e(7, "FlatnessParam100"),
            ],
        ),
        (
            0x6010,
            "hip_angle",
            vec![i16e(1, "hip_angle"), i16e(2, "desired_hip_angle")],
        ),
        (0x6012, "FeedbackTime", vec![(1, "Time", dtype::UINT16, 16)]),
        (
            0x6014,
            "knee_angle",
            vec![i16e(1, "knee_angle"), i16e(2, "desired_knee_angle")],
        ),
        (
            0x6020,
            "Commands",
            vec![i16e(1, "PWM10000_knee"), i16e(2, "PWM10000_hip")],
        ),
        (
            0x6030,
            "Velocity",
            vec![
                (1, "velocity_knee1000", dtype::INT32, 32),
                (2, "velocity_hip1000", dtype::INT32, 32),
            ],
        ),
    ];
    let mut od = ObjectDictionary::new();
    for (index, name, subs) in objects {
        let access = if index >= 0x7000 {
            Access::ReadWrite
        } else {
            Access::ReadOnly
        };
        let entries: Vec<_> = subs
            .into_iter()
            .map(|(sub, entry_name, data_type, bits)| {
                (sub, entry_name.to_string(), data_type, bits)
            })
            .collect();
        od.add_record(index, name, access, &entries);
    }
    od
}

#[cfg(test)]
mod tests {
    use super::super::leg_physics::Actuator;
    use super::*;

    /// Table 6.1 (FR leg): gains, filter, transition time; the ellipse starts as a point.
    fn table_6_1(od: &mut ObjectDictionary, y_c_mm: i64, a_cm: i64, b_cm: i64) {
        od.set_int(0x7000, 9, 3);
        od.set_int(0x7012, 1, 20);
        for (sub, v) in [(1, 8000), (2, 50), (3, 0), (4, 8000), (5, 50), (6, 0)] {
            od.set_int(0x7020, sub, v);
        }
        for (sub, v) in [
            (1, 0),
            (2, y_c_mm),
            (3, a_cm),
            (4, b_cm),
            (5, 100),
            (6, 0),
            (7, 0),
        ] {
            od.set_int(0x7030, sub, v);
        }
    }

    struct Rig {
        leg: LaelapsLeg,
        od: ObjectDictionary,
        t_ns: u64,
    }

    impl Rig {
        fn new() -> Self {
            let mut od = object_dictionary();
            let mut leg = LaelapsLeg::new(LaelapsLegConfig::from_params(&[]).unwrap());
            leg.reset(&mut od);
            Self {
                leg,
                od,
                t_ns: 1_000_000_000,
            }
        }

        /// Run for `seconds` at the 10 kHz firmware rate, calling `each` after every step.
        fn run(
            &mut self,
            seconds: f64,
            valid: bool,
            mut each: impl FnMut(&LaelapsLeg, &ObjectDictionary),
        ) {
            let steps = (seconds * 1e9 / PERIOD_NS as f64).round() as u64;
            for _ in 0..steps {
                self.t_ns += PERIOD_NS;
                self.leg.step(&mut self.od, self.t_ns, valid);
                each(&self.leg, &self.od);
            }
        }
    }

    /// Table 6.1's legs: name, y_cntr_traj1000 (mm), phase_deg.
    const TABLE_6_1_LEGS: [(&str, i64, i64); 4] = [
        ("FL", 599, 180),
        ("FR", 599, 0),
        ("HL", 598, 0),
        ("HR", 598, 180),
    ];

    /// What one leg did over the steady trot.
    #[derive(Debug, Default)]
    struct TrotStats {
        samples: u32,
        /// Periods with the PWM at its limit, and the number and longest run of such
        /// stretches; hip then knee.
        at_limit: [u32; 2],
        episodes: [u32; 2],
        longest: [u32; 2],
        peak_pwm: [f64; 2],
        /// Peak |filtered velocity|, rad/s.
        peak_velocity: [f64; 2],
        /// Squared joint errors (rad²) and toe distances from the desired path (m).
        joint_err_sq: [f64; 2],
        toe_err_sq: f64,
        toe_err_max: f64,
        toe_x: (f64, f64),
        min_toe_y: f64,
        contact_sum: f64,
    }

    impl TrotStats {
        fn share_at_limit(&self, joint: usize) -> f64 {
            f64::from(self.at_limit[joint]) / f64::from(self.samples)
        }

        fn rms_deg(&self, joint: usize) -> f64 {
            (self.joint_err_sq[joint] / f64::from(self.samples))
                .sqrt()
                .to_degrees()
        }

        fn toe_rms_m(&self) -> f64 {
            (self.toe_err_sq / f64::from(self.samples)).sqrt()
        }
    }

    /// The trot of §6.2.1.1 on one leg: Table 6.1 with a = b = 0, Operational, b to 4 cm, then
    /// a to 5 cm (3 s transitions), one more second, then `seconds` of steady trot measured.
    fn trot(y_c_mm: i64, phase_deg: i64, seconds: f64) -> (TrotStats, Rig) {
        let mut rig = Rig::new();
        table_6_1(&mut rig.od, y_c_mm, 0, 0);
        rig.od.set_int(0x7030, 6, phase_deg);
        rig.run(0.5, true, |_, _| {});
        rig.od.set_int(0x7000, 1, 1);
        rig.run(3.0, true, |_, _| {});
        rig.od.set_int(0x7030, 4, 4);
        rig.run(3.0, true, |_, _| {});
        rig.od.set_int(0x7030, 3, 5);
        rig.run(4.0, true, |_, _| {});
        assert!((rig.leg.trajectory().current().a - 0.05).abs() < 1e-9);
        // The desired path: the semi-ellipse where the leg can reach it (eq. 4.5).
        let p = *rig.leg.trajectory().current();
        let path: Vec<(f64, f64)> = (0..1440)
            .map(|i| p.point_at(std::f64::consts::TAU * f64::from(i) / 1440.0))
            .filter(|&(x, y)| inverse(x, y).is_some())
            .collect();
        let limits = [
            rig.leg.physics().hip.pwm_limit_pct,
            rig.leg.physics().knee.pwm_limit_pct,
        ];
        let mut st = TrotStats {
            toe_x: (f64::MAX, f64::MIN),
            min_toe_y: f64::MAX,
            ..TrotStats::default()
        };
        let mut run = [0u32; 2];
        rig.run(seconds, true, |leg, _| {
            st.samples += 1;
            for j in 0..2 {
                let pwm = leg.pwm()[j].abs();
                st.peak_pwm[j] = st.peak_pwm[j].max(pwm);
                st.peak_velocity[j] = st.peak_velocity[j].max(leg.velocity()[j].abs());
                if pwm >= limits[j] - 1e-9 {
                    st.episodes[j] += u32::from(run[j] == 0);
                    run[j] += 1;
                    st.at_limit[j] += 1;
                    st.longest[j] = st.longest[j].max(run[j]);
                } else {
                    run[j] = 0;
                }
            }
            let (d, q) = (leg.desired(), leg.physics().q);
            st.joint_err_sq[0] += (d.theta1 - q.theta1).powi(2);
            st.joint_err_sq[1] += (d.theta2 - q.theta2).powi(2);
            let (x, y) = forward(q);
            let e = path
                .iter()
                .map(|&(px, py)| (px - x).hypot(py - y))
                .fold(f64::MAX, f64::min);
            st.toe_err_sq += e * e;
            st.toe_err_max = st.toe_err_max.max(e);
            st.toe_x = (st.toe_x.0.min(x), st.toe_x.1.max(x));
            st.min_toe_y = st.min_toe_y.min(y);
            st.contact_sum += leg.physics().contact_force();
        });
        (st, rig)
    }

    /// The trot of Table 6.1 has the shape chapter 6 reports (Figs. 6.5–6.11), leg by leg.
    #[test]
    fn table_6_1_trot_has_the_shape_of_chapter_6() {
        let seconds = 3.0; // three strides at 1 Hz
        let strides = 3;
        let hip = Actuator::hip();
        let knee = Actuator::knee();
        let mut hind_hip_share: f64 = 1.0;
        let mut fore_hip_share: f64 = 0.0;
        for (name, y_c, phase) in TABLE_6_1_LEGS {
            let (st, rig) = trot(y_c, phase, seconds);
            eprintln!(
                "{name}: at the PWM limit hip {:.1} % knee {:.1} % (peaks {:.1} / {:.1} %, \
                 {:?} stretches, longest {:?} periods), RMS error hip {:.2}° knee {:.2}°, toe \
                 {:.1} mm RMS / {:.1} mm max from the path, x {:.0}..{:.0} mm, peak speed \
                 {:.2} / {:.2} rad/s, mean contact {:.0} N",
                100.0 * st.share_at_limit(0),
                100.0 * st.share_at_limit(1),
                st.peak_pwm[0],
                st.peak_pwm[1],
                st.episodes,
                st.longest,
                st.rms_deg(0),
                st.rms_deg(1),
                st.toe_rms_m() * 1e3,
                st.toe_err_max * 1e3,
                st.toe_x.0 * 1e3,
                st.toe_x.1 * 1e3,
                st.peak_velocity[0],
                st.peak_velocity[1],
                st.contact_sum / f64::from(st.samples)
            );
            // Fig. 6.8: no knee chatters; the hind knees stay within the limit (the fore knees
            // may touch it, briefly).
            assert!(st.share_at_limit(1) < 0.05, "{name} knee {st:?}");
            assert!(st.longest[1] < 500, "{name} knee held at the limit: {st:?}");
            if name.starts_with('H') {
                assert_eq!(st.at_limit[1], 0, "{name} knee {st:?}");
                hind_hip_share = hind_hip_share.min(st.share_at_limit(0));
                // Fig. 6.9: the hind hips reach their limit at every stride, briefly.
                assert!(st.episodes[0] >= strides, "{name} hip {st:?}");
                assert!(st.share_at_limit(0) < 0.15, "{name} hip {st:?}");
            } else {
                fore_hip_share = fore_hip_share.max(st.share_at_limit(0));
            }
            // Figs. 6.10/6.11: within the motor speed limits (the gearheads' 6000 rpm input).
            let gear_limit = |a: &Actuator| 6000.0 / 60.0 * std::f64::consts::TAU / a.ratio;
            assert!(st.peak_velocity[0] < gear_limit(&hip), "{name} {st:?}");
            assert!(st.peak_velocity[1] < gear_limit(&knee), "{name} {st:?}");
            // Figs. 6.5–6.7: tracked, but not closely (low gains, no I term, the ground).
            assert!(st.rms_deg(0) < 8.0 && st.rms_deg(1) < 8.0, "{name} {st:?}");
            assert!(
                st.toe_rms_m() < 0.015 && st.toe_err_max < 0.035,
                "{name} {st:?}"
            );
            assert!(st.toe_x.0 > -0.080 && st.toe_x.1 < 0.070, "{name} {st:?}");
            // The toe really lifts (b = 4 cm) and the leg carries its share of the weight.
            assert!(st.min_toe_y < 0.560, "{name} {st:?}");
            let mean_contact = st.contact_sum / f64::from(st.samples);
            let load = rig.leg.physics().params.body_load;
            assert!((mean_contact - load).abs() < 0.15 * load, "{name} {st:?}");
        }
        // "hip PWM limits are recurrently reached, especially in the hind legs".
        assert!(
            hind_hip_share > fore_hip_share,
            "{hind_hip_share} {fore_hip_share}"
        );
    }

    /// A trot trace for looking at the dynamics by eye:
    /// `cargo test -p ether-ros-sim print_a_trot_trace -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn print_a_trot_trace() {
        let (_, mut rig) = trot(599, 0, 0.0);
        let mut i = 0;
        rig.run(1.0, true, |leg, _| {
            i += 1;
            if i % 50 == 0 {
                let d = leg.desired();
                let q = leg.physics().q;
                let p = forward(q);
                eprintln!(
                    "{i:5} d {:7.2} {:7.2} q {:7.2} {:7.2} pwm {:6.2} {:6.2} v {:5.2} {:5.2} \
                     toe {:6.1} {:6.1} F {:6.1}",
                    d.theta1.to_degrees(),
                    d.theta2.to_degrees(),
                    q.theta1.to_degrees(),
                    q.theta2.to_degrees(),
                    leg.pwm()[0],
                    leg.pwm()[1],
                    leg.velocity()[0],
                    leg.velocity()[1],
                    p.0 * 1e3,
                    p.1 * 1e3,
                    leg.physics().contact_force()
                );
            }
        });
    }

    #[test]
    fn standing_holds_the_pose_without_chattering() {
        let mut rig = Rig::new();
        table_6_1(&mut rig.od, 599, 0, 0);
        rig.od.set_int(0x7000, 1, 1);
        rig.run(4.0, true, |_, _| {});
        // Over the last second: the PWM stays well inside the limits and barely moves; the
        // leg carries its share of the weight.
        let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
        let mut force = 0.0;
        rig.run(1.0, true, |leg, _| {
            for j in 0..2 {
                lo[j] = lo[j].min(leg.pwm()[j]);
                hi[j] = hi[j].max(leg.pwm()[j]);
            }
            force += leg.physics().contact_force() / 10_000.0;
        });
        for j in 0..2 {
            assert!(lo[j].abs() < 30.0 && hi[j].abs() < 30.0, "{lo:?} {hi:?}");
            assert!(hi[j] - lo[j] < 2.0, "PWM swings: {lo:?} {hi:?}");
        }
        let load = rig.leg.physics().params.body_load;
        assert!((force - load).abs() < 0.1 * load, "contact {force} N");
        let (x, y) = forward(rig.leg.physics().q);
        assert!(
            x.abs() < 0.01 && (0.580..0.600).contains(&y),
            "toe ({x}, {y})"
        );
    }

    #[test]
    fn pwm_never_exceeds_the_limits_even_with_huge_errors() {
        let mut rig = Rig::new();
        table_6_1(&mut rig.od, 480, 0, 0);
        for sub in [1, 4] {
            rig.od.set_int(0x7020, sub, 32000);
        }
        rig.od.set_int(0x7000, 9, 0);
        rig.od.set_int(0x7000, 1, 1);
        let mut max_pwm = [0f64; 2];
        rig.run(0.5, true, |leg, _| {
            max_pwm[0] = max_pwm[0].max(leg.pwm()[0].abs());
            max_pwm[1] = max_pwm[1].max(leg.pwm()[1].abs());
        });
        assert!(
            max_pwm[0] > 41.0 && max_pwm[0] <= 41.17,
            "hip {}",
            max_pwm[0]
        );
        assert!(
            max_pwm[1] > 38.0 && max_pwm[1] <= 38.25,
            "knee {}",
            max_pwm[1]
        );
        let reported = rig.od.get_int(0x6020, 2).abs();
        assert!(reported <= 4117, "{reported}");
    }

    #[test]
    fn invalid_ellipse_is_ignored_and_the_last_valid_one_kept() {
        let mut rig = Rig::new();
        table_6_1(&mut rig.od, 560, 5, 4);
        rig.od.set_int(0x7000, 9, 0);
        rig.od.set_int(0x7000, 1, 1);
        rig.run(0.2, true, |_, _| {});
        let valid = *rig.leg.trajectory().target();
        // Centre 700 mm: beyond the leg's reach. Then a = 30 cm: far outside too.
        rig.od.set_int(0x7030, 2, 700);
        rig.run(0.3, true, |_, _| {});
        rig.od.set_int(0x7030, 2, 560);
        rig.od.set_int(0x7030, 3, 30);
        let mut max_r: f64 = 0.0;
        rig.run(1.0, true, |leg, _| {
            let (x, y) = forward(leg.desired());
            max_r = max_r.max(x.hypot(y));
        });
        assert_eq!(*rig.leg.trajectory().target(), valid);
        assert_eq!(rig.leg.trajectory().rejected(), 2);
        // The old ellipse (flat stance at 560 mm, a = 5 cm) is still served.
        assert!((0.560..0.5625).contains(&max_r), "desired reach {max_r}");
        // A valid set is taken again.
        rig.od.set_int(0x7030, 3, 3);
        rig.run(0.01, true, |_, _| {});
        assert!((rig.leg.trajectory().target().a - 0.03).abs() < 1e-12);
    }

    #[test]
    fn outputs_not_valid_means_zero_pwm_and_commands_ignored() {
        let mut rig = Rig::new();
        table_6_1(&mut rig.od, 560, 5, 4);
        rig.od.set_int(0x7000, 1, 1);
        rig.run(0.5, true, |_, _| {});
        assert!(rig.leg.pwm()[0].abs() + rig.leg.pwm()[1].abs() > 0.1);
        let mut max_abs = 0f64;
        rig.run(1.0, false, |leg, od| {
            max_abs = max_abs.max(leg.pwm()[0].abs()).max(leg.pwm()[1].abs());
            max_abs = max_abs
                .max(od.get_int(0x6020, 1).abs() as f64)
                .max(od.get_int(0x6020, 2).abs() as f64);
        });
        assert_eq!(max_abs, 0.0);
        assert_eq!(rig.leg.mode(), Mode::Off);
        // Motors free: the leg rests on the floor (the body sinks towards its harness, at most
        // body_travel below where it stood), the desired angles report the measured ones.
        assert_eq!(rig.leg.desired(), rig.leg.measured());
        let physics = rig.leg.physics();
        assert!(physics.contact_force() > 1.0);
        let lowest = physics.params.floor_y - physics.params.body_travel;
        assert!(forward(physics.q).1 > lowest - 0.002);
        // Back to valid: the leg is held where it is, no jump.
        rig.od.set_int(0x7000, 1, 0);
        let before = rig.leg.measured();
        rig.run(0.001, true, |_, _| {});
        assert_eq!(rig.leg.mode(), Mode::Configurational);
        assert!((rig.leg.desired().theta1 - before.theta1).abs() < 1e-3);
    }

    #[test]
    fn velocity_filter_has_its_bandwidth() {
        // A sine through the filter: near unity gain well below the bandwidth, about -3 dB at
        // it and strongly attenuated well above it.
        let gain = |signal_hz: f64, bandwidth_hz: f64| {
            let mut f = VelocityFilter::default();
            let dt = 1e-4;
            let mut peak: f64 = 0.0;
            let w = std::f64::consts::TAU * signal_hz;
            for i in 0..200_000 {
                let t = i as f64 * dt;
                let v = f.update((w * t).sin(), dt, bandwidth_hz);
                if t > 1.0 {
                    peak = peak.max(v.abs());
                }
            }
            peak / w
        };
        assert!((gain(1.0, 20.0) - 1.0).abs() < 0.02);
        assert!((gain(20.0, 20.0) - std::f64::consts::FRAC_1_SQRT_2).abs() < 0.03);
        assert!(gain(200.0, 20.0) < 0.12);
        assert!(gain(200.0, 0.0) > 0.95, "bandwidth 0: unfiltered");
    }

    #[test]
    fn feedback_reports_time_angles_and_velocities_in_table_4_2_units() {
        let mut rig = Rig::new();
        table_6_1(&mut rig.od, 560, 0, 0);
        rig.od.set_int(0x7000, 9, 0);
        rig.od.set_int(0x7000, 1, 1);
        rig.run(2.5, true, |_, _| {});
        assert_eq!(rig.od.get_int(0x6012, 1), 2);
        let q = inverse(0.0, 0.560).unwrap();
        let hip = rig.od.get_int(0x6010, 1) as f64 / 100.0;
        let knee = rig.od.get_int(0x6014, 1) as f64 / 100.0;
        // Within a degree or so: the PIV has no integral term here (Ki = 0, Table 6.1), so the
        // leg's weight and the joints' friction leave a small steady error.
        assert!((hip - q.theta1.to_degrees()).abs() < 1.5, "hip {hip}");
        assert!((knee - q.theta2.to_degrees()).abs() < 1.5, "knee {knee}");
        assert_eq!(
            rig.od.get_int(0x6010, 2),
            (q.theta1.to_degrees() * 100.0).round() as i64
        );
        assert!(rig.od.get_int(0x6030, 1).abs() < 50, "at rest");
    }

    #[test]
    #[ignore]
    fn release_cost_per_control_period() {
        // `cargo test --release -p ether-ros-sim release_cost -- --ignored --nocapture`
        let mut rig = Rig::new();
        table_6_1(&mut rig.od, 599, 5, 4);
        rig.od.set_int(0x7000, 1, 1);
        // Thread CPU time, not wall time: the machine is shared.
        let cpu_ns = || {
            let mut ts = libc::timespec {
                tv_sec: 0,
                tv_nsec: 0,
            };
            // SAFETY: clock_gettime only writes the timespec we pass.
            unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
            ts.tv_sec as f64 * 1e9 + ts.tv_nsec as f64
        };
        let start = cpu_ns();
        rig.run(10.0, true, |_, _| {});
        eprintln!(
            "{:.3} us CPU per 100 us control period",
            (cpu_ns() - start) / 1e3 / 1e5
        );
        let start = cpu_ns();
        let mut sink = 0.0;
        for _ in 0..100_000 {
            sink += Commands::read(&rig.od, &rig.leg.slots).transition_s;
            rig.leg.write_feedback(&mut rig.od);
        }
        let per = (cpu_ns() - start) / 1e3 / 1e5;
        eprintln!("{per:.3} us CPU of it in object dictionary reads and writes ({sink})");
    }

    #[test]
    fn unknown_parameters_are_refused_by_name() {
        let err = LaelapsLegConfig::from_params(&[("floor_hight".into(), 1.0)])
            .err()
            .unwrap();
        assert!(err.contains("'floor_hight'"), "{err}");
        assert!(LaelapsLegConfig::from_params(&[("initial_toe_y_m".into(), 0.9)]).is_err());
    }
}
