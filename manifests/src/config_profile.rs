//! The `ConfigProfile` kind: one entry of the config library — the best known
//! config for a context (robot model + the running apps and nodes + labels),
//! with the trials it was learned from. Exported from one robot and imported on
//! another of the same model, it lets a fleet share what it learned.

use std::collections::BTreeMap;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::config::ResourceConfig;
use crate::meta::ObjectMeta;

/// A learned config for one context.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct ConfigProfile {
    /// Always `configbot.dev/v1alpha1`.
    pub api_version: String,
    /// Always `ConfigProfile`.
    pub kind: String,
    pub metadata: ObjectMeta,
    pub spec: ConfigProfileSpec,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct ConfigProfileSpec {
    /// The context the config was learned in.
    pub context: ProfileContext,
    /// The PerformanceSpec (name) the config satisfies.
    pub spec_name: String,
    /// Digest of the spec's metrics and knobs when the config was learned; a
    /// config learned for other targets is only used to warm-start relearning.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spec_digest: Option<String>,
    /// The best known config.
    pub config: ResourceConfig,
    /// Constraint satisfaction measured for `config` (0..1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub satisfaction: Option<f64>,
    /// Scalarised non-core performance measured for `config`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub objective: Option<f64>,
    /// Trials of the run that found it (used to warm-start a relearning).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub trials: Vec<ProfileTrial>,
}

/// Robot model, running apps and nodes, and user labels.
#[derive(
    Debug, Clone, Default, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize, JsonSchema,
)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct ProfileContext {
    /// Robot model (`spot`); configs are shared only between robots of one model.
    pub robot_model: String,
    /// Running apps, sorted.
    #[serde(default)]
    pub apps: Vec<String>,
    /// Running ROS nodes, sorted.
    #[serde(default)]
    pub nodes: Vec<String>,
    /// User labels (e.g. `location: outdoor`) set by annotation.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub labels: BTreeMap<String, String>,
}

/// One measured trial: its config and metric values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct ProfileTrial {
    pub config: ResourceConfig,
    /// Metric values by metric name.
    pub values: BTreeMap<String, f64>,
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub censored: bool,
}

impl ProfileContext {
    /// A stable, human-readable key of the context:
    /// `model|app,app|/node,/node|k=v,k=v`.
    pub fn key(&self) -> String {
        let labels: Vec<String> = self
            .labels
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect();
        format!(
            "{}|{}|{}|{}",
            self.robot_model,
            self.apps.join(","),
            self.nodes.join(","),
            labels.join(",")
        )
    }
}
