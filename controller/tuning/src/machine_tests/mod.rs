//! Tests of the tuning run's state machine: the transition table (state,
//! input, environment) → (next state, events) and the effect each state asks
//! for, here; the search's decisions in `search`, remediation in
//! `remediation`. The fixtures below serve all three.

mod remediation;
mod search;
mod startup;

use configbot_api::graph::{Graph, NodeInfo, TopicInfo};
use configbot_api::measure::{MeasureReport, Probe, ProbeSeries};
use configbot_manifests::{PerformanceSpec, RobotStack};

use super::*;

fn stack() -> RobotStack {
    stack_of(&["/planner"], &["/camera", "/detector"])
}

/// The harness stack with `nav`'s nodes in the core app and `det`'s in the
/// non-core one.
fn stack_of(nav: &[&str], det: &[&str]) -> RobotStack {
    let n = |names: &[&str]| -> Vec<serde_json::Value> {
        names
            .iter()
            .map(|name| serde_json::json!({"name": name, "run": {"command": "x"}}))
            .collect()
    };
    serde_json::from_value(serde_json::json!({
        "apiVersion": "configbot.dev/v1alpha1", "kind": "RobotStack", "metadata": {"name": "s"},
        "spec": {"robot": {"model": "m", "cpus": 2}, "apps": [
            {"name": "nav", "core": true, "nodes": n(nav)},
            {"name": "det", "nodes": n(det)}]}
    }))
    .unwrap()
}

fn spec(settle: f64, max_trials: u32) -> PerformanceSpec {
    serde_json::from_value(serde_json::json!({
        "apiVersion": "configbot.dev/v1alpha1", "kind": "PerformanceSpec", "metadata": {"name": "p"},
        "spec": {"stackRef": {"name": "s"},
            "metrics": [
                {"name": "cmd", "app": "nav", "source": {"topicRate": {"topic": "/cmd_vel"}}, "target": {"atLeast": 35}},
                {"name": "det", "app": "det", "source": {"topicRate": {"topic": "/detections"}}, "target": {"atLeast": 10}}],
            "tuning": {"settleSeconds": settle, "maxTrials": max_trials, "trialSeconds": 5}}
    }))
    .unwrap()
}

fn graph() -> Graph {
    let mut g = Graph::default();
    for n in ["/planner", "/camera", "/detector"] {
        g.nodes.insert(
            n.into(),
            NodeInfo {
                name: n.into(),
                uri: String::new(),
                pid: None,
            },
        );
    }
    let mut topic = |name: &str, publisher: &str, subscribers: &[&str]| {
        g.topics.insert(
            name.into(),
            TopicInfo {
                name: name.into(),
                msg_type: "m/M".into(),
                publishers: [publisher.to_string()].into(),
                subscribers: subscribers.iter().map(|s| s.to_string()).collect(),
            },
        );
    };
    topic("/image", "/camera", &["/detector"]);
    topic("/detections", "/detector", &[]);
    topic("/cmd_vel", "/planner", &[]);
    g
}

fn ctx() -> ProfileContext {
    ProfileContext {
        robot_model: "m".into(),
        apps: vec!["det".into(), "nav".into()],
        nodes: vec!["/camera".into(), "/detector".into(), "/planner".into()],
        labels: Default::default(),
    }
}

/// A report with `cmd` and `det` values per 1 s sub-window (and /image at 30 Hz).
fn report(cmd: &[f64], det: f64) -> Input {
    let s = |topic: &str, v: Vec<f64>| ProbeSeries {
        probe: Probe::TopicRate {
            topic: topic.into(),
            subscriber: None,
        },
        mean: v.iter().sum::<f64>() / v.len() as f64,
        values: v,
    };
    Input::Measured(MeasureReport {
        started_unix_ms: 0,
        duration_ms: 1000 * cmd.len() as u64,
        sub_window_ms: 1000,
        series: vec![
            s("/cmd_vel", cmd.to_vec()),
            s("/detections", vec![det; cmd.len()]),
            s("/image", vec![30.0; cmd.len()]),
        ],
    })
}

