//! The knob space of a tuning run (pure): a CPU-limit knob per running node
//! of the stack (bounds from `spec.knobs.cpu`, per-node overrides; core nodes
//! fixed when `fixCoreNodes`), and an adaptor-rate knob per edge the data-plane
//! policy selects (topic above `minTopicRateHz` touching a non-core app, plus
//! include/exclude) with bounds `[minRateHz, source rate]`. Maps optimizer
//! points to `ResourceConfig`s and back.
//!
//! The live graph prunes the space: a non-core node whose outputs reach no
//! metric (no path of topics from it to a metric's topic, and no metric on
//! its CPU) cannot help an objective and only takes CPU from the others, so
//! its CPU knob and the adaptors feeding it are *pinned* at their minimum and
//! get no search dimension ([`KnobSpace::pinned`]). Knobs that act on the same
//! node (its CPU and its input adaptors) are reported as acting together
//! ([`KnobSpace::together`]).
//!
//! The core nodes' CPU weight is no knob: a run starts with every node at
//! the same weight and gives the core nodes [`CORE_WEIGHT`] in every config
//! from the moment a trial or a verification misses in bursts
//! ([`KnobSpace::weighted`], set by `outcome::weigh_on_bursts`). Measured
//! two other ways on this machine class (docs/tuning-history.md, sessions
//! 23 and 24): weighted in every config, the real stacks' core trackers
//! stopped dropping frames when the non-core detectors were busy at once,
//! but Basic-NAV's detector lost its objective; searched as a knob, the
//! extra dimension cost the real nodelet stack its objective.

use std::collections::BTreeMap;

use configbot_api::graph::{EdgeId, Graph};
use configbot_api::policy::{self, AppOf, EdgeSelector, PolicyConfig};
use configbot_manifests::performance_spec::KnobStatus;
use configbot_manifests::{AdaptorRate, PerformanceSpecSpec, ResourceConfig, RobotStackSpec};
use serde::{Deserialize, Serialize};

/// What one knob sets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "camelCase")]
pub enum KnobTarget {
    /// `cpu.max` of a node, in CPUs.
    Cpu { node: String },
    /// Rate of the adaptor on one subscription edge, in Hz.
    Adaptor { topic: String, subscriber: String },
}

/// One knob with its bounds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KnobDef {
    pub name: String,
    pub target: KnobTarget,
    pub min: f64,
    pub max: f64,
    /// Lowering this knob only takes CPU or input from a non-core app (a
    /// non-core node's CPU, or an adaptor feeding a non-core subscriber), so it
    /// cannot hurt a core service (see `search::every_config_as_safe_as`).
    #[serde(default)]
    pub restricts_non_core: bool,
    /// The objectives (non-core metrics) the knob's node works for: those
    /// a path of topics leads to from it, or, for an input a non-core app
    /// claims (`App::inputs`), the claiming apps' objectives. What
    /// [`KnobSpace::trimmed`] may take from it is judged by them alone.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub feeds: Vec<String>,
}

impl KnobDef {
    /// The value a config sets for `v`: rounded to 0.001 CPU or 0.01 Hz, so
    /// configs read well in status.
    fn as_set(&self, v: f64) -> f64 {
        match self.target {
            KnobTarget::Cpu { .. } => round(v, 1000.0),
            KnobTarget::Adaptor { .. } => round(v, 100.0),
        }
    }
}

/// The knobs of a run, in optimizer order.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct KnobSpace {
    /// The searched knobs (the optimizer's dimensions).
    pub knobs: Vec<KnobDef>,
    pub period_micros: u64,
    /// Knobs held at their minimum and not searched: they act only on
    /// non-core nodes whose outputs reach no metric.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub pinned: Vec<KnobDef>,
    /// Groups of searched knobs that act on the same node (its CPU and the
    /// adaptors feeding it): each group's knobs move its output together.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub together: Vec<Vec<String>>,
    /// The running core nodes: given [`CORE_WEIGHT`] once `weighted`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub core: Vec<String>,
    /// Every config gives the core nodes [`CORE_WEIGHT`] (see the module docs).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub weighted: bool,
}

/// The CPU weight of a core node in a weighted config (cgroup v2 units; a
/// non-core node keeps the default 100): under contention a core node gets
/// 100 times a non-core one's share, so it runs as soon as it is runnable.
/// Measured on the real two-path stack at one config, 90 s each with the same
/// limits and rates: the core tracker missed 25 Hz in 11 of 90 windows
/// unweighted (latency p99 151 ms) and in none weighted (p99 46 ms).
pub const CORE_WEIGHT: u32 = 10_000;

/// How far above the level at which it stops counting a trimmed objective
/// is kept ([`KnobSpace::trimmed`]): a short window counts a 1 Hz output
/// to ±20 %, and the level is the least of such counts.
pub const TRIM_HEADROOM: f64 = 1.5;
/// A trim that keeps more than this share of an input is not made: it
/// frees too little CPU to be worth a config that was not measured.
pub const TRIM_BELOW: f64 = 0.8;

/// The knob space could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum KnobError {
    #[error("knob {name}: bounds [{min}, {max}] are empty")]
    EmptyBounds { name: String, min: f64, max: f64 },
    #[error("optimizer space: {0}")]
    Space(String),
}

/// The inputs non-core apps claim in other apps' nodes (`App::inputs`),
/// each with whether any claiming app has a metric (an input that feeds no
/// measured app is pinned like a metric-less node).
fn claimed_inputs(stack: &RobotStackSpec, spec: &PerformanceSpecSpec) -> BTreeMap<EdgeId, bool> {
    let mut out: BTreeMap<EdgeId, bool> = BTreeMap::new();
    for app in stack.apps.iter().filter(|a| !a.core) {
        let measured = spec.metrics.iter().any(|m| m.app == app.name);
        for i in &app.inputs {
            let edge = EdgeId {
                topic: i.topic.clone(),
                subscriber: i.node.clone(),
            };
            *out.entry(edge).or_default() |= measured;
        }
    }
    out
}

/// The stack's apps as the adaptor policy reads them: each node's core
/// flag, and the inputs non-core apps claim (adapted as their own).
struct StackApps<'a> {
    core: &'a BTreeMap<&'a str, bool>,
    claimed: &'a BTreeMap<EdgeId, bool>,
}

impl AppOf for StackApps<'_> {
    fn is_core(&self, node: &str) -> Option<bool> {
        self.core.get(node).copied()
    }
    fn claims(&self, edge: &EdgeId) -> bool {
        self.claimed.contains_key(edge)
    }
}

/// Name of a CPU knob.
pub fn cpu_knob_name(node: &str) -> String {
    format!("cpu:{node}")
}

/// Name of an adaptor knob.
pub fn adaptor_knob_name(topic: &str, subscriber: &str) -> String {
    format!("rate:{topic}>{subscriber}")
}

