//! The `PerformanceSpec` kind: what a stack must achieve. Metrics of core apps
//! are constraints (`J ≥ J°`), metrics of non-core apps are objectives capped at
//! their target (`min(J, J°)`), plus the knob bounds and the tuning, monitoring
//! and remediation policies.

use std::collections::BTreeMap;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::config::ResourceConfig;
use crate::meta::{Condition, ObjectMeta};
use crate::vocab::Phase;

/// Targets for a RobotStack and how ConfigBot may tune it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct PerformanceSpec {
    /// Always `configbot.dev/v1alpha1`.
    pub api_version: String,
    /// Always `PerformanceSpec`.
    pub kind: String,
    pub metadata: ObjectMeta,
    pub spec: PerformanceSpecSpec,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub status: Option<PerformanceSpecStatus>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct PerformanceSpecSpec {
    /// The RobotStack (same namespace) this spec is for.
    pub stack_ref: StackRef,
    /// The metrics and their targets; at least one.
    pub metrics: Vec<Metric>,
    #[serde(default)]
    pub knobs: Knobs,
    #[serde(default)]
    pub tuning: Tuning,
    #[serde(default)]
    pub monitoring: Monitoring,
    #[serde(default)]
    pub remediation: Remediation,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct StackRef {
    pub name: String,
}

/// One measured quantity of an app and its target.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct Metric {
    /// Metric name: a DNS label (`cmd-vel-rate`).
    pub name: String,
    /// The app it measures; the app's `core` flag makes it a constraint or an objective.
    pub app: String,
    pub source: MetricSource,
    pub target: Target,
    /// Length of the window a value is averaged over, in seconds.
    #[serde(default = "default_metric_window")]
    pub window_seconds: f64,
    /// Weight of an objective under the `Weighted` scalarization.
    #[serde(default = "one")]
    pub weight: f64,
}

/// Where a metric's value comes from. Exactly one field is set.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct MetricSource {
    /// Rate of a ROS topic in Hz, measured as `rostopic hz` does.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub topic_rate: Option<TopicRateSource>,
    /// CPU used by a node, in CPUs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpu_usage: Option<CpuUsageSource>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct TopicRateSource {
    /// Absolute topic name, e.g. `/cmd_vel`.
    pub topic: String,
    /// Measure at this subscriber's side of an adaptor instead of at the publisher.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub subscriber: Option<String>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct CpuUsageSource {
    /// Absolute ROS node name.
    pub node: String,
}

/// The target value; exactly one of `atLeast` (rates) and `atMost` (latencies, usage).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct Target {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub at_least: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub at_most: Option<f64>,
}

/// Direction and value of a target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Bound {
    AtLeast(f64),
    AtMost(f64),
}

impl Target {
    /// The target as a bound, when exactly one side is set.
    pub fn bound(&self) -> Option<Bound> {
        match (self.at_least, self.at_most) {
            (Some(v), None) => Some(Bound::AtLeast(v)),
            (None, Some(v)) => Some(Bound::AtMost(v)),
            _ => None,
        }
    }
}

/// The configuration space: CPU limits per node and adaptor rates per edge.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct Knobs {
    #[serde(default)]
    pub cpu: CpuKnobs,
    #[serde(default)]
    pub adaptors: AdaptorPolicy,
}

/// Bounds of the per-node `cpu.max` knobs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct CpuKnobs {
    /// Lower bound for every tuned node, in CPUs.
    #[serde(default = "default_cpu_min")]
    pub min: f64,
    /// Upper bound for every tuned node, in CPUs (defaults to the robot's CPUs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max: Option<f64>,
    /// CFS period in microseconds; short periods avoid freezing fast loops.
    #[serde(default = "default_period_us")]
    pub period_micros: u64,
    /// Leave core nodes unlimited and untuned (the paper's default).
    #[serde(default = "yes")]
    pub fix_core_nodes: bool,
    /// Per-node overrides.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub nodes: Vec<NodeCpuBounds>,
}

