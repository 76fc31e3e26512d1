//! The node runtime: one daemon that owns the robot. [`NodeRuntime`] joins
//! the [`Agent`] (per-node cgroups, run/match processes), the process monitor
//! (`configbot-procmon`: eBPF → proc connector → /proc scan) and a data plane
//! (a `dyn DataPlane` started by name from [`backends`]; ROS 1's
//! `configbot-ros1` makes the agent the ROS master). Glue only:
//!
//! - every process event goes to [`Agent::process_event`] (immediate `match`
//!   adoption), wakes the ROS graph monitor and becomes a [`RuntimeEvent`];
//! - ROS adoption: a `run` node (by its name) or a `match: {rosNode}` node
//!   whose ROS name has a pid in the graph (slave API `getPid`) has that pid
//!   moved into its cgroup, on every graph change and every second;
//! - adaptor placement follows the stack's core/non-core apps, updated by
//!   [`NodeRuntime::set_stack`];
//! - `apply` (module `apply`) and `measure` (module `measure`);
//! - rosbag recordings on request (module [`record`]).
//!
//! The controller drives it through [`NodeApi`], which
//! [`crate::client::AgentClient`] implements over HTTP.

mod apply;
pub mod backends;
mod measure;
pub mod record;

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard, RwLock};
use std::time::Duration;

use configbot_api::graph::{EdgeId, Graph, GraphEvent};
use configbot_api::measure::{MeasureReport, MeasureRequest};
use configbot_api::policy::AppOf;
use configbot_cgroups::{AgentThreads, CgroupBackend};
use configbot_dataplane::{DataPlane, ThreadHook, ThreadHooks};
use configbot_manifests::{ResourceConfig, RobotStack};
use configbot_procmon::{MonitorConfig, MonitorHandle, Preference, ProcessMonitor};
use prometheus::{GaugeVec, Opts, Registry, TextEncoder};
use tokio::sync::broadcast;
use tokio::task::JoinHandle;

pub use self::apply::{Plan, plan};
pub use self::backends::{DEFAULT_BACKEND, DataPlaneOptions};
pub use self::measure::{Reading, boundaries, series};
use crate::agent::stack::StackDiff;
use crate::agent::{Agent, NodeStatus};
use crate::contract::{BoxFuture, NodeApi};
use crate::error::{Error, Result};
use crate::events::{AgentEvent, ProcEvent, ProcEventKind, RuntimeEvent};
use crate::spec::{AgentSettings, NodeSource, StackSpec};

/// Shortest gap between two graph wake-ups caused by process events.
pub const WAKE_GAP: Duration = Duration::from_millis(50);

/// Everything [`NodeRuntime::start`] needs besides the cgroup backend.
#[derive(Debug, Clone)]
pub struct RuntimeOptions {
    pub settings: AgentSettings,
    /// `None`: no data plane (`--no-ros`).
    pub data_plane: Option<DataPlaneOptions>,
    /// `None`: no process monitor; `match` nodes are found by the agent's scan.
    pub monitor: Option<Preference>,
}

/// The node runtime handle; cheap to clone.
#[derive(Debug, Clone)]
pub struct NodeRuntime {
    inner: Arc<Inner>,
}

struct Inner {
    agent: Agent,
    dp: Option<Arc<dyn DataPlane>>,
    /// The stack's apps as the adaptor placement reads them.
    apps: Arc<RwLock<AppMap>>,
    events: broadcast::Sender<RuntimeEvent>,
    monitor: Mutex<Option<MonitorHandle>>,
    monitor_status: String,
    tasks: Mutex<Vec<JoinHandle<()>>>,
    /// Process events ask for a graph refresh here; one task passes them on
    /// to the data plane at most every [`WAKE_GAP`].
    wake: tokio::sync::Notify,
    /// Serializes set_stack and apply.
    ops: tokio::sync::Mutex<()>,
    /// Topics whose meters this runtime started.
    metered: Mutex<BTreeSet<String>>,
    registry: Registry,
    topic_rate: GaugeVec,
    recordings: record::Recordings,
}

impl std::fmt::Debug for Inner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NodeRuntime")
            .field("agent", &self.agent)
            .field("data_plane", &self.dp.as_ref().map(|d| d.uri().to_owned()))
            .field("monitor", &self.monitor_status)
            .finish_non_exhaustive()
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Milliseconds since the Unix epoch.
pub(crate) fn unix_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_millis()).unwrap_or(u64::MAX))
}

