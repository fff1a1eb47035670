//! The motion the axis stage commands between commands: setpoint interpolation, trajectory
//! sampling, the quiet stop after a mode change or an enable, the blend that joins a new motion
//! within the acceleration and velocity limits, and the braking envelope that keeps an axis
//! inside its position limits (and, in cst, below its velocity limit) in the velocity and torque
//! modes. Pure functions
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

    /// The value at time `t` (ns): the ramp's, then `to` once it is done.
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
    /// Position where the stop started (SI).
    pub position: f64,
    /// Velocity where the stop started (SI).
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

/// The next position target of an axis in csp, blended from the state it is commanded to have
/// (`position`, and `velocity`: the velocity of the last step on the wire) towards the wanted
/// motion (`wanted` and its velocity `wanted_velocity`) within the acceleration limit `amax`
/// and the velocity limit `vmax`, for a step of `dt` seconds. Returns the target and the
/// velocity of the step to it.
///
/// A wanted motion the axis can follow (the step it needs changes the velocity by at most
/// `amax·dt` and stays within `vmax`) is followed exactly. Anything else — the first cycles of
/// a hand-over, a setpoint that jumps, a trajectory that starts away from the axis — is joined
/// the fastest way the limits allow without overshoot: the velocity steers towards the wanted
/// one plus the speed from which the remaining gap can still be closed decelerating at `amax`,
/// and never changes by more than `amax·dt` in one step. `amax` = ∞ leaves only the velocity
/// limit (the step clamped to `vmax·dt`).
pub fn blend(
    position: f64,
    velocity: f64,
    wanted: f64,
    wanted_velocity: f64,
    vmax: f64,
    amax: f64,
    dt: f64,
) -> (f64, f64) {
    if dt <= 0.0 {
        return (position, velocity);
    }
    let need = (wanted - position) / dt;
    if amax.is_infinite() {
        if need.abs() <= vmax {
            return (wanted, need);
        }
        let v = need.clamp(-vmax, vmax);
        return (position + v * dt, v);
    }
    let dv = amax * dt;
    let vmax = vmax.max(0.0);
    let along = wanted_velocity.clamp(-vmax, vmax);
    // Followed exactly when the step there keeps the velocity change within the limit, and the
    // velocity it arrives with is the wanted one within it too (so the next step can be made).
    if (need - velocity).abs() <= dv && (need - along).abs() <= dv && need.abs() <= vmax {
        return (wanted, need);
    }
    // The gap left if this step moved along with the wanted motion; closed at the speed from
    // which slowing by `dv` per step ends on it (v² / 2a + v·dt / 2 = gap, less dv·dt / 8 for
    // a last step that is not a whole `dv`), the last bit in one step.
    let gap = wanted - position - along * dt;
    let g = gap.abs();
    let braking = -0.5 * dv + (0.25 * dv * dv + 2.0 * amax * (g - dv * dt / 8.0).max(0.0)).sqrt();
    let closing = braking.max((g / dt).min(dv)).min(g / dt);
    let v = (along + gap.signum() * closing)
        .clamp(velocity - dv, velocity + dv)
        .clamp(-vmax, vmax);
    (position + v * dt, v)
}

