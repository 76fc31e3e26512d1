//! CPU limits: the user's view ([`CpuLimit`], in CPUs) and the kernel's
//! ([`CpuMax`], quota and period in microseconds), with the v1/v2 file formats.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The kernel's default CFS period (100 ms).
pub const DEFAULT_PERIOD_US: u64 = 100_000;
/// Smallest period the kernel accepts (1 ms).
pub const MIN_PERIOD_US: u64 = 1_000;
/// Largest period the kernel accepts (1 s).
pub const MAX_PERIOD_US: u64 = 1_000_000;
/// Smallest quota the kernel accepts (1 ms).
pub const MIN_QUOTA_US: u64 = 1_000;
/// A sanity bound on a limit; far above any robot's core count.
const MAX_CPUS: f64 = 1024.0;

/// A node's CPU setting as configured: a limit (`cpus = None` means
/// unlimited) and a weight against the subtree's other nodes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct CpuLimit {
    /// CPUs the node may use per period (e.g. 0.35); `None` = unlimited.
    pub cpus: Option<f64>,
    /// CFS period in microseconds; a short period keeps fast loops from
    /// being frozen for a whole 100 ms window.
    #[serde(default = "default_period")]
    pub period_us: u64,
    /// Share of a busy CPU against the other nodes of the subtree: when
    /// nodes compete, each gets CPU in proportion to its weight.
    #[serde(default)]
    pub weight: CpuWeight,
}

fn default_period() -> u64 {
    DEFAULT_PERIOD_US
}

impl CpuLimit {
    /// No limit, default period.
    pub const UNLIMITED: CpuLimit = CpuLimit {
        cpus: None,
        period_us: DEFAULT_PERIOD_US,
        weight: CpuWeight::DEFAULT,
    };

    /// A limit of `cpus` CPUs with the default period.
    pub fn cpus(cpus: f64) -> Self {
        Self {
            cpus: Some(cpus),
            ..Self::UNLIMITED
        }
    }

    /// Validates and converts to the kernel's quota/period; `node` names the error.
    pub fn to_cpu_max(&self, node: &str) -> Result<CpuMax> {
        let bad = |reason: String| Error::InvalidLimit {
            node: node.to_owned(),
            reason,
        };
        if !(MIN_PERIOD_US..=MAX_PERIOD_US).contains(&self.period_us) {
            return Err(bad(format!(
                "period {} us outside {MIN_PERIOD_US}..={MAX_PERIOD_US}",
                self.period_us
            )));
        }
        let quota_us = match self.cpus {
            None => None,
            Some(c) if !c.is_finite() || c <= 0.0 || c > MAX_CPUS => {
                return Err(bad(format!("cpus {c} must be in (0, {MAX_CPUS}]")));
            }
            Some(c) => {
                // Bounded above by MAX_CPUS * MAX_PERIOD_US, so the cast is exact enough.
                #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
                let q = (c * self.period_us as f64).round() as u64;
                if q < MIN_QUOTA_US {
                    return Err(bad(format!(
                        "cpus {c} x period {} us = quota {q} us, below the kernel minimum {MIN_QUOTA_US} us",
                        self.period_us
                    )));
                }
                Some(q)
            }
        };
        Ok(CpuMax {
            quota_us,
            period_us: self.period_us,
        })
    }
}

/// The kernel's view of a limit: quota (`None` = unlimited) and period, in µs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct CpuMax {
    pub quota_us: Option<u64>,
    pub period_us: u64,
}

impl CpuMax {
    /// The limit back in CPUs (at the default weight).
    pub fn to_limit(self) -> CpuLimit {
        CpuLimit {
            #[allow(clippy::cast_precision_loss)]
            cpus: self.quota_us.map(|q| q as f64 / self.period_us as f64),
            period_us: self.period_us,
            weight: CpuWeight::DEFAULT,
        }
    }

    /// The v2 `cpu.max` line, e.g. `max 100000` or `20000 100000`.
    pub fn to_v2(self) -> String {
        match self.quota_us {
            None => format!("max {}", self.period_us),
            Some(q) => format!("{q} {}", self.period_us),
        }
    }

    /// Parses a v2 `cpu.max` line.
    pub fn parse_v2(text: &str) -> Option<Self> {
        let mut it = text.split_whitespace();
        let quota = it.next()?;
        let period_us = it.next()?.parse().ok()?;
        if it.next().is_some() {
            return None;
        }
        let quota_us = match quota {
            "max" => None,
            q => Some(q.parse().ok()?),
        };
        Some(Self {
            quota_us,
            period_us,
        })
    }

    /// The v1 `cpu.cfs_quota_us` value (`-1` = unlimited).
    pub fn v1_quota(self) -> String {
        self.quota_us
            .map_or_else(|| "-1".to_owned(), |q| q.to_string())
    }

    /// Builds from the v1 `cpu.cfs_quota_us` and `cpu.cfs_period_us` contents.
    pub fn parse_v1(quota: &str, period: &str) -> Option<Self> {
        let period_us = period.trim().parse().ok()?;
        let q: i64 = quota.trim().parse().ok()?;
        let quota_us = if q < 0 { None } else { Some(q.unsigned_abs()) };
        Some(Self {
            quota_us,
            period_us,
        })
    }
}

