//! ROS 1 data plane for the ConfigBot agent: a ROS Master + Parameter Server
//! that persists to SQLite, a graph monitor (nodes, topics, edges, pids),
//! TCPROS topic meters and transparent per-subscriber rate adaptors, behind
//! [`configbot_dataplane::DataPlane`]. Entry point: [`Ros1DataPlane::start`].
//!
//! The data plane runs on threads of its own, not on its caller's runtime,
//! in two runtimes by job (each at most [`DATA_PLANE_THREADS`] threads):
//! `configbot-ros1` runs the master, the servers, the meters and the taps
//! they read; `configbot-relay` runs the taps that feed only relays and the
//! relays' writes to adapted subscribers. Each thread runs its job's hook
//! of [`Ros1Config::threads`] as it starts (the agent moves the first into
//! a cgroup at the largest weight beside the node cgroups, the second into
//! one at a node's weight): a meter stamps each message as it arrives, so
//! neither the caller's work nor a busy robot may hold a message back,
//! while copying a camera's images to a non-core subscriber waits its turn
//! like the nodes' own work. Measured on real-two-paths (2-core
//! VM, 2026-11-27, 240 s after tuning, with an independent rospy subscriber
//! of the core topic in a cgroup of its own): with the data plane on the
//! agent's runtime outside the robot's subtree, the meter read 4 windows at
//! 24.7–26.7 Hz, each followed by a burst, while the independent subscriber
//! never had fewer than 28 messages in any second; on threads of their own
//! in that cgroup, the meter's one low window (26 Hz) was the subscriber's.

pub mod adaptor;
mod core;
pub mod http;
pub mod limits;
mod master;
pub mod meter;
pub mod params;
pub mod state;
pub mod stats;
pub mod store;
pub mod tap;
pub mod tcpros;
pub mod upstream;
pub mod xmlrpc;

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use configbot_api::policy::{AppOf, PolicyConfig};
use configbot_dataplane::{
    AdaptorSetting, DataPlane, DataPlaneError, EdgeCounters, EdgeId, Graph, GraphEvent,
    MessageCount, NodeInfo, ThreadHooks, TopicInfo, TopicStats,
};
use tokio::sync::{Notify, broadcast};
use tokio::task::JoinHandle;

use crate::core::{Core, lock};
pub use crate::core::{MASTER_CALLER_ID, Placement};
use crate::state::{Effect, MasterState};
use crate::xmlrpc::Value;