/// The most CPU a node's knob may give it: the spec's bound for the node,
/// else its bound for every node, else (and at most) the robot's CPUs.
pub fn cpu_max(spec: &PerformanceSpecSpec, node: &str, cpus: f64) -> f64 {
    let cpu = &spec.knobs.cpu;
    cpu.nodes
        .iter()
        .find(|b| b.node == node)
        .and_then(|o| o.max)
        .or(cpu.max)
        .unwrap_or(cpus)
        .min(cpus)
}

/// Derive the knobs. `running` is the set of nodes alive on the robot (from
/// the graph); `rates` the measured rate of each topic; `cpus` the robot's CPUs.
pub fn derive(
    stack: &RobotStackSpec,
    spec: &PerformanceSpecSpec,
    graph: &Graph,
    rates: &BTreeMap<String, f64>,
    cpus: f64,
) -> Result<KnobSpace, KnobError> {
    let cpu = &spec.knobs.cpu;
    let feeds = feeds_a_metric(graph, spec);
    let objectives_of = objectives_fed(stack, spec, graph);
    let claimed = claimed_inputs(stack, spec);
    let core_of: BTreeMap<&str, bool> = stack
        .nodes()
        .map(|(app, n)| (n.name.as_str(), app.core))
        .collect();
    let mut knobs = Vec::new();
    for (app, node) in stack.nodes() {
        if !graph.nodes.contains_key(&node.name) {
            continue;
        }
        let over = cpu.nodes.iter().find(|b| b.node == node.name);
        if over.is_some_and(|o| o.fixed) || (app.core && cpu.fix_core_nodes && over.is_none()) {
            continue;
        }
        let min = over.and_then(|o| o.min).unwrap_or(cpu.min);
        let max = cpu_max(spec, &node.name, cpus);
        let name = cpu_knob_name(&node.name);
        if min.partial_cmp(&max) != Some(std::cmp::Ordering::Less) {
            return Err(KnobError::EmptyBounds { name, min, max });
        }
        knobs.push(KnobDef {
            name,
            target: KnobTarget::Cpu {
                node: node.name.clone(),
            },
            min,
            max,
            restricts_non_core: !app.core,
            feeds: objectives_of(&node.name, None),
        });
    }
    let a = &spec.knobs.adaptors;
    if a.enabled {
        let apps = StackApps {
            core: &core_of,
            claimed: &claimed,
        };
        let sel = |s: &configbot_manifests::performance_spec::EdgeSelector| EdgeSelector {
            topic: s.topic.clone(),
            subscriber: s.subscriber.clone(),
        };
        let mut cfg = PolicyConfig {
            min_topic_rate_hz: a.min_topic_rate_hz,
            include: a.include.iter().map(sel).collect(),
            ..PolicyConfig::default()
        };
        cfg.exclude.extend(a.exclude.iter().map(sel));
        for e in policy::select_adaptor_edges(graph, rates, &apps, &cfg) {
            let Some(&source) = rates.get(&e.topic) else {
                continue;
            };
            if source <= a.min_rate_hz {
                continue;
            }
            let restricts_non_core = apps.is_core(&e.subscriber) == Some(false) || apps.claims(&e);
            let feeds = objectives_of(&e.subscriber, Some(&e));
            knobs.push(KnobDef {
                name: adaptor_knob_name(&e.topic, &e.subscriber),
                target: KnobTarget::Adaptor {
                    topic: e.topic,
                    subscriber: e.subscriber,
                },
                min: a.min_rate_hz,
                max: source,
                restricts_non_core,
                feeds,
            });
        }
    }
    // A knob acting only on a non-core node that feeds no metric is pinned.
    let acts_on = |k: &KnobDef| match &k.target {
        KnobTarget::Cpu { node } => node.clone(),
        KnobTarget::Adaptor { subscriber, .. } => subscriber.clone(),
    };
    let idle = |k: &KnobDef| {
        if let KnobTarget::Adaptor { topic, subscriber } = &k.target
            && let Some(measured) = claimed.get(&EdgeId {
                topic: topic.clone(),
                subscriber: subscriber.clone(),
            })
        {
            return !measured;
        }
        let n = acts_on(k);
        core_of.get(n.as_str()) == Some(&false) && !feeds.contains(&n)
    };
    let (pinned, knobs): (Vec<KnobDef>, Vec<KnobDef>) = knobs.into_iter().partition(idle);
    let mut by_node: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for k in &knobs {
        by_node.entry(acts_on(k)).or_default().push(k.name.clone());
    }
    let together = by_node.into_values().filter(|g| g.len() > 1).collect();
    let core = stack
        .nodes()
        .filter(|(app, n)| app.core && graph.nodes.contains_key(&n.name))
        .map(|(_, n)| n.name.clone())
        .collect();
    Ok(KnobSpace {
        knobs,
        period_micros: cpu.period_micros,
        pinned,
        together,
        core,
        weighted: false,
    })
}

/// The nodes whose work can reach a metric (pure): a node that publishes a
/// metric's topic or has a CPU metric, and every node with a path of topics
/// (publisher → subscriber → what it publishes → ...) to such a node.
pub fn feeds_a_metric(
    graph: &Graph,
    spec: &PerformanceSpecSpec,
) -> std::collections::BTreeSet<String> {
    spec.metrics
        .iter()
        .flat_map(|m| upstream(graph, m))
        .collect()
}

/// The nodes whose work can reach metric `m` (pure): the publishers of its
/// topic (or the node of its CPU metric), and every node upstream of them.
/// Liveness topics (nodelet bonds) carry no data: a loader process that
/// only exchanges heartbeats with its manager feeds nothing.
fn upstream(
    graph: &Graph,
    m: &configbot_manifests::performance_spec::Metric,
) -> std::collections::BTreeSet<String> {
    use std::collections::BTreeSet;
    let mut reached: BTreeSet<String> = BTreeSet::new();
    if let Some(t) = &m.source.topic_rate
        && let Some(info) = graph.topics.get(&t.topic)
    {
        reached.extend(info.publishers.iter().cloned());
    }
    if let Some(c) = &m.source.cpu_usage {
        reached.insert(c.node.clone());
    }
    let mut frontier: Vec<String> = reached.iter().cloned().collect();
    while let Some(n) = frontier.pop() {
        for t in graph.topics.values().filter(|t| {
            t.subscribers.contains(&n) && configbot_api::policy::adaptable_type(&t.msg_type)
        }) {
            for p in &t.publishers {
                if reached.insert(p.clone()) {
                    frontier.push(p.clone());
                }
            }
        }
    }
    reached
}

