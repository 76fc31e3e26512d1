//! Changing the stack at run time: the pure difference between two stacks
//! ([`diff_stacks`]) and [`Agent::set_stack`], which carries it out — new
//! nodes get a cgroup and start, removed nodes stop and lose their cgroup,
//! nodes whose `run`/`match` changed restart, nodes whose app or `core` flag
//! changed are updated in place.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use configbot_cgroups::{CpuStats, NodeName};
use serde::{Deserialize, Serialize};

use super::process;
use super::{Agent, NodeRt};
use crate::error::{Error, Result};
use crate::procfs::Matcher;
use crate::spec::{NodeSource, NodeSpec, StackSpec};
use crate::state::PersistedNode;

/// What a stack change does, node by node.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct StackDiff {
    pub added: Vec<NodeName>,
    pub removed: Vec<NodeName>,
    /// `run` or `match` changed: stop, then start with the new spec.
    pub restarted: Vec<NodeName>,
    /// Only the app or the `core` flag changed: no process is touched.
    pub updated: Vec<NodeName>,
}

impl StackDiff {
    pub fn is_empty(&self) -> bool {
        self.added.is_empty()
            && self.removed.is_empty()
            && self.restarted.is_empty()
            && self.updated.is_empty()
    }
}

/// The node-by-node difference from `old` to `new`. Pure.
pub fn diff_stacks(old: &StackSpec, new: &StackSpec) -> StackDiff {
    let index = |s: &StackSpec| -> BTreeMap<NodeName, (String, NodeSpec)> {
        s.nodes()
            .map(|(app, n)| (n.name.clone(), (app.to_owned(), n.clone())))
            .collect()
    };
    let (old, new) = (index(old), index(new));
    let mut d = StackDiff::default();
    for (name, (app, spec)) in &new {
        match old.get(name) {
            None => d.added.push(name.clone()),
            Some((_, o)) if o.source != spec.source => d.restarted.push(name.clone()),
            Some((oa, o)) if oa != app || o.core != spec.core => d.updated.push(name.clone()),
            Some(_) => {}
        }
    }
    d.removed = old
        .keys()
        .filter(|n| !new.contains_key(*n))
        .cloned()
        .collect();
    d
}

impl Agent {
    /// Replaces the stack at run time and returns what changed. Removed
    /// nodes are stopped (SIGINT → SIGTERM → SIGKILL, `match` nodes too) and
    /// their cgroups removed; changed nodes restart; new nodes start (stopped
    /// if their app is stopped, frozen if it is frozen). Limits of removed nodes leave the committed
    /// config; the committed config keeps the node set it was made for, so a
    /// later agent restart with this stack lifts core limits (see `state`).
    pub async fn set_stack(&self, stack: StackSpec) -> Result<StackDiff> {
        stack.validate().map_err(Error::InvalidStack)?;
        let diff = diff_stacks(&self.st().stack, &stack);
        let specs: BTreeMap<NodeName, (String, NodeSpec)> = stack
            .nodes()
            .map(|(app, n)| (n.name.clone(), (app.to_owned(), n.clone())))
            .collect();
        for node in &diff.removed {
            self.stop_node(node).await;
            self.remove_cgroup(node).await?;
            let mut st = self.st();
            st.nodes.remove(node);
            if let Some(c) = st.committed.as_mut() {
                c.limits.remove(node);
            }
        }
        // A restarted node of a frozen app is frozen again once it runs.
        let refreeze: Vec<NodeName> = diff
            .restarted
            .iter()
            .filter(|n| self.st().nodes.get(*n).is_some_and(|n| n.persisted.frozen))
            .cloned()
            .collect();
        for node in &diff.restarted {
            self.stop_node(node).await;
        }
        for node in diff
            .added
            .iter()
            .chain(&diff.restarted)
            .chain(&diff.updated)
        {
            let Some((app, spec)) = specs.get(node) else {
                continue;
            };
            self.backend().create(node)?;
            let mut st = self.st();
            let app_stopped = st
                .nodes
                .values()
                .any(|n| n.app == *app && n.persisted.stopped);
            let app_frozen = st
                .nodes
                .values()
                .any(|n| n.app == *app && n.persisted.frozen);
            let matcher = match &spec.source {
                NodeSource::Match(m) => Matcher::new(m),
                NodeSource::Run(_) => None,
            };
            match st.nodes.get_mut(node) {
                Some(rt) => {
                    rt.app = app.clone();
                    rt.spec = spec.clone();
                    rt.matcher = matcher;
                }
                None => {
                    st.nodes.insert(
                        node.clone(),
                        NodeRt {
                            app: app.clone(),
                            spec: spec.clone(),
                            matcher,
                            persisted: PersistedNode {
                                stopped: app_stopped,
                                frozen: app_frozen,
                                ..PersistedNode::default()
                            },
                            supervisor: None,
                            sample: None,
                            usage_cpus: 0.0,
                            stats: CpuStats::default(),
                            limit: None,
                            weight: None,
                        },
                    );
                }
            }
        }
        self.st().stack = stack;
        for node in &refreeze {
            if let Some(rt) = self.st().nodes.get_mut(node) {
                rt.persisted.frozen = true;
            }
        }
        for node in diff.added.iter().chain(&diff.restarted) {
            let stopped = self
                .st()
                .nodes
                .get(node)
                .is_none_or(|n| n.persisted.stopped);
            if !stopped {
                self.start_supervisor(node, None);
            }
        }
        self.scan_matches(None);
        self.persist();
        Ok(diff)
    }

