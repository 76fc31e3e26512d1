//! Table tests of the transition function: (state, input, environment) →
//! (next state, events), and the effect each state asks for.

use configbot_agent::measure::{MeasureReport, Probe, ProbeSeries};
use configbot_dataplane::{Graph, NodeInfo, TopicInfo};
use configbot_manifests::performance_spec::RemediationAction;
use configbot_manifests::{PerformanceSpec, RobotStack};

use super::*;
use crate::tuning::{knobs, outcome, search};

fn stack() -> RobotStack {
    let n = |name: &str| serde_json::json!({"name": name, "run": {"command": "x"}});
    serde_json::from_value(serde_json::json!({
        "apiVersion": "configbot.dev/v1alpha1", "kind": "RobotStack", "metadata": {"name": "s"},
        "spec": {"robot": {"model": "m", "cpus": 2}, "apps": [
            {"name": "nav", "core": true, "nodes": [n("/planner")]},
            {"name": "det", "nodes": [n("/camera"), n("/detector")]}]}
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
    g.topics.insert(
        "/image".into(),
        TopicInfo {
            name: "/image".into(),
            msg_type: "m/M".into(),
            publishers: ["/camera".to_string()].into(),
            subscribers: ["/detector".to_string()].into(),
        },
    );
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
        State::Monitor { .. } => "Monitor",
        State::RemediatePause { .. } => "RemediatePause",
        State::RemediateApply { .. } => "RemediateApply",
        State::Remediating { .. } => "Remediating",
        State::RemediateUndo { .. } => "RemediateUndo",
    }
}

fn reasons(out: &[Output]) -> Vec<&'static str> {
    out.iter()
        .map(|o| match o {
            Output::Event { reason, .. } => *reason,
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
            vec!["Baseline"],
        ),
        (
            "warm start from the library's trials",
            State::Baseline {
                graph: graph(),
                prior: Some(profile()),
            },
            report(&BAD, 5.0),
            false,
            true,
            "TrialApply",
            vec!["Baseline"],
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
            }),
            false,
            true,
            "Observe",
            vec!["ContextChanged"],
        ),
        (
            "context change during a trial: start over",
            trial(None),
            Input::Trigger(Trigger::ContextChanged {
                from: "a".into(),
                to: "b".into(),
                by: "graph check".into(),
            }),
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
            },
            Input::Trigger(Trigger::ContextChanged {
                from: "a".into(),
                to: "b".into(),
                by: "graph check".into(),
            }),
            false,
            true,
            "Observe",
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
fn early_stop_is_a_censored_observation() {
    let (st, sp) = (stack(), spec(0.0, 5));
    let env = env(&st, &sp);
    let (run, _) = step(
        with(State::Baseline {
            graph: graph(),
            prior: None,
        }),
        report(&BAD, 5.0),
        &env,
    );
    assert_eq!(run.knobs.knobs.len(), 3, "{:?}", run.knobs);
    let State::TrialApply { .. } = run.state else {
        panic!("{:?}", run.state)
    };
    let (run, _) = step(run, Input::Applied, &env);
    let (run, _) = step(run, report(&[10.0, 12.0], 5.0), &env);
    assert_eq!(run.trials.len(), 1);
    assert!(run.trials[0].censored);
    assert!(!run.trials[0].eval.feasible);
    let o = run.optimizer.as_ref().unwrap();
    assert_eq!(o.observations().len(), 2, "baseline and the censored trial");
    assert!(o.observations()[1].censored);
    assert_eq!(name(&run.state), "TrialApply", "the next trial");
}

#[test]
fn best_failing_verification_tries_the_next_best_then_unsat() {
    let (st, sp) = (stack(), spec(0.0, 5));
    let env = env(&st, &sp);
    let mut run = with(State::Verify {
        candidate: Candidate::Trial { index: 1 },
        config: cfg(),
    });
    let Input::Measured(good) = report(&OK, 8.0) else {
        unreachable!()
    };
    let Input::Measured(better) = report(&OK, 9.0) else {
        unreachable!()
    };
    for r in [&good, &better] {
        run.trials.push(TrialRecord {
            config: cfg(),
            x: vec![],
            eval: measure::evaluate(&env.defs(), r, Default::default()),
            censored: false,
        });
    }
    let (run, out) = step(run, report(&[20.0; 10], 5.0), &env);
    assert_eq!(reasons(&out), vec!["VerificationFailed"]);
    assert_eq!(
        run.state,
        State::VerifyApply {
            candidate: Candidate::Trial { index: 0 },
            config: cfg()
        }
    );
    let (run, _) = step(run, Input::Applied, &env);
    let (run, out) = step(run, report(&[20.0; 10], 5.0), &env);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "Unsat"]);
    assert_eq!(name(&run.state), "UnsatApply");
}

