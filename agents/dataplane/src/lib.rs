//! Backend-neutral view of a robot's message-passing data plane: the graph
//! (nodes, topics, edges, pids), per-topic rate statistics, and per-subscriber
//! adaptors that limit the rate a single subscriber receives.
//!
//! A backend (ROS 1 today, ROS 2 later) implements [`DataPlane`]; the agent
//! daemon only talks to this trait. The adaptor selection policy is a pure
//! function in [`policy`].

pub mod policy;

use std::collections::{BTreeMap, BTreeSet};

use serde::{Deserialize, Serialize};

/// One node of the graph.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct NodeInfo {
    /// Fully qualified node name, e.g. `/talker`.
    pub name: String,
    /// Backend-specific address of the node (ROS 1: slave XML-RPC URI).
    pub uri: String,
    /// Process id reported by the node, when it answered.
    pub pid: Option<u32>,
}

/// One topic with its message type.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct TopicInfo {
    pub name: String,
    pub msg_type: String,
    pub publishers: BTreeSet<String>,
    pub subscribers: BTreeSet<String>,
}

/// A publisher→subscriber edge on one topic.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct Edge {
    pub topic: String,
    pub publisher: String,
    pub subscriber: String,
}

/// A snapshot of the whole graph.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Graph {
    /// Nodes by name.
    pub nodes: BTreeMap<String, NodeInfo>,
    /// Topics by name.
    pub topics: BTreeMap<String, TopicInfo>,
}

impl Graph {
    /// Every publisher→subscriber edge, sorted.
    pub fn edges(&self) -> Vec<Edge> {
        let mut out = Vec::new();
        for t in self.topics.values() {
            for p in &t.publishers {
                for s in &t.subscribers {
                    out.push(Edge {
                        topic: t.name.clone(),
                        publisher: p.clone(),
                        subscriber: s.clone(),
                    });
                }
            }
        }
        out
    }

    /// The changes that turn `self` into `next`, as events.
    pub fn diff(&self, next: &Graph) -> Vec<GraphEvent> {
        let mut ev = Vec::new();
        for (name, n) in &next.nodes {
            match self.nodes.get(name) {
                None => ev.push(GraphEvent::NodeAdded(n.clone())),
                Some(old) if old != n => ev.push(GraphEvent::NodeChanged(n.clone())),
                Some(_) => {}
            }
        }
        for name in self.nodes.keys() {
            if !next.nodes.contains_key(name) {
                ev.push(GraphEvent::NodeRemoved(name.clone()));
            }
        }
        let old: BTreeSet<Edge> = self.edges().into_iter().collect();
        let new: BTreeSet<Edge> = next.edges().into_iter().collect();
        ev.extend(new.difference(&old).cloned().map(GraphEvent::EdgeAdded));
        ev.extend(old.difference(&new).cloned().map(GraphEvent::EdgeRemoved));
        ev
    }
}

/// A change in the graph.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum GraphEvent {
    NodeAdded(NodeInfo),
    /// Same name, new uri or pid.
    NodeChanged(NodeInfo),
    NodeRemoved(String),
    EdgeAdded(Edge),
    EdgeRemoved(Edge),
}

/// Rate statistics of one message stream, measured like `rostopic hz`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TopicStats {
    /// 1 / mean inter-arrival time over the window.
    pub rate_hz: f64,
    /// Inter-arrival times in seconds.
    pub min_interval_s: f64,
    pub max_interval_s: f64,
    pub stddev_interval_s: f64,
    /// Low (5th) percentile of the rate over one-second sub-windows.
    pub low_rate_hz: f64,
    pub bytes_per_s: f64,
    /// Messages in the window.
    pub samples: usize,
    /// Window span in seconds.
    pub window_s: f64,
}

/// One adapted edge: everything on `topic` delivered to `subscriber`.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct EdgeId {
    pub topic: String,
    pub subscriber: String,
}

/// The setting of one adaptor.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct AdaptorSetting {
    /// Maximum forwarded rate; `None` = pass-through.
    pub rate_hz: Option<f64>,
}

/// Counters of one adaptor since it was created.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct EdgeCounters {
    pub forwarded: u64,
    pub dropped: u64,
    pub bytes: u64,
}

