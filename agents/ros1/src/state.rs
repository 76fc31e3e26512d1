//! The master's registration state (nodes, publishers, subscribers,
//! services, topic types, parameters and parameter subscriptions) and the
//! rules of the ROS Master API over it. Pure: every operation returns the
//! callbacks ([`Effect`]s) the IO layer must make.

use std::collections::{BTreeMap, BTreeSet};

use serde::{Deserialize, Serialize};

use crate::params::{self, ParamTree};
use crate::xmlrpc::Value;

/// A callback the master owes some node after a state change.
#[derive(Debug, Clone, PartialEq)]
pub enum Effect {
    /// Tell node (at `api`) to shut down: another node took its name.
    Shutdown { api: String, reason: String },
    /// The publisher set of `topic` changed (a publisher came, went or got
    /// a new URI): re-point the master's own subscribers (topic meters,
    /// adaptor relays), which are not registered nodes.
    PublishersChanged { topic: String },
    /// Send `subscriber` the current publisher list of `topic`.
    PublisherUpdate { topic: String, subscriber: String },
    /// Send `node` the new value of subscribed parameter `key`.
    ParamUpdate {
        node: String,
        key: String,
        value: Value,
    },
}

/// Registrations and parameters.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MasterState {
    /// node name → slave API URI
    pub nodes: BTreeMap<String, String>,
    /// topic → publishing nodes
    pub publishers: BTreeMap<String, BTreeSet<String>>,
    /// topic → subscribing nodes
    pub subscribers: BTreeMap<String, BTreeSet<String>>,
    /// service → (node, service URI)
    pub services: BTreeMap<String, (String, String)>,
    /// topic → message type
    pub topic_types: BTreeMap<String, String>,
    pub params: ParamTree,
    /// parameter key → subscribed nodes
    pub param_subscribers: BTreeMap<String, BTreeSet<String>>,
}

fn remove_from(map: &mut BTreeMap<String, BTreeSet<String>>, key: &str, node: &str) -> bool {
    let Some(set) = map.get_mut(key) else {
        return false;
    };
    let removed = set.remove(node);
    if set.is_empty() {
        map.remove(key);
    }
    removed
}

impl MasterState {
    /// Records `node` at `api`. A different API under the same name bumps the
    /// old node: its registrations go and it is told to shut down.
    pub fn register_node(&mut self, node: &str, api: &str) -> Vec<Effect> {
        let mut fx = Vec::new();
        match self.nodes.get(node) {
            Some(old) if old == api => {}
            Some(old) => {
                let old = old.clone();
                fx.extend(self.drop_node(node));
                fx.push(Effect::Shutdown {
                    api: old,
                    reason: format!("new node registered with same name {node}"),
                });
                self.nodes.insert(node.into(), api.into());
            }
            None => {
                self.nodes.insert(node.into(), api.into());
            }
        }
        fx
    }

    fn note_type(&mut self, topic: &str, msg_type: &str) {
        if msg_type != "*" && !msg_type.is_empty() {
            self.topic_types.insert(topic.into(), msg_type.into());
        } else {
            self.topic_types
                .entry(topic.into())
                .or_insert_with(|| "*".into());
        }
    }

    /// registerPublisher → (subscriber APIs, effects).
    pub fn register_publisher(
        &mut self,
        node: &str,
        api: &str,
        topic: &str,
        msg_type: &str,
    ) -> (Vec<String>, Vec<Effect>) {
        let mut fx = self.register_node(node, api);
        self.note_type(topic, msg_type);
        self.publishers
            .entry(topic.into())
            .or_default()
            .insert(node.into());
        fx.extend(self.updates_for(topic));
        (self.apis(self.subscribers.get(topic)), fx)
    }

    /// unregisterPublisher → (number removed, effects).
    pub fn unregister_publisher(
        &mut self,
        node: &str,
        api: &str,
        topic: &str,
    ) -> (i64, Vec<Effect>) {
        if self.nodes.get(node).is_some_and(|a| a != api) {
            return (0, Vec::new());
        }
        if !remove_from(&mut self.publishers, topic, node) {
            return (0, Vec::new());
        }
        let fx = self.updates_for(topic);
        self.gc_node(node);
        (1, fx)
    }

