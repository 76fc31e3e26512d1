//! Adaptor selection policy (paper §ConfigBot design): put an adaptor on an
//! edge when its topic runs above `min_topic_rate_hz` and its publisher or
//! subscriber belongs to a non-core app; explicit include/exclude lists win.
//! Pure: the caller supplies the graph, measured rates and the app mapping.
//!
//! This is the one rule both sides apply. The agent places adaptors by it at
//! subscribe time (`configbot_ros1::placement_from_apps` and the ROS 1
//! master, fed the agent runtime's app mapping: [`PolicyConfig`], [`AppOf`],
//! [`adaptable_type`]), and the controller's knob space
//! (`configbot_tuning::knobs`) gives an adaptor-rate knob to the edges
//! [`select_adaptor_edges`] returns. Neither side keeps a copy of it, so an
//! edge the controller tunes is an edge the agent adapts.

use std::collections::{BTreeMap, BTreeSet};

use crate::graph::{EdgeId, Graph};

/// Which app a node belongs to and whether that app is core.
pub trait AppOf {
    /// `Some(true)` for a node of a core app, `Some(false)` for a non-core
    /// app, `None` for a node of no known app (treated as core: never adapted
    /// on its own account).
    fn is_core(&self, node: &str) -> Option<bool>;
    /// Whether a non-core app claims `edge`, an input of another app's node
    /// (a shared nodelet manager's subscription that only it consumes): it is
    /// adapted as that app's own inputs are.
    fn claims(&self, _edge: &EdgeId) -> bool {
        false
    }
}

impl<F: Fn(&str) -> Option<bool>> AppOf for F {
    fn is_core(&self, node: &str) -> Option<bool> {
        self(node)
    }
}

/// Selects edges: a topic, optionally narrowed to one subscriber (the shape
/// of the PerformanceSpec's `EdgeSelector`).
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct EdgeSelector {
    pub topic: String,
    pub subscriber: Option<String>,
}

impl EdgeSelector {
    /// Every subscriber of `topic`.
    pub fn topic(topic: &str) -> Self {
        Self {
            topic: topic.into(),
            subscriber: None,
        }
    }

    /// Exactly one edge.
    pub fn edge(e: &EdgeId) -> Self {
        Self {
            topic: e.topic.clone(),
            subscriber: Some(e.subscriber.clone()),
        }
    }

    pub fn matches(&self, e: &EdgeId) -> bool {
        self.topic == e.topic && self.subscriber.as_ref().is_none_or(|s| *s == e.subscriber)
    }
}

/// Message types that carry liveness, not data: an adaptor that thins them
/// breaks the protocol (a nodelet whose bond heartbeats, `bond/Status`, stop
/// arriving is unloaded by its manager). Never adapted, even when included.
pub const NEVER_ADAPTED_TYPES: [&str; 1] = ["bond/Status"];

/// Whether edges of messages of type `msg_type` may be adapted at all.
pub fn adaptable_type(msg_type: &str) -> bool {
    !NEVER_ADAPTED_TYPES.contains(&msg_type)
}

/// Policy knobs.
#[derive(Debug, Clone, PartialEq)]
pub struct PolicyConfig {
    /// Topics at or below this rate are not adapted (default 5 Hz).
    pub min_topic_rate_hz: f64,
    /// Edges always adapted (if their topic has a publisher).
    pub include: Vec<EdgeSelector>,
    /// Edges never adapted; wins over `include`. Defaults to `/rosout`,
    /// `/rosout_agg` and `/clock`.
    pub exclude: Vec<EdgeSelector>,
}

impl PolicyConfig {
    pub fn excluded(&self, e: &EdgeId) -> bool {
        self.exclude.iter().any(|s| s.matches(e))
    }

    pub fn included(&self, e: &EdgeId) -> bool {
        self.include.iter().any(|s| s.matches(e))
    }
}

impl Default for PolicyConfig {
    fn default() -> Self {
        Self {
            min_topic_rate_hz: 5.0,
            include: Vec::new(),
            exclude: ["/rosout", "/rosout_agg", "/clock"]
                .into_iter()
                .map(EdgeSelector::topic)
                .collect(),
        }
    }
}

