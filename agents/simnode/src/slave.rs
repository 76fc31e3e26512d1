//! The node's slave XML-RPC API (what masters, rosnode and other nodes
//! call): getPid, getMasterUri, getBusInfo, getBusStats, getSubscriptions,
//! getPublications, requestTopic, publisherUpdate, paramUpdate, shutdown.
//! Subscriptions are live [`configbot_ros1::upstream::UpstreamSet`]s, so a
//! publisherUpdate (e.g. one naming an adaptor instead of the publisher)
//! reconnects the node.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use configbot_ros1::http::{BoxFut, Handler};
use configbot_ros1::tcpros::Header;
use configbot_ros1::upstream::{Frame, FrameSink, UpstreamSet};
use configbot_ros1::xmlrpc::{MethodCall, Response, Value};
use tokio::sync::Notify;

use crate::dispatch::{Dispatcher, Incoming};
use crate::msg;
use crate::publish::{BusRow, Publications};

/// Feeds one input topic's frames to the callbacks that listen to it and
/// remembers the connected publishers for getBusInfo.
#[derive(Debug)]
pub struct InSink {
    pub topic: String,
    /// Indices of the callbacks fed by this topic.
    pub callbacks: Vec<usize>,
    pub dispatcher: Arc<Dispatcher>,
    pub pubs: Arc<Publications>,
    /// Publisher api → (connection id, publisher caller id).
    conns: Mutex<BTreeMap<String, (u32, String)>>,
}

impl InSink {
    pub fn new(
        topic: &str,
        callbacks: Vec<usize>,
        dispatcher: Arc<Dispatcher>,
        pubs: Arc<Publications>,
    ) -> Self {
        Self {
            topic: topic.into(),
            callbacks,
            dispatcher,
            pubs,
            conns: Mutex::new(BTreeMap::new()),
        }
    }

    fn bus_rows(&self) -> Vec<BusRow> {
        self.conns.lock().map_or_else(
            |_| Vec::new(),
            |c| {
                c.values()
                    .map(|(id, peer)| (*id, peer.clone(), 'i', self.topic.clone()))
                    .collect()
            },
        )
    }
}

impl FrameSink for InSink {
    fn on_header(&self, api: &str, header: &Header) {
        let peer = header
            .get("callerid")
            .cloned()
            .unwrap_or_else(|| api.into());
        if let Ok(mut c) = self.conns.lock() {
            c.insert(api.into(), (self.pubs.next_id(), peer));
        }
    }

    fn on_frame(&self, _api: &str, frame: Frame) {
        let at = std::time::Instant::now();
        // The one owner of the frame (this connection feeds no one else).
        let frame = Arc::unwrap_or_clone(frame);
        if let Some((last, rest)) = self.callbacks.split_last() {
            for &i in rest {
                self.dispatcher.deliver(
                    i,
                    Incoming {
                        body: frame.clone(),
                        at,
                    },
                );
            }
            self.dispatcher.deliver(*last, Incoming { body: frame, at });
        }
    }

    fn on_gone(&self, api: &str) {
        if let Ok(mut c) = self.conns.lock() {
            c.remove(api);
        }
    }
}

/// A live subscription: its sink, its publisher connections, and how many
/// publisherUpdates it has had.
///
/// The count orders the two ways a publisher list arrives. A master sends
/// publisherUpdate only to registered subscribers, so an update that arrives
/// while the node still waits for its registerSubscriber reply is newer than
/// that reply; applying the reply afterwards would drop the publisher the
/// update added (seen once in CI: a /scan publisher that registered during
/// the navigation node's registerSubscriber, and cmd_vel never flowed).
#[derive(Debug)]
pub struct Subscription {
    pub sink: Arc<InSink>,
    pub upstream: UpstreamSet,
    updates: Mutex<u64>,
}

impl Subscription {
    pub fn new(sink: Arc<InSink>, upstream: UpstreamSet) -> Self {
        Self {
            sink,
            upstream,
            updates: Mutex::new(0),
        }
    }

    /// How many publisherUpdates have arrived; read before registering.
    pub fn updates_seen(&self) -> u64 {
        *self
            .updates
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// A publisherUpdate: the master's current publishers of the topic.
    pub fn publisher_update(&self, apis: &[String]) {
        let mut n = self
            .updates
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        *n += 1;
        self.upstream.set_publishers(apis, "*");
    }

    /// The registerSubscriber reply of a call made after `seen` updates:
    /// applied unless an update arrived since (it is newer); returns whether
    /// it was applied.
    pub fn registered(&self, seen: u64, apis: &[String]) -> bool {
        let n = self
            .updates
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let fresh = *n == seen;
        if fresh {
            self.upstream.set_publishers(apis, "*");
        }
        fresh
    }
}

/// The slave API handler.
#[derive(Debug)]
pub struct Slave {
    pub master_uri: String,
    pub host: String,
    pub tcpros_port: u16,
    pub pubs: Arc<Publications>,
    pub subs: BTreeMap<String, Subscription>,
    pub shutdown: Arc<Notify>,
}

/// Publisher URIs in a publisherUpdate / registerSubscriber reply.
pub fn uris(v: Option<&Value>) -> Vec<String> {
    v.and_then(Value::as_array)
        .map(|a| {
            a.iter()
                .filter_map(|u| u.as_str().map(String::from))
                .collect()
        })
        .unwrap_or_default()
}

impl Slave {
    fn bus_info(&self) -> Value {
        let mut rows = self.pubs.bus_rows();
        for s in self.subs.values() {
            rows.extend(s.sink.bus_rows());
        }
        Value::Array(
            rows.into_iter()
                .map(|(id, peer, dir, topic)| {
                    Value::Array(vec![
                        Value::Int(i64::from(id)),
                        Value::Str(peer),
                        Value::str(dir.to_string()),
                        Value::str("TCPROS"),
                        Value::Str(topic),
                        Value::Bool(true),
                        Value::str(""),
                    ])
                })
                .collect(),
        )
    }

