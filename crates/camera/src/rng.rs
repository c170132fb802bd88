//! Deterministic, thread-count-independent random streams: one PCG generator per (seed, frame,
//! row), keyed through SplitMix64 so neighbouring keys give unrelated streams.

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

/// SplitMix64 finalizer.
#[inline]
pub fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The generator for one stream of a seed (e.g. `stream(seed, row, phase)`).
pub fn stream(seed: u64, a: u64, b: u64) -> Pcg64Mcg {
    Pcg64Mcg::seed_from_u64(mix(mix(mix(seed) ^ a) ^ b.rotate_left(32)))
}

/// Key reserved for per-frame draws (f, the read-noise map) so they never collide with rows.
pub const FRAME_KEY: u64 = u64::MAX;
