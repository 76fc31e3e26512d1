//! The agent core: owns the node table, applies configs, adopts processes,
//! starts/stops apps and samples cgroup stats. HTTP and the binary sit on top.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use configbot_api::backoff::Backoff;
use configbot_cgroups::{
    CgroupBackend, CgroupConfig, CpuLimit, CpuMax, CpuStats, CpuWeight, NodeName,
};
use configbot_manifests::AdaptorRate;
use serde::{Deserialize, Serialize};
use tokio::sync::{broadcast, watch};
use tokio::task::JoinHandle;

use crate::error::{Error, Result};
use crate::events::{AgentEvent, ProcEvent, ProcEventKind};
use crate::metrics::Metrics;
use crate::procfs::{Matcher, ProcInfo, is_alive, list_procs, read_proc, with_descendants};
use crate::spec::{AgentSettings, NodeSource, NodeSpec, StackSpec};
use crate::state::{self, CommittedConfig, PersistedNode, PersistedState, StartupLimits};
use crate::supervise;
use process::{RunNode, send_signal};

pub(crate) mod process;
pub mod stack;

/// The agent handle; cheap to clone, shared by the API and supervisors.
#[derive(Debug, Clone)]
pub struct Agent {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    backend: Box<dyn CgroupBackend>,
    settings: AgentSettings,
    proc_root: PathBuf,
    state: Mutex<State>,
    events: broadcast::Sender<AgentEvent>,
    metrics: Metrics,
    background: Mutex<Option<JoinHandle<()>>>,
    parked: Mutex<Vec<watch::Sender<bool>>>,
}

#[derive(Debug, Default)]
struct State {
    nodes: BTreeMap<NodeName, NodeRt>,
    stack: StackSpec,
    committed: Option<CommittedConfig>,
    active_monitor: String,
}

#[derive(Debug)]
struct NodeRt {
    app: String,
    spec: NodeSpec,
    matcher: Option<Matcher>,
    persisted: PersistedNode,
    supervisor: Option<(watch::Sender<bool>, JoinHandle<()>)>,
    sample: Option<(u64, Instant)>,
    usage_cpus: f64,
    stats: CpuStats,
    limit: Option<CpuMax>,
    weight: Option<CpuWeight>,
}

/// A config put by the controller: CPU limits, and the adaptor rates per
/// (topic, subscriber) edge that the runtime hands to the data plane (the
/// agent core records and persists them).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct ConfigUpdate {
    pub limits: BTreeMap<NodeName, CpuLimit>,
    #[serde(default)]
    pub adaptor_rates: Vec<AdaptorRate>,
}

/// One node in the inventory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct NodeStatus {
    pub name: NodeName,
    pub app: String,
    /// `run` or `match`.
    pub kind: String,
    pub core: bool,
    pub pids: Vec<u32>,
    pub main_pid: Option<u32>,
    pub cgroup: PathBuf,
    pub cpu_usage_cpus: f64,
    pub cpu_limit: Option<CpuMax>,
    /// CPU weight against the stack's other nodes (100: the default).
    #[serde(default)]
    pub cpu_weight: Option<CpuWeight>,
    pub stats: CpuStats,
    pub restarts: u32,
    pub stopped: bool,
    /// Frozen (SIGSTOP) by an app freeze.
    #[serde(default)]
    pub frozen: bool,
}