    /// registerSubscriber → (publisher nodes, effects).
    pub fn register_subscriber(
        &mut self,
        node: &str,
        api: &str,
        topic: &str,
        msg_type: &str,
    ) -> (Vec<String>, Vec<Effect>) {
        let fx = self.register_node(node, api);
        self.note_type(topic, msg_type);
        self.subscribers
            .entry(topic.into())
            .or_default()
            .insert(node.into());
        let pubs = self
            .publishers
            .get(topic)
            .map(|s| s.iter().cloned().collect())
            .unwrap_or_default();
        (pubs, fx)
    }

    pub fn unregister_subscriber(&mut self, node: &str, api: &str, topic: &str) -> i64 {
        if self.nodes.get(node).is_some_and(|a| a != api) {
            return 0;
        }
        let n = i64::from(remove_from(&mut self.subscribers, topic, node));
        self.gc_node(node);
        n
    }

    pub fn register_service(
        &mut self,
        node: &str,
        api: &str,
        service: &str,
        service_api: &str,
    ) -> Vec<Effect> {
        let fx = self.register_node(node, api);
        self.services
            .insert(service.into(), (node.into(), service_api.into()));
        fx
    }

    pub fn unregister_service(&mut self, node: &str, service: &str, service_api: &str) -> i64 {
        match self.services.get(service) {
            Some((n, a)) if n == node && a == service_api => {
                self.services.remove(service);
                self.gc_node(node);
                1
            }
            _ => 0,
        }
    }

    /// Removes every registration of `node` (dead or bumped).
    pub fn drop_node(&mut self, node: &str) -> Vec<Effect> {
        let mut fx = Vec::new();
        let topics: Vec<String> = self
            .publishers
            .iter()
            .filter(|(_, s)| s.contains(node))
            .map(|(t, _)| t.clone())
            .collect();
        for t in topics {
            remove_from(&mut self.publishers, &t, node);
            fx.extend(self.updates_for(&t));
        }
        let subs: Vec<String> = self.subscribers.keys().cloned().collect();
        for t in subs {
            remove_from(&mut self.subscribers, &t, node);
        }
        self.services.retain(|_, (n, _)| n != node);
        let keys: Vec<String> = self.param_subscribers.keys().cloned().collect();
        for k in keys {
            remove_from(&mut self.param_subscribers, &k, node);
        }
        self.nodes.remove(node);
        fx
    }

    fn gc_node(&mut self, node: &str) {
        let used = self.publishers.values().any(|s| s.contains(node))
            || self.subscribers.values().any(|s| s.contains(node))
            || self.services.values().any(|(n, _)| n == node)
            || self.param_subscribers.values().any(|s| s.contains(node));
        if !used {
            self.nodes.remove(node);
        }
    }

    /// What a change of `topic`'s publisher set owes: the master's own
    /// subscribers first (also when no node subscribes), then every
    /// registered subscriber.
    fn updates_for(&self, topic: &str) -> Vec<Effect> {
        let nodes =
            self.subscribers
                .get(topic)
                .into_iter()
                .flatten()
                .map(|s| Effect::PublisherUpdate {
                    topic: topic.into(),
                    subscriber: s.clone(),
                });
        std::iter::once(Effect::PublishersChanged {
            topic: topic.into(),
        })
        .chain(nodes)
        .collect()
    }

    fn apis(&self, nodes: Option<&BTreeSet<String>>) -> Vec<String> {
        nodes
            .into_iter()
            .flatten()
            .filter_map(|n| self.nodes.get(n).cloned())
            .collect()
    }

    /// Slave API URIs of the publishers of `topic`.
    pub fn publisher_apis(&self, topic: &str) -> Vec<String> {
        self.apis(self.publishers.get(topic))
    }

    /// getSystemState's `[publishers, subscribers, services]`.
    pub fn system_state(&self) -> Value {
        let list = |m: &BTreeMap<String, BTreeSet<String>>| {
            Value::Array(
                m.iter()
                    .map(|(t, ns)| {
                        Value::Array(vec![
                            Value::str(t),
                            Value::Array(ns.iter().map(Value::str).collect()),
                        ])
                    })
                    .collect(),
            )
        };
        let services = Value::Array(
            self.services
                .iter()
                .map(|(s, (n, _))| {
                    Value::Array(vec![Value::str(s), Value::Array(vec![Value::str(n)])])
                })
                .collect(),
        );
        Value::Array(vec![
            list(&self.publishers),
            list(&self.subscribers),
            services,
        ])
    }

