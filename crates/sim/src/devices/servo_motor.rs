//! The mechanics behind one axis of the simulated CiA 402 drive (`cia402`): a motor driving a
//! load through an ideal gear, with viscous and Coulomb friction, and the drive's internal
//! position → velocity cascade that turns a position or velocity reference into motor torque.
//!
//! Everything is on the motor side (rad, rad/s, Nm); the load's inertia is reflected through
//! the gear (J = J_motor + J_load / N²). The current loop is taken as ideal: the commanded
//! torque (after the torque limit) acts at once.

use std::f64::consts::TAU;

/// Physical parameters of one axis (`sim.params` of a `cia402` slave; see
/// docs/cia402-simulator.md for the defaults and why).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotorParams {
    /// Rotor inertia, kg·m².
    pub motor_inertia: f64,
    /// Load inertia at the joint (output of the gear), kg·m².
    pub load_inertia: f64,
    /// Viscous friction at the motor, Nm per rad/s.
    pub viscous_friction: f64,
    /// Coulomb (dry) friction at the motor, Nm.
    pub coulomb_friction: f64,
    /// Motor encoder increments per motor revolution.
    pub counts_per_rev: f64,
    /// Motor revolutions per joint revolution.
    pub gear_ratio: f64,
    /// Motor rated torque, Nm (0x6076 holds it in mNm).
    pub rated_torque: f64,
    /// Bandwidth of the velocity loop, Hz.
    pub velocity_loop_hz: f64,
    /// Bandwidth of the position loop, Hz.
    pub position_loop_hz: f64,
}

impl Default for MotorParams {
    /// A small robot-joint servo: a 0.2 Nm (rated) frameless motor with a 14-bit absolute
    /// encoder behind a 50:1 harmonic gear, driving a 0.01 kg·m² link (0.5 kg at 0.14 m).
    fn default() -> Self {
        Self {
            motor_inertia: 3.0e-6,
            load_inertia: 0.01,
            viscous_friction: 1.0e-5,
            coulomb_friction: 0.01,
            counts_per_rev: 16_384.0,
            gear_ratio: 50.0,
            rated_torque: 0.2,
            velocity_loop_hz: 150.0,
            position_loop_hz: 30.0,
        }
    }
}

impl MotorParams {
    /// Total inertia seen by the motor, kg·m².
    pub fn inertia(&self) -> f64 {
        self.motor_inertia + self.load_inertia / (self.gear_ratio * self.gear_ratio)
    }

    /// Encoder increments per radian of the motor.
    pub fn counts_per_rad(&self) -> f64 {
        self.counts_per_rev / TAU
    }
}

/// Motor speed below which Coulomb friction holds the motor (rad/s).
const STICTION_SPEED: f64 = 1e-9;

/// The motor + gear + load state.
#[derive(Clone, Copy, Debug)]
pub struct Mechanics {
    pub params: MotorParams,
    /// Motor angle, rad (unbounded).
    pub angle: f64,
    /// Motor speed, rad/s.
    pub speed: f64,
}

impl Mechanics {
    pub fn new(params: MotorParams) -> Self {
        Self {
            params,
            angle: 0.0,
            speed: 0.0,
        }
    }

    /// Friction torque opposing the motion for a drive torque `torque` (Nm).
    fn friction(&self, torque: f64) -> f64 {
        let p = &self.params;
        if self.speed.abs() > STICTION_SPEED {
            p.viscous_friction * self.speed + p.coulomb_friction * self.speed.signum()
        } else {
            // At rest: static friction holds up to the Coulomb level.
            torque.clamp(-p.coulomb_friction, p.coulomb_friction)
        }
    }

    /// Advance by `dt` seconds under the motor torque `torque` (semi-implicit Euler). Friction
    /// never reverses the motion: a speed that would cross zero because of friction stops.
    pub fn advance(&mut self, dt: f64, torque: f64) {
        let j = self.params.inertia();
        let before = self.speed;
        let mut speed = before + dt * (torque - self.friction(torque)) / j;
        let friction_only_reverses = before != 0.0
            && speed.signum() != before.signum()
            && torque.abs() <= self.params.coulomb_friction;
        if friction_only_reverses {
            speed = 0.0;
        }
        self.speed = speed;
        self.angle += dt * speed;
    }
}

/// The drive's cascade: a P position loop with velocity feed-forward feeding a PI velocity
/// loop whose output is the torque command. Gains follow from the loop bandwidths and the
/// inertia, so a heavier load does not make the loop unstable.
#[derive(Clone, Copy, Debug, Default)]
pub struct Cascade {
    integral: f64,
}

