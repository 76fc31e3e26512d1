//! The driver: one async task per PerformanceSpec that runs the tuning
//! machine against a [`Robot`]. Each iteration reads the spec and stack from
//! the store, persists the run (the resume point) and writes status, does the
//! IO the state asks for ([`machine::effect`]), and feeds the result to
//! [`machine::step`]; events and library entries go to the store. While
//! monitoring it also watches robot events (process execs, graph changes) and
//! the periodic graph check, and turns a changed context into a trigger.
//!
//! [`TuningManager`] starts and stops runners; the PerformanceSpec reconciler
//! calls it when the server has a robot attached.

use std::collections::HashMap;
use std::hash::{Hash, Hasher};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use configbot_api::backoff::{Backoff, XorShift};
use configbot_manifests::{Kind, PerformanceSpec, PerformanceSpecStatus, Reason, RobotStack};
use serde::{Deserialize, Serialize};
use tokio::sync::broadcast;
use tokio::task::JoinHandle;

use configbot_tuning::library::{self, CONTEXT_LABELS};
use configbot_tuning::machine::{self, Effect, Env, Input, Output, Recording, Remedy, Run, State};
use configbot_tuning::monitor::{self, RobotEvent, Trigger};
use configbot_tuning::outcome;

use super::profiles;
use super::robot::{Clock, Robot, RobotError};
use crate::metrics::Metrics;
use crate::store::{Store, StoreError};

/// Scope of the runs in the store's controller state.
pub const STATE_SCOPE: &str = "tuning-run";
/// Annotation a task executive sets to pause tuning (`"false"`).
pub const TUNING_ALLOWED: &str = "configbot.dev/tuning-allowed";

/// Errors of one runner iteration (logged as events, then retried).
#[derive(Debug, thiserror::Error)]
pub enum RunnerError {
    #[error("store: {0}")]
    Store(#[from] StoreError),
    #[error(transparent)]
    Robot(#[from] RobotError),
    #[error("persisted tuning run {key}: {source}")]
    State {
        key: String,
        #[source]
        source: serde_json::Error,
    },
}

/// What a runner needs: the robot, its clock, the store and the metrics.
#[derive(Clone)]
pub struct RunnerCtx {
    pub robot: Arc<dyn Robot>,
    pub clock: Arc<dyn Clock>,
    pub store: Arc<Store>,
    pub metrics: Arc<Metrics>,
}

impl std::fmt::Debug for RunnerCtx {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunnerCtx").finish_non_exhaustive()
    }
}

#[derive(Serialize, Deserialize)]
struct Persisted {
    uid: String,
    run: Run,
}

/// A run as persisted (its resume point) for the spec with `uid`.
fn persisted(uid: &str, run: &Run, key: &str) -> Result<String, RunnerError> {
    serde_json::to_string(&Persisted {
        uid: uid.to_string(),
        run: run.clone(),
    })
    .map_err(|source| RunnerError::State {
        key: key.to_string(),
        source,
    })
}

/// An event's type: `Normal` or `Warning`.
fn event_type(normal: bool) -> &'static str {
    if normal { "Normal" } else { "Warning" }
}

fn run_key(ns: &str, name: &str) -> String {
    format!("{ns}/{name}")
}

/// The persisted run of a spec, if any (for tools and tests).
pub fn load_run(store: &Store, ns: &str, name: &str) -> Result<Option<Run>, RunnerError> {
    let key = run_key(ns, name);
    store
        .get_state(STATE_SCOPE, &key)?
        .map(|b| serde_json::from_str::<Persisted>(&b).map(|p| p.run))
        .transpose()
        .map_err(|source| RunnerError::State { key, source })
}

/// Whether tuning may run now: the spec field and the task executive's annotation.
pub fn tuning_allowed(spec: &PerformanceSpec) -> bool {
    spec.spec.tuning.allowed
        && spec
            .metadata
            .annotations
            .get(TUNING_ALLOWED)
            .is_none_or(|v| v.trim() != "false")
}

