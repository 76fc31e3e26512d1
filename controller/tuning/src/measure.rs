//! Measures (pure), with one definition used for the baseline, every trial,
//! verification and the steady state (status, CLI, metrics):
//!
//! - **Constraint satisfaction rate**: the share of sub-windows (1 s) in which
//!   every core constraint holds.
//! - **Non-core performance**: each objective's value over the whole window
//!   (the agent's, refined by message arrivals) normalised
//!   and capped at its target (`min(J, J°)/J°`, or `J°/max(J, J°)` for
//!   at-most targets), combined by `spec.tuning.scalarization` (MaxMin: the
//!   worst; Weighted: weighted mean) — the same definition as the
//!   optimizer's.
//! - **Constraint value fed to the optimizer**: a per-sub-window lower (upper)
//!   bound, `mean − 2.33·sd` (`mean + 2.33·sd`) of the sub-window values, so a
//!   config that meets its target only on average (and would hold in half of
//!   the sub-windows) does not count as feasible; 2.33 sd is the 99 % one-sided
//!   normal quantile, matching the ≥ 99 % satisfaction goal. A trial
//!   measured on near the boundary to ten windows that all held is judged
//!   by its windows instead ([`held_every_window`]), and its verification
//!   must hold the whole minute: a config whose every window of ten held
//!   can still miss one window in twenty, and the minute, not the trial, is
//!   what tells. (Measured on the real nodelet stack, before verifications
//!   held such trials to the minute: three configs chosen by their worst
//!   window held every window of their trials and missed 3–4 of 60
//!   windows afterwards, their 60-window bounds 23.9, 24.7 and 25.2
//!   against 25 Hz. Judged by the bound alone, session 62's seed 3 called
//!   three trials at objective 0.44–0.64 whose ten windows all held
//!   infeasible and kept 0.508.) A Student-t prediction bound (k = 4.1 from
//!   five windows, 2.96 from ten) was tried and dropped: it judged demo
//!   trials whose every window held infeasible, and the demo took 13 trials
//!   and 319 s against 254 s with 2.33 on the same busy machine, ending with
//!   less detection (1.1 against 1.9 Hz). In a run whose core windows miss
//!   in bursts, a trial is judged by its windows instead, its worst window
//!   the value the optimizer sees ([`judge_by_windows`]): there the
//!   verification's two-minute record is the test.
//! - **Near the boundary** ([`near_boundary`]): a measurement whose bound
//!   misses but whose windows mostly hold is measured longer instead of
//!   being discarded, up to [`BOUNDARY_WINDOWS`] windows or more.
//! - **Short of the bar** ([`short_of_bar`]): a verification whose every
//!   window held but whose margin is less than [`BAR_Z`] sd, whether or not
//!   its 2.33·sd bound holds, is measured
//!   on towards [`BAR_WINDOWS`] windows, the minute a user (or the bench)
//!   judges it by, and is judged as that minute is: by its windows alone
//!   ([`BAR_SATISFACTION`]); it holds early once every window so far is on
//!   target and together they clear the [`BAR_Z`] margin. The 2.33·sd bound predicts
//!   about one miss per 100 windows, while a minute at ≥ 99.5 % allows
//!   none in 60: on the real two-path stack two configs verified over 30
//!   windows, every one on target, then missed one of 60. Rejecting on the
//!   bound instead cost Basic-NAV (bench, 2026-11-28): three capped trials'
//!   verifications, each of ten windows on target with bounds 34.9, 34.9
//!   and 34.2 against 35 Hz, were failed, and the run took 11 trials and
//!   205 s where its fifth trial had reached the cap.
//! - **Few messages** ([`few_messages`]): an objective below its cap whose
//!   topic counted fewer than [`FEW_MESSAGES`] messages in a trial is
//!   measured by too few to rank configs by; a trial among the best so far
//!   with such an objective is measured longer (see
//!   `search::thin_contender`).

use std::collections::BTreeMap;

use configbot_api::measure::{MeasureReport, MeasureRequest, Probe, ProbeSeries};
use configbot_manifests::performance_spec::{Bound, Scalarization};
use configbot_manifests::{PerformanceSpecSpec, RobotStackSpec};
use serde::{Deserialize, Serialize};

/// One-sided 99 % normal quantile: the bound a trial and a verification meet.
pub const BOUND_Z: f64 = 2.33;
/// How many 1 s windows a measurement near the boundary is extended to: ten
/// windows estimate the spread well enough for the bound to tell (see
/// [`near_boundary`]).
pub const BOUNDARY_WINDOWS: usize = 10;
/// A measurement is near the boundary when its bound misses but at least
/// this share of its windows hold.
pub const NEAR_SHARE: f64 = 0.8;
/// The windows of the minute a verified config is judged by.
pub const BAR_WINDOWS: usize = 60;
/// The share of that minute's windows that must hold: none of 60 may miss.
pub const BAR_SATISFACTION: f64 = 0.995;
/// The margin, in sd of the windows, at which a normal config misses none of
/// [`BAR_WINDOWS`] windows nine times in ten: a miss per window of at most
/// 1 − 0.9^(1/60) = 0.18 %, the one-sided quantile 2.92. A config with less
/// is not rejected for it (the normal tail of 30 windows is too noisy to
/// judge by alone: a tolerance bound of 3.16·sd rejected the real nodelet
/// stack's best region); it is measured over the whole minute instead.
pub const BAR_Z: f64 = 2.92;

