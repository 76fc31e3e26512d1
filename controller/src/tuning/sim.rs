//! A deterministic simulated robot for tests: ROS-like nodes with a
//! CPU cost per message and per timer cycle, publish rates, per-node CPU
//! limits, CFS-like sharing of N CPUs weighted by threads and cgroup CPU
//! weight (water-filling), and
//! per-edge adaptors — a generalisation of the optimizer crate's robot-stack
//! problem. A node given a fraction f of its demand processes (and publishes)
//! a fraction f of its input; the model iterates to a fixed point.
//!
//! `measure` answers at once with one value per sub-window (steady value ×
//! (1 ± noise), the noise a hash of seed, simulated time and probe) and
//! advances the simulated clock by the window; [`SimRobot`] is also the
//! [`Clock`], so nothing waits in real time. A frozen app stays in the graph
//! but does no work; recordings are only remembered (topics and name).

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use configbot_api::graph::{Graph, NodeInfo, TopicInfo};
use configbot_api::measure::{MeasureReport, MeasureRequest, Probe, ProbeSeries};
use configbot_manifests::{ResourceConfig, RobotStack};
use tokio::sync::{Notify, broadcast};

use configbot_tuning::monitor::RobotEvent;

use super::robot::{BoxFuture, Clock, NodeApi, Robot, RobotError};

/// One input of a node: messages of `topic` cost `cost` CPU-seconds each.
#[derive(Debug, Clone, PartialEq)]
pub struct SimInput {
    pub topic: String,
    pub cost: f64,
}

/// One simulated node.
#[derive(Debug, Clone, PartialEq)]
pub struct SimNode {
    pub name: String,
    pub app: String,
    /// Parallelism (CPUs it can use at most) and CFS weight (times the
    /// config's `cpuWeight` / 100).
    pub threads: f64,
    /// A periodic loop at this rate (a sensor, a planner); `None`: driven by its first input.
    pub timer_hz: Option<f64>,
    /// CPU-seconds per timer cycle.
    pub cycle_cost: f64,
    pub inputs: Vec<SimInput>,
    /// Topic published once per processed cycle / trigger message.
    pub publishes: Option<String>,
}

/// Steady state of the model for one config.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SimRates {
    /// Rate of every topic (publisher side).
    pub topics: BTreeMap<String, f64>,
    /// Rate delivered per (topic, subscriber).
    pub delivered: BTreeMap<(String, String), f64>,
    /// CPUs each node gets.
    pub cpu: BTreeMap<String, f64>,
}

#[derive(Debug)]
struct SimState {
    nodes: Vec<SimNode>,
    stopped: BTreeSet<String>,
    frozen: BTreeSet<String>,
    /// Recordings: name → topics, while running.
    recording: BTreeMap<String, Vec<String>>,
    config: ResourceConfig,
    applied: Vec<(u64, ResourceConfig)>,
    measures: u64,
    hang_at: Option<u64>,
}

/// The simulated robot. Cheap to share behind an `Arc`.
#[derive(Debug)]
pub struct SimRobot {
    cpus: f64,
    noise: f64,
    seed: u64,
    now_ms: AtomicU64,
    state: Mutex<SimState>,
    events: broadcast::Sender<RobotEvent>,
    hanging: Notify,
}