fn profile() -> Box<ConfigProfile> {
    Box::new(library::profile(
        "default",
        "p",
        None,
        &ctx(),
        &ResourceConfig::default(),
        1.0,
        Some(0.5),
        vec![],
    ))
}

fn stale() -> Box<ConfigProfile> {
    let mut p = profile();
    p.spec.spec_digest = Some("0000000000000000".into());
    p
}

/// A remediation that stopped `app` (no freeze, no recording).
fn paused(app: &str) -> Remedy {
    Remedy {
        apps: vec![app.into()],
        ..Remedy::default()
    }
}

fn with(state: State) -> Run {
    let mut r = Run::new(1, Trigger::SpecChanged);
    r.state = state;
    r.context = Some(ctx());
    r
}

fn name(s: &State) -> &'static str {
    match s {
        State::StartUp { .. } => "StartUp",
        State::Observe { .. } => "Observe",
        State::Baseline { .. } => "Baseline",
        State::Drain { .. } => "Drain",
        State::TrialApply { .. } => "TrialApply",
        State::TrialSettle { .. } => "TrialSettle",
        State::TrialProfile { .. } => "TrialProfile",
        State::VerifyApply { .. } => "VerifyApply",
        State::VerifySettle { .. } => "VerifySettle",
        State::Verify { .. } => "Verify",
        State::UnsatApply { .. } => "UnsatApply",
        State::RestoreApply { .. } => "RestoreApply",
        State::RestoreSettle { .. } => "RestoreSettle",
        State::Monitor { .. } => "Monitor",
        State::RemediatePause { .. } => "RemediatePause",
        State::RemediateApply { .. } => "RemediateApply",
        State::Remediating { .. } => "Remediating",
        State::RemediateUndo { .. } => "RemediateUndo",
    }
}

/// The message of an event output.
fn event_text(o: &Output) -> &str {
    match o {
        Output::Event { message, .. } => message,
        o => panic!("not an event: {o:?}"),
    }
}

fn reasons(out: &[Output]) -> Vec<&str> {
    out.iter()
        .map(|o| match o {
            Output::Event { reason, .. } => reason.as_str(),
            Output::SaveProfile(_) => "<save>",
        })
        .collect()
}

fn observe(skip: bool) -> State {
    State::Observe {
        trigger: Trigger::SpecChanged,
        skip_library: skip,
    }
}

fn cfg() -> ResourceConfig {
    let mut c = ResourceConfig::default();
    c.cpu.insert("/detector".into(), 0.5);
    c
}

fn observed(known: bool) -> Input {
    Input::Observed {
        graph: graph(),
        context: ctx(),
        known: known.then(profile),
    }
}

/// The graph check's context change from "a" to "b", with these nodes joined.
fn context_changed(joined: &[&str]) -> Input {
    Input::Trigger(Trigger::ContextChanged {
        from: "a".into(),
        to: "b".into(),
        by: "graph check".into(),
        joined: joined.iter().map(|n| n.to_string()).collect(),
    })
}

const OK: [f64; 5] = [40.0; 5];
const BAD: [f64; 5] = [20.0; 5];