/// A CPU weight against sibling cgroups, in cgroup v2 units: 1–10000, a
/// plain process's cgroup has 100. On v1 it is written as `cpu.shares` =
/// weight × 1024 / 100 (v1's default 1024 = v2's 100).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "u32", into = "u32")]
pub struct CpuWeight(u32);

impl CpuWeight {
    /// The kernel's default.
    pub const DEFAULT: CpuWeight = CpuWeight(100);
    /// The largest weight: against a node at [`CpuWeight::DEFAULT`], 100 to 1.
    pub const MAX: CpuWeight = CpuWeight(10_000);

    pub fn new(weight: u32) -> Result<Self> {
        Self::named(weight, "subtree root")
    }

    /// A weight for `what` (a node), which the error names.
    pub fn named(weight: u32, what: &str) -> Result<Self> {
        if (1..=10_000).contains(&weight) {
            Ok(Self(weight))
        } else {
            Err(Error::InvalidLimit {
                node: what.into(),
                reason: format!("cpu weight {weight} is outside 1..=10000"),
            })
        }
    }

    /// The v2 `cpu.weight` value.
    pub fn v2(self) -> u32 {
        self.0
    }

    /// The v1 `cpu.shares` value.
    pub fn v1_shares(self) -> u64 {
        u64::from(self.0) * 1024 / 100
    }

    /// The weight a v1 `cpu.shares` value stands for (rounded up, clamped
    /// to 1–10000: v1 allows 2–262144 shares).
    pub fn from_v1_shares(shares: u64) -> Self {
        let w = (shares.saturating_mul(100)).div_ceil(1024);
        Self(u32::try_from(w.clamp(1, 10_000)).unwrap_or(10_000))
    }
}

impl Default for CpuWeight {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl TryFrom<u32> for CpuWeight {
    type Error = Error;
    fn try_from(w: u32) -> Result<Self> {
        Self::new(w)
    }
}

impl From<CpuWeight> for u32 {
    fn from(w: CpuWeight) -> u32 {
        w.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_map_to_v1_shares_within_the_kernels_ranges() {
        assert_eq!(CpuWeight::DEFAULT.v1_shares(), 1024);
        assert_eq!(CpuWeight::new(6400).unwrap().v1_shares(), 65_536);
        assert_eq!(CpuWeight::new(1).unwrap().v1_shares(), 10);
        assert_eq!(CpuWeight::new(10_000).unwrap().v1_shares(), 102_400);
        for w in [1, 100, 250, 6400, 10_000] {
            let back = CpuWeight::from_v1_shares(CpuWeight::new(w).unwrap().v1_shares());
            assert_eq!(back.v2(), w, "{w}");
        }
        assert_eq!(CpuWeight::from_v1_shares(262_144).v2(), 10_000);
        assert!(CpuWeight::new(0).is_err());
        assert!(CpuWeight::new(10_001).is_err());
        assert!(CpuWeight::try_from(0).is_err());
        assert_eq!(u32::from(CpuWeight::try_from(250).unwrap()), 250);
    }

    type Case = (Option<f64>, u64, Option<(Option<u64>, u64)>);

    #[test]
    fn limits_convert_to_quota_or_are_rejected() {
        let cases: [Case; 9] = [
            (Some(0.2), 100_000, Some((Some(20_000), 100_000))),
            (Some(0.35), 20_000, Some((Some(7_000), 20_000))),
            (Some(1.5), 100_000, Some((Some(150_000), 100_000))),
            (None, 50_000, Some((None, 50_000))),
            (Some(0.0), 100_000, None),
            (Some(-1.0), 100_000, None),
            (Some(f64::NAN), 100_000, None),
            (Some(0.01), 50_000, None), // quota 500 us < 1 ms
            (Some(0.5), 500, None),     // period too short
        ];
        for (cpus, period_us, want) in cases {
            let got = CpuLimit {
                cpus,
                period_us,
                weight: CpuWeight::DEFAULT,
            }
            .to_cpu_max("/n")
            .ok()
            .map(|m| (m.quota_us, m.period_us));
            assert_eq!(got, want, "cpus {cpus:?} period {period_us}");
        }
    }

    #[test]
    fn file_formats_round_trip() {
        let limited = CpuMax {
            quota_us: Some(20_000),
            period_us: 100_000,
        };
        assert_eq!(limited.to_v2(), "20000 100000");
        assert_eq!(CpuMax::parse_v2("20000 100000\n"), Some(limited));
        assert_eq!(
            CpuMax::parse_v2("max 100000"),
            Some(CpuMax {
                quota_us: None,
                period_us: 100_000
            })
        );
        assert_eq!(CpuMax::parse_v2("max"), None);
        assert_eq!(CpuMax::parse_v2("1 2 3"), None);
        assert_eq!(limited.v1_quota(), "20000");
        assert_eq!(CpuMax::parse_v1("20000\n", "100000\n"), Some(limited));
        assert_eq!(CpuMax::parse_v1("-1", "100000").unwrap().quota_us, None);
        assert_eq!(limited.to_limit().cpus, Some(0.2));
    }
}
