//! The tuning runner end to end against the simulated robot (simulated time,
//! so each scenario takes seconds): a violating default reaches Satisfied with
//! ≥ 99 % steady-state satisfaction; an impossible spec ends Unsat naming the
//! constraint and the best value; a run killed mid-trial resumes without
//! repeating finished trials; a familiar context re-applies its library config
//! without trials; remediation stops the non-core app and restores the core
//! constraint, and its undo restarts it.

use std::sync::Arc;
use std::time::Duration;

use configbot_controller::metrics::Metrics;
use configbot_controller::store::Store;
use configbot_controller::tuning::robot::NodeApi;
use configbot_controller::tuning::runner::{self, RunnerCtx};
use configbot_controller::tuning::sim::SimRobot;
use configbot_manifests::Kind;
use configbot_test_support::{try_wait_until_async, wait_until_async};
use configbot_tuning::machine::{Remedy, State};
use serde_json::{Value, json};

/// How often the tests' condition waits look.
const POLL: Duration = Duration::from_millis(20);

mod fixture;
use fixture::{sim, spec, stack};

struct Fixture {
    dir: tempfile::TempDir,
    store: Arc<Store>,
    sim: Arc<SimRobot>,
    metrics: Arc<Metrics>,
}

impl Fixture {
    fn new(spec: Value) -> Fixture {
        let dir = tempfile::tempdir().unwrap();
        let store = Arc::new(Store::open(&dir.path().join("db.sqlite")).unwrap());
        store.put(Kind::RobotStack, stack(), true).unwrap();
        store.put(Kind::PerformanceSpec, spec, true).unwrap();
        Fixture {
            dir,
            store,
            sim: sim(7),
            metrics: Arc::new(Metrics::new()),
        }
    }

    fn ctx(&self) -> RunnerCtx {
        RunnerCtx {
            robot: self.sim.clone(),
            clock: self.sim.clone(),
            store: self.store.clone(),
            metrics: self.metrics.clone(),
        }
    }

    fn spawn(&self) -> tokio::task::JoinHandle<()> {
        tokio::spawn(runner::run_spec(
            self.ctx(),
            "default".into(),
            "nav-spec".into(),
        ))
    }

    fn status(&self) -> Value {
        self.store
            .get(Kind::PerformanceSpec, "default", "nav-spec")
            .unwrap()
            .unwrap()["status"]
            .clone()
    }

    fn run(&self) -> configbot_tuning::machine::Run {
        runner::load_run(&self.store, "default", "nav-spec")
            .unwrap()
            .unwrap()
    }

    fn events(&self) -> Vec<(String, String)> {
        self.store
            .events(None, Some("PerformanceSpec"), Some("nav-spec"))
            .unwrap()
            .into_iter()
            .map(|e| (e.reason.to_string(), e.message))
            .collect()
    }

    /// Wait (real time, with a timeout) until `f` holds on the persisted run.
    async fn until(&self, what: &str, f: impl Fn(&configbot_tuning::machine::Run) -> bool) {
        let held = async || {
            runner::load_run(&self.store, "default", "nav-spec")
                .ok()
                .flatten()
                .is_some_and(|r| f(&r))
        };
        try_wait_until_async(what, Duration::from_secs(240), POLL, held)
            .await
            .unwrap_or_else(|e| panic!("{e}; events: {:#?}", self.events()));
    }
}

