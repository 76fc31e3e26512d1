//! The paper's Fig. 7 on one robot: Basic-NAV and its spec are tuned; at
//! t ≈ `switch_at` the user switches the robot to Terrain-NAV (deletes the
//! Basic-NAV spec, applies Terrain-NAV's RobotStack and PerformanceSpec: the
//! robot runs the newest stack), ConfigBot relearns; then the user switches
//! back (deletes Terrain-NAV's spec and stack, applies Basic-NAV's spec
//! again) and the library config learned for Basic-NAV's context is reused.
//!
//! This module holds the timeline's data and the pure computations on it:
//! the moments (context observed, config applied and verified) are read by
//! [`moments`] from what [`live`] recorded while the run went on (the core
//! metric per second without a gap, the specs' status and events polled
//! every [`live::WATCH`]), never guessed from sleeps; [`chart`] draws
//! `timeline.svg`.

mod live;

use configbot_api::measure::MeasureReport;
use configbot_manifests::{Phase, Reason};
use serde::Serialize;

pub use self::live::run;
use crate::report::svg::{Chart, Mark, Rule, Series, colors};
use configbot_tuning::measure::{self, MetricDef};

/// A change of one spec's status, as first seen.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Sample {
    /// Seconds since the timeline started.
    pub t: f64,
    pub spec: String,
    pub uid: String,
    pub phase: Phase,
    pub context: Option<String>,
    pub settled: bool,
    /// Reason of the `Tuned` condition (`LibraryConfig` when reused).
    pub tuned_reason: Option<Reason>,
    pub trials: u32,
}

/// A tuning event, as first seen.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct SeenEvent {
    pub t: f64,
    pub spec: String,
    pub reason: Reason,
    pub message: String,
}

/// One second of the run: the core metric's rate and whether every core
/// constraint held in it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Second {
    /// End of the 1 s window, seconds since the timeline started.
    pub t: f64,
    pub core: f64,
    pub satisfied: bool,
}

/// A spec's run from a switch (or from t = 0) to its outcome.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Moments {
    pub spec: String,
    /// The switch: when the user changed the robot's stack (0 for the first run).
    pub at: f64,
    /// When the robot ran the new stack (its nodes up, its core topics flowing).
    pub stack_up: f64,
    /// When the user applied the spec (once the stack was up, as a user would).
    pub spec_applied: f64,
    /// When the run first showed the context it settled in.
    pub detected: Option<f64>,
    /// When it settled: config applied and verified (Monitoring), or the
    /// safest config applied (Unsat).
    pub applied: Option<f64>,
    /// `detected - spec_applied`: how long the loop took to see the context.
    pub detection_seconds: Option<f64>,
    /// `applied - at`: relearn time, or reuse time when `reused`.
    pub settle_seconds: Option<f64>,
    /// The library config was re-applied (no trials).
    pub reused: bool,
    pub trials: u32,
    /// The phase it settled in (none when it did not settle).
    pub phase: Option<Phase>,
}

/// Share of satisfied seconds between two moments.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Segment {
    pub label: String,
    pub from: f64,
    pub to: f64,
    pub seconds: usize,
    pub satisfaction: Option<f64>,
}

/// Everything the timeline recorded (`timeline` in bench.json).
#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct Timeline {
    pub core_metric: String,
    pub target: f64,
    /// Basic-NAV tuned from t = 0, then the switch to Terrain-NAV, then back.
    pub initial: Moments,
    pub to_terrain: Moments,
    pub back_to_basic: Moments,
    pub segments: Vec<Segment>,
    pub seconds: Vec<Second>,
    pub samples: Vec<Sample>,
    pub events: Vec<SeenEvent>,
    /// Anything unusual on the way (core topics silent after a switch).
    pub notes: Vec<String>,
    pub svg: String,
}

/// When a switch happened: the stack change, the stack up, the spec applied.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Switch {
    pub at: f64,
    pub stack_up: f64,
    pub spec_applied: f64,
}