fn labels(
    spec: &PerformanceSpec,
    stack: &RobotStack,
) -> std::collections::BTreeMap<String, String> {
    spec.metadata
        .annotations
        .get(CONTEXT_LABELS)
        .or(stack.metadata.annotations.get(CONTEXT_LABELS))
        .map(|s| library::parse_labels(s))
        .unwrap_or_default()
}

struct Runner {
    ctx: RunnerCtx,
    ns: String,
    name: String,
    events: broadcast::Receiver<RobotEvent>,
    next_graph_check_ms: u64,
    graph_interval_ms: u64,
    /// Recent process execs (pid, time), to report how long after its
    /// process started a new node was detected.
    execs: std::collections::VecDeque<(u32, u64)>,
    /// Retries of failed iterations: 1 s doubling to 30 s, ±25 % jitter.
    backoff: Backoff,
}

/// The newest node of `new_nodes` that is not in `old_nodes` and whose pid
/// (from the graph) exec'd recently: its name and exec time (pure).
pub fn new_node_exec(
    execs: &std::collections::VecDeque<(u32, u64)>,
    old_nodes: &[String],
    new_nodes: &[String],
    graph: &configbot_api::graph::Graph,
) -> Option<(String, u64)> {
    new_nodes
        .iter()
        .filter(|n| !old_nodes.contains(n))
        .filter_map(|n| {
            let pid = graph.nodes.get(n)?.pid?;
            let at = execs.iter().rev().find(|(p, _)| *p == pid)?.1;
            Some((n.clone(), at))
        })
        .max_by_key(|(_, at)| *at)
}

/// Run the tuning loop of one spec until the spec is deleted.
pub async fn run_spec(ctx: RunnerCtx, ns: String, name: String) {
    let events = ctx.robot.events();
    let backoff = retry_backoff(&ns, &name);
    let mut r = Runner {
        ctx,
        ns,
        name,
        events,
        next_graph_check_ms: 0,
        graph_interval_ms: 30_000,
        execs: std::collections::VecDeque::new(),
        backoff,
    };
    let mut run: Option<Run> = None;
    loop {
        match r.iterate(run.take()).await {
            Ok(Some(next)) => {
                r.backoff.reset();
                run = Some(next);
            }
            Ok(None) => return,
            Err((e, keep)) => {
                if r.backoff.attempts() == 0 {
                    r.event(false, &Reason::TuningError, &e.to_string());
                }
                run = keep;
                let delay = r.backoff.next_delay();
                r.ctx.clock.sleep(delay).await;
            }
        }
    }
}

/// The runner's retry backoff, its jitter seeded by the spec's name so
/// runners that fail together (a robot gone) retry apart.
fn retry_backoff(ns: &str, name: &str) -> Backoff {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    (ns, name).hash(&mut h);
    Backoff::jittered(
        Duration::from_secs(1),
        Duration::from_secs(30),
        0.25,
        XorShift::new(h.finish()),
    )
}

type IterResult = Result<Option<Run>, (RunnerError, Option<Run>)>;

impl Runner {
    fn event(&self, normal: bool, reason: &Reason, message: &str) {
        if let Ok(Some(obj)) = self
            .ctx
            .store
            .get(Kind::PerformanceSpec, &self.ns, &self.name)
        {
            let _ = self
                .ctx
                .store
                .record_event(&obj, event_type(normal), reason, message);
        }
    }