/// The edges that should carry an adaptor. `rates` maps topic → measured rate
/// (Hz); a topic without a measurement is not selected by the rate rule.
pub fn select_adaptor_edges(
    graph: &Graph,
    rates: &BTreeMap<String, f64>,
    apps: &dyn AppOf,
    cfg: &PolicyConfig,
) -> BTreeSet<EdgeId> {
    let non_core = |n: &str| apps.is_core(n) == Some(false);
    let mut out = BTreeSet::new();
    for t in graph.topics.values() {
        for sub in &t.subscribers {
            let id = EdgeId {
                topic: t.name.clone(),
                subscriber: sub.clone(),
            };
            if cfg.excluded(&id) || t.publishers.is_empty() || !adaptable_type(&t.msg_type) {
                continue;
            }
            if cfg.included(&id) || apps.claims(&id) {
                out.insert(id);
                continue;
            }
            let fast = rates
                .get(&t.name)
                .is_some_and(|r| *r > cfg.min_topic_rate_hz);
            let involves_non_core = non_core(sub) || t.publishers.iter().any(|p| non_core(p));
            if fast && involves_non_core {
                out.insert(id);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::TopicInfo;

    fn g() -> Graph {
        let mut g = Graph::default();
        let mut add = |topic: &str, pubs: &[&str], subs: &[&str]| {
            g.topics.insert(
                topic.into(),
                TopicInfo {
                    name: topic.into(),
                    msg_type: "t/T".into(),
                    publishers: pubs.iter().map(|s| s.to_string()).collect(),
                    subscribers: subs.iter().map(|s| s.to_string()).collect(),
                },
            );
        };
        add("/camera", &["/cam"], &["/nav", "/detector"]);
        add("/odom", &["/base"], &["/nav"]);
        add("/slow", &["/cam"], &["/detector"]);
        add("/rosout", &["/detector"], &["/logger"]);
        add("/orphan", &[], &["/detector"]);
        g
    }

    fn apps(n: &str) -> Option<bool> {
        match n {
            "/cam" | "/nav" | "/base" => Some(true),
            "/detector" => Some(false),
            _ => None,
        }
    }

    fn e(t: &str, s: &str) -> EdgeId {
        EdgeId {
            topic: t.into(),
            subscriber: s.into(),
        }
    }

    fn rates() -> BTreeMap<String, f64> {
        [
            ("/camera", 30.0),
            ("/odom", 50.0),
            ("/slow", 5.0),
            ("/rosout", 100.0),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect()
    }

    #[test]
    fn default_policy_table() {
        let sel = select_adaptor_edges(&g(), &rates(), &apps, &PolicyConfig::default());
        // fast topic, non-core subscriber: adapted; core subscriber of a
        // core publisher: not; 5 Hz is not above 5 Hz; /rosout excluded.
        assert_eq!(sel, [e("/camera", "/detector")].into_iter().collect());
    }

    #[test]
    fn non_core_publisher_adapts_all_its_subscribers() {
        let apps = |n: &str| if n == "/cam" { Some(false) } else { Some(true) };
        let sel = select_adaptor_edges(&g(), &rates(), &apps, &PolicyConfig::default());
        assert!(sel.contains(&e("/camera", "/nav")));
        assert!(sel.contains(&e("/camera", "/detector")));
        assert!(!sel.contains(&e("/slow", "/detector")));
        assert!(!sel.contains(&e("/odom", "/nav")));
    }

    #[test]
    fn include_and_exclude_lists_win() {
        let cfg = PolicyConfig {
            include: vec![
                EdgeSelector::edge(&e("/odom", "/nav")),
                EdgeSelector::edge(&e("/orphan", "/detector")),
                EdgeSelector::topic("/slow"),
            ],
            exclude: vec![
                EdgeSelector::edge(&e("/camera", "/detector")),
                EdgeSelector::topic("/slow"),
            ],
            ..PolicyConfig::default()
        };
        // a custom exclude list replaces the default one: /rosout (100 Hz,
        // non-core publisher) is now adapted too
        let sel = select_adaptor_edges(&g(), &rates(), &apps, &cfg);
        assert!(sel.contains(&e("/rosout", "/logger")));
        let mut cfg = cfg;
        cfg.exclude.extend(PolicyConfig::default().exclude);
        let sel = select_adaptor_edges(&g(), &rates(), &apps, &cfg);
        // orphan has no publisher: nothing to adapt; exclude wins over include.
        assert_eq!(sel, [e("/odom", "/nav")].into_iter().collect());
        let cfg = PolicyConfig {
            include: vec![EdgeSelector::topic("/slow")],
            ..PolicyConfig::default()
        };
        let sel = select_adaptor_edges(&g(), &rates(), &apps, &cfg);
        assert!(sel.contains(&e("/slow", "/detector")), "topic-wide include");
    }

    /// Bond heartbeats between a nodelet manager and its loaders are fast
    /// and touch non-core loaders, but thinning them unloads the nodelet.
    #[test]
    fn liveness_topics_are_never_adapted_even_when_included() {
        let mut graph = g();
        let mut bond = graph.topics["/camera"].clone();
        bond.name = "/vision/bond".into();
        bond.msg_type = "bond/Status".into();
        graph.topics.insert(bond.name.clone(), bond);
        let mut rates = rates();
        rates.insert("/vision/bond".into(), 10.0);
        let cfg = PolicyConfig {
            include: vec![EdgeSelector::topic("/vision/bond")],
            ..PolicyConfig::default()
        };
        let sel = select_adaptor_edges(&graph, &rates, &apps, &cfg);
        assert!(sel.iter().all(|e| e.topic != "/vision/bond"), "{sel:?}");
        assert!(sel.contains(&e("/camera", "/detector")));
        assert!(!adaptable_type("bond/Status") && adaptable_type("sensor_msgs/Image"));
    }

    #[test]
    fn unmeasured_topic_is_not_selected() {
        let sel = select_adaptor_edges(&g(), &BTreeMap::new(), &apps, &PolicyConfig::default());
        assert!(sel.is_empty());
    }
}
