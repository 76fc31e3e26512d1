//! How long a trial or a verification waits after its config is applied
//! before it measures (pure).
//!
//! The previous config leaves transients behind: a non-core node draining a
//! backlog of frames it piled up under a tight CPU limit takes CPU from the
//! core services for seconds, and a queue refills after its adaptor opens.
//! Measuring them would charge the previous config's cost to this one. The
//! spec's `settleSeconds` is the least wait. From [`ADAPTIVE_FROM_SECONDS`] up,
//! the wait is itself measured in 1 s windows and goes on while a core metric
//! still moves — its last window differs from the mean of the two before by
//! more than [`MOVING`] of its target — up to [`MAX_FACTOR`] × `settleSeconds`.
//! Shorter settles (tests, simulations) are plain sleeps.
//!
//! A non-core node that piled up work (frames in flight) can stay stuck: when
//! new work arrives faster than its CPU limit lets it finish the old, no
//! settle ends the backlog, and every config measured after a CPU-starved one
//! would look worse than it is (the bench's first runs learned a wrong
//! feasibility boundary from such trials). So adaptive settles also *drain*
//! first: before a trial's or a candidate's config is applied, the non-core
//! apps get their minimum input and their maximum CPU (see
//! `KnobSpace::drain_point`) until the core metrics meet their targets and
//! hold still ([`drained`]), at most [`DRAIN_MAX_SECONDS`]. Each config is then
//! measured from the same, empty state, as the optimizer's model assumes.

use std::time::Duration;

use configbot_api::measure::MeasureReport;

use super::measure::MetricDef;

/// Settles of at least this many seconds are adaptive.
pub const ADAPTIVE_FROM_SECONDS: f64 = 2.0;
/// An adaptive settle ends at the latest after this many times `settleSeconds`.
pub const MAX_FACTOR: f64 = 3.0;
/// A core metric still moves when its last 1 s value is further than this
/// share of its target from the mean of the two values before it.
pub const MOVING: f64 = 0.1;
/// Length of one adaptive extension (one sub-window).
pub const STEP_MS: u64 = 1000;

/// The first drain measurement; then one [`STEP_MS`] at a time.
pub const DRAIN_FIRST_MS: u64 = 2000;
/// A drain ends at the latest after this many seconds.
pub const DRAIN_MAX_SECONDS: f64 = 10.0;

/// Whether configs are drained into (adaptive settles only).
pub fn drains(settle_seconds: f64) -> bool {
    settle_seconds >= ADAPTIVE_FROM_SECONDS
}

/// The next drain measurement's length, given what it measured so far.
pub fn drain_ms(so_far: Option<&MeasureReport>) -> u64 {
    so_far.map_or(DRAIN_FIRST_MS, |_| STEP_MS)
}

/// Whether a drain that measured `so_far` is over: in its last window every
/// core metric met its target and moved less than [`MOVING`] of it since the
/// window before — or it took [`DRAIN_MAX_SECONDS`].
pub fn drained(defs: &[MetricDef], so_far: &MeasureReport) -> bool {
    if so_far.duration_ms as f64 / 1000.0 + 1e-9 >= DRAIN_MAX_SECONDS {
        return true;
    }
    defs.iter().filter(|d| d.core).all(|d| {
        let Some(s) = so_far.series.iter().find(|s| s.probe == d.probe) else {
            return true;
        };
        let &[.., before, last] = &s.values[..] else {
            return false;
        };
        d.holds(last) && (last - before).abs() <= MOVING * d.target.abs()
    })
}

/// What the settle does next.
#[derive(Debug, Clone, PartialEq)]
pub enum Wait {
    /// A plain wait (short settles).
    Sleep(Duration),
    /// Measure the metrics for this many milliseconds in 1 s windows.
    Measure { ms: u64 },
}

/// The next wait of a settle of `settle_seconds`, given what it measured so far.
pub fn next(settle_seconds: f64, so_far: Option<&MeasureReport>) -> Wait {
    if settle_seconds < ADAPTIVE_FROM_SECONDS {
        return Wait::Sleep(Duration::from_secs_f64(settle_seconds.max(0.0)));
    }
    match so_far {
        None => Wait::Measure {
            ms: (settle_seconds * 1000.0).round() as u64,
        },
        Some(_) => Wait::Measure { ms: STEP_MS },
    }
}

/// Whether an adaptive settle that measured `so_far` is over: it waited its
/// maximum, or it waited its minimum and no core metric still moves.
pub fn done(defs: &[MetricDef], settle_seconds: f64, so_far: &MeasureReport) -> bool {
    let waited = so_far.duration_ms as f64 / 1000.0;
    if waited + 1e-9 >= MAX_FACTOR * settle_seconds {
        return true;
    }
    waited + 1e-9 >= settle_seconds && moving(defs, so_far).is_empty()
}