    /// One effect and one step. `Ok(None)`: the spec is gone.
    async fn iterate(&mut self, run: Option<Run>) -> IterResult {
        let store = self.ctx.store.clone();
        let key = run_key(&self.ns, &self.name);
        let keep = run.clone();
        let fail = |e: RunnerError, keep: Option<Run>| (e, keep);
        let obj = match store.get(Kind::PerformanceSpec, &self.ns, &self.name) {
            Ok(Some(o)) => o,
            Ok(None) => {
                // A spec deleted mid-remediation leaves nothing paused behind.
                if let Some(
                    State::RemediatePause { remedy }
                    | State::RemediateApply { remedy }
                    | State::Remediating { remedy }
                    | State::RemediateUndo { remedy },
                ) = run.as_ref().map(|r| &r.state)
                    && let Err(e) = self.resume(remedy, &remedy.apps).await
                {
                    tracing::warn!(
                        spec = %format_args!("{}/{}", self.ns, self.name),
                        error = %e,
                        "spec deleted while remediating; resuming its paused apps failed"
                    );
                }
                let _ = store.delete_state(STATE_SCOPE, &key);
                return Ok(None);
            }
            Err(e) => return Err(fail(e.into(), keep)),
        };
        let Ok(spec) = serde_json::from_value::<PerformanceSpec>(obj.clone()) else {
            // Invalid specs are reported by the reconciler; wait for a fix.
            self.ctx.clock.sleep(Duration::from_secs(1)).await;
            return Ok(keep);
        };
        let stack = store
            .get(Kind::RobotStack, &self.ns, &spec.spec.stack_ref.name)
            .map_err(|e| fail(e.into(), keep.clone()))?
            .and_then(|s| serde_json::from_value::<RobotStack>(s).ok());
        let Some(stack) = stack else {
            self.ctx.clock.sleep(Duration::from_secs(1)).await;
            return Ok(keep);
        };
        let generation = spec.metadata.generation.unwrap_or(0);
        let uid = spec.metadata.uid.clone().unwrap_or_default();
        // A run carried from this runner's last step had its resume point
        // written with that step's events.
        let carried = matches!(&run, Some(r) if r.generation == generation);
        let mut run = match run {
            Some(r) if r.generation == generation => r,
            Some(old) => {
                let t = Trigger::SpecChanged;
                self.trigger_metric(&t);
                self.event(true, &t.reason(), &t.message());
                Run::after_spec_change(old, generation)
            }
            None => match store.get_state(STATE_SCOPE, &key) {
                Ok(Some(body)) => match serde_json::from_str::<Persisted>(&body) {
                    Ok(p) if p.uid == uid && p.run.generation == generation => {
                        let resumed = p.run.resumed();
                        self.event(
                            true,
                            &Reason::Resumed,
                            &format!(
                                "resumed the tuning run in phase {} after {} trials",
                                resumed.phase(),
                                resumed.trials.len()
                            ),
                        );
                        resumed
                    }
                    // The spec changed while this controller was down.
                    Ok(p) if p.uid == uid => Run::after_spec_change(p.run, generation),
                    _ => Run::new(generation, Trigger::SpecChanged),
                },
                Ok(None) => Run::new(generation, Trigger::SpecChanged),
                Err(e) => return Err(fail(e.into(), None)),
            },
        };
        let cpus = stack.spec.robot.cpus.unwrap_or_else(machine_cpus);
        let (ns, name) = (self.ns.clone(), self.name.clone());
        let env = Env {
            stack: &stack,
            spec: &spec.spec,
            namespace: &ns,
            spec_name: &name,
            cpus,
            tuning_allowed: tuning_allowed(&spec),
        };
        // Persist a new, resumed or re-specified run's resume point and
        // publish status before doing the IO.
        if !carried {
            let body = persisted(&uid, &run, &key).map_err(|e| fail(e, Some(run.clone())))?;
            store
                .put_state(STATE_SCOPE, &key, &body)
                .map_err(|e| fail(e.into(), Some(run.clone())))?;
        }
        self.write_status(&run, &env, generation)
            .map_err(|e| fail(e, Some(run.clone())))?;
        self.graph_interval_ms = (spec.spec.monitoring.graph_interval_seconds * 1000.0) as u64;
        let effect = machine::effect(&run, &env);
        let labels = labels(&spec, &stack);
        let input = match self.execute(effect, &run, &stack, &labels).await {
            Ok(i) => i,
            Err(e) => return Err(fail(e, Some(run))),
        };
        if matches!(input, Input::Observed { .. }) {
            self.next_graph_check_ms = self.ctx.clock.now_ms() + self.graph_interval_ms;
        }
        let before = Some(run.clone());
        let (next, outputs) = machine::step(run, input, &env);
        run = next;
        // The step's events go to the store with its resume point, in one
        // transaction: a run resumed after a crash neither repeats a step
        // whose events were recorded (a trial's event twice) nor loses them.
        // Profiles are saved before: a save is idempotent, so a step
        // replayed after a crash in between saves it again. A write that
        // fails replays the step too, from the run before it.
        let events: Vec<(&str, Reason, String)> =
            outputs.into_iter().map(|o| self.output(o)).collect();
        let body = match persisted(&uid, &run, &key) {
            Ok(b) => b,
            Err(e) => return Err(fail(e, before)),
        };
        match store.put_state_and_events(Some((STATE_SCOPE, &key, &body)), &obj, &events) {
            Ok(()) => Ok(Some(run)),
            Err(e) => Err(fail(e.into(), before)),
        }
    }