/// The objectives a knob works for (pure, see [`KnobDef::feeds`]), as a
/// function of the node it acts on and, for an adaptor, its edge.
fn objectives_fed<'a>(
    stack: &'a RobotStackSpec,
    spec: &'a PerformanceSpecSpec,
    graph: &Graph,
) -> impl Fn(&str, Option<&EdgeId>) -> Vec<String> + 'a {
    let core_app = |app: &str| stack.app(app).is_none_or(|a| a.core);
    let reach: Vec<(&str, &str, std::collections::BTreeSet<String>)> = spec
        .metrics
        .iter()
        .filter(|m| !core_app(&m.app))
        .map(|m| (m.name.as_str(), m.app.as_str(), upstream(graph, m)))
        .collect();
    move |node: &str, edge: Option<&EdgeId>| {
        let claimants: Vec<&str> = edge
            .map(|e| {
                stack
                    .apps
                    .iter()
                    .filter(|a| !a.core)
                    .filter(|a| {
                        a.inputs
                            .iter()
                            .any(|i| i.topic == e.topic && i.node == e.subscriber)
                    })
                    .map(|a| a.name.as_str())
                    .collect()
            })
            .unwrap_or_default();
        reach
            .iter()
            .filter(|(_, app, nodes)| {
                if claimants.is_empty() {
                    nodes.contains(node)
                } else {
                    claimants.contains(app)
                }
            })
            .map(|(name, _, _)| name.to_string())
            .collect()
    }
}

impl KnobSpace {
    /// The optimizer's space: CPU knobs linear, adaptor rates on a log scale.
    pub fn optimizer_space(&self) -> Result<configbot_optimizer::Space, KnobError> {
        let knobs = self
            .knobs
            .iter()
            .map(|k| match k.target {
                KnobTarget::Cpu { .. } => configbot_optimizer::Knob::linear(&k.name, k.min, k.max),
                KnobTarget::Adaptor { .. } => configbot_optimizer::Knob::log(&k.name, k.min, k.max),
            })
            .collect();
        configbot_optimizer::Space::new(knobs).map_err(|e| KnobError::Space(e.to_string()))
    }

    /// The core nodes' weights in this run's configs: [`CORE_WEIGHT`] each
    /// once [`KnobSpace::weighted`], none before.
    pub fn core_weights(&self) -> BTreeMap<String, u32> {
        if !self.weighted {
            return BTreeMap::new();
        }
        self.core.iter().map(|n| (n.clone(), CORE_WEIGHT)).collect()
    }

    /// A trial's config as the run applies it now: with the core nodes'
    /// weights once [`KnobSpace::weighted`] (the trial may have been
    /// measured before that), unchanged before.
    pub fn weigh(&self, mut cfg: ResourceConfig) -> ResourceConfig {
        if self.weighted {
            cfg.cpu_weight = self.core_weights();
        }
        cfg
    }

    /// The config of a point (knob values in order, each as set:
    /// [`KnobDef::as_set`]; the core nodes' weights: [`KnobSpace::core_weights`]).
    pub fn to_config(&self, x: &[f64]) -> ResourceConfig {
        let mut cfg = ResourceConfig {
            cpu_period_micros: Some(self.period_micros),
            cpu_weight: self.core_weights(),
            ..ResourceConfig::default()
        };
        let pinned = self.pinned.iter().map(|k| (k, k.min));
        for (k, v) in self.knobs.iter().zip(x.iter().copied()).chain(pinned) {
            let v = v.clamp(k.min, k.max);
            match &k.target {
                KnobTarget::Cpu { node } => {
                    cfg.cpu.insert(node.clone(), k.as_set(v));
                }
                KnobTarget::Adaptor { topic, subscriber } => cfg.adaptors.push(AdaptorRate {
                    topic: topic.clone(),
                    subscriber: subscriber.clone(),
                    rate_hz: k.as_set(v),
                }),
            }
        }
        cfg
    }

    /// The config `current` as the knobs see it: the searched knobs at the
    /// point `x`, the pinned ones and the weights as `current` has them
    /// (unset when it does not set them): what a baseline measured, before
    /// anything was pinned or weighted.
    pub fn as_running(&self, x: &[f64], current: &ResourceConfig) -> ResourceConfig {
        let searched = KnobSpace {
            knobs: self.knobs.clone(),
            period_micros: self.period_micros,
            ..KnobSpace::default()
        };
        let mut cfg = searched.to_config(x);
        cfg.cpu_weight = current.cpu_weight.clone();
        for k in &self.pinned {
            match &k.target {
                KnobTarget::Cpu { node } => {
                    if let Some(v) = current.cpu.get(node) {
                        cfg.cpu.insert(node.clone(), *v);
                    }
                }
                KnobTarget::Adaptor { topic, subscriber } => cfg.adaptors.extend(
                    current
                        .adaptors
                        .iter()
                        .filter(|a| a.topic == *topic && a.subscriber == *subscriber)
                        .cloned(),
                ),
            }
        }
        cfg
    }

    /// The point of a config: a knob the config does not set is at its upper
    /// bound (unlimited CPU, pass-through adaptor); values are clamped into bounds.
    pub fn from_config(&self, cfg: &ResourceConfig) -> Vec<f64> {
        self.knobs
            .iter()
            .map(|k| {
                let v = match &k.target {
                    KnobTarget::Cpu { node } => cfg.cpu.get(node).copied(),
                    KnobTarget::Adaptor { topic, subscriber } => cfg
                        .adaptors
                        .iter()
                        .find(|a| a.topic == *topic && a.subscriber == *subscriber)
                        .map(|a| a.rate_hz),
                };
                v.unwrap_or(k.max).clamp(k.min, k.max)
            })
            .collect()
    }

    /// The point `x` with every knob that only restricts a non-core app moved
    /// to `fraction` of the way from its minimum to its value in `x`; other
    /// knobs keep their value. Lowering such knobs cannot hurt a core service
    /// (see [`KnobDef::restricts_non_core`]), so this is `x` with a margin from
    /// the core constraints' edge. `None` when nothing would change.
    pub fn backed_off(&self, x: &[f64], fraction: f64) -> Option<Vec<f64>> {
        let f = fraction.clamp(0.0, 1.0);
        self.moved(x, |k, v| {
            if k.restricts_non_core {
                let v = v.clamp(k.min, k.max);
                k.min + f * (v - k.min)
            } else {
                v
            }
        })
    }

    /// `x` with each knob's value mapped by `f` (pure); `None` when `x` is
    /// not a point of this space or the config would not change.
    fn moved(&self, x: &[f64], f: impl Fn(&KnobDef, f64) -> f64) -> Option<Vec<f64>> {
        if self.knobs.len() != x.len() {
            return None;
        }
        let y: Vec<f64> = self.knobs.iter().zip(x).map(|(k, &v)| f(k, v)).collect();
        (self.to_config(&y) != self.to_config(x)).then_some(y)
    }

    /// The point `x` with the input of every non-core app that works only
    /// for objectives in surplus cut down to what they count (pure):
    /// `surplus` gives, per objective, how many times more it measured
    /// than the level at which more stops counting
    /// ([`crate::measure::surplus`]). An adaptor knob whose every objective
    /// ([`KnobDef::feeds`]) has a surplus is scaled so that the one with the
    /// least keeps [`TRIM_HEADROOM`] times that level (an app's output
    /// follows its input while its input is what limits it), not below its
    /// minimum; only cuts to at most [`TRIM_BELOW`] of the value are made.
    /// Other knobs keep their value: a CPU limit caps what an app takes,
    /// and an app given less input takes less. `None` when nothing would
    /// change.
    pub fn trimmed(&self, x: &[f64], surplus: &BTreeMap<String, f64>) -> Option<Vec<f64>> {
        self.moved(x, |k, v| {
            let cut = (matches!(k.target, KnobTarget::Adaptor { .. })
                && k.restricts_non_core
                && !k.feeds.is_empty())
            .then(|| {
                k.feeds
                    .iter()
                    .map(|m| surplus.get(m).map(|h| TRIM_HEADROOM / h))
                    .try_fold(0.0_f64, |a, f| Some(a.max(f?)))
            })
            .flatten()
            .filter(|&f| f <= TRIM_BELOW);
            match cut {
                Some(f) => (v * f).max(k.min).min(v),
                None => v,
            }
        })
    }

