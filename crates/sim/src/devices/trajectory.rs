//! The semi-elliptical toe trajectory of the Laelaps II firmware (thesis eq. 4.5 and Table 4.1
//! record 0x7030), its workspace check and the linear transition of parameter changes.
//!
//! Shape, in the hip frame (`x` forward, `y` down), with `s = psi + phase` and `psi` the
//! integrated trajectory phase (`dpsi/dt = 2π·freq`, so changing the frequency never makes the
//! toe jump):
//!
//! ```text
//! x = x_c + a·cos(s)
//! y = y_c + b·sin(s)              when sin(s) < 0  (swing: the toe lifts by up to b)
//! y = y_c + flatness·b·sin(s)     when sin(s) >= 0 (stance: flattened half)
//! ```
//!
//! With `flatness = 0` the stance half is the straight line `y = y_c` (the ground) and the swing
//! half an arc of height `b` (the ground clearance): the semi-ellipse. `flatness = 1` is the full
//! ellipse of eq. 4.5. During the swing `x` goes from `x_c - a` to `x_c + a` (the toe moves
//! forward in the air and backward on the ground: walking forward).

use super::leg_kinematics::in_workspace;

/// How far beyond the fully stretched reach (600 mm) a commanded ellipse may graze and still be
/// accepted. Table 6.1's trot (centre 599 mm, a = 5 cm, flat stance) reaches 601.08 mm at the
/// ends of its stance line, so a strict 600 mm check would refuse the thesis's own experiment.
/// Points in this band are unreachable; the firmware serves the last reachable point there
/// (see `LaelapsLeg`).
pub const REACH_TOLERANCE_M: f64 = 0.002;
/// Highest accepted trajectory frequency, Hz.
pub const MAX_FREQ_HZ: f64 = 10.0;
/// Largest accepted angle of a trajectory point from the downward vertical (the "sensible x").
pub const MAX_TOE_ANGLE_DEG: f64 = 45.0;
/// Points sampled along the ellipse by the workspace check.
const CHECK_SAMPLES: usize = 256;

/// Trajectory parameters in SI units (m, Hz, rad, fraction).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrajectoryParams {
    pub x_c: f64,
    pub y_c: f64,
    pub a: f64,
    pub b: f64,
    pub freq_hz: f64,
    pub phase_rad: f64,
    pub flatness: f64,
}

impl TrajectoryParams {
    /// From the raw 0x7030 values: x/y centre in mm, a/b in cm, freq in Hz/100, phase in deg,
    /// flatness /100.
    pub fn from_raw(raw: [i64; 7]) -> Self {
        Self {
            x_c: raw[0] as f64 / 1000.0,
            y_c: raw[1] as f64 / 1000.0,
            a: raw[2] as f64 / 100.0,
            b: raw[3] as f64 / 100.0,
            freq_hz: raw[4] as f64 / 100.0,
            phase_rad: (raw[5] as f64).to_radians(),
            flatness: raw[6] as f64 / 100.0,
        }
    }

    /// A single point (a = b = 0) at the toe position (x, y).
    pub fn point(x: f64, y: f64) -> Self {
        Self {
            x_c: x,
            y_c: y,
            a: 0.0,
            b: 0.0,
            freq_hz: 0.0,
            phase_rad: 0.0,
            flatness: 0.0,
        }
    }

    fn lerp(&self, other: &Self, f: f64) -> Self {
        let l = |p: f64, q: f64| p + (q - p) * f;
        Self {
            x_c: l(self.x_c, other.x_c),
            y_c: l(self.y_c, other.y_c),
            a: l(self.a, other.a),
            b: l(self.b, other.b),
            freq_hz: l(self.freq_hz, other.freq_hz),
            phase_rad: l(self.phase_rad, other.phase_rad),
            flatness: l(self.flatness, other.flatness),
        }
    }

    /// The toe point at trajectory angle `s` (rad).
    pub fn point_at(&self, s: f64) -> (f64, f64) {
        let sin = s.sin();
        let lift = if sin < 0.0 { 1.0 } else { self.flatness };
        (self.x_c + self.a * s.cos(), self.y_c + lift * self.b * sin)
    }