impl SimRobot {
    /// `cpus` shared by `nodes`; `noise` is the relative amplitude of the
    /// per-sub-window noise (0.01 = ±1 %).
    pub fn new(cpus: f64, nodes: Vec<SimNode>, noise: f64, seed: u64) -> Arc<SimRobot> {
        Arc::new(SimRobot {
            cpus,
            noise,
            seed,
            now_ms: AtomicU64::new(1_700_000_000_000),
            state: Mutex::new(SimState {
                nodes,
                stopped: BTreeSet::new(),
                frozen: BTreeSet::new(),
                recording: BTreeMap::new(),
                config: ResourceConfig::default(),
                applied: Vec::new(),
                measures: 0,
                hang_at: None,
            }),
            events: broadcast::channel(256).0,
            hanging: Notify::new(),
        })
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, SimState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Stop an app before any runner starts (no event).
    pub fn set_stopped(&self, app: &str, stopped: bool) {
        let mut s = self.lock();
        if stopped {
            s.stopped.insert(app.into());
        } else {
            s.stopped.remove(app);
        }
    }

    /// Change a node's model at run time (a heavier workload, a new rate).
    pub fn update_node(&self, name: &str, f: impl FnOnce(&mut SimNode)) {
        if let Some(n) = self.lock().nodes.iter_mut().find(|n| n.name == name) {
            f(n);
        }
    }

    /// Every config applied so far.
    pub fn applied(&self) -> Vec<ResourceConfig> {
        self.lock().applied.iter().map(|a| a.1.clone()).collect()
    }

    /// Every config applied so far with the simulated time it was applied at.
    pub fn applied_at(&self) -> Vec<(u64, ResourceConfig)> {
        self.lock().applied.clone()
    }

    /// The config applied now.
    pub fn config(&self) -> ResourceConfig {
        self.lock().config.clone()
    }

    /// Measure calls so far.
    pub fn measures(&self) -> u64 {
        self.lock().measures
    }

    /// The `n`-th measure call from now (1-based) never returns (a controller
    /// "killed" mid-trial); [`SimRobot::hung`] resolves when it is reached.
    pub fn hang_at_measure(&self, n: u64) {
        let mut s = self.lock();
        s.hang_at = Some(s.measures + n);
    }

    /// Resolves once a measure call hangs.
    pub async fn hung(&self) {
        self.hanging.notified().await
    }

    /// Clear a hang for the next runner.
    pub fn clear_hang(&self) {
        self.lock().hang_at = None;
    }

    /// Steady state under the current config.
    pub fn rates(&self) -> SimRates {
        let s = self.lock();
        let idle: BTreeSet<String> = s.stopped.union(&s.frozen).cloned().collect();
        model(&s.nodes, &idle, &s.config, self.cpus)
    }

    /// Apps frozen now.
    pub fn frozen(&self) -> BTreeSet<String> {
        self.lock().frozen.clone()
    }

    /// Recordings running now: name → topics.
    pub fn recordings(&self) -> BTreeMap<String, Vec<String>> {
        self.lock().recording.clone()
    }

    fn running(s: &SimState) -> impl Iterator<Item = &SimNode> {
        s.nodes.iter().filter(|n| !s.stopped.contains(&n.app))
    }

    /// A simulated node's pid: 1000 + its index in the stack.
    fn pid_of(s: &SimState, node: &str) -> Option<u32> {
        let i = s.nodes.iter().position(|n| n.name == node)?;
        u32::try_from(i).ok().map(|i| 1000 + i)
    }

    fn graph_now(&self) -> Graph {
        let s = self.lock();
        let mut g = Graph::default();
        for n in Self::running(&s) {
            g.nodes.insert(
                n.name.clone(),
                NodeInfo {
                    name: n.name.clone(),
                    uri: format!("sim://{}", n.name),
                    pid: Self::pid_of(&s, &n.name),
                },
            );
            if let Some(p) = &n.publishes {
                topic_entry(&mut g, p).publishers.insert(n.name.clone());
            }
            for i in &n.inputs {
                topic_entry(&mut g, &i.topic)
                    .subscribers
                    .insert(n.name.clone());
            }
        }
        g
    }

    fn noise(&self, t_ms: u64, probe: usize) -> f64 {
        let mut h = self.seed ^ t_ms.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (probe as u64) << 48;
        h ^= h >> 33;
        h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
        h ^= h >> 33;
        h = h.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
        h ^= h >> 33;
        let u = (h >> 11) as f64 / (1u64 << 53) as f64; // 0..1
        1.0 + self.noise * (2.0 * u - 1.0)
    }

    /// A frozen app keeps its nodes in the graph but does no work.
    fn set_frozen(&self, app: &str, frozen: bool) -> Result<(), RobotError> {
        let mut s = self.lock();
        if !s.nodes.iter().any(|n| n.app == app) {
            let op = if frozen { "freeze_app" } else { "thaw_app" };
            return Err(RobotError::new(op, format!("unknown app {app}")));
        }
        if frozen {
            s.frozen.insert(app.into());
        } else {
            s.frozen.remove(app);
        }
        Ok(())
    }

    fn set_app(&self, app: &str, stopped: bool) -> Result<(), RobotError> {
        let op = if stopped { "stop_app" } else { "start_app" };
        let before = self.graph_now();
        {
            let mut s = self.lock();
            if !s.nodes.iter().any(|n| n.app == app) {
                return Err(RobotError::new(op, format!("no app {app:?} in the stack")));
            }
            if stopped {
                s.stopped.insert(app.into());
            } else {
                s.stopped.remove(app);
            }
        }
        let after = self.graph_now();
        let at = self.now_ms();
        if !stopped {
            let started: Vec<(u32, String)> = {
                let s = self.lock();
                s.nodes
                    .iter()
                    .filter(|n| n.app == app)
                    .filter_map(|n| Some((Self::pid_of(&s, &n.name)?, n.name.clone())))
                    .collect()
            };
            for (pid, name) in started {
                let _ = self.events.send(RobotEvent::ProcessExec {
                    pid,
                    comm: Some(name.trim_start_matches('/').chars().take(15).collect()),
                    at_unix_ms: at,
                });
            }
        }
        let _ = self.events.send(RobotEvent::GraphChanged {
            events: before.diff(&after),
        });
        let _ = self.events.send(if stopped {
            RobotEvent::AppStopped { app: app.into() }
        } else {
            RobotEvent::AppStarted { app: app.into() }
        });
        Ok(())
    }
}

/// Weighted water-filling of `capacity` among caps.
fn share(caps: &[f64], weights: &[f64], capacity: f64) -> Vec<f64> {
    let mut alloc = vec![0.0; caps.len()];
    let mut active: Vec<usize> = (0..caps.len()).filter(|&i| caps[i] > 0.0).collect();
    let mut remaining = capacity;
    while !active.is_empty() {
        let wsum: f64 = active.iter().map(|&i| weights[i]).sum();
        let per = remaining / wsum;
        let (sat, unsat): (Vec<usize>, Vec<usize>) =
            active.iter().partition(|&&i| caps[i] <= weights[i] * per);
        if sat.is_empty() {
            for &i in &unsat {
                alloc[i] = weights[i] * per;
            }
            break;
        }
        for &i in &sat {
            alloc[i] = caps[i];
            remaining -= caps[i];
        }
        active = unsat;
    }
    alloc
}

/// The steady state of `nodes` (minus stopped apps) under `cfg` on `cpus`.
pub fn model(
    nodes: &[SimNode],
    stopped: &BTreeSet<String>,
    cfg: &ResourceConfig,
    cpus: f64,
) -> SimRates {
    let nodes: Vec<&SimNode> = nodes.iter().filter(|n| !stopped.contains(&n.app)).collect();
    let n = nodes.len();
    let mut frac = vec![1.0f64; n];
    let mut out = SimRates::default();
    let adaptor = |topic: &str, sub: &str| {
        cfg.adaptors
            .iter()
            .find(|a| a.topic == topic && a.subscriber == sub)
            .map_or(f64::INFINITY, |a| a.rate_hz)
    };
    for _ in 0..80 {
        let mut topics: BTreeMap<String, f64> = BTreeMap::new();
        // Output rates from the current fractions (sources first, then one pass per depth).
        for _ in 0..n.max(1) {
            for (i, node) in nodes.iter().enumerate() {
                let base = match node.timer_hz {
                    Some(hz) => hz,
                    None => node.inputs.first().map_or(0.0, |inp| {
                        topics
                            .get(&inp.topic)
                            .copied()
                            .unwrap_or(0.0)
                            .min(adaptor(&inp.topic, &node.name))
                    }),
                };
                if let Some(p) = &node.publishes {
                    topics.insert(p.clone(), base * frac[i]);
                }
            }
        }
        let delivered =
            |t: &str, sub: &str| topics.get(t).copied().unwrap_or(0.0).min(adaptor(t, sub));
        let demand: Vec<f64> = nodes
            .iter()
            .map(|node| {
                node.timer_hz.unwrap_or(0.0) * node.cycle_cost
                    + node
                        .inputs
                        .iter()
                        .map(|i| delivered(&i.topic, &node.name) * i.cost)
                        .sum::<f64>()
            })
            .collect();
        let caps: Vec<f64> = nodes
            .iter()
            .zip(&demand)
            .map(|(node, d)| {
                d.min(node.threads)
                    .min(cfg.cpu.get(&node.name).copied().unwrap_or(f64::INFINITY))
            })
            .collect();
        // A node's cgroup weight (100 by default) scales its threads' share.
        let weights: Vec<f64> = nodes
            .iter()
            .map(|n| {
                n.threads * f64::from(cfg.cpu_weight.get(&n.name).copied().unwrap_or(100)) / 100.0
            })
            .collect();
        let alloc = share(&caps, &weights, cpus);
        for i in 0..n {
            let f = if demand[i] > 0.0 {
                (alloc[i] / demand[i]).min(1.0)
            } else {
                1.0
            };
            frac[i] = 0.5 * frac[i] + 0.5 * f;
        }
        out.delivered = nodes
            .iter()
            .flat_map(|node| {
                node.inputs.iter().map(|i| {
                    (
                        (i.topic.clone(), node.name.clone()),
                        delivered(&i.topic, &node.name),
                    )
                })
            })
            .collect();
        out.cpu = nodes
            .iter()
            .zip(&alloc)
            .map(|(n, a)| (n.name.clone(), *a))
            .collect();
        out.topics = topics;
    }
    out
}

impl Clock for SimRobot {
    fn now_ms(&self) -> u64 {
        self.now_ms.load(Ordering::SeqCst)
    }