/// A run whose knobs are /detector's CPU (non-core, 0.1..2) and /planner's
/// (core), with trials 0 and 1 feasible (objective 0.8 and 0.9 of `det`).
fn with_two_trials(env: &Env<'_>) -> Run {
    let knob = |node: &str, restricts_non_core| knobs::KnobDef {
        name: knobs::cpu_knob_name(node),
        target: knobs::KnobTarget::Cpu { node: node.into() },
        min: 0.1,
        max: 2.0,
        restricts_non_core,
    };
    let mut run = with(State::Observe {
        trigger: Trigger::SpecChanged,
        skip_library: false,
    });
    run.knobs = KnobSpace {
        knobs: vec![knob("/detector", true), knob("/planner", false)],
        period_micros: 20_000,
    };
    for (x, det) in [([1.0, 1.5], 8.0), ([1.9, 1.5], 9.0)] {
        let Input::Measured(r) = report(&OK, det) else {
            unreachable!()
        };
        run.trials.push(TrialRecord {
            config: run.knobs.to_config(&x),
            x: x.to_vec(),
            eval: measure::evaluate(&env.defs(), &r, Default::default()),
            censored: false,
        });
    }
    run
}

/// Verify the run's current candidate: apply, settle, measure `cmd`.
fn verify(run: Run, env: &Env<'_>, cmd: &[f64]) -> (Run, Vec<Output>) {
    assert_eq!(name(&run.state), "VerifyApply");
    let (run, _) = step(run, Input::Applied, env);
    assert_eq!(name(&run.state), "VerifySettle", "settles before measuring");
    let (run, _) = step(run, Input::Slept, env);
    assert_eq!(name(&run.state), "Verify");
    step(run, report(cmd, 9.0), env)
}

#[test]
fn a_best_trial_failing_verification_is_backed_off_before_the_next_best() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let mut run = with_two_trials(&env);
    let mut out = Vec::new();
    run.state = finish(&mut run, &env, &env.defs(), &mut out);
    assert_eq!(
        run.state,
        State::VerifyApply {
            candidate: Candidate::Trial { index: 1 },
            config: run.trials[1].config.clone()
        }
    );
    // Three back-off steps of /detector's CPU, /planner's kept: 0.1 + f × 1.8.
    let mut fractions = Vec::new();
    for _ in 0..3 {
        let (r, out) = verify(run, &env, &BAD);
        run = r;
        assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
        let State::VerifyApply {
            candidate: Candidate::Backoff { index: 1, fraction },
            config,
        } = &run.state
        else {
            panic!("{:?}", run.state)
        };
        let want = 0.1 + fraction * 1.8;
        assert!((config.cpu["/detector"] - want).abs() < 1e-3, "{config:?}");
        assert_eq!(config.cpu["/planner"], 1.5);
        fractions.push(*fraction);
    }
    let want = [0.8, 0.64, 0.512];
    assert!(
        fractions
            .iter()
            .zip(want)
            .all(|(f, w)| (f - w).abs() < 1e-9)
    );
    // The last step failed too: the next best trial, as measured, and no back-off for it.
    let (run, out) = verify(run, &env, &BAD);
    assert_eq!(reasons(&out), vec!["VerificationFailed"]);
    assert_eq!(
        run.state,
        State::VerifyApply {
            candidate: Candidate::Trial { index: 0 },
            config: run.trials[0].config.clone()
        }
    );
    assert_eq!(run.rejected, vec![1]);
    let (run, out) = verify(run, &env, &BAD);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "Unsat"]);
    assert_eq!(run.rejected, vec![1, 0]);
}

