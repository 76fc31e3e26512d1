//! `ResourceConfig`: one point of the configuration space — CPU limits and
//! weights per node and adaptor rates per subscription edge — as the
//! controller sends it to the agent and reports it in status.

use std::collections::BTreeMap;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// CPU limits and weights per ROS node and rate limits per subscription edge.
/// A node or edge that is not listed is unlimited (and at the default weight).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct ResourceConfig {
    /// CPU limit in CPUs per absolute node name (`0.35` = 35 % of one CPU).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub cpu: BTreeMap<String, f64>,
    /// CPU weight per absolute node name against the stack's other nodes, in
    /// cgroup v2 units (1–10000; unlisted: 100, the kernel's default). When
    /// the CPUs are contended, nodes get CPU in proportion to their weights;
    /// when not, a weight takes nothing from anyone.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub cpu_weight: BTreeMap<String, u32>,
    /// CFS period in microseconds used for every limit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpu_period_micros: Option<u64>,
    /// Adaptor rates per edge.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub adaptors: Vec<AdaptorRate>,
}

/// The rate limit of one subscription edge.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct AdaptorRate {
    pub topic: String,
    /// The subscribing node.
    pub subscriber: String,
    /// Forward at most this many messages per second.
    pub rate_hz: f64,
}