    /// Acts on one output of a step; returns the event it makes (type,
    /// reason, message), for the store.
    fn output(&self, o: Output) -> (&'static str, Reason, String) {
        match o {
            Output::Event {
                warning,
                reason,
                message,
            } => {
                let m = &self.ctx.metrics.tuning;
                let l = [self.ns.as_str(), self.name.as_str()];
                match reason {
                    Reason::LibraryHit => m.library_hits.with_label_values(&l).inc(),
                    Reason::RemediationUndone => m
                        .remediations
                        .with_label_values(&[l[0], l[1], "undo"])
                        .inc(),
                    Reason::ConstraintViolated
                    | Reason::ContextChanged
                    | Reason::LibraryConfigFailed
                    | Reason::TuningAllowed => m
                        .triggers
                        .with_label_values(&[l[0], l[1], reason.as_str()])
                        .inc(),
                    _ => {}
                }
                (event_type(!warning), reason, message)
            }
            Output::SaveProfile(p) => match profiles::save(&self.ctx.store, &p) {
                Ok(()) => (
                    event_type(true),
                    Reason::ProfileSaved,
                    format!(
                        "config library: saved ConfigProfile {} for context {}",
                        p.metadata.name,
                        p.spec.context.key()
                    ),
                ),
                Err(e) => (event_type(false), Reason::ProfileSaveFailed, e.to_string()),
            },
        }
    }

    fn trigger_metric(&self, t: &Trigger) {
        self.ctx
            .metrics
            .tuning
            .triggers
            .with_label_values(&[self.ns.as_str(), self.name.as_str(), t.reason().as_str()])
            .inc();
    }