#[test]
fn transition_table() {
    let st = stack();
    let sp = spec(1.0, 5);
    let sp0 = spec(0.0, 5);
    let trial = |partial: Option<MeasureReport>| State::TrialProfile {
        x: vec![],
        config: cfg(),
        partial,
    };
    let Input::Measured(two_ok) = report(&[40.0, 40.0], 5.0) else {
        unreachable!()
    };
    // (case, state, input, settle-free spec?, tuning allowed, next state, event reasons)
    type Case = (
        &'static str,
        State,
        Input,
        bool,
        bool,
        &'static str,
        Vec<&'static str>,
    );
    let cases: Vec<Case> = vec![
        (
            "unknown context measures a baseline",
            observe(false),
            observed(false),
            false,
            true,
            "Baseline",
            vec![],
        ),
        (
            "familiar context re-applies at once",
            observe(false),
            observed(true),
            false,
            true,
            "VerifyApply",
            vec!["LibraryHit"],
        ),
        (
            "relearning skips the library",
            observe(true),
            observed(true),
            false,
            true,
            "Baseline",
            vec![],
        ),
        (
            "a profile learned for other targets only warm-starts",
            observe(false),
            Input::Observed {
                graph: graph(),
                context: ctx(),
                known: Some(stale()),
            },
            false,
            true,
            "Baseline",
            vec![],
        ),
        (
            "violating baseline starts trials",
            State::Baseline {
                graph: graph(),
                prior: None,
            },
            report(&BAD, 5.0),
            false,
            true,
            "TrialApply",
            vec!["Baseline", "FeasibilityFirst"],
        ),
        (
            "a library profile without trials: no warm start, the corner first",
            State::Baseline {
                graph: graph(),
                prior: Some(profile()),
            },
            report(&BAD, 5.0),
            false,
            true,
            "TrialApply",
            vec!["Baseline", "FeasibilityFirst"],
        ),
        (
            "tuning not allowed + violated: remediate",
            State::Baseline {
                graph: graph(),
                prior: None,
            },
            report(&BAD, 5.0),
            false,
            false,
            "RemediatePause",
            vec!["Baseline", "Remediated"],
        ),
        (
            "tuning not allowed + holds: keep it",
            State::Baseline {
                graph: graph(),
                prior: None,
            },
            report(&OK, 5.0),
            false,
            false,
            "VerifyApply",
            vec!["Baseline"],
        ),
        (
            "applied trial settles",
            State::TrialApply {
                x: vec![],
                config: cfg(),
            },
            Input::Applied,
            false,
            true,
            "TrialSettle",
            vec![],
        ),
        (
            "no settle time: profile at once",
            State::TrialApply {
                x: vec![],
                config: cfg(),
            },
            Input::Applied,
            true,
            true,
            "TrialProfile",
            vec![],
        ),
        (
            "settled trial profiles",
            State::TrialSettle {
                x: vec![],
                config: cfg(),
                so_far: None,
            },
            Input::Slept,
            false,
            true,
            "TrialProfile",
            vec![],
        ),
        (
            "promising first part: profile the rest",
            trial(None),
            report(&[40.0, 40.0], 5.0),
            false,
            true,
            "TrialProfile",
            vec![],
        ),
        (
            "clearly infeasible first part: stop early",
            trial(None),
            report(&[20.0, 21.0], 5.0),
            false,
            true,
            "UnsatApply",
            vec!["Trial", "Unsat"],
        ),
        (
            "complete trial is recorded",
            trial(Some(two_ok)),
            report(&[40.0, 40.0, 40.0], 5.0),
            false,
            true,
            "VerifyApply",
            vec!["Trial"],
        ),
        (
            "mismatched input is ignored",
            State::TrialApply {
                x: vec![],
                config: cfg(),
            },
            Input::Slept,
            false,
            true,
            "TrialApply",
            vec![],
        ),
        (
            "verified trial: monitor and save",
            State::Verify {
                candidate: Candidate::Trial { index: 0 },
                config: cfg(),
                so_far: None,
            },
            report(&[40.0; 10], 5.0),
            false,
            true,
            "Monitor",
            vec!["Satisfied", "<save>"],
        ),
        (
            "failed library config: relearn",
            State::Verify {
                candidate: Candidate::Library { profile: profile() },
                config: cfg(),
                so_far: None,
            },
            report(&[20.0; 10], 5.0),
            false,
            true,
            "Observe",
            vec!["LibraryConfigFailed"],
        ),
        (
            "failed library config, no tuning: remediate",
            State::Verify {
                candidate: Candidate::Library { profile: profile() },
                config: cfg(),
                so_far: None,
            },
            report(&[20.0; 10], 5.0),
            false,
            false,
            "RemediatePause",
            vec!["LibraryConfigFailed", "Remediated"],
        ),
        (
            "sustained violation: relearn",
            State::Monitor {
                satisfied: true,
                config: cfg(),
            },
            report(&BAD, 5.0),
            false,
            true,
            "Observe",
            vec!["ConstraintViolated"],
        ),
        (
            "sustained violation, no tuning: remediate",
            State::Monitor {
                satisfied: true,
                config: cfg(),
            },
            report(&BAD, 5.0),
            false,
            false,
            "RemediatePause",
            vec!["ConstraintViolated", "Remediated"],
        ),
        (
            "short violation: keep monitoring",
            State::Monitor {
                satisfied: true,
                config: cfg(),
            },
            report(&[20.0, 40.0, 20.0, 40.0, 20.0], 5.0),
            false,
            true,
            "Monitor",
            vec![],
        ),
        (
            "after Unsat violations do not relearn",
            State::Monitor {
                satisfied: false,
                config: cfg(),
            },
            report(&BAD, 5.0),
            false,
            true,
            "Monitor",
            vec![],
        ),
        (
            "context change while monitoring",
            State::Monitor {
                satisfied: true,
                config: cfg(),
            },
            Input::Trigger(Trigger::ContextChanged {
                from: "a".into(),
                to: "b".into(),
                by: "exec".into(),
                joined: vec!["/det".into()],
            }),
            false,
            true,
            "StartUp",
            vec!["ContextChanged"],
        ),
        (
            "nodes only left while monitoring: nothing starts, observe at once",
            State::Monitor {
                satisfied: true,
                config: cfg(),
            },
            context_changed(&[]),
            false,
            true,
            "Observe",
            vec!["ContextChanged"],
        ),
        (
            "context change during a trial: start over",
            trial(None),
            context_changed(&["/det"]),
            false,
            true,
            "StartUp",
            vec!["ContextChanged"],
        ),
        (
            "nodes only left during a trial: start over without the start-up wait",
            trial(None),
            context_changed(&[]),
            false,
            true,
            "Observe",
            vec!["ContextChanged"],
        ),
        (
            "context change during a verification: start over",
            State::Verify {
                candidate: Candidate::Trial { index: 0 },
                config: cfg(),
                so_far: None,
            },
            context_changed(&["/det"]),
            false,
            true,
            "StartUp",
            vec!["ContextChanged"],
        ),
        (
            "a violation during a trial is the trial's own result, not a trigger",
            trial(None),
            Input::Trigger(Trigger::ConstraintViolated {
                seconds: 5.0,
                satisfaction: 0.0,
            }),
            false,
            true,
            "TrialProfile",
            vec![],
        ),
        (
            "apps stopped: lift limits",
            State::RemediatePause {
                remedy: paused("det"),
            },
            Input::AppsPaused(None),
            false,
            false,
            "RemediateApply",
            vec![],
        ),
        (
            "apps paused, inputs recorded: say where",
            State::RemediatePause {
                remedy: Remedy {
                    record: true,
                    ..paused("det")
                },
            },
            Input::AppsPaused(Some(Recording {
                path: "/bags/x.bag".into(),
                topics: vec!["/image".into()],
            })),
            false,
            false,
            "RemediateApply",
            vec!["RecordingInputs"],
        ),
        (
            "apps paused, recording asked for but none started: warn",
            State::RemediatePause {
                remedy: Remedy {
                    record: true,
                    ..paused("det")
                },
            },
            Input::AppsPaused(None),
            false,
            false,
            "RemediateApply",
            vec!["NotRecording"],
        ),
        (
            "limits lifted: remediating",
            State::RemediateApply {
                remedy: paused("det"),
            },
            Input::Applied,
            false,
            false,
            "Remediating",
            vec![],
        ),
        (
            "still not allowed",
            State::Remediating {
                remedy: paused("det"),
            },
            report(&OK, 5.0),
            false,
            false,
            "Remediating",
            vec![],
        ),
        (
            "allowed again: undo",
            State::Remediating {
                remedy: paused("det"),
            },
            report(&OK, 5.0),
            false,
            true,
            "RemediateUndo",
            vec![],
        ),
        (
            "undone: relearn",
            State::RemediateUndo {
                remedy: paused("det"),
            },
            Input::AppsResumed(None),
            false,
            true,
            "Observe",
            vec!["RemediationUndone"],
        ),
        (
            "unsat config applied: monitor",
            State::UnsatApply { config: cfg() },
            Input::Applied,
            false,
            true,
            "Monitor",
            vec![],
        ),
    ];
    for (case, state, input, no_settle, allowed, want, want_events) in cases {
        let sp = if no_settle { &sp0 } else { &sp };
        let env = Env {
            stack: &st,
            spec: &sp.spec,
            namespace: "default",
            spec_name: "p",
            cpus: 2.0,
            tuning_allowed: allowed,
        };
        let (run, out) = step(with(state), input, &env);
        assert_eq!(name(&run.state), want, "{case}");
        assert_eq!(reasons(&out), want_events, "{case}");
    }
}

