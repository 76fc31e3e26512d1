//! The balanced config (pure): under max-min scalarisation, a config
//! computed from what the trials measured rather than asked of the models.
//! Each objective whose app has a CPU knob and an input adaptor of its own
//! gets a cost model fitted to the trials (CPU used = `a` per message put
//! out + `b` per message taken in) and the input it needs, and all of them
//! get the same share of their targets: as high as the CPU the trials'
//! non-core apps used together, in a trial that held every core target,
//! allows ([`balanced`]). The objectives without such an app keep what the
//! base trial measured, so under max-min the config promises no more than
//! the worst of them (`Balanced::promise`), and it is measured only when
//! that is more than the base trial's objective (`search::balance_next`).
//!
//! Why: the non-core detectors of a real stack are saturated in most
//! trials, and a saturated app takes an equal CFS share of what the core
//! path leaves whatever its input, so the search's trials put the CPU where
//! the apps with the most input were, not where the worst objective needed
//! it, and trimming an input by the objective's surplus frees nothing while
//! the app stays saturated. Measured on real-perception (session 49): the
//! trials fed the flow detector 10–28 Hz of camera for 2–3.3 Hz of flow,
//! while the oracle's config feeds it 3.4 Hz, leaving the rest for the
//! lines detector, the objective every trial was worst at. A balanced
//! config feeds each app just above what it is to put out, with a CPU limit
//! just above what that costs, so none of them is saturated and each gets
//! the CPU its share of the level costs.

use configbot_api::measure::Probe;

use super::knobs::{KnobSpace, KnobTarget};
use super::machine::TrialRecord;
use super::measure::{self, MetricDef};

/// An app is fed this many times the input its output needs: a short
/// window counts a slow input to ±10 %, and an app a little short of input
/// drops its objective below the level.
pub const INPUT_HEADROOM: f64 = 1.15;
/// An app's CPU limit is this many times what its share is modelled to
/// cost: the input, not the limit, is to hold it back.
pub const CPU_HEADROOM: f64 = 1.3;
/// The level is not set above this share of the targets (capped objectives
/// count no more than their cap; a little above it keeps them there).
pub const LEVEL_CAP: f64 = 1.1;
/// An app that measured less than this share of its input as output in
/// every trial is fed as if it put out this share.
pub const MIN_YIELD: f64 = 0.05;
/// Trials an app must have been measured in (with output, input and CPU
/// use) for its cost model.
pub const MIN_FIT: usize = 3;

/// The cost model and the share of one balanced objective.
#[derive(Debug, Clone, PartialEq)]
pub struct App {
    pub metric: String,
    /// Its node, and the indices of its CPU knob and input knob.
    pub node: String,
    pub cpu_knob: usize,
    pub input_knob: usize,
    /// CPUs per message put out.
    pub a: f64,
    /// CPUs per message taken in.
    pub b: f64,
    /// The most output per input any trial measured (at most 1).
    pub yield_: f64,
    /// The output it is to put out, in Hz.
    pub output: f64,
    /// Its input and CPU limit in the balanced config.
    pub input: f64,
    pub cpu: f64,
}

/// A balanced config.
#[derive(Debug, Clone, PartialEq)]
pub struct Balanced {
    /// The share of its target each balanced objective is to reach.
    pub level: f64,
    /// The max-min objective the config promises: the level, or the worst
    /// objective it does not balance as the base trial measured it, if
    /// that is lower (it leaves those objectives' knobs as they were).
    pub promise: f64,
    /// The CPUs the non-core apps may use together, and what the others
    /// (pinned or not balanced) used in the base trial.
    pub budget: f64,
    pub others: f64,
    pub apps: Vec<App>,
    /// The config's point: the base trial's, with each balanced app's
    /// CPU and input set.
    pub x: Vec<f64>,
}

impl Balanced {
    /// What the event of a balanced trial says.
    pub fn text(&self) -> String {
        let apps: Vec<String> = self
            .apps
            .iter()
            .map(|a| {
                format!(
                    "{} {:.2} Hz ({:.2} Hz in, {:.2} CPU)",
                    a.metric, a.output, a.input, a.cpu
                )
            })
            .collect();
        format!(
            "each at {:.0} % of its target within the {:.2} CPUs the non-core apps used in a trial that held ({:.2} of them taken by the others): {}",
            self.level * 100.0,
            self.budget,
            self.others,
            apps.join(", ")
        )
    }
}

