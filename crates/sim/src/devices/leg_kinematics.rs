//! Kinematics of the Laelaps II leg (thesis eqs. 4.1–4.4).
//!
//! Frame: origin at the hip axis, `x` forward, `y` pointing down. `theta1` is the thigh angle and
//! `theta2` the shank angle, both absolute and measured from the downward vertical towards +x, as
//! in eq. 4.1. The relative knee angle `phi = theta2 - theta1` lies in [-90°, 0°]: 0 is the
//! straight leg (reach l1 + l2 = 600 mm) and -90° the knee end-stop (reach sqrt(l1² + l2²) =
//! 430.12 mm).

/// Thigh (upper, actual link) length, m.
pub const L1: f64 = 0.250;
/// Virtual lower link length (shank with its stiff spring), m.
pub const L2: f64 = 0.350;
/// Maximum reach (straight leg), eq. 4.4.
pub const REACH_MAX: f64 = L1 + L2;

/// Minimum reach (knee at its end-stop, phi = -90°), eq. 4.4: sqrt(l1² + l2²) = 0.43012 m.
pub fn reach_min() -> f64 {
    (L1 * L1 + L2 * L2).sqrt()
}

/// Joint angles of the leg (rad).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointAngles {
    pub theta1: f64,
    pub theta2: f64,
}

/// Forward kinematics, eq. 4.1: toe position (x, y) in m.
pub fn forward(q: JointAngles) -> (f64, f64) {
    let x = L1 * q.theta1.sin() + L2 * q.theta2.sin();
    let y = L1 * q.theta1.cos() + L2 * q.theta2.cos();
    (x, y)
}

/// Jacobian d(x, y)/d(theta1, theta2) of eq. 4.1, rows (x, y); the tests check the physics
/// model against it.
#[cfg(test)]
pub fn jacobian(q: JointAngles) -> [[f64; 2]; 2] {
    [
        [L1 * q.theta1.cos(), L2 * q.theta2.cos()],
        [-L1 * q.theta1.sin(), -L2 * q.theta2.sin()],
    ]
}

/// Whether a toe point lies in the leg's workspace: the toe below the hip and its distance from
/// the hip in [reach_min - tol, REACH_MAX + tol] (tol in m, may be 0).
pub fn in_workspace(x: f64, y: f64, tol: f64) -> bool {
    let r = x.hypot(y);
    y > 0.0 && r >= reach_min() - tol && r <= REACH_MAX + tol
}

/// Inverse kinematics, eqs. 4.2–4.3 (knee bent backwards: sin(phi) <= 0). `None` when the point
/// is not reachable (outside the annulus reach_min..REACH_MAX or above the hip).
pub fn inverse(x: f64, y: f64) -> Option<JointAngles> {
    if !in_workspace(x, y, 1e-12) {
        return None;
    }
    let cos_phi = ((x * x + y * y - (L1 * L1 + L2 * L2)) / (2.0 * L1 * L2)).clamp(-1.0, 1.0);
    let sin_phi = -(1.0 - cos_phi * cos_phi).sqrt();
    let phi = sin_phi.atan2(cos_phi);
    let theta2 = std::f64::consts::FRAC_PI_2 - y.atan2(x) + (L1 * sin_phi).atan2(L2 + L1 * cos_phi);
    let theta1 = theta2 - phi;
    Some(JointAngles { theta1, theta2 })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn workspace_limits_match_eq_4_4() {
        assert!((reach_min() - 0.43012).abs() < 1e-5);
        assert!((REACH_MAX - 0.600).abs() < 1e-12);
        assert!(inverse(0.0, 0.601).is_none());
        assert!(inverse(0.0, 0.42).is_none());
        assert!(inverse(0.0, -0.5).is_none());
        assert!(inverse(0.0, 0.5).is_some());
    }

    #[test]
    fn inverse_then_forward_round_trips_over_the_workspace() {
        let mut checked = 0;
        let r_min = reach_min();
        for i in 0..=40 {
            let r = r_min + 1e-6 + (REACH_MAX - r_min - 2e-6) * f64::from(i) / 40.0;
            for j in 0..=36 {
                // Angles of the toe from the downward vertical, -80°..+80°.
                let a = (-80.0 + 160.0 * f64::from(j) / 36.0_f64).to_radians();
                let (x, y) = (r * a.sin(), r * a.cos());
                let q = inverse(x, y).expect("point inside the workspace");
                let phi = q.theta2 - q.theta1;
                assert!(
                    (-std::f64::consts::FRAC_PI_2 - 1e-9..=1e-9).contains(&phi),
                    "phi {phi}"
                );
                let (fx, fy) = forward(q);
                assert!(
                    (fx - x).abs() < 1e-9 && (fy - y).abs() < 1e-9,
                    "({x},{y}) -> ({fx},{fy})"
                );
                checked += 1;
            }
        }
        assert_eq!(checked, 41 * 37);
    }

    #[test]
    fn standing_pose_has_a_slightly_bent_knee() {
        let q = inverse(0.0, 0.599).unwrap();
        let phi = (q.theta2 - q.theta1).to_degrees();
        assert!((-8.0..-5.0).contains(&phi), "phi {phi}");
        assert!(q.theta1 > 0.0 && q.theta2 < 0.0);
    }
}