    /// The point `x` with every knob that works only for the objectives in
    /// `factors` raised by the largest of their factors (pure; see
    /// [`crate::measure::lift`]): the CPU of a non-core app whose every
    /// objective ([`KnobDef::feeds`]) is among them and the adaptors into
    /// it, not above the knob's maximum. A knob that also works for another
    /// objective keeps its value, and so does every knob that does not only
    /// restrict a non-core app. `None` when nothing would change.
    pub fn lifted(&self, x: &[f64], factors: &BTreeMap<String, f64>) -> Option<Vec<f64>> {
        self.moved(x, |k, v| {
            let raise = (k.restricts_non_core && !k.feeds.is_empty())
                .then(|| {
                    k.feeds
                        .iter()
                        .map(|m| factors.get(m).copied())
                        .try_fold(1.0_f64, |a, f| Some(a.max(f?)))
                })
                .flatten();
            match raise {
                Some(f) => (v * f).min(k.max).max(v),
                None => v,
            }
        })
    }

    /// Back-offs of `x` with a fraction of its own for each knob that only
    /// restricts a non-core app (pure): every combination of the fractions
    /// `0, 1/(n−1), …, 1` of the way from the knob's minimum to its value in
    /// `x`, other knobs as in `x`, with `n` (2 to 5) as large as keeps the
    /// points within `limit`. The candidates a shaped back-off chooses
    /// among (`outcome::backoff_point`).
    pub fn backoff_shapes(&self, x: &[f64], limit: usize) -> Vec<Vec<f64>> {
        if self.knobs.len() != x.len() {
            return Vec::new();
        }
        let free: Vec<usize> = (0..x.len())
            .filter(|&i| self.knobs[i].restricts_non_core && x[i] > self.knobs[i].min)
            .collect();
        let d = u32::try_from(free.len()).unwrap_or(u32::MAX);
        let Some(n) = (2..=5usize)
            .rev()
            .find(|n| n.checked_pow(d).is_some_and(|c| c <= limit))
        else {
            return Vec::new();
        };
        let total = n.pow(d);
        (0..total)
            .map(|code| {
                let mut y = x.to_vec();
                let mut rest = code;
                for &i in &free {
                    let f = (rest % n) as f64 / (n - 1) as f64;
                    rest /= n;
                    let k = &self.knobs[i];
                    let v = x[i].clamp(k.min, k.max);
                    y[i] = k.min + f * (v - k.min);
                }
                y
            })
            .collect()
    }

    /// Whether `y` gives the non-core apps at least what `z` does on every
    /// knob that only restricts one, each as a config sets it (pure): with
    /// the other knobs as in `z`, `y` is then no safer for the core
    /// constraints than `z` (see [`KnobDef::restricts_non_core`]), so once
    /// `z` failed, `y` is no back-off from it. False for points of another
    /// space.
    pub fn gives_no_less(&self, y: &[f64], z: &[f64]) -> bool {
        if y.len() != self.knobs.len() || z.len() != self.knobs.len() {
            return false;
        }
        self.knobs
            .iter()
            .zip(y.iter().zip(z))
            .filter(|(k, _)| k.restricts_non_core)
            .all(|(k, (&a, &b))| k.as_set(a) >= k.as_set(b))
    }

    /// Whether `z` gives the non-core apps at least what `y` does on every
    /// knob that only restricts one and sets every other knob as `y` does,
    /// each as a config sets it (pure). A non-core app's rate does not fall
    /// when it gets more input or more CPU, so an objective measured at `z`
    /// caps what `y` can give (see `outcome::objective_ceiling`). False for
    /// points of another space.
    pub fn covers(&self, z: &[f64], y: &[f64]) -> bool {
        self.gives_no_less(z, y)
            && self
                .knobs
                .iter()
                .zip(z.iter().zip(y))
                .filter(|(k, _)| !k.restricts_non_core)
                .all(|(k, (&a, &b))| k.as_set(a) == k.as_set(b))
    }

    /// The point that drains the non-core apps before `x` is applied: every
    /// adaptor feeding a non-core subscriber at its minimum rate (no new
    /// work) and every non-core node's CPU at its maximum (finish the old
    /// work fast); other knobs as in `x`. `None` without such an adaptor (no
    /// input to hold back).
    pub fn drain_point(&self, x: &[f64]) -> Option<Vec<f64>> {
        let adaptor = |k: &KnobDef| matches!(k.target, KnobTarget::Adaptor { .. });
        if self.knobs.len() != x.len()
            || !self
                .knobs
                .iter()
                .any(|k| k.restricts_non_core && adaptor(k))
        {
            return None;
        }
        Some(
            self.knobs
                .iter()
                .zip(x)
                .map(|(k, &v)| match (k.restricts_non_core, adaptor(k)) {
                    (true, true) => k.min,
                    (true, false) => k.max,
                    (false, _) => v,
                })
                .collect(),
        )
    }

    /// The most restrictive point next to `x`: every knob that only
    /// restricts a non-core app at its minimum, the others as in `x`. Among
    /// the configs a run can try it leaves the core services the most; `None`
    /// when no knob restricts a non-core app or `x` is that point already.
    pub fn restrictive_corner(&self, x: &[f64]) -> Option<Vec<f64>> {
        self.moved(x, |k, v| if k.restricts_non_core { k.min } else { v })
    }

    /// How much the point `x` gives the non-core apps: the mean position of
    /// the knobs that only restrict a non-core app, each from 0 at its minimum
    /// to 1 at its maximum (adaptor rates on a log scale, as the optimizer
    /// sees them). 0 without such knobs.
    pub fn non_core_share(&self, x: &[f64]) -> f64 {
        let positions: Vec<f64> = self
            .knobs
            .iter()
            .zip(x)
            .filter(|(k, _)| k.restricts_non_core && k.max > k.min)
            .map(|(k, &v)| {
                let v = v.clamp(k.min, k.max);
                match k.target {
                    KnobTarget::Adaptor { .. } if k.min > 0.0 => {
                        (v / k.min).ln() / (k.max / k.min).ln()
                    }
                    _ => (v - k.min) / (k.max - k.min),
                }
            })
            .collect();
        if positions.is_empty() {
            0.0
        } else {
            positions.iter().sum::<f64>() / positions.len() as f64
        }
    }

