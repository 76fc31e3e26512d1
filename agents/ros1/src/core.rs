//! The shared core of the ROS 1 data plane: master state behind a lock, its
//! persistence, adaptor relays and topic meters with the taps that feed them
//! (one upstream subscription per topic), and the IO that carries out the
//! master's [`Effect`]s (re-pointing taps, publisherUpdate, paramUpdate,
//! shutdown calls).

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use configbot_api::backoff::Backoff;
use configbot_dataplane::{AdaptorSetting, EdgeId};
use tokio::sync::Notify;

use crate::adaptor::{ADAPTOR_PREFIX, AdaptorMetrics, EdgeRelay, Relays};
use crate::http;
use crate::meter::{METER_KEY, Meter};
use crate::state::{Effect, MasterState};
use crate::store::Store;
use crate::tap::Tap;
use crate::upstream::FrameSink;
use crate::xmlrpc::Value;

/// Decides at subscribe time whether an edge gets a (pass-through) adaptor:
/// `(edge, publisher node names) -> bool`.
pub type Placement = Arc<dyn Fn(&EdgeId, &[String]) -> bool + Send + Sync>;

/// Caller id the master uses in its callbacks.
pub const MASTER_CALLER_ID: &str = "/master";

/// How many times the master tries to get one publisherUpdate through.
pub const UPDATE_ATTEMPTS: u32 = 4;

pub(crate) struct Core {
    pub state: Mutex<MasterState>,
    pub store: Mutex<Store>,
    pub master_uri: String,
    pub adaptor_uri: String,
    pub relays: Relays,
    pub settings: Mutex<BTreeMap<EdgeId, AdaptorSetting>>,
    pub placement: Placement,
    pub metrics: AdaptorMetrics,
    pub meters: Mutex<BTreeMap<String, Arc<Meter>>>,
    /// One per topic that a meter or a relay reads, by topic.
    pub taps: Mutex<BTreeMap<String, Arc<Tap>>>,
    /// The runtime of the metering threads (the master, the meters and the
    /// taps they read) and of the relaying ones (taps that feed only
    /// relays, and the relays' writes to their subscribers).
    pub metering: tokio::runtime::Handle,
    pub relaying: tokio::runtime::Handle,
    pub meter_window_s: f64,
    pub wake: Notify,
    pub timeout: Duration,
    /// One lock per edge with an update pending or in flight:
    /// publisherUpdates of a topic to a subscriber go out one at a time, each
    /// with the list as it is when sent, so of the calls the node answered the
    /// last is the newest (spawned calls could arrive reordered). A call that
    /// timed out may still be handled by the node later, after its retry.
    pub updating: Mutex<BTreeMap<EdgeId, Arc<tokio::sync::Mutex<()>>>>,
    /// Set when the data plane is dropped: pending publisherUpdates stop.
    pub closed: std::sync::atomic::AtomicBool,
}

impl std::fmt::Debug for Core {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Core")
            .field("master_uri", &self.master_uri)
            .field("adaptor_uri", &self.adaptor_uri)
            .finish_non_exhaustive()
    }
}

/// Locks, recovering from poisoning (a panicked holder left valid data: every
/// critical section is a plain map update).
pub(crate) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The entry `key` of `map`, made by `make` if it is missing; `true` when it
/// was made by this call (so its caller wires it up once).
fn get_or_make<K: Ord + Clone, V>(
    map: &Mutex<BTreeMap<K, Arc<V>>>,
    key: &K,
    make: impl FnOnce() -> V,
) -> (Arc<V>, bool) {
    let mut map = lock(map);
    if let Some(v) = map.get(key) {
        return (v.clone(), false);
    }
    let v = Arc::new(make());
    map.insert(key.clone(), v.clone());
    (v, true)
}

impl Core {
    /// Writes the master state to the database (errors are logged: the
    /// in-memory master keeps serving).
    pub fn persist(&self) {
        let snapshot = lock(&self.state).clone();
        if let Err(e) = lock(&self.store).save(&snapshot) {
            tracing::error!(error = %e, "persisting master state");
        }
    }

    pub fn persist_adaptors(&self) {
        let s = lock(&self.settings).clone();
        if let Err(e) = lock(&self.store).save_adaptors(&s) {
            tracing::error!(error = %e, "persisting adaptor settings");
        }
    }