/// The knobs of an objective's own app: the index of its CPU knob and of
/// its one input adaptor, each working for that objective alone.
fn own_knobs(knobs: &KnobSpace, metric: &str) -> Option<(usize, usize, String)> {
    let alone = |i: &usize| {
        let k = &knobs.knobs[*i];
        k.restricts_non_core && k.feeds.len() == 1 && k.feeds[0] == metric
    };
    let cpu: Vec<usize> = (0..knobs.knobs.len())
        .filter(alone)
        .filter(|&i| matches!(knobs.knobs[i].target, KnobTarget::Cpu { .. }))
        .collect();
    let [c] = cpu[..] else { return None };
    let KnobTarget::Cpu { node } = &knobs.knobs[c].target else {
        return None;
    };
    let inputs: Vec<usize> = (0..knobs.knobs.len())
        .filter(alone)
        .filter(|&i| {
            matches!(&knobs.knobs[i].target,
                KnobTarget::Adaptor { subscriber, .. } if subscriber == node)
        })
        .collect();
    let [a] = inputs[..] else { return None };
    Some((c, a, node.clone()))
}

/// Least squares of `cpu = a·out + b·in` through the origin, both
/// coefficients at least 0 (pure). `None` when no positive cost per
/// output fits.
pub fn fit(points: &[(f64, f64, f64)]) -> Option<(f64, f64)> {
    let (mut oo, mut oi, mut ii, mut co, mut ci) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for &(o, i, c) in points {
        oo += o * o;
        oi += o * i;
        ii += i * i;
        co += c * o;
        ci += c * i;
    }
    let det = oo * ii - oi * oi;
    if det > 1e-9 * oo * ii {
        let a = (co * ii - ci * oi) / det;
        let b = (ci * oo - co * oi) / det;
        if a > 0.0 && b >= 0.0 {
            return Some((a, b));
        }
    }
    (oo > 0.0 && co > 0.0).then(|| (co / oo, 0.0))
}