    /// The knob list as status shows it: the searched knobs, then the pinned
    /// ones with the value they are held at.
    pub fn status(&self) -> Vec<KnobStatus> {
        let searched = self.knobs.iter().map(|k| (k, None));
        let pinned = self.pinned.iter().map(|k| (k, Some(k.min)));
        searched
            .chain(pinned)
            .map(|(k, pinned_at)| KnobStatus {
                name: k.name.clone(),
                min: k.min,
                max: k.max,
                pinned_at,
            })
            .collect()
    }

    /// The nodes of the non-core CPU knobs, searched and pinned: the ones
    /// a trial measures the CPU use of (`measure::with_usage`).
    pub fn non_core_nodes(&self) -> Vec<String> {
        self.knobs
            .iter()
            .chain(&self.pinned)
            .filter(|k| k.restricts_non_core)
            .filter_map(|k| match &k.target {
                KnobTarget::Cpu { node } => Some(node.clone()),
                KnobTarget::Adaptor { .. } => None,
            })
            .collect()
    }

    /// The pinned knobs' names.
    pub fn pinned_names(&self) -> Vec<&str> {
        self.pinned.iter().map(|k| k.name.as_str()).collect()
    }
}

fn round(v: f64, per: f64) -> f64 {
    (v * per).round() / per
}

#[cfg(test)]
mod tests {
    use super::*;
    use configbot_api::graph::{NodeInfo, TopicInfo};
    use configbot_manifests::performance_spec::NodeCpuBounds;

    fn stack() -> RobotStackSpec {
        serde_json::from_value(serde_json::json!({
            "robot": {"model": "spot", "cpus": 2},
            "apps": [
                {"name": "nav", "core": true, "nodes": [
                    {"name": "/lidar", "run": {"command": "x"}},
                    {"name": "/planner", "run": {"command": "x"}}]},
                {"name": "det", "nodes": [
                    {"name": "/camera", "run": {"command": "x"}},
                    {"name": "/detector", "run": {"command": "x"}}]},
                {"name": "web", "nodes": [{"name": "/web", "run": {"command": "x"}}]}
            ]
        }))
        .unwrap()
    }

    fn spec() -> PerformanceSpecSpec {
        serde_json::from_value(serde_json::json!({
            "stackRef": {"name": "s"},
            "metrics": [
                {"name": "cmd", "app": "nav",
                    "source": {"topicRate": {"topic": "/cmd_vel"}}, "target": {"atLeast": 35}},
                {"name": "det", "app": "det",
                    "source": {"topicRate": {"topic": "/detections"}}, "target": {"atLeast": 5}},
                {"name": "web", "app": "web",
                    "source": {"topicRate": {"topic": "/overlay"}}, "target": {"atLeast": 10}}]
        }))
        .unwrap()
    }

    fn graph(nodes: &[&str]) -> Graph {
        let mut g = Graph::default();
        for n in nodes {
            g.nodes.insert(
                n.to_string(),
                NodeInfo {
                    name: n.to_string(),
                    uri: String::new(),
                    pid: None,
                },
            );
        }
        let mut topic = |t: &str, p: &str, s: &[&str]| {
            g.topics.insert(
                t.into(),
                TopicInfo {
                    name: t.into(),
                    msg_type: "m/M".into(),
                    publishers: [p.to_string()].into(),
                    subscribers: s
                        .iter()
                        .filter(|s| nodes.contains(s))
                        .map(|s| s.to_string())
                        .collect(),
                },
            );
        };
        topic("/scan", "/lidar", &["/planner", "/web"]);
        topic("/image", "/camera", &["/detector"]);
        topic("/cmd_vel", "/planner", &[]);
        topic("/detections", "/detector", &[]);
        topic("/overlay", "/web", &[]);
        g
    }

    fn rates() -> BTreeMap<String, f64> {
        [("/scan", 40.0), ("/image", 30.0), ("/cmd_vel", 40.0)]
            .into_iter()
            .map(|(k, v)| (k.to_string(), v))
            .collect()
    }

    fn names(s: &KnobSpace) -> Vec<&str> {
        s.knobs.iter().map(|k| k.name.as_str()).collect()
    }

    #[test]
    fn knob_table() {
        let all = ["/lidar", "/planner", "/camera", "/detector", "/web"];
        let mut fixed = spec();
        fixed.knobs.cpu.nodes = vec![NodeCpuBounds {
            node: "/camera".into(),
            min: None,
            max: None,
            fixed: true,
        }];
        let mut tune_core = spec();
        tune_core.knobs.cpu.fix_core_nodes = false;
        tune_core.knobs.adaptors.enabled = false;
        let mut slow = spec();
        slow.knobs.adaptors.min_topic_rate_hz = 35.0;
        let cases: Vec<(&str, PerformanceSpecSpec, Vec<&str>, Vec<&str>)> = vec![
            (
                "defaults: non-core nodes and edges touching non-core apps",
                spec(),
                all.to_vec(),
                vec![
                    "cpu:/camera",
                    "cpu:/detector",
                    "cpu:/web",
                    "rate:/image>/detector",
                    "rate:/scan>/web",
                ],
            ),
            (
                "a stopped app has no knobs",
                spec(),
                vec!["/lidar", "/planner", "/camera", "/detector"],
                vec!["cpu:/camera", "cpu:/detector", "rate:/image>/detector"],
            ),
            (
                "per-node fixed",
                fixed,
                all.to_vec(),
                vec![
                    "cpu:/detector",
                    "cpu:/web",
                    "rate:/image>/detector",
                    "rate:/scan>/web",
                ],
            ),
            (
                "core nodes tuned, adaptors off",
                tune_core,
                all.to_vec(),
                vec![
                    "cpu:/lidar",
                    "cpu:/planner",
                    "cpu:/camera",
                    "cpu:/detector",
                    "cpu:/web",
                ],
            ),
            (
                "only topics above minTopicRateHz",
                slow,
                all.to_vec(),
                vec![
                    "cpu:/camera",
                    "cpu:/detector",
                    "cpu:/web",
                    "rate:/scan>/web",
                ],
            ),
        ];
        for (what, spec, running, want) in cases {
            let s = derive(&stack(), &spec, &graph(&running), &rates(), 2.0).unwrap();
            assert_eq!(names(&s), want, "{what}");
        }
    }