impl Default for CpuKnobs {
    fn default() -> Self {
        CpuKnobs {
            min: default_cpu_min(),
            max: None,
            period_micros: default_period_us(),
            fix_core_nodes: true,
            nodes: Vec::new(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct NodeCpuBounds {
    /// Absolute ROS node name from the stack.
    pub node: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max: Option<f64>,
    /// Do not tune this node (keep it unlimited).
    #[serde(default)]
    pub fixed: bool,
}

/// Which subscription edges get a rate-limiting adaptor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct AdaptorPolicy {
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Only topics faster than this get adaptors (the paper uses 5 Hz).
    #[serde(default = "default_min_topic_rate")]
    pub min_topic_rate_hz: f64,
    /// Lowest rate an adaptor may be tuned to.
    #[serde(default = "default_min_adaptor_rate")]
    pub min_rate_hz: f64,
    /// Edges that always get an adaptor.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub include: Vec<EdgeSelector>,
    /// Edges that never get an adaptor.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub exclude: Vec<EdgeSelector>,
}

impl Default for AdaptorPolicy {
    fn default() -> Self {
        AdaptorPolicy {
            enabled: true,
            min_topic_rate_hz: default_min_topic_rate(),
            min_rate_hz: default_min_adaptor_rate(),
            include: Vec::new(),
            exclude: Vec::new(),
        }
    }
}

/// A subscription edge: a topic, optionally narrowed to one subscriber node.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct EdgeSelector {
    pub topic: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub subscriber: Option<String>,
}

/// How objectives of several non-core apps are combined.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
pub enum Scalarization {
    /// Maximise the worst normalised objective (the paper's public code).
    #[default]
    MaxMin,
    /// Maximise the weighted sum of normalised objectives.
    Weighted,
}

/// How a tuning run proceeds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct Tuning {
    /// Whether tuning may run now (a task executive can also pause it by annotation).
    #[serde(default = "yes")]
    pub allowed: bool,
    /// Profiling window of one trial, in seconds.
    #[serde(default = "default_trial_seconds")]
    pub trial_seconds: f64,
    /// Time to let a new config settle before profiling, in seconds. From 2 s
    /// up it is the least wait: the settle goes on while a core metric still
    /// moves (the previous config's transients), up to three times this.
    #[serde(default = "default_settle_seconds")]
    pub settle_seconds: f64,
    #[serde(default = "default_max_trials")]
    pub max_trials: u32,
    /// Seed of the optimizer, for reproducible runs.
    #[serde(default)]
    pub seed: u64,
    /// Never try a config predicted to push a core metric below this fraction of its target.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub safety_floor: Option<f64>,
    #[serde(default)]
    pub scalarization: Scalarization,
    /// How long a run waits, before it measures anything, for the stack's
    /// declared nodes to register and its metrics' topics to flow (nodes that
    /// load a model take seconds). Past it the run goes on and says which
    /// nodes never came up.
    #[serde(default = "default_startup_timeout")]
    pub startup_timeout_seconds: f64,
    /// In a run whose core windows miss in bursts (a window missed while
    /// every core mean held its target), how long a config must hold, no
    /// window missed, before it is accepted, in seconds. The default is
    /// two of the minutes a config is judged by: there a window's dip does
    /// not scale with the spread of its neighbours, so no margin predicts
    /// a clean minute, and only a clean record tells.
    #[serde(default = "default_record_seconds")]
    pub record_seconds: f64,
}

impl Default for Tuning {
    fn default() -> Self {
        Tuning {
            allowed: true,
            trial_seconds: default_trial_seconds(),
            settle_seconds: default_settle_seconds(),
            max_trials: default_max_trials(),
            seed: 0,
            safety_floor: None,
            scalarization: Scalarization::MaxMin,
            startup_timeout_seconds: default_startup_timeout(),
            record_seconds: default_record_seconds(),
        }
    }
}

/// The runtime monitors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct Monitoring {
    /// Period of the ROS graph refresh, in seconds (process starts wake it early).
    #[serde(default = "default_graph_interval")]
    pub graph_interval_seconds: f64,
    /// A constraint violated this long triggers relearning, in seconds.
    #[serde(default = "default_violation_window")]
    pub violation_window_seconds: f64,
}

impl Default for Monitoring {
    fn default() -> Self {
        Monitoring {
            graph_interval_seconds: default_graph_interval(),
            violation_window_seconds: default_violation_window(),
        }
    }
}

/// What to do when a constraint is violated and tuning is not allowed now.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct Remediation {
    #[serde(default)]
    pub action: RemediationAction,
    /// While remediating, record a rosbag of the paused apps' inputs (every
    /// topic they subscribe to) for relearning later, where `rosbag` is
    /// installed on the robot. The bag is written beside the agent's state
    /// (`bags/<namespace>-<spec>-<ms>.bag`); events name its path.
    #[serde(default)]
    pub record_rosbag: bool,
}