impl Agent {
    /// Starts the agent for `stack`: sets the subtree's CPU weight (when
    /// configured), creates the node cgroups, restores or
    /// lifts limits (see [`state`]), re-attaches to processes that survived a
    /// previous agent, starts the rest and begins scanning for `match` nodes.
    pub async fn start(
        backend: Box<dyn CgroupBackend>,
        settings: AgentSettings,
        stack: StackSpec,
    ) -> Result<Self> {
        stack.validate().map_err(Error::InvalidStack)?;
        let persisted = state::load(&settings.state_file)?.unwrap_or_default();
        let metrics = Metrics::new().map_err(Error::Metrics)?;
        if let Some(w) = settings.subtree_cpu_weight {
            backend.set_root_weight(w)?;
        }
        let mut nodes = BTreeMap::new();
        for (app, n) in stack.nodes() {
            backend.create(&n.name)?;
            let matcher = match &n.source {
                NodeSource::Match(m) => Matcher::new(m),
                NodeSource::Run(_) => None,
            };
            nodes.insert(
                n.name.clone(),
                NodeRt {
                    app: app.to_owned(),
                    spec: n.clone(),
                    matcher,
                    persisted: persisted.nodes.get(&n.name).cloned().unwrap_or_default(),
                    supervisor: None,
                    sample: None,
                    usage_cpus: 0.0,
                    stats: CpuStats::default(),
                    limit: None,
                    weight: None,
                },
            );
        }
        // Empty cgroups of nodes no longer in the stack go; ones that still
        // hold processes are left alone (never kill what we do not supervise).
        for stale in backend.nodes()? {
            if !nodes.contains_key(&stale) && backend.pids(&stale).is_ok_and(|p| p.is_empty()) {
                backend.remove(&stale)?;
            }
        }
        let (events, _) = broadcast::channel(1024);
        let agent = Self {
            inner: Arc::new(Inner {
                backend,
                settings,
                proc_root: PathBuf::from("/proc"),
                state: Mutex::new(State {
                    nodes,
                    stack: stack.clone(),
                    committed: None,
                    active_monitor: String::new(),
                }),
                events,
                metrics,
                background: Mutex::new(None),
                parked: Mutex::new(Vec::new()),
            }),
        };
        agent.set_active_monitor("proc_scan");
        agent.restore_limits(&stack, persisted.committed)?;
        agent.reattach_or_start();
        agent.scan_matches(None);
        agent.persist();
        let bg = agent.clone();
        let handle = tokio::spawn(async move {
            let mut tick = tokio::time::interval(bg.inner.settings.scan_interval);
            loop {
                tick.tick().await;
                // /proc and cgroup reads are blocking file IO: keep them off
                // the (possibly single-threaded) runtime serving the API.
                let a = bg.clone();
                let _ = tokio::task::spawn_blocking(move || {
                    a.scan_matches(None);
                    a.enforce_frozen();
                    a.sample();
                    a.rotate_logs();
                })
                .await;
            }
        });
        *lock(&agent.inner.background) = Some(handle);
        Ok(agent)
    }

    fn restore_limits(&self, stack: &StackSpec, committed: Option<CommittedConfig>) -> Result<()> {
        match state::startup_limits(stack, committed.as_ref()) {
            StartupLimits::Reapply(cfg) => {
                configbot_cgroups::apply(self.backend(), &cfg)?;
                self.st().committed = committed;
                self.emit(AgentEvent::ConfigApplied {
                    nodes: cfg.limits.keys().cloned().collect(),
                });
            }
            StartupLimits::LiftCore(nodes) => {
                let unlimited = CgroupConfig {
                    limits: nodes
                        .iter()
                        .map(|n| (n.clone(), CpuLimit::UNLIMITED))
                        .collect(),
                };
                configbot_cgroups::apply(self.backend(), &unlimited)?;
                self.emit(AgentEvent::LimitsLifted {
                    nodes,
                    reason: "no committed config for this stack".into(),
                });
            }
        }
        Ok(())
    }

    fn reattach_or_start(&self) {
        let run_nodes: Vec<(NodeName, PersistedNode)> = self
            .st()
            .nodes
            .iter()
            .filter(|(_, n)| matches!(n.spec.source, NodeSource::Run(_)))
            .map(|(k, n)| (k.clone(), n.persisted.clone()))
            .collect();
        for (node, p) in run_nodes {
            if p.stopped {
                continue;
            }
            let in_cgroup = self.backend().pids(&node).unwrap_or_default();
            let alive = p.main.filter(|&(pid, st)| {
                in_cgroup.contains(&pid) && is_alive(&self.inner.proc_root, pid, st)
            });
            if alive.is_none() {
                // Leftovers of a main process that died with the old agent.
                for pid in in_cgroup {
                    send_signal(pid, libc::SIGKILL);
                }
            }
            self.start_supervisor(&node, alive);
        }
    }