/// The moments of `spec`'s run after switch `w` (pure): the first sample at
/// or after the spec was applied that settled, and the first that showed
/// the context it settled in.
pub fn moments(samples: &[Sample], events: &[SeenEvent], spec: &str, w: Switch) -> Moments {
    let Switch {
        at,
        stack_up,
        spec_applied,
    } = w;
    let mine: Vec<&Sample> = samples
        .iter()
        .filter(|s| s.spec == spec && s.t >= spec_applied)
        .collect();
    let done = mine.iter().find(|s| s.settled);
    let detected = match done {
        Some(d) => mine
            .iter()
            .find(|s| s.context.is_some() && s.context == d.context)
            .map(|s| s.t),
        None => mine.iter().find(|s| s.context.is_some()).map(|s| s.t),
    };
    let hit = events
        .iter()
        .any(|e| e.spec == spec && e.t >= spec_applied && e.reason == Reason::LibraryHit);
    Moments {
        spec: spec.into(),
        at,
        stack_up,
        spec_applied,
        detected,
        applied: done.map(|s| s.t),
        detection_seconds: detected.map(|d| d - spec_applied),
        settle_seconds: done.map(|s| s.t - at),
        reused: hit && done.is_some_and(|s| s.tuned_reason == Some(Reason::LibraryConfig)),
        trials: done.map_or(0, |s| s.trials),
        phase: done.map(|s| s.phase.clone()),
    }
}

/// Per-second points from consecutive measurements (pure): `t0_ms` is the
/// timeline's start (Unix ms).
pub fn seconds(
    reports: &[MeasureReport],
    core: &MetricDef,
    defs: &[MetricDef],
    t0_ms: u64,
) -> Vec<Second> {
    let mut out = Vec::new();
    for r in reports {
        let ok = measure::windows_ok(defs, r);
        let values = r
            .series
            .iter()
            .find(|s| s.probe == core.probe)
            .map(|s| s.values.as_slice())
            .unwrap_or(&[]);
        for (i, v) in values.iter().enumerate() {
            let end = r.started_unix_ms + (i as u64 + 1) * r.sub_window_ms;
            out.push(Second {
                t: (end as f64 - t0_ms as f64) / 1000.0,
                core: *v,
                satisfied: ok.get(i).copied().unwrap_or(false),
            });
        }
    }
    out
}

/// Satisfaction between consecutive `cuts` (label, start), the last up to
/// the end (pure). A window belongs to the segment its end falls in.
pub fn segments(secs: &[Second], cuts: &[(String, f64)]) -> Vec<Segment> {
    let end = secs.last().map_or(0.0, |s| s.t);
    cuts.iter()
        .enumerate()
        .map(|(i, (label, from))| {
            let to = cuts.get(i + 1).map_or(end, |c| c.1);
            let last = i + 1 == cuts.len();
            let inside: Vec<&Second> = secs
                .iter()
                .filter(|s| s.t > *from && (s.t <= to || last))
                .collect();
            let ok = inside.iter().filter(|s| s.satisfied).count();
            Segment {
                label: label.clone(),
                from: *from,
                to,
                seconds: inside.len(),
                satisfaction: (!inside.is_empty()).then(|| ok as f64 / inside.len() as f64),
            }
        })
        .collect()
}

/// The timeline chart (pure): the core rate per second, violated seconds
/// as crosses, the target, and vertical rules at each switch, detection
/// and applied moment.
pub fn chart(t: &Timeline) -> Chart {
    let mut rules = vec![Rule {
        label: format!("target {}", t.target),
        value: t.target,
        vertical: false,
    }];
    for (m, to) in [
        (&t.initial, "basic-nav"),
        (&t.to_terrain, "terrain-nav"),
        (&t.back_to_basic, "basic-nav"),
    ] {
        rules.push(Rule {
            label: format!("→ {to}"),
            value: m.at,
            vertical: true,
        });
        if let Some(d) = m.detected.filter(|d| *d > m.at) {
            rules.push(Rule {
                label: "detected".into(),
                value: d,
                vertical: true,
            });
        }
        if let Some(a) = m.applied {
            rules.push(Rule {
                label: if m.reused { "reused" } else { "applied" }.into(),
                value: a,
                vertical: true,
            });
        }
    }
    Chart {
        title: format!("Context switch: {} per second", t.core_metric),
        x_label: "s since Basic-NAV's spec was applied".into(),
        y_label: "Hz (1 s windows)".into(),
        series: vec![
            Series {
                name: t.core_metric.clone(),
                mark: Mark::Line,
                color: colors::CORE,
                points: t.seconds.iter().map(|s| (s.t, s.core)).collect(),
            },
            Series {
                name: "violated".into(),
                mark: Mark::Cross,
                color: colors::INFEASIBLE,
                points: t
                    .seconds
                    .iter()
                    .filter(|s| !s.satisfied)
                    .map(|s| (s.t, s.core))
                    .collect(),
            },
        ],
        rules,
        y_from_zero: true,
        ..Chart::default()
    }
}