    /// The publisher list `subscriber` should see for `topic`: the adaptor
    /// when the edge is adapted and has publishers, else the real ones.
    pub fn publishers_for(self: &Arc<Self>, topic: &str, subscriber: &str) -> Vec<String> {
        let (apis, msg_type) = self.publishers_of(topic);
        let id = EdgeId {
            topic: topic.into(),
            subscriber: subscriber.into(),
        };
        let setting = lock(&self.settings).get(&id).copied();
        match setting {
            Some(s) if !apis.is_empty() => {
                self.ensure_relay(&id, s);
                self.tap(topic, TapReader::Relay)
                    .set_publishers(&apis, &msg_type);
                vec![self.adaptor_uri.clone()]
            }
            _ => apis,
        }
    }

    /// The master's publisher APIs of `topic` and its type.
    fn publishers_of(&self, topic: &str) -> (Vec<String>, String) {
        let st = lock(&self.state);
        (st.publisher_apis(topic), st.type_of(topic).to_string())
    }

    fn ensure_relay(&self, id: &EdgeId, s: AdaptorSetting) -> Arc<EdgeRelay> {
        let (edge, created) = get_or_make(&self.relays, id, || {
            EdgeRelay::new(id.clone(), s, self.metrics.clone())
        });
        if created {
            self.tap(&id.topic, TapReader::Relay)
                .add(&relay_key(id), edge.clone());
        }
        edge
    }

    /// Removes the relay of `id` (its subscriber is gone or no longer
    /// adapted) and its topic's tap when nothing else reads it.
    pub fn drop_relay(&self, id: &EdgeId) -> Option<Arc<EdgeRelay>> {
        let edge = lock(&self.relays).remove(id)?;
        self.leave_tap(
            &id.topic,
            &relay_key(id),
            &(edge.clone() as Arc<dyn FrameSink>),
        );
        Some(edge)
    }

    /// The tap of `topic`, created (and pointed at the topic's publishers)
    /// when nothing read the topic yet; for a meter its connections run on
    /// the metering threads, for a relay where they are (the relaying
    /// threads for a new tap).
    fn tap(&self, topic: &str, reader: TapReader) -> Arc<Tap> {
        let metered = reader == TapReader::Meter;
        let rt = if metered {
            &self.metering
        } else {
            &self.relaying
        };
        let (tap, created) = get_or_make(&self.taps, &topic.to_string(), || {
            Tap::new(topic, self.timeout, rt.clone(), metered)
        });
        if created {
            let (apis, ty) = self.publishers_of(topic);
            tap.set_publishers(&apis, &ty);
        } else if metered {
            tap.meter_on(self.metering.clone());
        }
        tap
    }

    /// Removes `reader` (by `key`) from `topic`'s tap, and the tap (closing
    /// its connections) when it was the last.
    fn leave_tap(&self, topic: &str, key: &str, reader: &Arc<dyn FrameSink>) {
        let mut taps = lock(&self.taps);
        if let Some(t) = taps.get(topic)
            && !t.remove(key, reader)
        {
            taps.remove(topic);
        }
    }

    /// Re-points `topic`'s tap (its meter and relays) at its current publishers.
    pub fn refresh_topic(&self, topic: &str) {
        let tap = lock(&self.taps).get(topic).cloned();
        if let Some(t) = tap {
            let (apis, ty) = self.publishers_of(topic);
            t.set_publishers(&apis, &ty);
        }
    }

    /// Carries out effects in background tasks.
    pub fn run_effects(self: &Arc<Self>, fx: Vec<Effect>) {
        for e in fx {
            let core = self.clone();
            match e {
                Effect::Shutdown { api, reason } => {
                    tokio::spawn(async move {
                        let _ = http::call(
                            &api,
                            "shutdown",
                            &[Value::str(MASTER_CALLER_ID), Value::str(reason)],
                            core.timeout,
                        )
                        .await;
                    });
                }
                Effect::PublishersChanged { topic } => self.refresh_topic(&topic),
                Effect::PublisherUpdate { topic, subscriber } => {
                    tokio::spawn(core.publisher_update(EdgeId { topic, subscriber }));
                }
                Effect::ParamUpdate { node, key, value } => {
                    let api = lock(&self.state).nodes.get(&node).cloned();
                    let Some(api) = api else { continue };
                    tokio::spawn(async move {
                        let _ = http::call(
                            &api,
                            "paramUpdate",
                            &[Value::str(MASTER_CALLER_ID), Value::str(key), value],
                            core.timeout,
                        )
                        .await;
                    });
                }
            }
        }
    }

    /// Sends `edge.subscriber` the publishers of `edge.topic`, after any
    /// update of the edge still in flight and with the list as it is when
    /// sent. A call that does not get through (a node too busy to answer in
    /// time, a refused connection) is sent again, up to [`UPDATE_ATTEMPTS`]
    /// times, while the node still subscribes: a lost update leaves a roscpp
    /// or simnode subscriber without a publisher for good.
    async fn publisher_update(self: Arc<Self>, edge: EdgeId) {
        let turn = lock(&self.updating)
            .entry(edge.clone())
            .or_default()
            .clone();
        let held = turn.lock().await;
        self.send_publisher_update(&edge).await;
        drop(held);
        // Forget the edge's lock unless another update holds or waits for it.
        let mut updating = lock(&self.updating);
        if Arc::strong_count(&turn) == 2 {
            updating.remove(&edge);
        }
    }

