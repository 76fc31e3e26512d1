//! CPU statistics of one cgroup and the parsers for `cpu.stat` and `cpu.pressure`.

use serde::{Deserialize, Serialize};

/// Cumulative CPU counters of a cgroup (monotonic while it exists).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct CpuStats {
    /// CPU time used, ns (v1 `cpuacct.usage`, v2 `usage_usec` x 1000).
    pub usage_ns: u64,
    /// Enforcement periods that elapsed while the group was runnable.
    pub nr_periods: u64,
    /// Periods in which the group was throttled.
    pub nr_throttled: u64,
    /// Total time throttled, ns.
    pub throttled_ns: u64,
    /// v2 PSI (`cpu.pressure`), `None` on v1.
    pub pressure: Option<Pressure>,
}

/// The `some` line of v2 `cpu.pressure`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Pressure {
    pub avg10: f64,
    pub avg60: f64,
    pub avg300: f64,
    /// Total stall time, µs.
    pub total_us: u64,
}

/// Parses `key value` lines (`cpu.stat`) into `(key, value)` pairs.
pub(crate) fn parse_flat_keyed(text: &str) -> impl Iterator<Item = (&str, u64)> {
    text.lines().filter_map(|l| {
        let mut it = l.split_whitespace();
        let k = it.next()?;
        let v = it.next()?.parse().ok()?;
        Some((k, v))
    })
}

/// Fills throttling counters from a v1 or v2 `cpu.stat`; `v2` selects the unit of throttled time.
pub(crate) fn apply_cpu_stat(stats: &mut CpuStats, text: &str, v2: bool) {
    for (k, v) in parse_flat_keyed(text) {
        match k {
            "nr_periods" => stats.nr_periods = v,
            "nr_throttled" => stats.nr_throttled = v,
            "throttled_time" if !v2 => stats.throttled_ns = v,
            "throttled_usec" if v2 => stats.throttled_ns = v.saturating_mul(1000),
            "usage_usec" if v2 => stats.usage_ns = v.saturating_mul(1000),
            _ => {}
        }
    }
}

/// Parses the `some` line of a PSI file.
pub(crate) fn parse_pressure(text: &str) -> Option<Pressure> {
    let line = text.lines().find(|l| l.starts_with("some "))?;
    let mut p = Pressure::default();
    for kv in line.split_whitespace().skip(1) {
        let (k, v) = kv.split_once('=')?;
        match k {
            "avg10" => p.avg10 = v.parse().ok()?,
            "avg60" => p.avg60 = v.parse().ok()?,
            "avg300" => p.avg300 = v.parse().ok()?,
            "total" => p.total_us = v.parse().ok()?,
            _ => {}
        }
    }
    Some(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_v1_and_v2_cpu_stat() {
        let mut s = CpuStats::default();
        apply_cpu_stat(
            &mut s,
            "nr_periods 10\nnr_throttled 4\nthrottled_time 5000\nnr_bursts 0\n",
            false,
        );
        assert_eq!(
            (s.nr_periods, s.nr_throttled, s.throttled_ns),
            (10, 4, 5000)
        );
        let mut s = CpuStats::default();
        apply_cpu_stat(
            &mut s,
            "usage_usec 1500\nuser_usec 1000\nsystem_usec 500\nnr_periods 7\nnr_throttled 2\nthrottled_usec 30\n",
            true,
        );
        assert_eq!(
            (s.usage_ns, s.nr_periods, s.nr_throttled, s.throttled_ns),
            (1_500_000, 7, 2, 30_000)
        );
    }

    #[test]
    fn parses_pressure() {
        let p = parse_pressure(
            "some avg10=1.50 avg60=0.20 avg300=0.00 total=12345\nfull avg10=0.00 avg60=0.00 avg300=0.00 total=0\n",
        )
        .unwrap();
        assert_eq!(p.avg10, 1.5);
        assert_eq!(p.total_us, 12345);
        assert!(parse_pressure("garbage").is_none());
    }
}
