//! Seeded pseudo-random numbers for the simulators: SplitMix64 (Steele,
//! Lea & Flood 2014), so that a scenario and a seed give the same flight on
//! every machine and thread count.

use std::f64::consts::PI;

/// A SplitMix64 stream.
#[derive(Debug, Clone)]
pub struct Random(u64);

impl Random {
    /// A stream started from `seed`.
    pub fn new(seed: u64) -> Self {
        Random(seed)
    }

    /// An independent stream for a named purpose, so that adding a draw in
    /// one part of the simulator does not shift every other part.
    pub fn fork(&self, purpose: &str) -> Random {
        let salt = purpose.bytes().fold(0xCBF2_9CE4_8422_2325u64, |h, b| {
            (h ^ b as u64).wrapping_mul(0x100_0000_01B3)
        });
        let mut child = Random(self.0 ^ salt);
        child.next_u64();
        child
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [low, high).
    pub fn uniform(&mut self, low: f64, high: f64) -> f64 {
        low + (high - low) * (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform integer in the inclusive range [low, high].
    pub fn integer(&mut self, low: usize, high: usize) -> usize {
        low + (self.next_u64() % (high - low + 1) as u64) as usize
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let u = self.uniform(f64::MIN_POSITIVE, 1.0);
        let v = self.uniform(0.0, 1.0);
        (-2.0 * u.ln()).sqrt() * (2.0 * PI * v).cos()
    }

    /// A vector of three uniform draws in [-scale, scale).
    pub fn vector(&mut self, scale: f64) -> [f64; 3] {
        [0, 1, 2].map(|_| scale * self.uniform(-1.0, 1.0))
    }
}