#[test]
fn a_backed_off_config_that_holds_is_monitored_learned_and_shown() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let mut run = with_two_trials(&env);
    let mut out = Vec::new();
    run.state = finish(&mut run, &env, &env.defs(), &mut out);
    let (run, _) = verify(run, &env, &BAD);
    let State::VerifyApply { config, .. } = run.state.clone() else {
        panic!()
    };
    let (run, out) = verify(run, &env, &OK);
    assert_eq!(reasons(&out), vec!["Satisfied", "<save>"]);
    let Some(Output::SaveProfile(p)) = out.get(1) else {
        panic!()
    };
    assert_eq!(
        p.spec.config, config,
        "the library keeps the backed-off config"
    );
    assert_eq!(
        run.state,
        State::Monitor {
            satisfied: true,
            config: config.clone()
        }
    );
    let status = super::super::status::status(&Default::default(), &run, &env.defs(), 5, 1, "now");
    assert_eq!(status.best_trial, Some(1));
    assert_eq!(status.best_trial_backoff, Some(0.8));
    assert_eq!(status.rejected_trials, vec![1]);
    assert_eq!(status.best_config, Some(config));
    assert_eq!(
        status.non_core_performance["det"], 9.0,
        "from the verification, not the trial"
    );
}

#[test]
fn a_long_settle_is_measured_and_extended_while_a_core_metric_recovers() {
    let (st, sp) = (stack(), spec(3.0, 5));
    let env = env(&st, &sp);
    let (run, _) = step(
        with(State::TrialApply {
            x: vec![],
            config: cfg(),
        }),
        Input::Applied,
        &env,
    );
    assert_eq!(name(&run.state), "TrialSettle");
    let Effect::Measure(first) = effect(&run, &env) else {
        panic!("an adaptive settle measures")
    };
    assert_eq!(first.duration_ms, 3000, "the spec's settle first");
    // /cmd_vel climbs back while the detector drains: one more second.
    let (run, out) = step(run, report(&[12.0, 20.0, 30.0], 5.0), &env);
    assert!(out.is_empty());
    assert_eq!(name(&run.state), "TrialSettle");
    let Effect::Measure(more) = effect(&run, &env) else {
        panic!()
    };
    assert_eq!(more.duration_ms, 1000);
    let (run, _) = step(run, report(&[38.0], 5.0), &env);
    assert_eq!(name(&run.state), "TrialSettle", "30 then 38: still moving");
    let (run, out) = step(run, report(&[37.0], 5.0), &env);
    assert_eq!(
        run.state,
        State::TrialProfile {
            x: vec![],
            config: cfg(),
            partial: None
        }
    );
    assert_eq!(reasons(&out), vec!["SettledLate"]);
    // Verification settles the same way.
    let (run, _) = step(
        with(State::VerifyApply {
            candidate: Candidate::Baseline,
            config: cfg(),
        }),
        Input::Applied,
        &env,
    );
    let (run, out) = step(run, report(&[38.0, 38.0, 37.0], 5.0), &env);
    assert_eq!(name(&run.state), "Verify", "steady at once: no extension");
    assert!(out.is_empty());
}

#[test]
fn with_an_adaptive_settle_configs_are_applied_after_a_drain_of_the_non_core_apps() {
    let mut out = Vec::new();
    // Short settles (tests, simulations) do not drain.
    let (st1, sp1) = (stack(), spec(1.0, 5));
    let env1 = env(&st1, &sp1);
    let mut run = with_two_trials(&env1);
    run.state = finish(&mut run, &env1, &env1.defs(), &mut out);
    assert_eq!(name(&run.state), "VerifyApply");
    let (st, sp) = (stack(), spec(4.0, 5));
    let env = env(&st, &sp);
    let mut run = with_two_trials(&env);
    // An adaptor into the detector too: its input can be held back.
    run.knobs.knobs.push(knobs::KnobDef {
        name: knobs::adaptor_knob_name("/image", "/detector"),
        target: knobs::KnobTarget::Adaptor {
            topic: "/image".into(),
            subscriber: "/detector".into(),
        },
        min: 0.5,
        max: 30.0,
        restricts_non_core: true,
    });
    for t in &mut run.trials {
        t.x.push(5.0);
        t.config = run.knobs.to_config(&t.x);
    }
    let best = run.trials[1].config.clone();
    run.state = finish(&mut run, &env, &env.defs(), &mut out);
    let State::Drain { config, then, .. } = &run.state else {
        panic!("{:?}", run.state)
    };
    assert_eq!(
        **then,
        State::VerifyApply {
            candidate: Candidate::Trial { index: 1 },
            config: best.clone()
        }
    );
    assert_eq!(config.cpu["/detector"], 2.0, "non-core CPU freed");
    assert_eq!(
        config.cpu["/planner"], 1.5,
        "core knobs as in the candidate"
    );
    assert_eq!(config.adaptors[0].rate_hz, 0.5, "non-core input held back");
    assert_eq!(run.phase(), "Satisfied");
    let drain = config.clone();
    assert_eq!(effect(&run, &env), Effect::Apply(drain.clone()));
    let (run, _) = step(run, Input::Applied, &env);
    assert_eq!(run.current, drain);
    let Effect::Measure(m) = effect(&run, &env) else {
        panic!()
    };
    assert_eq!(m.duration_ms, settle::DRAIN_FIRST_MS);
    // Navigation starved while the detector finishes its backlog, then back.
    let (run, _) = step(run, report(&[12.0, 14.0], 0.0), &env);
    assert_eq!(name(&run.state), "Drain");
    let (run, _) = step(run, report(&[37.0], 0.0), &env);
    assert_eq!(name(&run.state), "Drain", "on target but moved 23 Hz");
    let resumed = run.clone().resumed();
    assert!(matches!(
        resumed.state,
        State::Drain {
            applied: false,
            so_far: None,
            ..
        }
    ));
    let (run, _) = step(run, report(&[38.0], 0.0), &env);
    assert_eq!(
        run.state,
        State::VerifyApply {
            candidate: Candidate::Trial { index: 1 },
            config: best
        }
    );
}