#[test]
fn relearning_after_a_violation_starts_cold_after_a_failed_library_config_warm() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = Env {
        stack: &st,
        spec: &sp.spec,
        namespace: "default",
        spec_name: "p",
        cpus: 2.0,
        tuning_allowed: true,
    };
    let violated = Trigger::ConstraintViolated {
        seconds: 5.0,
        satisfaction: 0.5,
    };
    let failed = Trigger::LibraryConfigFailed { satisfaction: 0.5 };
    for (trigger, warm) in [(violated, false), (failed, true)] {
        let state = State::Observe {
            trigger: trigger.clone(),
            skip_library: true,
        };
        let (run, _) = step(with(state), observed(true), &env);
        let State::Baseline { prior, .. } = run.state else {
            panic!("{trigger:?}: {:?}", run.state)
        };
        assert_eq!(prior.is_some(), warm, "{trigger:?}");
    }
}

#[test]
fn a_library_config_is_verified_from_a_drained_state() {
    let (st, sp) = (stack(), spec(4.0, 5));
    let env = env(&st, &sp);
    let mut p = profile();
    p.spec.config = cfg();
    p.spec
        .config
        .adaptors
        .push(configbot_manifests::AdaptorRate {
            topic: "/image".into(),
            subscriber: "/detector".into(),
            rate_hz: 4.0,
        });
    let learned = p.spec.config.clone();
    let known = |p: &ConfigProfile| Input::Observed {
        graph: graph(),
        context: ctx(),
        known: Some(Box::new(p.clone())),
    };
    let (run, out) = step(with(observe(false)), known(&p), &env);
    assert_eq!(reasons(&out), vec!["LibraryHit"]);
    let State::Drain { config, then, .. } = &run.state else {
        panic!("{:?}", run.state)
    };
    assert_eq!(
        config.cpu["/detector"], 2.0,
        "the detector finishes its backlog"
    );
    assert_eq!(config.adaptors[0].rate_hz, 0.5, "and gets no new frames");
    assert!(matches!(
        &**then,
        State::VerifyApply { candidate: Candidate::Library { .. }, config } if *config == learned
    ));
    assert_eq!(run.phase(), configbot_manifests::Phase::Satisfied);
    let (run, _) = step(run, Input::Applied, &env);
    let (run, _) = step(run, report(&[20.0, 38.0], 0.0), &env);
    assert_eq!(name(&run.state), "Drain", "core still moving");
    let (run, _) = step(run, report(&[39.0], 0.0), &env);
    assert!(matches!(
        run.state,
        State::VerifyApply {
            candidate: Candidate::Library { .. },
            ..
        }
    ));
    // Short settles (tests, simulations) and configs that hold back no
    // non-core input verify at once.
    let sp1 = spec(1.0, 5);
    let (run, _) = step(with(observe(false)), known(&p), &self::env(&st, &sp1));
    assert_eq!(name(&run.state), "VerifyApply");
    p.spec.config.adaptors.clear();
    let (run, _) = step(with(observe(false)), known(&p), &env);
    assert_eq!(name(&run.state), "VerifyApply");
}

