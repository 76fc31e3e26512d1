//! The live part of the Fig. 7 timeline: drives the context switch on a
//! fresh robot (apply, delete, wait until the switched stack runs) while two
//! background loops record what happened — [`record`] measures the core
//! metric per second without a gap, [`watch`] polls the specs' status and
//! events every [`WATCH`]. The moments are then computed from that record by
//! the pure functions of the parent module.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use configbot_api::measure::MeasureReport;
use configbot_manifests::{Kind, PerformanceSpecStatus, decode_status};
use configbot_tuning::status::TUNED;
use hyper::Method;

use super::{Sample, SeenEvent, Switch, Timeline, chart, moments, seconds, segments};
use crate::bench::owner::Current;
use crate::bench::{self, BenchArgs, Plan, example_for, follow, outcome, start};
use crate::demo::{PrivateRobot, measure_defs};
use configbot_controller::robot::EmbeddedRobot;
use configbot_controller::store::Store;
use configbot_controller::tuning::robot::NodeApi;
use configbot_tuning::measure::{self, MetricDef};

/// Status and event poll interval of [`watch`].
pub const WATCH: Duration = Duration::from_millis(100);

fn now_ms() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

/// Measures `defs` in back-to-back 5 s runs of 1 s windows until `stop`.
async fn record(
    robot: Arc<EmbeddedRobot>,
    defs: Vec<MetricDef>,
    stop: Arc<AtomicBool>,
) -> Vec<MeasureReport> {
    let mut out = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        match measure_defs(robot.as_ref(), &defs, 5).await {
            Ok(r) => out.push(r),
            Err(e) => {
                eprintln!("configbot bench: timeline measurement: {e}");
                tokio::time::sleep(Duration::from_secs(1)).await;
            }
        }
    }
    out
}

/// Polls `specs`' status and events every [`WATCH`] until `stop`; keeps a
/// sample when a spec's status changed and each event once.
async fn watch(
    store: Arc<Store>,
    specs: Vec<String>,
    t0_ms: u64,
    stop: Arc<AtomicBool>,
) -> (Vec<Sample>, Vec<SeenEvent>) {
    let mut samples: Vec<Sample> = Vec::new();
    let mut events = Vec::new();
    let mut last: BTreeMap<String, Sample> = BTreeMap::new();
    let mut last_event = 0i64;
    while !stop.load(Ordering::Relaxed) {
        let t = (now_ms().saturating_sub(t0_ms)) as f64 / 1000.0;
        for name in &specs {
            let Ok(Some(o)) = store.get(Kind::PerformanceSpec, "default", name) else {
                continue;
            };
            let Ok(st) = decode_status::<PerformanceSpecStatus>(&o) else {
                continue;
            };
            let s = Sample {
                t,
                spec: name.clone(),
                uid: o["metadata"]["uid"].as_str().unwrap_or("").into(),
                settled: outcome(&st),
                tuned_reason: st
                    .conditions
                    .iter()
                    .find(|c| c.type_ == TUNED)
                    .map(|c| c.reason.clone()),
                trials: st.trials,
                phase: st.phase,
                context: st.context,
            };
            let changed = last.get(name).is_none_or(|p| {
                Sample {
                    t: p.t,
                    ..s.clone()
                } != *p
            });
            if changed {
                last.insert(name.clone(), s.clone());
                samples.push(s);
            }
        }
        if let Ok(evs) = store.events(Some("default"), None, None) {
            let seen = last_event;
            for e in evs.into_iter().filter(|e| e.id > seen) {
                last_event = e.id;
                if specs.contains(&e.name) {
                    events.push(SeenEvent {
                        t,
                        spec: e.name,
                        reason: e.reason,
                        message: e.message,
                    });
                }
            }
        }
        tokio::time::sleep(WATCH).await;
    }
    (samples, events)
}

async fn delete(robot: &PrivateRobot, kind: Kind, name: &str) -> anyhow::Result<()> {
    let path = crate::client::path(kind, Some("default"), Some(name));
    robot
        .client
        .send(Method::DELETE, &path, None, "application/json")
        .await?;
    Ok(())
}