/// A metric of the spec, resolved against the stack.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricDef {
    pub name: String,
    pub app: String,
    pub probe: Probe,
    /// `true`: `(true, v)` at least v; `(false, v)` at most v.
    pub at_least: bool,
    pub target: f64,
    /// Metric of a core app: a constraint; otherwise an objective.
    pub core: bool,
    pub weight: f64,
}

impl MetricDef {
    /// The rate of `topic` (all subscribers), at least `target` Hz; a
    /// constraint when `core`, else an objective of weight 1.
    pub fn rate_at_least(name: &str, app: &str, topic: &str, target: f64, core: bool) -> MetricDef {
        MetricDef {
            name: name.into(),
            app: app.into(),
            probe: Probe::TopicRate {
                topic: topic.into(),
                subscriber: None,
            },
            at_least: true,
            target,
            core,
            weight: 1.0,
        }
    }

    /// Whether one value meets the target.
    pub fn holds(&self, v: f64) -> bool {
        self.margin(v) >= 0.0
    }

    /// How far `v` is on the holding side of the target (negative: it misses).
    pub fn margin(&self, v: f64) -> f64 {
        if self.at_least {
            v - self.target
        } else {
            self.target - v
        }
    }

    /// `>= 35` / `<= 0.5`.
    pub fn target_text(&self) -> String {
        format!(
            "{} {}",
            if self.at_least { ">=" } else { "<=" },
            self.target
        )
    }
}

/// The metrics of a spec (a metric of an app missing from the stack counts as core).
pub fn metric_defs(stack: &RobotStackSpec, spec: &PerformanceSpecSpec) -> Vec<MetricDef> {
    spec.metrics
        .iter()
        .filter_map(|m| {
            let probe = match (&m.source.topic_rate, &m.source.cpu_usage) {
                (Some(t), _) => Probe::TopicRate {
                    topic: t.topic.clone(),
                    subscriber: t.subscriber.clone(),
                },
                (None, Some(c)) => Probe::CpuUsage {
                    node: c.node.clone(),
                },
                (None, None) => return None,
            };
            let (at_least, target) = match m.target.bound()? {
                Bound::AtLeast(v) => (true, v),
                Bound::AtMost(v) => (false, v),
            };
            Some(MetricDef {
                name: m.name.clone(),
                app: m.app.clone(),
                probe,
                at_least,
                target,
                core: stack.app(&m.app).is_none_or(|a| a.core),
                weight: m.weight,
            })
        })
        .collect()
}

/// A request for every metric plus the rate of `extra_topics` (for the knob space).
pub fn request(
    defs: &[MetricDef],
    extra_topics: &[String],
    duration_ms: u64,
    sub_window_ms: u64,
) -> MeasureRequest {
    let mut probes: Vec<Probe> = defs.iter().map(|d| d.probe.clone()).collect();
    for t in extra_topics {
        let p = Probe::TopicRate {
            topic: t.clone(),
            subscriber: None,
        };
        if !probes.contains(&p) {
            probes.push(p);
        }
    }
    MeasureRequest {
        probes,
        duration_ms,
        sub_window_ms,
    }
}

/// The CPU use of each of `nodes`, added to a request (pure): a trial
/// measures the non-core nodes' use beside the metrics
/// ([`Evaluation::usage`]).
pub fn with_usage(mut req: MeasureRequest, nodes: &[String]) -> MeasureRequest {
    for n in nodes {
        let p = Probe::CpuUsage { node: n.clone() };
        if !req.probes.contains(&p) {
            req.probes.push(p);
        }
    }
    req
}

/// The latency probes of the core metrics that rate a topic as a plain
/// subscriber sees it (pure): how late their messages arrive after the
/// stamp in their header, the sign of a core pipeline falling behind before
/// its rate misses (see [`Probe::TopicLatency`]).
pub fn latency_probes(defs: &[MetricDef]) -> Vec<Probe> {
    defs.iter().filter_map(latency_probe).collect()
}

/// Each core metric's latency peaks per window in a report that measured
/// [`latency_probes`] (pure), by metric name; metrics without one are left out.
pub fn latency_peaks(defs: &[MetricDef], report: &MeasureReport) -> BTreeMap<String, Vec<f64>> {
    defs.iter()
        .filter_map(|d| {
            let p = latency_probe(d)?;
            Some((d.name.clone(), series(report, &p)?.to_vec()))
        })
        .collect()
}

/// The latency probe of a core metric that rates a topic as a plain
/// subscriber sees it; `None` for any other metric.
fn latency_probe(d: &MetricDef) -> Option<Probe> {
    match &d.probe {
        Probe::TopicRate {
            topic,
            subscriber: None,
        } if d.core => Some(Probe::TopicLatency {
            topic: topic.clone(),
        }),
        _ => None,
    }
}

/// The series of `probe` in a report: its 1 s windows and its whole-window
/// value, the agent's, which for a topic is refined by the arrivals of the
/// messages that bound its count (the agent's `measure`), so a 1 Hz
/// objective measured over a 5 s trial is not read in steps of 0.2 Hz as the
/// mean of its windows would be.
fn probe_series<'a>(report: &'a MeasureReport, probe: &Probe) -> Option<&'a ProbeSeries> {
    report.series.iter().find(|s| s.probe == *probe)
}