/// Result of one controller evaluation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TorqueCommand {
    /// Motor torque after the limit, Nm.
    pub torque: f64,
    /// The torque (or speed) limit cut the command.
    pub limited: bool,
}

impl Cascade {
    pub fn reset(&mut self) {
        self.integral = 0.0;
    }

    /// Velocity command of the position loop: feed-forward plus P on the position error,
    /// clamped to `max_speed` (rad/s, 0 = no limit). Returns (command, limited).
    pub fn position_loop(
        params: &MotorParams,
        error: f64,
        feed_forward: f64,
        max_speed: f64,
    ) -> (f64, bool) {
        let kp = TAU * params.position_loop_hz;
        limit(feed_forward + kp * error, max_speed)
    }

    /// Torque for the speed command `target` (rad/s) at measured `speed`, limited to
    /// ±`max_torque` (Nm), with the integral held while the output saturates (anti-windup).
    pub fn velocity_loop(
        &mut self,
        params: &MotorParams,
        target: f64,
        speed: f64,
        max_torque: f64,
        dt: f64,
    ) -> TorqueCommand {
        let w = TAU * params.velocity_loop_hz;
        let kv = params.inertia() * w;
        let ki = kv * w / 4.0;
        let error = target - speed;
        let unclamped = kv * error + ki * (self.integral + error * dt);
        let (torque, limited) = limit(unclamped, max_torque);
        if !limited {
            self.integral += error * dt;
        }
        TorqueCommand { torque, limited }
    }
}

/// Clamp `value` to ±`bound` (no bound when `bound` <= 0); true when it was cut.
pub fn limit(value: f64, bound: f64) -> (f64, bool) {
    if bound > 0.0 && value.abs() > bound {
        (bound.copysign(value), true)
    } else {
        (value, false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn torque_accelerates_the_load_as_j_alpha_equals_tau_minus_friction() {
        let p = MotorParams::default();
        let mut m = Mechanics::new(p);
        let torque = 0.3;
        let dt = 62.5e-6;
        let steps = 1600; // 0.1 s
        for _ in 0..steps {
            m.advance(dt, torque);
        }
        let t = dt * steps as f64;
        // dω/dt = (τ - τc - b·ω)/J: first-order response towards (τ - τc)/b.
        let tau_net = torque - p.coulomb_friction;
        let time_constant = p.inertia() / p.viscous_friction;
        let expected = tau_net / p.viscous_friction * (1.0 - (-t / time_constant).exp());
        assert!(
            (m.speed - expected).abs() / expected < 1e-3,
            "{} vs {expected}",
            m.speed
        );
        // Early on, α ≈ (τ - τc)/J.
        let mut m = Mechanics::new(p);
        m.advance(dt, torque);
        let alpha = m.speed / dt;
        assert!((alpha - tau_net / p.inertia()).abs() / alpha < 1e-6);
    }

    #[test]
    fn coulomb_friction_holds_a_small_torque_and_stops_a_coasting_motor() {
        let p = MotorParams::default();
        let mut m = Mechanics::new(p);
        for _ in 0..1000 {
            m.advance(62.5e-6, 0.5 * p.coulomb_friction);
        }
        assert_eq!((m.speed, m.angle), (0.0, 0.0), "stiction holds");
        m.speed = 5.0;
        for _ in 0..100_000 {
            m.advance(62.5e-6, 0.0);
        }
        assert_eq!(
            m.speed, 0.0,
            "friction stops the coasting motor without reversing it"
        );
        assert!(m.angle > 0.0);
    }

    #[test]
    fn velocity_loop_limits_torque_and_does_not_wind_up() {
        let p = MotorParams::default();
        let mut c = Cascade::default();
        let cmd = c.velocity_loop(&p, 1000.0, 0.0, 0.6, 1e-4);
        assert_eq!(
            cmd,
            TorqueCommand {
                torque: 0.6,
                limited: true
            }
        );
        for _ in 0..10_000 {
            c.velocity_loop(&p, 1000.0, 0.0, 0.6, 1e-4);
        }
        // Saturated all along: no integral built up, so at the target the torque is ~0.
        let at_target = c.velocity_loop(&p, 1000.0, 1000.0, 0.6, 1e-4);
        assert!(at_target.torque.abs() < 1e-9 && !at_target.limited);
    }
}