/// The core metrics whose last 1 s value still moves (see the module doc).
/// A metric with fewer than three values counts as moving.
pub fn moving<'a>(defs: &'a [MetricDef], r: &MeasureReport) -> Vec<&'a str> {
    defs.iter()
        .filter(|d| d.core)
        .filter(|d| {
            let Some(s) = r.series.iter().find(|s| s.probe == d.probe) else {
                return false;
            };
            let &[.., a, b, last] = &s.values[..] else {
                return true;
            };
            (last - (a + b) / 2.0).abs() > MOVING * d.target.abs()
        })
        .map(|d| d.name.as_str())
        .collect()
}

#[cfg(test)]
mod tests {
    use configbot_api::measure::{Probe, ProbeSeries};

    use super::*;

    fn defs() -> Vec<MetricDef> {
        vec![
            MetricDef::rate_at_least("cmd", "a", "/cmd_vel", 35.0, true),
            MetricDef::rate_at_least("det", "a", "/detections", 3.0, false),
        ]
    }

    fn report(cmd: &[f64], det: &[f64]) -> MeasureReport {
        let s = |topic: &str, v: &[f64]| ProbeSeries {
            probe: Probe::TopicRate {
                topic: topic.into(),
                subscriber: None,
            },
            mean: 0.0,
            values: v.to_vec(),
        };
        MeasureReport {
            started_unix_ms: 0,
            duration_ms: 1000 * cmd.len() as u64,
            sub_window_ms: 1000,
            series: vec![s("/cmd_vel", cmd), s("/detections", det)],
        }
    }

    #[test]
    fn short_settles_sleep_and_long_ones_measure_then_extend_by_a_second() {
        assert_eq!(next(0.5, None), Wait::Sleep(Duration::from_millis(500)));
        assert_eq!(next(4.0, None), Wait::Measure { ms: 4000 });
        let r = report(&[38.0; 4], &[2.0; 4]);
        assert_eq!(next(4.0, Some(&r)), Wait::Measure { ms: STEP_MS });
    }

    #[test]
    fn a_core_metric_recovering_from_the_last_config_extends_the_settle() {
        let d = defs();
        // The detector drains a backlog: /cmd_vel climbs back.
        let draining = report(&[10.0, 15.0, 25.0, 36.0], &[6.0; 4]);
        assert_eq!(moving(&d, &draining), vec!["cmd"]);
        assert!(!done(&d, 4.0, &draining));
        let recovered = report(&[10.0, 15.0, 25.0, 36.0, 38.0, 37.0], &[6.0; 6]);
        assert!(done(&d, 4.0, &recovered), "36, 38 then 37: within 3.5 Hz");
        // Non-core metrics may move: only the core ones decide.
        let steady = report(&[38.0, 37.0, 39.0, 38.0], &[0.0, 6.0, 0.0, 6.0]);
        assert!(done(&d, 4.0, &steady));
        // A config that settles into a violation is settled too.
        let low = report(&[20.0, 21.0, 19.0, 20.0], &[3.0; 4]);
        assert!(done(&d, 4.0, &low));
    }

    #[test]
    fn the_settle_is_at_least_its_minimum_and_at_most_its_maximum() {
        let d = defs();
        let steady = report(&[38.0; 3], &[2.0; 3]);
        assert!(!done(&d, 4.0, &steady), "3 s of a 4 s minimum");
        let noisy: Vec<f64> = (0..12)
            .map(|i| if i % 2 == 0 { 20.0 } else { 40.0 })
            .collect();
        let r = report(&noisy[..11], &[2.0; 11]);
        assert!(!done(&d, 4.0, &r), "still moving at 11 s");
        let r = report(&noisy, &[2.0; 12]);
        assert!(done(&d, 4.0, &r), "12 s = 3 × 4 s is the most");
        assert!(moving(&d, &report(&[38.0, 38.0], &[1.0; 2])) == vec!["cmd"]);
    }
    #[test]
    fn a_drain_ends_when_the_core_is_back_on_target_and_still() {
        let d = defs();
        assert!(drains(4.0) && !drains(1.0));
        assert_eq!(drain_ms(None), DRAIN_FIRST_MS);
        // The detector finishes its backlog at full CPU: navigation starved.
        let r = report(&[12.0, 14.0], &[0.0; 2]);
        assert!(!drained(&d, &r));
        assert_eq!(drain_ms(Some(&r)), STEP_MS);
        assert!(!drained(&d, &report(&[12.0, 14.0, 30.0], &[0.0; 3])));
        assert!(
            !drained(&d, &report(&[12.0, 14.0, 36.0], &[0.0; 3])),
            "moved 22 Hz"
        );
        assert!(drained(&d, &report(&[12.0, 14.0, 36.0, 38.0], &[0.0; 4])));
        // Never on target: ten seconds at most.
        assert!(!drained(&d, &report(&[20.0; 9], &[0.0; 9])));
        assert!(drained(&d, &report(&[20.0; 10], &[0.0; 10])));
        assert!(
            !drained(&d, &report(&[38.0], &[0.0])),
            "one window says nothing"
        );
    }
}
