//! Distributed clock of one virtual ESC: a local clock running from the host's monotonic clock
//! with a drift, the system-time offset, and the time control loop driven by writes to the
//! system time register (0x0910), as in the ESC.
//!
//! What a real ESC does (datasheet, "Distributed Clocks", drift compensation): a write to
//! 0x0910 does not set the time. The ESC computes Δ = local system time at the frame's arrival
//! − written time (− its propagation delay 0x0928 for followers), averages Δ over 2^n values
//! (n = 0x0934 bits 0..3), shows the mean in 0x092C, and trims its clock speed, in bounded
//! steps, so that Δ → 0. It never jumps.
//!
//! The model here is a PI loop on Δ averaged exponentially over about 2^n compares:
//! - proportional: the averaged offset is slewed out at a rate proportional to it
//!   (`|Δ| / τ`, at most `MAX_SLEW`), and only up to the measured amount, so a pause
//!   between compares cannot make it overshoot;
//! - integral: a frequency correction accumulates Δ·dt (`Δ` clamped to what the slew can
//!   handle), which learns the crystal's drift, so a locked clock keeps Δ ≈ 0 without slewing.
//!
//! The gains make a well damped loop (~40 ms at the default 0x0930, slower for larger values)
//! that tolerates noisy compares: in "reference follows master" the written master time is
//! stamped before the frame leaves and reaches the reference tens of µs later, with jitter.
//! The previous model learned the frequency from a single compare (Δ/dt, up to half of it),
//! and only when the previous slew had completed: one jittery compare moved the speed by
//! hundreds of ppm, and once the speed was off by more than the slew rate no slew completed
//! again, so the correction stayed stuck at its −500 ppm limit and the clock ran away.
//!
//! The clock is a pure function of host time between "rebase" points (a compare, a drift step),
//! so reading it never changes it: `local = base_local + (t − base_host)·rate + slew applied`.

/// Fastest the slew can move the local clock against host time (200 ns per ms).
const MAX_SLEW: f64 = 2.0e-4;
/// Largest frequency correction the loop learns (±500 ppm).
const MAX_CORRECTION: f64 = 5.0e-4;
/// Proportional time constant at the default speed counter start (0x0930 = 0x1000): an offset
/// Δ is slewed out at |Δ| / τ (ns/ns). The time constants scale with 0x0930 (a larger start
/// value: a smaller bandwidth, as in the ESC), and the integral's is twice the proportional
/// one (damping ~0.7; settling ~40 ms at the default).
const PHASE_TAU_NS: f64 = 20.0e6;
/// Speed counter start (0x0930) at which `PHASE_TAU_NS` applies: the ESC's power-on value.
pub const DEFAULT_SPEED_COUNTER_START: u16 = 0x1000;
/// Largest filter depth exponent used (0x0934 bits 0..3 allow 15).
const MAX_FILTER_DEPTH: u8 = 12;
/// Longest time step one compare integrates (see `compare`).
const MAX_INTEGRAL_STEP_NS: f64 = 5.0e6;

#[derive(Clone, Debug)]
pub struct DcClock {
    base_host: u64,
    base_local: f64,
    /// Clock drift of the crystal, in ppm (fault injection can step it).
    drift_ppm: f64,
    /// Frequency correction learned by the control loop (dimensionless).
    correction: f64,
    /// Offset still to be slewed in from `base_host` on (ns, signed)…
    slew: f64,
    /// …at this rate (ns per ns, at most `MAX_SLEW`).
    slew_rate: f64,
    /// Host time of the last compare (the integral's time step).
    last_compare_host: Option<u64>,
    /// Filtered Δ (local − received, ns): what 0x092C shows.
    filtered: f64,
    /// Smallest |filtered| seen since the slew saturated (anti-windup, see `compare`).
    saturated_best: Option<f64>,
}

impl DcClock {
    /// A clock that reads `start_local` at host time `host_now`.
    pub fn new(host_now: u64, start_local: u64, drift_ppm: f64) -> Self {
        DcClock {
            base_host: host_now,
            base_local: start_local as f64,
            drift_ppm,
            correction: 0.0,
            slew: 0.0,
            slew_rate: 0.0,
            last_compare_host: None,
            filtered: 0.0,
            saturated_best: None,
        }
    }