    #[test]
    fn a_non_core_node_that_feeds_no_metric_is_pinned_at_its_minimum_and_not_searched() {
        let all = ["/lidar", "/planner", "/camera", "/detector", "/web"];
        let mut sp = spec();
        sp.metrics.retain(|m| m.name != "web");
        let s = derive(&stack(), &sp, &graph(&all), &rates(), 2.0).unwrap();
        assert_eq!(
            names(&s),
            vec!["cpu:/camera", "cpu:/detector", "rate:/image>/detector"],
            "searched"
        );
        assert_eq!(s.pinned_names(), vec!["cpu:/web", "rate:/scan>/web"]);
        // The camera feeds the detector, whose output is a metric: searched.
        let reach = feeds_a_metric(&graph(&all), &sp);
        assert!(reach.contains("/camera") && reach.contains("/lidar"));
        assert!(!reach.contains("/web"));
        // A baseline shows the pinned knobs as they ran, not pinned yet.
        let running = s.as_running(&[1.0, 1.0, 10.0], &ResourceConfig::default());
        assert!(!running.cpu.contains_key("/web") && running.adaptors.len() == 1);
        // Every config holds the pinned knobs at their minimum.
        let cfg = s.to_config(&[1.0, 1.0, 10.0]);
        assert_eq!(cfg.cpu["/web"], 0.05);
        assert!(
            cfg.adaptors
                .iter()
                .any(|a| a.subscriber == "/web" && a.rate_hz == 0.5)
        );
        // Status lists them with the value they are held at.
        let st = s.status();
        assert_eq!(st.len(), 5);
        assert_eq!(st[3].pinned_at, Some(0.05));
        assert_eq!(st[0].pinned_at, None);
        // The detector's CPU and its input adaptor act together.
        assert_eq!(
            s.together,
            vec![vec![
                "cpu:/detector".to_string(),
                "rate:/image>/detector".to_string()
            ]]
        );
        // No metric on the detector's output either: the camera feeds only
        // the detector, so the whole det app is pinned.
        sp.metrics.retain(|m| m.name != "det");
        let s = derive(&stack(), &sp, &graph(&all), &rates(), 2.0).unwrap();
        assert!(names(&s).is_empty(), "{:?}", names(&s));
        assert_eq!(s.pinned.len(), 5);
    }