/// What the adaptor placement needs of the stack: the core flag of every
/// node tied to a ROS name, and the inputs non-core apps claim.
#[derive(Debug, Default)]
struct AppMap {
    core: BTreeMap<String, bool>,
    claimed: std::collections::BTreeSet<EdgeId>,
}

impl AppOf for AppMap {
    fn is_core(&self, node: &str) -> Option<bool> {
        self.core.get(node).copied()
    }
    fn claims(&self, edge: &EdgeId) -> bool {
        self.claimed.contains(edge)
    }
}

/// The placement's live view of [`AppMap`], replaced on `set_stack_spec`.
struct LiveApps(Arc<RwLock<AppMap>>);

impl AppOf for LiveApps {
    fn is_core(&self, node: &str) -> Option<bool> {
        self.0
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .is_core(node)
    }
    fn claims(&self, edge: &EdgeId) -> bool {
        self.0
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .claims(edge)
    }
}

/// [`AppMap`] of `stack`.
fn app_map(stack: &StackSpec) -> AppMap {
    let mut m = AppMap::default();
    for (_, n) in stack.nodes() {
        m.core.insert(n.name.as_str().to_owned(), n.core);
        if let NodeSource::Match(mm) = &n.source
            && let Some(r) = &mm.ros_node
        {
            m.core.insert(r.clone(), n.core);
        }
    }
    m.claimed = stack
        .apps
        .iter()
        .flat_map(|a| a.inputs.iter().cloned())
        .collect();
    m
}

/// `run` nodes get the data plane's environment (ROS 1: `ROS_MASTER_URI`
/// of the agent's master) unless they set it.
fn with_node_env(mut stack: StackSpec, env: &[(String, String)]) -> StackSpec {
    for app in &mut stack.apps {
        for n in &mut app.nodes {
            if let NodeSource::Run(r) = &mut n.source {
                for (k, v) in env {
                    r.env.entry(k.clone()).or_insert_with(|| v.clone());
                }
            }
        }
    }
    stack
}

/// The environment of [`with_node_env`]: none without a data plane.
fn node_env(dp: Option<&dyn DataPlane>) -> Vec<(String, String)> {
    dp.map(DataPlane::node_env).unwrap_or_default()
}

/// What each data-plane thread runs as it starts, by its job: it moves
/// into the agent's cgroup for that job (the meters' at the largest weight,
/// the relays' at a node's; see `configbot_cgroups::threads`). A job's hook
/// is `None` where threads cannot have a cgroup of their own (v2) or it
/// cannot be made: its threads then stay in the agent's cgroup.
fn data_plane_threads(backend: &dyn CgroupBackend) -> ThreadHooks {
    let hook = |group: AgentThreads| -> Option<ThreadHook> {
        match backend.agent_threads(group) {
            Ok(Some(place)) => Some(Arc::new(move || {
                if let Err(e) = place.place_current_thread() {
                    tracing::warn!(error = %e, ?group, "a data-plane thread stays in the agent's cgroup");
                }
            })),
            Ok(None) => None,
            Err(e) => {
                tracing::warn!(error = %e, ?group, "no cgroup for the data plane's threads");
                None
            }
        }
    };
    ThreadHooks {
        metering: hook(AgentThreads::Metering),
        relaying: hook(AgentThreads::Relaying),
    }
}

impl NodeRuntime {
    /// Starts the data plane (so the master is up before nodes start), then
    /// the agent for `stack`, then the process monitor and the glue tasks.
    pub async fn start(
        backend: Box<dyn CgroupBackend>,
        opts: RuntimeOptions,
        stack: StackSpec,
    ) -> Result<Self> {
        let registry = Registry::new();
        let apps = Arc::new(RwLock::new(app_map(&stack)));
        let dp = match &opts.data_plane {
            None => None,
            Some(o) => {
                let apps = Arc::new(LiveApps(apps.clone()));
                let hook = data_plane_threads(backend.as_ref());
                Some(backends::start(o, apps, &registry, hook).await?)
            }
        };
        let stack = with_node_env(stack, &node_env(dp.as_deref()));
        let agent = Agent::start(backend, opts.settings, stack).await?;
        let (monitor, stream) = match opts.monitor {
            None => (None, None),
            Some(pref) => {
                let (h, s) = ProcessMonitor::start(MonitorConfig::with_preference(pref))
                    .await
                    .map_err(Error::Monitor)?;
                agent.set_active_monitor(h.label());
                (Some(h), Some(s))
            }
        };
        let rt = Self::assemble(agent, dp, apps, registry, monitor)?;
        rt.inner
            .recordings
            .stop_orphans(std::path::Path::new("/proc"))
            .await;
        if let Some(mut s) = stream {
            let me = rt.clone();
            rt.spawn(async move {
                while let Some(ev) = s.recv().await {
                    me.on_process_event(&ev);
                }
            });
        }
        if let Some(dp) = rt.inner.dp.clone() {
            let me = rt.clone();
            let d = dp.clone();
            rt.spawn(async move { me.graph_loop(d).await });
            let me = rt.clone();
            rt.spawn(async move {
                loop {
                    me.inner.wake.notified().await;
                    dp.wake();
                    tokio::time::sleep(WAKE_GAP).await;
                }
            });
        }
        Ok(rt)
    }

