//! Start-up (pure): a run decides nothing before the stack is up. Real nodes
//! take seconds to register and longer to publish (people_detect loads its
//! model; a lazy opencv_apps node subscribes only once its output has a
//! subscriber), and a baseline measured before that reads 0 Hz: a run on a
//! real stack declared Unsat within 5 s of apply, after 0 trials, from an
//! empty graph. So a run first waits until every node the stack starts
//! (`run`) is in the graph and every metric's topic has delivered messages (the core
//! ones at least; the non-core ones get [`NON_CORE_GRACE_MS`] more, since a
//! default config may starve them for good), or until the spec's
//! `startupTimeoutSeconds`, after which it goes on and says which nodes never
//! registered and which topics never flowed.

use std::collections::BTreeSet;

use configbot_api::graph::Graph;
use configbot_api::measure::MeasureReport;
use configbot_manifests::RobotStack;
use serde::{Deserialize, Serialize};

use super::measure::MetricDef;

/// Pause between two graph reads while declared nodes are missing.
pub const POLL_MS: u64 = 1000;
/// Length of one probe of the metrics' topics.
pub const PROBE_MS: u64 = 1000;
/// How long non-core metrics may stay silent once the core ones flow.
pub const NON_CORE_GRACE_MS: u64 = 10_000;

/// Where the start-up wait is.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "step", rename_all = "camelCase")]
pub enum Wait {
    /// Read the graph.
    #[default]
    ReadGraph,
    /// Declared nodes are missing: wait [`POLL_MS`], then read again.
    Sleep { missing: Vec<String> },
    /// Every declared node is there (or the time is up): probe the metrics'
    /// topics until they flow.
    Probe {
        missing: Vec<String>,
        flowed: BTreeSet<String>,
        /// When every core metric had flowed (ms into the wait).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        core_up_ms: Option<u64>,
    },
}

/// The nodes `stack` has the agent start (`run`) that `graph` does not
/// have, in stack order. A `match` node is adopted when something else
/// starts it and may be absent on purpose (an app of another context), so
/// the run does not wait for it.
pub fn missing(stack: &RobotStack, graph: &Graph) -> Vec<String> {
    stack
        .spec
        .nodes()
        .filter(|(_, n)| n.run.is_some())
        .map(|(_, n)| n.name.clone())
        .filter(|n| !graph.nodes.contains_key(n))
        .collect()
}

/// The metrics whose probe saw messages in `r`.
pub fn flowing(defs: &[MetricDef], r: &MeasureReport) -> Vec<String> {
    defs.iter()
        .filter(|d| r.series.iter().any(|s| s.probe == d.probe && s.mean > 0.0))
        .map(|d| d.name.clone())
        .collect()
}

/// Whether a probe wait is over, `waited_ms` into the start-up: every
/// metric flowed, or the core ones did [`NON_CORE_GRACE_MS`] ago, or the
/// timeout passed.
pub fn done(
    defs: &[MetricDef],
    flowed: &BTreeSet<String>,
    core_up_ms: Option<u64>,
    waited_ms: u64,
    timeout_ms: u64,
) -> bool {
    let all = defs.iter().all(|d| flowed.contains(&d.name));
    let grace = core_up_ms.is_some_and(|t| waited_ms >= t + NON_CORE_GRACE_MS);
    all || grace || waited_ms >= timeout_ms
}

/// Whether every core metric has flowed.
pub fn core_up(defs: &[MetricDef], flowed: &BTreeSet<String>) -> bool {
    defs.iter()
        .filter(|d| d.core)
        .all(|d| flowed.contains(&d.name))
}

/// The metrics (by topic or node) that never flowed.
pub fn silent<'a>(defs: &'a [MetricDef], flowed: &BTreeSet<String>) -> Vec<&'a str> {
    defs.iter()
        .filter(|d| !flowed.contains(&d.name))
        .map(|d| d.name.as_str())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn defs() -> Vec<MetricDef> {
        vec![
            MetricDef::rate_at_least("cmd", "nav", "/cmd_vel", 35.0, true),
            MetricDef::rate_at_least("det", "det", "/detections", 3.0, false),
        ]
    }

    #[test]
    fn the_wait_ends_when_everything_flows_or_the_non_core_grace_or_the_timeout_passes() {
        let d = defs();
        let set = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<BTreeSet<_>>();
        // (flowed, core up at, waited, done)
        let cases: Vec<(BTreeSet<String>, Option<u64>, u64, bool)> = vec![
            (set(&[]), None, 5_000, false),
            (set(&["cmd"]), Some(3_000), 5_000, false),
            (set(&["cmd"]), Some(3_000), 13_000, true),
            (set(&["cmd", "det"]), Some(3_000), 4_000, true),
            (set(&["det"]), None, 59_000, false),
            (set(&["det"]), None, 60_000, true),
        ];
        for (flowed, up, waited, want) in cases {
            assert_eq!(
                done(&d, &flowed, up, waited, 60_000),
                want,
                "{flowed:?} {up:?} {waited}"
            );
        }
        assert!(core_up(&d, &set(&["cmd"])));
        assert!(!core_up(&d, &set(&["det"])));
        assert_eq!(silent(&d, &set(&["cmd"])), vec!["det"]);
    }
}

#[cfg(test)]
mod missing_tests {
    use super::*;

    #[test]
    fn only_nodes_the_agent_starts_are_waited_for() {
        let stack: RobotStack = serde_json::from_value(serde_json::json!({
            "apiVersion": "configbot.dev/v1alpha1", "kind": "RobotStack", "metadata": {"name": "s"},
            "spec": {"apps": [{"name": "a", "nodes": [
                {"name": "/started", "run": {"command": "x"}},
                {"name": "/adopted", "match": {"rosNode": "/adopted"}}]}]}
        }))
        .unwrap();
        assert_eq!(missing(&stack, &Graph::default()), vec!["/started"]);
    }
}