    /// getPublishedTopics: `[[topic, type]]` of topics with publishers under
    /// `subgraph`.
    pub fn published_topics(&self, subgraph: &str) -> Value {
        let prefix = if subgraph.is_empty() || subgraph == "/" {
            "/".to_string()
        } else {
            format!("{}/", params::canonical(subgraph))
        };
        Value::Array(
            self.publishers
                .keys()
                .filter(|t| t.starts_with(&prefix))
                .map(|t| Value::Array(vec![Value::str(t), Value::str(self.type_of(t))]))
                .collect(),
        )
    }

    pub fn type_of(&self, topic: &str) -> &str {
        self.topic_types.get(topic).map_or("*", String::as_str)
    }

    /// getTopicTypes.
    pub fn topic_types_value(&self) -> Value {
        Value::Array(
            self.topic_types
                .iter()
                .map(|(t, ty)| Value::Array(vec![Value::str(t), Value::str(ty)]))
                .collect(),
        )
    }

    /// setParam with subscriber notifications.
    pub fn set_param(&mut self, key: &str, value: Value) -> Vec<Effect> {
        self.params.set(key, value);
        self.param_effects(key)
    }

    /// deleteParam; None if it was not set.
    pub fn delete_param(&mut self, key: &str) -> Option<Vec<Effect>> {
        self.params.delete(key).then(|| self.param_effects(key))
    }

    fn param_effects(&self, key: &str) -> Vec<Effect> {
        let mut fx = Vec::new();
        for k in params::affected(key, self.param_subscribers.keys()) {
            let value = self
                .params
                .get(&k)
                .unwrap_or(Value::Struct(BTreeMap::new()));
            for n in self.param_subscribers.get(&k).into_iter().flatten() {
                fx.push(Effect::ParamUpdate {
                    node: n.clone(),
                    key: format!("{}/", k.trim_end_matches('/')),
                    value: value.clone(),
                });
            }
        }
        fx
    }

    /// subscribeParam → current value (`{}` when unset).
    pub fn subscribe_param(&mut self, node: &str, api: &str, key: &str) -> (Value, Vec<Effect>) {
        let fx = self.register_node(node, api);
        self.param_subscribers
            .entry(key.into())
            .or_default()
            .insert(node.into());
        (
            self.params
                .get(key)
                .unwrap_or(Value::Struct(BTreeMap::new())),
            fx,
        )
    }