/// The balanced config from `trials`, its other knobs as in `base` (pure;
/// see the module docs), with the CPU the trials' non-core apps used
/// together scaled by `shrink` (less than 1 after a balanced trial missed a
/// core target). Meant for max-min scalarisation, where only the worst
/// share counts (`search::balance_next` asks for it there alone). `None`
/// when no objective has an app of its own with a cost model, when the
/// budget leaves nothing for them, or when the config is one a trial
/// already measured.
pub fn balanced(
    knobs: &KnobSpace,
    defs: &[MetricDef],
    trials: &[TrialRecord],
    base: &TrialRecord,
    shrink: f64,
) -> Option<Balanced> {
    let nodes = knobs.non_core_nodes();
    let measured =
        |t: &&TrialRecord| !t.censored && nodes.iter().all(|n| t.eval.usage.contains_key(n));
    let used = |t: &TrialRecord| nodes.iter().map(|n| t.eval.usage[n]).sum::<f64>();
    let budget = trials
        .iter()
        .filter(measured)
        .filter(|t| t.feasible())
        .map(used)
        .fold(0.0_f64, f64::max)
        * shrink;
    if !measured(&base) {
        return None;
    }
    let objectives: Vec<&MetricDef> = defs
        .iter()
        .filter(|d| !d.core && d.at_least && d.target > 0.0)
        .filter(|d| matches!(d.probe, Probe::TopicRate { .. }))
        .collect();
    let mut apps = Vec::new();
    for d in &objectives {
        let Some((c, i, node)) = own_knobs(knobs, &d.name) else {
            continue;
        };
        let points: Vec<(f64, f64, f64)> = trials
            .iter()
            .filter(measured)
            .filter_map(|t| {
                let out = t.eval.means.get(&d.name).copied()?;
                let input = *t.x.get(i)?;
                (out > 0.0 && input > 0.0).then(|| (out, input, t.eval.usage[&node]))
            })
            .collect();
        if points.len() < MIN_FIT {
            continue;
        }
        let Some((a, b)) = fit(&points) else {
            continue;
        };
        let yield_ = points
            .iter()
            .map(|(o, i, _)| (o / i).min(1.0))
            .fold(MIN_YIELD, f64::max);
        apps.push(App {
            metric: d.name.clone(),
            node,
            cpu_knob: c,
            input_knob: i,
            a,
            b,
            yield_,
            output: 0.0,
            input: 0.0,
            cpu: 0.0,
        });
    }
    if apps.is_empty() {
        return None;
    }
    let others = nodes
        .iter()
        .filter(|n| !apps.iter().any(|p| &p.node == *n))
        .map(|n| base.eval.usage[n])
        .fold(0.0, |a, u| a + u);
    let target = |m: &str| {
        objectives
            .iter()
            .find(|d| d.name == m)
            .map_or(0.0, |d| d.target)
    };
    // CPUs per unit of level: each app's share costs its output at the
    // level plus the input that output needs.
    let per_level: f64 = apps
        .iter()
        .map(|p| target(&p.metric) * (p.a + p.b * INPUT_HEADROOM / p.yield_))
        .sum();
    let spare = budget - others;
    if spare <= 0.0 || per_level <= 0.0 {
        return None;
    }
    // The objectives not balanced stay as the base trial measured them:
    // lifting the balanced ones past them buys nothing under max-min.
    let rest = objectives
        .iter()
        .filter(|d| !apps.iter().any(|p| p.metric == d.name))
        .map(|d| measure::normalise(d, base.eval.means.get(&d.name).copied().unwrap_or(0.0)))
        .fold(f64::INFINITY, f64::min);
    let level = (spare / per_level)
        .min(LEVEL_CAP)
        .min(rest * measure::LIFT_TIE);
    let mut x = base.x.clone();
    for p in &mut apps {
        let (kc, ki) = (&knobs.knobs[p.cpu_knob], &knobs.knobs[p.input_knob]);
        p.output = level * target(&p.metric);
        p.input = (p.output * INPUT_HEADROOM / p.yield_).clamp(ki.min, ki.max);
        p.cpu = ((p.a * p.output + p.b * p.input) * CPU_HEADROOM).clamp(kc.min, kc.max);
        x[p.cpu_knob] = p.cpu;
        x[p.input_knob] = p.input;
    }
    let x = knobs.from_config(&knobs.to_config(&x));
    let seen = trials.iter().any(|t| {
        t.x.len() == x.len()
            && t.x
                .iter()
                .zip(&x)
                .all(|(a, b)| (a - b).abs() <= 0.02 * a.abs().max(b.abs()).max(1e-9))
    });
    (!seen).then_some(Balanced {
        level,
        promise: level.min(rest),
        budget,
        others,
        apps,
        x,
    })
}

#[cfg(test)]
mod tests {
    use configbot_manifests::ResourceConfig;

    use super::super::knobs::KnobDef;
    use super::super::measure::Evaluation;
    use super::*;

    fn knob(target: KnobTarget, min: f64, max: f64, feeds: &[&str]) -> KnobDef {
        let name = match &target {
            KnobTarget::Cpu { node } => format!("cpu:{node}"),
            KnobTarget::Adaptor { subscriber, .. } => format!("rate:{subscriber}"),
        };
        KnobDef {
            name,
            target,
            min,
            max,
            restricts_non_core: true,
            feeds: feeds.iter().map(|f| f.to_string()).collect(),
        }
    }
    fn cpu(node: &str, feeds: &[&str]) -> KnobDef {
        knob(KnobTarget::Cpu { node: node.into() }, 0.05, 2.0, feeds)
    }
    fn input(node: &str, feeds: &[&str]) -> KnobDef {
        let t = KnobTarget::Adaptor {
            topic: "/image".into(),
            subscriber: node.into(),
        };
        knob(t, 0.5, 30.0, feeds)
    }

    /// Flow (target 4 Hz) and lines (1 Hz) with an app each, a debugging
    /// view pinned at its minimum; `extra` knobs after them.
    fn space(extra: Vec<KnobDef>) -> KnobSpace {
        let mut knobs = vec![
            cpu("/flow", &["flow"]),
            input("/flow", &["flow"]),
            cpu("/lines", &["lines"]),
            input("/lines", &["lines"]),
        ];
        knobs.extend(extra);
        KnobSpace {
            knobs,
            period_micros: 100_000,
            pinned: vec![cpu("/debug", &[])],
            ..KnobSpace::default()
        }
    }