    /// Do the IO of one effect.
    async fn execute(
        &mut self,
        effect: Effect,
        run: &Run,
        stack: &RobotStack,
        labels: &std::collections::BTreeMap<String, String>,
    ) -> Result<Input, RunnerError> {
        let robot = self.ctx.robot.clone();
        Ok(match effect {
            Effect::Observe => {
                let graph = robot.graph().await?;
                let context = library::context(stack, &graph, labels);
                let known = profiles::lookup(&self.ctx.store, &self.ns, &self.name, &context)?
                    .map(Box::new);
                Input::Observed {
                    graph,
                    context,
                    known,
                }
            }
            Effect::Apply(cfg) => {
                robot.apply(&cfg).await?;
                Input::Applied
            }
            Effect::Sleep(d) => {
                self.ctx.clock.sleep(d).await;
                Input::Slept
            }
            Effect::Measure(req) => {
                if !matches!(run.state, State::Monitor { .. }) {
                    let m = robot.measure(&req).await?;
                    // Trials and verifications are for one graph: a node that
                    // came or went meanwhile voids them (checked after each one).
                    if matches!(run.state, State::TrialProfile { .. } | State::Verify { .. })
                        && let Some(t) = self
                            .context_trigger(run, stack, labels, "graph check after a measurement")
                            .await?
                    {
                        return Ok(Input::Trigger(t));
                    }
                    return Ok(Input::Measured(m));
                }
                // Monitoring: the periodic graph check, then measure while watching events.
                if self.ctx.clock.now_ms() >= self.next_graph_check_ms
                    && let Some(t) = self
                        .context_trigger(run, stack, labels, "periodic graph check")
                        .await?
                {
                    return Ok(Input::Trigger(t));
                }
                loop {
                    tokio::select! {
                        biased;
                        ev = self.events.recv() => match ev {
                            Ok(e) => {
                                if let RobotEvent::ProcessExec { pid, at_unix_ms, .. } = &e {
                                    if self.execs.len() >= 512 {
                                        self.execs.pop_front();
                                    }
                                    self.execs.push_back((*pid, *at_unix_ms));
                                }
                                if let Some(cause) = monitor::recheck_cause(&e) {
                                    if let Some(t) = self.context_trigger(run, stack, labels, &cause).await? {
                                        return Ok(Input::Trigger(t));
                                    }
                                    // Not visible in the graph yet: look again soon.
                                    self.next_graph_check_ms = self.ctx.clock.now_ms() + 1000;
                                }
                            }
                            Err(broadcast::error::RecvError::Lagged(_)) => {
                                self.next_graph_check_ms = 0;
                            }
                            Err(broadcast::error::RecvError::Closed) => {
                                return Ok(Input::Measured(robot.measure(&req).await?));
                            }
                        },
                        m = robot.measure(&req) => return Ok(Input::Measured(m?)),
                    }
                }
            }
            Effect::PauseApps(remedy) => {
                // Inputs first: a stopped app's nodes leave the graph.
                let mut recording = None;
                if remedy.record {
                    let topics = outcome::paused_inputs(stack, &robot.graph().await?, &remedy.apps);
                    if let Some(path) = robot
                        .start_recording(&self.recording_name(), &topics)
                        .await?
                    {
                        let path = path.display().to_string();
                        recording = Some(Recording { path, topics });
                    }
                }
                for a in &remedy.apps {
                    if remedy.freeze {
                        robot.freeze_app(a).await?;
                    } else {
                        robot.stop_app(a).await?;
                    }
                }
                let action = if remedy.freeze {
                    "freeze_non_core"
                } else {
                    "stop_non_core"
                };
                self.ctx
                    .metrics
                    .tuning
                    .remediations
                    .with_label_values(&[self.ns.as_str(), self.name.as_str(), action])
                    .inc();
                Input::AppsPaused(recording)
            }
            Effect::ResumeApps(remedy) => {
                // An app the stack no longer has is no longer the robot's to resume.
                let apps: Vec<String> = remedy
                    .apps
                    .iter()
                    .filter(|a| stack.spec.apps.iter().any(|s| s.name == **a))
                    .cloned()
                    .collect();
                Input::AppsResumed(self.resume(&remedy, &apps).await?)
            }
        })
    }

    /// Undoes a remediation: stops its recording, then starts or thaws
    /// `apps` (trying every one; the first error is returned); the bag's path.
    async fn resume(&self, remedy: &Remedy, apps: &[String]) -> Result<Option<String>, RobotError> {
        let robot = &self.ctx.robot;
        let bag = if remedy.record {
            let bag = robot.stop_recording(&self.recording_name()).await?;
            bag.map(|p| p.display().to_string())
        } else {
            None
        };
        let mut first_error = None;
        for a in apps {
            let r = if remedy.freeze {
                robot.thaw_app(a).await
            } else {
                robot.start_app(a).await
            };
            if let Err(e) = r {
                first_error.get_or_insert(e);
            }
        }
        first_error.map_or(Ok(bag), Err)
    }