/// Errors of a data-plane backend.
#[derive(Debug, thiserror::Error)]
pub enum DataPlaneError {
    #[error("unknown topic {0}")]
    UnknownTopic(String),
    #[error("no subscriber {subscriber} on topic {topic}")]
    UnknownEdge { topic: String, subscriber: String },
    #[error("invalid adaptor rate {0} (must be finite and > 0)")]
    InvalidRate(f64),
    #[error("data plane backend failed: {message}")]
    Backend {
        message: String,
        #[source]
        source: Option<Box<dyn std::error::Error + Send + Sync>>,
    },
}

/// A backend of the data plane. Methods are cheap and non-blocking: IO runs
/// in the backend's own tasks.
pub trait DataPlane: Send + Sync {
    /// The current graph, with pids known so far.
    fn graph(&self) -> Graph;
    /// Rate statistics of `topic` as seen by a plain subscriber. The first
    /// call starts measuring; `Ok(None)` until enough messages arrived.
    fn topic_stats(&self, topic: &str) -> Result<Option<TopicStats>, DataPlaneError>;
    /// Messages the topic's meter has received since it started (the first
    /// call starts it, like [`DataPlane::topic_stats`]); a monotonic counter,
    /// so callers get exact counts over any interval from two readings.
    fn topic_messages(&self, topic: &str) -> Result<u64, DataPlaneError> {
        Err(DataPlaneError::Backend {
            message: format!("message counts of {topic} are not supported by this backend"),
            source: None,
        })
    }
    /// Rate statistics of what an adaptor forwards to its subscriber.
    fn edge_stats(&self, edge: &EdgeId) -> Option<TopicStats>;
    /// Puts an adaptor on `edge` (if none) and sets its rate; applies to a
    /// running subscriber without reconnecting when the adaptor exists.
    fn set_adaptor(&self, edge: &EdgeId, setting: AdaptorSetting) -> Result<(), DataPlaneError>;
    /// Removes the adaptor: the subscriber is pointed back at the publishers.
    fn remove_adaptor(&self, edge: &EdgeId) -> Result<(), DataPlaneError>;
    /// Adapted edges and their settings.
    fn adaptors(&self) -> BTreeMap<EdgeId, AdaptorSetting>;
    /// Counters of every adaptor.
    fn adaptor_counters(&self) -> BTreeMap<EdgeId, EdgeCounters>;
    /// Graph change events from now on.
    fn subscribe_events(&self) -> tokio::sync::broadcast::Receiver<GraphEvent>;
    /// Refreshes the graph (pids, liveness) now instead of at the next period.
    fn wake(&self);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(n: &str) -> NodeInfo {
        NodeInfo {
            name: n.into(),
            uri: format!("http://x/{n}"),
            pid: None,
        }
    }

    fn graph(pubs: &[&str], subs: &[&str]) -> Graph {
        let mut g = Graph::default();
        for n in pubs.iter().chain(subs) {
            g.nodes.insert((*n).into(), node(n));
        }
        g.topics.insert(
            "/t".into(),
            TopicInfo {
                name: "/t".into(),
                msg_type: "std_msgs/String".into(),
                publishers: pubs.iter().map(|s| s.to_string()).collect(),
                subscribers: subs.iter().map(|s| s.to_string()).collect(),
            },
        );
        g
    }

    #[test]
    fn edges_are_publisher_subscriber_pairs() {
        let g = graph(&["/a", "/b"], &["/c"]);
        let e = g.edges();
        assert_eq!(e.len(), 2);
        assert_eq!(e[0].publisher, "/a");
        assert_eq!(e[1].publisher, "/b");
        assert!(e.iter().all(|e| e.subscriber == "/c"));
    }

    #[test]
    fn diff_reports_added_and_removed_nodes_and_edges() {
        let a = graph(&["/a"], &["/c"]);
        let b = graph(&["/a"], &["/d"]);
        let ev = a.diff(&b);
        assert!(ev.contains(&GraphEvent::NodeAdded(node("/d"))));
        assert!(ev.contains(&GraphEvent::NodeRemoved("/c".into())));
        assert!(
            ev.iter()
                .any(|e| matches!(e, GraphEvent::EdgeAdded(x) if x.subscriber == "/d"))
        );
        assert!(
            ev.iter()
                .any(|e| matches!(e, GraphEvent::EdgeRemoved(x) if x.subscriber == "/c"))
        );
        assert!(a.diff(&a).is_empty());
    }
}