    fn defs(names: &[(&str, f64)]) -> Vec<MetricDef> {
        names
            .iter()
            .map(|(n, t)| MetricDef::rate_at_least(n, n, &format!("/{n}/out"), *t, false))
            .collect()
    }

    /// A trial at `x` whose apps put out `outs` (by metric) and used the
    /// CPU `use_` (by node), every core target held.
    fn trial(x: &[f64], outs: &[(&str, f64)], use_: &[(&str, f64)]) -> TrialRecord {
        TrialRecord {
            config: ResourceConfig::default(),
            x: x.to_vec(),
            eval: Evaluation {
                means: outs.iter().map(|(m, v)| (m.to_string(), *v)).collect(),
                usage: use_.iter().map(|(n, v)| (n.to_string(), *v)).collect(),
                objective: Some(0.2),
                feasible: true,
                satisfaction: 1.0,
                ..Evaluation::default()
            },
            censored: false,
        }
    }

    /// Flow costs 0.1 CPU per output and 0.004 per input, lines 0.5 and
    /// 0.004; each puts out `yield_` of its input up to what its CPU buys.
    fn modelled(x: &[f64], yield_: f64) -> TrialRecord {
        let out = |c: f64, i: f64, a: f64| (yield_ * i).min((c - 0.004 * i).max(0.0) / a);
        let (flow, lines) = (out(x[0], x[1], 0.1), out(x[2], x[3], 0.5));
        trial(
            x,
            &[("flow", flow), ("lines", lines)],
            &[
                ("/flow", 0.1 * flow + 0.004 * x[1]),
                ("/lines", 0.5 * lines + 0.004 * x[3]),
                ("/debug", 0.05),
            ],
        )
    }

    #[test]
    fn the_cost_fit_recovers_cost_per_output_and_per_input() {
        // cpu = 0.1·out + 0.01·in, at several regimes.
        let pts: Vec<(f64, f64, f64)> = [(3.0, 3.0), (3.0, 20.0), (5.0, 30.0), (1.0, 1.5)]
            .iter()
            .map(|&(o, i)| (o, i, 0.1 * o + 0.01 * i))
            .collect();
        let (a, b) = fit(&pts).unwrap();
        assert!((a - 0.1).abs() < 1e-9 && (b - 0.01).abs() < 1e-9, "{a} {b}");
        // Input and output in proportion: no way to tell them apart, the
        // cost is put on the output.
        let pts = [(1.0, 2.0, 0.3), (2.0, 4.0, 0.6)];
        let (a, b) = fit(&pts).unwrap();
        assert!((a - 0.3).abs() < 1e-9 && b == 0.0, "{a} {b}");
        assert_eq!(fit(&[(1.0, 1.0, 0.0)]), None);
    }