    pub fn unsubscribe_param(&mut self, node: &str, key: &str) -> i64 {
        let n = i64::from(remove_from(&mut self.param_subscribers, key, node));
        self.gc_node(node);
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn publisher_registration_notifies_subscribers() {
        let mut s = MasterState::default();
        let (pubs, fx) = s.register_subscriber("/l", "http://l:1/", "/chatter", "std_msgs/String");
        assert!(pubs.is_empty() && fx.is_empty());
        let (subs, fx) = s.register_publisher("/t", "http://t:1/", "/chatter", "std_msgs/String");
        assert_eq!(subs, vec!["http://l:1/"]);
        assert_eq!(
            fx,
            vec![
                Effect::PublishersChanged {
                    topic: "/chatter".into()
                },
                Effect::PublisherUpdate {
                    topic: "/chatter".into(),
                    subscriber: "/l".into()
                }
            ]
        );
        assert_eq!(s.publisher_apis("/chatter"), vec!["http://t:1/"]);
        let (n, fx) = s.unregister_publisher("/t", "http://t:1/", "/chatter");
        assert_eq!((n, fx.len()), (1, 2));
        assert!(
            !s.nodes.contains_key("/t"),
            "node without registrations is forgotten"
        );
        // wrong api: ignored
        assert_eq!(
            s.unregister_subscriber("/l", "http://other/", "/chatter"),
            0
        );
        assert_eq!(s.unregister_subscriber("/l", "http://l:1/", "/chatter"), 1);
        assert!(s.nodes.is_empty());
    }

    #[test]
    fn same_name_new_api_bumps_old_node() {
        let mut s = MasterState::default();
        s.register_publisher("/t", "http://old/", "/a", "x/Y");
        s.register_subscriber("/l", "http://l/", "/a", "x/Y");
        let (_, fx) = s.register_subscriber("/t", "http://new/", "/b", "x/Y");
        assert!(fx.contains(&Effect::Shutdown {
            api: "http://old/".into(),
            reason: "new node registered with same name /t".into()
        }));
        assert!(fx.iter().any(
            |e| matches!(e, Effect::PublisherUpdate { subscriber, .. } if subscriber == "/l")
        ));
        assert!(!s.publishers.contains_key("/a"));
        assert_eq!(s.nodes["/t"], "http://new/");
    }

    #[test]
    fn publisher_changes_without_subscribers_still_repoint_meters() {
        // A topic only the master's meter reads (e.g. /cmd_vel): a restarted
        // publisher (same name, new URI) must still re-point the meter.
        let changed =
            |fx: &[Effect], t: &str| fx.contains(&Effect::PublishersChanged { topic: t.into() });
        let mut s = MasterState::default();
        let (_, fx) = s.register_publisher("/nav", "http://old/", "/cmd_vel", "x/Y");
        assert_eq!(
            fx,
            vec![Effect::PublishersChanged {
                topic: "/cmd_vel".into()
            }]
        );
        s.register_publisher("/nav", "http://old/", "/path", "x/Y");
        // The new incarnation registers /cmd_vel first: the bump drops the
        // old /path too, and both topics change.
        let (_, fx) = s.register_publisher("/nav", "http://new/", "/cmd_vel", "x/Y");
        assert!(changed(&fx, "/cmd_vel") && changed(&fx, "/path"), "{fx:?}");
        assert_eq!(s.publisher_apis("/cmd_vel"), vec!["http://new/"]);
        // The old incarnation's late unregister changes nothing.
        assert_eq!(
            s.unregister_publisher("/nav", "http://old/", "/cmd_vel"),
            (0, vec![])
        );
        let (n, fx) = s.unregister_publisher("/nav", "http://new/", "/cmd_vel");
        assert_eq!(
            (n, fx),
            (
                1,
                vec![Effect::PublishersChanged {
                    topic: "/cmd_vel".into()
                }]
            )
        );
    }

    #[test]
    fn system_state_and_topics() {
        let mut s = MasterState::default();
        s.register_publisher("/t", "http://t/", "/ns/a", "x/Y");
        s.register_subscriber("/l", "http://l/", "/b", "*");
        s.register_service("/t", "http://t/", "/srv", "rosrpc://t:1");
        let Value::Array(st) = s.system_state() else {
            panic!()
        };
        assert_eq!(st.len(), 3);
        assert_eq!(
            s.published_topics("/ns"),
            Value::Array(vec![Value::Array(vec![
                Value::str("/ns/a"),
                Value::str("x/Y")
            ])])
        );
        assert_eq!(s.published_topics("/other"), Value::Array(vec![]));
        assert_eq!(s.type_of("/b"), "*");
        assert_eq!(s.unregister_service("/t", "/srv", "rosrpc://t:1"), 1);
    }

    #[test]
    fn param_subscriptions_get_updates() {
        let mut s = MasterState::default();
        let (v, _) = s.subscribe_param("/n", "http://n/", "/a");
        assert_eq!(v, Value::Struct(BTreeMap::new()));
        let fx = s.set_param("/a/b", Value::Int(1));
        assert_eq!(fx.len(), 1);
        let Effect::ParamUpdate { key, value, .. } = &fx[0] else {
            panic!()
        };
        assert_eq!(key, "/a/");
        assert!(matches!(value, Value::Struct(m) if m.get("b") == Some(&Value::Int(1))));
        assert!(s.set_param("/z", Value::Int(1)).is_empty());
        assert!(s.delete_param("/nope").is_none());
        assert_eq!(s.delete_param("/a").map(|f| f.len()), Some(1));
    }
}