/// Errors of starting the ROS 1 data plane.
#[derive(Debug, thiserror::Error)]
pub enum Ros1Error {
    #[error("bad master uri {0} (want http://host:port/)")]
    BadMasterUri(String),
    #[error("binding {what} on {addr}")]
    Bind {
        what: &'static str,
        addr: String,
        #[source]
        source: std::io::Error,
    },
    #[error("opening the ros1 database")]
    Store(#[from] store::StoreError),
    #[error("registering adaptor metrics")]
    Metrics(#[from] prometheus::Error),
    #[error("starting the data plane's threads")]
    Runtime(#[source] std::io::Error),
    #[error("the data plane's start was cancelled")]
    Cancelled,
}

/// Worker threads of each of the data plane's runtimes (at most the
/// machine's CPUs).
pub const DATA_PLANE_THREADS: usize = 2;

/// Where the master listens unless told otherwise: every interface, as
/// rosmaster does.
pub const DEFAULT_MASTER_BIND: &str = "0.0.0.0";

/// Where the adaptors listen unless told otherwise: loopback, where the
/// default advertised host (localhost) points.
pub const DEFAULT_ADAPTOR_BIND: &str = "127.0.0.1";

/// Configuration of [`Ros1DataPlane::start`].
#[derive(Clone)]
pub struct Ros1Config {
    /// The URI nodes use as ROS_MASTER_URI; its port is where the master listens.
    pub master_uri: String,
    /// Address the master binds to. rosmaster listens on every interface
    /// (nodes on other hosts reach it); the default does the same.
    pub bind_host: String,
    /// Address the adaptors' slave XML-RPC and TCPROS servers bind to. Only
    /// adapted subscribers connect there, at `advertise_host`; the default,
    /// loopback, fits the default `advertise_host` (localhost).
    pub adaptor_bind_host: String,
    /// Host name put in adaptor URIs (must resolve for the nodes).
    pub advertise_host: String,
    /// Ports of the adaptor's slave XML-RPC and TCPROS servers (0 = any).
    pub adaptor_xmlrpc_port: u16,
    pub adaptor_tcpros_port: u16,
    /// Period of the full graph refresh (pids, liveness).
    pub refresh_period: Duration,
    /// Timeout of calls to nodes.
    pub call_timeout: Duration,
    /// Window of topic meters.
    pub meter_window: Duration,
    /// Which edges get a pass-through adaptor when their subscriber
    /// registers; `None` = only edges set through `set_adaptor`.
    pub placement: Option<Placement>,
    /// Run by each of the data plane's threads as it starts, by its job
    /// (the agent moves them into cgroups of their own).
    pub threads: ThreadHooks,
}

impl std::fmt::Debug for Ros1Config {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Ros1Config")
            .field("master_uri", &self.master_uri)
            .field("bind_host", &self.bind_host)
            .field("adaptor_bind_host", &self.adaptor_bind_host)
            .field("refresh_period", &self.refresh_period)
            .field("placement", &self.placement.is_some())
            .field("threads", &self.threads)
            .finish_non_exhaustive()
    }
}

impl Default for Ros1Config {
    fn default() -> Self {
        Self {
            master_uri: "http://localhost:11311/".into(),
            bind_host: DEFAULT_MASTER_BIND.into(),
            adaptor_bind_host: DEFAULT_ADAPTOR_BIND.into(),
            advertise_host: "localhost".into(),
            adaptor_xmlrpc_port: 0,
            adaptor_tcpros_port: 0,
            refresh_period: Duration::from_secs(30),
            call_timeout: Duration::from_secs(3),
            meter_window: Duration::from_secs(10),
            placement: None,
            threads: ThreadHooks::default(),
        }
    }
}

/// Placement from the app mapping: an edge gets a pass-through adaptor at
/// subscribe time when its subscriber or a current publisher belongs to a
/// non-core app (or it is on the include list), unless excluded. The rate
/// rule of the policy is applied later, on measured rates, by the caller.
///
/// Adaptors are placed at subscribe time because rospy subscribers never
/// drop a publisher connection on publisherUpdate: an adaptor inserted into
/// a live rospy edge only takes over after the subscriber resubscribes.
pub fn placement_from_apps(apps: Arc<dyn AppOf + Send + Sync>, cfg: PolicyConfig) -> Placement {
    Arc::new(move |id: &EdgeId, pubs: &[String]| {
        if cfg.excluded(id) {
            return false;
        }
        if cfg.included(id) || apps.claims(id) {
            return true;
        }
        let non_core = |n: &str| apps.is_core(n) == Some(false);
        non_core(&id.subscriber) || pubs.iter().any(|p| non_core(p))
    })
}

/// The running ROS 1 data plane. Dropping it stops every server and task
/// and its threads.
#[derive(Debug)]
pub struct Ros1DataPlane {
    core: Arc<Core>,
    pids: Arc<Mutex<BTreeMap<(String, String), u32>>>,
    events: broadcast::Sender<GraphEvent>,
    tasks: Vec<JoinHandle<()>>,
    master_port: u16,
    /// The threads everything above runs on, by job (none only inside
    /// [`Ros1DataPlane::start`]); dropped last, after the tasks are aborted.
    rt: OwnRuntime,
    relay_rt: OwnRuntime,
}

/// The data plane's runtime, shut down without blocking when dropped: the
/// one dropping it may be another runtime's thread (the agent's), where a
/// blocking shutdown panics.
#[derive(Debug)]
struct OwnRuntime(Option<tokio::runtime::Runtime>);

impl OwnRuntime {
    /// Owns `rt`; its handle, to spawn on it.
    fn new(rt: tokio::runtime::Runtime) -> (Self, tokio::runtime::Handle) {
        let handle = rt.handle().clone();
        (Self(Some(rt)), handle)
    }
}

impl Drop for OwnRuntime {
    fn drop(&mut self) {
        if let Some(rt) = self.0.take() {
            rt.shutdown_background();
        }
    }
}

/// One of the data plane's runtimes: threads named `name`, each running
/// `hook` as it starts.
fn runtime(
    name: &str,
    hook: Option<configbot_dataplane::ThreadHook>,
) -> Result<tokio::runtime::Runtime, Ros1Error> {
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(DATA_PLANE_THREADS);
    let mut builder = tokio::runtime::Builder::new_multi_thread();
    builder
        .worker_threads(threads)
        .thread_name(name)
        .enable_all();
    if let Some(hook) = hook {
        builder.on_thread_start(move || hook());
    }
    builder.build().map_err(Ros1Error::Runtime)
}

impl Drop for Ros1DataPlane {
    fn drop(&mut self) {
        self.core
            .closed
            .store(true, std::sync::atomic::Ordering::Relaxed);
        for t in &self.tasks {
            t.abort();
        }
        if let Ok(mut r) = self.core.relays.lock() {
            r.clear();
        }
        if let Ok(mut m) = self.core.meters.lock() {
            m.clear();
        }
        if let Ok(mut t) = self.core.taps.lock() {
            t.clear();
        }
    }
}

impl Ros1DataPlane {
    /// Starts the data plane's threads, opens the database at `db_path`,
    /// restores and verifies the persisted graph, and starts the master,
    /// adaptor servers and graph monitor on those threads. Adaptor metrics
    /// go to `registry`. Runs from any tokio runtime.
    pub async fn start(
        config: Ros1Config,
        db_path: &Path,
        registry: &prometheus::Registry,
    ) -> Result<Self, Ros1Error> {
        // Owned at once: dropping a runtime (an error below, or this future
        // cancelled) must not block.
        let (metering, on_metering) =
            OwnRuntime::new(runtime("configbot-ros1", config.threads.metering.clone())?);
        let (relaying, on_relaying) =
            OwnRuntime::new(runtime("configbot-relay", config.threads.relaying.clone())?);
        let (db, registry) = (db_path.to_path_buf(), registry.clone());
        let started = on_metering
            .spawn(async move { Self::start_here(config, &db, &registry, on_relaying).await });
        let mut dp = started.await.map_err(|_| Ros1Error::Cancelled)??;
        dp.rt = metering;
        dp.relay_rt = relaying;
        Ok(dp)
    }

    /// [`Self::start`] on the runtime this runs on (the data plane's).
    async fn start_here(
        config: Ros1Config,
        db_path: &Path,
        registry: &prometheus::Registry,
        relaying: tokio::runtime::Handle,
    ) -> Result<Self, Ros1Error> {
        let (_, port, _) = http::parse_uri(&config.master_uri)
            .ok_or_else(|| Ros1Error::BadMasterUri(config.master_uri.clone()))?;
        let bind = |what, host: &String, port: u16| {
            let host = host.clone();
            async move {
                http::bind(&host, port)
                    .await
                    .map_err(|source| Ros1Error::Bind {
                        what,
                        addr: format!("{host}:{port}"),
                        source,
                    })
            }
        };
        let (master_l, master_addr) = bind("master", &config.bind_host, port).await?;
        let adaptor_host = &config.adaptor_bind_host;
        let (slave_l, slave_addr) =
            bind("adaptor xml-rpc", adaptor_host, config.adaptor_xmlrpc_port).await?;
        let (tcp_l, tcp_addr) =
            bind("adaptor tcpros", adaptor_host, config.adaptor_tcpros_port).await?;
        let store = store::Store::open(db_path)?;
        let state = store.load()?;
        let settings = store.load_adaptors()?;
        let metrics = adaptor::AdaptorMetrics::new(registry)?;
        let adaptor_uri = format!("http://{}:{}/", config.advertise_host, slave_addr.port());
        let core = Arc::new(Core {
            state: Mutex::new(MasterState::default()),
            store: Mutex::new(store),
            master_uri: config.master_uri.clone(),
            adaptor_uri,
            relays: Arc::new(Mutex::new(BTreeMap::new())),
            settings: Mutex::new(settings),
            placement: config
                .placement
                .clone()
                .unwrap_or_else(|| Arc::new(|_: &EdgeId, _: &[String]| false)),
            metrics,
            meters: Mutex::new(BTreeMap::new()),
            taps: Mutex::new(BTreeMap::new()),
            metering: tokio::runtime::Handle::current(),
            relaying: relaying.clone(),
            meter_window_s: config.meter_window.as_secs_f64(),
            wake: Notify::new(),
            timeout: config.call_timeout,
            updating: Mutex::new(BTreeMap::new()),
            closed: std::sync::atomic::AtomicBool::new(false),
        });
        let mut tasks = vec![
            tokio::spawn(http::serve(
                master_l,
                Arc::new(master::MasterHandler { core: core.clone() }),
            )),
            tokio::spawn(http::serve(
                slave_l,
                Arc::new(adaptor::SlaveHandler {
                    master_uri: config.master_uri.clone(),
                    host: config.advertise_host.clone(),
                    tcpros_port: tcp_addr.port(),
                }),
            )),
            tokio::spawn(adaptor::serve_tcpros(
                tcp_l,
                core.relays.clone(),
                config.call_timeout,
                relaying,
            )),
        ];
        let pids = Arc::new(Mutex::new(BTreeMap::new()));
        restore(&core, state, &pids).await;
        let (events, _) = broadcast::channel(1024);
        tasks.push(tokio::spawn(monitor(
            core.clone(),
            pids.clone(),
            events.clone(),
            config.refresh_period,
        )));
        Ok(Self {
            core,
            pids,
            events,
            tasks,
            master_port: master_addr.port(),
            rt: OwnRuntime(None),
            relay_rt: OwnRuntime(None),
        })
    }

    /// Enters the data plane's runtime, so that what a call spawns (taps,
    /// relays, calls to nodes) runs on the data plane's threads.
    fn enter(&self) -> Option<tokio::runtime::EnterGuard<'_>> {
        self.rt.0.as_ref().map(|rt| rt.enter())
    }

    /// The master URI nodes should use.
    pub fn master_uri(&self) -> &str {
        &self.core.master_uri
    }

    /// The port the master actually listens on.
    pub fn master_port(&self) -> u16 {
        self.master_port
    }

    /// The adaptor's slave URI (what adapted subscribers are given).
    pub fn adaptor_uri(&self) -> &str {
        &self.core.adaptor_uri
    }
}

/// Loads the persisted state, drops the nodes whose slave URI refuses
/// connections (they died while the agent was down; a stopped or busy node
/// that does not answer in time is kept), and points adapted subscribers at
/// the new adaptor endpoint.
async fn restore(
    core: &Arc<Core>,
    state: MasterState,
    pids: &Mutex<BTreeMap<(String, String), u32>>,
) {
    let nodes: Vec<(String, String)> = state
        .nodes
        .iter()
        .map(|(n, a)| (n.clone(), a.clone()))
        .collect();
    *lock(&core.state) = state;
    let answers = get_pids(&nodes, core.timeout).await;
    let mut fx = Vec::new();
    {
        let mut st = lock(&core.state);
        let mut p = lock(pids);
        for ((name, api), pid) in nodes.iter().zip(answers) {
            match pid {
                PidReply::Pid(pid) => {
                    p.insert((name.clone(), api.clone()), pid);
                }
                PidReply::Silent => {}
                PidReply::Gone => fx.extend(st.drop_node(name)),
            }
        }
    }
    core.persist();
    let adapted: Vec<EdgeId> = lock(&core.settings).keys().cloned().collect();
    {
        let st = lock(&core.state);
        for id in adapted {
            if st
                .subscribers
                .get(&id.topic)
                .is_some_and(|s| s.contains(&id.subscriber))
            {
                fx.push(Effect::PublisherUpdate {
                    topic: id.topic,
                    subscriber: id.subscriber,
                });
            }
        }
    }
    core.run_effects(fx);
}

/// What a node's slave API did with a getPid call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PidReply {
    Pid(u32),
    /// No answer in time, or not a pid: the process may be stopped
    /// (SIGSTOP by an app freeze: the kernel still accepts its
    /// connections) or busy. Kept, as rosmaster keeps every node.
    Silent,
    /// Nothing listens at its URI any more: the node is gone.
    Gone,
}