/// A torque command in cst near a limit or at speed: the axis never runs faster than `vmax`,
/// nor outward faster than the braking speed of the distance left before a position limit.
/// A torque that pushes towards such a bound fades out over the last `band` SI/s below it
/// (`bands.0` for the braking envelope, `bands.1` for `vmax`: so the axis comes up to the
/// bound smoothly instead of hitting it and bouncing, no chatter); an axis faster than a bound
/// is braked, up to `torque_max`, in proportion to the excess speed (full braking at `band`
/// SI/s over it). Returns the torque.
#[allow(clippy::too_many_arguments)]
pub fn limit_torque(
    torque: f64,
    position: f64,
    velocity: f64,
    limits: (f64, f64),
    decel: f64,
    vmax: f64,
    torque_max: f64,
    bands: (f64, f64),
) -> f64 {
    let (min, max) = limits;
    // The fastest the axis may move towards +1 (up) or -1 (down), the distance to that side's
    // limit, and the band of whichever bound that is.
    let allowed = |side: f64| {
        let distance = if side > 0.0 {
            max - position
        } else {
            position - min
        };
        let envelope = braking_speed(distance, decel);
        if envelope < vmax {
            (envelope, distance, bands.0)
        } else {
            (vmax, distance, bands.1)
        }
    };
    for side in [1.0f64, -1.0] {
        let speed = velocity * side;
        let (bound, _, band) = allowed(side);
        if speed > bound {
            let excess = if bound.is_finite() {
                speed - bound
            } else {
                0.0
            };
            let brake = torque_max * (excess / band).min(1.0);
            // A commanded torque that brakes harder stays.
            return -side * brake.max(-torque * side);
        }
    }
    if torque == 0.0 {
        return 0.0;
    }
    let side = torque.signum();
    let (bound, distance, band) = allowed(side);
    if distance <= 0.0 {
        return 0.0;
    }
    let headroom = bound - velocity * side;
    if headroom.is_infinite() {
        return torque;
    }
    torque * (headroom / band).clamp(0.0, 1.0)
}

/// Cycles of history the cst limiter keeps (positions read, torques written).
const CST_HISTORY: usize = 16;
/// The velocity from positions: the difference over this many cycles (an encoder count does
/// not jitter as a drive's velocity actual does; a short span keeps the estimate recent).
const CST_SPAN: usize = 2;
/// Observations of the torque's effect before the gain counts as known.
const CST_LEARNED: u32 = 4;
/// Share of each new observation in the gain estimate.
const CST_GAIN_SMOOTHING: f64 = 0.2;
/// A torque counts for learning the gain from this share of the torque limit up (below it,
/// friction is a large part of what the torque does).
const CST_LEARN_SHARE: f64 = 0.25;
/// Once the gain is known, the bands below the bounds span at least what the torque limit adds
/// to the speed in this many cycles: a loop on the predicted speed slow enough for a latency a
/// cycle or two off the assumed one (no chatter), still reaching the bound in a few ms.
const CST_BAND_CYCLES: f64 = 6.0;
/// Until the gain is known the torque rises to the torque limit over this many cycles at the
/// fastest: the axis's response is seen before it is fast.
const CST_RISE_CYCLES: f64 = 40.0;

/// The velocity limit and the braking envelope in cst, against a drive that acts on a torque
/// only a few cycles after it is written (`latency`) and reports a velocity that jitters.
///
/// A torque limit can take a light axis to its velocity limit within a few cycles, faster
/// than a loop on the velocity read can react: the speed the axis will have when a torque
/// written now takes effect is predicted instead (a Smith predictor). The velocity comes from
/// the positions read ([`CST_SPAN`] cycles apart), and the torques written since (still in
/// flight to the drive) are added through the axis's gain — its acceleration per unit of
/// torque, learned from the positions while a steady torque accelerates it. Until the gain is
/// known the torque rises gradually ([`CST_RISE_CYCLES`]) and the prediction extrapolates the
/// acceleration seen. The predicted velocity and position go to [`limit_torque`].
#[derive(Clone, Copy, Debug)]
pub struct CstLimiter {
    positions: [f64; CST_HISTORY],
    torques: [f64; CST_HISTORY],
    /// Cycles recorded since the reset (saturating).
    count: usize,
    /// Next slot of the rings.
    head: usize,
    /// Acceleration per unit of torque (SI); 0: not known yet.
    gain: f64,
    learned: u32,
    /// The torque written last cycle.
    last: f64,
    /// The speed predicted and the velocity limit's band of the last cycle.
    predicted: f64,
    vband: f64,
}

