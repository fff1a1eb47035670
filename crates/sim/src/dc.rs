//! Distributed clock of one virtual ESC: a local clock running from the host's monotonic clock
//! with a drift, the system-time offset, and the drift control loop driven by writes to the
//! system time register (0x0910), as the ESC's PLL does.
//!
//! The clock is a pure function of host time between "rebase" points (a compare, a drift step),
//! so reading it never changes it: `local = base_local + (t - base_host)·rate + slew`, where the
//! slew applies the last measured offset error at a bounded rate (like the real ESC, which adds
//! 9 or 11 ns instead of 10 ns per 10 ns tick until the error is gone) and `rate` carries the
//! drift and the learned frequency correction.

/// Fastest the slew can move the local clock against host time (200 ns per ms).
const MAX_SLEW: f64 = 2.0e-4;
/// Largest frequency correction the loop learns (±500 ppm).
const MAX_CORRECTION: f64 = 5.0e-4;
/// Time constant of the frequency estimate: a compare after `dt` corrects `dt / τ` of the
/// measured frequency error (at most half), so frequent compares with 1 ns quantisation
/// average out instead of making the rate jitter.
const FREQUENCY_TAU_NS: f64 = 20.0e6;
const MAX_FREQUENCY_GAIN: f64 = 0.5;

#[derive(Clone, Debug)]
pub struct DcClock {
    base_host: u64,
    base_local: f64,
    /// Clock drift of the crystal, in ppm (fault injection can step it).
    drift_ppm: f64,
    /// Frequency correction learned by the control loop (dimensionless).
    correction: f64,
    /// Offset still to be slewed in at `MAX_SLEW` from `base_host` on (ns, signed).
    slew: f64,
    /// Host time of the last compare (for the frequency estimate).
    last_compare_host: Option<u64>,
    /// Slew that was pending when the last compare happened.
    last_slew: f64,
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
            last_compare_host: None,
            last_slew: 0.0,
        }
    }

    fn rate(&self) -> f64 {
        1.0 + self.drift_ppm * 1e-6 + self.correction
    }

    /// Local time (ns) at host time `host`.
    pub fn local_f64(&self, host: u64) -> f64 {
        let dt = host as f64 - self.base_host as f64;
        let mut t = self.base_local + dt * self.rate();
        if self.slew != 0.0 {
            let needed = self.slew.abs() / MAX_SLEW;
            t += if dt <= 0.0 {
                0.0
            } else if dt >= needed {
                self.slew
            } else {
                self.slew.signum() * MAX_SLEW * dt
            };
        }
        t
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
        if self.slew != 0.0 && dt > 0.0 {
            let applied = (MAX_SLEW * dt).min(self.slew.abs());
            self.slew -= self.slew.signum() * applied;
        }
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

    /// Reset the control loop (write to the speed counter start register).
    pub fn reset_loop(&mut self, host: u64) {
        self.rebase(host);
        self.correction = 0.0;
        self.slew = 0.0;
        self.last_compare_host = None;
    }

    /// One compare of the drift control loop: `diff` = local system time − received system
    /// time (ns), measured at host time `host`. Slews the offset out and learns the frequency
    /// error once the previous slew had time to complete.
    pub fn compare(&mut self, host: u64, diff: i64) {
        self.rebase(host);
        let diff = diff as f64;
        if let Some(last) = self.last_compare_host {
            let dt = host.saturating_sub(last) as f64;
            if dt > 0.0 && self.last_slew.abs() <= MAX_SLEW * dt {
                // The previous error was fully slewed in: what is left is frequency error.
                let gain = (dt / FREQUENCY_TAU_NS).min(MAX_FREQUENCY_GAIN);
                self.correction =
                    (self.correction - gain * diff / dt).clamp(-MAX_CORRECTION, MAX_CORRECTION);
            }
        }
        self.slew = -diff;
        self.last_slew = self.slew;
        self.last_compare_host = Some(host);
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
        for _ in 0..400 {
            host += 1_000_000;
            let diff = c.local(host) as i64 - host as i64;
            c.compare(host, diff);
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
            c.compare(host, diff);
        }
        assert!(
            (c.correction_ppm() - 35.0).abs() < 2.0,
            "{}",
            c.correction_ppm()
        );
        let diff = c.local(host + 30_000) as i64 - (host + 30_000) as i64;
        assert!(diff.abs() < 10, "{diff}");
    }

    #[test]
    fn difference_register_encoding() {
        assert_eq!(encode_time_difference(5), 5);
        assert_eq!(encode_time_difference(-5), 0x8000_0005);
        assert_eq!(encode_time_difference(i64::MIN), 0xffff_ffff);
    }
}