/// The 1 s windows of `probe` in a report.
fn series<'a>(report: &'a MeasureReport, probe: &Probe) -> Option<&'a [f64]> {
    probe_series(report, probe).map(|s| s.values.as_slice())
}

/// Every topic's whole-window rate in a report.
pub fn topic_rates(report: &MeasureReport) -> BTreeMap<String, f64> {
    report
        .series
        .iter()
        .filter_map(|s| match &s.probe {
            Probe::TopicRate {
                topic,
                subscriber: None,
            } => Some((topic.clone(), s.mean)),
            _ => None,
        })
        .collect()
}

/// Per sub-window: did every core constraint hold? (A missing value is a violation.)
pub fn windows_ok(defs: &[MetricDef], report: &MeasureReport) -> Vec<bool> {
    let n = report
        .series
        .iter()
        .map(|s| s.values.len())
        .max()
        .unwrap_or(0);
    (0..n)
        .map(|i| {
            defs.iter().filter(|d| d.core).all(|d| {
                series(report, &d.probe)
                    .and_then(|v| v.get(i))
                    .is_some_and(|&v| d.holds(v))
            })
        })
        .collect()
}

/// Share of sub-windows in which every core constraint held (1 with no windows and no constraints).
pub fn satisfaction(defs: &[MetricDef], report: &MeasureReport) -> f64 {
    let w = windows_ok(defs, report);
    if w.is_empty() {
        return if defs.iter().any(|d| d.core) {
            0.0
        } else {
            1.0
        };
    }
    w.iter().filter(|b| **b).count() as f64 / w.len() as f64
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0);
    }
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = if v.len() > 1 {
        v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)
    } else {
        0.0
    };
    (mean, var.sqrt())
}

/// The constraint value the optimizer sees (see the module docs): the
/// normal bound `mean ∓ 2.33·sd` of the sub-window values.
pub fn robust_value(def: &MetricDef, values: &[f64]) -> f64 {
    let (mean, sd) = mean_sd(values);
    if def.at_least {
        mean - BOUND_Z * sd
    } else {
        mean + BOUND_Z * sd
    }
}

/// A measurement judged by its windows alone (pure), as a trial of a run
/// whose core windows miss in bursts is (`Run::bursty`): each core
/// constraint's value becomes its worst window, and the measurement is
/// feasible when every window held. There a dip does not scale with the
/// spread of the windows around it, so the bound neither predicts a clean
/// minute nor rules one out, and the verification's record (two minutes
/// without a miss) is the test a config must pass; the bench's oracle
/// screens its configs the same way. Measured on real-nodelets
/// (2026-11-27): judged by the bound, four trials at objective 0.97–1.0
/// whose 10 windows were all on target were called infeasible, and the run
/// kept a config at 0.46, while the oracle's best, screened by its windows,
/// held two minutes at 1.0.
pub fn judge_by_windows(defs: &[MetricDef], report: &MeasureReport, eval: &mut Evaluation) {
    let mut feasible = true;
    let core = defs.iter().filter(|d| d.core);
    for ((d, c), &w) in core.zip(eval.constraints.iter_mut()).zip(&eval.worst) {
        let measured = series(report, &d.probe).is_some_and(|v| !v.is_empty());
        *c = w;
        feasible &= measured && d.holds(w);
    }
    eval.feasible = feasible;
}

/// Whether every core constraint was measured over at least
/// [`BOUNDARY_WINDOWS`] windows and every one of them held (pure): a trial
/// measured on past its own length (near the boundary, or a contender on
/// few messages) that missed none. Such a trial is judged
/// by its windows ([`judge_by_windows`]) in every run, bursty or not: ten
/// windows on target are what the verification's first measurement asks
/// of a config, and the verification, not the trial, holds it to the
/// minute without a miss (a trial measured near a core target is verified
/// over the whole minute, `machine::at_the_boundary`). Measured on
/// real-nodelets (session 62, seed 3, a run that never turned bursty):
/// judged by the bound, trials 12, 15 and 19, at objective 0.44–0.64,
/// held all ten windows, worst 26 Hz against 25, and were called
/// infeasible; the run kept 0.508 where the oracle's best is 0.713.
pub fn held_every_window(defs: &[MetricDef], report: &MeasureReport) -> bool {
    let core: Vec<&MetricDef> = defs.iter().filter(|d| d.core).collect();
    !core.is_empty()
        && core
            .iter()
            .all(|d| series(report, &d.probe).is_some_and(|v| v.len() >= BOUNDARY_WINDOWS))
        && windows_ok(defs, report).iter().all(|ok| *ok)
}

/// Whether a measurement that is not feasible is near the boundary, so
/// measuring longer can tell (pure): some core constraint's bound misses,
/// yet for every core constraint at least [`NEAR_SHARE`] of the windows hold.
pub fn near_boundary(defs: &[MetricDef], report: &MeasureReport) -> bool {
    let core: Vec<&MetricDef> = defs.iter().filter(|d| d.core).collect();
    let values = |d: &MetricDef| series(report, &d.probe).unwrap_or(&[]);
    let misses = core.iter().any(|d| {
        let v = values(d);
        v.is_empty() || !d.holds(robust_value(d, v))
    });
    let mostly = core.iter().all(|d| {
        let v = values(d);
        !v.is_empty()
            && v.iter().filter(|&&x| d.holds(x)).count() as f64 >= NEAR_SHARE * v.len() as f64
    });
    misses && mostly
}