impl Default for CstLimiter {
    fn default() -> Self {
        CstLimiter {
            positions: [0.0; CST_HISTORY],
            torques: [0.0; CST_HISTORY],
            count: 0,
            head: 0,
            gain: 0.0,
            learned: 0,
            last: 0.0,
            predicted: 0.0,
            vband: 0.0,
        }
    }
}

impl CstLimiter {
    /// Forget the motion (a new entry into cst, a disable); the gain learned is kept: it is
    /// the axis's, not the motion's.
    pub fn restart(&mut self) {
        let (gain, learned) = (self.gain, self.learned);
        *self = CstLimiter {
            gain,
            learned,
            ..Default::default()
        };
    }

    /// The gain learned (0 while unknown).
    pub fn gain(&self) -> f64 {
        if self.learned >= CST_LEARNED {
            self.gain
        } else {
            0.0
        }
    }

    /// Was the last cut the velocity limit's (the predicted speed within its band below
    /// `vmax` or above it), not the braking envelope's?
    pub fn near_velocity_limit(&self, vmax: f64) -> bool {
        self.predicted.abs() + self.vband >= vmax
    }

    /// Entry `back` cycles before the newest of `ring` (0: the newest).
    fn at(&self, ring: &[f64; CST_HISTORY], back: usize) -> f64 {
        let back = back.min(self.count.saturating_sub(1));
        ring[(self.head + CST_HISTORY - 1 - back) % CST_HISTORY]
    }