    fn rate(&self) -> f64 {
        1.0 + self.drift_ppm * 1e-6 + self.correction
    }

    /// Part of the pending slew applied `dt` ns after the base point.
    fn slew_applied(&self, dt: f64) -> f64 {
        if self.slew == 0.0 || dt <= 0.0 {
            return 0.0;
        }
        self.slew.signum() * (self.slew_rate * dt).min(self.slew.abs())
    }

    /// Local time (ns) at host time `host`.
    pub fn local_f64(&self, host: u64) -> f64 {
        let dt = host as f64 - self.base_host as f64;
        self.base_local + dt * self.rate() + self.slew_applied(dt)
    }

    pub fn local(&self, host: u64) -> u64 {
        let t = self.local_f64(host);
        if t <= 0.0 {
            0
        } else {
            t as u64
        }
    }

    fn rebase(&mut self, host: u64) {
        let now = self.local_f64(host);
        let dt = host as f64 - self.base_host as f64;
        self.slew -= self.slew_applied(dt);
        self.base_local = now;
        self.base_host = host.max(self.base_host);
    }

    pub fn drift_ppm(&self) -> f64 {
        self.drift_ppm
    }

    /// Change the crystal drift from host time `host` on.
    pub fn set_drift(&mut self, host: u64, drift_ppm: f64) {
        self.rebase(host);
        self.drift_ppm = drift_ppm;
    }

    /// Learned frequency correction in ppm (for diagnostics).
    pub fn correction_ppm(&self) -> f64 {
        self.correction * 1e6
    }

    /// The filtered time difference (local − received, ns), as 0x092C shows it.
    pub fn filtered_difference(&self) -> i64 {
        self.filtered.round() as i64
    }

    /// Reset the control loop (write to the speed counter start register).
    pub fn reset_loop(&mut self, host: u64) {
        self.rebase(host);
        self.correction = 0.0;
        self.slew = 0.0;
        self.slew_rate = 0.0;
        self.last_compare_host = None;
        self.filtered = 0.0;
        self.saturated_best = None;
    }

    /// One compare of the time control loop: `diff` = local system time − received system
    /// time (ns) at host time `host`, averaged over about 2^`filter_depth` compares (0x0934),
    /// with the loop bandwidth set by `speed_counter_start` (0x0930). Returns the filtered
    /// difference (for 0x092C).
    pub fn compare(
        &mut self,
        host: u64,
        diff: i64,
        filter_depth: u8,
        speed_counter_start: u16,
    ) -> i64 {
        let scale = f64::from(speed_counter_start.max(1)) / f64::from(DEFAULT_SPEED_COUNTER_START);
        let phase_tau = PHASE_TAU_NS * scale;
        let frequency_tau = 2.0 * phase_tau;
        // Offset beyond which the slew runs at its maximum rate (the proportional part
        // saturates).
        let slew_saturation = MAX_SLEW * phase_tau;
        // Time never runs backwards for the clock (a caller's earlier instant is "now").
        let host = host.max(self.base_host);
        self.rebase(host);
        let diff = diff as f64;
        let dt = match self.last_compare_host {
            None => {
                self.filtered = diff;
                0.0
            }
            Some(last) => {
                // One compare moves the average by a bounded amount, like the ESC, whose loop
                // steps by the sign of Δ: a frame that arrives very late (the master's
                // scheduling spike) must not throw the clock.
                let step = (diff - self.filtered).clamp(-slew_saturation, slew_saturation);
                let weight = 1.0 / f64::from(1u32 << filter_depth.min(MAX_FILTER_DEPTH));
                self.filtered += step * weight;
                // A long pause says nothing about how the offset evolved in between: the
                // integral takes at most `MAX_INTEGRAL_STEP_NS` of it.
                (host.saturating_sub(last) as f64).min(MAX_INTEGRAL_STEP_NS)
            }
        };
        let e = self.filtered;
        // Integral: learn the frequency error. While the slew runs at its limit (a large
        // offset being removed) the integral holds, or it would wind up and overshoot once the
        // offset is gone; it still learns if the offset keeps growing all the same (the
        // frequency error is beyond what the slew can follow), so no error can lock it out.
        let saturated = e.abs() > slew_saturation;
        let integrate = if saturated {
            let best = self.saturated_best.get_or_insert(e.abs());
            *best = best.min(e.abs());
            e.abs() > *best + slew_saturation
        } else {
            self.saturated_best = None;
            true
        };
        if integrate && dt > 0.0 {
            let e_i = e.clamp(-slew_saturation, slew_saturation);
            self.correction = (self.correction - e_i * dt / (phase_tau * frequency_tau))
                .clamp(-MAX_CORRECTION, MAX_CORRECTION);
        }
        // Proportional: slew the measured offset out (it replaces what was still pending: the
        // new measurement already includes it).
        self.slew = -e;
        self.slew_rate = (e.abs() / phase_tau).min(MAX_SLEW);
        self.last_compare_host = Some(host);
        self.filtered_difference()
    }
}