fn env<'a>(st: &'a RobotStack, sp: &'a PerformanceSpec) -> Env<'a> {
    Env {
        stack: st,
        spec: &sp.spec,
        namespace: "default",
        spec_name: "p",
        cpus: 2.0,
        tuning_allowed: true,
    }
}

#[test]
fn effects_and_resume_points() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let measure_ms = |s: State| match effect(&with(s), &env) {
        Effect::Measure(r) => r.duration_ms,
        e => panic!("{e:?}"),
    };
    assert_eq!(effect(&with(observe(false)), &env), Effect::Observe);
    assert_eq!(
        effect(
            &with(State::TrialSettle {
                x: vec![],
                config: cfg(),
                so_far: None,
            }),
            &env
        ),
        Effect::Sleep(Duration::from_secs(1))
    );
    let Input::Measured(two) = report(&[40.0, 40.0], 5.0) else {
        unreachable!()
    };
    let trial = |partial| State::TrialProfile {
        x: vec![],
        config: cfg(),
        partial,
    };
    assert_eq!(measure_ms(trial(None)), 2000, "early-stop part first");
    assert_eq!(measure_ms(trial(Some(two))), 3000, "then the rest");
    let base = with(State::Baseline {
        graph: graph(),
        prior: None,
    });
    let Effect::Measure(r) = effect(&base, &env) else {
        panic!()
    };
    assert_eq!(r.probes.len(), 3, "two metrics and the /image rate");
    assert_eq!(
        effect(
            &with(State::RemediatePause {
                remedy: paused("det"),
            }),
            &env
        ),
        Effect::PauseApps(paused("det"))
    );
    let resumed = with(trial(None)).resumed();
    assert_eq!(
        resumed.state,
        State::TrialApply {
            x: vec![],
            config: cfg()
        }
    );
    let resumed = with(State::Verify {
        candidate: Candidate::Baseline,
        config: cfg(),
        so_far: None,
    })
    .resumed();
    assert_eq!(name(&resumed.state), "VerifyApply");
    let settling = with(State::VerifySettle {
        candidate: Candidate::Baseline,
        config: cfg(),
        so_far: None,
    });
    assert_eq!(
        effect(&settling, &env),
        Effect::Sleep(Duration::from_secs(1))
    );
    assert_eq!(name(&settling.resumed().state), "VerifyApply");
    let json = serde_json::to_string(&with(trial(None))).unwrap();
    let back: Run = serde_json::from_str(&json).unwrap();
    assert_eq!(back.state, trial(None));
    // A back-off persists in the shape earlier versions wrote, and a run's
    // set-aside back-off and edges survive a restart.
    let backoff = Backoff {
        index: 1,
        fraction: 0.8,
        step: 1,
        shaped: false,
    };
    let verifying = State::VerifyApply {
        candidate: Candidate::Backoff(backoff),
        config: cfg(),
    };
    assert_eq!(
        serde_json::to_value(&verifying).unwrap()["candidate"],
        serde_json::json!({"kind": "backoff", "index": 1, "fraction": 0.8, "step": 1})
    );
    let mut run = with(verifying.clone());
    run.deferred_backoff = Some(backoff);
    run.edges.push(Edge {
        constraint: 0,
        beyond: 38.0,
        at_least: true,
    });
    run.failed_verifications.push(TrialRecord {
        config: cfg(),
        x: vec![0.5, 2.0],
        eval: Default::default(),
        censored: false,
    });
    let back: Run = serde_json::from_str(&serde_json::to_string(&run).unwrap()).unwrap();
    assert_eq!(back.state, verifying);
    assert_eq!(back.deferred_backoff, Some(backoff));
    assert_eq!(back.edges, run.edges);
    assert_eq!(back.failed_verifications, run.failed_verifications);
    // A shaped back-off says so; an unshaped one is written as before.
    let shaped = Backoff {
        shaped: true,
        ..backoff
    };
    assert_eq!(
        serde_json::to_value(Candidate::Backoff(shaped)).unwrap()["shaped"],
        serde_json::json!(true)
    );
    let unshaped = serde_json::to_value(Candidate::Backoff(backoff)).unwrap();
    assert!(unshaped.get("shaped").is_none(), "{unshaped}");
}

#[test]
fn baseline_is_the_config_last_applied() {
    let (st, sp) = (stack(), spec(0.0, 5));
    let env = env(&st, &sp);
    let (run, _) = step(
        with(State::UnsatApply { config: cfg() }),
        Input::Applied,
        &env,
    );
    assert_eq!(run.current, cfg());
    let mut run = run;
    run.state = State::Baseline {
        graph: graph(),
        prior: None,
    };
    let (run, _) = step(run, report(&BAD, 5.0), &env);
    let b = run.baseline.unwrap();
    assert_eq!(b.config.cpu["/detector"], 0.5);
    assert_eq!(
        b.config.cpu["/camera"], 2.0,
        "unset knobs at their upper bound"
    );
}
