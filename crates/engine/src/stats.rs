//! Counters and histograms the RT thread updates every cycle and Python reads at any time.
//!
//! Histograms are log-linear: values below 32 ns have a bucket each; above, every power of two is
//! split into 32 equal buckets, so a bucket's width is at most 1/32 (3 %) of its value and the
//! whole range of u64 fits in 1920 fixed counters. Updating one is a handful of relaxed atomic
//! adds: no allocation, no lock.

use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

const SUB_BITS: u32 = 5;
const SUB: usize = 1 << SUB_BITS;
/// Number of buckets covering all of u64.
pub const BUCKETS: usize = (64 - SUB_BITS as usize + 1) * SUB;

/// Bucket holding `v`.
pub fn bucket_of(v: u64) -> usize {
    if v < SUB as u64 {
        return v as usize;
    }
    let msb = 63 - v.leading_zeros();
    let shift = msb - SUB_BITS;
    let sub = ((v >> shift) as usize) & (SUB - 1);
    (shift as usize + 1) * SUB + sub
}

/// Smallest value that falls in bucket `i`.
pub fn bucket_low(i: usize) -> u64 {
    if i < SUB {
        return i as u64;
    }
    let shift = (i / SUB - 1) as u32;
    ((SUB + i % SUB) as u64) << shift
}

/// Width of bucket `i`.
fn bucket_width(i: usize) -> u64 {
    if i < SUB {
        1
    } else {
        1u64 << (i / SUB - 1)
    }
}

/// A lock-free histogram of durations (ns) with logarithmic buckets: the RT thread records,
/// any thread reads a summary.
pub struct Histogram {
    buckets: Box<[AtomicU64]>,
    count: AtomicU64,
    sum: AtomicU64,
    min: AtomicU64,
    max: AtomicU64,
}

/// A histogram's summary in ns.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Summary {
    /// Values recorded.
    pub count: u64,
    /// Smallest value.
    pub min: u64,
    /// Largest value.
    pub max: u64,
    /// Mean value.
    pub mean: f64,
    /// Median (bucket resolution).
    pub p50: u64,
    /// 99th percentile.
    pub p99: u64,
    /// 99.9th percentile.
    pub p999: u64,
}

impl Default for Histogram {
    fn default() -> Self {
        Histogram {
            buckets: (0..BUCKETS).map(|_| AtomicU64::new(0)).collect(),
            count: AtomicU64::new(0),
            sum: AtomicU64::new(0),
            min: AtomicU64::new(u64::MAX),
            max: AtomicU64::new(0),
        }
    }
}

impl Histogram {
    /// Record one value (RT thread: the only writer).
    pub fn record(&self, v: u64) {
        self.buckets[bucket_of(v)].fetch_add(1, Relaxed);
        self.count.fetch_add(1, Relaxed);
        self.sum.fetch_add(v, Relaxed);
        if v < self.min.load(Relaxed) {
            self.min.store(v, Relaxed);
        }
        if v > self.max.load(Relaxed) {
            self.max.store(v, Relaxed);
        }
    }

    /// Forget every value recorded.
    pub fn reset(&self) {
        for b in self.buckets.iter() {
            b.store(0, Relaxed);
        }
        self.count.store(0, Relaxed);
        self.sum.store(0, Relaxed);
        self.min.store(u64::MAX, Relaxed);
        self.max.store(0, Relaxed);
    }

    /// Summary with percentiles at bucket midpoints, clamped to the observed min/max.
    pub fn summary(&self) -> Summary {
        let counts: Vec<u64> = self.buckets.iter().map(|b| b.load(Relaxed)).collect();
        let total: u64 = counts.iter().sum();
        if total == 0 {
            return Summary::default();
        }
        let min = self.min.load(Relaxed);
        let max = self.max.load(Relaxed);
        let quantile = |q: f64| -> u64 {
            let rank = ((q * total as f64).ceil() as u64).clamp(1, total);
            let mut seen = 0;
            for (i, &c) in counts.iter().enumerate() {
                seen += c;
                if seen >= rank {
                    let mid = bucket_low(i) + bucket_width(i) / 2;
                    return mid.clamp(min.min(max), max);
                }
            }
            max
        };
        Summary {
            count: total,
            min: min.min(max),
            max,
            mean: self.sum.load(Relaxed) as f64 / total as f64,
            p50: quantile(0.5),
            p99: quantile(0.99),
            p999: quantile(0.999),
        }
    }
}

/// Event counters of the cyclic exchange (monotonic until `reset`).
#[derive(Default)]
pub struct Counters {
    /// Cycles run.
    pub cycles: AtomicU64,
    /// Cyclic frames whose reply did not come back.
    pub lost_frames: AtomicU64,
    /// Cyclic replies that came back after their cycle.
    pub late_frames: AtomicU64,
    /// Frames received that match no frame sent.
    pub unmatched_frames: AtomicU64,
    /// Replies with a working counter other than expected.
    pub wkc_errors: AtomicU64,
    /// Times the output watchdog stopped the outputs.
    pub watchdog_trips: AtomicU64,
    /// Panic stops.
    pub panics: AtomicU64,
    /// Cycles that took longer than the cycle time.
    pub overruns: AtomicU64,
    /// Frames the link failed to send.
    pub send_errors: AtomicU64,
    /// Acyclic frames passed through the cycle.
    pub acyclic_frames: AtomicU64,
    /// Acyclic frames without an answer in time.
    pub acyclic_timeouts: AtomicU64,
    /// Samples Python did not take in time (the ring was full).
    pub samples_dropped: AtomicU64,
}