    /// The rosbag recording of this spec's remediations.
    fn recording_name(&self) -> String {
        outcome::recording_name(&self.ns, &self.name)
    }

    /// Read the graph; a trigger when the context differs from the run's.
    async fn context_trigger(
        &mut self,
        run: &Run,
        stack: &RobotStack,
        labels: &std::collections::BTreeMap<String, String>,
        by: &str,
    ) -> Result<Option<Trigger>, RunnerError> {
        let graph = self.ctx.robot.graph().await?;
        let ctx = library::context(stack, &graph, labels);
        self.next_graph_check_ms = u64::MAX; // set again after the next Observe
        let from = run.context.as_ref().map(|c| c.key()).unwrap_or_default();
        if from == ctx.key() {
            self.next_graph_check_ms = self.ctx.clock.now_ms() + self.graph_interval_ms;
            return Ok(None);
        }
        let old_nodes: &[String] = run.context.as_ref().map_or(&[], |c| &c.nodes);
        let started = new_node_exec(&self.execs, old_nodes, &ctx.nodes, &graph);
        let by = match started {
            Some((node, t)) => format!(
                "{by}; {node} seen {} ms after its process exec",
                self.ctx.clock.now_ms().saturating_sub(t)
            ),
            None => by.to_string(),
        };
        let joined = ctx
            .nodes
            .iter()
            .filter(|n| !old_nodes.contains(n))
            .cloned()
            .collect();
        Ok(Some(Trigger::ContextChanged {
            from,
            to: ctx.key(),
            by,
            joined,
        }))
    }

    fn write_status(&self, run: &Run, env: &Env<'_>, generation: i64) -> Result<(), RunnerError> {
        let defs = env.defs();
        self.metrics(run, &defs);
        for _ in 0..5 {
            let Some(obj) = self
                .ctx
                .store
                .get(Kind::PerformanceSpec, &self.ns, &self.name)?
            else {
                return Ok(());
            };
            let old: PerformanceSpecStatus =
                configbot_manifests::decode_status(&obj).unwrap_or_default();
            let new = configbot_tuning::status::status(
                &old,
                run,
                &defs,
                env.spec.tuning.max_trials,
                generation,
                &crate::store::now_rfc3339(),
            );
            if new == old {
                return Ok(());
            }
            let value = serde_json::to_value(&new).map_err(|source| RunnerError::State {
                key: run_key(&self.ns, &self.name),
                source,
            })?;
            let rv = obj["metadata"]["resourceVersion"].as_str();
            match self
                .ctx
                .store
                .put_status(Kind::PerformanceSpec, &self.ns, &self.name, value, rv)
            {
                Err(StoreError::Conflict { .. }) => continue,
                r => return r.map(|_| ()).map_err(Into::into),
            }
        }
        Ok(())
    }

    fn metrics(&self, run: &Run, defs: &[configbot_tuning::measure::MetricDef]) {
        let m = &self.ctx.metrics.tuning;
        let (ns, name) = (self.ns.as_str(), self.name.as_str());
        let phase = run.phase();
        for p in &machine::PHASES {
            m.phase
                .with_label_values(&[ns, name, p.as_str()])
                .set(i64::from(phase == *p));
        }
        m.trials
            .with_label_values(&[ns, name])
            .set(run.trials.len() as i64);
        let latest = run.trials.last().or(run.baseline.as_ref());
        let sat = match run.state {
            State::Monitor { .. } => run.monitor.satisfaction(),
            _ => None,
        }
        .or(latest.map(|t| t.eval.satisfaction));
        if let Some(s) = sat {
            m.satisfaction.with_label_values(&[ns, name]).set(s);
        }
        for d in defs {
            m.metric_target
                .with_label_values(&[ns, name, d.name.as_str()])
                .set(d.target);
            if let Some(v) = latest.and_then(|t| t.eval.means.get(&d.name)) {
                m.metric_value
                    .with_label_values(&[ns, name, d.name.as_str()])
                    .set(*v);
            }
        }
    }
}

