//! Transparent per-subscriber adaptors. The master hands an adapted
//! subscriber the adaptor's slave URI instead of the real publishers; the
//! adaptor (a slave XML-RPC endpoint + a TCPROS server shared by all edges)
//! relays frames from the real publishers (read through the topic's tap,
//! [`crate::tap`]) and forwards at most the configured rate to that one
//! subscriber. The rate limiter is a pure credit
//! accumulator, so any rate up to the input rate is reachable.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use configbot_dataplane::{AdaptorSetting, EdgeCounters, EdgeId, TopicStats};
use prometheus::{GaugeVec, IntCounterVec, Opts, Registry};
use tokio::net::TcpListener;
use tokio::sync::{mpsc, watch};

use crate::http::{BoxFut, Handler};
use crate::limits::TCPROS_HEADER_TIMEOUT;
use crate::stats::RateWindow;
use crate::tcpros::{self, Header};
use crate::upstream::{Frame, FrameSink};
use crate::xmlrpc::{MethodCall, Response, Value};

/// Name prefix of everything the adaptors show to ROS.
pub const ADAPTOR_PREFIX: &str = "/configbot/adaptor";

/// Credit accumulator: each message earns `rate * dt` credit, a message is
/// forwarded when credit ≥ 1. Burst is capped at [`Limiter::CAP`] messages.
#[derive(Debug, Clone, Default)]
pub struct Limiter {
    credit: f64,
    last: Option<f64>,
}

impl Limiter {
    pub const CAP: f64 = 2.0;

    /// Whether the message arriving at `t` (seconds) is forwarded.
    pub fn admit(&mut self, t: f64, rate: Option<f64>) -> bool {
        let dt = self.last.map_or(f64::INFINITY, |l| (t - l).max(0.0));
        self.last = Some(t);
        let Some(r) = rate else {
            self.credit = Self::CAP;
            return true;
        };
        self.credit = (self.credit + r * dt).min(Self::CAP);
        if self.credit >= 1.0 {
            self.credit -= 1.0;
            true
        } else {
            false
        }
    }
}

/// Prometheus metrics of all adaptors.
#[derive(Debug, Clone)]
pub struct AdaptorMetrics {
    forwarded: IntCounterVec,
    dropped: IntCounterVec,
    bytes: IntCounterVec,
    rate: GaugeVec,
}

impl AdaptorMetrics {
    /// Creates and registers the metrics in `registry`.
    pub fn new(registry: &Registry) -> Result<Self, prometheus::Error> {
        let labels = &["topic", "subscriber"];
        let forwarded = IntCounterVec::new(
            Opts::new(
                "configbot_adaptor_forwarded_total",
                "messages forwarded by an adaptor",
            ),
            labels,
        )?;
        let dropped = IntCounterVec::new(
            Opts::new(
                "configbot_adaptor_dropped_total",
                "messages dropped by an adaptor",
            ),
            labels,
        )?;
        let bytes = IntCounterVec::new(
            Opts::new(
                "configbot_adaptor_forwarded_bytes_total",
                "payload bytes forwarded by an adaptor",
            ),
            labels,
        )?;
        let rate = GaugeVec::new(
            Opts::new(
                "configbot_adaptor_rate_hz",
                "configured adaptor rate, -1 = pass-through",
            ),
            labels,
        )?;
        registry.register(Box::new(forwarded.clone()))?;
        registry.register(Box::new(dropped.clone()))?;
        registry.register(Box::new(bytes.clone()))?;
        registry.register(Box::new(rate.clone()))?;
        Ok(Self {
            forwarded,
            dropped,
            bytes,
            rate,
        })
    }
}

/// One adapted edge.
#[derive(Debug)]
pub struct EdgeRelay {
    pub id: EdgeId,
    setting: Mutex<AdaptorSetting>,
    limiter: Mutex<Limiter>,
    forwarded: AtomicU64,
    dropped: AtomicU64,
    bytes: AtomicU64,
    /// Last message of each latching publisher, by publisher API.
    latched: Mutex<BTreeMap<String, Frame>>,
    /// Reply header of each connected publisher.
    headers: Mutex<BTreeMap<String, Header>>,
    header: watch::Sender<Option<Header>>,
    downstream: Mutex<Vec<mpsc::Sender<Frame>>>,
    consumer: Mutex<RateWindow>,
    epoch: Instant,
    metrics: AdaptorMetrics,
}