    /// One cycle: the position read now, the torque asked for (already within the torque
    /// limit); returns the torque to write and whether a bound cut it. `latency`: cycles from
    /// a torque written to its effect in the positions read; `dt` the cycle (s).
    #[allow(clippy::too_many_arguments)]
    pub fn step(
        &mut self,
        position: f64,
        torque: f64,
        limits: (f64, f64),
        decel: f64,
        vmax: f64,
        torque_max: f64,
        latency: usize,
        dt: f64,
    ) -> (f64, bool) {
        self.positions[self.head] = position;
        self.torques[self.head] = self.last;
        self.head = (self.head + 1) % CST_HISTORY;
        self.count = (self.count + 1).min(CST_HISTORY);
        let latency = latency.min(CST_HISTORY - 2 * CST_SPAN - 1);
        let n = CST_SPAN as f64;
        let (velocity, accel) = if self.count > 2 * CST_SPAN {
            let (p0, p1, p2) = (
                self.at(&self.positions, 0),
                self.at(&self.positions, CST_SPAN),
                self.at(&self.positions, 2 * CST_SPAN),
            );
            (
                (p0 - p1) / (n * dt),
                (p0 - 2.0 * p1 + p2) / (n * n * dt * dt),
            )
        } else {
            (0.0, 0.0)
        };
        // The acceleration seen is that of the last 2·span cycles, caused by the torques
        // written `latency` cycles before those: learn the gain where they were steady, away
        // from the position limits (where a drive may stop the axis by itself).
        if self.count >= CST_HISTORY {
            let (mut lo, mut hi, mut sum) = (f64::INFINITY, f64::NEG_INFINITY, 0.0);
            for back in latency..latency + 2 * CST_SPAN {
                let t = self.at(&self.torques, back);
                lo = lo.min(t);
                hi = hi.max(t);
                sum += t;
            }
            let mean = sum / (2 * CST_SPAN) as f64;
            // Steady or rising evenly (the gradual rise while the gain is unknown): the mean
            // is the torque at the middle of the window.
            let steady = hi - lo <= 0.5 * mean.abs() && lo * hi > 0.0;
            let inside = position - limits.0 > 0.05 * (limits.1 - limits.0)
                && limits.1 - position > 0.05 * (limits.1 - limits.0);
            if steady && inside && mean.abs() >= CST_LEARN_SHARE * torque_max {
                let seen = accel / mean;
                if seen > 0.0 && seen.is_finite() {
                    self.gain = if self.learned == 0 {
                        seen
                    } else {
                        self.gain + CST_GAIN_SMOOTHING * (seen - self.gain)
                    };
                    self.learned = self.learned.saturating_add(1);
                }
            }
        }
        // The velocity estimate is for the middle of its span; the torque written now takes
        // effect `latency` cycles after the newest position.
        let horizon = latency as f64 + 0.5 * n;
        let gain = self.gain();
        let predicted = if gain > 0.0 {
            let mut in_flight = 0.0;
            for back in 0..latency + CST_SPAN / 2 {
                in_flight += self.at(&self.torques, back);
            }
            velocity + gain * in_flight * dt
        } else {
            velocity + accel * horizon * dt
        };
        let ahead = position + 0.5 * (velocity + predicted) * horizon * dt;
        // Bands: the braking envelope's, and the velocity limit's — at least what the torque
        // limit adds in `CST_BAND_CYCLES` once the gain is known, so that a cycle's error of
        // the prediction does not turn the fade into braking (chatter).
        let mut band = if decel.is_finite() {
            (decel * 0.01).max(1e-3)
        } else if vmax.is_finite() {
            (vmax * 0.1).max(1e-3)
        } else {
            0.1
        };
        let mut vband = if vmax.is_finite() {
            band.max(vmax * 0.2)
        } else {
            band
        };
        if gain > 0.0 {
            let step = CST_BAND_CYCLES * gain * torque_max * dt;
            // The position envelope's band from the torque asked for: sized from the torque
            // limit it faded a light push (2 of 8 N·m) out 54 mrad short of the limit.
            band = band.max(CST_BAND_CYCLES * gain * torque.abs().min(torque_max) * dt);
            vband = vband.max(step);
        }
        let mut out = limit_torque(
            torque,
            ahead,
            predicted,
            limits,
            decel,
            vmax,
            torque_max,
            (band, vband),
        );
        if gain == 0.0 && out * self.last >= 0.0 && out.abs() > self.last.abs() {
            // Unknown gain: a gradual rise (a reversal starts from zero).
            let rise = torque_max / CST_RISE_CYCLES;
            out = out.signum() * out.abs().min(self.last.abs() + rise);
        } else if gain == 0.0 && out * self.last < 0.0 && out * torque > 0.0 {
            out = out.signum() * out.abs().min(torque_max / CST_RISE_CYCLES);
        }
        self.last = out;
        self.predicted = predicted;
        self.vband = vband;
        (out, out != torque)
    }
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
        assert_eq!(
            limit_torque(2.0, 0.0, 0.5, lim, 10.0, f64::INFINITY, 5.0, (0.1, 0.1)),
            2.0
        );
        // 0.05 before the upper limit (braking speed 1/s), moving up slower: still pushed.
        assert_eq!(
            limit_torque(2.0, 0.95, 0.5, lim, 10.0, f64::INFINITY, 5.0, (0.1, 0.1)),
            2.0
        );
        // Faster than the envelope by half the band: half the torque limit, downwards.
        assert!(
            (limit_torque(2.0, 0.95, 1.05, lim, 10.0, f64::INFINITY, 5.0, (0.1, 0.1)) + 2.5).abs()
                < 1e-9
        );
        // At the limit, standing: no outward torque; inward torque stays.
        assert_eq!(
            limit_torque(2.0, 1.0, 0.0, lim, 10.0, f64::INFINITY, 5.0, (0.1, 0.1)),
            0.0
        );
        assert_eq!(
            limit_torque(-2.0, 1.0, 0.0, lim, 10.0, f64::INFINITY, 5.0, (0.1, 0.1)),
            -2.0
        );
        // Beyond the lower limit and still moving out: full braking upwards.
        assert_eq!(
            limit_torque(-1.0, -1.1, -1.0, lim, 10.0, f64::INFINITY, 5.0, (0.1, 0.1)),
            5.0
        );
    }

    #[test]
    fn torque_fades_below_the_velocity_limit_and_brakes_above_it() {
        let lim = (-10.0, 10.0);
        let t = |torque: f64, v: f64| limit_torque(torque, 0.0, v, lim, 10.0, 3.0, 5.0, (0.1, 0.2));
        // Well below the limit: untouched; the last 0.2 rad/s below it: faded.
        assert_eq!(t(2.0, 1.0), 2.0);
        assert!((t(2.0, 2.9) - 1.0).abs() < 1e-9);
        assert_eq!(t(2.0, 3.0), 0.0);
        // Against the motion: untouched (it slows the axis).
        assert_eq!(t(-2.0, 3.0), -2.0);
        // Over the limit: braked in proportion to the excess, or harder where commanded.
        assert!((t(2.0, 3.1) + 2.5).abs() < 1e-9);
        assert_eq!(t(0.0, -3.5), 5.0);
        assert_eq!(t(-5.0, 3.1), -5.0);
        // Just before a position limit, at rest: the outward torque fades to nothing.
        let near = limit_torque(2.0, 9.9995, 0.0, lim, 10.0, 3.0, 5.0, (0.2, 0.2));
        assert!(near > 0.0 && near < 2.0, "{near}");
    }

    /// Second differences of a target sequence over dt²: the acceleration of every step.
    fn accelerations(targets: &[f64], dt: f64) -> impl Iterator<Item = f64> + '_ {
        targets
            .windows(3)
            .map(move |w| ((w[2] - w[1]) - (w[1] - w[0])).abs() / (dt * dt))
    }

    #[test]
    fn blend_follows_what_it_can_and_joins_the_rest_within_the_limits() {
        let dt = 0.001;
        let (vmax, amax) = (3.0, 20.0);
        // A motion within the limits is followed exactly.
        let (p, v) = blend(0.0, 1.0, 0.00101, 1.01, vmax, amax, dt);
        assert_eq!(p, 0.00101);
        assert!((v - 1.01).abs() < 1e-9);
        // A wanted position 0.2 rad back (a stale first point) while moving at 1 rad/s: the
        // velocity changes by at most amax·dt per cycle, the target comes to rest on the point
        // without overshoot and stays there.
        let (mut p, mut v) = (0.0, 1.0);
        let mut targets = vec![-dt * 1.0, 0.0];
        for _ in 0..2000 {
            (p, v) = blend(p, v, -0.2, 0.0, vmax, amax, dt);
            targets.push(p);
        }
        assert!((p + 0.2).abs() < 1e-12 && v == 0.0, "{p} {v}");
        assert!(targets.iter().all(|&x| x >= -0.2 - 1e-12));
        assert!(accelerations(&targets, dt).all(|a| a <= amax + 1e-6));
        assert!(targets
            .windows(2)
            .all(|w| (w[1] - w[0]).abs() <= vmax * dt + 1e-12));
        // Joining a trajectory running 1 rad ahead at 2 rad/s: caught up within the limits,
        // then followed exactly.
        let (mut p, mut v) = (0.0, 0.0);
        let mut targets = vec![0.0, 0.0];
        let path = |k: usize| 1.0 + 2.0 * k as f64 * dt;
        for k in 0..3000 {
            (p, v) = blend(p, v, path(k), 2.0, vmax, amax, dt);
            targets.push(p);
        }
        assert!((p - path(2999)).abs() < 1e-9, "{p}");
        assert!(accelerations(&targets, dt).all(|a| a <= amax + 1e-6));
        assert!(targets
            .windows(2)
            .all(|w| (w[1] - w[0]).abs() <= vmax * dt + 1e-12));
        // No acceleration limit: only the velocity limit's step.
        assert_eq!(
            blend(0.0, 0.0, 1.0, 0.0, vmax, f64::INFINITY, dt),
            (vmax * dt, vmax)
        );
    }
}