/// CPUs this process may run on.
pub fn machine_cpus() -> f64 {
    std::thread::available_parallelism().map_or(1.0, |n| n.get() as f64)
}

/// Starts and stops one runner per PerformanceSpec.
#[derive(Debug)]
pub struct TuningManager {
    ctx: RunnerCtx,
    runners: Mutex<HashMap<(String, String), JoinHandle<()>>>,
}

impl TuningManager {
    pub fn new(ctx: RunnerCtx) -> TuningManager {
        TuningManager {
            ctx,
            runners: Mutex::new(HashMap::new()),
        }
    }

    /// Make sure a runner for the spec is running (inside a tokio runtime).
    pub fn ensure(&self, ns: &str, name: &str) {
        let mut r = self.runners.lock().unwrap_or_else(|p| p.into_inner());
        let key = (ns.to_string(), name.to_string());
        if r.get(&key).is_some_and(|h| !h.is_finished()) {
            return;
        }
        let h = tokio::spawn(run_spec(self.ctx.clone(), key.0.clone(), key.1.clone()));
        r.insert(key, h);
    }

    /// Stop the spec's runner (its persisted run stays for a resume).
    pub fn stop(&self, ns: &str, name: &str) {
        let mut r = self.runners.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(h) = r.remove(&(ns.to_string(), name.to_string())) {
            h.abort();
        }
    }

    /// The spec was deleted: stop its runner and drop its persisted run.
    pub fn forget(&self, ns: &str, name: &str) {
        let h = {
            let mut r = self.runners.lock().unwrap_or_else(|p| p.into_inner());
            r.remove(&(ns.to_string(), name.to_string()))
        };
        let store = self.ctx.store.clone();
        let key = run_key(ns, name);
        // Delete only once the runner has stopped: an iteration in flight
        // could otherwise write the state again after the delete.
        tokio::spawn(async move {
            if let Some(h) = h {
                h.abort();
                let _ = h.await;
            }
            if let Err(e) = store.delete_state(STATE_SCOPE, &key) {
                tracing::warn!(run = %key, error = %e, "removing a stopped tuning run's state");
            }
        });
    }

    /// Specs with a live runner.
    pub fn running(&self) -> Vec<(String, String)> {
        let r = self.runners.lock().unwrap_or_else(|p| p.into_inner());
        let mut v: Vec<_> = r
            .iter()
            .filter(|(_, h)| !h.is_finished())
            .map(|(k, _)| k.clone())
            .collect();
        v.sort();
        v
    }
}

impl Drop for TuningManager {
    fn drop(&mut self) {
        let r = self.runners.get_mut().unwrap_or_else(|p| p.into_inner());
        for (_, h) in r.drain() {
            h.abort();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use configbot_api::graph::{Graph, NodeInfo};

    #[test]
    fn detection_latency_is_measured_from_the_new_nodes_own_exec() {
        let mut g = Graph::default();
        for (n, pid) in [("/nav", 10), ("/hog", 42)] {
            g.nodes.insert(
                n.into(),
                NodeInfo {
                    name: n.into(),
                    uri: String::new(),
                    pid: Some(pid),
                },
            );
        }
        // Other processes exec'd after the hog: they must not count.
        let execs: std::collections::VecDeque<(u32, u64)> =
            [(10, 100), (42, 5_000), (77, 9_000)].into_iter().collect();
        let old = vec!["/nav".to_owned()];
        let new = vec!["/hog".to_owned(), "/nav".to_owned()];
        assert_eq!(
            new_node_exec(&execs, &old, &new, &g),
            Some(("/hog".to_owned(), 5_000))
        );
        // A node whose process started before the monitor saw it: no claim.
        assert_eq!(
            new_node_exec(&execs, &old, &["/nav".to_owned(), "/x".to_owned()], &g),
            None
        );
    }
}