impl EdgeRelay {
    pub fn new(id: EdgeId, setting: AdaptorSetting, metrics: AdaptorMetrics) -> Self {
        let r = Self {
            id,
            setting: Mutex::new(setting),
            limiter: Mutex::new(Limiter::default()),
            forwarded: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            bytes: AtomicU64::new(0),
            latched: Mutex::new(BTreeMap::new()),
            headers: Mutex::new(BTreeMap::new()),
            header: watch::channel(None).0,
            downstream: Mutex::new(Vec::new()),
            consumer: Mutex::new(RateWindow::new(10.0)),
            epoch: Instant::now(),
            metrics,
        };
        r.publish_setting(setting);
        r
    }

    fn labels(&self) -> [&str; 2] {
        [&self.id.topic, &self.id.subscriber]
    }

    fn publish_setting(&self, s: AdaptorSetting) {
        self.metrics
            .rate
            .with_label_values(&self.labels())
            .set(s.rate_hz.unwrap_or(-1.0));
    }

    /// Changes the rate; applies from the next message.
    pub fn set(&self, s: AdaptorSetting) {
        if let Ok(mut g) = self.setting.lock() {
            *g = s;
        }
        self.publish_setting(s);
    }

    pub fn setting(&self) -> AdaptorSetting {
        self.setting
            .lock()
            .map_or_else(|_| AdaptorSetting::default(), |g| *g)
    }

    pub fn counters(&self) -> EdgeCounters {
        EdgeCounters {
            forwarded: self.forwarded.load(Ordering::Relaxed),
            dropped: self.dropped.load(Ordering::Relaxed),
            bytes: self.bytes.load(Ordering::Relaxed),
        }
    }

    /// Rate of the forwarded stream (what the subscriber receives).
    pub fn consumer_stats(&self) -> Option<TopicStats> {
        let now = self.epoch.elapsed().as_secs_f64();
        self.consumer.lock().ok()?.stats(now)
    }

    /// Closes all downstream connections (the subscriber sees EOF).
    pub fn close_downstream(&self) {
        if let Ok(mut d) = self.downstream.lock() {
            d.clear();
        }
    }

    fn attach(&self, tx: mpsc::Sender<Frame>) {
        if let Ok(mut d) = self.downstream.lock() {
            d.retain(|s| !s.is_closed());
            d.push(tx);
        }
    }
}

impl FrameSink for EdgeRelay {
    fn on_header(&self, api: &str, header: &Header) {
        if let Ok(mut h) = self.headers.lock() {
            h.insert(api.to_string(), header.clone());
        }
        self.header.send_replace(Some(header.clone()));
    }

    fn on_gone(&self, api: &str) {
        if let Ok(mut h) = self.headers.lock() {
            h.remove(api);
        }
        if let Ok(mut l) = self.latched.lock() {
            l.remove(api);
        }
    }

    fn on_frame(&self, api: &str, frame: Frame) {
        let latching = self.headers.lock().is_ok_and(|h| {
            h.get(api)
                .is_some_and(|h| h.get("latching").is_some_and(|v| v == "1"))
        });
        if latching && let Ok(mut l) = self.latched.lock() {
            l.insert(api.to_string(), frame.clone());
        }
        let Ok(mut down) = self.downstream.lock() else {
            return;
        };
        down.retain(|s| !s.is_closed());
        if down.is_empty() {
            return;
        }
        let t = self.epoch.elapsed().as_secs_f64();
        let rate = self.setting().rate_hz;
        let pass = self
            .limiter
            .lock()
            .map(|mut l| l.admit(t, rate))
            .unwrap_or(true);
        let labels = self.labels();
        if !pass {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            self.metrics.dropped.with_label_values(&labels).inc();
            return;
        }
        let mut delivered = false;
        for s in down.iter() {
            delivered |= s.try_send(frame.clone()).is_ok();
        }
        if delivered {
            let n = frame.len() as u64;
            self.forwarded.fetch_add(1, Ordering::Relaxed);
            self.bytes.fetch_add(n, Ordering::Relaxed);
            self.metrics.forwarded.with_label_values(&labels).inc();
            self.metrics.bytes.with_label_values(&labels).inc_by(n);
            if let Ok(mut c) = self.consumer.lock() {
                c.record(t, frame.len());
            }
        } else {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            self.metrics.dropped.with_label_values(&labels).inc();
        }
    }
}