impl Default for Remediation {
    fn default() -> Self {
        Remediation {
            action: RemediationAction::StopNonCore,
            record_rosbag: false,
        }
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
pub enum RemediationAction {
    /// Do nothing but report.
    None,
    /// Stop non-core apps and give their CPU to core nodes.
    #[default]
    StopNonCore,
    /// Freeze non-core apps (SIGSTOP to every process in their cgroups)
    /// instead of stopping them: they keep their memory and ROS connections
    /// and go on where they were when thawed (SIGCONT).
    FreezeNonCore,
}

/// What the control plane reports about a spec.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct PerformanceSpecStatus {
    /// The reconciler's `Pending`, `Accepted` or `Invalid`, then the tuning
    /// run's `Baseline`, `Tuning`, `Satisfied`, `Unsat`, `Monitoring` or `Remediating`.
    #[serde(default)]
    pub phase: Phase,
    #[serde(default)]
    pub observed_generation: i64,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub conditions: Vec<Condition>,
    /// Share of 1 s windows in which every core constraint held (0..1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub satisfaction: Option<f64>,
    /// Measured value of each non-core objective.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub non_core_performance: BTreeMap<String, f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub best_config: Option<ResourceConfig>,
    /// Trials measured in the current tuning run.
    #[serde(default)]
    pub trials: u32,
    /// The trial budget of the current run (for progress displays).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_trials: Option<u32>,
    /// The knobs of the current run, derived from the stack, the spec and the live graph.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub knobs: Vec<KnobStatus>,
    /// The measurement of the config found on the robot when the run started.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub baseline: Option<TrialStatus>,
    /// Every trial of the current run, in order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub trial_history: Vec<TrialStatus>,
    /// Index (into `trialHistory`) of the trial whose config is applied as the best.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub best_trial: Option<u32>,
    /// Set when the best trial failed verification and a backed-off version of
    /// it held (a margin from the core constraint's edge): the fraction (0..1)
    /// of the way from each non-core knob's minimum to the trial's value that
    /// the applied config keeps, or, when the back-off was shaped (each knob at
    /// its own fraction), the fraction it was predicted at least as safe as.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub best_trial_backoff: Option<f64>,
    /// Trials whose config failed verification (its trial measurement was not
    /// confirmed over the longer verification window), in order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rejected_trials: Vec<u32>,
    /// The context the run is for (robot model, running apps and nodes, labels).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub context: Option<String>,
    /// Why the run is where it is (for Unsat: which constraint, the best value reached, what to relax).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// One knob of a tuning run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct KnobStatus {
    /// `cpu:/node` or `rate:/topic>/subscriber`.
    pub name: String,
    pub min: f64,
    pub max: f64,
    /// Set when the knob is not searched but held at this value: it acts
    /// only on a non-core node whose outputs reach no metric.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pinned_at: Option<f64>,
}

/// One measured config: baseline, trial or library re-apply.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct TrialStatus {
    /// 0-based trial number within the run.
    pub index: u32,
    pub config: ResourceConfig,
    /// Value of every metric by name (window mean).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub values: BTreeMap<String, f64>,
    /// Share of 1 s sub-windows in which every core constraint held (0..1).
    pub satisfaction: f64,
    /// Scalarised non-core performance (0..1 when every objective has a target).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub objective: Option<f64>,
    /// Every core constraint met (and the trial ran its full window).
    pub feasible: bool,
    /// Stopped early because clearly infeasible.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub censored: bool,
}

fn default_metric_window() -> f64 {
    1.0
}
fn one() -> f64 {
    1.0
}
fn yes() -> bool {
    true
}
fn default_cpu_min() -> f64 {
    0.05
}
fn default_period_us() -> u64 {
    20_000
}
fn default_min_topic_rate() -> f64 {
    5.0
}
fn default_min_adaptor_rate() -> f64 {
    0.5
}

fn default_startup_timeout() -> f64 {
    60.0
}

/// `spec.tuning.recordSeconds` when the spec does not say.
pub fn default_record_seconds() -> f64 {
    120.0
}

fn default_trial_seconds() -> f64 {
    5.0
}
fn default_settle_seconds() -> f64 {
    1.0
}
fn default_max_trials() -> u32 {
    30
}
fn default_graph_interval() -> f64 {
    30.0
}
fn default_violation_window() -> f64 {
    5.0
}