/// The fewest messages an objective's topic counts in a trial for the
/// trial's objective to rank it among the best: with fewer, one message
/// more or less moves the objective by a fifth or more of its value.
/// Measured on real-perception (session 52, a VM where lines at ≥ 1 Hz ran
/// at 0.2–0.3 Hz, one or two messages in a 5 s trial): three trials of
/// one balanced config (its knobs within 2 % of each other) measured
/// objectives 0.192, 0.162 and 0.285; the run verified the last of them,
/// and its two-minute record gave 0.260.
pub const FEW_MESSAGES: f64 = 5.0;

/// The objectives below their cap whose topic rate counted fewer than
/// [`FEW_MESSAGES`] messages over `report`, each with its count (its
/// whole-window rate times the window's length) (pure). At-least rate
/// objectives only: an at-most target or another probe is not a count.
pub fn few_messages(defs: &[MetricDef], report: &MeasureReport) -> Vec<(String, f64)> {
    let secs = report.duration_ms as f64 / 1000.0;
    defs.iter()
        .filter(|d| !d.core && d.at_least && matches!(d.probe, Probe::TopicRate { .. }))
        .filter_map(|d| {
            let rate = probe_series(report, &d.probe).map_or(0.0, |s| s.mean);
            let count = rate * secs;
            (normalise(d, rate) < 1.0 && count < FEW_MESSAGES).then(|| (d.name.clone(), count))
        })
        .collect()
}

/// Whether a measurement shorter than [`BAR_WINDOWS`] windows leaves some
/// core constraint less than [`BAR_Z`] sd from its target (pure), so only a
/// whole minute can tell whether it holds one.
pub fn short_of_bar(defs: &[MetricDef], report: &MeasureReport) -> bool {
    defs.iter().filter(|d| d.core).any(|d| {
        let v = series(report, &d.probe).unwrap_or(&[]);
        if v.is_empty() || v.len() >= BAR_WINDOWS {
            return false;
        }
        let (mean, sd) = mean_sd(v);
        d.margin(mean) < BAR_Z * sd
    })
}

/// Normalised, capped value of one objective.
pub fn normalise(def: &MetricDef, j: f64) -> f64 {
    if def.at_least {
        j.min(def.target).max(0.0) / def.target
    } else {
        def.target / j.max(def.target)
    }
}

/// Scalarised non-core performance; `None` without objectives.
pub fn scalarize(
    defs: &[MetricDef],
    means: &BTreeMap<String, f64>,
    s: Scalarization,
) -> Option<f64> {
    let u: Vec<(f64, f64)> = defs
        .iter()
        .filter(|d| !d.core)
        .map(|d| {
            (
                normalise(d, means.get(&d.name).copied().unwrap_or(0.0)),
                d.weight,
            )
        })
        .collect();
    if u.is_empty() {
        return None;
    }
    Some(match s {
        Scalarization::MaxMin => u.iter().map(|p| p.0).fold(f64::INFINITY, f64::min),
        Scalarization::Weighted => {
            let w: f64 = u.iter().map(|p| p.1).sum();
            if w <= 0.0 {
                0.0
            } else {
                u.iter().map(|(u, w)| u * w).sum::<f64>() / w
            }
        }
    })
}

/// How many times more each at-least objective measured than the level at
/// which more of it stops counting (pure): its target for
/// [`Scalarization::Weighted`] (objectives are capped there), the
/// scalarised level itself for [`Scalarization::MaxMin`] (only the worst
/// objective counts, so one above it gains nothing until the worst rises).
/// Only objectives above that level are listed; none when the level is 0.
/// At-most objectives are left out: less input need not bring them down.
pub fn surplus(
    defs: &[MetricDef],
    means: &BTreeMap<String, f64>,
    s: Scalarization,
) -> BTreeMap<String, f64> {
    let level = match s {
        Scalarization::Weighted => Some(1.0),
        Scalarization::MaxMin => scalarize(defs, means, s),
    };
    let Some(level) = level.filter(|&l| l > 0.0) else {
        return BTreeMap::new();
    };
    defs.iter()
        .filter(|d| !d.core && d.at_least && d.target > 0.0)
        .filter_map(|d| {
            let h = means.get(&d.name)? / d.target / level;
            (h > 1.0).then(|| (d.name.clone(), h))
        })
        .collect()
}

/// Objectives within this factor of the worst one count as tied with it in
/// a [`lift`]: a window's count of a slow output is ±20 %.
pub const LIFT_TIE: f64 = 1.25;

/// Under [`Scalarization::MaxMin`], what raising the worst objectives of a
/// measurement would take (see [`lift`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Lift {
    /// The scalarised level: the worst objective's normalised value.
    pub level: f64,
    /// The objective above the worst ones that sets the next level, and
    /// that level (at most 1, the cap).
    pub next: (String, f64),
    /// Each worst objective (within [`LIFT_TIE`] of the level) and how
    /// many times more it must measure to reach
    /// [`crate::knobs::TRIM_HEADROOM`] times the next level: an app's
    /// output follows its input and CPU while those are what limit it.
    pub factors: BTreeMap<String, f64>,
}