/// The relays of all adapted edges, shared by the servers below; each reads
/// its topic's tap.
pub type Relays = Arc<Mutex<BTreeMap<EdgeId, Arc<EdgeRelay>>>>;

/// Accepts subscriber connections on the adaptor's TCPROS port; each
/// connection's writes run on `rt` (the relaying threads).
pub async fn serve_tcpros(
    listener: TcpListener,
    relays: Relays,
    timeout: Duration,
    rt: tokio::runtime::Handle,
) {
    loop {
        let Ok((stream, addr)) = listener.accept().await else {
            tokio::time::sleep(Duration::from_millis(50)).await;
            continue;
        };
        let _ = stream.set_nodelay(true);
        // Registered with `rt`'s IO driver from here on, so the relaying
        // threads, not the accepting ones, wake for its writes.
        let Ok(stream) = stream.into_std() else {
            continue;
        };
        let relays = relays.clone();
        rt.spawn(async move {
            let Ok(mut stream) = tokio::net::TcpStream::from_std(stream) else {
                return;
            };
            let peer = addr.to_string();
            let read = tokio::time::timeout(
                TCPROS_HEADER_TIMEOUT,
                tcpros::read_header(&mut stream, &peer),
            );
            let h = match read.await {
                Ok(Ok(h)) => h,
                // A header over the limit or garbled: say why, as publishers do.
                Ok(Err(tcpros::TcprosError::Protocol { what, .. })) => {
                    let mut e = Header::new();
                    e.insert("error".into(), what);
                    let _ = tokio::io::AsyncWriteExt::write_all(
                        &mut stream,
                        &tcpros::encode_header(&e),
                    )
                    .await;
                    return;
                }
                // Gone, or too slow to send a header: drop the connection.
                _ => return,
            };
            let id = EdgeId {
                topic: h.get("topic").cloned().unwrap_or_default(),
                subscriber: h.get("callerid").cloned().unwrap_or_default(),
            };
            let edge = relays.lock().ok().and_then(|r| r.get(&id).cloned());
            let Some(edge) = edge else {
                let mut e = Header::new();
                e.insert(
                    "error".into(),
                    format!("no adaptor for {} on {}", id.subscriber, id.topic),
                );
                let _ =
                    tokio::io::AsyncWriteExt::write_all(&mut stream, &tcpros::encode_header(&e))
                        .await;
                return;
            };
            // Wait for an upstream publisher's header to answer with its type.
            let mut rx = edge.header.subscribe();
            let up: Option<Header> =
                match tokio::time::timeout(timeout, rx.wait_for(Option::is_some)).await {
                    Ok(Ok(r)) => r.clone(),
                    _ => None,
                };
            let Some(up) = up else { return };
            let mut reply = Header::new();
            for k in [
                "type",
                "md5sum",
                "message_definition",
                "latching",
                "callerid",
            ] {
                if let Some(v) = up.get(k) {
                    reply.insert(k.into(), v.clone());
                }
            }
            reply.insert("topic".into(), id.topic.clone());
            let any_latching = edge.headers.lock().is_ok_and(|h| {
                h.values()
                    .any(|h| h.get("latching").is_some_and(|v| v == "1"))
            });
            reply.insert(
                "latching".into(),
                if any_latching { "1" } else { "0" }.into(),
            );
            if let (Some(want), Some(have)) = (h.get("md5sum"), up.get("md5sum"))
                && want != "*"
                && have != "*"
                && want != have
            {
                let mut e = Header::new();
                e.insert(
                    "error".into(),
                    format!("md5sum mismatch on {}: {want} vs {have}", id.topic),
                );
                let _ =
                    tokio::io::AsyncWriteExt::write_all(&mut stream, &tcpros::encode_header(&e))
                        .await;
                return;
            }
            if tokio::io::AsyncWriteExt::write_all(&mut stream, &tcpros::encode_header(&reply))
                .await
                .is_err()
            {
                return;
            }
            // Attach first, then replay latched messages: a message arriving
            // in between may be seen twice, never lost.
            let (tx, mut rx) = mpsc::channel::<Frame>(16);
            edge.attach(tx);
            let latched: Vec<Frame> = edge
                .latched
                .lock()
                .map(|l| l.values().cloned().collect())
                .unwrap_or_default();
            drop(edge);
            for f in latched {
                if tcpros::write_frame(&mut stream, &f, &peer).await.is_err() {
                    return;
                }
            }
            while let Some(f) = rx.recv().await {
                if tcpros::write_frame(&mut stream, &f, &peer).await.is_err() {
                    break;
                }
            }
        });
    }
}

