//! The agent's persisted state (a JSON file written atomically) and the pure
//! startup-safety decision made from it.
//!
//! Safety rule: on start the agent re-applies the last config the controller
//! committed **only if it was committed for the same set of nodes** as the
//! current stack; otherwise that config is stale and the limits of all `core`
//! nodes are lifted until the controller applies a new one. Kernel cgroup
//! limits survive an agent crash, so a matching config keeps limits intact.

use std::collections::{BTreeMap, BTreeSet};
use std::io::Write;
use std::path::Path;

use configbot_cgroups::{CgroupConfig, CpuLimit, NodeName};
use configbot_manifests::AdaptorRate;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::spec::StackSpec;

/// What survives an agent restart.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct PersistedState {
    pub committed: Option<CommittedConfig>,
    #[serde(default)]
    pub nodes: BTreeMap<NodeName, PersistedNode>,
    /// The stack last set at run time (`set_stack`), used when the agent
    /// starts without one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stack: Option<StackSpec>,
}

/// The last config the controller put, with the node set it was made for.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct CommittedConfig {
    pub limits: BTreeMap<NodeName, CpuLimit>,
    /// Adaptor rates per (topic, subscriber) edge. A state file of an older
    /// agent (topic → rate map) reads as no rates.
    #[serde(default, deserialize_with = "edge_rates_or_legacy")]
    pub adaptor_rates: Vec<AdaptorRate>,
    pub stack_nodes: BTreeSet<NodeName>,
}

fn edge_rates_or_legacy<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<Vec<AdaptorRate>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Either {
        Edges(Vec<AdaptorRate>),
        // Read to be skipped, never used.
        Legacy(#[allow(dead_code)] BTreeMap<String, f64>),
    }
    Ok(match Either::deserialize(d)? {
        Either::Edges(v) => v,
        Either::Legacy(_) => Vec::new(),
    })
}

/// A node's process identity and counters.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct PersistedNode {
    /// Main pid and its start time (identity across pid reuse), `run` nodes.
    pub main: Option<(u32, u64)>,
    pub restarts: u32,
    /// Stopped on request (app stop): do not start on agent restart.
    pub stopped: bool,
    /// Frozen on request (app freeze, SIGSTOP): thawed by an app thaw, or
    /// before the node is stopped.
    #[serde(default)]
    pub frozen: bool,
}

/// Reads the state file; a missing file is `None`.
pub fn load(path: &Path) -> Result<Option<PersistedState>> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(source) => {
            return Err(Error::Io {
                path: path.to_path_buf(),
                source,
            });
        }
    };
    serde_json::from_str(&text)
        .map(Some)
        .map_err(|source| Error::State {
            path: path.to_path_buf(),
            source,
        })
}

/// Writes the state file atomically: temp file in the same dir, fsync, rename.
pub fn save(path: &Path, state: &PersistedState) -> Result<()> {
    let io = |source| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(io)?;
    let tmp = path.with_extension("tmp");
    let body = serde_json::to_vec_pretty(state).map_err(|source| Error::State {
        path: path.to_path_buf(),
        source,
    })?;
    let mut f = std::fs::File::create(&tmp).map_err(io)?;
    f.write_all(&body).map_err(io)?;
    f.sync_all().map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)?;
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// What to do with limits at startup.
#[derive(Debug, Clone, PartialEq)]
pub enum StartupLimits {
    /// The committed config matches this stack: apply it again.
    Reapply(CgroupConfig),
    /// No usable config: lift these (core) nodes' limits.
    LiftCore(Vec<NodeName>),
}

/// The set of node names in a stack.
pub fn stack_nodes(stack: &StackSpec) -> BTreeSet<NodeName> {
    stack.nodes().map(|(_, n)| n.name.clone()).collect()
}

/// Decides startup limits from the stack and the persisted config.
pub fn startup_limits(stack: &StackSpec, committed: Option<&CommittedConfig>) -> StartupLimits {
    match committed {
        Some(c) if c.stack_nodes == stack_nodes(stack) => StartupLimits::Reapply(CgroupConfig {
            limits: c.limits.clone(),
        }),
        _ => StartupLimits::LiftCore(
            stack
                .nodes()
                .filter(|(_, n)| n.core)
                .map(|(_, n)| n.name.clone())
                .collect(),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spec::{AppSpec, MatchSpec, NodeSource, NodeSpec};

    fn stack(names: &[(&str, bool)]) -> StackSpec {
        StackSpec {
            apps: vec![AppSpec {
                name: "a".into(),
                inputs: Vec::new(),
                nodes: names
                    .iter()
                    .map(|(n, core)| NodeSpec {
                        name: NodeName::new(n).unwrap(),
                        core: *core,
                        source: NodeSource::Match(MatchSpec {
                            process_name: Some("x".into()),
                            cmdline_regex: None,
                            ros_node: None,
                        }),
                    })
                    .collect(),
            }],
        }
    }

    #[test]
    fn startup_limits_table() {
        let s = stack(&[("/a", true), ("/b", false)]);
        let committed = CommittedConfig {
            limits: BTreeMap::from([(NodeName::new("/a").unwrap(), CpuLimit::cpus(0.2))]),
            adaptor_rates: Vec::new(),
            stack_nodes: stack_nodes(&s),
        };
        let lift_a = StartupLimits::LiftCore(vec![NodeName::new("/a").unwrap()]);
        assert!(
            matches!(startup_limits(&s, Some(&committed)), StartupLimits::Reapply(c) if c.limits.len() == 1)
        );
        assert_eq!(startup_limits(&s, None), lift_a);
        let other = stack(&[("/a", true), ("/c", false)]);
        let lift_other = StartupLimits::LiftCore(vec![NodeName::new("/a").unwrap()]);
        assert_eq!(
            startup_limits(&other, Some(&committed)),
            lift_other,
            "stale for a changed stack"
        );
    }

    #[test]
    fn save_then_load_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/state.json");
        assert_eq!(load(&path).unwrap(), None);
        let mut st = PersistedState::default();
        st.nodes.insert(
            NodeName::new("/n").unwrap(),
            PersistedNode {
                main: Some((42, 7)),
                restarts: 2,
                stopped: true,
                frozen: true,
            },
        );
        save(&path, &st).unwrap();
        assert_eq!(load(&path).unwrap(), Some(st));
        let legacy = r#"{"committed":{"limits":{},"adaptorRates":{"/t":5.0},"stackNodes":[]}}"#;
        std::fs::write(&path, legacy).unwrap();
        assert_eq!(
            load(&path)
                .unwrap()
                .unwrap()
                .committed
                .unwrap()
                .adaptor_rates,
            vec![]
        );
        std::fs::write(&path, "{").unwrap();
        assert!(matches!(load(&path), Err(Error::State { .. })));
    }
}
