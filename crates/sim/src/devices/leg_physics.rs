//! Physics of one Laelaps II leg: current-controlled motor amplifiers limited by the supply
//! voltage, Maxon gearheads and the 48/26 pulley, the two-link leg with gravity, joint end-stops,
//! and the ground: a spring-damper treadmill belt under the toe that carries the leg's share of
//! the body's weight.
//!
//! Generalized coordinates are the absolute link angles of `leg_kinematics` (theta1 thigh,
//! theta2 shank). The knee actuator sits on the body and drives the shank angle theta2 through
//! its transmission, the hip actuator drives theta1; so each motor's reflected rotor inertia and
//! friction act on its own coordinate. Integration is semi-implicit Euler.
//!
//! The body is not simulated as a rigid body (each leg is its own slave, in its own firmware
//! model): the hip moves only vertically relative to the belt, slowly, so that over a stride the
//! leg carries its share of the weight (`LegParams::body_load`); see docs/laelaps.md.

use super::leg_kinematics::{JointAngles, L1, L2};

/// Standard gravity, m/s².
const G: f64 = 9.80665;

/// One actuator: motor, amplifier, gearhead and pulley.
#[derive(Clone, Copy, Debug)]
pub struct Actuator {
    /// Motor torque constant, Nm/A.
    pub torque_constant: f64,
    /// Motor continuous (nominal) current, A: the amplifier delivers it at the PWM limit.
    pub continuous_current: f64,
    /// PWM limit of the firmware, % (Table 6.1).
    pub pwm_limit_pct: f64,
    /// Gearhead ratio times pulley ratio.
    pub ratio: f64,
    /// Gearhead efficiency (applied to the delivered torque).
    pub efficiency: f64,
    /// Rotor inertia, kg·m².
    pub rotor_inertia: f64,
    /// Viscous friction at the joint, N·m·s/rad.
    pub viscous: f64,
    /// Coulomb friction at the joint, N·m.
    pub coulomb: f64,
    /// Winding resistance, ohm (terminal resistance of the datasheet).
    pub resistance: f64,
    /// Supply voltage of the amplifier, V (thesis Table 6.2: 40.34 V).
    pub supply_voltage: f64,
}

/// 48/26 pulley after both gearheads.
pub const PULLEY: f64 = 48.0 / 26.0;
/// The robot's supply voltage during the trot, V (thesis Table 6.2).
pub const SUPPLY_VOLTAGE: f64 = 40.34;

impl Actuator {
    /// Hip: Maxon EC 45 250 W (48 V winding) + GP 52 C 343/8 + pulley 48/26.
    pub fn hip() -> Self {
        Self {
            torque_constant: 0.0530,
            continuous_current: 5.5,
            pwm_limit_pct: 41.17,
            ratio: 343.0 / 8.0 * PULLEY,
            efficiency: 0.75,
            rotor_inertia: 209e-7,
            viscous: 0.8,
            coulomb: 0.4,
            resistance: 0.45,
            supply_voltage: SUPPLY_VOLTAGE,
        }
    }

    /// Knee: Maxon RE 50 200 W (48 V winding) + GP 52 C 637/12 + pulley 48/26.
    pub fn knee() -> Self {
        Self {
            torque_constant: 0.0934,
            continuous_current: 4.58,
            pwm_limit_pct: 38.25,
            ratio: 637.0 / 12.0 * PULLEY,
            efficiency: 0.75,
            rotor_inertia: 536e-7,
            viscous: 1.0,
            coulomb: 0.5,
            resistance: 0.50,
            supply_voltage: SUPPLY_VOLTAGE,
        }
    }

    /// Amplifier current at 100 % PWM: the PWM limit corresponds to the continuous current.
    pub fn full_scale_current(&self) -> f64 {
        self.continuous_current * 100.0 / self.pwm_limit_pct
    }

    /// Motor current for a PWM command (%).
    pub fn current(&self, pwm_pct: f64) -> f64 {
        pwm_pct / 100.0 * self.full_scale_current()
    }

    /// Torque delivered at the joint for a PWM command (%) with the joint at rest, N·m.
    pub fn joint_torque(&self, pwm_pct: f64) -> f64 {
        self.joint_torque_at(pwm_pct, 0.0)
    }

    /// Torque delivered at the joint for a PWM command (%) while the joint turns at `w` rad/s.
    /// The amplifier's current loop gives the commanded current as long as the supply can drive
    /// it against the motor's back-EMF (k_e = k_t in SI units) and winding resistance; beyond
    /// that the current, and the torque, fall off. This is what bounds the joint speeds.
    pub fn joint_torque_at(&self, pwm_pct: f64, w: f64) -> f64 {
        let emf = self.torque_constant * w * self.ratio;
        let most = (self.supply_voltage - emf) / self.resistance;
        let least = (-self.supply_voltage - emf) / self.resistance;
        let current = self.current(pwm_pct).clamp(least, most);
        current * self.torque_constant * self.ratio * self.efficiency
    }