/// The worst objectives of `means` under max-min scalarisation and how far
/// each must rise to pass the next one (pure). Only the worst objective
/// counts, so giving more to an app whose objective sits above it buys
/// nothing, and giving its own app more is the one way up. `None` under
/// weighted scalarisation, with fewer than two at-least objectives, when
/// the worst measured nothing (no rate to scale from) or when every
/// objective is tied with the worst.
pub fn lift(defs: &[MetricDef], means: &BTreeMap<String, f64>, s: Scalarization) -> Option<Lift> {
    if s != Scalarization::MaxMin {
        return None;
    }
    let u: Vec<(&str, f64)> = defs
        .iter()
        .filter(|d| !d.core && d.at_least && d.target > 0.0)
        .map(|d| {
            (
                d.name.as_str(),
                normalise(d, means.get(&d.name).copied().unwrap_or(0.0)),
            )
        })
        .collect();
    let level = u.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
    if u.len() < 2 || level <= 0.0 || !level.is_finite() {
        return None;
    }
    let tied = |v: f64| v <= level * LIFT_TIE;
    let (next_name, next) = u
        .iter()
        .filter(|p| !tied(p.1))
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    let goal = crate::knobs::TRIM_HEADROOM * next;
    Some(Lift {
        level,
        next: (next_name.to_string(), *next),
        factors: u
            .iter()
            .filter(|p| tied(p.1))
            .map(|(n, v)| (n.to_string(), goal / v))
            .collect(),
    })
}

/// Everything the loop derives from one measurement.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Evaluation {
    /// Whole-window mean of every metric.
    pub means: BTreeMap<String, f64>,
    /// CPUs each node a [`with_usage`] probe measured used over the window,
    /// by node name (what `balance` fits its cost model to).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub usage: BTreeMap<String, f64>,
    /// Optimizer-facing constraint values, in metric order (core metrics only).
    pub constraints: Vec<f64>,
    /// Each core constraint's worst window, in the same order (0 with no
    /// window).
    #[serde(default)]
    pub worst: Vec<f64>,
    /// Objective means, in metric order (non-core metrics only).
    pub objectives: Vec<f64>,
    pub satisfaction: f64,
    /// Windows in which some core constraint missed its target.
    #[serde(default)]
    pub missed: u32,
    pub objective: Option<f64>,
    /// Every constraint's robust value meets its target.
    pub feasible: bool,
}

pub fn evaluate(defs: &[MetricDef], report: &MeasureReport, s: Scalarization) -> Evaluation {
    let mut means = BTreeMap::new();
    let mut constraints = Vec::new();
    let mut worst = Vec::new();
    let mut objectives = Vec::new();
    let mut feasible = true;
    for d in defs {
        // A metric's mean is its whole-window value (core metrics' too: the
        // bursts rule reads them), its constraint judged by its windows.
        let found = probe_series(report, &d.probe);
        let values = found.map_or(&[][..], |s| s.values.as_slice());
        let mean = found.map_or(0.0, |s| s.mean);
        means.insert(d.name.clone(), mean);
        if d.core {
            let r = if values.is_empty() {
                0.0
            } else {
                robust_value(d, values)
            };
            feasible &= !values.is_empty() && d.holds(r);
            constraints.push(r);
            worst.push(worst_window(d, values));
        } else {
            objectives.push(mean);
        }
    }
    let missed = windows_ok(defs, report).iter().filter(|ok| !**ok).count();
    let usage = report
        .series
        .iter()
        .filter_map(|p| match &p.probe {
            Probe::CpuUsage { node } => Some((node.clone(), p.mean)),
            _ => None,
        })
        .collect();
    Evaluation {
        objective: scalarize(defs, &means, s),
        usage,
        satisfaction: satisfaction(defs, report),
        missed: u32::try_from(missed).unwrap_or(u32::MAX),
        means,
        constraints,
        worst,
        objectives,
        feasible,
    }
}

/// The window of `values` furthest on the missing side of `d`'s target: the
/// least for an at-least target, the most for an at-most one; 0 with no
/// window (as the robust value: a measurement without windows is judged
/// infeasible by its emptiness, not by this value).
pub fn worst_window(d: &MetricDef, values: &[f64]) -> f64 {
    if values.is_empty() {
        0.0
    } else if d.at_least {
        values.iter().copied().fold(f64::INFINITY, f64::min)
    } else {
        values.iter().copied().fold(f64::NEG_INFINITY, f64::max)
    }
}

/// Early stop of a trial: a core constraint that missed `floor × target` (or
/// exceeded `target / floor` for at-most) in every sub-window so far. Returns its name.
pub fn clearly_infeasible(
    defs: &[MetricDef],
    report: &MeasureReport,
    floor: f64,
) -> Option<String> {
    defs.iter()
        .filter(|d| d.core)
        .find(|d| {
            let v = series(report, &d.probe).unwrap_or(&[]);
            !v.is_empty()
                && v.iter().all(|&x| {
                    if d.at_least {
                        x < floor * d.target
                    } else {
                        x > d.target / floor
                    }
                })
        })
        .map(|d| d.name.clone())
}

