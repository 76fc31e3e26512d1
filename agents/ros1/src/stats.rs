//! Rate statistics over a sliding window of message arrivals, computed as
//! `rostopic hz` does (1 / mean inter-arrival), plus inter-arrival spread, a
//! low percentile of per-second rates, and bytes per second. Pure: arrival
//! times are plain seconds supplied by the caller.

use std::collections::VecDeque;

use configbot_dataplane::TopicStats;

/// Arrivals within the last `window_s` seconds.
#[derive(Debug, Clone)]
pub struct RateWindow {
    window_s: f64,
    samples: VecDeque<(f64, usize)>,
}

impl RateWindow {
    pub fn new(window_s: f64) -> Self {
        Self {
            window_s,
            samples: VecDeque::new(),
        }
    }

    /// Records a message of `bytes` at time `t` (seconds, monotonic).
    pub fn record(&mut self, t: f64, bytes: usize) {
        self.samples.push_back((t, bytes));
        self.trim(t);
    }

    fn trim(&mut self, now: f64) {
        while self
            .samples
            .front()
            .is_some_and(|(t, _)| now - t > self.window_s)
        {
            self.samples.pop_front();
        }
    }

    /// Statistics as of `now`; None with fewer than 3 messages in the window.
    pub fn stats(&mut self, now: f64) -> Option<TopicStats> {
        self.trim(now);
        let n = self.samples.len();
        if n < 3 {
            return None;
        }
        let ts: Vec<f64> = self.samples.iter().map(|s| s.0).collect();
        let deltas: Vec<f64> = ts.windows(2).map(|w| w[1] - w[0]).collect();
        let mean = deltas.iter().sum::<f64>() / deltas.len() as f64;
        if mean <= 0.0 {
            return None;
        }
        let var = deltas.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / deltas.len() as f64;
        let min = deltas.iter().copied().fold(f64::INFINITY, f64::min);
        let max = deltas.iter().copied().fold(0.0, f64::max);
        let span = ts[n - 1] - ts[0];
        // bytes of all but the first message over the span they arrived in
        let bytes: usize = self.samples.iter().skip(1).map(|s| s.1).sum();
        Some(TopicStats {
            rate_hz: 1.0 / mean,
            min_interval_s: min,
            max_interval_s: max,
            stddev_interval_s: var.sqrt(),
            low_rate_hz: low_percentile_rate(&ts, now, 0.05).unwrap_or(1.0 / mean),
            bytes_per_s: if span > 0.0 { bytes as f64 / span } else { 0.0 },
            samples: n,
            window_s: span,
        })
    }
}

/// The `p` quantile of message counts in whole one-second bins ending at
/// `now` and starting no earlier than the first arrival.
pub fn low_percentile_rate(ts: &[f64], now: f64, p: f64) -> Option<f64> {
    let first = *ts.first()?;
    let bins = (now - first).floor() as usize;
    if bins < 2 {
        return None;
    }
    let mut counts = vec![0usize; bins];
    for t in ts {
        let back = now - t;
        let i = back.floor() as usize;
        if i < bins {
            counts[i] += 1;
        }
    }
    counts.sort_unstable();
    let idx = ((bins as f64 - 1.0) * p).round() as usize;
    Some(counts[idx.min(bins - 1)] as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steady_30hz() {
        let mut w = RateWindow::new(10.0);
        for i in 0..=300 {
            w.record(i as f64 / 30.0, 100);
        }
        let s = w.stats(10.0).unwrap();
        assert!((s.rate_hz - 30.0).abs() < 1e-6, "{s:?}");
        assert!(s.stddev_interval_s < 1e-9);
        assert!((s.bytes_per_s - 3000.0).abs() < 1.0, "{s:?}");
        assert!((29.0..=31.0).contains(&s.low_rate_hz), "{s:?}");
    }

    #[test]
    fn gap_lowers_low_percentile_and_raises_max() {
        let mut w = RateWindow::new(100.0);
        let mut t = 0.0;
        for _ in 0..200 {
            w.record(t, 10);
            t += 0.05;
        }
        t += 3.0; // silence
        for _ in 0..200 {
            w.record(t, 10);
            t += 0.05;
        }
        let s = w.stats(t).unwrap();
        assert!(s.max_interval_s > 3.0);
        assert_eq!(s.low_rate_hz, 0.0);
        assert!(s.rate_hz < 20.0 && s.rate_hz > 10.0, "{s:?}");
    }

    #[test]
    fn old_samples_leave_the_window() {
        let mut w = RateWindow::new(1.0);
        for i in 0..10 {
            w.record(i as f64 * 0.1, 1);
        }
        assert!(w.stats(0.95).is_some());
        assert!(w.stats(5.0).is_none());
    }
}