    #[test]
    fn a_balanced_config_gives_each_app_the_input_and_cpu_of_the_same_share_of_its_target() {
        let k = space(vec![]);
        let d = defs(&[("flow", 4.0), ("lines", 1.0)]);
        // Saturated trials (much input, little CPU) and one input-bound.
        let trials: Vec<TrialRecord> = [
            [0.3, 20.0, 0.3, 20.0],
            [0.2, 2.0, 0.4, 10.0],
            [0.35, 25.0, 0.2, 3.0],
            [0.15, 1.0, 0.3, 0.5],
        ]
        .iter()
        .map(|x| modelled(x, 1.0))
        .collect();
        let budget = trials
            .iter()
            .map(|t| t.eval.usage.values().sum::<f64>())
            .fold(0.0, f64::max);
        let b = balanced(&k, &d, &trials, &trials[0], 1.0).unwrap();
        assert!((b.budget - budget).abs() < 1e-9 && (b.others - 0.05).abs() < 1e-9);
        // What one unit of level costs both apps at 1.15 times the input
        // their output needs.
        let per_level = 4.0 * (0.1 + 0.004 * 1.15) + (0.5 + 0.004 * 1.15);
        let level = (budget - 0.05) / per_level;
        assert!((b.level - level).abs() < 1e-6, "{b:?}");
        assert!(b.level < LEVEL_CAP);
        assert_eq!(b.promise, b.level, "every objective is balanced");
        let flow = &b.apps[0];
        assert!((flow.a - 0.1).abs() < 1e-6 && (flow.b - 0.004).abs() < 1e-6);
        assert!((flow.output - 4.0 * level).abs() < 1e-6);
        assert!((b.x[1] - flow.output * 1.15).abs() < 0.01, "{:?}", b.x);
        assert!((b.x[0] - (0.1 * flow.output + 0.004 * b.x[1]) * 1.3).abs() < 0.002);
        let lines = &b.apps[1];
        assert!((b.x[3] - lines.output * 1.15).abs() < 0.01);
        assert!(b.text().contains("flow"), "{}", b.text());
        // Half the budget after two balanced misses, say: less for each.
        let less = balanced(&k, &d, &trials, &trials[0], 0.5).unwrap();
        assert!(less.level < b.level && less.x[1] < b.x[1] && less.x[3] < b.x[3]);
        // Once measured as planned, it is not proposed again.
        let outs: Vec<(&str, f64)> = b
            .apps
            .iter()
            .map(|p| (p.metric.as_str(), p.output))
            .collect();
        let cost = |p: &App| p.a * p.output + p.b * p.input;
        let mut seen = trials.clone();
        seen.push(trial(
            &b.x,
            &outs,
            &[
                ("/flow", cost(flow)),
                ("/lines", cost(lines)),
                ("/debug", 0.05),
            ],
        ));
        assert_eq!(balanced(&k, &d, &seen, &trials[0], 1.0), None);
        // An app that puts out half of what it takes in is fed twice as much.
        let halves: Vec<TrialRecord> = trials.iter().map(|t| modelled(&t.x, 0.5)).collect();
        let h = balanced(&k, &d, &halves, &halves[0], 1.0).unwrap();
        assert!((h.apps[0].yield_ - 0.5).abs() < 1e-6, "{h:?}");
        assert!((h.x[1] - h.apps[0].output * 1.15 / 0.5).abs() < 0.01);
    }

    #[test]
    fn an_objective_without_an_app_of_its_own_holds_the_level_near_where_it_measured() {
        // People's app has only a CPU knob that also works for flow: it is
        // not balanced, and the base measured it at 30 % of its target.
        let k = space(vec![cpu("/people", &["people", "flow"])]);
        let d = defs(&[("flow", 4.0), ("lines", 1.0), ("people", 2.0)]);
        let trials: Vec<TrialRecord> = [
            [0.3, 20.0, 0.3, 20.0, 0.5],
            [0.2, 2.0, 0.4, 10.0, 0.5],
            [0.35, 25.0, 0.2, 3.0, 0.5],
        ]
        .iter()
        .map(|x| {
            let mut t = modelled(x, 1.0);
            t.eval.means.insert("people".into(), 0.6);
            t.eval.usage.insert("/people".into(), 0.5);
            t
        })
        .collect();
        let b = balanced(&k, &d, &trials, &trials[0], 1.0).unwrap();
        assert_eq!(b.apps.len(), 2);
        assert!((b.level - 0.3 * measure::LIFT_TIE).abs() < 1e-9, "{b:?}");
        assert!(
            (b.promise - 0.3).abs() < 1e-9,
            "people, not balanced, bounds what it promises: {b:?}"
        );
        assert!((b.others - 0.55).abs() < 1e-9);
        assert_eq!(b.x[4], 0.5, "the knob not balanced keeps the base's value");
    }

    #[test]
    fn no_balanced_config_without_the_apps_cpu_use_or_enough_trials() {
        let k = space(vec![]);
        let d = defs(&[("flow", 4.0), ("lines", 1.0)]);
        let x = [
            [0.3, 20.0, 0.3, 20.0],
            [0.2, 2.0, 0.4, 10.0],
            [0.35, 25.0, 0.2, 3.0],
        ];
        let mut trials: Vec<TrialRecord> = x.iter().map(|x| modelled(x, 1.0)).collect();
        assert!(balanced(&k, &d, &trials, &trials[0], 1.0).is_some());
        // Two trials are too few to fit a cost model to.
        assert_eq!(balanced(&k, &d, &trials[..2], &trials[0], 1.0), None);
        // Trials measured without the non-core nodes' use (a run resumed
        // from before it was measured) teach nothing.
        for t in &mut trials {
            t.eval.usage.clear();
        }
        assert_eq!(balanced(&k, &d, &trials, &trials[0], 1.0), None);
    }
}