    async fn send_publisher_update(self: &Arc<Self>, edge: &EdgeId) {
        let mut backoff = Backoff::new(Duration::from_millis(250), Duration::from_secs(2));
        for attempt in 1..=UPDATE_ATTEMPTS {
            if self.closed.load(std::sync::atomic::Ordering::Relaxed) {
                return;
            }
            let api = {
                let st = lock(&self.state);
                let subscribes = st
                    .subscribers
                    .get(&edge.topic)
                    .is_some_and(|s| s.contains(&edge.subscriber));
                st.nodes
                    .get(&edge.subscriber)
                    .filter(|_| subscribes)
                    .cloned()
            };
            let Some(api) = api else { return };
            let list = self.publishers_for(&edge.topic, &edge.subscriber);
            let l = Value::Array(list.into_iter().map(Value::Str).collect());
            let params = [Value::str(MASTER_CALLER_ID), Value::str(&edge.topic), l];
            match http::call(&api, "publisherUpdate", &params, self.timeout).await {
                Err(e @ (http::HttpError::Io { .. } | http::HttpError::Timeout { .. })) => {
                    if attempt == UPDATE_ATTEMPTS {
                        tracing::warn!(
                            error = %e,
                            attempts = attempt,
                            topic = %edge.topic,
                            "publisherUpdate: giving up"
                        );
                        return;
                    }
                    tokio::time::sleep(backoff.next_delay()).await;
                }
                _ => return,
            }
        }
    }

    /// Sets (creating) the adaptor of `id`.
    pub fn set_adaptor(self: &Arc<Self>, id: &EdgeId, s: AdaptorSetting) {
        let existed = lock(&self.settings).insert(id.clone(), s).is_some();
        self.persist_adaptors();
        let relay = lock(&self.relays).get(id).cloned();
        if let Some(r) = relay {
            r.set(s);
        }
        if !existed {
            // Point the subscriber at the adaptor (roscpp drops the direct
            // connection; rospy only adds connections, so for rospy the
            // adaptor applies from the subscriber's next (re)subscription).
            self.run_effects(vec![Effect::PublisherUpdate {
                topic: id.topic.clone(),
                subscriber: id.subscriber.clone(),
            }]);
        }
    }

    /// Removes the adaptor of `id` and points the subscriber back at the
    /// real publishers; returns whether there was one.
    pub fn remove_adaptor(self: &Arc<Self>, id: &EdgeId) -> bool {
        let had = lock(&self.settings).remove(id).is_some();
        self.persist_adaptors();
        // Tell the subscriber first, then close the relay: the subscriber
        // connects to the publishers and sees EOF from the adaptor.
        self.run_effects(vec![Effect::PublisherUpdate {
            topic: id.topic.clone(),
            subscriber: id.subscriber.clone(),
        }]);
        let relay = lock(&self.relays).remove(id);
        if let Some(r) = relay {
            let (core, id, timeout) = (self.clone(), id.clone(), self.timeout);
            tokio::spawn(async move {
                tokio::time::sleep(timeout.min(Duration::from_millis(500))).await;
                r.close_downstream();
                // By then the edge may be adapted again, with a new relay
                // under the same key: only this one leaves.
                core.leave_tap(&id.topic, &relay_key(&id), &(r as Arc<dyn FrameSink>));
            });
        }
        had
    }

    /// Starts (if needed) measuring `topic`.
    pub fn meter(&self, topic: &str) -> Arc<Meter> {
        let (m, created) = get_or_make(&self.meters, &topic.to_string(), || {
            Meter::new(self.meter_window_s)
        });
        if created {
            self.tap(topic, TapReader::Meter).add(METER_KEY, m.reader());
        }
        m
    }
}

/// Who a tap is got for ([`Core::tap`]): a meter, whose tap's connections
/// run on the metering threads (it stamps each message as it is read), or
/// a relay, which copies messages for a non-core subscriber and whose tap
/// runs on the relaying threads unless a meter reads it too.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum TapReader {
    Meter,
    Relay,
}

/// A relay's key among its topic's tap's readers: its subscriber, as the
/// adaptor presents itself to ROS.
fn relay_key(id: &EdgeId) -> String {
    format!("{ADAPTOR_PREFIX}{}", id.subscriber)
}