    pub(crate) fn start_supervisor(&self, node: &NodeName, reattach: Option<(u32, u64)>) {
        let mut st = self.st();
        let Some(rt) = st.nodes.get_mut(node) else {
            return;
        };
        let NodeSource::Run(spec) = rt.spec.source.clone() else {
            return;
        };
        if rt
            .supervisor
            .as_ref()
            .is_some_and(|(_, h)| !h.is_finished())
        {
            return;
        }
        let (tx, rx) = watch::channel(false);
        let backoff = Backoff::new(self.settings().backoff_initial, self.settings().backoff_max);
        let policy = spec.restart_policy;
        let run = RunNode {
            agent: self.clone(),
            node: node.clone(),
            spec,
        };
        let handle = tokio::spawn(supervise::supervise(run, policy, backoff, rx, reattach));
        rt.supervisor = Some((tx, handle));
    }

    /// The cgroup backend.
    pub fn backend(&self) -> &dyn CgroupBackend {
        self.inner.backend.as_ref()
    }

    /// The agent's settings.
    pub fn settings(&self) -> &AgentSettings {
        &self.inner.settings
    }

    pub(crate) fn proc_root(&self) -> &Path {
        &self.inner.proc_root
    }

    /// The agent's metrics.
    pub fn metrics(&self) -> &Metrics {
        &self.inner.metrics
    }

    /// Subscribes to the event stream.
    pub fn subscribe(&self) -> broadcast::Receiver<AgentEvent> {
        self.inner.events.subscribe()
    }

    pub(crate) fn emit(&self, ev: AgentEvent) {
        // No subscribers is fine.
        let _ = self.inner.events.send(ev);
    }

