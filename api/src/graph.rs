//! The ROS graph as data: nodes, topics and their publisher→subscriber
//! edges ([`Graph`], with [`Graph::edges`] and [`Graph::diff`] into
//! [`GraphEvent`]s), per-topic rate statistics ([`TopicStats`]), and the
//! adapted edges with their settings and counters ([`EdgeId`],
//! [`AdaptorSetting`], [`EdgeCounters`]). The agent serves these (`GET
//! /v1/graph`, graph events on `/v1/events`); the data-plane trait
//! (`configbot_dataplane::DataPlane`) is written in them; the controller's
//! tuning core reads them.

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

    /// The JSON the agent serves and the controller reads: field names and
    /// enum tags exactly as they were when these types lived in the agent's
    /// crates (a change here breaks a controller talking to an older agent).
    #[test]
    fn wire_format_is_stable() {
        let mut g = graph(&["/a"], &["/b"]);
        g.nodes.get_mut("/a").unwrap().pid = Some(7);
        assert_eq!(
            serde_json::to_string(&g).unwrap(),
            r#"{"nodes":{"/a":{"name":"/a","uri":"http://x//a","pid":7},"/b":{"name":"/b","uri":"http://x//b","pid":null}},"topics":{"/t":{"name":"/t","msg_type":"std_msgs/String","publishers":["/a"],"subscribers":["/b"]}}}"#
        );
        let e = g.edges().remove(0);
        let evs = vec![
            GraphEvent::NodeAdded(g.nodes["/a"].clone()),
            GraphEvent::NodeRemoved("/c".into()),
            GraphEvent::EdgeAdded(e),
        ];
        let j = serde_json::to_string(&evs).unwrap();
        assert_eq!(
            j,
            r#"[{"NodeAdded":{"name":"/a","uri":"http://x//a","pid":7}},{"NodeRemoved":"/c"},{"EdgeAdded":{"topic":"/t","publisher":"/a","subscriber":"/b"}}]"#
        );
        assert_eq!(serde_json::from_str::<Vec<GraphEvent>>(&j).unwrap(), evs);
        let stats = TopicStats {
            rate_hz: 30.0,
            min_interval_s: 0.03,
            max_interval_s: 0.04,
            stddev_interval_s: 0.001,
            low_rate_hz: 29.5,
            bytes_per_s: 1000.0,
            samples: 60,
            window_s: 2.0,
        };
        assert_eq!(
            serde_json::to_string(&stats).unwrap(),
            r#"{"rate_hz":30.0,"min_interval_s":0.03,"max_interval_s":0.04,"stddev_interval_s":0.001,"low_rate_hz":29.5,"bytes_per_s":1000.0,"samples":60,"window_s":2.0}"#
        );
        let edge = EdgeId {
            topic: "/t".into(),
            subscriber: "/b".into(),
        };
        let adaptor = (
            edge,
            AdaptorSetting { rate_hz: Some(2.5) },
            AdaptorSetting::default(),
            EdgeCounters {
                forwarded: 1,
                dropped: 2,
                bytes: 3,
            },
        );
        assert_eq!(
            serde_json::to_string(&adaptor).unwrap(),
            r#"[{"topic":"/t","subscriber":"/b"},{"rate_hz":2.5},{"rate_hz":null},{"forwarded":1,"dropped":2,"bytes":3}]"#
        );
    }
}
