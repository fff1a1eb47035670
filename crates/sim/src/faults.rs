//! Fault injection: what the network does wrong on purpose, consulted for every frame, with a
//! seedable random generator so a failing test can be replayed.

/// xorshift64* — small, fast, deterministic; quality is ample for fault decisions.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator seeded with `seed`: the same seed gives the same faults.
    pub fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    /// The next pseudo-random 64-bit number (deterministic for a seed).
    pub fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// A pseudo-random number in `0..n` (0 when `n` is 0).
    pub fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next_u64() % n as u64) as usize
        }
    }
}

/// Network-wide faults (per-slave faults — refuse OP, stalled mailbox, drift — live in the
/// slave).
#[derive(Clone, Debug, Default)]
pub struct Faults {
    /// Probability that a frame starts a drop burst.
    pub drop_rate: f64,
    /// Frames dropped per burst (at least 1).
    pub drop_burst: u32,
    /// Frames still to drop of the burst in progress.
    pub drop_remaining: u32,
    /// Dropped frames are lost before reaching slave 0 (true) instead of on the way back after
    /// every slave processed them (false, the default: the master loses the answer, the slaves
    /// still got their outputs).
    pub drop_outbound: bool,
    /// Probability that an answered frame is corrupted.
    pub corrupt_rate: f64,
    /// Bytes flipped per corrupted frame (at least 1).
    pub corrupt_bytes: u32,
    /// Delay before each answer (µs).
    pub delay_us: u64,
    /// The master's link is down: no frame comes back.
    pub link_down: bool,
    /// Slaves whose port-0 link (to their parent, or the master) is down: they and everything
    /// behind them are unreachable, and the parent closes the port. In a line, a cut at slave
    /// `k` is the break between `k − 1` and `k`.
    pub cut_links: Vec<usize>,
}

impl Faults {
    /// Decide whether this frame is dropped.
    pub fn should_drop(&mut self, rng: &mut Rng) -> bool {
        if self.link_down {
            return true;
        }
        if self.drop_remaining > 0 {
            self.drop_remaining -= 1;
            return true;
        }
        if self.drop_rate > 0.0 && rng.unit() < self.drop_rate {
            self.drop_remaining = self.drop_burst.max(1) - 1;
            return true;
        }
        false
    }

    /// Corrupt an answered frame in place (EtherCAT payload only, so it still reaches the
    /// master and is seen as garbage or a wrong working counter). Returns true if it did.
    pub fn maybe_corrupt(&mut self, rng: &mut Rng, frame: &mut [u8]) -> bool {
        const START: usize = 16;
        if self.corrupt_rate <= 0.0 || frame.len() <= START || rng.unit() >= self.corrupt_rate {
            return false;
        }
        for _ in 0..self.corrupt_bytes.max(1) {
            let i = START + rng.below(frame.len() - START);
            frame[i] ^= 1 << rng.below(8);
        }
        true
    }
}