    fn st(&self) -> MutexGuard<'_, State> {
        lock(&self.inner.state)
    }

    /// Writes the state file; a failure is reported as an event, not fatal.
    pub(crate) fn persist(&self) {
        let snapshot = {
            let st = self.st();
            PersistedState {
                committed: st.committed.clone(),
                nodes: st
                    .nodes
                    .iter()
                    .map(|(k, n)| (k.clone(), n.persisted.clone()))
                    .collect(),
                stack: Some(st.stack.clone()),
            }
        };
        if let Err(e) = state::save(&self.inner.settings.state_file, &snapshot) {
            self.emit(AgentEvent::StateWriteFailed {
                error: error_chain(&e),
            });
        }
    }

    pub(crate) fn update_node(&self, node: &NodeName, f: impl FnOnce(&mut PersistedNode)) {
        if let Some(rt) = self.st().nodes.get_mut(node) {
            f(&mut rt.persisted);
        }
        self.persist();
    }

    /// Moves `pid`, all its threads and its current descendants into `node`'s
    /// cgroup; later children follow by inheritance. This is also the entry
    /// point for the ROS layer (getPid of a node) and the process monitor.
    pub fn adopt(&self, node: &NodeName, pid: u32) -> Result<Vec<u32>> {
        let procs = list_procs(&self.inner.proc_root);
        self.adopt_with(node, pid, &procs)
    }

    fn adopt_with(&self, node: &NodeName, pid: u32, procs: &[ProcInfo]) -> Result<Vec<u32>> {
        if !self.st().nodes.contains_key(node) {
            return Err(Error::UnknownNode(node.to_string()));
        }
        let mut moved = Vec::new();
        for p in with_descendants(procs, pid) {
            match self.backend().add_pid(node, p) {
                Ok(()) => moved.push(p),
                // A descendant may exit meanwhile; the root pid must move.
                Err(e) if p == pid => return Err(e.into()),
                Err(_) => {}
            }
        }
        self.emit(AgentEvent::NodeAdopted {
            node: node.clone(),
            pids: moved.clone(),
        });
        Ok(moved)
    }

    /// Adopts matching processes not yet in their node's cgroup. `only` limits
    /// the scan to one process (monitor events).
    fn scan_matches(&self, only: Option<ProcInfo>) {
        let matchers: Vec<(NodeName, Matcher)> = self
            .st()
            .nodes
            .iter()
            .filter(|(_, n)| !n.persisted.stopped)
            .filter_map(|(k, n)| Some((k.clone(), n.matcher.clone()?)))
            .collect();
        if matchers.is_empty() {
            return;
        }
        let procs = match only {
            Some(p) => vec![p],
            None => list_procs(&self.inner.proc_root),
        };
        // A process already in any node's cgroup stays there: the first node
        // that claims it wins, and run nodes' processes are never stolen.
        let mut owned: std::collections::HashSet<u32> = self
            .st()
            .nodes
            .keys()
            .cloned()
            .collect::<Vec<_>>()
            .iter()
            .flat_map(|n| self.backend().pids(n).unwrap_or_default())
            .collect();
        let me = std::process::id();
        for (node, m) in matchers {
            for p in procs.iter().filter(|p| p.pid != me && m.matches(p)) {
                if owned.insert(p.pid)
                    && let Ok(moved) = self.adopt_with(&node, p.pid, &procs)
                {
                    owned.extend(moved);
                }
            }
        }
    }

    /// Feeds one process-monitor event: counts it; an exec that matches a
    /// `match` node is adopted at once instead of at the next scan.
    pub fn process_event(&self, ev: &ProcEvent) {
        self.inner
            .metrics
            .monitor_events
            .with_label_values(&[ev.kind.label()])
            .inc();
        if ev.kind != ProcEventKind::Exec {
            return;
        }
        self.emit(AgentEvent::ProcessExec {
            pid: ev.pid,
            comm: ev.comm.clone(),
        });
        if let Some(p) = read_proc(&self.inner.proc_root, ev.pid) {
            self.scan_matches(Some(p));
        }
    }

    /// Records which process monitor is active (`ebpf`, `proc_connector`, `proc_scan`).
    pub fn set_active_monitor(&self, name: &str) {
        self.st().active_monitor = name.to_owned();
        self.inner.metrics.set_active_monitor(name);
    }

    /// The active process monitor.
    pub fn active_monitor(&self) -> String {
        self.st().active_monitor.clone()
    }

    /// Applies a controller config atomically and records it as committed.
    pub fn put_config(&self, update: ConfigUpdate) -> Result<()> {
        let stack_nodes = {
            let st = self.st();
            if let Some(n) = update.limits.keys().find(|n| !st.nodes.contains_key(*n)) {
                return Err(Error::UnknownNode(n.to_string()));
            }
            state::stack_nodes(&st.stack)
        };
        let cfg = CgroupConfig {
            limits: update.limits.clone(),
        };
        if let Err(e) = configbot_cgroups::apply(self.backend(), &cfg) {
            self.emit(AgentEvent::ConfigRejected {
                error: error_chain(&e),
            });
            return Err(e.into());
        }
        self.st().committed = Some(CommittedConfig {
            limits: update.limits,
            adaptor_rates: update.adaptor_rates,
            stack_nodes,
        });
        self.persist();
        self.emit(AgentEvent::ConfigApplied {
            nodes: cfg.limits.keys().cloned().collect(),
        });
        self.sample();
        Ok(())
    }

    /// The last committed config, if any.
    pub fn committed(&self) -> Option<CommittedConfig> {
        self.st().committed.clone()
    }

    fn app_nodes(&self, app: &str) -> Result<Vec<NodeName>> {
        let nodes: Vec<NodeName> = self
            .st()
            .nodes
            .iter()
            .filter(|(_, n)| n.app == app)
            .map(|(k, _)| k.clone())
            .collect();
        if nodes.is_empty() {
            return Err(Error::UnknownApp(app.to_owned()));
        }
        Ok(nodes)
    }

    /// Stops every node of `app` gracefully (SIGINT → SIGTERM → SIGKILL, the
    /// nodes in parallel) and keeps it stopped, across agent restarts too,
    /// until [`Agent::start_app`].
    pub async fn stop_app(&self, app: &str) -> Result<()> {
        let nodes = self.app_nodes(app)?;
        for node in &nodes {
            if let Some(rt) = self.st().nodes.get_mut(node) {
                rt.persisted.stopped = true;
            }
        }
        // All at once, as roslaunch does: one slow node does not delay the rest.
        futures_util::future::join_all(nodes.iter().map(|n| self.stop_node(n))).await;
        self.persist();
        self.emit(AgentEvent::AppStopped {
            app: app.to_owned(),
        });
        Ok(())
    }

    /// Starts `app` again: `run` nodes are spawned, `match` nodes adopted when seen.
    pub fn start_app(&self, app: &str) -> Result<()> {
        for node in self.app_nodes(app)? {
            self.update_node(&node, |p| p.stopped = false);
            self.start_supervisor(&node, None);
        }
        self.scan_matches(None);
        self.emit(AgentEvent::AppStarted {
            app: app.to_owned(),
        });
        Ok(())
    }

    /// Freezes every node of `app`: SIGSTOP to each process in its cgroups.
    /// The processes keep their memory and sockets but use no CPU until
    /// [`Agent::thaw_app`] or [`Agent::stop_app`] (a stop thaws them first so
    /// they get its SIGINT). The flag survives agent restarts and node
    /// restarts: processes that show up in a frozen node are frozen too.
    /// A vfork parent whose child was stopped before its exec is not
    /// stopped itself: it waits in the kernel (state `D`) for the child,
    /// and runs no code until the thaw continues it.
    pub fn freeze_app(&self, app: &str) -> Result<()> {
        self.set_frozen(app, true)?;
        self.emit(AgentEvent::AppFrozen {
            app: app.to_owned(),
        });
        Ok(())
    }

    /// Thaws every node of `app` (SIGCONT to each process in its cgroups).
    pub fn thaw_app(&self, app: &str) -> Result<()> {
        self.set_frozen(app, false)?;
        self.emit(AgentEvent::AppThawed {
            app: app.to_owned(),
        });
        Ok(())
    }

    fn set_frozen(&self, app: &str, frozen: bool) -> Result<()> {
        let nodes = self.app_nodes(app)?;
        let done = nodes
            .iter()
            .try_for_each(|node| self.set_node_frozen(node, frozen));
        self.persist();
        done
    }

    /// Sets a node's frozen flag and sends its processes SIGSTOP or SIGCONT,
    /// both under the state lock, so [`Agent::enforce_frozen`] never sends a
    /// SIGSTOP between a thaw's flag and its SIGCONT. The caller persists.
    pub(crate) fn set_node_frozen(&self, node: &NodeName, frozen: bool) -> Result<()> {
        let mut st = self.st();
        if let Some(rt) = st.nodes.get_mut(node) {
            rt.persisted.frozen = frozen;
        }
        let sig = if frozen { libc::SIGSTOP } else { libc::SIGCONT };
        process::signal_cgroup(self, node, sig)?;
        Ok(())
    }

    /// Keeps frozen nodes frozen: a process that appeared in a frozen node's
    /// cgroup since (a restarted node, a node the stack added to a frozen
    /// app, a process of an agent restart) gets its SIGSTOP here, every
    /// `scanInterval`. SIGSTOP to a stopped process changes nothing. Runs
    /// under the state lock (see [`Agent::set_node_frozen`]).
    fn enforce_frozen(&self) {
        let st = self.st();
        for (node, _) in st
            .nodes
            .iter()
            .filter(|(_, n)| n.persisted.frozen && !n.persisted.stopped)
        {
            let _ = process::signal_cgroup(self, node, libc::SIGSTOP);
        }
    }

    /// App names.
    pub fn apps(&self) -> Vec<String> {
        self.st()
            .stack
            .apps
            .iter()
            .map(|a| a.name.clone())
            .collect()
    }

    /// Reads stats of every node and updates usage rates and metrics.
    pub fn sample(&self) {
        let names: Vec<NodeName> = self.st().nodes.keys().cloned().collect();
        for node in names {
            let stats = self.backend().stats(&node);
            let limit = self.backend().cpu_max(&node).ok();
            let weight = self.backend().weight(&node).ok();
            let now = Instant::now();
            let mut st = self.st();
            let Some(rt) = st.nodes.get_mut(&node) else {
                continue;
            };
            if let Ok(s) = stats {
                if let Some((prev, t)) = rt.sample {
                    let dt = now.duration_since(t).as_secs_f64();
                    if dt > 0.0 {
                        #[allow(clippy::cast_precision_loss)]
                        let used = s.usage_ns.saturating_sub(prev) as f64 / 1e9;
                        rt.usage_cpus = used / dt;
                    }
                }
                rt.sample = Some((s.usage_ns, now));
                rt.stats = s;
            }
            rt.limit = limit;
            rt.weight = weight;
            let m = &self.inner.metrics;
            let label = [node.as_str()];
            m.usage.with_label_values(&label).set(rt.usage_cpus);
            let lim = limit.and_then(|l| l.to_limit().cpus).unwrap_or(-1.0);
            m.limit.with_label_values(&label).set(lim);
            if let Some(w) = weight {
                m.weight.with_label_values(&label).set(i64::from(w.v2()));
            }
            m.throttled_periods
                .with_label_values(&label)
                .set(i64::try_from(rt.stats.nr_throttled).unwrap_or(i64::MAX));
            #[allow(clippy::cast_precision_loss)]
            m.throttled_seconds
                .with_label_values(&label)
                .set(rt.stats.throttled_ns as f64 / 1e9);
        }
    }

    fn rotate_logs(&self) {
        let names: Vec<NodeName> = self
            .st()
            .nodes
            .iter()
            .filter(|(_, n)| matches!(n.spec.source, NodeSource::Run(_)))
            .map(|(k, _)| k.clone())
            .collect();
        let s = &self.inner.settings;
        for n in names {
            let _ = crate::spawn::rotate_if_needed(&self.log_path(&n), s.log_max_bytes, s.log_keep);
        }
    }

    /// The log file of a `run` node.
    pub fn log_path(&self, node: &NodeName) -> PathBuf {
        self.inner
            .settings
            .log_dir
            .join(format!("{}.log", node.dir_name()))
    }

    /// The node inventory.
    pub fn inventory(&self) -> Vec<NodeStatus> {
        let st = self.st();
        st.nodes
            .iter()
            .map(|(name, rt)| NodeStatus {
                name: name.clone(),
                app: rt.app.clone(),
                kind: match rt.spec.source {
                    NodeSource::Run(_) => "run",
                    NodeSource::Match(_) => "match",
                }
                .to_owned(),
                core: rt.spec.core,
                pids: self.backend().pids(name).unwrap_or_default(),
                main_pid: rt.persisted.main.map(|(p, _)| p),
                cgroup: self.backend().node_path(name),
                cpu_usage_cpus: rt.usage_cpus,
                cpu_limit: rt.limit,
                cpu_weight: rt.weight,
                stats: rt.stats,
                restarts: rt.persisted.restarts,
                stopped: rt.persisted.stopped,
                frozen: rt.persisted.frozen,
            })
            .collect()
    }

    /// Stops background work and detaches from the processes, which keep
    /// running and are re-attached by the next agent. Lifts every limit first
    /// when `liftLimitsOnShutdown` is set.
    pub async fn shutdown(&self) {
        for h in self.detach() {
            let _ = h.await;
        }
        if self.inner.settings.lift_limits_on_shutdown {
            let nodes: Vec<NodeName> = self.st().nodes.keys().cloned().collect();
            for n in &nodes {
                let _ = self.backend().set_cpu_max(
                    n,
                    CpuMax {
                        quota_us: None,
                        period_us: configbot_cgroups::DEFAULT_PERIOD_US,
                    },
                );
            }
            self.emit(AgentEvent::LimitsLifted {
                nodes,
                reason: "agent shutdown".into(),
            });
        }
        self.persist();
    }

    /// Aborts the background loop and all supervisors without touching any
    /// process (synchronous, so usable from `Drop`); returns the handles.
    pub fn detach(&self) -> Vec<JoinHandle<()>> {
        let mut handles: Vec<JoinHandle<()>> =
            lock(&self.inner.background).take().into_iter().collect();
        let mut senders = Vec::new();
        for (tx, h) in self
            .st()
            .nodes
            .values_mut()
            .filter_map(|rt| rt.supervisor.take())
        {
            senders.push(tx);
            handles.push(h);
        }
        for h in &handles {
            h.abort();
        }
        // A dropped stop sender reads as "stop" to a supervisor that is still
        // running: keep the senders alive with the agent so an aborted
        // supervisor never terminates its node on the way out.
        lock(&self.inner.parked).extend(senders);
        handles
    }

    /// Stops every app, removes every node cgroup and the subtree root, then
    /// shuts down. For uninstalling and for tests.
    pub async fn teardown(&self) -> Result<()> {
        for app in self.apps() {
            self.stop_app(&app).await?;
        }
        self.shutdown().await;
        let names: Vec<NodeName> = self.st().nodes.keys().cloned().collect();
        for n in names {
            self.backend().remove(&n)?;
        }
        self.backend().remove_root()?;
        Ok(())
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// "outer: inner: innermost" for an error and its sources.
pub fn error_chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut cur = e.source();
    while let Some(c) = cur {
        s.push_str(": ");
        s.push_str(&c.to_string());
        cur = c.source();
    }
    s
}