impl PidReply {
    fn pid(self) -> Option<u32> {
        match self {
            PidReply::Pid(p) => Some(p),
            PidReply::Silent | PidReply::Gone => None,
        }
    }
}

async fn get_pids(nodes: &[(String, String)], timeout: Duration) -> Vec<PidReply> {
    let handles: Vec<_> = nodes
        .iter()
        .map(|(_, api)| {
            let api = api.clone();
            tokio::spawn(async move {
                match http::call(&api, "getPid", &[Value::str(MASTER_CALLER_ID)], timeout).await {
                    Ok(v) => pid_of(&v).map_or(PidReply::Silent, PidReply::Pid),
                    Err(http::HttpError::Io { source, .. })
                        if source.kind() == std::io::ErrorKind::ConnectionRefused =>
                    {
                        PidReply::Gone
                    }
                    Err(http::HttpError::BadUri(_)) => PidReply::Gone,
                    Err(_) => PidReply::Silent,
                }
            })
        })
        .collect();
    let mut out = Vec::with_capacity(handles.len());
    for h in handles {
        out.push(h.await.unwrap_or(PidReply::Silent));
    }
    out
}

/// The pid in a getPid reply `[1, msg, pid]`.
fn pid_of(v: &Value) -> Option<u32> {
    let a = v.as_array()?;
    (a.first()?.as_i64()? == 1).then_some(())?;
    u32::try_from(a.get(2)?.as_i64()?).ok()
}