impl Counters {
    /// (name, counter) pairs, in the order `stats()` reports them.
    pub fn named(&self) -> [(&'static str, &AtomicU64); 12] {
        [
            ("cycles", &self.cycles),
            ("lost_frames", &self.lost_frames),
            ("late_frames", &self.late_frames),
            ("unmatched_frames", &self.unmatched_frames),
            ("wkc_errors", &self.wkc_errors),
            ("watchdog_trips", &self.watchdog_trips),
            ("panics", &self.panics),
            ("overruns", &self.overruns),
            ("send_errors", &self.send_errors),
            ("acyclic_frames", &self.acyclic_frames),
            ("acyclic_timeouts", &self.acyclic_timeouts),
            ("samples_dropped", &self.samples_dropped),
        ]
    }

    /// Set every counter to 0.
    pub fn reset(&self) {
        for (_, c) in self.named() {
            c.store(0, Relaxed);
        }
    }
}

/// Counters and round trip of one cyclic frame (one per frame of the plan, allocated with
/// the run's exchange).
#[derive(Default)]
pub struct FrameStats {
    /// Times the frame went out.
    pub sent: AtomicU64,
    /// Times the frame's reply did not come back.
    pub lost: AtomicU64,
    /// Times the frame's reply came back after its cycle.
    pub late: AtomicU64,
    /// Replies with a logical datagram's working counter other than expected.
    pub wkc_errors: AtomicU64,
    /// Sum of the logical working counters of the last reply.
    pub last_wkc: AtomicU64,
    /// Times the frame's own (group) watchdog tripped.
    pub watchdog_trips: AtomicU64,
    /// The frame's round trip.
    pub rtt: Histogram,
    /// Freshness (kept by `reset`: it is state, not a count): 1 + the cycle whose reply last
    /// came back whole (every working counter as expected; 0: none yet), and when it arrived
    /// (CLOCK_MONOTONIC ns).
    pub last_good_cycle: AtomicU64,
    /// When that reply arrived (CLOCK_MONOTONIC ns).
    pub last_good_ns: AtomicU64,
}

impl FrameStats {
    /// The counters by name, for the snapshot.
    pub fn named(&self) -> [(&'static str, &AtomicU64); 6] {
        [
            ("sent", &self.sent),
            ("lost", &self.lost),
            ("late", &self.late),
            ("wkc_errors", &self.wkc_errors),
            ("last_wkc", &self.last_wkc),
            ("watchdog_trips", &self.watchdog_trips),
        ]
    }

    /// Set the counters to 0 (the freshness stays: it is state).
    pub fn reset(&self) {
        for (_, c) in self.named() {
            c.store(0, Relaxed);
        }
        self.rtt.reset();
    }
}

/// Everything `stats()` reports.
#[derive(Default)]
pub struct Stats {
    /// Event counters.
    pub counters: Counters,
    /// Actual minus planned wake-up.
    pub wake_latency: Histogram,
    /// Wake-up to cyclic frame sent.
    pub exec: Histogram,
    /// Time between wake-ups.
    pub period: Histogram,
    /// Round trip of the cyclic frames.
    pub rtt: Histogram,
    /// Time inside the link's send call for the cyclic frame (part of `exec`).
    pub send: Histogram,
}

impl Stats {
    /// The histograms by name, for the snapshot.
    pub fn histograms(&self) -> [(&'static str, &Histogram); 5] {
        [
            ("wake_latency", &self.wake_latency),
            ("exec", &self.exec),
            ("period", &self.period),
            ("rtt", &self.rtt),
            ("send", &self.send),
        ]
    }

    /// Reset every counter and histogram.
    pub fn reset(&self) {
        self.counters.reset();
        for (_, h) in self.histograms() {
            h.reset();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_cover_values_in_order() {
        let mut last = 0;
        for v in (0..100_000u64).chain([u64::MAX / 3, u64::MAX]) {
            let b = bucket_of(v);
            assert!(b < BUCKETS);
            assert!(b >= last, "bucket order breaks at {v}");
            last = b;
            assert!(bucket_low(b) <= v);
            assert!(v - bucket_low(b) < bucket_width(b));
        }
    }

    #[test]
    fn percentiles_are_within_a_bucket() {
        let h = Histogram::default();
        for v in 1..=10_000u64 {
            h.record(v * 100);
        }
        let s = h.summary();
        assert_eq!(s.count, 10_000);
        assert_eq!(s.min, 100);
        assert_eq!(s.max, 1_000_000);
        let close = |got: u64, want: f64| ((got as f64 - want) / want).abs() < 0.04;
        assert!(close(s.p50, 500_000.0), "p50 {}", s.p50);
        assert!(close(s.p99, 990_000.0), "p99 {}", s.p99);
        assert!(close(s.p999, 999_000.0), "p999 {}", s.p999);
        assert!((s.mean - 500_050.0).abs() < 1.0);
        h.reset();
        assert_eq!(h.summary(), Summary::default());
    }
}