    fn sleep(&self, d: Duration) -> BoxFuture<'_, ()> {
        self.now_ms
            .fetch_add(d.as_millis() as u64, Ordering::SeqCst);
        Box::pin(tokio::task::yield_now())
    }
}

impl NodeApi for SimRobot {
    type Error = RobotError;

    fn apply<'a>(&'a self, cfg: &'a ResourceConfig) -> BoxFuture<'a, Result<(), RobotError>> {
        Box::pin(async move {
            if cfg.cpu.values().any(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(RobotError::new(
                    "apply",
                    format!("invalid CPU limit in {cfg:?}"),
                ));
            }
            let at = self.now_ms();
            let mut s = self.lock();
            s.config = cfg.clone();
            s.applied.push((at, cfg.clone()));
            Ok(())
        })
    }

    fn measure<'a>(
        &'a self,
        req: &'a MeasureRequest,
    ) -> BoxFuture<'a, Result<MeasureReport, RobotError>> {
        Box::pin(async move {
            // Yield before the window "passes": a caller racing this against
            // events sees events that are already there first.
            tokio::task::yield_now().await;
            let hang = {
                let mut s = self.lock();
                s.measures += 1;
                s.hang_at == Some(s.measures)
            };
            if hang {
                self.hanging.notify_one();
                std::future::pending::<()>().await;
            }
            let sub = req.sub_window_ms.max(1);
            let windows = (req.duration_ms / sub).max(1);
            let rates = self.rates();
            let start = self.now_ms.fetch_add(windows * sub, Ordering::SeqCst);
            let series = req
                .probes
                .iter()
                .enumerate()
                .map(|(pi, p)| {
                    let steady = match p {
                        Probe::TopicRate {
                            topic,
                            subscriber: None,
                        } => rates.topics.get(topic).copied().unwrap_or(0.0),
                        Probe::TopicRate {
                            topic,
                            subscriber: Some(s),
                        } => rates
                            .delivered
                            .get(&(topic.clone(), s.clone()))
                            .copied()
                            .unwrap_or(0.0),
                        Probe::CpuUsage { node } => rates.cpu.get(node).copied().unwrap_or(0.0),
                        // This robot's messages carry no stamps: never late.
                        Probe::TopicLatency { .. } => 0.0,
                    };
                    let values: Vec<f64> = (0..windows)
                        .map(|w| steady * self.noise(start + w * sub, pi))
                        .collect();
                    let mean = values.iter().sum::<f64>() / values.len() as f64;
                    ProbeSeries {
                        probe: p.clone(),
                        values,
                        mean,
                    }
                })
                .collect();
            Ok(MeasureReport {
                started_unix_ms: start,
                duration_ms: windows * sub,
                sub_window_ms: sub,
                series,
            })
        })
    }

    fn graph(&self) -> BoxFuture<'_, Result<Graph, RobotError>> {
        Box::pin(async move { Ok(self.graph_now()) })
    }

    fn stop_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), RobotError>> {
        Box::pin(async move { self.set_app(app, true) })
    }

    fn start_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), RobotError>> {
        Box::pin(async move { self.set_app(app, false) })
    }

    fn freeze_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), RobotError>> {
        Box::pin(async move { self.set_frozen(app, true) })
    }

    fn thaw_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), RobotError>> {
        Box::pin(async move { self.set_frozen(app, false) })
    }

    fn start_recording<'a>(
        &'a self,
        name: &'a str,
        topics: &'a [String],
    ) -> BoxFuture<'a, Result<Option<PathBuf>, RobotError>> {
        Box::pin(async move {
            if topics.is_empty() {
                return Ok(None);
            }
            self.lock().recording.insert(name.into(), topics.to_vec());
            Ok(Some(bag(name)))
        })
    }

    fn stop_recording<'a>(
        &'a self,
        name: &'a str,
    ) -> BoxFuture<'a, Result<Option<PathBuf>, RobotError>> {
        Box::pin(async move {
            let was = self.lock().recording.remove(name);
            Ok(was.map(|_| bag(name)))
        })
    }

    /// The simulated stack is fixed: a stack change does nothing.
    fn set_stack<'a>(
        &'a self,
        _stack: Option<&'a RobotStack>,
    ) -> BoxFuture<'a, Result<(), RobotError>> {
        Box::pin(async { Ok(()) })
    }
}