/// Builds the graph from master state and known pids. Pure.
pub fn build_graph(st: &MasterState, pids: &BTreeMap<(String, String), u32>) -> Graph {
    let mut g = Graph::default();
    for (name, uri) in &st.nodes {
        g.nodes.insert(
            name.clone(),
            NodeInfo {
                name: name.clone(),
                uri: uri.clone(),
                pid: pids.get(&(name.clone(), uri.clone())).copied(),
            },
        );
    }
    let topics: BTreeSet<&String> = st.publishers.keys().chain(st.subscribers.keys()).collect();
    for t in topics {
        g.topics.insert(
            t.clone(),
            TopicInfo {
                name: t.clone(),
                msg_type: st.type_of(t).to_string(),
                publishers: st.publishers.get(t).cloned().unwrap_or_default(),
                subscribers: st.subscribers.get(t).cloned().unwrap_or_default(),
            },
        );
    }
    g
}

async fn monitor(
    core: Arc<Core>,
    pids: Arc<Mutex<BTreeMap<(String, String), u32>>>,
    events: broadcast::Sender<GraphEvent>,
    period: Duration,
) {
    let mut last = Graph::default();
    let mut full = true;
    loop {
        let nodes: Vec<(String, String)> = lock(&core.state)
            .nodes
            .iter()
            .map(|(n, a)| (n.clone(), a.clone()))
            .collect();
        let todo: Vec<(String, String)> = {
            let p = lock(&pids);
            nodes
                .iter()
                .filter(|k| full || !p.contains_key(*k))
                .cloned()
                .collect()
        };
        let answers = get_pids(&todo, core.timeout).await;
        {
            let mut p = lock(&pids);
            for (k, reply) in todo.into_iter().zip(answers) {
                match reply.pid() {
                    Some(pid) => {
                        p.insert(k, pid);
                    }
                    None => {
                        p.remove(&k);
                    }
                }
            }
            p.retain(|k, _| nodes.contains(k));
        }
        let g = build_graph(&lock(&core.state), &lock(&pids));
        for e in last.diff(&g) {
            let _ = events.send(e);
        }
        last = g;
        full = tokio::select! {
            _ = tokio::time::sleep(period) => true,
            _ = core.wake.notified() => false,
        };
    }
}