/// How long a switched stack's core topics may stay silent before the
/// timeline goes on anyway (and says so in `notes`).
const SWITCH_FLOW: Duration = Duration::from_secs(20);

/// Waits until the robot runs `stack` — the agent has its nodes, each is in
/// the ROS graph, and its core topics flow (at most [`SWITCH_FLOW`]) — as a
/// user switching stacks would before applying the new stack's spec.
/// Returns a note when core topics stayed silent.
async fn wait_for_stack(
    robot: &PrivateRobot,
    stack: &configbot_manifests::RobotStack,
    defs: &[MetricDef],
) -> anyhow::Result<Option<String>> {
    let want: std::collections::BTreeSet<String> =
        stack.spec.nodes().map(|(_, n)| n.name.clone()).collect();
    let deadline = Instant::now() + bench::FLOW_TIMEOUT;
    loop {
        let agent = robot.robot.runtime().agent().stack();
        let have: std::collections::BTreeSet<String> = configbot_agent::state::stack_nodes(&agent)
            .iter()
            .map(|n| n.as_str().to_string())
            .collect();
        let graph = robot.robot.graph().await?;
        if have == want && want.iter().all(|n| graph.nodes.contains_key(n)) {
            break;
        }
        anyhow::ensure!(
            Instant::now() < deadline,
            "the robot did not run {} within {} s",
            stack.metadata.name,
            bench::FLOW_TIMEOUT.as_secs()
        );
        tokio::time::sleep(WATCH).await;
    }
    let core: Vec<MetricDef> = defs.iter().filter(|d| d.core).cloned().collect();
    let silent = bench::wait_until_up(robot.robot.as_ref(), &core, SWITCH_FLOW).await;
    if silent.is_empty() {
        return Ok(None);
    }
    let note = format!(
        "{}: no messages on {} within {} s of the switch; its spec was applied anyway",
        stack.metadata.name,
        silent.join(", "),
        SWITCH_FLOW.as_secs()
    );
    println!("    {note}");
    Ok(Some(note))
}

/// Sets its flag when dropped: the spawned loops end with the run, also
/// when the run is cancelled.
struct StopOnDrop(Arc<AtomicBool>);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

/// Sleeps until `secs` after `t0`.
async fn until(t0: Instant, secs: f64) {
    let left = secs - t0.elapsed().as_secs_f64();
    if left > 0.0 {
        tokio::time::sleep(Duration::from_secs_f64(left)).await;
    }
}