#[test]
fn the_trial_to_verify_is_the_near_best_one_that_gives_non_core_apps_the_least() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let mut run = with_two_trials(&env);
    run.trials.clear();
    // /detector's CPU (non-core), /planner's (core); `det` targets 10.
    for (x, det) in [([1.9, 1.5], 12.0), ([1.0, 1.5], 9.7), ([0.5, 1.5], 8.0)] {
        let Input::Measured(r) = report(&OK, det) else {
            unreachable!()
        };
        run.trials.push(TrialRecord {
            config: run.knobs.to_config(&x),
            x: x.to_vec(),
            eval: measure::evaluate(&env.defs(), &r, Default::default()),
            censored: false,
        });
    }
    assert_eq!(
        search::best_trial(&run),
        Some(1),
        "0.97 is as good as the capped 1.0 within a message; 0.8 is not"
    );
    run.rejected.push(1);
    assert_eq!(search::best_trial(&run), Some(0));
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

#[test]
fn safe_exploration_is_off_when_the_baseline_is_below_the_floor() {
    let st = stack();
    let sp = spec(1.0, 10);
    let defs = measure::metric_defs(&st.spec, &sp.spec);
    let core = defs.iter().filter(|d| d.core).count();
    assert!(core >= 1);
    let target = defs.iter().find(|d| d.core).unwrap().target;
    assert!(!baseline_is_safe(0.8, &defs, &vec![target * 0.5; core]));
    assert!(baseline_is_safe(0.8, &defs, &vec![target * 0.9; core]));
}

#[test]
fn safe_exploration_is_off_when_no_config_can_be_worse_than_the_baseline() {
    let knob = |name: &str, restricts_non_core: bool| knobs::KnobDef {
        name: name.into(),
        target: knobs::KnobTarget::Cpu { node: name.into() },
        min: 0.1,
        max: 2.0,
        restricts_non_core,
    };
    let space = |ks: Vec<knobs::KnobDef>| KnobSpace {
        knobs: ks,
        period_micros: 20_000,
    };
    let non_core = space(vec![knob("/detector", true), knob("/web", true)]);
    assert!(every_config_as_safe_as(&non_core, &[2.0, 2.0]));
    assert!(
        !every_config_as_safe_as(&non_core, &[2.0, 1.0]),
        "a limited baseline: raising /web could starve the core"
    );
    let with_core = space(vec![knob("/detector", true), knob("/planner", false)]);
    assert!(
        !every_config_as_safe_as(&with_core, &[2.0, 2.0]),
        "lowering a core node's CPU can starve it"
    );
    assert!(!every_config_as_safe_as(&non_core, &[2.0]));
}

#[test]
fn a_spec_change_while_remediating_resumes_the_paused_apps_first() {
    let mut old = with(State::Remediating {
        remedy: paused("obj"),
    });
    old.current = cfg();
    let new = Run::after_spec_change(old, 7);
    assert_eq!(new.generation, 7);
    assert_eq!(
        new.state,
        State::RemediateUndo {
            remedy: paused("obj"),
        }
    );
    assert_eq!(new.current, cfg());
    // Any other state starts over from observing.
    let fresh = Run::after_spec_change(
        with(State::Observe {
            trigger: Trigger::SpecChanged,
            skip_library: false,
        }),
        8,
    );
    assert_eq!(
        name(&fresh.state),
        name(&State::Observe {
            trigger: Trigger::SpecChanged,
            skip_library: false
        })
    );
}