    /// A runtime around an already started agent, without ROS and without a
    /// process monitor (tests, `--no-ros`-style embedding).
    pub fn with_agent(agent: Agent) -> Result<Self> {
        let apps = Arc::new(RwLock::new(app_map(&agent.stack())));
        Self::assemble(agent, None, apps, Registry::new(), None)
    }

    fn assemble(
        agent: Agent,
        dp: Option<Arc<dyn DataPlane>>,
        apps: Arc<RwLock<AppMap>>,
        registry: Registry,
        monitor: Option<MonitorHandle>,
    ) -> Result<Self> {
        let topic_rate = GaugeVec::new(
            Opts::new(
                "configbot_agent_topic_rate_hz",
                "Mean rate of a topic (subscriber: delivered to that node) over the last measure window",
            ),
            &["topic", "subscriber"],
        )
        .map_err(Error::Metrics)?;
        registry
            .register(Box::new(topic_rate.clone()))
            .map_err(Error::Metrics)?;
        let monitor_status = monitor
            .as_ref()
            .map_or_else(|| "none".to_owned(), |m| m.status().summary());
        let (events, _) = broadcast::channel(4096);
        // Bags live beside the agent's state.
        let bags = agent
            .settings()
            .state_file
            .parent()
            .map_or_else(|| PathBuf::from("bags"), |d| d.join("bags"));
        let agent_recording_max_mb = agent.settings().recording_max_mb;
        let rt = Self {
            inner: Arc::new(Inner {
                agent,
                dp,
                apps,
                events,
                monitor: Mutex::new(monitor),
                monitor_status,
                tasks: Mutex::new(Vec::new()),
                wake: tokio::sync::Notify::new(),
                ops: tokio::sync::Mutex::new(()),
                metered: Mutex::new(BTreeSet::new()),
                registry,
                topic_rate,
                recordings: record::Recordings::new(bags, agent_recording_max_mb),
            }),
        };
        let mut rx = rt.inner.agent.subscribe();
        let me = rt.clone();
        rt.spawn(async move {
            loop {
                match rx.recv().await {
                    // The runtime emits its own, richer exec events.
                    Ok(AgentEvent::ProcessExec { .. }) => {}
                    Ok(ev) => me.emit(RuntimeEvent::Agent(ev)),
                    Err(broadcast::error::RecvError::Lagged(n)) => {
                        me.emit(RuntimeEvent::Lagged { missed: n });
                    }
                    Err(broadcast::error::RecvError::Closed) => return,
                }
            }
        });
        Ok(rt)
    }

    fn spawn(&self, f: impl std::future::Future<Output = ()> + Send + 'static) {
        lock(&self.inner.tasks).push(tokio::spawn(f));
    }

    fn emit(&self, ev: RuntimeEvent) {
        let _ = self.inner.events.send(ev);
    }

    /// The agent core.
    pub fn agent(&self) -> &Agent {
        &self.inner.agent
    }

    /// The data plane, when enabled.
    pub fn data_plane(&self) -> Option<Arc<dyn DataPlane>> {
        self.inner.dp.clone()
    }

    /// The data plane's URI (ROS 1: the master URI nodes should use), when
    /// enabled.
    pub fn master_uri(&self) -> Option<String> {
        self.inner.dp.as_ref().map(|d| d.uri().to_owned())
    }

    /// The process monitor in use and why better ones failed.
    pub fn monitor_status(&self) -> &str {
        &self.inner.monitor_status
    }