    /// Joint speed at which the supply cannot drive any current into the motor, rad/s.
    pub fn no_load_joint_speed(&self) -> f64 {
        self.supply_voltage / self.torque_constant / self.ratio
    }

    /// Rotor inertia seen at the joint, kg·m².
    pub fn reflected_inertia(&self) -> f64 {
        self.rotor_inertia * self.ratio * self.ratio
    }

    /// Friction torque opposing the joint velocity `w` (Coulomb smoothed around 0).
    fn friction(&self, w: f64) -> f64 {
        -self.viscous * w - self.coulomb * (w / 0.01).tanh()
    }
}

/// Mechanical parameters of the leg and its floor.
#[derive(Clone, Copy, Debug)]
pub struct LegParams {
    /// Thigh mass (kg) and its centre of mass from the hip (m).
    pub thigh_mass: f64,
    pub thigh_com: f64,
    /// Shank (with the spring and foot) mass (kg) and centre of mass from the knee (m).
    pub shank_mass: f64,
    pub shank_com: f64,
    /// Floor (belt) surface at power-on, m below the hip (y); stiffness N/m, damping N·s/m,
    /// friction coefficient between foot and belt.
    pub floor_y: f64,
    pub floor_stiffness: f64,
    pub floor_damping: f64,
    pub floor_friction: f64,
    /// The share of the body's weight this leg carries on average, N (0: the hip is held at a
    /// fixed height above the floor). The body height follows the load slowly:
    /// d(floor_y)/dt = (contact force - body_load) / body_damping, within ±body_travel of
    /// `floor_y` (a harness stops the body there).
    pub body_load: f64,
    pub body_damping: f64,
    pub body_travel: f64,
    /// Knee end-stops: relative angle phi = theta2 - theta1 in [-90°, 0°]; hip stop ±80°.
    pub stop_stiffness: f64,
    pub stop_damping: f64,
}

impl Default for LegParams {
    fn default() -> Self {
        Self {
            thigh_mass: 1.2,
            thigh_com: 0.10,
            shank_mass: 0.5,
            shank_com: 0.17,
            floor_y: 0.5955,
            floor_stiffness: 50_000.0,
            floor_damping: 500.0,
            floor_friction: 0.6,
            body_load: 110.0,
            body_damping: 20_000.0,
            body_travel: 0.020,
            stop_stiffness: 2_000.0,
            stop_damping: 20.0,
        }
    }
}

/// The leg's mechanical state and its integrator.
#[derive(Clone, Debug)]
pub struct LegPhysics {
    pub params: LegParams,
    pub hip: Actuator,
    pub knee: Actuator,
    /// Joint angles (rad) and velocities (rad/s).
    pub q: JointAngles,
    pub w: [f64; 2],
    /// Last floor reaction (Fx, Fy) on the toe, N (Fy < 0 pushes up).
    pub contact: (f64, f64),
    /// Where the floor (belt) surface is now, m below the hip: the body's height.
    pub floor_y: f64,
    /// Velocity of the belt's surface along x, m/s (negative: it carries the toe backwards).
    pub belt_vx: f64,
}

impl LegPhysics {
    pub fn new(params: LegParams, q: JointAngles) -> Self {
        Self {
            params,
            hip: Actuator::hip(),
            knee: Actuator::knee(),
            q,
            w: [0.0; 2],
            contact: (0.0, 0.0),
            floor_y: params.floor_y,
            belt_vx: 0.0,
        }
    }

    /// Magnitude of the floor's normal force, N.
    pub fn contact_force(&self) -> f64 {
        -self.contact.1
    }

    /// Floor reaction on the toe at height `toe_y` with the Jacobian `jac` (both from the
    /// current angles, computed once per step by the caller). Friction opposes the toe's slip
    /// over the belt.
    fn floor_force(&self, toe_y: f64, jac: &[[f64; 2]; 2]) -> (f64, f64) {
        let p = &self.params;
        let depth = toe_y - self.floor_y;
        if depth <= 0.0 {
            return (0.0, 0.0);
        }
        let vx = jac[0][0] * self.w[0] + jac[0][1] * self.w[1];
        let vy = jac[1][0] * self.w[0] + jac[1][1] * self.w[1];
        // Normal force pushes up (-y) and never pulls the toe into the floor.
        let normal = (p.floor_stiffness * depth + p.floor_damping * vy).max(0.0);
        let slip = vx - self.belt_vx;
        let tangential = -p.floor_friction * normal * (slip / 0.01).tanh();
        (tangential, -normal)
    }