fn monitoring(r: &configbot_tuning::machine::Run, windows: u64) -> bool {
    matches!(
        r.state,
        State::Monitor {
            satisfied: true,
            ..
        }
    ) && r.monitor.windows >= windows
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn violating_default_reaches_satisfied_with_99_percent_in_steady_state() {
    let f = Fixture::new(spec(35.0, 15, json!({})));
    let h = f.spawn();
    f.until("steady-state monitoring", |r| monitoring(r, 60))
        .await;
    h.abort();
    let run = f.run();
    let base = run.baseline.as_ref().unwrap();
    assert!(
        base.eval.satisfaction < 0.5,
        "the default config violates: {:?}",
        base.eval
    );
    let steady = run.monitor.satisfaction().unwrap();
    let best_i = f.status()["bestTrial"].as_u64().unwrap() as usize;
    eprintln!(
        "baseline satisfaction {:.3} (cmd-vel {:.1} Hz); {} trials; best trial {best_i}: {:?} objective {:?}; steady-state satisfaction {steady:.3} over {} windows",
        base.eval.satisfaction,
        base.eval.means["cmd-vel"],
        run.trials.len(),
        run.trials[best_i].config,
        run.trials[best_i].eval.objective,
        run.monitor.windows
    );
    assert!(steady >= 0.99, "steady-state satisfaction {steady}");
    let st = f.status();
    assert_eq!(st["phase"], "Monitoring");
    assert!(st["satisfaction"].as_f64().unwrap() >= 0.99);
    assert!(st["trials"].as_u64().unwrap() >= 1);
    assert_eq!(
        st["knobs"].as_array().unwrap().len(),
        3,
        "cpu of /camera and /detector, adaptor /image>/detector: {}",
        st["knobs"]
    );
    let tuned = st["conditions"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["type"] == "Tuned")
        .unwrap();
    assert_eq!(tuned["status"], "True");
    let best = st["bestTrial"].as_u64().unwrap() as usize;
    assert!(st["trialHistory"][best]["feasible"].as_bool().unwrap());
    assert!(st["nonCorePerformance"]["detections"].as_f64().unwrap() > 1.0);
    // The learned config went to the library as a ConfigProfile.
    let (profiles, _) = f.store.list(Kind::ConfigProfile, None).unwrap();
    assert_eq!(profiles.len(), 1);
    let reasons: Vec<String> = f.events().into_iter().map(|e| e.0).collect();
    for r in ["Baseline", "Trial", "Satisfied", "ProfileSaved"] {
        assert!(reasons.iter().any(|x| x == r), "event {r} in {reasons:?}");
    }
    assert!(f.metrics.render().contains("configbot_tuning_satisfaction"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_context_change_during_trials_starts_the_run_over_for_the_new_context() {
    let f = Fixture::new(spec(35.0, 15, json!({})));
    let h = f.spawn();
    f.until("a trial of the first context", |r| {
        r.trials.len() >= 2 && r.phase() == configbot_manifests::Phase::Tuning
    })
    .await;
    f.sim.stop_app("det").await.unwrap();
    f.until("monitoring the nav-only context", |r| {
        monitoring(r, 3) && r.context.as_ref().is_some_and(|c| c.apps == ["nav"])
    })
    .await;
    h.abort();
    let events = f.events();
    let restart = events
        .iter()
        .position(|(r, m)| r == "ContextChanged" && m.contains("starts over"))
        .unwrap_or_else(|| panic!("{events:#?}"));
    let trials_before = events[..restart]
        .iter()
        .filter(|(r, _)| r == "Trial")
        .count();
    assert!(
        (2..15).contains(&trials_before),
        "the run stopped its trials at the change, before its budget of 15: {events:#?}"
    );
    assert!(
        !events[..restart].iter().any(|(r, _)| r == "Satisfied"),
        "no config of the old context was verified: {events:#?}"
    );
    assert!(f.run().trials.is_empty(), "nothing to tune without det");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn impossible_spec_ends_unsat_naming_constraint_and_best_value() {
    // The planner's loop runs at 40 Hz: 45 Hz is impossible.
    let f = Fixture::new(spec(45.0, 6, json!({})));
    let h = f.spawn();
    f.until("unsat", |r| {
        matches!(
            r.state,
            State::Monitor {
                satisfied: false,
                ..
            }
        )
    })
    .await;
    h.abort();
    let st = f.status();
    assert_eq!(st["phase"], "Unsat");
    let reason = st["reason"].as_str().unwrap();
    assert!(
        reason.contains("constraint cmd-vel (>= 45) was not met"),
        "{reason}"
    );
    let best: f64 = reason
        .split("best value reached ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .unwrap()
        .parse()
        .unwrap();
    assert!(
        (38.0..=40.5).contains(&best),
        "best value {best} in: {reason}"
    );
    assert!(reason.contains("relax the target to at most"), "{reason}");
    let ready = st["conditions"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["type"] == "Ready")
        .unwrap();
    assert_eq!(ready["status"], "False");
    assert_eq!(ready["reason"], "Unsat");
    assert!(f.events().iter().any(|(r, _)| r == "Unsat"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn killed_mid_run_resumes_without_repeating_finished_trials() {
    let f = Fixture::new(spec(35.0, 10, json!({"settleSeconds": 0})));
    // Baseline is measure 1; trials take one or two measures each: measure 12 is mid-run.
    f.sim.hang_at_measure(12);
    let h = f.spawn();
    tokio::time::timeout(Duration::from_secs(120), f.sim.hung())
        .await
        .expect("the run reaches the hanging measure");
    h.abort();
    let _ = h.await;
    let before = f.run();
    let k = before.trials.len();
    assert!(k >= 3, "some trials finished before the kill: {k}");
    let State::TrialProfile {
        config: interrupted,
        ..
    } = before.state.clone()
    else {
        panic!("killed while profiling a trial, got {:?}", before.state)
    };
    // A new controller on the same database.
    f.sim.clear_hang();
    let store2 = Arc::new(Store::open(&f.dir.path().join("db.sqlite")).unwrap());
    let ctx = RunnerCtx {
        store: store2.clone(),
        ..f.ctx()
    };
    let h = tokio::spawn(runner::run_spec(ctx, "default".into(), "nav-spec".into()));
    f.until("the resumed run to finish", |r| {
        matches!(r.state, State::Monitor { .. })
    })
    .await;
    h.abort();
    let after = f.run();
    assert_eq!(
        &after.trials[..k],
        &before.trials[..],
        "finished trials are kept exactly"
    );
    assert_eq!(
        after.trials[k].config, interrupted,
        "the interrupted trial is the first one measured after the restart"
    );
    for t in &after.trials[k + 1..] {
        assert!(
            !before.trials.iter().any(|b| b.config == t.config),
            "a finished trial was repeated: {:?}",
            t.config
        );
    }
    assert_eq!(after.trials.len(), 10);
    assert!(f.events().iter().any(|(r, _)| r == "Resumed"));
}

// Single-threaded: the runner and the test interleave only at await points,
// so the app start lands while the runner waits in its monitor (as on a real robot).
#[tokio::test]
async fn familiar_context_reapplies_library_config_without_trials() {
    let f = Fixture::new(spec(35.0, 10, json!({})));
    let h = f.spawn();
    f.until("first tuning", |r| monitoring(r, 5)).await;
    let learned = f.run().state.clone();
    let State::Monitor {
        config: learned, ..
    } = learned
    else {
        unreachable!()
    };
    // The non-core app stops: a new context (nothing to tune, the baseline holds).
    f.sim.stop_app("det").await.unwrap();
    f.until("the nav-only context", |r| {
        monitoring(r, 5) && r.context.as_ref().is_some_and(|c| c.apps == ["nav"])
    })
    .await;
    assert!(f.run().trials.is_empty());
    // Back to the familiar context: the library config, at once, without trials.
    let applies_before = f.sim.applied().len();
    let t0 = configbot_controller::tuning::robot::Clock::now_ms(&*f.sim);
    f.sim.start_app("det").await.unwrap();
    f.until("the familiar context", |r| {
        monitoring(r, 5) && r.context.as_ref().is_some_and(|c| c.apps.len() == 2)
    })
    .await;
    h.abort();
    let applied = f.sim.applied();
    assert_eq!(
        &applied[applies_before..],
        std::slice::from_ref(&learned),
        "exactly one apply: the learned config"
    );
    let run = f.run();
    assert!(run.trials.is_empty(), "no trials in a familiar context");
    assert_eq!(run.library_hits, 1);
    let st = f.status();
    let tuned = st["conditions"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["type"] == "Tuned")
        .unwrap()
        .clone();
    assert_eq!(tuned["reason"], "LibraryConfig");
    assert!(st["satisfaction"].as_f64().unwrap() >= 0.99);
    let events = f.events();
    let hit = events.iter().position(|(r, _)| r == "LibraryHit").unwrap();
    assert!(
        events[..hit].iter().any(|(r, m)| r == "ContextChanged"
            && m.contains("det")
            && m.contains("process exec")
            && m.contains(" 0 ms after its process exec")),
        "{events:#?}"
    );
    // Simulated time from the app start to the re-apply: under 2 s.
    let (at, _) = f.sim.applied_at().last().cloned().unwrap();
    assert!(
        at - t0 < 2000,
        "re-applied {} ms after the app started",
        at - t0
    );
}

/// A spec the task executive forbids tuning for (annotation), with this
/// `remediation` section; its runner is running and has reached
/// Remediating with ten windows measured.
async fn remediating(remediation: Value) -> (Fixture, tokio::task::JoinHandle<()>) {
    let mut s = spec(35.0, 4, json!({}));
    s["metadata"]["annotations"] = json!({"configbot.dev/tuning-allowed": "false"});
    s["spec"]["remediation"] = remediation;
    let f = Fixture::new(s);
    let h = f.spawn();
    f.until("remediation", |r| {
        matches!(r.state, State::Remediating { .. }) && r.monitor.windows >= 10
    })
    .await;
    (f, h)
}

impl Fixture {
    /// The task executive allows tuning again; waits for the relearned run.
    async fn allow_tuning(&self) {
        let mut obj = self
            .store
            .get(Kind::PerformanceSpec, "default", "nav-spec")
            .unwrap()
            .unwrap();
        obj["metadata"]["annotations"] = json!({});
        obj["metadata"]
            .as_object_mut()
            .unwrap()
            .remove("resourceVersion");
        self.store.put(Kind::PerformanceSpec, obj, false).unwrap();
        self.until("relearning after the undo", |r| {
            matches!(r.state, State::Monitor { .. })
        })
        .await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn remediation_stops_the_non_core_app_and_is_undone_when_tuning_is_allowed() {
    let (f, h) = remediating(json!({})).await;
    let run = f.run();
    assert_eq!(
        run.state,
        State::Remediating {
            remedy: Remedy {
                apps: vec!["det".into()],
                ..Remedy::default()
            }
        }
    );
    let g = f.sim.graph().await.unwrap();
    assert!(
        !g.nodes.contains_key("/detector"),
        "the non-core app is stopped"
    );
    assert!(
        run.monitor.satisfaction().unwrap() >= 0.99,
        "the core constraint is restored"
    );
    assert_eq!(f.status()["phase"], "Remediating");
    assert!(
        f.events()
            .iter()
            .any(|(r, m)| r == "Remediated" && m.contains("det"))
    );
    f.allow_tuning().await;
    h.abort();
    assert!(f.events().iter().any(|(r, _)| r == "RemediationUndone"));
    let g = f.sim.graph().await.unwrap();
    assert!(g.nodes.contains_key("/detector"), "restarted");
    assert!(
        f.metrics
            .render()
            .contains("configbot_tuning_remediations_total")
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn remediation_can_freeze_the_non_core_app_and_record_its_inputs() {
    let (f, h) = remediating(json!({"action": "FreezeNonCore", "recordRosbag": true})).await;
    let run = f.run();
    assert!(
        run.monitor.satisfaction().unwrap() >= 0.99,
        "the core constraint is restored"
    );
    assert_eq!(f.sim.frozen(), ["det".to_string()].into());
    let g = f.sim.graph().await.unwrap();
    assert!(g.nodes.contains_key("/detector"), "frozen, not stopped");
    assert_eq!(
        f.sim.recordings(),
        [("default.nav-spec".to_string(), vec!["/image".to_string()])].into()
    );
    let events = f.events();
    assert!(
        events.iter().any(|(r, m)| r == "RecordingInputs"
            && m.contains("/image")
            && m.contains("sim://default.nav-spec.bag")),
        "{events:#?}"
    );
    f.allow_tuning().await;
    h.abort();
    assert!(f.sim.frozen().is_empty(), "thawed");
    assert!(f.sim.recordings().is_empty(), "recording stopped");
    assert!(
        f.events().iter().any(|(r, m)| r == "RemediationUndone"
            && m.contains("thawed det")
            && m.contains("recorded to sim://default.nav-spec.bag")),
        "{:#?}",
        f.events()
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn server_with_a_robot_starts_a_runner_per_spec_and_stops_it_on_delete() {
    let dir = tempfile::tempdir().unwrap();
    let (server, _cfg) = fixture::serve(dir.path(), 11).await;
    let store = server.state.store.clone();
    let mut last = Value::Null;
    let monitoring =
        try_wait_until_async("Monitoring", Duration::from_secs(120), POLL, async || {
            last = store
                .get(Kind::PerformanceSpec, "default", "nav-spec")
                .unwrap()
                .unwrap();
            (last["status"]["phase"] == "Monitoring").then(|| last["status"].clone())
        })
        .await;
    let status = monitoring.unwrap_or_else(|e| panic!("{e}: {last:#}"));
    let cond = |t: &str| {
        status["conditions"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["type"] == t)
            .cloned()
            .unwrap_or_else(|| panic!("condition {t} in {status:#}"))
    };
    assert_eq!(cond("Accepted")["status"], "True", "the reconciler's part");
    assert_eq!(cond("StackResolved")["status"], "True");
    assert_eq!(
        cond("Ready")["reason"],
        "Satisfied",
        "the runner owns Ready"
    );
    assert_eq!(
        server
            .state
            .store
            .list(Kind::ConfigProfile, None)
            .unwrap()
            .0
            .len(),
        1
    );
    let tuning = server.tuning.clone().unwrap();
    assert_eq!(
        tuning.running(),
        vec![("default".to_string(), "nav-spec".to_string())]
    );
    store
        .delete(Kind::PerformanceSpec, "default", "nav-spec")
        .unwrap();
    wait_until_async(
        "the runner to stop",
        Duration::from_secs(30),
        POLL,
        async || {
            tuning.running().is_empty()
                && runner::load_run(&store, "default", "nav-spec")
                    .unwrap()
                    .is_none()
        },
    )
    .await;
    drop(tuning);
    server.stop();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn exported_profile_lets_another_robot_of_the_model_skip_tuning() {
    let a = Fixture::new(spec(35.0, 8, json!({})));
    let h = a.spawn();
    a.until("robot A tuned", |r| monitoring(r, 5)).await;
    h.abort();
    let (profiles, _) = a.store.list(Kind::ConfigProfile, None).unwrap();
    let yaml = serde_saphyr::to_string(&profiles[0]).unwrap();
    // Robot B: a fresh database; the profile is imported as a manifest.
    let b = Fixture::new(spec(35.0, 8, json!({})));
    let loaded = configbot_manifests::load("profile.yaml", &yaml).unwrap();
    assert_eq!(loaded.len(), 1);
    b.store
        .put(Kind::ConfigProfile, loaded[0].manifest.to_json(), true)
        .unwrap();
    let h = b.spawn();
    b.until("robot B monitoring", |r| monitoring(r, 5)).await;
    h.abort();
    let run = b.run();
    assert!(
        run.trials.is_empty() && run.baseline.is_none(),
        "no tuning on B"
    );
    assert_eq!(run.library_hits, 1);
    assert_eq!(b.sim.applied(), vec![profiles_config(&profiles[0])]);
}

fn profiles_config(p: &Value) -> configbot_manifests::ResourceConfig {
    serde_json::from_value(p["spec"]["config"].clone()).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sustained_violation_triggers_relearning_that_restores_the_constraint() {
    let f = Fixture::new(spec(35.0, 10, json!({})));
    let h = f.spawn();
    f.until("first tuning", |r| monitoring(r, 10)).await;
    let first = f.run();
    let State::Monitor {
        config: learned, ..
    } = first.state.clone()
    else {
        unreachable!()
    };
    // The lidar's work per scan quadruples (0.2 -> 0.8 CPU): the learned config
    // no longer leaves the planner enough CPU.
    f.sim.update_node("/lidar", |n| n.cycle_cost = 0.02);
    f.until("relearned", |r| {
        monitoring(r, 30) && matches!(&r.state, State::Monitor { config, .. } if *config != learned)
    })
    .await;
    h.abort();
    let events = f.events();
    let violated = events
        .iter()
        .position(|(r, _)| r == "ConstraintViolated")
        .unwrap_or_else(|| panic!("{events:#?}"));
    assert!(
        events[violated..].iter().any(|(r, _)| r == "Trial"),
        "relearning ran trials: {:#?}",
        &events[violated..]
    );
    // Before relearning, the next best trial of the first run was verified
    // (the learned config might only have tipped) and failed: the workload
    // did change.
    let next_best = events[violated..]
        .iter()
        .position(|(r, _)| r == "VerifyingNextBest")
        .unwrap_or_else(|| panic!("{events:#?}"));
    let verdict = events[violated + next_best..]
        .iter()
        .find(|(r, _)| r == "Satisfied" || r == "VerificationFailed");
    assert_eq!(
        verdict.map(|(r, _)| r.as_str()),
        Some("VerificationFailed"),
        "{events:#?}"
    );
    let run = f.run();
    let base = run.baseline.as_ref().unwrap();
    assert!(
        base.eval.satisfaction < 0.5,
        "the relearn baseline is the config on the robot, now violating: {:?}",
        base.eval
    );
    assert!(
        first.trials.iter().any(|t| t.config == base.config) && base.config != learned,
        "the relearn baseline is the next best trial's config: {:?}",
        base.config
    );
    assert!(run.monitor.satisfaction().unwrap() >= 0.99);
    assert!(
        f.metrics
            .render()
            .contains("configbot_tuning_triggers_total{cause=\"ConstraintViolated\"")
    );
}