/// The adaptor's slave XML-RPC API: enough for subscribers to connect.
#[derive(Debug)]
pub struct SlaveHandler {
    pub master_uri: String,
    pub host: String,
    pub tcpros_port: u16,
}

impl Handler for SlaveHandler {
    fn handle(self: Arc<Self>, call: MethodCall) -> BoxFut<Response> {
        Box::pin(async move {
            let ok = |v| Response::Ok(Value::ros(1, "", v));
            match call.method.as_str() {
                "requestTopic" => {
                    let wants_tcpros =
                        call.params
                            .get(2)
                            .and_then(Value::as_array)
                            .is_some_and(|ps| {
                                ps.iter().any(|p| {
                                    p.as_array().and_then(|a| a.first()).and_then(Value::as_str)
                                        == Some("TCPROS")
                                })
                            });
                    if !wants_tcpros {
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
                "getPid" => ok(Value::Int(i64::from(std::process::id()))),
                "getMasterUri" => ok(Value::str(&self.master_uri)),
                "getBusInfo" | "getSubscriptions" | "getPublications" => ok(Value::Array(vec![])),
                "getBusStats" => ok(Value::Array(vec![
                    Value::Array(vec![]),
                    Value::Array(vec![]),
                    Value::Array(vec![]),
                ])),
                "shutdown" | "paramUpdate" | "publisherUpdate" => ok(Value::Int(0)),
                other => Response::Fault {
                    code: -32601,
                    message: format!("unknown method {other}"),
                },
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(input_hz: f64, rate: Option<f64>, secs: f64) -> f64 {
        let mut l = Limiter::default();
        let n = (input_hz * secs) as usize;
        let passed = (0..n)
            .filter(|i| l.admit(*i as f64 / input_hz, rate))
            .count();
        passed as f64 / secs
    }

    #[test]
    fn limiter_reaches_any_rate() {
        // 20 of 30 gives 20, not 15 as a minimum-interval throttle would
        assert!((run(30.0, Some(20.0), 100.0) - 20.0).abs() < 0.1);
        assert!((run(30.0, Some(5.0), 100.0) - 5.0).abs() < 0.1);
        assert!((run(30.0, Some(29.0), 100.0) - 29.0).abs() < 0.1);
        assert!((run(30.0, Some(50.0), 100.0) - 30.0).abs() < 0.1);
        assert!((run(30.0, None, 100.0) - 30.0).abs() < 0.1);
        assert!((run(1000.0, Some(333.0), 10.0) - 333.0).abs() < 1.0);
    }

    #[test]
    fn limiter_with_jittered_input_keeps_the_mean() {
        let mut l = Limiter::default();
        let mut t = 0.0;
        let mut passed = 0;
        for i in 0..3000 {
            // 30 Hz mean with ±40% alternating jitter
            t += (1.0 / 30.0) * if i % 2 == 0 { 0.6 } else { 1.4 };
            passed += usize::from(l.admit(t, Some(20.0)));
        }
        let rate = passed as f64 / t;
        assert!((rate - 20.0).abs() < 0.3, "{rate}");
    }

    #[test]
    fn metrics_register_in_a_private_registry() {
        let reg = Registry::new();
        let m = AdaptorMetrics::new(&reg).unwrap();
        let e = EdgeRelay::new(
            EdgeId {
                topic: "/t".into(),
                subscriber: "/s".into(),
            },
            AdaptorSetting { rate_hz: Some(3.0) },
            m,
        );
        e.set(AdaptorSetting { rate_hz: None });
        let names: Vec<String> = reg.gather().iter().map(|f| f.name().to_string()).collect();
        assert!(
            names.contains(&"configbot_adaptor_rate_hz".to_string()),
            "{names:?}"
        );
        assert!(
            AdaptorMetrics::new(&reg).is_err(),
            "double registration is refused"
        );
    }
}