    fn stop_torques(&self) -> [f64; 2] {
        let p = &self.params;
        let phi = self.q.theta2 - self.q.theta1;
        let dphi = self.w[1] - self.w[0];
        let lo = -std::f64::consts::FRAC_PI_2;
        // Torque on phi pushing it back into [-90°, 0°]; it acts +on theta2 and -on theta1.
        let knee = if phi > 0.0 {
            -p.stop_stiffness * phi - p.stop_damping * dphi.max(0.0)
        } else if phi < lo {
            p.stop_stiffness * (lo - phi) - p.stop_damping * dphi.min(0.0)
        } else {
            0.0
        };
        let hip_lim = 80f64.to_radians();
        let t1 = self.q.theta1;
        let hip = if t1 > hip_lim {
            -p.stop_stiffness * (t1 - hip_lim) - p.stop_damping * self.w[0].max(0.0)
        } else if t1 < -hip_lim {
            p.stop_stiffness * (-hip_lim - t1) - p.stop_damping * self.w[0].min(0.0)
        } else {
            0.0
        };
        [hip - knee, knee]
    }

    /// Advance by `dt` seconds with the given PWM commands (%), in `substeps` steps.
    pub fn advance(&mut self, dt: f64, pwm_hip: f64, pwm_knee: f64, substeps: u32) {
        let h = dt / f64::from(substeps.max(1));
        for _ in 0..substeps.max(1) {
            let tau_motor = [
                self.hip.joint_torque_at(pwm_hip, self.w[0]),
                self.knee.joint_torque_at(pwm_knee, self.w[1]),
            ];
            self.substep(h, tau_motor);
        }
    }

