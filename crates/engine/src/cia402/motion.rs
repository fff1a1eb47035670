//! The motion the axis stage commands between commands: setpoint interpolation, trajectory
//! sampling, the quiet stop after a mode change or an enable, and the braking envelope that
//! keeps an axis inside its position limits in the velocity and torque modes. Pure functions
//! and small state, no allocation: the RT thread runs them every cycle.

use super::Point;

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

    /// The slope at `t` (SI/s): 0 once the setpoint is reached.
    pub fn slope(&self, t: i64) -> f64 {
        if self.span <= 0 || t >= self.t_to + self.span || t < self.t_to {
            return 0.0;
        }
        (self.to - self.from) / (self.span as f64 * 1e-9)
    }

    /// Has the last setpoint been reached at `t`?
    pub fn at_rest(&self, t: i64) -> bool {
        self.span <= 0 || t >= self.t_to + self.span
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
/// `points` (sorted by time); `cursor` remembers the segment (time only moves forward).
/// Before the first point: the first point; after the last: the last point's position with
/// velocity 0 (the flag: done).
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

/// The velocity at time `t` of a velocity trajectory (csv): linear between the points'
/// velocities; the first point's before it, 0 after the last (the flag: done).
pub fn sample_velocity(points: &[Point], t: i64, cursor: &mut usize) -> (f64, bool) {
    let Some(last) = points.last() else {
        return (0.0, true);
    };
    if t >= last.t_ns {
        return (0.0, true);
    }
    let first = points[0];
    if t <= first.t_ns {
        return (first.velocity, false);
    }
    while *cursor + 1 < points.len() && points[*cursor + 1].t_ns <= t {
        *cursor += 1;
    }
    let a = points[*cursor];
    let b = points[(*cursor + 1).min(points.len() - 1)];
    let span = (b.t_ns - a.t_ns) as f64;
    if span <= 0.0 {
        return (b.velocity, false);
    }
    let f = (t - a.t_ns) as f64 / span;
    (a.velocity + (b.velocity - a.velocity) * f, false)
}

/// A quiet stop: from a position and velocity, decelerate at a constant rate to rest and hold.
/// A mode change or an enable starts the new mode with one (docs/cia402.md, "Mode changes").
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StopRamp {
    pub position: f64,
    pub velocity: f64,
}

impl StopRamp {
    /// Advance by `dt` seconds at deceleration `decel` (∞: at rest at once).
    pub fn advance(&mut self, decel: f64, dt: f64) {
        let v0 = self.velocity;
        if v0 == 0.0 {
            return;
        }
        let dv = decel * dt;
        if v0.abs() <= dv {
            // Comes to rest within this step: the rest of the stopping distance.
            self.position += if decel.is_finite() {
                v0 * v0.abs() / (2.0 * decel)
            } else {
                0.0
            };
            self.velocity = 0.0;
        } else {
            let v1 = v0 - v0.signum() * dv;
            self.position += (v0 + v1) * 0.5 * dt;
            self.velocity = v1;
        }
    }

    /// Where the ramp comes to rest.
    pub fn rest_position(&self, decel: f64) -> f64 {
        if decel.is_finite() && decel > 0.0 {
            self.position + self.velocity * self.velocity.abs() / (2.0 * decel)
        } else {
            self.position
        }
    }
}

/// The highest speed from which an axis `distance` before a limit still stops at the limit
/// decelerating at `decel`: √(2·decel·distance); 0 at or beyond the limit, ∞ before it when
/// `decel` is ∞.
pub fn braking_speed(distance: f64, decel: f64) -> f64 {
    if distance <= 0.0 {
        0.0
    } else if decel.is_infinite() {
        f64::INFINITY
    } else {
        (2.0 * decel * distance).sqrt()
    }
}

/// `velocity` cut so that the axis, expected at `position` when the command takes effect, can
/// still stop inside [`min`, `max`] decelerating at `decel`: outward speed at most
/// `braking_speed` of the distance left; inward motion is never cut.
pub fn limit_velocity(velocity: f64, position: f64, min: f64, max: f64, decel: f64) -> f64 {
    if velocity > 0.0 {
        velocity.min(braking_speed(max - position, decel))
    } else if velocity < 0.0 {
        velocity.max(-braking_speed(position - min, decel))
    } else {
        0.0
    }
}

/// A torque command in cst near a limit: an outward torque is cut to zero once the axis moves
/// outward at the braking speed of the distance left (so it never accelerates into the limit),
/// and while it moves outward faster than that the axis is braked, up to `torque_max`, in
/// proportion to the excess speed (full braking at `band` SI/s over it). Returns the torque.
pub fn limit_torque(
    torque: f64,
    position: f64,
    velocity: f64,
    limits: (f64, f64),
    decel: f64,
    torque_max: f64,
    band: f64,
) -> f64 {
    let (min, max) = limits;
    // +1: the upper limit is ahead of a motion upwards, -1: the lower one.
    for side in [1.0f64, -1.0] {
        let distance = if side > 0.0 {
            max - position
        } else {
            position - min
        };
        let outward_speed = velocity * side;
        let allowed = braking_speed(distance, decel);
        let outward_torque = torque * side > 0.0;
        if outward_speed > allowed {
            let excess = if allowed.is_finite() {
                outward_speed - allowed
            } else {
                0.0
            };
            let brake = torque_max * (excess / band).min(1.0);
            return -side * brake;
        }
        if outward_torque && (distance <= 0.0 || outward_speed >= allowed) {
            return 0.0;
        }
    }
    torque
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolator_holds_and_spans_by_arrival() {
        let mut i = Interpolator::default();
        i.reset(1.0);
        assert_eq!(i.value(123), 1.0);
        i.push(2.0, 1000, 10, 10_000);
        assert_eq!(i.value(1000), 1.0);
        assert_eq!(i.value(1005), 1.5);
        assert_eq!(i.value(1010), 2.0);
        assert!(i.at_rest(1010) && !i.at_rest(1005));
        i.push(4.0, 2000, 10, 10_000);
        // Span 1000 (since the previous arrival): half-way at +500.
        assert_eq!(i.value(2500), 3.0);
        assert!((i.slope(2500) - 2.0 / 1e-6).abs() < 1e-3);
        assert_eq!(i.value(9999), 4.0);
        // A long pause is capped at max_span.
        i.push(5.0, 100_000, 10, 10_000);
        assert_eq!(i.value(110_000), 5.0);
    }

    #[test]
    fn a_stop_ramp_comes_to_rest_at_its_braking_distance() {
        let mut r = StopRamp {
            position: 1.0,
            velocity: -2.0,
        };
        // 2 rad/s at 10 rad/s²: 0.2 s and 0.2 rad.
        assert!((r.rest_position(10.0) - 0.8).abs() < 1e-12);
        for _ in 0..1000 {
            r.advance(10.0, 0.001);
        }
        assert_eq!(r.velocity, 0.0);
        assert!((r.position - 0.8).abs() < 1e-9, "{}", r.position);
        // Infinite deceleration: at rest where it is.
        let mut r = StopRamp {
            position: 1.0,
            velocity: 3.0,
        };
        r.advance(f64::INFINITY, 0.001);
        assert_eq!((r.position, r.velocity), (1.0, 0.0));
    }

    #[test]
    fn velocity_toward_a_limit_follows_the_braking_envelope() {
        // 0.05 before the limit at 10/s²: at most 1/s outward; inward untouched.
        assert!((limit_velocity(3.0, 0.95, -1.0, 1.0, 10.0) - 1.0).abs() < 1e-12);
        assert_eq!(limit_velocity(-3.0, 0.95, -1.0, 1.0, 10.0), -3.0);
        assert_eq!(limit_velocity(0.5, 1.2, -1.0, 1.0, 10.0), 0.0);
        assert_eq!(limit_velocity(-0.5, 1.2, -1.0, 1.0, 10.0), -0.5);
        assert!((limit_velocity(-3.0, -0.95, -1.0, 1.0, 10.0) + 1.0).abs() < 1e-12);
        // Infinite deceleration: cut only at the limit.
        assert_eq!(limit_velocity(3.0, 0.999, -1.0, 1.0, f64::INFINITY), 3.0);
        assert_eq!(limit_velocity(3.0, 1.0, -1.0, 1.0, f64::INFINITY), 0.0);
    }

    #[test]
    fn torque_toward_a_limit_is_cut_then_brakes() {
        let lim = (-1.0, 1.0);
        // Far from the limits: untouched.
        assert_eq!(limit_torque(2.0, 0.0, 0.5, lim, 10.0, 5.0, 0.1), 2.0);
        // 0.05 before the upper limit (braking speed 1/s), moving up slower: still pushed.
        assert_eq!(limit_torque(2.0, 0.95, 0.5, lim, 10.0, 5.0, 0.1), 2.0);
        // Faster than the envelope by half the band: half the torque limit, downwards.
        assert!((limit_torque(2.0, 0.95, 1.05, lim, 10.0, 5.0, 0.1) + 2.5).abs() < 1e-9);
        // At the limit, standing: no outward torque; inward torque stays.
        assert_eq!(limit_torque(2.0, 1.0, 0.0, lim, 10.0, 5.0, 0.1), 0.0);
        assert_eq!(limit_torque(-2.0, 1.0, 0.0, lim, 10.0, 5.0, 0.1), -2.0);
        // Beyond the lower limit and still moving out: full braking upwards.
        assert_eq!(limit_torque(-1.0, -1.1, -1.0, lim, 10.0, 5.0, 0.1), 5.0);
    }
}