impl DataPlane for Ros1DataPlane {
    fn graph(&self) -> Graph {
        build_graph(&lock(&self.core.state), &lock(&self.pids))
    }

    fn topic_stats(&self, topic: &str) -> Result<Option<TopicStats>, DataPlaneError> {
        let _on = self.enter();
        let known = {
            let st = lock(&self.core.state);
            st.publishers.contains_key(topic) || st.subscribers.contains_key(topic)
        };
        if !known {
            return Err(DataPlaneError::UnknownTopic(topic.into()));
        }
        Ok(self.core.meter(topic).stats())
    }

    fn topic_messages(&self, topic: &str) -> Result<MessageCount, DataPlaneError> {
        let _on = self.enter();
        let known = {
            let st = lock(&self.core.state);
            st.publishers.contains_key(topic) || st.subscribers.contains_key(topic)
        };
        if !known {
            return Err(DataPlaneError::UnknownTopic(topic.into()));
        }
        Ok(self.core.meter(topic).messages())
    }

    fn edge_stats(&self, edge: &EdgeId) -> Option<TopicStats> {
        let r = lock(&self.core.relays).get(edge).cloned()?;
        r.consumer_stats()
    }

    fn set_adaptor(&self, edge: &EdgeId, setting: AdaptorSetting) -> Result<(), DataPlaneError> {
        let _on = self.enter();
        if let Some(r) = setting.rate_hz
            && !(r.is_finite() && r > 0.0)
        {
            return Err(DataPlaneError::InvalidRate(r));
        }
        self.core.set_adaptor(edge, setting);
        Ok(())
    }