    /// A nodelet manager shared by a core and a non-core app: the core
    /// tracker's input and the people detector's input arrive at one process.
    #[test]
    fn an_input_a_non_core_app_claims_in_a_core_process_is_an_adaptor_knob_that_restricts_only_it()
    {
        let stack: RobotStackSpec = serde_json::from_value(serde_json::json!({
            "apps": [
                {"name": "tracking", "core": true, "nodes": [
                    {"name": "/cam", "run": {"command": "x"}},
                    {"name": "/vision", "run": {"command": "x"}}]},
                {"name": "people", "nodes": [{"name": "/people_loader", "run": {"command": "x"}}],
                    "inputs": [{"node": "/vision", "topic": "/cam/image_raw"}]}
            ]
        }))
        .unwrap();
        let mut sp: PerformanceSpecSpec = serde_json::from_value(serde_json::json!({
            "stackRef": {"name": "s"},
            "metrics": [
                {"name": "corners", "app": "tracking",
                    "source": {"topicRate": {"topic": "/corners"}}, "target": {"atLeast": 25}},
                {"name": "people", "app": "people",
                    "source": {"topicRate": {"topic": "/found"}}, "target": {"atLeast": 2}}]
        }))
        .unwrap();
        let mut g = Graph::default();
        for n in ["/cam", "/vision", "/people_loader"] {
            g.nodes.insert(
                n.into(),
                NodeInfo {
                    name: n.into(),
                    uri: String::new(),
                    pid: None,
                },
            );
        }
        for (t, p, s) in [
            ("/cam/image_raw", "/cam", Some("/vision")),
            ("/cam/image_mono", "/cam", Some("/vision")),
            ("/corners", "/vision", None),
            ("/found", "/vision", None),
            ("/vision/bond", "/people_loader", Some("/vision")),
        ] {
            g.topics.insert(
                t.into(),
                TopicInfo {
                    name: t.into(),
                    msg_type: if t.ends_with("bond") {
                        "bond/Status".into()
                    } else {
                        "m/M".into()
                    },
                    publishers: [p.to_string()].into(),
                    subscribers: s.into_iter().map(str::to_string).collect(),
                },
            );
        }
        let rates: BTreeMap<String, f64> = [
            ("/cam/image_raw", 30.0),
            ("/cam/image_mono", 30.0),
            ("/vision/bond", 10.0),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
        let s = derive(&stack, &sp, &g, &rates, 2.0).unwrap();
        // The claimed input is searched; the core input beside it is not a knob.
        assert_eq!(names(&s), vec!["rate:/cam/image_raw>/vision"]);
        assert!(
            s.knobs[0].restricts_non_core,
            "it only takes input from people"
        );
        assert_eq!((s.knobs[0].min, s.knobs[0].max), (0.5, 30.0));
        // It works for the claimant's objective only, though /vision also
        // publishes the core corners.
        assert_eq!(s.knobs[0].feeds, vec!["people"]);
        // The loader only exchanges bond heartbeats with the manager: it
        // feeds nothing, so it is pinned at its minimum, and the bond is
        // never adapted.
        assert_eq!(s.pinned_names(), vec!["cpu:/people_loader"]);
        // So the restrictive corner throttles that input, and never the core CPU.
        assert_eq!(s.restrictive_corner(&[30.0]), Some(vec![0.5]));
        // Without adaptors there is nothing to search.
        let mut off = sp.clone();
        off.knobs.adaptors.enabled = false;
        assert!(names(&derive(&stack, &off, &g, &rates, 2.0).unwrap()).is_empty());
        // An input claimed only by an app with no metric is pinned too.
        sp.metrics.retain(|m| m.app != "people");
        let s = derive(&stack, &sp, &g, &rates, 2.0).unwrap();
        assert!(names(&s).is_empty());
        assert_eq!(
            s.pinned_names(),
            vec!["cpu:/people_loader", "rate:/cam/image_raw>/vision"]
        );
    }

    #[test]
    fn each_knob_works_for_the_objectives_downstream_of_its_node() {
        let all = ["/lidar", "/planner", "/camera", "/detector", "/web"];
        let s = derive(&stack(), &spec(), &graph(&all), &rates(), 2.0).unwrap();
        let feeds: Vec<(&str, Vec<&str>)> = s
            .knobs
            .iter()
            .map(|k| {
                (
                    k.name.as_str(),
                    k.feeds.iter().map(String::as_str).collect(),
                )
            })
            .collect();
        assert_eq!(
            feeds,
            vec![
                ("cpu:/camera", vec!["det"]),
                ("cpu:/detector", vec!["det"]),
                ("cpu:/web", vec!["web"]),
                ("rate:/image>/detector", vec!["det"]),
                // /web reads the core /scan; the core metric is no objective.
                ("rate:/scan>/web", vec!["web"]),
            ]
        );
    }

    #[test]
    fn trimming_cuts_only_inputs_whose_every_objective_is_in_surplus() {
        let knob = |name: &str, target: KnobTarget, feeds: &[&str]| KnobDef {
            name: name.into(),
            target,
            min: 0.5,
            max: 30.0,
            restricts_non_core: true,
            feeds: feeds.iter().map(|f| f.to_string()).collect(),
        };
        let rate = |sub: &str| KnobTarget::Adaptor {
            topic: "/image".into(),
            subscriber: sub.into(),
        };
        let s = KnobSpace {
            knobs: vec![
                knob("rate:/image>/bright", rate("/bright"), &["bright"]),
                knob("rate:/image>/vision", rate("/vision"), &["people", "flow"]),
                knob("rate:/image>/both", rate("/both"), &["bright", "people"]),
                knob(
                    "cpu:/bright",
                    KnobTarget::Cpu {
                        node: "/bright".into(),
                    },
                    &["bright"],
                ),
                knob("rate:/image>/tiny", rate("/tiny"), &["tiny"]),
            ],
            period_micros: 20_000,
            ..KnobSpace::default()
        };
        let surplus: BTreeMap<String, f64> = [("bright", 6.0), ("people", 1.1), ("tiny", 60.0)]
            .into_iter()
            .map(|(k, v)| (k.to_string(), v))
            .collect();
        let y = s.trimmed(&[30.0, 1.0, 20.0, 1.5, 2.0], &surplus).unwrap();
        // bright measured 6 times what counts: its input keeps 1.5 of the 6.
        assert!((y[0] - 7.5).abs() < 1e-9, "{y:?}");
        // flow has no surplus, so /vision's input stays; /both feeds people,
        // whose 1.1 would be cut below TRIM_HEADROOM: it stays too.
        assert_eq!((y[1], y[2]), (1.0, 20.0));
        // A CPU limit is not trimmed: less input takes less CPU.
        assert_eq!(y[3], 1.5);
        // Never below the knob's minimum.
        assert_eq!(y[4], 0.5);
        // A cut that keeps more than TRIM_BELOW of the input is not made.
        let slight: BTreeMap<String, f64> = [("bright".to_string(), 1.7)].into();
        assert_eq!(s.trimmed(&[30.0, 1.0, 20.0, 1.5, 0.5], &slight), None);
    }

    #[test]
    fn a_lift_raises_only_knobs_that_work_for_the_worst_objectives_alone() {
        let knob = |name: &str, target: KnobTarget, feeds: &[&str], non_core: bool| KnobDef {
            name: name.into(),
            target,
            min: 0.05,
            max: 2.0,
            restricts_non_core: non_core,
            feeds: feeds.iter().map(|f| f.to_string()).collect(),
        };
        let rate = |sub: &str| KnobTarget::Adaptor {
            topic: "/image".into(),
            subscriber: sub.into(),
        };
        let cpu = |node: &str| KnobTarget::Cpu { node: node.into() };
        let s = KnobSpace {
            knobs: vec![
                knob("cpu:/bright", cpu("/bright"), &["bright"], true),
                knob("rate:/image>/bright", rate("/bright"), &["bright"], true),
                knob(
                    "rate:/image>/vision",
                    rate("/vision"),
                    &["people", "flow"],
                    true,
                ),
                knob(
                    "rate:/image>/both",
                    rate("/both"),
                    &["bright", "people"],
                    true,
                ),
                knob("cpu:/tracker", cpu("/tracker"), &["bright"], false),
            ],
            period_micros: 20_000,
            ..KnobSpace::default()
        };
        let factors: BTreeMap<String, f64> = [("bright".to_string(), 7.5)].into();
        let y = s.lifted(&[0.05, 0.5, 0.5, 0.5, 1.0], &factors).unwrap();
        // The brightness app's CPU and input rise together, its input to
        // its knob's maximum at most.
        assert!((y[0] - 0.375).abs() < 1e-9, "{y:?}");
        assert_eq!(y[1], 2.0);
        // /vision works for other objectives, /both for people too, and a
        // knob that may restrict a core app is never raised.
        assert_eq!(&y[2..], &[0.5, 0.5, 1.0]);
        // Both worst: /both rises by the larger factor.
        let both: BTreeMap<String, f64> =
            [("bright".to_string(), 2.0), ("people".to_string(), 3.0)].into();
        let y = s.lifted(&[0.05, 0.5, 0.5, 0.5, 1.0], &both).unwrap();
        assert_eq!(y[3], 1.5);
        // Nothing changes at the maxima.
        assert_eq!(s.lifted(&[2.0, 2.0, 0.5, 0.5, 1.0], &factors), None);
    }

    #[test]
    fn the_most_restrictive_corner_puts_every_non_core_knob_at_its_minimum() {
        let mut sp = spec();
        sp.knobs.cpu.fix_core_nodes = false;
        let all = ["/lidar", "/planner", "/camera", "/detector", "/web"];
        let s = derive(&stack(), &sp, &graph(&all), &rates(), 2.0).unwrap();
        let top: Vec<f64> = s.knobs.iter().map(|k| k.max).collect();
        let corner = s.restrictive_corner(&top).unwrap();
        let want: Vec<f64> = s
            .knobs
            .iter()
            .map(|k| if k.restricts_non_core { k.min } else { k.max })
            .collect();
        assert_eq!(corner, want);
        assert_eq!(s.restrictive_corner(&corner), None, "already there");
    }

    #[test]
    fn knobs_on_non_core_apps_say_they_only_restrict_them() {
        let mut sp = spec();
        sp.knobs.cpu.fix_core_nodes = false;
        let all = ["/lidar", "/planner", "/camera", "/detector", "/web"];
        let s = derive(&stack(), &sp, &graph(&all), &rates(), 2.0).unwrap();
        let flags: Vec<(&str, bool)> = s
            .knobs
            .iter()
            .map(|k| (k.name.as_str(), k.restricts_non_core))
            .collect();
        assert_eq!(
            flags,
            vec![
                ("cpu:/lidar", false),
                ("cpu:/planner", false),
                ("cpu:/camera", true),
                ("cpu:/detector", true),
                ("cpu:/web", true),
                ("rate:/image>/detector", true),
                ("rate:/scan>/web", true),
            ]
        );
    }

    #[test]
    fn a_weighted_run_gives_its_running_core_nodes_the_core_weight_in_every_config() {
        let running = ["/planner", "/camera", "/detector", "/web"];
        let mut s = derive(&stack(), &spec(), &graph(&running), &rates(), 2.0).unwrap();
        assert_eq!(s.core, ["/planner"], "/lidar does not run");
        let x = s.from_config(&ResourceConfig::default());
        assert!(s.to_config(&x).cpu_weight.is_empty(), "unweighted at first");
        let measured = s.to_config(&x);
        s.weighted = true;
        let want = BTreeMap::from([("/planner".to_string(), CORE_WEIGHT)]);
        assert_eq!(s.to_config(&x).cpu_weight, want);
        let corner = s.restrictive_corner(&x).unwrap();
        assert_eq!(s.to_config(&corner).cpu_weight, want);
        let again = s.weigh(measured.clone());
        assert_eq!((again.cpu_weight, again.cpu), (want, measured.cpu));
        // The weight is no dimension: a config's point ignores it.
        assert_eq!(s.from_config(&s.to_config(&x)), x);
    }

    #[test]
    fn bounds_and_config_round_trip() {
        let mut sp = spec();
        sp.knobs.cpu.max = Some(1.5);
        sp.knobs.cpu.nodes = vec![NodeCpuBounds {
            node: "/detector".into(),
            min: Some(0.2),
            max: Some(3.0),
            fixed: false,
        }];
        let all = ["/lidar", "/planner", "/camera", "/detector", "/web"];
        let s = derive(&stack(), &sp, &graph(&all), &rates(), 2.0).unwrap();
        let b: Vec<(f64, f64)> = s.knobs.iter().map(|k| (k.min, k.max)).collect();
        assert_eq!(
            b,
            vec![
                (0.05, 1.5),
                (0.2, 2.0),
                (0.05, 1.5),
                (0.5, 30.0),
                (0.5, 40.0)
            ]
        );
        let x = vec![0.3, 0.75, 1.5, 4.0, 40.0];
        let cfg = s.to_config(&x);
        assert_eq!(cfg.cpu["/detector"], 0.75);
        assert_eq!(cfg.adaptors[0].rate_hz, 4.0);
        assert_eq!(s.from_config(&cfg), x);
        // Unset knobs read as their upper bound.
        assert_eq!(
            s.from_config(&ResourceConfig::default()),
            vec![1.5, 2.0, 1.5, 30.0, 40.0]
        );
        assert_eq!(s.optimizer_space().unwrap().dim(), 5);
    }
    #[test]
    fn backing_off_lowers_only_knobs_that_restrict_non_core_apps() {
        let mut sp = spec();
        sp.knobs.cpu.fix_core_nodes = false;
        let all = ["/lidar", "/planner", "/camera", "/detector", "/web"];
        let s = derive(&stack(), &sp, &graph(&all), &rates(), 2.0).unwrap();
        // cpu: lidar, planner (core), camera, detector, web; rates: detector, web.
        let x = vec![1.0, 1.0, 0.05, 1.05, 2.0, 10.5, 0.5];
        let y = s.backed_off(&x, 0.5).unwrap();
        let want = [1.0, 1.0, 0.05, 0.55, 1.025, 5.5, 0.5];
        for (got, want) in y.iter().zip(want) {
            assert!((got - want).abs() < 1e-9, "{y:?}");
        }
        // Everything non-core already at its minimum: nothing to back off.
        let floor = vec![1.0, 1.0, 0.05, 0.05, 0.05, 0.5, 0.5];
        assert_eq!(s.backed_off(&floor, 0.5), None);
        assert_eq!(s.backed_off(&x, 1.0), None);
    }
    #[test]
    fn back_off_shapes_give_each_non_core_knob_its_own_fraction() {
        let mut sp = spec();
        sp.knobs.cpu.fix_core_nodes = false;
        let all = ["/lidar", "/planner", "/camera", "/detector", "/web"];
        let s = derive(&stack(), &sp, &graph(&all), &rates(), 2.0).unwrap();
        // cpu: lidar, planner (core), camera, detector, web; rates: detector, web.
        // camera and the web rate sit at their minimum: three knobs move.
        let x = vec![1.0, 1.0, 0.05, 1.05, 2.0, 10.5, 0.5];
        let shapes = s.backoff_shapes(&x, 4096);
        assert_eq!(shapes.len(), 125, "five fractions for each of three knobs");
        for y in &shapes {
            assert_eq!((y[0], y[1], y[2], y[6]), (1.0, 1.0, 0.05, 0.5), "{y:?}");
        }
        assert!(shapes.contains(&x), "no back-off at all is one shape");
        assert!(shapes.contains(&vec![1.0, 1.0, 0.05, 0.05, 0.05, 0.5, 0.5]));
        // The detector's CPU a quarter of the way, the rest kept.
        assert!(shapes.contains(&vec![1.0, 1.0, 0.05, 0.3, 2.0, 10.5, 0.5]));
        let uniform = s.backed_off(&x, 0.5).unwrap();
        assert!(
            shapes
                .iter()
                .any(|y| y.iter().zip(&uniform).all(|(a, b)| (a - b).abs() < 1e-9))
        );
        // A tighter limit takes fewer fractions: 3³ = 27 ≤ 30 < 4³.
        assert_eq!(s.backoff_shapes(&x, 30).len(), 27);
        assert!(s.backoff_shapes(&x, 7).is_empty(), "not even 2³");
        // Once x failed, a shape that keeps every non-core knob is no back-off
        // from it (the core knobs do not count); one that lowers any one is.
        let kept: Vec<&Vec<f64>> = shapes.iter().filter(|y| s.gives_no_less(y, &x)).collect();
        assert_eq!(kept, vec![&x]);
        let mut core_lower = x.clone();
        core_lower[0] = 0.5;
        assert!(s.gives_no_less(&core_lower, &x));
        // Compared as a config sets them: a failed point read back from its
        // config (rounded to 0.001 CPU) still counts.
        let failed = s.from_config(&s.to_config(&[1.0, 1.0, 0.05, 0.30049, 2.0, 10.5, 0.5]));
        assert!(s.gives_no_less(&[1.0, 1.0, 0.05, 0.3004, 2.0, 10.5, 0.5], &failed));
        assert!(!s.gives_no_less(&[1.0, 1.0, 0.05, 0.29, 2.0, 10.5, 0.5], &failed));
    }
    #[test]
    fn draining_holds_back_non_core_input_and_frees_non_core_cpu() {
        let mut sp = spec();
        sp.knobs.cpu.fix_core_nodes = false;
        let all = ["/lidar", "/planner", "/camera", "/detector", "/web"];
        let s = derive(&stack(), &sp, &graph(&all), &rates(), 2.0).unwrap();
        let x = vec![1.0, 1.2, 0.3, 0.4, 0.5, 10.0, 3.0];
        // Core CPU kept; non-core CPU at max (2.0); adaptors at min (0.5).
        assert_eq!(
            s.drain_point(&x),
            Some(vec![1.0, 1.2, 2.0, 2.0, 2.0, 0.5, 0.5])
        );
        let cpu_only = KnobSpace {
            knobs: s.knobs[..5].to_vec(),
            period_micros: s.period_micros,
            ..KnobSpace::default()
        };
        assert_eq!(cpu_only.drain_point(&x[..5]), None, "no input to hold back");
    }
    #[test]
    fn the_non_core_share_is_the_mean_position_of_the_non_core_knobs() {
        let mut sp = spec();
        sp.knobs.cpu.fix_core_nodes = false;
        let all = ["/lidar", "/planner", "/camera", "/detector", "/web"];
        let s = derive(&stack(), &sp, &graph(&all), &rates(), 2.0).unwrap();
        // cpu 0.05..2 (camera, detector, web non-core); rates 0.5..30 / 0.5..40 (log).
        let floor = vec![2.0, 2.0, 0.05, 0.05, 0.05, 0.5, 0.5];
        assert!(
            s.non_core_share(&floor).abs() < 1e-12,
            "core knobs do not count"
        );
        let top = vec![0.05, 0.05, 2.0, 2.0, 2.0, 30.0, 40.0];
        assert!((s.non_core_share(&top) - 1.0).abs() < 1e-12);
        // /image>/detector at sqrt(0.5 × 30) is half way on the log scale.
        let mid = vec![1.0, 1.0, 0.05, 0.05, 0.05, (0.5f64 * 30.0).sqrt(), 0.5];
        assert!((s.non_core_share(&mid) - 0.1).abs() < 1e-9);
    }
}