    fn on_process_event(&self, ev: &configbot_procmon::ProcEvent) {
        use configbot_procmon::ProcEventKind as K;
        let kind = match ev.kind {
            K::Exec => ProcEventKind::Exec,
            K::Exit => ProcEventKind::Exit,
        };
        self.inner.agent.process_event(&ProcEvent {
            kind,
            pid: ev.pid,
            ppid: ev.ppid,
            comm: ev.comm.clone(),
        });
        // Every exec/exit wakes the graph monitor (coalesced: a busy host
        // execs hundreds of processes a second).
        self.inner.wake.notify_one();
        let seen = unix_ms();
        self.emit(match kind {
            ProcEventKind::Exec => {
                let age_ms = configbot_procmon::monotonic_now_ns().saturating_sub(ev.timestamp_ns)
                    / 1_000_000;
                RuntimeEvent::ProcessExec {
                    pid: ev.pid,
                    ppid: ev.ppid,
                    comm: ev.comm.clone(),
                    filename: ev.filename.clone(),
                    at_unix_ms: seen.saturating_sub(age_ms),
                    seen_unix_ms: seen,
                }
            }
            ProcEventKind::Exit => RuntimeEvent::ProcessExit {
                pid: ev.pid,
                exit_code: ev.exit_code,
            },
        });
    }

    /// Graph changes become events and trigger ROS adoption; a 1 s tick
    /// catches pids that appeared without a change event reaching us.
    async fn graph_loop(&self, dp: Arc<dyn DataPlane>) {
        let mut rx = dp.subscribe_events();
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        loop {
            tokio::select! {
                r = rx.recv() => match r {
                    Ok(first) => {
                        let mut events: Vec<GraphEvent> = vec![first];
                        while let Ok(more) = rx.try_recv() {
                            events.push(more);
                        }
                        self.emit(RuntimeEvent::GraphChanged { events });
                    }
                    Err(broadcast::error::RecvError::Lagged(_)) => {}
                    Err(broadcast::error::RecvError::Closed) => return,
                },
                _ = tick.tick() => {}
            }
            self.adopt_ros_nodes();
        }
    }

    /// Moves each ROS-named node's graph pid into its cgroup when it is not
    /// in a node cgroup yet (a process in another node's cgroup is never
    /// stolen).
    pub fn adopt_ros_nodes(&self) {
        let Some(dp) = &self.inner.dp else {
            return;
        };
        let names = self.inner.agent.ros_names();
        if names.is_empty() {
            return;
        }
        let graph = dp.graph();
        let inventory = self.inner.agent.inventory();
        let owner = |pid: u32| inventory.iter().find(|n| n.pids.contains(&pid));
        for (node, ros) in names {
            let Some(pid) = graph.nodes.get(&ros).and_then(|n| n.pid) else {
                continue;
            };
            if owner(pid).is_none() {
                let _ = self.inner.agent.adopt(&node, pid);
            }
        }
    }

    fn mark_metered(&self, topic: &str) -> bool {
        lock(&self.inner.metered).insert(topic.to_owned())
    }

    fn metrics_topic_rate(&self, topic: &str, subscriber: Option<&str>, hz: f64) {
        self.inner
            .topic_rate
            .with_label_values(&[topic, subscriber.unwrap_or("")])
            .set(hz);
    }

    /// Prometheus text: the agent's metrics, then the runtime's (topic
    /// rates, ROS adaptors).
    pub fn render_metrics(&self) -> Result<String> {
        let mut text = self
            .inner
            .agent
            .metrics()
            .render()
            .map_err(Error::Metrics)?;
        let more = TextEncoder::new()
            .encode_to_string(&self.inner.registry.gather())
            .map_err(Error::Metrics)?;
        text.push_str(&more);
        Ok(text)
    }

    /// Replaces the stack at run time: new nodes get cgroups and start,
    /// removed nodes stop and lose their cgroup, changed nodes restart, and
    /// the adaptor placement's app map follows.
    pub async fn set_stack_spec(&self, stack: StackSpec) -> Result<StackDiff> {
        let _serial = self.inner.ops.lock().await;
        let stack = with_node_env(stack, &node_env(self.inner.dp.as_deref()));
        let map = app_map(&stack);
        let diff = self.inner.agent.set_stack(stack).await?;
        *self
            .inner
            .apps
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = map;
        self.adopt_ros_nodes();
        Ok(diff)
    }

    /// The node inventory.
    pub async fn inventory(&self) -> Result<Vec<NodeStatus>> {
        Ok(self.inner.agent.inventory())
    }

    /// Runtime events from now on.
    pub fn events(&self) -> broadcast::Receiver<RuntimeEvent> {
        self.inner.events.subscribe()
    }

    /// Stops the recordings, the glue tasks and the process monitor, then
    /// shuts the agent down (nodes keep running). The data plane stops when the last
    /// handle is dropped.
    pub async fn shutdown(&self) {
        self.inner.recordings.stop_all().await;
        self.detach();
        self.inner.agent.shutdown().await;
    }