    /// Why these parameters make an invalid ellipse, or `None` when it is valid: every point
    /// inside the workspace (with `REACH_TOLERANCE_M` beyond the stretched leg), below the hip and
    /// within ±45° of the vertical; non-negative axes and frequency, flatness in [0, 1].
    pub fn invalid_reason(&self) -> Option<String> {
        if !(self.a >= 0.0 && self.b >= 0.0) {
            return Some(format!(
                "negative semi-axis (a {} m, b {} m)",
                self.a, self.b
            ));
        }
        if !(0.0..=MAX_FREQ_HZ).contains(&self.freq_hz) {
            return Some(format!(
                "frequency {} Hz outside 0..{MAX_FREQ_HZ}",
                self.freq_hz
            ));
        }
        if !(0.0..=1.0).contains(&self.flatness) {
            return Some(format!("flatness {} outside 0..1", self.flatness));
        }
        let max_tan = MAX_TOE_ANGLE_DEG.to_radians().tan();
        for i in 0..CHECK_SAMPLES {
            let s = std::f64::consts::TAU * i as f64 / CHECK_SAMPLES as f64;
            let (x, y) = self.point_at(s);
            if !in_workspace(x, y, REACH_TOLERANCE_M) {
                return Some(format!(
                    "point ({:.1}, {:.1}) mm at reach {:.1} mm is outside the workspace",
                    x * 1e3,
                    y * 1e3,
                    x.hypot(y) * 1e3
                ));
            }
            if x.abs() > y * max_tan {
                return Some(format!(
                    "point ({:.1}, {:.1}) mm is more than {MAX_TOE_ANGLE_DEG}° from the vertical",
                    x * 1e3,
                    y * 1e3
                ));
            }
        }
        None
    }
}

/// The firmware's trajectory generator: the parameters in use ramp linearly from where they
/// were to the last accepted target over the transition time.
#[derive(Clone, Debug)]
pub struct Trajectory {
    start: TrajectoryParams,
    target: TrajectoryParams,
    current: TrajectoryParams,
    elapsed_s: f64,
    duration_s: f64,
    psi: f64,
    rejected: u64,
    last_rejected: Option<TrajectoryParams>,
}

impl Trajectory {
    /// A trajectory resting at the toe point (x, y).
    pub fn at_point(x: f64, y: f64) -> Self {
        let p = TrajectoryParams::point(x, y);
        Self {
            start: p,
            target: p,
            current: p,
            elapsed_s: 0.0,
            duration_s: 0.0,
            psi: 0.0,
            rejected: 0,
            last_rejected: None,
        }
    }

    /// Offer new parameters. Unchanged ones are a no-op; invalid ones are disregarded (the
    /// target in effect stays) and counted; valid ones start a linear transition of
    /// `transition_s` seconds from the parameters in use (0: applied at once).
    /// Returns false when the parameters were rejected.
    pub fn offer(&mut self, params: TrajectoryParams, transition_s: f64) -> bool {
        if params == self.target {
            return true;
        }
        if params.invalid_reason().is_some() {
            // Count a rejected set once, not once per control tick while the master keeps it.
            if self.last_rejected != Some(params) {
                self.rejected += 1;
                self.last_rejected = Some(params);
            }
            return false;
        }
        self.start = self.current;
        self.target = params;
        self.elapsed_s = 0.0;
        self.duration_s = transition_s.max(0.0);
        if self.duration_s == 0.0 {
            self.current = params;
        }
        true
    }

    /// Jump to the parameters at once (no transition), if valid. Returns false when rejected.
    pub fn set_now(&mut self, params: TrajectoryParams) -> bool {
        if self.offer(params, 0.0) {
            self.start = params;
            self.current = params;
            self.elapsed_s = 0.0;
            self.duration_s = 0.0;
            true
        } else {
            false
        }
    }