    fn remove_adaptor(&self, edge: &EdgeId) -> Result<(), DataPlaneError> {
        let _on = self.enter();
        if self.core.remove_adaptor(edge) {
            Ok(())
        } else {
            Err(DataPlaneError::UnknownEdge {
                topic: edge.topic.clone(),
                subscriber: edge.subscriber.clone(),
            })
        }
    }

    fn adaptors(&self) -> BTreeMap<EdgeId, AdaptorSetting> {
        lock(&self.core.settings).clone()
    }

    fn adaptor_counters(&self) -> BTreeMap<EdgeId, EdgeCounters> {
        let mut out: BTreeMap<EdgeId, EdgeCounters> = lock(&self.core.settings)
            .keys()
            .map(|k| (k.clone(), EdgeCounters::default()))
            .collect();
        for (k, r) in lock(&self.core.relays).iter() {
            out.insert(k.clone(), r.counters());
        }
        out
    }

    fn subscribe_events(&self) -> broadcast::Receiver<GraphEvent> {
        self.events.subscribe()
    }

    fn wake(&self) {
        self.core.wake.notify_one();
    }

    fn uri(&self) -> &str {
        self.master_uri()
    }

    fn node_env(&self) -> Vec<(String, String)> {
        vec![("ROS_MASTER_URI".to_owned(), self.master_uri().to_owned())]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn placement_follows_apps_and_lists() {
        use configbot_api::policy::EdgeSelector;
        let apps: Arc<dyn AppOf + Send + Sync> = Arc::new(|n: &str| match n {
            "/det" => Some(false),
            "/nav" | "/cam" => Some(true),
            _ => None,
        });
        let e = |t: &str, s: &str| EdgeId {
            topic: t.into(),
            subscriber: s.into(),
        };
        let cfg = PolicyConfig {
            include: vec![EdgeSelector::edge(&e("/odom", "/nav"))],
            exclude: vec![
                EdgeSelector::edge(&e("/img", "/det")),
                EdgeSelector::topic("/rosout"),
            ],
            ..PolicyConfig::default()
        };
        let place = placement_from_apps(apps, cfg);
        assert!(place(&e("/camera", "/det"), &["/cam".into()]));
        assert!(
            place(&e("/camera", "/nav"), &["/det".into()]),
            "non-core publisher"
        );
        assert!(!place(&e("/camera", "/nav"), &["/cam".into()]));
        assert!(place(&e("/odom", "/nav"), &[]), "include list");
        assert!(!place(&e("/img", "/det"), &["/cam".into()]), "exclude list");
        assert!(!place(&e("/rosout", "/det"), &[]), "excluded topic");
    }

    /// A core nodelet manager's input that a non-core app claims is adapted;
    /// its other inputs are not.
    #[test]
    fn placement_adapts_an_input_a_non_core_app_claims() {
        struct Claims;
        impl AppOf for Claims {
            fn is_core(&self, _: &str) -> Option<bool> {
                Some(true)
            }
            fn claims(&self, e: &EdgeId) -> bool {
                e.topic == "/cam/image_raw" && e.subscriber == "/vision"
            }
        }
        let place = placement_from_apps(Arc::new(Claims), PolicyConfig::default());
        let e = |t: &str| EdgeId {
            topic: t.into(),
            subscriber: "/vision".into(),
        };
        assert!(place(&e("/cam/image_raw"), &["/cam".into()]));
        assert!(!place(&e("/cam/image_mono"), &["/cam".into()]));
    }

    #[test]
    fn graph_from_state_has_types_edges_and_pids() {
        let mut st = MasterState::default();
        st.register_publisher("/cam", "http://c/", "/img", "sensor_msgs/Image");
        st.register_subscriber("/det", "http://d/", "/img", "sensor_msgs/Image");
        st.register_subscriber("/det", "http://d/", "/lonely", "std_msgs/String");
        let mut pids = BTreeMap::new();
        pids.insert(("/cam".to_string(), "http://c/".to_string()), 42);
        pids.insert(("/det".to_string(), "http://old/".to_string()), 7);
        let g = build_graph(&st, &pids);
        assert_eq!(g.nodes["/cam"].pid, Some(42));
        assert_eq!(
            g.nodes["/det"].pid, None,
            "pid of an older incarnation is not used"
        );
        assert_eq!(g.topics["/img"].msg_type, "sensor_msgs/Image");
        assert_eq!(g.edges().len(), 1);
        assert!(g.topics["/lonely"].publishers.is_empty());
    }
}