    fn substep(&mut self, h: f64, tau_motor: [f64; 2]) {
        let p = self.params;
        let (m1, c1, m2, c2) = (p.thigh_mass, p.thigh_com, p.shank_mass, p.shank_com);
        // Links as uniform rods about their centres of mass.
        let i1 = m1 * L1 * L1 / 12.0;
        let i2 = m2 * L2 * L2 / 12.0;
        // One sin/cos per angle serves the mass matrix, gravity, kinematics and the Jacobian.
        let (s1, co1) = self.q.theta1.sin_cos();
        let (s2, co2) = self.q.theta2.sin_cos();
        let cos_d = co1 * co2 + s1 * s2; // cos(theta1 - theta2)
        let sin_d = s1 * co2 - co1 * s2; // sin(theta1 - theta2)
        let k = m2 * L1 * c2;
        let m11 = i1 + m1 * c1 * c1 + m2 * L1 * L1 + self.hip.reflected_inertia();
        let m22 = i2 + m2 * c2 * c2 + self.knee.reflected_inertia();
        let m12 = k * cos_d;
        // Velocity-product terms of the Lagrangian in absolute angles.
        let h1 = k * sin_d * self.w[1] * self.w[1];
        let h2 = -k * sin_d * self.w[0] * self.w[0];
        // y points down, so gravity pulls the links towards theta = 0.
        let g1 = -G * (m1 * c1 + m2 * L1) * s1;
        let g2 = -G * m2 * c2 * s2;
        // Eq. 4.1 and its Jacobian from the same sines and cosines.
        let toe_y = L1 * co1 + L2 * co2;
        let jac = [[L1 * co1, L2 * co2], [-L1 * s1, -L2 * s2]];
        let (fx, fy) = self.floor_force(toe_y, &jac);
        self.contact = (fx, fy);
        let q1 = jac[0][0] * fx + jac[1][0] * fy;
        let q2 = jac[0][1] * fx + jac[1][1] * fy;
        let stops = self.stop_torques();
        let r1 = tau_motor[0] + self.hip.friction(self.w[0]) + g1 + q1 + stops[0] - h1;
        let r2 = tau_motor[1] + self.knee.friction(self.w[1]) + g2 + q2 + stops[1] - h2;
        let det = m11 * m22 - m12 * m12;
        let a1 = (m22 * r1 - m12 * r2) / det;
        let a2 = (m11 * r2 - m12 * r1) / det;
        self.w[0] += h * a1;
        self.w[1] += h * a2;
        self.q.theta1 += h * self.w[0];
        self.q.theta2 += h * self.w[1];
        if p.body_load > 0.0 {
            // The body rises while the leg pushes harder than its share of the weight and sinks
            // while it pushes less (or is in the air, the other legs holding the body).
            let rate = (-fy - p.body_load) / p.body_damping;
            self.floor_y = (self.floor_y + h * rate)
                .clamp(p.floor_y - p.body_travel, p.floor_y + p.body_travel);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::leg_kinematics::{forward, inverse};
    use super::*;

    #[test]
    fn actuator_torques_follow_the_gear_ratios() {
        let hip = Actuator::hip();
        let knee = Actuator::knee();
        assert!((hip.ratio - 343.0 / 8.0 * 48.0 / 26.0).abs() < 1e-12);
        assert!((knee.ratio - 637.0 / 12.0 * 48.0 / 26.0).abs() < 1e-12);
        // At the PWM limit the amplifier gives the continuous current.
        assert!((hip.current(41.17) - 5.5).abs() < 1e-9);
        assert!((knee.current(-38.25) + 4.58).abs() < 1e-9);
        assert!(hip.joint_torque(41.17) > 10.0 && knee.joint_torque(38.25) > 20.0);
    }

    #[test]
    fn the_supply_voltage_bounds_the_joint_speeds() {
        for a in [Actuator::hip(), Actuator::knee()] {
            let limit = a.pwm_limit_pct;
            let top = a.no_load_joint_speed();
            // Full torque at rest, less while the back-EMF eats the supply, none at the top.
            assert!((a.joint_torque_at(limit, 0.0) - a.joint_torque(limit)).abs() < 1e-12);
            assert!(a.joint_torque_at(limit, 0.5 * top) == a.joint_torque(limit));
            assert!(a.joint_torque_at(limit, 0.97 * top) < 0.6 * a.joint_torque(limit));
            assert!(a.joint_torque_at(limit, top).abs() < 1e-9);
            // Braking a joint that runs the other way is not limited.
            assert!(a.joint_torque_at(limit, -top) >= a.joint_torque(limit) - 1e-9);
        }
        // 40.34 V (Table 6.2): the knee cannot exceed ~4.4 rad/s, below its gearhead's 6000 rpm
        // input limit (6.41 rad/s at the joint); the hip could reach ~9.6 rad/s.
        let knee = Actuator::knee().no_load_joint_speed();
        assert!((4.3..4.5).contains(&knee), "{knee}");
        let hip = Actuator::hip().no_load_joint_speed();
        assert!((9.4..9.8).contains(&hip), "{hip}");
    }

    #[test]
    fn a_moving_belt_carries_a_standing_toe_along() {
        // Motors off, the toe pressed 3 mm into the belt by the body's weight.
        let mut leg = LegPhysics::new(LegParams::default(), inverse(0.0, 0.5985).unwrap());
        leg.belt_vx = -0.2;
        for _ in 0..1_000 {
            leg.advance(1e-4, 0.0, 0.0, 1);
        }
        let jac = super::super::leg_kinematics::jacobian(leg.q);
        let vx = jac[0][0] * leg.w[0] + jac[0][1] * leg.w[1];
        assert!(leg.contact_force() > 20.0, "{}", leg.contact_force());
        assert!(vx < -0.1, "toe moves back with the belt: {vx} m/s");
        assert!(forward(leg.q).0 < -0.01, "{:?}", forward(leg.q));
    }

    #[test]
    fn a_free_leg_hanging_in_the_air_settles_straight_down() {
        let params = LegParams {
            floor_y: 10.0,
            ..LegParams::default()
        };
        let mut leg = LegPhysics::new(params, inverse(0.15, 0.5).unwrap());
        for _ in 0..50_000 {
            leg.advance(1e-4, 0.0, 0.0, 1);
        }
        let (x, y) = forward(leg.q);
        // Coulomb friction stops it a little off the vertical.
        assert!(x.abs() < 0.05 && y > 0.59, "toe at ({x}, {y})");
        assert_eq!(leg.contact_force(), 0.0);
    }

    #[test]
    fn the_floor_stops_a_falling_toe() {
        let params = LegParams {
            floor_y: 0.55,
            ..LegParams::default()
        };
        let mut leg = LegPhysics::new(params, inverse(0.0, 0.5).unwrap());
        let mut max_y: f64 = 0.0;
        for _ in 0..30_000 {
            leg.advance(1e-4, 0.0, 0.0, 1);
            max_y = max_y.max(forward(leg.q).1);
        }
        // The straightening leg presses into the floor spring, but it holds the toe.
        assert!(max_y < 0.57, "toe went to {max_y}");
        assert!(leg.contact_force() > 1.0, "the leg rests on the floor");
        assert!(
            leg.w[0].abs() + leg.w[1].abs() < 0.05,
            "and has stopped: {:?}",
            leg.w
        );
    }
}