fn opt(v: Option<f64>) -> String {
    v.map_or("-".into(), |x| format!("{x:.1} s"))
}

/// The timeline in a few lines (pure).
pub fn summary(t: &Timeline) -> String {
    let mut out = String::from("Context-switch timeline:\n");
    for (label, m) in [
        ("basic-nav tuned from scratch", &t.initial),
        ("switch to terrain-nav", &t.to_terrain),
        ("switch back to basic-nav", &t.back_to_basic),
    ] {
        out.push_str(&format!(
            "  {label} at {:.1} s: stack up after {}, spec applied, context observed {} later, {} {} after the switch ({} trials, {})\n",
            m.at,
            opt(Some(m.stack_up - m.at)),
            opt(m.detection_seconds),
            if m.reused {
                "library config reused"
            } else {
                "settled"
            },
            opt(m.settle_seconds),
            m.trials,
            m.phase.as_ref().map_or("not settled", Phase::as_str),
        ));
    }
    for s in &t.segments {
        out.push_str(&format!(
            "  {:<28} {:>6.1}–{:<6.1} s  satisfaction {}\n",
            s.label,
            s.from,
            s.to,
            s.satisfaction
                .map_or("-".into(), |x| format!("{:.1}%", x * 100.0))
        ));
    }
    for n in &t.notes {
        out.push_str(&format!("  note: {n}\n"));
    }
    out.push_str(&format!("  plot: {}\n", t.svg));
    out
}

#[cfg(test)]
mod tests {
    use configbot_api::measure::ProbeSeries;

    use super::*;

    fn sample(
        t: f64,
        spec: &str,
        phase: Phase,
        ctx: Option<&str>,
        reason: Option<Reason>,
    ) -> Sample {
        Sample {
            t,
            spec: spec.into(),
            uid: "u".into(),
            settled: matches!(phase, Phase::Monitoring | Phase::Unsat),
            phase,
            context: ctx.map(str::to_string),
            tuned_reason: reason,
            trials: 3,
        }
    }

    fn ev(t: f64, spec: &str, reason: Reason) -> SeenEvent {
        SeenEvent {
            t,
            spec: spec.into(),
            reason,
            message: String::new(),
        }
    }

    #[test]
    fn moments_come_from_the_samples_after_the_switch() {
        let samples = vec![
            sample(1.0, "basic", Phase::Baseline, Some("b"), None),
            sample(
                20.0,
                "basic",
                Phase::Monitoring,
                Some("b"),
                Some(Reason::Satisfied),
            ),
            sample(50.4, "terrain", Phase::Baseline, Some("t-partial"), None),
            sample(51.0, "terrain", Phase::Baseline, Some("t"), None),
            sample(
                80.0,
                "terrain",
                Phase::Monitoring,
                Some("t"),
                Some(Reason::Satisfied),
            ),
            // The library config applied and being verified: not settled yet.
            sample(
                100.2,
                "basic",
                Phase::Satisfied,
                Some("b"),
                Some(Reason::LibraryConfig),
            ),
            sample(
                106.0,
                "basic",
                Phase::Monitoring,
                Some("b"),
                Some(Reason::LibraryConfig),
            ),
        ];
        let events = vec![ev(100.2, "basic", Reason::LibraryHit)];
        let w = |at: f64, up: f64| Switch {
            at,
            stack_up: up,
            spec_applied: up,
        };
        let first = moments(&samples, &events, "basic", w(0.0, 0.0));
        assert_eq!((first.detected, first.applied), (Some(1.0), Some(20.0)));
        assert!(!first.reused, "the first run learned its config");
        // Detected when the run showed the context it settled in, not a partial one.
        let t = moments(&samples, &events, "terrain", w(49.0, 50.0));
        assert_eq!(t.detected, Some(51.0));
        assert!((t.detection_seconds.unwrap() - 1.0).abs() < 1e-9);
        assert_eq!(
            t.settle_seconds,
            Some(31.0),
            "from the switch, not the spec"
        );
        assert_eq!(t.phase, Some(Phase::Monitoring));
        // Back: only samples after the second switch count.
        let b = moments(&samples, &events, "basic", w(99.0, 100.0));
        assert_eq!((b.detected, b.applied), (Some(100.2), Some(106.0)));
        assert!(b.reused);
        // Never settled: no applied moment, the first context seen is the detection.
        let n = moments(&samples[..4], &[], "terrain", w(50.0, 50.0));
        assert_eq!((n.detected, n.applied, n.phase), (Some(50.4), None, None));
    }