    fn pairs<'a>(names: impl Iterator<Item = &'a String>) -> Value {
        Value::Array(
            names
                .map(|t| Value::Array(vec![Value::str(t), Value::str(msg::MSG_TYPE)]))
                .collect(),
        )
    }

    fn answer(&self, call: &MethodCall) -> Response {
        let ok = |v| Response::Ok(Value::ros(1, "", v));
        match call.method.as_str() {
            "getPid" => ok(Value::Int(i64::from(std::process::id()))),
            "getMasterUri" => ok(Value::str(&self.master_uri)),
            "getBusInfo" => ok(self.bus_info()),
            "getBusStats" => ok(Value::Array(vec![
                Value::Array(vec![]),
                Value::Array(vec![]),
                Value::Array(vec![]),
            ])),
            "getPublications" => ok(Self::pairs(self.pubs.names())),
            "getSubscriptions" => ok(Self::pairs(self.subs.keys())),
            "requestTopic" => {
                let topic = call.params.get(1).and_then(Value::as_str).unwrap_or("");
                if self.pubs.topic(topic).is_none() {
                    return Response::Ok(Value::ros(
                        0,
                        format!("{} does not publish {topic}", self.pubs.caller_id),
                        Value::Array(vec![]),
                    ));
                }
                let tcpros = call
                    .params
                    .get(2)
                    .and_then(Value::as_array)
                    .is_some_and(|ps| {
                        ps.iter().any(|p| {
                            p.as_array().and_then(|a| a.first()).and_then(Value::as_str)
                                == Some("TCPROS")
                        })
                    });
                if !tcpros {
                    return Response::Ok(Value::ros(
                        0,
                        "only TCPROS is supported",
                        Value::Array(vec![]),
                    ));
                }
                ok(Value::Array(vec![
                    Value::str("TCPROS"),
                    Value::str(&self.host),
                    Value::Int(i64::from(self.tcpros_port)),
                ]))
            }
            "publisherUpdate" => {
                let topic = call.params.get(1).and_then(Value::as_str).unwrap_or("");
                if let Some(s) = self.subs.get(topic) {
                    s.publisher_update(&uris(call.params.get(2)));
                }
                ok(Value::Int(0))
            }
            "paramUpdate" => ok(Value::Int(0)),
            "shutdown" => {
                self.shutdown.notify_one();
                ok(Value::Int(0))
            }
            other => Response::Fault {
                code: -32601,
                message: format!("unknown method {other}"),
            },
        }
    }
}

impl Handler for Slave {
    fn handle(self: Arc<Self>, call: MethodCall) -> BoxFut<Response> {
        Box::pin(async move { self.answer(&call) })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dispatch::PerMessage;
    use std::sync::atomic::AtomicBool;
    use std::time::Duration;

    fn subscription() -> Subscription {
        let stop = Arc::new(AtomicBool::new(false));
        let dispatcher = Arc::new(Dispatcher::PerMessage(Arc::new(PerMessage::new(
            vec![],
            1,
            0.0,
            stop,
        ))));
        let pubs = Arc::new(Publications::new("/n", []));
        let sink = Arc::new(InSink::new("/scan", vec![], dispatcher, pubs));
        let upstream = UpstreamSet::new(
            "/n",
            "/scan",
            sink.clone(),
            Duration::from_secs(1),
            tokio::runtime::Handle::current(),
        );
        Subscription::new(sink, upstream)
    }

    // Publisher APIs nobody listens on: the connections just keep retrying.
    fn apis(n: &[&str]) -> Vec<String> {
        n.iter()
            .map(|p| format!("http://127.0.0.1:9/{p}"))
            .collect()
    }

    #[tokio::test]
    async fn a_register_reply_older_than_an_update_does_not_undo_it() {
        let s = subscription();
        let seen = s.updates_seen();
        // The publisher registers while our registerSubscriber is in flight.
        s.publisher_update(&apis(&["lidar"]));
        // The reply the master computed before it: no publishers yet.
        assert!(!s.registered(seen, &[]));
        assert_eq!(s.upstream.len(), 1, "the update's publisher was dropped");
    }

    #[tokio::test]
    async fn a_register_reply_with_no_update_since_sets_the_publishers() {
        let s = subscription();
        s.publisher_update(&apis(&["old"]));
        let seen = s.updates_seen();
        assert!(s.registered(seen, &apis(&["a", "b"])));
        assert_eq!(s.upstream.len(), 2);
        // Later updates still replace the list (an adaptor instead of both).
        s.publisher_update(&apis(&["adaptor"]));
        assert_eq!(s.upstream.len(), 1);
    }
}