/// Concatenate two consecutive reports of the same request.
pub fn concat(a: &MeasureReport, b: &MeasureReport) -> MeasureReport {
    let mut out = a.clone();
    out.duration_ms += b.duration_ms;
    let total = out.duration_ms.max(1) as f64;
    for s in &mut out.series {
        if let Some(t) = b.series.iter().find(|t| t.probe == s.probe) {
            s.mean = match s.probe {
                // A latency's whole-window value is its peak.
                Probe::TopicLatency { .. } => s.mean.max(t.mean),
                _ => (s.mean * a.duration_ms as f64 + t.mean * b.duration_ms as f64) / total,
            };
            s.values.extend_from_slice(&t.values);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use configbot_api::measure::ProbeSeries;

    #[test]
    fn core_topics_get_a_latency_probe_and_their_peaks_are_read_by_metric() {
        let mut delivered = def("delivered", true, true, 10.0);
        delivered.probe = Probe::TopicRate {
            topic: "/t".into(),
            subscriber: Some("/s".into()),
        };
        let defs = [
            def("corners", true, true, 25.0),
            def("flow", false, true, 4.0),
            delivered,
        ];
        let probes = latency_probes(&defs);
        assert_eq!(
            probes,
            vec![Probe::TopicLatency {
                topic: "/corners".into()
            }],
            "core, and as a plain subscriber sees it"
        );
        let report = |values: Vec<f64>| MeasureReport {
            started_unix_ms: 0,
            duration_ms: 2000,
            sub_window_ms: 1000,
            series: vec![ProbeSeries {
                probe: probes[0].clone(),
                mean: values.iter().copied().fold(0.0, f64::max),
                values,
            }],
        };
        let (a, b) = (report(vec![0.033, 0.133]), report(vec![0.2, 0.05]));
        let peaks = latency_peaks(&defs, &a);
        assert_eq!(peaks.len(), 1);
        assert_eq!(peaks["corners"], vec![0.033, 0.133]);
        let both = concat(&a, &b);
        assert_eq!(both.series[0].values, vec![0.033, 0.133, 0.2, 0.05]);
        assert_eq!(
            both.series[0].mean, 0.2,
            "a latency's whole window is its peak"
        );
    }

    fn def(name: &str, core: bool, at_least: bool, target: f64) -> MetricDef {
        MetricDef {
            name: name.into(),
            app: "a".into(),
            probe: Probe::TopicRate {
                topic: format!("/{name}"),
                subscriber: None,
            },
            at_least,
            target,
            core,
            weight: 1.0,
        }
    }

    fn report(series: &[(&str, &[f64])]) -> MeasureReport {
        MeasureReport {
            started_unix_ms: 0,
            duration_ms: 1000 * series[0].1.len() as u64,
            sub_window_ms: 1000,
            series: series
                .iter()
                .map(|(n, v)| ProbeSeries {
                    probe: Probe::TopicRate {
                        topic: format!("/{n}"),
                        subscriber: None,
                    },
                    values: v.to_vec(),
                    mean: v.iter().sum::<f64>() / v.len() as f64,
                })
                .collect(),
        }
    }

    #[test]
    fn satisfaction_table() {
        let defs = vec![def("cmd", true, true, 35.0), def("lat", true, false, 0.1)];
        let cases: Vec<(&[f64], &[f64], f64)> = vec![
            (&[40.0, 40.0, 40.0, 40.0], &[0.05; 4], 1.0),
            (&[40.0, 34.9, 40.0, 40.0], &[0.05; 4], 0.75),
            (&[40.0, 34.9, 40.0, 40.0], &[0.2, 0.05, 0.05, 0.05], 0.5),
            (&[10.0; 4], &[0.2; 4], 0.0),
        ];
        for (cmd, lat, want) in cases {
            let r = report(&[("cmd", cmd), ("lat", lat)]);
            assert_eq!(satisfaction(&defs, &r), want, "{cmd:?} {lat:?}");
        }
    }

    #[test]
    fn objectives_are_capped_and_scalarised() {
        let mut defs = vec![
            def("cmd", true, true, 35.0),
            def("det", false, true, 10.0),
            def("web", false, true, 20.0),
        ];
        defs[2].weight = 3.0;
        let means: BTreeMap<String, f64> = [("det", 15.0), ("web", 10.0)]
            .into_iter()
            .map(|(k, v)| (k.to_string(), v))
            .collect();
        assert_eq!(scalarize(&defs, &means, Scalarization::MaxMin), Some(0.5));
        // (1.0 * 1 + 0.5 * 3) / 4
        assert_eq!(
            scalarize(&defs, &means, Scalarization::Weighted),
            Some(0.625)
        );
        assert_eq!(scalarize(&defs[..1], &means, Scalarization::MaxMin), None);
        assert_eq!(normalise(&def("l", false, false, 0.1), 0.2), 0.5);
    }

    #[test]
    fn objectives_take_the_whole_window_value_and_constraints_their_windows() {
        // A 0.7 Hz objective counted in 1 s windows reads 0.6 over five;
        // the agent's whole-window value (by arrivals) says 0.7.
        let defs = vec![def("cmd", true, true, 35.0), def("det", false, true, 1.0)];
        let mut r = report(&[
            ("cmd", &[36.0, 30.0, 36.0, 36.0, 36.0]),
            ("det", &[1.0, 0.0, 1.0, 1.0, 0.0]),
        ]);
        r.series[1].mean = 0.7;
        let e = evaluate(&defs, &r, Scalarization::MaxMin);
        assert_eq!(e.means["det"], 0.7);
        assert_eq!(e.objective, Some(0.7));
        assert_eq!(e.worst, vec![30.0]);
        assert!(!e.feasible);
    }

    #[test]
    fn feasibility_needs_margin_not_just_the_mean() {
        let defs = vec![def("cmd", true, true, 35.0)];
        let steady = report(&[("cmd", &[36.0, 36.0, 36.0, 36.0, 36.0])]);
        let noisy = report(&[("cmd", &[33.0, 39.0, 34.0, 38.0, 36.0])]);
        let e = evaluate(&defs, &steady, Scalarization::MaxMin);
        assert!(e.feasible);
        assert_eq!(e.constraints, vec![36.0]);
        let e = evaluate(&defs, &noisy, Scalarization::MaxMin);
        assert_eq!(e.means["cmd"], 36.0);
        assert!(!e.feasible, "mean meets the target, sub-windows do not");
        assert_eq!(e.satisfaction, 0.6);
    }

    #[test]
    fn ten_windows_on_target_are_held_every_window_however_spread() {
        let defs = vec![def("cmd", true, true, 25.0), def("det", false, true, 5.0)];
        // Session 62's seed 3, trial 19: worst 26, the bound below 25.
        let spread: Vec<f64> = [26.0, 30.0, 27.0, 31.0, 29.0].repeat(2);
        let r = report(&[("cmd", &spread), ("det", &[1.0; 10])]);
        assert!(!evaluate(&defs, &r, Scalarization::MaxMin).feasible);
        assert!(held_every_window(&defs, &r));
        // Five windows are too few, however steady.
        let r = report(&[("cmd", &[29.0; 5]), ("det", &[1.0; 5])]);
        assert!(!held_every_window(&defs, &r));
        // One window of ten missed.
        let mut one_low = spread.clone();
        one_low[3] = 24.0;
        let r = report(&[("cmd", &one_low), ("det", &[1.0; 10])]);
        assert!(!held_every_window(&defs, &r));
        // Every core constraint counts; non-core ones do not.
        let defs = vec![
            def("cmd", true, true, 25.0),
            def("lat", true, false, 0.1),
            def("det", false, true, 5.0),
        ];
        let r = report(&[("cmd", &spread), ("lat", &[0.05; 10]), ("det", &[0.0; 10])]);
        assert!(held_every_window(&defs, &r));
        let r = report(&[("cmd", &spread), ("lat", &[0.05; 9]), ("det", &[0.0; 10])]);
        assert!(!held_every_window(&defs, &r), "lat has nine windows");
        // No core constraint: nothing to judge by.
        let defs = vec![def("det", false, true, 5.0)];
        assert!(!held_every_window(&defs, &report(&[("det", &[9.0; 10])])));
    }

    #[test]
    fn a_margin_short_of_the_bar_is_told_until_the_minute_is_measured() {
        let defs = vec![def("cmd", true, true, 25.0), def("det", false, true, 5.0)];
        // Mean 29, sd 1.44: 2.33 sd (3.4) clears the target's 4 Hz, 2.92 sd (4.2) does not.
        let close: Vec<f64> = [27.0, 31.0, 29.0, 28.0, 30.0].repeat(6);
        let r = report(&[("cmd", &close), ("det", &[1.0; 30])]);
        assert!(evaluate(&defs, &r, Scalarization::MaxMin).feasible);
        assert!(short_of_bar(&defs, &r));
        // Half the spread: 2.92 sd clears it.
        let wide_margin: Vec<f64> = [28.0, 30.0, 29.0, 28.5, 29.5].repeat(6);
        let r = report(&[("cmd", &wide_margin), ("det", &[1.0; 30])]);
        assert!(!short_of_bar(&defs, &r));
        // A whole minute is judged by its windows, not told again.
        let minute = close.repeat(2);
        let r = report(&[("cmd", &minute), ("det", &[1.0; 60])]);
        assert!(!short_of_bar(&defs, &r));
        // Only core constraints count; at-most ones by their upper side.
        let defs = vec![def("det", false, true, 5.0), def("lat", true, false, 0.1)];
        let lat = [0.05, 0.07, 0.06, 0.05, 0.07].repeat(6);
        let r = report(&[("det", &[1.0; 30]), ("lat", &lat)]);
        assert!(!short_of_bar(&defs, &r));
        let lat = [0.05, 0.085, 0.06, 0.05, 0.075].repeat(6);
        let r = report(&[("det", &[1.0; 30]), ("lat", &lat)]);
        assert!(evaluate(&defs, &r, Scalarization::MaxMin).feasible);
        assert!(short_of_bar(&defs, &r));
    }

    #[test]
    fn few_messages_counts_uncapped_at_least_rates_of_non_core_apps() {
        let defs = vec![
            def("cmd", true, true, 35.0),
            def("lines", false, true, 1.0),
            def("flow", false, true, 4.0),
            def("slow", false, true, 0.5),
            def("lat", false, false, 0.2),
        ];
        // Five 1 s windows: lines 0.6 Hz (3 messages), flow 2 Hz (10),
        // slow 0.6 Hz (3, but over its 0.5 Hz cap), lat an at-most value.
        let r = report(&[
            ("cmd", &[1.0; 5]),
            ("lines", &[0.6; 5]),
            ("flow", &[2.0; 5]),
            ("slow", &[0.6; 5]),
            ("lat", &[0.1; 5]),
        ]);
        let few = few_messages(&defs, &r);
        assert_eq!(few.len(), 1, "{few:?}");
        assert_eq!(few[0].0, "lines");
        assert!((few[0].1 - 3.0).abs() < 1e-9, "{few:?}");
        // Twice as long: six messages, enough to rank by.
        let r = report(&[("cmd", &[1.0; 10]), ("lines", &[0.6; 10])]);
        assert!(few_messages(&defs[..2], &r).is_empty());
        // A topic that sent nothing counts zero messages.
        let r = report(&[("cmd", &[1.0; 5]), ("flow", &[2.0; 5])]);
        let few = few_messages(&defs[..3], &r);
        assert_eq!(few, vec![("lines".to_string(), 0.0)]);
    }

    #[test]
    fn early_stop_and_concat() {
        let defs = vec![def("cmd", true, true, 35.0), def("det", false, true, 5.0)];
        let bad = report(&[("cmd", &[20.0, 25.0]), ("det", &[1.0, 1.0])]);
        let near = report(&[("cmd", &[20.0, 30.0]), ("det", &[1.0, 1.0])]);
        assert_eq!(clearly_infeasible(&defs, &bad, 0.8), Some("cmd".into()));
        assert_eq!(clearly_infeasible(&defs, &near, 0.8), None);
        let c = concat(&bad, &near);
        assert_eq!(c.duration_ms, 4000);
        assert_eq!(c.series[0].values, vec![20.0, 25.0, 20.0, 30.0]);
        assert_eq!(c.series[0].mean, 23.75);
    }

    #[test]
    fn surplus_is_measured_against_the_level_at_which_more_stops_counting() {
        let defs = vec![
            def("core", true, true, 25.0),
            def("people", false, true, 3.0),
            def("bright", false, true, 15.0),
            def("latency", false, false, 0.1),
        ];
        let means: BTreeMap<String, f64> = [
            ("core", 28.0),
            ("people", 1.0),
            ("bright", 20.0),
            ("latency", 0.05),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
        // Max-min: the level is people's 1/3; bright measured 4 times that.
        let s = surplus(&defs, &means, Scalarization::MaxMin);
        assert_eq!(s.keys().collect::<Vec<_>>(), vec!["bright"]);
        assert!((s["bright"] - 4.0).abs() < 1e-9);
        // Weighted: each counts up to its target, so only bright's cap is passed.
        let s = surplus(&defs, &means, Scalarization::Weighted);
        assert!((s["bright"] - 20.0 / 15.0).abs() < 1e-9);
        assert_eq!(s.len(), 1);
        // At level 0 nothing is known to be in surplus.
        let mut none = means.clone();
        none.insert("people".into(), 0.0);
        assert!(surplus(&defs, &none, Scalarization::MaxMin).is_empty());
    }

    #[test]
    fn a_lift_raises_the_worst_objectives_past_the_next_one_up() {
        let defs = vec![
            def("core", true, true, 25.0),
            def("people", false, true, 3.0),
            def("flow", false, true, 3.0),
            def("bright", false, true, 15.0),
        ];
        let means = |people: f64, flow: f64, bright: f64| -> BTreeMap<String, f64> {
            [
                ("core", 28.0),
                ("people", people),
                ("flow", flow),
                ("bright", bright),
            ]
            .into_iter()
            .map(|(k, v)| (k.to_string(), v))
            .collect()
        };
        // The restrictive corner of real-nodelets: bright's 0.5 Hz (0.033)
        // sets the level; people and flow's 0.5 Hz (0.167) is the next.
        let l = lift(&defs, &means(0.5, 0.5, 0.5), Scalarization::MaxMin).unwrap();
        assert!((l.level - 0.5 / 15.0).abs() < 1e-9);
        assert_eq!(l.next.0, "people");
        assert_eq!(l.factors.keys().collect::<Vec<_>>(), vec!["bright"]);
        // To 1.5 times the next level: 0.25 of 15 Hz, from 0.5 Hz.
        assert!((l.factors["bright"] - 7.5).abs() < 1e-9, "{l:?}");
        // Objectives within LIFT_TIE of the worst rise with it; the next
        // level is capped at 1.
        let l = lift(&defs, &means(1.0, 1.2, 30.0), Scalarization::MaxMin).unwrap();
        assert_eq!(l.factors.keys().collect::<Vec<_>>(), vec!["flow", "people"]);
        assert_eq!(l.next, ("bright".to_string(), 1.0));
        assert!((l.factors["people"] - 4.5).abs() < 1e-9, "{l:?}");
        // Nothing to lift: every objective tied, the worst at 0, or
        // weighted scalarisation (every objective counts there).
        assert_eq!(
            lift(&defs, &means(1.0, 1.1, 5.5), Scalarization::MaxMin),
            None
        );
        assert_eq!(
            lift(&defs, &means(0.0, 1.0, 5.0), Scalarization::MaxMin),
            None
        );
        assert_eq!(
            lift(&defs, &means(0.5, 0.5, 0.5), Scalarization::Weighted),
            None
        );
        // One objective has nothing to pass.
        assert_eq!(
            lift(&defs[..2], &means(0.5, 0.5, 0.5), Scalarization::MaxMin),
            None
        );
    }
}