    /// Stops a node's supervisor and every process in its cgroup.
    pub(crate) async fn stop_node(&self, node: &NodeName) {
        // A stopped process keeps SIGINT and SIGTERM pending until SIGCONT:
        // thaw a frozen node so its stop is graceful.
        if self
            .st()
            .nodes
            .get(node)
            .is_some_and(|n| n.persisted.frozen)
        {
            let _ = self.set_node_frozen(node, false);
            self.persist();
        }
        let sup = self
            .st()
            .nodes
            .get_mut(node)
            .and_then(|rt| rt.supervisor.take());
        if let Some((tx, handle)) = sup {
            let _ = tx.send(true);
            let _ = handle.await;
        }
        // match nodes, and anything a finished run node left behind.
        if !self.backend().pids(node).unwrap_or_default().is_empty() {
            process::terminate(self, node, None).await;
        }
    }

    /// Removes a node's (emptied) cgroup; the kernel may report it busy for
    /// a moment after the last process exited.
    async fn remove_cgroup(&self, node: &NodeName) -> Result<()> {
        let deadline = Instant::now() + Duration::from_secs(2);
        loop {
            match self.backend().remove(node) {
                Ok(()) => return Ok(()),
                Err(e) if Instant::now() >= deadline => return Err(e.into()),
                Err(_) => tokio::time::sleep(Duration::from_millis(20)).await,
            }
        }
    }

    /// The stack as the agent runs it now.
    pub fn stack(&self) -> StackSpec {
        self.st().stack.clone()
    }

    /// Nodes tied to a ROS graph name, with that name: a `run` node by its
    /// own name, a `match` node by its `rosNode`. Stopped nodes are left out.
    pub fn ros_names(&self) -> Vec<(NodeName, String)> {
        self.st()
            .nodes
            .iter()
            .filter(|(_, n)| !n.persisted.stopped)
            .filter_map(|(k, n)| match &n.spec.source {
                NodeSource::Run(_) => Some((k.clone(), k.as_str().to_owned())),
                NodeSource::Match(m) => Some((k.clone(), m.ros_node.clone()?)),
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stack(json: &str) -> StackSpec {
        serde_json::from_str(json).unwrap()
    }

    #[test]
    fn diff_sorts_nodes_into_added_removed_restarted_updated() {
        let old = stack(
            r#"{"apps":[{"name":"a","nodes":[
                {"name":"/keep","run":{"command":"/bin/sleep","args":["9"]}},
                {"name":"/gone","match":{"processName":"x"}},
                {"name":"/cmd","run":{"command":"/bin/sleep","args":["9"]}},
                {"name":"/flag","match":{"rosNode":"/flag"}}]}]}"#,
        );
        let new = stack(
            r#"{"apps":[{"name":"a","nodes":[
                {"name":"/keep","run":{"command":"/bin/sleep","args":["9"]}},
                {"name":"/cmd","run":{"command":"/bin/sleep","args":["8"]}},
                {"name":"/flag","core":true,"match":{"rosNode":"/flag"}}]},
              {"name":"b","nodes":[{"name":"/new","match":{"rosNode":"/new"}}]}]}"#,
        );
        let d = diff_stacks(&old, &new);
        let n = |s: &str| NodeName::new(s).unwrap();
        assert_eq!(d.added, vec![n("/new")]);
        assert_eq!(d.removed, vec![n("/gone")]);
        assert_eq!(d.restarted, vec![n("/cmd")]);
        assert_eq!(d.updated, vec![n("/flag")]);
        assert!(diff_stacks(&new, &new).is_empty());
    }
}
