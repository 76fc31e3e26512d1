//! The node's life: bind the slave API and TCPROS servers, register with
//! the master (retrying until it answers), run publisher threads and
//! callbacks, and on SIGINT/SIGTERM or a slave `shutdown` unregister and
//! stop.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use configbot_ros1::http;
use configbot_ros1::upstream::UpstreamSet;
use configbot_ros1::xmlrpc::Value;
use tokio::sync::Notify;

use crate::dispatch::{Callback, Dispatcher, PerMessage, Pool};
use crate::publish::{self, Publications, Topic};
use crate::slave::{InSink, Slave, Subscription, uris};
use crate::spec::{CallbackSpec, PublishSpec};
use crate::{SimnodeError, burn, msg};

/// Everything a node needs, resolved from the command line.
#[derive(Debug, Clone)]
pub struct NodeConfig {
    pub name: String,
    pub master_uri: String,
    /// Host put in this node's URIs.
    pub host: String,
    pub publish: Vec<PublishSpec>,
    pub cost_ms_per_msg: f64,
    pub callbacks: Vec<CallbackSpec>,
    /// `None` = thread-per-message.
    pub workers: Option<usize>,
    pub max_threads: usize,
    /// Thread-per-message: extra cost per other running message, in percent.
    pub contention_pct: f64,
    pub stats_every: Option<Duration>,
    pub call_timeout: Duration,
}

/// Sleeps until `until`, waking early when `stop` is set.
fn sleep_until(until: Instant, stop: &AtomicBool) {
    loop {
        let now = Instant::now();
        if now >= until || stop.load(Ordering::Relaxed) {
            return;
        }
        std::thread::sleep((until - now).min(Duration::from_millis(100)));
    }
}

/// A periodic publisher: work, publish, wait for the next tick; a tick
/// missed by more than a period is dropped (no catch-up burst), so a
/// CPU-starved publisher's rate falls, as a driver's would.
pub fn publisher_loop(spec: PublishSpec, topic: Arc<Topic>, cost: Duration, stop: Arc<AtomicBool>) {
    let period = Duration::from_secs_f64(1.0 / spec.hz);
    let mut next = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        burn::burn(cost, &stop);
        topic.publish(msg::encode(topic.next_seq(), msg::now_ns(), spec.bytes));
        next += period;
        let now = Instant::now();
        if now > next + period {
            next = now;
        }
        sleep_until(next, &stop);
    }
}

async fn register(
    cfg: &NodeConfig,
    api: &str,
    method: &str,
    topic: &str,
) -> Result<Vec<String>, http::HttpError> {
    let v = http::call(
        &cfg.master_uri,
        method,
        &[
            Value::str(&cfg.name),
            Value::str(topic),
            Value::str(msg::MSG_TYPE),
            Value::str(api),
        ],
        cfg.call_timeout,
    )
    .await?;
    Ok(uris(v.as_array().and_then(|a| a.get(2))))
}

fn stats_line(
    cfg: &NodeConfig,
    pubs: &Publications,
    d: &Dispatcher,
    last: &mut Vec<u64>,
    dt: f64,
) -> String {
    let mut now = Vec::new();
    let mut parts = Vec::new();
    for name in pubs.names() {
        let n = pubs.topic(name).map_or(0, |t| t.published());
        now.push(n);
        parts.push((format!("{name} out"), n));
    }
    for cb in d.callbacks() {
        let (r, x, k) = (
            cb.received.load(Ordering::Relaxed),
            cb.dropped.load(Ordering::Relaxed),
            cb.done.load(Ordering::Relaxed),
        );
        now.extend([r, x, k]);
        let e = format!("{}->{}", cb.spec.input, cb.spec.output);
        parts.push((format!("{e} in"), r));
        parts.push((format!("{e} dropped"), x));
        parts.push((format!("{e} done"), k));
    }
    let mut s = format!("simnode {}:", cfg.name);
    for (i, (label, n)) in parts.iter().enumerate() {
        let prev = last.get(i).copied().unwrap_or(0);
        s.push_str(&format!(" {label} {:.1}/s;", (n - prev) as f64 / dt));
    }
    s.push_str(&format!(" active threads {}", d.active()));
    *last = now;
    s
}

