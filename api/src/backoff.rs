//! The one retry backoff of the controller and the agent (reconcile requeues,
//! the tuning runner's retries, the agent's restarts of crashed nodes, the
//! ROS 1 data plane's publisherUpdate retries and upstream reconnects):
//! exponential from a base delay, capped, with optional ± jitter drawn from
//! an injected [`Jitter`] source so tests can pin it. Pure: it computes
//! durations; the caller sleeps.

use std::time::Duration;

/// A source of jitter: samples spread evenly over `[0, 1]`. Any
/// `FnMut() -> f64` is one (tests pass `|| 0.0` or `|| 1.0`).
pub trait Jitter {
    /// The next sample, in `[0, 1]` (values outside are clamped).
    fn sample(&mut self) -> f64;
}

impl<F: FnMut() -> f64> Jitter for F {
    fn sample(&mut self) -> f64 {
        self()
    }
}

/// A seeded xorshift64 generator: cheap, deterministic per seed, good
/// enough to spread retries apart.
#[derive(Debug, Clone)]
pub struct XorShift(u64);

impl XorShift {
    const DEFAULT_SEED: u64 = 0x9E37_79B9_7F4A_7C15;

    /// A generator from `seed` (0, which xorshift never leaves, is replaced).
    pub fn new(seed: u64) -> Self {
        Self(if seed == 0 { Self::DEFAULT_SEED } else { seed })
    }

    /// The next raw 64-bit value (also a seed for another generator).
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

impl Default for XorShift {
    fn default() -> Self {
        Self::new(Self::DEFAULT_SEED)
    }
}

impl Jitter for XorShift {
    fn sample(&mut self) -> f64 {
        (self.next_u64() % 501) as f64 / 500.0
    }
}

/// Exponential backoff: `initial`, doubling per call of [`Backoff::next_delay`],
/// capped at `max`; [`Backoff::reset`] after a success starts over. With a
/// jitter spread `s`, each delay is its base times a factor in
/// `[1 - s, 1 + s]`, and still never above `max`.
#[derive(Debug, Clone)]
pub struct Backoff<J = XorShift> {
    initial: Duration,
    max: Duration,
    spread: f64,
    attempt: u32,
    jitter: J,
}

impl Backoff {
    /// Without jitter: `initial`, `2 × initial`, `4 × initial`, … up to `max`.
    pub fn new(initial: Duration, max: Duration) -> Self {
        Self::jittered(initial, max, 0.0, XorShift::default())
    }
}

impl<J: Jitter> Backoff<J> {
    /// With `± spread` jitter (0.25: each delay is 0.75 to 1.25 times its
    /// base) drawn from `jitter`.
    pub fn jittered(initial: Duration, max: Duration, spread: f64, jitter: J) -> Self {
        Self {
            initial,
            max,
            spread: spread.clamp(0.0, 1.0),
            attempt: 0,
            jitter,
        }
    }

    /// The delay before the next retry; each call doubles the base.
    pub fn next_delay(&mut self) -> Duration {
        let base = self
            .initial
            .saturating_mul(1u32 << self.attempt.min(20))
            .min(self.max);
        self.attempt = self.attempt.saturating_add(1);
        if self.spread == 0.0 {
            return base;
        }
        let unit = self.jitter.sample().clamp(0.0, 1.0);
        base.mul_f64(1.0 - self.spread + 2.0 * self.spread * unit)
            .min(self.max)
    }

    /// Starts over from `initial` (after a success, or a healthy run).
    pub fn reset(&mut self) {
        self.attempt = 0;
    }

    /// How many delays were handed out since the start or the last reset.
    pub fn attempts(&self) -> u32 {
        self.attempt
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(d: Duration) -> u128 {
        d.as_millis()
    }

    #[test]
    fn without_jitter_it_doubles_caps_and_resets() {
        let mut b = Backoff::new(Duration::from_millis(100), Duration::from_millis(1000));
        let got: Vec<u128> = (0..6).map(|_| ms(b.next_delay())).collect();
        assert_eq!(got, [100, 200, 400, 800, 1000, 1000]);
        assert_eq!(b.attempts(), 6);
        b.reset();
        assert_eq!((b.attempts(), ms(b.next_delay())), (0, 100));
        for _ in 0..100 {
            b.next_delay();
        }
        assert_eq!(ms(b.next_delay()), 1000);
    }

    #[test]
    fn jitter_spans_the_spread_around_the_base_and_never_passes_the_cap() {
        let (initial, max) = (Duration::from_millis(800), Duration::from_secs(30));
        let table: [(f64, [u128; 7]); 3] = [
            // lowest sample: 0.75 × base
            (0.0, [600, 1200, 2400, 4800, 9600, 19200, 22500]),
            // middle: the base itself
            (0.5, [800, 1600, 3200, 6400, 12800, 25600, 30000]),
            // highest: 1.25 × base, cut at the cap
            (1.0, [1000, 2000, 4000, 8000, 16000, 30000, 30000]),
        ];
        for (sample, want) in table {
            let mut b = Backoff::jittered(initial, max, 0.25, move || sample);
            let got: Vec<u128> = (0..7).map(|_| ms(b.next_delay())).collect();
            assert_eq!(got, want, "sample {sample}");
        }
        // Samples out of range are clamped.
        let mut b = Backoff::jittered(initial, max, 0.25, || 7.0);
        assert_eq!(ms(b.next_delay()), 1000);
    }

    #[test]
    fn the_jitter_source_is_asked_once_per_delay() {
        let mut samples = [0.0, 1.0, 0.5].into_iter();
        let mut b = Backoff::jittered(
            Duration::from_secs(1),
            Duration::from_secs(60),
            0.5,
            move || samples.next().unwrap_or(0.5),
        );
        let got: Vec<u128> = (0..4).map(|_| ms(b.next_delay())).collect();
        assert_eq!(got, [500, 3000, 4000, 8000]);
    }

    #[test]
    fn xorshift_is_deterministic_in_range_and_spread_out() {
        let (mut a, mut b) = (XorShift::new(42), XorShift::new(42));
        let xs: Vec<f64> = (0..1000).map(|_| a.sample()).collect();
        let ys: Vec<f64> = (0..1000).map(|_| b.sample()).collect();
        assert_eq!(xs, ys);
        assert!(xs.iter().all(|x| (0.0..=1.0).contains(x)));
        let low = xs.iter().filter(|x| **x < 0.5).count();
        assert!((400..600).contains(&low), "{low} of 1000 below 0.5");
        assert_ne!(XorShift::new(0).next_u64(), 0);
        assert_ne!(XorShift::new(1).next_u64(), XorShift::new(2).next_u64());
    }
}