    /// Restart the trajectory phase (the toe starts at s = phase).
    pub fn restart_phase(&mut self) {
        self.psi = 0.0;
    }

    /// Advance the transition and the phase by `dt` seconds.
    pub fn advance(&mut self, dt: f64) {
        if self.duration_s > 0.0 && self.elapsed_s < self.duration_s {
            self.elapsed_s = (self.elapsed_s + dt).min(self.duration_s);
            self.current = self
                .start
                .lerp(&self.target, self.elapsed_s / self.duration_s);
        } else {
            self.current = self.target;
        }
        self.psi =
            (self.psi + std::f64::consts::TAU * self.current.freq_hz * dt) % std::f64::consts::TAU;
    }

    /// The toe point the trajectory commands now.
    pub fn point(&self) -> (f64, f64) {
        self.current.point_at(self.psi + self.current.phase_rad)
    }

    pub fn current(&self) -> &TrajectoryParams {
        &self.current
    }

    pub fn target(&self) -> &TrajectoryParams {
        &self.target
    }

    /// Whether a transition is still running.
    pub fn in_transition(&self) -> bool {
        self.duration_s > 0.0 && self.elapsed_s < self.duration_s
    }

    /// Number of distinct parameter sets disregarded as invalid ellipses.
    pub fn rejected(&self) -> u64 {
        self.rejected
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trot(y_c_mm: i64, a_cm: i64, b_cm: i64) -> TrajectoryParams {
        TrajectoryParams::from_raw([0, y_c_mm, a_cm, b_cm, 100, 0, 0])
    }

    #[test]
    fn table_6_1_trot_is_accepted_and_far_ellipses_are_not() {
        assert_eq!(trot(599, 5, 4).invalid_reason(), None);
        assert_eq!(trot(598, 5, 4).invalid_reason(), None);
        assert!(trot(650, 0, 0).invalid_reason().is_some());
        assert!(trot(599, 20, 4).invalid_reason().is_some());
        assert!(trot(450, 5, 4).invalid_reason().is_some()); // swing reaches inside 430 mm
        let mut flat = trot(550, 5, 4);
        flat.flatness = 1.5;
        assert!(flat.invalid_reason().is_some());
    }

    #[test]
    fn semi_ellipse_lifts_in_swing_and_is_flat_in_stance() {
        let p = trot(599, 5, 4);
        let (x, y) = p.point_at(1.5 * std::f64::consts::PI);
        assert!((x - 0.0).abs() < 1e-12 && (y - 0.559).abs() < 1e-12);
        let (_, y) = p.point_at(0.5 * std::f64::consts::PI);
        assert!((y - 0.599).abs() < 1e-12);
        let mut full = p;
        full.flatness = 1.0;
        assert!((full.point_at(0.5 * std::f64::consts::PI).1 - 0.639).abs() < 1e-12);
    }

    #[test]
    fn changes_ramp_linearly_over_the_transition_time() {
        let mut t = Trajectory::at_point(0.0, 0.599);
        assert!(t.set_now(trot(599, 0, 0)));
        assert!(t.offer(trot(599, 0, 4), 3.0));
        for _ in 0..15_000 {
            t.advance(1e-4);
        }
        assert!((t.current().b - 0.02).abs() < 1e-9, "b {}", t.current().b);
        assert!(t.in_transition());
        for _ in 0..15_001 {
            t.advance(1e-4);
        }
        assert!((t.current().b - 0.04).abs() < 1e-12);
        assert!(!t.in_transition());
    }

    #[test]
    fn invalid_parameters_are_disregarded() {
        let mut t = Trajectory::at_point(0.0, 0.599);
        assert!(t.set_now(trot(560, 5, 4)));
        assert!(!t.offer(trot(700, 5, 4), 0.0));
        assert!(!t.offer(trot(700, 5, 4), 0.0));
        assert_eq!(t.rejected(), 1);
        assert_eq!(*t.target(), trot(560, 5, 4));
        t.advance(1e-4);
        assert_eq!(*t.current(), trot(560, 5, 4));
    }
}