/// Runs the node until SIGINT/SIGTERM or a slave-API `shutdown`.
pub async fn run_node(cfg: NodeConfig) -> Result<(), SimnodeError> {
    let stop = Arc::new(AtomicBool::new(false));
    let bind = |what: &'static str| move |source| SimnodeError::Bind { what, source };
    let (tcp_listener, tcp_addr) = http::bind("0.0.0.0", 0)
        .await
        .map_err(bind("tcpros server"))?;
    let (rpc_listener, rpc_addr) = http::bind("0.0.0.0", 0).await.map_err(bind("slave api"))?;
    let api = format!("http://{}:{}/", cfg.host, rpc_addr.port());

    let mut out_topics: BTreeSet<String> = cfg.publish.iter().map(|p| p.topic.clone()).collect();
    out_topics.extend(cfg.callbacks.iter().map(|c| c.output.clone()));
    let pubs = Arc::new(Publications::new(&cfg.name, out_topics.clone()));

    let callbacks: Vec<Arc<Callback>> = cfg
        .callbacks
        .iter()
        .filter_map(|c| {
            pubs.topic(&c.output)
                .map(|t| Arc::new(Callback::new(c.clone(), t)))
        })
        .collect();
    let dispatcher = Arc::new(match cfg.workers {
        Some(n) => {
            Dispatcher::Pool(Pool::start(callbacks, n, stop.clone()).map_err(SimnodeError::Spawn)?)
        }
        None => Dispatcher::PerMessage(Arc::new(PerMessage::new(
            callbacks,
            cfg.max_threads,
            cfg.contention_pct,
            stop.clone(),
        ))),
    });

    let mut by_input: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    for (i, c) in cfg.callbacks.iter().enumerate() {
        by_input.entry(c.input.clone()).or_default().push(i);
    }
    let subs: BTreeMap<String, Subscription> = by_input
        .into_iter()
        .map(|(topic, idx)| {
            let sink = Arc::new(InSink::new(&topic, idx, dispatcher.clone(), pubs.clone()));
            let upstream = UpstreamSet::new(
                &cfg.name,
                &topic,
                sink.clone(),
                cfg.call_timeout,
                tokio::runtime::Handle::current(),
            );
            (topic, Subscription::new(sink, upstream))
        })
        .collect();
    let in_topics: Vec<String> = subs.keys().cloned().collect();

    let shutdown = Arc::new(Notify::new());
    let slave = Arc::new(Slave {
        master_uri: cfg.master_uri.clone(),
        host: cfg.host.clone(),
        tcpros_port: tcp_addr.port(),
        pubs: pubs.clone(),
        subs,
        shutdown: shutdown.clone(),
    });
    let rpc_task = tokio::spawn(http::serve(rpc_listener, slave.clone()));
    let tcp_task = tokio::spawn(publish::serve_tcpros(
        tcp_listener,
        pubs.clone(),
        cfg.call_timeout,
    ));

    let work = async {
        // Register (a real node waits for its master the same way).
        let mut pending: Vec<(&str, String)> = out_topics
            .iter()
            .map(|t| ("registerPublisher", t.clone()))
            .chain(in_topics.iter().map(|t| ("registerSubscriber", t.clone())))
            .collect();
        while !pending.is_empty() {
            let mut left = Vec::new();
            for (method, topic) in pending {
                let sub = slave
                    .subs
                    .get(&topic)
                    .filter(|_| method == "registerSubscriber");
                let seen = sub.map(Subscription::updates_seen);
                match register(&cfg, &api, method, &topic).await {
                    Ok(list) => {
                        if let (Some(s), Some(seen)) = (sub, seen) {
                            s.registered(seen, &list);
                        }
                    }
                    Err(_) => left.push((method, topic)),
                }
            }
            if !left.is_empty() {
                tokio::time::sleep(Duration::from_millis(500)).await;
            }
            pending = left;
        }
        for p in &cfg.publish {
            let (spec, stop) = (p.clone(), stop.clone());
            let cost = Duration::from_secs_f64(cfg.cost_ms_per_msg.max(0.0) / 1000.0);
            let Some(topic) = pubs.topic(&p.topic) else {
                continue;
            };
            std::thread::Builder::new()
                .name("simnode-pub".into())
                .spawn(move || publisher_loop(spec, topic, cost, stop))
                .map_err(SimnodeError::Spawn)?;
        }
        let Some(every) = cfg.stats_every else {
            return std::future::pending().await;
        };
        let mut last = Vec::new();
        let mut tick = tokio::time::interval(every);
        tick.tick().await;
        loop {
            tick.tick().await;
            eprintln!(
                "{}",
                stats_line(&cfg, &pubs, &dispatcher, &mut last, every.as_secs_f64())
            );
        }
    };
    let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
        .map_err(SimnodeError::Signal)?;
    let result = tokio::select! {
        r = work => r,
        _ = tokio::signal::ctrl_c() => Ok(()),
        _ = term.recv() => Ok(()),
        _ = shutdown.notified() => Ok(()),
    };

    // Stop work, then unregister everything (concurrently, bounded).
    stop.store(true, Ordering::Relaxed);
    dispatcher.shutdown();
    let mut calls = tokio::task::JoinSet::new();
    let in_set: BTreeSet<String> = in_topics.iter().cloned().collect();
    for (method, topics) in [
        ("unregisterPublisher", &out_topics),
        ("unregisterSubscriber", &in_set),
    ] {
        for t in topics {
            let (uri, name, api, t, timeout) = (
                cfg.master_uri.clone(),
                cfg.name.clone(),
                api.clone(),
                t.clone(),
                cfg.call_timeout.min(Duration::from_secs(2)),
            );
            calls.spawn(async move {
                let _ = http::call(
                    &uri,
                    method,
                    &[Value::Str(name), Value::Str(t), Value::Str(api)],
                    timeout,
                )
                .await;
            });
        }
    }
    while calls.join_next().await.is_some() {}
    rpc_task.abort();
    tcp_task.abort();
    drop(slave);
    result
}