    #[test]
    fn seconds_and_segments_follow_the_windows() {
        let core = MetricDef::rate_at_least("cmd", "nav", "/cmd_vel", 35.0, true);
        let rep = |start: u64, v: Vec<f64>| MeasureReport {
            started_unix_ms: start,
            duration_ms: v.len() as u64 * 1000,
            sub_window_ms: 1000,
            series: vec![ProbeSeries {
                probe: core.probe.clone(),
                values: v,
                mean: 0.0,
            }],
        };
        let defs = vec![core.clone()];
        let s = seconds(
            &[rep(10_000, vec![20.0, 40.0]), rep(12_050, vec![36.0, 10.0])],
            &core,
            &defs,
            10_000,
        );
        let ts: Vec<f64> = s.iter().map(|x| x.t).collect();
        assert_eq!(ts, [1.0, 2.0, 3.05, 4.05]);
        assert_eq!(
            s.iter().map(|x| x.satisfied).collect::<Vec<_>>(),
            [false, true, true, false]
        );
        let seg = segments(&s, &[("a".into(), 0.0), ("b".into(), 2.0)]);
        assert_eq!(seg[0].seconds, 2);
        assert_eq!(seg[0].satisfaction, Some(0.5));
        assert_eq!((seg[1].from, seg[1].to, seg[1].seconds), (2.0, 4.05, 2));
        assert_eq!(seg[1].satisfaction, Some(0.5));
        // A segment without windows has no satisfaction.
        let empty = segments(&s, &[("a".into(), 0.0), ("late".into(), 9.0)]);
        assert_eq!(empty[1].satisfaction, None);
    }

    #[test]
    fn chart_marks_violations_and_every_moment() {
        let m = |at: f64, d: Option<f64>, a: Option<f64>, reused: bool| Moments {
            spec: "x".into(),
            at,
            stack_up: at,
            spec_applied: at,
            detected: d,
            applied: a,
            detection_seconds: None,
            settle_seconds: None,
            reused,
            trials: 0,
            phase: None,
        };
        let t = Timeline {
            core_metric: "cmd".into(),
            target: 35.0,
            initial: m(0.0, Some(0.0), Some(20.0), false),
            to_terrain: m(50.0, Some(50.3), Some(80.0), false),
            back_to_basic: m(100.0, Some(100.1), None, false),
            segments: Vec::new(),
            seconds: vec![
                Second {
                    t: 1.0,
                    core: 20.0,
                    satisfied: false,
                },
                Second {
                    t: 2.0,
                    core: 40.0,
                    satisfied: true,
                },
            ],
            samples: Vec::new(),
            events: Vec::new(),
            notes: Vec::new(),
            svg: String::new(),
        };
        let c = chart(&t);
        assert_eq!(c.series[0].points.len(), 2);
        assert_eq!(c.series[1].points, vec![(1.0, 20.0)]);
        let labels: Vec<(&str, f64)> = c
            .rules
            .iter()
            .map(|r| (r.label.as_str(), r.value))
            .collect();
        assert_eq!(
            labels,
            [
                ("target 35", 35.0),
                ("→ basic-nav", 0.0),
                ("applied", 20.0),
                ("→ terrain-nav", 50.0),
                ("detected", 50.3),
                ("applied", 80.0),
                ("→ basic-nav", 100.0),
                ("detected", 100.1),
            ]
        );
        assert!(c.to_svg().starts_with("<svg"));
    }
}