impl Robot for SimRobot {
    fn events(&self) -> broadcast::Receiver<RobotEvent> {
        self.events.subscribe()
    }
}

/// The path the simulated robot gives the recording `name`.
fn bag(name: &str) -> PathBuf {
    PathBuf::from(format!("sim://{name}.bag"))
}

fn topic_entry<'a>(g: &'a mut Graph, t: &str) -> &'a mut TopicInfo {
    g.topics.entry(t.to_string()).or_insert_with(|| TopicInfo {
        name: t.into(),
        msg_type: "sim/Msg".into(),
        publishers: BTreeSet::new(),
        subscribers: BTreeSet::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn busy(name: &str) -> SimNode {
        SimNode {
            name: name.into(),
            app: name.into(),
            threads: 1.0,
            timer_hz: Some(100.0),
            cycle_cost: 0.02,
            inputs: Vec::new(),
            publishes: Some(format!("{name}/out")),
        }
    }

    #[test]
    fn a_heavier_cgroup_weight_takes_more_of_a_contended_cpu() {
        // Two loops that want 2 CPUs each on 1 CPU.
        let nodes = [busy("/a"), busy("/b")];
        let idle = BTreeSet::new();
        let even = model(&nodes, &idle, &ResourceConfig::default(), 1.0);
        assert!((even.cpu["/a"] - 0.5).abs() < 1e-9, "{even:?}");
        let cfg = ResourceConfig {
            cpu_weight: [("/a".to_string(), 900)].into(),
            ..ResourceConfig::default()
        };
        let weighted = model(&nodes, &idle, &cfg, 1.0);
        assert!((weighted.cpu["/a"] - 0.9).abs() < 1e-9, "{weighted:?}");
        assert!((weighted.cpu["/b"] - 0.1).abs() < 1e-9, "{weighted:?}");
    }
}