/// Encode a signed time difference as register 0x092C: bit 31 set when the local copy is
/// smaller than the received time, magnitude in bits 0..=30 (saturated).
pub fn encode_time_difference(diff: i64) -> u32 {
    let mag = diff.unsigned_abs().min(0x7fff_ffff) as u32;
    if diff < 0 {
        mag | 0x8000_0000
    } else {
        mag
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drift_scales_the_clock() {
        let c = DcClock::new(1_000, 0, 100.0);
        assert_eq!(c.local(1_000_000_000 + 1_000), 1_000_100_000);
    }

    #[test]
    fn loop_converges_to_the_reference() {
        // Reference runs at host rate; this clock drifts +80 ppm and starts 3 µs ahead.
        let mut c = DcClock::new(0, 3_000, 80.0);
        let mut host = 0u64;
        let mut last = 0i64;
        // One compare per ms for 1 s: ten time constants of the loop.
        for _ in 0..1_000 {
            host += 1_000_000;
            let diff = c.local(host) as i64 - host as i64;
            c.compare(host, diff, 4, DEFAULT_SPEED_COUNTER_START);
            last = diff;
        }
        assert!(last.abs() < 20, "residual {last} ns");
        assert!(
            (c.correction_ppm() + 80.0).abs() < 1.0,
            "{}",
            c.correction_ppm()
        );
    }

    #[test]
    fn fast_compares_do_not_make_the_rate_jitter() {
        // IgH-style static drift compensation: a burst of compares 30 µs apart.
        let mut c = DcClock::new(0, 0, -35.0);
        let mut host = 0u64;
        for _ in 0..20_000 {
            host += 30_000;
            let diff = c.local(host) as i64 - host as i64;
            c.compare(host, diff, 4, DEFAULT_SPEED_COUNTER_START);
        }
        assert!(
            (c.correction_ppm() - 35.0).abs() < 2.0,
            "{}",
            c.correction_ppm()
        );
        let diff = c.local(host + 30_000) as i64 - (host + 30_000) as i64;
        assert!(diff.abs() < 10, "{diff}");
    }

    /// Deterministic noise in [0, 1) (xorshift), so the tests need no random crate.
    fn noise(state: &mut u64) -> f64 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    /// "Reference follows master": the written time is stamped before the frame leaves and
    /// arrives 10..40 µs later, 1 in 50 frames another 0..1 ms later (a scheduling spike). The
    /// clock drifts +50 ppm and starts 60 µs ahead. Returns (peak |correction| in ppm, final
    /// correction in ppm, worst distance in ns from the mean lag over the second half).
    fn noisy_reference(depth: u8, speed_counter_start: u16) -> (f64, f64, f64) {
        let mut c = DcClock::new(0, 60_000, 50.0);
        let mut rng = 0x9E37_79B9_7F4A_7C15u64;
        let cycle = 400_000u64;
        let mut peak = 0.0f64;
        let mut errors = Vec::new();
        let mut last_arrival = 0u64;
        for k in 0..20_000u64 {
            let written = k * cycle;
            let mut lag = 10_000 + (30_000.0 * noise(&mut rng)) as u64;
            if noise(&mut rng) < 0.02 {
                lag += (1_000_000.0 * noise(&mut rng)) as u64;
            }
            // A late frame holds up the next ones (frames never overtake).
            let arrival = (written + lag).max(last_arrival + 5_000);
            last_arrival = arrival;
            let diff = c.local(arrival) as i64 - written as i64;
            c.compare(arrival, diff, depth, speed_counter_start);
            peak = peak.max(c.correction_ppm().abs());
            if k >= 10_000 {
                // Against the master's time at a spike-free arrival (mean lag 25 µs).
                let on_time = written + 25_000;
                errors.push(c.local(on_time) as f64 - on_time as f64 + 25_000.0);
            }
        }
        let worst = errors.iter().fold(0.0f64, |m, e| m.max(e.abs()));
        (peak, c.correction_ppm(), worst)
    }

    #[test]
    fn noisy_writes_lock_without_saturating() {
        // With the ESC's defaults: locked, though the speed moves more.
        let (peak, last, worst) = noisy_reference(4, DEFAULT_SPEED_COUNTER_START);
        assert!(peak < 300.0, "correction reached {peak} ppm");
        assert!((last + 50.0).abs() < 30.0, "{last} ppm");
        assert!(worst < 20_000.0, "wandered {worst} ns");
        // As the master sets up a reference that follows its time: steady.
        let (peak, last, worst) = noisy_reference(6, 0x7FFF);
        assert!(peak < 150.0, "correction reached {peak} ppm");
        assert!((last + 50.0).abs() < 5.0, "{last} ppm");
        assert!(worst < 3_000.0, "wandered {worst} ns");
    }

    #[test]
    fn large_offset_is_slewed_out_without_windup() {
        // 1 ms off, no drift: the slew removes it at its maximum rate (5 s) and the integral
        // must not have learned a frequency error meanwhile (it would overshoot after).
        let mut c = DcClock::new(0, 1_000_000, 0.0);
        let mut host = 0u64;
        let mut diff = 0i64;
        for _ in 0..20_000 {
            host += 400_000;
            diff = c.local(host) as i64 - host as i64;
            c.compare(host, diff, 4, DEFAULT_SPEED_COUNTER_START);
            assert!(diff > -10_000, "overshoot to {diff} ns");
        }
        assert!(diff.abs() < 20, "residual {diff} ns");
        assert!(c.correction_ppm().abs() < 1.0, "{}", c.correction_ppm());
    }

    #[test]
    fn drift_beyond_the_slew_rate_is_still_learned() {
        // −300 ppm: more than the slew alone can follow; the integral must take over.
        let mut c = DcClock::new(0, 0, -300.0);
        let mut host = 0u64;
        let mut diff = 0i64;
        for _ in 0..50_000 {
            host += 400_000;
            diff = c.local(host) as i64 - host as i64;
            c.compare(host, diff, 4, DEFAULT_SPEED_COUNTER_START);
        }
        assert!(diff.abs() < 20, "residual {diff} ns");
        assert!(
            (c.correction_ppm() - 300.0).abs() < 1.0,
            "{}",
            c.correction_ppm()
        );
    }

    #[test]
    fn a_pause_between_compares_does_not_kick_the_frequency() {
        let mut c = DcClock::new(0, 0, 20.0);
        let mut host = 0u64;
        for _ in 0..10_000 {
            host += 100_000;
            let diff = c.local(host) as i64 - host as i64;
            c.compare(host, diff, 4, DEFAULT_SPEED_COUNTER_START);
        }
        let learned = c.correction_ppm();
        // One second without compares, then an offset of 2 µs (e.g. a master-side error).
        host += 1_000_000_000;
        let diff = c.local(host) as i64 - host as i64 + 2_000;
        c.compare(host, diff, 4, DEFAULT_SPEED_COUNTER_START);
        assert!(
            (c.correction_ppm() - learned).abs() < 1.0,
            "{}",
            c.correction_ppm()
        );
    }

    #[test]
    fn difference_register_encoding() {
        assert_eq!(encode_time_difference(5), 5);
        assert_eq!(encode_time_difference(-5), 0x8000_0005);
        assert_eq!(encode_time_difference(i64::MIN), 0xffff_ffff);
    }
}