#[test]
fn remediation_pauses_the_running_non_core_apps_as_the_spec_says() {
    let st = stack();
    let mut sp = spec(2.0, 5).spec;
    let remedy = |sp: &PerformanceSpecSpec, ctx: Option<&ProfileContext>| {
        let env = Env {
            stack: &st,
            spec: sp,
            namespace: "default",
            spec_name: "p",
            cpus: 2.0,
            tuning_allowed: false,
        };
        let mut out = Vec::new();
        let State::RemediatePause { remedy } = remediate(&env, ctx, &mut out) else {
            panic!("not pausing")
        };
        let Output::Event { message, .. } = &out[0] else {
            panic!()
        };
        (remedy, message.clone())
    };
    let (r, msg) = remedy(&sp, Some(&ctx()));
    assert_eq!(r, paused("det"));
    assert!(msg.contains("stopping det"), "{msg}");
    sp.remediation.action = RemediationAction::FreezeNonCore;
    sp.remediation.record_rosbag = true;
    let (r, msg) = remedy(&sp, Some(&ctx()));
    assert_eq!(
        r,
        Remedy {
            apps: vec!["det".into()],
            freeze: true,
            record: true
        }
    );
    assert!(msg.contains("freezing det"), "{msg}");
    // A non-core app that is not running is left alone; nothing paused, nothing recorded.
    let nav_only = ProfileContext {
        apps: vec!["nav".into()],
        ..ctx()
    };
    let (r, _) = remedy(&sp, Some(&nav_only));
    assert_eq!(
        r,
        Remedy {
            freeze: true,
            ..Remedy::default()
        }
    );
    sp.remediation.action = RemediationAction::None;
    assert!(remedy(&sp, Some(&ctx())).0.apps.is_empty());
}

#[test]
fn a_remediation_records_what_the_paused_apps_subscribe_to() {
    let mut g = graph();
    g.topics.insert(
        "/cmd_vel".into(),
        TopicInfo {
            name: "/cmd_vel".into(),
            msg_type: "m/M".into(),
            publishers: ["/planner".to_string()].into(),
            subscribers: ["/base".to_string(), "/camera".to_string()].into(),
        },
    );
    assert_eq!(
        outcome::paused_inputs(&stack(), &g, &["det".into()]),
        vec!["/cmd_vel".to_string(), "/image".to_string()]
    );
    assert!(outcome::paused_inputs(&stack(), &g, &["nav".into()]).is_empty());
    assert!(outcome::paused_inputs(&stack(), &g, &[]).is_empty());
}

#[test]
fn a_remediation_persisted_before_freezing_existed_still_reads() {
    let old: State =
        serde_json::from_value(serde_json::json!({"state": "remediateStop", "apps": ["det"]}))
            .unwrap();
    assert_eq!(
        old,
        State::RemediatePause {
            remedy: paused("det")
        }
    );
    let undo: State =
        serde_json::from_value(serde_json::json!({"state": "remediateUndo", "apps": ["det"]}))
            .unwrap();
    assert_eq!(
        undo,
        State::RemediateUndo {
            remedy: paused("det")
        }
    );
    // And today's form round-trips.
    let now = State::Remediating {
        remedy: Remedy {
            apps: vec!["det".into()],
            freeze: true,
            record: true,
        },
    };
    let back: State = serde_json::from_value(serde_json::to_value(&now).unwrap()).unwrap();
    assert_eq!(back, now);
}

#[test]
fn recording_names_are_unique_and_fit_a_file_name() {
    assert_eq!(outcome::recording_name("default", "nav"), "default.nav");
    assert_ne!(
        outcome::recording_name("a-b", "c"),
        outcome::recording_name("a", "b-c")
    );
    let long = "x".repeat(253);
    let (a, b) = (
        outcome::recording_name("default", &long),
        outcome::recording_name("default", &format!("{}y", &long[1..])),
    );
    assert!(a.len() <= 200 && b.len() <= 200, "{} {}", a.len(), b.len());
    assert_ne!(a, b);
}