/// Runs the context switch on a fresh robot.
pub async fn run(cur: &mut Current, a: &BenchArgs, p: &Plan) -> anyhow::Result<Timeline> {
    let (basic, mut basic_spec) = example_for("basic-nav", p)?;
    let (terrain, mut terrain_spec) = example_for("terrain-nav", p)?;
    if let Some(m) = p.timeline_trials {
        for s in [&mut basic_spec, &mut terrain_spec] {
            s.spec.tuning.max_trials = s.spec.tuning.max_trials.min(m);
        }
    }
    let defs = measure::metric_defs(&basic.spec, &basic_spec.spec);
    let core = defs
        .iter()
        .find(|d| d.core)
        .cloned()
        .ok_or_else(|| anyhow::anyhow!("basic-nav's spec has no core metric"))?;
    println!(
        "==> timeline: basic-nav, then terrain-nav at t ≈ {} s, then basic-nav again",
        p.switch_at
    );
    let robot = start(cur, &a.out, "timeline", "robot", &basic, &defs).await?;
    let stop = Arc::new(AtomicBool::new(false));
    // The recorder and watcher stop too when the bench is interrupted (this
    // future dropped).
    let _stop_on_drop = StopOnDrop(stop.clone());
    let t0 = Instant::now();
    let t0_ms = now_ms();
    let recorder = tokio::spawn(record(robot.robot.clone(), defs.clone(), stop.clone()));
    let watcher = tokio::spawn(watch(
        robot.server.state.store.clone(),
        vec![
            basic_spec.metadata.name.clone(),
            terrain_spec.metadata.name.clone(),
        ],
        t0_ms,
        stop.clone(),
    ));
    let timeout = Duration::from_secs(a.timeout_secs);
    let scenario = async {
        let since = |i: Instant| i.duration_since(t0).as_secs_f64();
        let basic_json = serde_json::to_value(&basic_spec)?;
        robot.apply(&basic_json, Kind::PerformanceSpec).await?;
        let s = follow(robot, &basic_spec.metadata.name, t0, timeout)
            .await?
            .settled_secs(&basic_spec.metadata.name)?;
        until(t0, (p.switch_at as f64).max(s + p.hold as f64)).await;

        println!("==> timeline: switching the robot to terrain-nav");
        let at = Instant::now();
        delete(robot, Kind::PerformanceSpec, &basic_spec.metadata.name).await?;
        robot
            .apply(&serde_json::to_value(&terrain)?, Kind::RobotStack)
            .await?;
        let mut notes: Vec<String> = Vec::new();
        notes.extend(wait_for_stack(robot, &terrain, &defs).await?);
        let up = Instant::now();
        robot
            .apply(&serde_json::to_value(&terrain_spec)?, Kind::PerformanceSpec)
            .await?;
        let sw1 = Switch {
            at: since(at),
            stack_up: since(up),
            spec_applied: since(Instant::now()),
        };
        let s = follow(robot, &terrain_spec.metadata.name, at, timeout)
            .await?
            .settled_secs(&terrain_spec.metadata.name)?;
        until(at, s + p.hold as f64).await;

        println!("==> timeline: switching the robot back to basic-nav");
        let at = Instant::now();
        delete(robot, Kind::PerformanceSpec, &terrain_spec.metadata.name).await?;
        delete(robot, Kind::RobotStack, &terrain.metadata.name).await?;
        notes.extend(wait_for_stack(robot, &basic, &defs).await?);
        let up = Instant::now();
        robot.apply(&basic_json, Kind::PerformanceSpec).await?;
        let sw2 = Switch {
            at: since(at),
            stack_up: since(up),
            spec_applied: since(Instant::now()),
        };
        let s = follow(robot, &basic_spec.metadata.name, at, timeout)
            .await?
            .settled_secs(&basic_spec.metadata.name)?;
        until(at, s + p.hold as f64).await;
        anyhow::Ok((sw1, sw2, notes))
    }
    .await;
    stop.store(true, Ordering::Relaxed);
    let (recorded, watched) = (recorder.await, watcher.await);
    cur.close().await?;
    let (sw1, sw2, notes) = scenario?;
    let reports = recorded?;
    let (samples, events) = watched?;
    let secs = seconds(&reports, &core, &defs, t0_ms);
    let start = Switch {
        at: 0.0,
        stack_up: 0.0,
        spec_applied: 0.0,
    };
    let initial = moments(&samples, &events, &basic_spec.metadata.name, start);
    let to_terrain = moments(&samples, &events, &terrain_spec.metadata.name, sw1);
    let back = moments(&samples, &events, &basic_spec.metadata.name, sw2);
    let mut cuts = vec![("basic-nav: tuning".to_string(), 0.0)];
    let mut cut = |label: &str, t: Option<f64>| {
        if let Some(t) = t {
            cuts.push((label.to_string(), t));
        }
    };
    cut("basic-nav: tuned", initial.applied);
    cut("terrain-nav: switching, tuning", Some(sw1.at));
    cut("terrain-nav: tuned", to_terrain.applied);
    cut("basic-nav again: switching", Some(sw2.at));
    cut("basic-nav again: settled", back.applied);
    let svg = a.out.join("timeline.svg");
    let t = Timeline {
        core_metric: core.name.clone(),
        target: core.target,
        initial,
        to_terrain,
        back_to_basic: back,
        segments: segments(&secs, &cuts),
        seconds: secs,
        samples,
        events,
        notes,
        svg: svg.display().to_string(),
    };
    std::fs::write(&svg, chart(&t).to_svg())?;
    Ok(t)
}