    /// Aborts every background task of the runtime and the agent and stops
    /// the process monitor, without touching processes (usable from `Drop`).
    pub fn detach(&self) {
        for t in lock(&self.inner.tasks).drain(..) {
            t.abort();
        }
        lock(&self.inner.monitor).take();
        self.inner.agent.detach();
    }
}

/// The controller's operations; `apply` and `measure` live in their modules.
impl NodeApi for NodeRuntime {
    type Error = Error;

    fn apply<'a>(&'a self, cfg: &'a ResourceConfig) -> BoxFuture<'a, Result<()>> {
        Box::pin(self.apply_config(cfg))
    }

    fn measure<'a>(&'a self, req: &'a MeasureRequest) -> BoxFuture<'a, Result<MeasureReport>> {
        Box::pin(self.measure_window(req))
    }

    fn graph(&self) -> BoxFuture<'_, Result<Graph>> {
        let graph = self.inner.dp.as_ref().map(|d| d.graph());
        Box::pin(async move { Ok(graph.unwrap_or_default()) })
    }

    fn stop_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<()>> {
        Box::pin(self.inner.agent.stop_app(app))
    }

    fn start_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<()>> {
        Box::pin(async move {
            self.inner.agent.start_app(app)?;
            self.adopt_ros_nodes();
            Ok(())
        })
    }

    /// See [`Agent::freeze_app`].
    fn freeze_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<()>> {
        Box::pin(async move { self.inner.agent.freeze_app(app) })
    }

    fn thaw_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<()>> {
        Box::pin(async move { self.inner.agent.thaw_app(app) })
    }

    /// See [`record`]: `None` when rosbag is not installed or there is
    /// nothing to record.
    fn start_recording<'a>(
        &'a self,
        name: &'a str,
        topics: &'a [String],
    ) -> BoxFuture<'a, Result<Option<PathBuf>>> {
        Box::pin(async move {
            let master = self.master_uri().ok_or_else(|| Error::NoDataPlane {
                what: "a rosbag recording".into(),
            })?;
            let started = self.inner.recordings.start(name, topics, &master).await?;
            if let Some((p, true)) = &started {
                self.emit(RuntimeEvent::Agent(AgentEvent::RecordingStarted {
                    name: name.to_owned(),
                    path: p.clone(),
                    topics: topics.to_vec(),
                }));
            }
            Ok(started.map(|(p, _)| p))
        })
    }

    fn stop_recording<'a>(&'a self, name: &'a str) -> BoxFuture<'a, Result<Option<PathBuf>>> {
        Box::pin(async move {
            let path = self.inner.recordings.stop(name).await;
            if let Some(p) = &path {
                self.emit(RuntimeEvent::Agent(AgentEvent::RecordingStopped {
                    name: name.to_owned(),
                    path: p.clone(),
                }));
            }
            Ok(path)
        })
    }

    /// See [`NodeRuntime::set_stack_spec`].
    fn set_stack<'a>(&'a self, stack: Option<&'a RobotStack>) -> BoxFuture<'a, Result<()>> {
        Box::pin(async move {
            let spec = match stack {
                Some(s) => StackSpec::from_manifest(s)?,
                None => StackSpec::default(),
            };
            self.set_stack_spec(spec).await.map(|_| ())
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn app_map_and_master_uri_injection() {
        let s: StackSpec = serde_json::from_str(
            r#"{"apps":[{"name":"a","nodes":[
                {"name":"/t","core":true,"run":{"command":"/bin/true"}},
                {"name":"/u","run":{"command":"/bin/true","env":{"ROS_MASTER_URI":"http://x:1/"}}},
                {"name":"/l","match":{"rosNode":"/listener"}}]}]}"#,
        )
        .unwrap();
        let m = app_map(&s);
        assert_eq!(m.is_core("/t"), Some(true));
        assert_eq!(m.is_core("/listener"), Some(false));
        assert!(m.claimed.is_empty());
        let uri = (
            "ROS_MASTER_URI".to_owned(),
            "http://localhost:5/".to_owned(),
        );
        let s = with_node_env(s, &[uri]);
        let env = |i: usize| match &s.apps[0].nodes[i].source {
            NodeSource::Run(r) => r.env.get("ROS_MASTER_URI").cloned(),
            NodeSource::Match(_) => None,
        };
        assert_eq!(env(0).as_deref(), Some("http://localhost:5/"));
        assert_eq!(env(1).as_deref(), Some("http://x:1/"), "explicit uri kept");
    }
}
