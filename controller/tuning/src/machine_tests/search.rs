//! The search inside a run: early-stopped (censored) trials, verification of
//! the best trial and its back-off, adaptive settling and draining, the
//! near-best rule, and when safe exploration applies.

use super::*;
use crate::{knobs, measure, outcome, search};

#[test]
fn early_stop_is_a_censored_observation() {
    let (st, sp) = (stack(), spec(0.0, 5));
    let env = env(&st, &sp);
    let (run, _) = step(
        with(State::Baseline {
            graph: graph(),
            prior: None,
        }),
        report(&OK, 5.0),
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
        so_far: None,
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
    assert_eq!(
        reasons(&out),
        vec!["VerificationFailed", "VerifyingNextBest"]
    );
    assert!(
        event_text(&out[1]).contains(
            "trial 0 measured objective 0.800, and no trial is beyond the edges the failed verifications left"
        ),
        "{out:?}"
    );
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
    // One core constraint, met in both trials, missed in both verifications:
    // the reason says so, not that constraints were never met together.
    let why = event_text(&out[1]);
    assert!(
        why.contains("were met in trial 0, trial 1, but each config verified over a longer window missed (trial 1, trial 0)"),
        "{why}"
    );
    assert!(!why.contains("never together"), "{why}");
}

/// A run whose knobs are /detector's CPU (non-core, 0.1..2) and /planner's
/// (core), with trials 0 and 1 feasible (objective 0.4 and 0.9 of `det`:
/// every back-off of trial 1 promises more than trial 0).
fn with_two_trials(env: &Env<'_>) -> Run {
    let knob = |node: &str, restricts_non_core| knobs::KnobDef {
        name: knobs::cpu_knob_name(node),
        target: knobs::KnobTarget::Cpu { node: node.into() },
        min: 0.1,
        max: 2.0,
        restricts_non_core,
        feeds: Vec::new(),
    };
    let mut run = with(State::Observe {
        trigger: Trigger::SpecChanged,
        skip_library: false,
    });
    run.knobs = KnobSpace {
        knobs: vec![knob("/detector", true), knob("/planner", false)],
        period_micros: 20_000,
        ..KnobSpace::default()
    };
    for (x, det) in [([1.0, 1.5], 4.0), ([1.9, 1.5], 9.0)] {
        push_trial(&mut run, env, &x, det);
    }
    run
}

/// [`with_two_trials`], its search finished: the next step verifies trial 1.
fn verifying(env: &Env<'_>) -> Run {
    let mut run = with_two_trials(env);
    run.state = finish(&mut run, env, &env.defs(), &mut Vec::new());
    run
}

/// Records a trial at `x` (a point of `run.knobs`) that met /cmd_vel and
/// gave detection `det`.
fn push_trial(run: &mut Run, env: &Env<'_>, x: &[f64], det: f64) {
    push_trial_at(run, env, x, &OK, det);
}

/// Records a trial at `x` that measured /cmd_vel `cmd` and detection `det`.
fn push_trial_at(run: &mut Run, env: &Env<'_>, x: &[f64], cmd: &[f64], det: f64) {
    let Input::Measured(r) = report(cmd, det) else {
        unreachable!()
    };
    run.trials.push(TrialRecord {
        config: run.knobs.to_config(x),
        x: x.to_vec(),
        eval: measure::evaluate(&env.defs(), &r, Default::default()),
        censored: false,
    });
}

/// A trial that fails its verification revises what the optimizer learned
/// of it: its core value becomes the worst the verification measured (here
/// every window at 30 Hz against 35), so the models no longer count it as
/// feasible. With trials left in the budget, the search goes on with the
/// optimizer's next trial before the failed trial backs off; the back-off
/// is set aside for the next failure. Once per failure: when the search
/// stops again, the best trial not rejected (trial 0) is verified, and
/// when that fails with the budget spent, the set-aside back-off is next.
#[test]
fn a_failed_verification_with_trials_left_revises_the_models_and_searches_on() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let defs = env.defs();
    let mut run = with_two_trials(&env);
    let settings = configbot_optimizer::Settings {
        max_trials: 6,
        candidates: 50,
        refine_steps: 2,
        ..Default::default()
    };
    let problem = outcome::problem(&run.knobs, &defs, &env).unwrap();
    let mut o = configbot_optimizer::Optimizer::new(problem, settings, &[1.0, 1.5]).unwrap();
    for t in &run.trials {
        o.tell(outcome::observation(t)).unwrap();
    }
    run.optimizer = Some(o);
    run.state = finish(&mut run, &env, &defs, &mut Vec::new());
    assert_verifies_trial_as_measured(&run, 1);

    let (mut failed, out) = verify(run, &env, &[30.0; 10]);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "SearchingOn"]);
    assert!(
        event_text(&out[1]).contains(
            "trial 1 failed its verification with 3 of 5 trials left: the search goes on"
        ),
        "{out:?}"
    );
    assert_eq!(name(&failed.state), "TrialApply");
    let told = failed.optimizer.as_ref().unwrap().observations();
    assert_eq!(
        told[1].constraints,
        vec![30.0],
        "trial 1 as its verification measured it"
    );
    assert_eq!(told[0].constraints, vec![40.0], "trial 0 as measured");
    assert_eq!(
        failed.trials[1].eval.constraints,
        vec![40.0],
        "the record stays"
    );
    let set_aside = failed.deferred_backoff.expect("the back-off waits");
    assert_eq!((set_aside.index, set_aside.step), (1, 1));

    // The search stops again: no second search for the same failure.
    let mut out = Vec::new();
    let next = finish(&mut failed, &env, &defs, &mut out);
    assert!(!reasons(&out).contains(&"SearchingOn"), "{out:?}");
    assert_eq!(
        next,
        State::VerifyApply {
            candidate: Candidate::Trial { index: 0 },
            config: failed.trials[0].config.clone()
        }
    );

    // Trial 0 fails with the budget spent: trial 1's back-off, set aside.
    for det in [1.0, 2.0, 3.0] {
        push_trial(&mut failed, &env, &[0.5, 1.5], det);
    }
    failed.state = next;
    let (backing, out) = verify(failed, &env, &[30.0; 10]);
    assert!(!reasons(&out).contains(&"SearchingOn"), "{out:?}");
    assert!(reasons(&out).contains(&"BackingOff"), "{out:?}");
    let State::VerifyApply {
        candidate: Candidate::Backoff(b),
        ..
    } = &backing.state
    else {
        panic!("{:?}", backing.state)
    };
    assert_eq!((b.index, b.step), (1, 1));
}

/// The run's next step applies trial `index`'s config, as measured, to verify it.
fn assert_verifies_trial_as_measured(run: &Run, index: usize) {
    assert_eq!(
        run.state,
        State::VerifyApply {
            candidate: Candidate::Trial { index },
            config: run.trials[index].config.clone()
        }
    );
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

/// A verification whose every window met 35 Hz but whose spread predicts
/// misses (mean 38.25, sd 2.3: bound 32.9) is not failed on the bound from
/// ten windows: it is measured on to the minute and judged by the minute's
/// windows, as a bursty run's is (there to the record). A window missed in
/// the first ten fails it at once. Where a measurement as long as the
/// minute is judged by its bound, the shortfall names it.
#[test]
fn a_verification_whose_windows_held_but_spread_predicts_misses_is_measured_on() {
    use crate::outcome::shortfall;
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let mut run = verifying(&env);
    let wide = [40.0, 36.0, 40.0, 40.0, 35.5, 40.0, 36.0, 40.0, 40.0, 35.0];
    let (on, out) = verify(run.clone(), &env, &wide);
    assert_eq!(reasons(&out), vec!["NearBoundary"]);
    assert!(
        event_text(&out[0]).contains(
            "trial 1 held over 10 s, with less margin than a minute without a miss needs (2.92·sd); measuring on to 60 s"
        ),
        "{out:?}"
    );
    assert_eq!(name(&on.state), "Verify");
    let (held, out) = step(on.clone(), report(&wide.repeat(5), 9.0), &env);
    assert_eq!(reasons(&out), vec!["Satisfied", "<save>"]);
    assert_eq!(name(&held.state), "Monitor");
    let mut one_miss = wide.repeat(5);
    one_miss[23] = 34.0;
    let (failed, out) = step(on, report(&one_miss, 9.0), &env);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
    assert!(
        event_text(&out[0]).contains("trial 1 held in only 98.3 % of the windows"),
        "{out:?}"
    );
    assert!(matches!(
        failed.state,
        State::VerifyApply {
            candidate: Candidate::Backoff(Backoff { index: 1, .. }),
            ..
        }
    ));

    let mut missed = wide;
    missed[4] = 34.0;
    let (failed, out) = verify(run.clone(), &env, &missed);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
    assert!(
        event_text(&out[0]).contains("trial 1 held in only 90.0 % of the windows"),
        "{out:?}"
    );
    assert_eq!(name(&failed.state), "VerifyApply");

    let Input::Measured(r) = report(&wide, 9.0) else {
        panic!("a report")
    };
    let eval = measure::evaluate(&env.defs(), &r, Default::default());
    let text = shortfall(&env.defs(), &eval, false);
    assert!(
        text.contains("held in 100.0 % of the windows, but their spread predicts misses: cmd of 32.9 by mean − 2.33·sd"),
        "{text}"
    );

    run.bursty = true;
    let (on, out) = verify(run, &env, &wide);
    assert_eq!(reasons(&out), vec!["NearBoundary"], "bursty: {out:?}");
    assert_eq!(name(&on.state), "Verify", "measuring on to the record");
}

/// A verification that holds, but by less than the bar's margin (every window
/// on target, mean 38.1, sd 1.14: 2.33 sd clears 35 Hz, 2.92 sd does not),
/// is measured on to a minute and judged as the bar judges a minute, by its
/// windows: with one of 60 missed it fails; with none it holds, even where
/// the minute's spread puts its bound below the target.
#[test]
fn a_verification_short_of_the_bar_is_measured_on_to_the_minute() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let run = verifying(&env);
    let close = [39.0, 37.0, 39.0, 39.0, 36.75, 39.0, 37.0, 39.0, 39.0, 36.5];
    let (on, out) = verify(run, &env, &close);
    assert_eq!(reasons(&out), vec!["NearBoundary"]);
    assert!(
        event_text(&out[0]).contains(
            "trial 1 held over 10 s, with less margin than a minute without a miss needs (2.92·sd); measuring on to 60 s"
        ),
        "{out:?}"
    );
    assert!(matches!(
        on.state,
        State::Verify {
            so_far: Some(_),
            ..
        }
    ));
    let Effect::Measure(req) = effect(&on, &env) else {
        panic!("{:?}", on.state)
    };
    assert_eq!(req.duration_ms, 10_000, "the minute's next piece");

    let rest = close.repeat(5);
    let (held, out) = step(on.clone(), report(&rest, 9.0), &env);
    assert_eq!(reasons(&out), vec!["Satisfied", "<save>"]);
    assert_eq!(held.verified.as_ref().map(|e| e.satisfaction), Some(1.0));
    assert_eq!(name(&held.state), "Monitor");

    let wide_on_target = [35.0, 41.0].repeat(25);
    let (held, out) = step(on.clone(), report(&wide_on_target, 9.0), &env);
    let minute = held.verified.as_ref().expect("verified");
    assert!(!minute.feasible, "the minute's bound misses: {minute:?}");
    assert_eq!(reasons(&out), vec!["Satisfied", "<save>"]);

    let mut one_miss = rest.clone();
    one_miss[37] = 34.0;
    let (failed, out) = step(on, report(&one_miss, 9.0), &env);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
    assert!(
        event_text(&out[0]).contains("trial 1 held in only 98.3 % of the windows"),
        "{out:?}"
    );
    assert_eq!(name(&failed.state), "VerifyApply");
}

/// A verification measured on because its margin was short of the bar
/// holds once the windows measured so far clear it, every one on target:
/// ten steadier windows after the first ten (mean 38.1, sd 0.8 over the
/// twenty: 2.92 sd is 2.3 Hz of the 3.1 above 35) end it at 20 s, while
/// ten as spread as the first leave it short and it measures on.
#[test]
fn a_verification_measured_on_holds_once_its_windows_clear_the_bar() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let run = verifying(&env);
    let close = [39.0, 37.0, 39.0, 39.0, 36.75, 39.0, 37.0, 39.0, 39.0, 36.5];
    let (on, _) = verify(run, &env, &close);
    assert_eq!(name(&on.state), "Verify");

    let (held, out) = step(on.clone(), report(&[38.1; 10], 9.0), &env);
    assert_eq!(reasons(&out), vec!["NearBoundary", "Satisfied", "<save>"]);
    assert!(
        event_text(&out[0]).contains(
            "trial 1 held every window over 20 s, which clear the margin a minute without a miss needs (2.92·sd)"
        ),
        "{out:?}"
    );
    assert_eq!(name(&held.state), "Monitor");
    assert_eq!(held.verified.as_ref().map(|e| e.satisfaction), Some(1.0));

    let (still, out) = step(on, report(&close, 9.0), &env);
    assert!(out.is_empty(), "{out:?}");
    let Effect::Measure(req) = effect(&still, &env) else {
        panic!("{:?}", still.state)
    };
    assert_eq!(req.duration_ms, 10_000, "measuring on");
}

/// A trial that was measured on near the boundary, or any trial of a run
/// that has missed windows in a burst, is verified over the bar's whole
/// minute, even when its first windows clear the margin: steady windows
/// that end any other verification at 10 s go on in 10 s pieces to 60 s.
/// A miss in a piece fails it at once.
#[test]
fn a_trial_measured_at_the_boundary_is_verified_over_the_whole_minute() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let run = verifying(&env);
    let steady = [40.0; 10];
    let (held, out) = verify(run.clone(), &env, &steady);
    assert_eq!(
        reasons(&out),
        vec!["Satisfied", "<save>"],
        "clears the margin"
    );
    assert_eq!(name(&held.state), "Monitor");

    let mut near = run.clone();
    near.near_boundary_trials = vec![1];
    let mut burst = run;
    burst.burst_windows = 1;
    for run in [near, burst] {
        let (mut on, out) = verify(run, &env, &steady);
        assert_eq!(reasons(&out), vec!["NearBoundary"]);
        assert!(
            event_text(&out[0]).contains(
                "trial 1 held over 10 s, its trial was measured near a core target (or this run has missed windows in a burst), so it must hold the minute without a miss; measuring on to 60 s, stopping at the first miss"
            ),
            "{out:?}"
        );
        let mut one_miss = steady;
        one_miss[3] = 30.0;
        let (failed, out) = step(on.clone(), report(&one_miss, 9.0), &env);
        assert_eq!(reasons(&out)[0], "VerificationFailed", "{out:?}");
        assert_eq!(failed.rejected, vec![1]);
        for _ in 0..4 {
            let Effect::Measure(req) = effect(&on, &env) else {
                panic!("{:?}", on.state)
            };
            assert_eq!(req.duration_ms, 10_000);
            let (next, out) = step(on, report(&steady, 9.0), &env);
            assert!(out.is_empty(), "not ended by its margin: {out:?}");
            on = next;
        }
        let (held, out) = step(on, report(&steady, 9.0), &env);
        assert_eq!(reasons(&out), vec!["Satisfied", "<save>"]);
        assert_eq!(name(&held.state), "Monitor");
    }
}

/// In a run whose core windows missed while their means held
/// (`Run::bursty`), a verification that holds its first measurement is
/// measured on to `tuning.recordSeconds` (120) whatever its margin,
/// in pieces of 30 s, and judged at the first piece that misses a window.
/// The same run, not bursty, holds at once on the same windows.
#[test]
fn a_bursty_run_verifies_a_config_over_two_clean_minutes_stopping_at_the_first_miss() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let mut run = verifying(&env);
    let steady = [40.0; 10];
    let (held, out) = verify(run.clone(), &env, &steady);
    assert_eq!(reasons(&out), vec!["Satisfied", "<save>"], "not bursty");
    assert_eq!(name(&held.state), "Monitor");

    run.bursty = true;
    let (mut on, out) = verify(run, &env, &steady);
    assert_eq!(reasons(&out), vec!["NearBoundary"]);
    assert!(
        event_text(&out[0]).contains(
            "trial 1 held over 10 s, this run's core windows miss in bursts while their means hold, so a config must hold 120 s without a miss (tuning.recordSeconds); measuring on to 120 s, stopping at the first miss"
        ),
        "{out:?}"
    );
    for left in [110_000, 80_000, 50_000] {
        let Effect::Measure(req) = effect(&on, &env) else {
            panic!("{:?}", on.state)
        };
        assert_eq!(req.duration_ms, left.min(30_000), "{left} ms left");
        let (next, out) = step(on, report(&[40.0; 30], 9.0), &env);
        assert!(out.is_empty(), "{out:?}");
        assert_eq!(name(&next.state), "Verify");
        on = next;
    }
    let Effect::Measure(req) = effect(&on, &env) else {
        panic!("{:?}", on.state)
    };
    assert_eq!(req.duration_ms, 20_000, "the last piece");
    let (held, out) = step(on.clone(), report(&[40.0; 20], 9.0), &env);
    assert_eq!(reasons(&out), vec!["Satisfied", "<save>"]);
    let record = held.verified.as_ref().expect("verified");
    assert_eq!(record.satisfaction, 1.0);
    assert_eq!(name(&held.state), "Monitor");

    let mut one_miss = [40.0; 20];
    one_miss[7] = 30.0;
    let (failed, out) = step(on, report(&one_miss, 9.0), &env);
    assert_eq!(reasons(&out)[0], "VerificationFailed", "{out:?}");
    assert!(
        event_text(&out[0]).contains("trial 1 held in only 99.2 % of the windows"),
        "{out:?}"
    );
    assert_eq!(failed.rejected, vec![1]);
}

/// A verification that misses windows while every core mean holds (the
/// non-core apps burst; the core nodes are not short of CPU) weights the
/// core nodes once the run has missed [`outcome::BURST_EVIDENCE`] windows
/// so (one window alone fails the verification as any miss does): the same
/// trial is verified again with them at [`knobs::CORE_WEIGHT`], and every
/// config after it is weighted, its back-offs included; the unweighted
/// failure is forgotten. A verification that misses on average backs off
/// without weights.
#[test]
fn a_verification_that_misses_in_bursts_weights_the_core_nodes_and_verifies_again() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let mut run = with_two_trials(&env);
    run.knobs.core = vec!["/planner".into()];
    let mut out = Vec::new();
    run.state = finish(&mut run, &env, &env.defs(), &mut out);
    let weights = std::collections::BTreeMap::from([("/planner".to_string(), knobs::CORE_WEIGHT)]);
    let mut one = [40.0; 10];
    one[3] = 20.0;
    let (once, out) = verify(run.clone(), &env, &one);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
    assert!(!once.knobs.weighted && !once.bursty && once.burst_windows == 1);
    let mut burst = [40.0; 10];
    burst[3] = 30.0;
    burst[7] = 30.0;
    let (weighted, out) = verify(run.clone(), &env, &burst);
    assert_eq!(reasons(&out), vec!["CoreWeighted"]);
    assert!(
        event_text(&out[0]).contains(
            "trial 1 held 80.0 % of the windows while every core mean held its target (cmd 38.0)"
        ),
        "{out:?}"
    );
    assert!(weighted.knobs.weighted);
    assert!(
        weighted.bursty,
        "its verifications hold a longer record from now on"
    );
    assert!(weighted.rejected.is_empty() && weighted.failed_verifications.is_empty());
    let State::VerifyApply {
        candidate: Candidate::Trial { index: 1 },
        config,
    } = &weighted.state
    else {
        panic!("{:?}", weighted.state)
    };
    assert_eq!(config.cpu_weight, weights);
    assert_eq!(config.cpu, weighted.trials[1].config.cpu, "the same limits");

    let (backed, out) = verify(weighted, &env, &burst);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
    let State::VerifyApply {
        candidate: Candidate::Backoff(_),
        config,
    } = &backed.state
    else {
        panic!("{:?}", backed.state)
    };
    assert_eq!(config.cpu_weight, weights, "a back-off stays weighted");

    let (unweighted, out) = verify(run, &env, &BAD);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
    assert!(!unweighted.knobs.weighted);
    assert!(!unweighted.bursty);
    let State::VerifyApply { config, .. } = &unweighted.state else {
        panic!("{:?}", unweighted.state)
    };
    assert!(config.cpu_weight.is_empty(), "{config:?}");
}

/// Verify the run's current candidate to its end, every core window on
/// target and the detector at `det`: apply, settle, then each piece the
/// run asks for (a bursty run's record is measured on in pieces).
fn verify_through(run: Run, env: &Env<'_>, det: f64) -> (Run, Vec<Output>) {
    let (run, _) = step(run, Input::Applied, env);
    let (mut run, _) = step(run, Input::Slept, env);
    let mut all = Vec::new();
    while name(&run.state) == "Verify" {
        let Effect::Measure(req) = effect(&run, env) else {
            panic!("{:?}", run.state)
        };
        let windows = usize::try_from(req.duration_ms / 1000).unwrap();
        let (next, out) = step(run, report(&vec![40.0; windows], det), env);
        all.extend(out);
        run = next;
    }
    (run, all)
}

/// [`with_two_trials`] with a core node, its trial 1 (objective 0.9)
/// verified: the verification missed two windows in bursts, so the run
/// weights its core nodes and verifies trial 1 again, weighted.
fn reverifying_weighted(env: &Env<'_>) -> Run {
    let mut run = with_two_trials(env);
    run.knobs.core = vec!["/planner".into()];
    run.state = finish(&mut run, env, &env.defs(), &mut Vec::new());
    let mut burst = [40.0; 10];
    burst[3] = 30.0;
    burst[7] = 30.0;
    let (weighted, out) = verify(run, env, &burst);
    assert_eq!(reasons(&out), vec!["CoreWeighted"]);
    weighted
}

/// A trial verified again weighted whose first piece holds every window
/// with much less objective than the trial measured unweighted (the core
/// nodes' demand grows with the CPU they get, as Basic-NAV's navigation
/// loop's does) is set aside before its record, the weight dropped, and
/// the trial's first back-off is verified unweighted: kept when it holds
/// with more objective than the weighted config, which is verified again,
/// weighted, when the back-off gives less or the back-offs are spent. A
/// weighted verification that keeps the trial's objective is measured to
/// its record and monitored as before.
#[test]
fn a_weight_that_costs_more_objective_than_a_back_off_promises_is_dropped_for_the_back_off() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let weights = std::collections::BTreeMap::from([("/planner".to_string(), knobs::CORE_WEIGHT)]);

    let (kept, out) = verify_through(reverifying_weighted(&env), &env, 9.0);
    assert_eq!(reasons(&out), vec!["NearBoundary", "Satisfied", "<save>"]);
    assert_eq!(name(&kept.state), "Monitor");
    assert!(kept.knobs.weighted && kept.weighted_fallback.is_none());

    // Weighted, the detector falls to 4.5 (objective 0.45); a back-off of
    // trial 1 (0.9) to 80 % promises 0.72.
    let (unweighted, out) = verify_through(reverifying_weighted(&env), &env, 4.5);
    assert_eq!(reasons(&out), vec!["CoreUnweighted", "BackingOff"]);
    assert!(
        event_text(&out[0]).contains(
            "trial 1 held every window of 10 s weighted at objective 0.450, where it measured 0.900 unweighted: the core nodes' weight takes more from the non-core apps than backing the trial off to 80 % promises (0.720)"
        ),
        "{out:?}"
    );
    assert!(!unweighted.knobs.weighted && unweighted.weight_declined);
    assert_eq!(unweighted.rejected, vec![1]);
    let fallback = unweighted.weighted_fallback.clone().expect("set aside");
    assert_eq!(fallback.config.cpu_weight, weights);
    let State::VerifyApply {
        candidate:
            Candidate::Backoff(Backoff {
                index: 1,
                fraction,
                step: 1,
                ..
            }),
        config,
    } = &unweighted.state
    else {
        panic!("{:?}", unweighted.state)
    };
    assert!((fraction - 0.8).abs() < 1e-9);
    assert!(config.cpu_weight.is_empty(), "{config:?}");

    // The back-off holds at 0.8: kept, unweighted.
    let (better, out) = verify_through(unweighted.clone(), &env, 8.0);
    assert_eq!(reasons(&out), vec!["NearBoundary", "Satisfied", "<save>"]);
    let State::Monitor { config, .. } = &better.state else {
        panic!("{:?}", better.state)
    };
    assert!(config.cpu_weight.is_empty());
    assert!(better.weighted_fallback.is_none() && !better.knobs.weighted);

    // The back-off holds at 0.4: the weighted config is verified again,
    // to its record this time, and monitored.
    let (back, out) = verify_through(unweighted.clone(), &env, 4.0);
    assert_eq!(
        reasons(&out),
        vec!["NearBoundary", "Satisfied", "CoreWeighted"]
    );
    assert!(
        event_text(&out[2]).contains(
            "no unweighted config held with more objective than trial 1 weighted (0.450): verifying it again"
        ),
        "{out:?}"
    );
    let again = State::VerifyApply {
        candidate: Candidate::Trial { index: 1 },
        config: fallback.config.clone(),
    };
    assert_eq!(back.state, again);
    assert!(back.knobs.weighted && back.weighted_fallback.is_none());
    let (kept, out) = verify_through(back, &env, 4.5);
    assert_eq!(reasons(&out), vec!["NearBoundary", "Satisfied", "<save>"]);
    assert_eq!(kept.applied, Some(Candidate::Trial { index: 1 }));
    let State::Monitor { config, .. } = &kept.state else {
        panic!("{:?}", kept.state)
    };
    assert_eq!(config.cpu_weight, weights);

    // The back-off misses in bursts: the run is not weighted again; the
    // next back-offs (64 % and 51 %, promising 0.576 and 0.461, more than
    // the weighted config's 0.45) are verified; when they miss too, the
    // back-offs are spent and the weighted config is verified again.
    let mut burst = [40.0; 10];
    burst[3] = 30.0;
    burst[7] = 30.0;
    let mut run = unweighted;
    for want in [0.64, 0.512] {
        let (next, out) = verify(run, &env, &burst);
        assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
        assert!(!next.knobs.weighted);
        let State::VerifyApply {
            candidate: Candidate::Backoff(b),
            config,
        } = &next.state
        else {
            panic!("{:?}", next.state)
        };
        assert!((b.fraction - want).abs() < 1e-9, "{b:?}");
        assert!(config.cpu_weight.is_empty());
        run = next;
    }
    let (spent, out) = verify(run, &env, &burst);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "CoreWeighted"]);
    assert_eq!(spent.state, again);

    // Weighted at 0.5, the weighted config outbids the 51 % back-off
    // (0.461): verified again once the 64 % one misses.
    let (half, out) = verify_through(reverifying_weighted(&env), &env, 5.0);
    assert_eq!(reasons(&out)[0], "CoreUnweighted", "{out:?}");
    let (at_64, out) = verify(half, &env, &burst);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
    let (back, out) = verify(at_64, &env, &burst);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "CoreWeighted"]);
    assert_eq!(name(&back.state), "VerifyApply");
    assert!(back.knobs.weighted);
}

#[test]
fn a_best_trial_failing_verification_is_backed_off_before_the_next_best() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let mut run = verifying(&env);
    assert_verifies_trial_as_measured(&run, 1);
    // Three back-off steps of /detector's CPU, /planner's kept: 0.1 + f × 1.8.
    let mut fractions = Vec::new();
    for _ in 0..3 {
        let (r, out) = verify(run, &env, &BAD);
        run = r;
        assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
        let State::VerifyApply {
            candidate:
                Candidate::Backoff(Backoff {
                    index: 1, fraction, ..
                }),
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
    assert_eq!(
        reasons(&out),
        vec!["VerificationFailed", "VerifyingNextBest"]
    );
    assert_verifies_trial_as_measured(&run, 0);
    assert_eq!(run.rejected, vec![1]);
    let (run, out) = verify(run, &env, &BAD);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "Unsat"]);
    assert_eq!(run.rejected, vec![1, 0]);
}

#[test]
fn a_backed_off_config_that_holds_is_monitored_learned_and_shown() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let run = verifying(&env);
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
    let status = crate::status::status(&Default::default(), &run, &env.defs(), 5, 1, "now");
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
        feeds: Vec::new(),
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
    assert_eq!(run.phase(), configbot_manifests::Phase::Satisfied);
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
        push_trial(&mut run, &env, &x, det);
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
        feeds: Vec::new(),
    };
    let space = |ks: Vec<knobs::KnobDef>| KnobSpace {
        knobs: ks,
        period_micros: 20_000,
        ..KnobSpace::default()
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

/// A held trial config tips: the next best is verified before relearning,
/// the run's trials kept; if it holds it is monitored (and learned, and a
/// second tip relearns), if not the run relearns cold.
#[test]
fn a_held_config_that_tips_verifies_the_next_best_before_relearning_cold() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let run = verifying(&env);
    let (run, out) = verify(run, &env, &OK);
    assert_eq!(reasons(&out), vec!["Satisfied", "<save>"]);
    // Trial 1's config tips after its verification.
    let (tipped, out) = step(run, report(&BAD, 5.0), &env);
    assert_eq!(
        reasons(&out),
        vec!["ConstraintViolated", "VerifyingNextBest"]
    );
    assert_verifies_trial_as_measured(&tipped, 0);
    assert_eq!(tipped.rejected, vec![1]);
    assert_eq!(tipped.trials.len(), 2, "the run's trials are kept");

    let (held, out) = verify(tipped.clone(), &env, &OK);
    assert_eq!(reasons(&out), vec!["Satisfied", "<save>"]);
    assert_eq!(name(&held.state), "Monitor");
    assert_eq!(held.tipped, None);
    assert_eq!(held.applied, Some(Candidate::Trial { index: 0 }));
    // The retry is spent: a second tip relearns.
    let (again, out) = step(held, report(&BAD, 5.0), &env);
    assert_eq!(reasons(&out), vec!["ConstraintViolated"]);
    assert_eq!(name(&again.state), "Observe");

    let (failed, out) = verify(tipped, &env, &BAD);
    assert_eq!(reasons(&out), vec!["VerificationFailed"]);
    let State::Observe {
        trigger: Trigger::ConstraintViolated { .. },
        skip_library: true,
    } = failed.state
    else {
        panic!("{:?}", failed.state)
    };
    assert_eq!(failed.rejected, vec![1, 0]);
    assert!(!failed.edges.is_empty(), "the failure left an edge");
    let mut failed = failed;
    failed.deferred_backoff = Some(Backoff {
        index: 1,
        fraction: 0.8,
        step: 1,
        shaped: false,
    });
    let (cold, _) = step(failed, observed(true), &env);
    let State::Baseline { prior: None, .. } = cold.state else {
        panic!("relearns cold: {:?}", cold.state)
    };
    assert!(cold.trials.is_empty() && cold.tipped.is_none());
    // Nothing of the old trials survives: no edge, no back-off set aside.
    assert!(cold.edges.is_empty() && cold.deferred_backoff.is_none());
}

/// Nothing to fall back on: a tipped config whose run has no other feasible
/// trial, or one from the library, relearns at once.
#[test]
fn a_tipped_config_with_nothing_else_to_try_relearns_at_once() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let monitoring = |applied| {
        let mut run = with_two_trials(&env);
        run.trials.truncate(1);
        run.applied = Some(applied);
        run.state = State::Monitor {
            satisfied: true,
            config: cfg(),
        };
        run
    };
    for applied in [
        Candidate::Trial { index: 0 },
        Candidate::Library { profile: profile() },
    ] {
        let (run, out) = step(monitoring(applied.clone()), report(&BAD, 5.0), &env);
        assert_eq!(reasons(&out), vec!["ConstraintViolated"], "{applied:?}");
        assert_eq!(name(&run.state), "Observe", "{applied:?}");
        assert!(run.tipped.is_none());
    }
}

/// The baseline of `cmd` values `base` measured; the run then applies its
/// first trial (the restrictive corner), and that trial measures `first`.
/// How much of a trial in `TrialProfile` is measured so far, in ms.
fn partial_ms(run: &Run) -> u64 {
    let State::TrialProfile {
        partial: Some(p), ..
    } = &run.state
    else {
        panic!("{:?}", run.state)
    };
    p.duration_ms
}

fn baseline_then_first_trial(env: &Env<'_>, base: &[f64], first: Input) -> (Run, Vec<Output>) {
    let (run, out) = step(
        with(State::Baseline {
            graph: graph(),
            prior: None,
        }),
        report(base, 5.0),
        env,
    );
    assert_eq!(reasons(&out), vec!["Baseline", "FeasibilityFirst"]);
    let State::TrialApply { x, config } = &run.state else {
        panic!("{:?}", run.state)
    };
    // The corner: every non-core knob at its minimum.
    let lows: Vec<f64> = run.knobs.knobs.iter().map(|k| k.min).collect();
    assert_eq!(x, &lows);
    assert_eq!(config.cpu["/detector"], 0.05);
    let (run, _) = step(run, Input::Applied, env);
    step(run, first, env)
}

#[test]
fn a_stack_whose_restrictive_corner_fails_ends_unsat_after_that_one_trial() {
    let (st, sp) = (stack(), spec(0.0, 20));
    let env = env(&st, &sp);
    let (run, out) = baseline_then_first_trial(&env, &BAD, report(&[30.0; 5], 0.0));
    assert_eq!(run.trials.len(), 1);
    assert_eq!(reasons(&out), vec!["Trial", "Unsat"]);
    assert_eq!(name(&run.state), "UnsatApply");
    let reason = run.reason.clone().unwrap();
    assert!(
        reason.contains("most restrictive config (trial 0") && reason.contains("cmd"),
        "{reason}"
    );
    assert!(!reason.contains("at most -"), "{reason}");
}

#[test]
fn a_feasible_restrictive_corner_goes_on_searching_from_it() {
    let (st, sp) = (stack(), spec(0.0, 20));
    let env = env(&st, &sp);
    let (run, out) = baseline_then_first_trial(&env, &BAD, report(&OK, 2.0));
    assert_eq!(reasons(&out), vec!["Trial"]);
    assert!(run.trials[0].feasible());
    assert_eq!(name(&run.state), "TrialApply", "the search goes on");
    assert_eq!(run.optimizer.as_ref().unwrap().observations().len(), 2);
}

#[test]
fn a_corner_that_missed_in_bursts_is_measured_again_weighted_before_any_verdict() {
    let (st, sp) = (stack(), spec(0.0, 20));
    let env = env(&st, &sp);
    // Three windows of five on target, the mean (37) above 35: bursts.
    let bursty = [40.0, 40.0, 30.0, 30.0, 45.0];
    let (run, out) = baseline_then_first_trial(&env, &BAD, report(&bursty, 0.0));
    assert_eq!(
        reasons(&out),
        vec!["Trial", "CoreWeighted", "FeasibilityFirst"]
    );
    assert!(event_text(&out[2]).contains("again with the core nodes weighted"));
    let State::TrialApply { x, config } = &run.state else {
        panic!("{:?}", run.state)
    };
    assert_eq!(x, &run.trials[0].x, "the corner again");
    assert_eq!(config.cpu_weight.get("/planner"), Some(&knobs::CORE_WEIGHT));
    assert_eq!(run.corner_trial, Some(1));
    // Weighted, it misses clearly: now the verdict.
    let (again, _) = step(run.clone(), Input::Applied, &env);
    let (again, out) = step(again, report(&[30.0; 5], 0.0), &env);
    assert_eq!(reasons(&out), vec!["Trial", "Unsat"]);
    assert_eq!(name(&again.state), "UnsatApply");
    // Weighted, it holds: the search goes on from it.
    let (run, _) = step(run, Input::Applied, &env);
    let (run, out) = step(run, report(&OK, 2.0), &env);
    assert_eq!(reasons(&out), vec!["Trial"]);
    assert_eq!(name(&run.state), "TrialApply");
    assert_eq!(run.trials.len(), 2);
}

#[test]
fn the_design_after_a_feasible_corner_is_drawn_toward_it() {
    let (st, sp) = (stack(), spec(0.0, 20));
    let env = env(&st, &sp);
    let (run, _) = baseline_then_first_trial(&env, &BAD, report(&OK, 2.0));
    let opt = run.optimizer.as_ref().unwrap();
    let space = &opt.problem().space;
    let corner = space.to_unit(&run.trials[0].x);
    let anchor = space.to_unit(opt.settings().design_anchor.as_ref().expect("anchored"));
    assert!(
        anchor
            .iter()
            .zip(&corner)
            .all(|(a, c)| (a - c).abs() < 1e-3),
        "{anchor:?} vs the corner {corner:?}"
    );
    // The baseline missed (halved), the corner held (grown by half).
    assert_eq!(opt.design_scale(), 0.75);
    let State::TrialApply { x, .. } = &run.state else {
        panic!("{:?}", run.state)
    };
    let u = space.to_unit(x);
    assert!(
        u.iter()
            .zip(&corner)
            .all(|(u, c)| (u - c).abs() <= 0.75 + 1e-3),
        "{u:?} is no nearer the corner {corner:?}"
    );
    // A baseline that holds has no corner to anchor at.
    let (run, _) = step(
        with(State::Baseline {
            graph: graph(),
            prior: None,
        }),
        report(&OK, 2.0),
        &env,
    );
    let opt = run.optimizer.as_ref().expect("a search");
    assert!(opt.settings().design_anchor.is_none());
    assert_eq!(opt.design_scale(), 1.0);
}

#[test]
fn a_run_whose_objectives_are_all_capped_stops_early_and_verifies() {
    let (st, sp) = (stack(), spec(0.0, 20));
    let env = env(&st, &sp);
    // The corner already meets cmd and gives the detector its 10 Hz cap.
    let (run, out) = baseline_then_first_trial(&env, &BAD, report(&OK, 10.0));
    assert_eq!(reasons(&out), vec!["Trial", "ObjectivesCapped"]);
    assert_eq!(run.trials.len(), 1, "one trial of 20");
    // Its config is applied and was just measured: the verification
    // measures on, in new windows, without a drain, an apply or a settle.
    assert_eq!(
        run.state,
        State::Verify {
            candidate: Candidate::Trial { index: 0 },
            config: run.trials[0].config.clone(),
            so_far: None,
        }
    );
    assert_eq!(
        effect(&run, &env),
        Effect::Measure(measure::request(&env.defs(), &[], 10_000, 1000)),
        "two trials' length of its own"
    );
    // Had another config been applied since, it is applied again first.
    let mut moved = run.clone();
    moved.current = ResourceConfig::default();
    let mut out = Vec::new();
    moved.state = finish(&mut moved, &env, &env.defs(), &mut out);
    assert_verifies_trial_as_measured(&moved, 0);
}

#[test]
fn a_capped_trial_that_misses_a_core_target_ends_the_initial_design() {
    let (st, sp) = (stack(), spec(0.0, 20));
    let env = env(&st, &sp);
    let (run, out) = baseline_then_first_trial(&env, &BAD, report(&OK, 2.0));
    assert_eq!(reasons(&out), vec!["Trial"]);
    assert!(run.optimizer.as_ref().unwrap().design_left() > 0);
    // The design's next point gives the detector its 10 Hz cap and starves cmd.
    let (run, _) = step(run, Input::Applied, &env);
    let (run, out) = step(run, report(&[20.0; 5], 10.0), &env);
    assert_eq!(reasons(&out), vec!["Trial", "DesignEnded"]);
    assert!(!run.trials[1].feasible() && !run.trials[1].censored);
    assert!(
        event_text(&out[1]).contains("trial 1 gives every objective its cap"),
        "{out:?}"
    );
    assert_eq!(run.optimizer.as_ref().unwrap().design_left(), 0);
    assert_eq!(name(&run.state), "TrialApply", "the models' proposal");
    // An uncapped miss leaves the design alone.
    let (run, out) = baseline_then_first_trial(&env, &BAD, report(&OK, 2.0));
    assert_eq!(reasons(&out), vec!["Trial"]);
    let left = run.optimizer.as_ref().unwrap().design_left();
    let (run, _) = step(run, Input::Applied, &env);
    let (run, out) = step(run, report(&[20.0; 5], 5.0), &env);
    assert_eq!(reasons(&out), vec!["Trial"]);
    assert_eq!(run.optimizer.as_ref().unwrap().design_left(), left - 1);
}

#[test]
fn a_trial_near_the_boundary_is_measured_longer_not_discarded() {
    let (st, sp) = (stack(), spec(0.0, 20));
    let env = env(&st, &sp);
    // Five windows on target but spread: the normal bound misses 35 (34.0).
    let spread = [37.0, 40.0, 36.0, 40.0, 38.0];
    let (run, out) = baseline_then_first_trial(&env, &BAD, report(&spread, 2.0));
    assert_eq!(reasons(&out), vec!["NearBoundary"]);
    assert!(run.trials.is_empty());
    assert_eq!(partial_ms(&run), 5000);
    assert_eq!(
        effect(&run, &env),
        Effect::Measure(measure::with_usage(
            measure::request(&env.defs(), &[], 5000, 1000),
            &run.knobs.non_core_nodes()
        )),
        "on to ten windows, the non-core nodes' CPU use beside the metrics"
    );
    // Five steadier windows: the ten windows' bound holds (35.5); feasible.
    let steady = [39.0, 38.0, 39.0, 39.0, 38.0];
    let (longer, out) = step(run.clone(), report(&steady, 2.0), &env);
    assert_eq!(reasons(&out), vec!["Trial"]);
    assert!(longer.trials[0].feasible(), "{:?}", longer.trials[0].eval);
    assert_eq!(
        longer.near_boundary_trials,
        vec![0],
        "its verification must hold the minute"
    );
    // Five more as spread: the bound of the ten (34.3) misses, but every
    // window held, and ten windows on target are what a verification's
    // first measurement asks: feasible by its windows, the models learning
    // its worst window (36), and its verification held to the minute.
    let (longer, out) = step(run.clone(), report(&spread, 2.0), &env);
    assert_eq!(reasons(&out), vec!["Trial"]);
    assert!(longer.trials[0].feasible(), "{:?}", longer.trials[0].eval);
    assert_eq!(longer.trials[0].eval.constraints, vec![36.0]);
    assert!(
        event_text(&out[0]).contains("feasible by its windows (all 10 held)"),
        "{out:?}"
    );
    assert!(!longer.bursty && !longer.knobs.weighted, "no window missed");
    assert_eq!(longer.near_boundary_trials, vec![0]);
    // A corner that missed one window of ten is infeasible, but it mostly
    // held, so it is near the boundary: no Unsat from it, the search goes
    // on ...
    let one_low = [38.0, 38.5, 34.0, 38.5, 38.0];
    let (mut longer, out) = step(run.clone(), report(&one_low, 2.0), &env);
    assert_eq!(reasons(&out), vec!["Trial"]);
    assert!(!longer.trials[0].feasible());
    assert_eq!(longer.trials[0].eval.satisfaction, 0.9);
    assert_eq!(name(&longer.state), "TrialApply");
    // ... and if no trial does better, the corner is verified over a longer
    // window before any verdict.
    let mut out = Vec::new();
    let end = finish(&mut longer, &env, &env.defs(), &mut out);
    assert_eq!(
        end,
        State::Verify {
            candidate: Candidate::Trial { index: 0 },
            config: longer.trials[0].config.clone(),
            so_far: None,
        },
        "the corner is still applied: measured on"
    );
    assert!(out.is_empty(), "{out:?}");
    // Its mean held: the miss was a burst, but one window is not yet
    // evidence enough to weight the core nodes (`outcome::BURST_EVIDENCE`) ...
    assert_eq!(longer.burst_windows, 1);
    assert!(!longer.knobs.weighted && !longer.bursty);
    // ... two are: the configs after it weight the core nodes.
    let two_low = [38.0, 38.5, 34.0, 38.5, 34.5];
    let (longer, out) = step(run, report(&two_low, 2.0), &env);
    assert_eq!(reasons(&out), vec!["Trial", "CoreWeighted"]);
    assert_eq!(longer.trials[0].eval.satisfaction, 0.8);
    assert!(longer.bursty);
    let State::TrialApply { config, .. } = &longer.state else {
        panic!("{:?}", longer.state)
    };
    assert_eq!(config.cpu_weight["/planner"], knobs::CORE_WEIGHT);
    // A trial that misses in most windows is not near: recorded at once.
    let mostly_low = [30.0, 36.0, 30.0, 30.0, 30.0];
    let (run, out) = baseline_then_first_trial(&env, &BAD, report(&mostly_low, 2.0));
    assert_eq!(reasons(&out), vec!["Trial", "Unsat"], "the corner missed");
    assert!(!run.trials[0].feasible());
}

/// In a run whose core windows miss in bursts (`Run::bursty`), a trial is
/// judged as its verification and the bench's oracle judge a config, by its
/// windows: ten windows on target, spread so that the bound misses (the
/// same trial is infeasible in a run that is not bursty, above), are
/// feasible there, and the value the models learn is the worst window; one
/// window missed is infeasible.
#[test]
fn a_bursty_run_judges_a_trial_by_its_windows() {
    let (st, sp) = (stack(), spec(0.0, 20));
    let env = env(&st, &sp);
    let spread = [37.0, 40.0, 36.0, 40.0, 38.0];
    let (mut run, _) = baseline_then_first_trial(&env, &BAD, report(&spread, 2.0));
    run.bursty = true;
    let (held, out) = step(run.clone(), report(&spread, 2.0), &env);
    assert_eq!(reasons(&out), vec!["Trial"]);
    let trial = &held.trials[0];
    assert!(trial.feasible(), "{:?}", trial.eval);
    assert_eq!(trial.eval.constraints, vec![36.0], "the worst window");
    assert!(
        event_text(&out[0])
            .contains("satisfaction 100.0 %, objective 0.200, feasible by its windows"),
        "{out:?}"
    );
    let mut one_low = spread;
    one_low[3] = 34.0;
    let (missed, _) = step(run, report(&one_low, 2.0), &env);
    assert!(!missed.trials[0].feasible(), "{:?}", missed.trials[0].eval);
    assert_eq!(missed.trials[0].eval.constraints, vec![34.0]);
}

/// A trial among the best so far whose objective rests on few messages
/// (`measure::FEW_MESSAGES`) is measured on to the extended length before
/// it is recorded: detection at 0.5 Hz counts 2.5 messages in 5 s, where
/// one message more or less moves its objective by two fifths. One with
/// enough messages is recorded at once, and so is a thin trial well below
/// an earlier best: a longer measurement would not make it the best. The
/// restrictive corner, the run's first trial here, is recorded at once
/// however thin: its objective is the least any config gives.
#[test]
fn a_contender_on_few_messages_is_measured_longer() {
    let (st, sp) = (stack(), spec(0.0, 20));
    let env = env(&st, &sp);
    let (corner, out) = baseline_then_first_trial(&env, &BAD, report(&OK, 0.5));
    assert_eq!(corner.corner_trial, Some(0));
    assert_eq!(reasons(&out).first(), Some(&"Trial"), "{out:?}");
    assert_eq!(corner.trials[0].eval.objective, Some(0.05));
    // The next trial, as thin and as good, is measured on.
    let (run, _) = step(corner.clone(), Input::Applied, &env);
    assert_eq!(name(&run.state), "TrialProfile");
    let (run, out) = step(run, report(&OK, 0.5), &env);
    assert_eq!(reasons(&out), vec!["FewMessages"]);
    assert!(
        event_text(&out[0]).contains("trial 1: objective 0.050 is among the best so far but rests on few messages (det 2.5 in 5 s); measuring up to 10 s"),
        "{out:?}"
    );
    assert_eq!(run.trials.len(), 1);
    assert_eq!(partial_ms(&run), 5000);
    let (longer, out) = step(run, report(&OK, 0.5), &env);
    assert_eq!(reasons(&out).first(), Some(&"Trial"), "{out:?}");
    assert_eq!(longer.trials.len(), 2);
    assert!(longer.trials[1].feasible());
    // With 2 s trials the extended length is five trials: a thin count is
    // recorded as measured.
    let mut short_spec = spec(0.0, 20);
    short_spec.spec.tuning.trial_seconds = 2.0;
    let short = super::env(&st, &short_spec);
    let (run, _) = baseline_then_first_trial(&short, &BAD, report(&OK[..2], 0.5));
    let (run, _) = step(run, Input::Applied, &short);
    let (run, out) = step(run, report(&OK[..2], 0.5), &short);
    assert_eq!(reasons(&out).first(), Some(&"Trial"), "{out:?}");
    assert_eq!(run.trials.len(), 2);
    // Ten messages in 5 s: recorded at once ...
    let (run, out) = baseline_then_first_trial(&env, &BAD, report(&OK, 2.0));
    assert_eq!(reasons(&out).first(), Some(&"Trial"), "{out:?}");
    assert_eq!(run.trials[0].eval.objective, Some(0.2));
    // ... and the next trial, thin but a quarter of that best, too.
    let (run, _) = step(run, Input::Applied, &env);
    assert_eq!(name(&run.state), "TrialProfile");
    let (run, out) = step(run, report(&OK, 0.5), &env);
    assert_eq!(reasons(&out).first(), Some(&"Trial"), "{out:?}");
    assert_eq!(run.trials.len(), 2);
    assert_eq!(run.trials[1].eval.objective, Some(0.05));
}

#[test]
fn with_every_knob_pinned_the_pinned_config_is_measured_before_a_verdict() {
    let st = stack();
    let mut sp = spec(0.0, 20);
    // No metric on the detector's output: the whole det app feeds no metric.
    sp.spec.metrics.retain(|m| m.name != "det");
    let env = env(&st, &sp);
    let (run, out) = step(
        with(State::Baseline {
            graph: graph(),
            prior: None,
        }),
        report(&BAD, 5.0),
        &env,
    );
    assert!(run.knobs.knobs.is_empty() && !run.knobs.pinned.is_empty());
    assert_eq!(reasons(&out), vec!["Baseline", "FeasibilityFirst"]);
    let State::TrialApply { config, .. } = &run.state else {
        panic!("{:?}", run.state)
    };
    assert_eq!(config.cpu["/detector"], 0.05);
    let (run, _) = step(run, Input::Applied, &env);
    let (run, out) = step(run, report(&OK, 5.0), &env);
    assert_eq!(
        reasons(&out),
        vec!["Trial", "ObjectivesCapped"],
        "no objectives"
    );
    assert_eq!(
        name(&run.state),
        "Verify",
        "the pinned config, still applied"
    );
}

/// A run whose trials had windows both on and off target verifies its pick
/// over [`crate::machine::NOISY_VERIFY_TRIALS`] trials' length, not two.
#[test]
fn a_run_that_saw_the_boundary_blur_verifies_longer() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let mut run = with_two_trials(&env);
    run.state = State::Verify {
        candidate: Candidate::Trial { index: 0 },
        config: cfg(),
        so_far: None,
    };
    let verify_ms = |run: &Run| match effect(run, &env) {
        Effect::Measure(r) => r.duration_ms,
        e => panic!("{e:?}"),
    };
    assert!(!crate::machine::boundary_blurred(&run), "every window held");
    assert_eq!(verify_ms(&run), 10_000, "two 5 s trials");
    // The same config missed /cmd_vel in 3 of its 10 windows.
    let mut cmd = OK.to_vec();
    cmd.resize(10, OK[0]);
    cmd[2..5].fill(20.0);
    let Input::Measured(r) = report(&cmd, 4.0) else {
        unreachable!()
    };
    run.trials.push(TrialRecord {
        config: cfg(),
        x: run.trials[0].x.clone(),
        eval: measure::evaluate(&env.defs(), &r, Default::default()),
        censored: false,
    });
    assert!(crate::machine::boundary_blurred(&run));
    assert_eq!(verify_ms(&run), 30_000, "six 5 s trials");
}

/// The next back-off fraction is where the line from the restrictive corner
/// to the failed verification crosses the target, kept within 0.4–0.8 of
/// the last fraction; without a corner (or when every bound held), 0.8.
#[test]
fn a_back_off_aims_where_the_line_from_the_corner_crosses_the_target() {
    use crate::outcome::next_fraction;
    let rate = MetricDef::rate_at_least("fps", "core", "/fps", 25.0, true);
    let mut latency = MetricDef::rate_at_least("lat", "core", "/lat", 100.0, true);
    latency.at_least = false;
    let objective = MetricDef::rate_at_least("det", "det", "/det", 3.0, false);
    let defs = [rate, objective];
    let near = |a: f64, b: f64| (a - b).abs() < 1e-9;
    // No corner measured: a fixed step.
    assert!(near(next_fraction(&defs, None, 1.0, &[24.0]), 0.8));
    // Corner 28.5 (3.5 above), verification 24.0 at 1 (1 below): 3.5 / 4.5.
    assert!(near(
        next_fraction(&defs, Some(&[28.5]), 1.0, &[24.0]),
        3.5 / 4.5
    ));
    // Far below (17.5): the secant says 0.32 of the way, kept at 0.4.
    assert!(near(next_fraction(&defs, Some(&[28.5]), 1.0, &[17.5]), 0.4));
    // Just below at 0.5: the secant says 0.49, kept at 0.8 × 0.5.
    assert!(near(
        next_fraction(&defs, Some(&[28.5]), 0.5, &[24.95]),
        0.4
    ));
    // The bound held (the windows missed): a fixed step.
    assert!(near(next_fraction(&defs, Some(&[28.5]), 0.5, &[25.5]), 0.4));
    // Two constraints, one at most: the first to reach its target decides.
    let both = [defs[0].clone(), latency];
    let f = next_fraction(&both, Some(&[28.5, 80.0]), 1.0, &[24.0, 120.0]);
    assert!(near(f, 0.5), "{f}");
}

/// A shaped back-off takes the point with the most predicted objective
/// among those predicted at least as safe as the uniform back-off, by each
/// constraint's pessimistic prediction (mean − sd at least, + sd at most).
#[test]
fn a_shaped_back_off_is_no_less_safe_by_the_models_and_promises_more() {
    use crate::outcome::safest_best;
    use configbot_optimizer::{Constraint, Prediction};
    let cons = [
        Constraint::at_least("fps", 25.0),
        Constraint::at_most("lat", 100.0),
    ];
    let p = |obj: f64, fps: (f64, f64), lat: (f64, f64)| Prediction {
        objective: Some((obj, 0.1)),
        constraints: vec![fps, lat],
    };
    // The uniform back-off: fps 28 ± 1 (27 pessimistic), latency 80 ± 5 (85).
    let uniform = p(0.4, (28.0, 1.0), (80.0, 5.0));
    let candidates = [
        p(0.9, (27.5, 1.0), (80.0, 5.0)), // more objective, fps less safe
        p(0.7, (29.0, 1.5), (79.0, 5.0)), // as safe on both (27.5, 84)
        p(0.8, (28.0, 1.0), (82.0, 5.0)), // latency less safe (87)
        p(0.6, (30.0, 0.5), (70.0, 2.0)), // safer, less objective than the one above
    ];
    assert_eq!(safest_best(&uniform, &candidates, &cons), Some(1));
    // Nothing safe promises more than the uniform back-off: keep it.
    assert_eq!(safest_best(&uniform, &candidates[..1], &cons), None);
    assert_eq!(
        safest_best(&p(0.95, (28.0, 1.0), (80.0, 5.0)), &candidates, &cons),
        None
    );
    // Without objective predictions (no complete trial) there is nothing to weigh.
    let blind = Prediction {
        objective: None,
        constraints: uniform.constraints.clone(),
    };
    assert_eq!(safest_best(&blind, &candidates, &cons), None);
}

/// With a measured corner the back-off aims at the target; after
/// [`BACKOFF_STEPS`] the next best trial is verified as measured.
#[test]
fn a_back_off_from_a_measured_corner_takes_the_secant_step() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let mut run = with_two_trials(&env);
    run.corner_trial = Some(0);
    let mut out = Vec::new();
    run.state = finish(&mut run, &env, &env.defs(), &mut out);
    let (run, out) = verify(run, &env, &BAD);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
    let State::VerifyApply {
        candidate: Candidate::Backoff(Backoff { fraction, step, .. }),
        ..
    } = run.state
    else {
        panic!("{:?}", run.state)
    };
    let corner = run.trials[0].eval.constraints[0];
    let Input::Measured(r) = report(&BAD, 9.0) else {
        panic!("a report")
    };
    let bound = measure::evaluate(&env.defs(), &r, Default::default()).constraints[0];
    let want = ((corner - 35.0) / (corner - bound)).clamp(0.4, 0.8);
    assert!((fraction - want).abs() < 1e-9, "{fraction} against {want}");
    assert_eq!(step, 1);
}

/// A back-off promises the line from the corner's objective to the pick's
/// (0 without a measured corner); a trial that measured at least that much
/// is verified instead, as measured, and the back-off is taken up again if
/// that trial fails too.
#[test]
fn a_trial_that_measured_more_than_a_back_off_promises_is_verified_instead() {
    use crate::outcome::backoff_promise;
    let near = |a: f64, b: f64| (a - b).abs() < 1e-9;
    assert!(near(backoff_promise(None, 0.9, 0.8), 0.72));
    assert!(near(backoff_promise(Some(0.04), 1.0, 0.63), 0.6448));
    assert!(
        near(backoff_promise(Some(0.5), 0.3, 0.5), 0.3),
        "never above the pick"
    );
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let mut run = with_two_trials(&env);
    // Trial 0 measured 0.8 at less CPU: more than trial 1 backed off to 80 %
    // (0.72), and with /cmd_vel at 60 Hz, beyond the edge trial 1's failure
    // leaves (its 40 Hz plus the 15 Hz its verification fell short).
    run.trials.clear();
    push_trial_at(&mut run, &env, &[1.0, 1.5], &[60.0; 5], 8.0);
    push_trial(&mut run, &env, &[1.9, 1.5], 9.0);
    let mut out = Vec::new();
    run.state = finish(&mut run, &env, &env.defs(), &mut out);
    let (run, out) = verify(run, &env, &BAD);
    assert_eq!(
        reasons(&out),
        vec!["VerificationFailed", "VerifyingNextBest"]
    );
    assert_verifies_trial_as_measured(&run, 0);
    let Output::Event { message, .. } = &out[1] else {
        panic!("{out:?}")
    };
    assert!(
        message.contains("trial 0 measured objective 0.800, no less than trial 1 backed off to 80 % promises (0.720)"),
        "{message}"
    );
    // Trial 0 fails too: the back-off set aside is taken up, not an Unsat.
    let (run, out) = verify(run, &env, &BAD);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
    let State::VerifyApply {
        candidate:
            Candidate::Backoff(Backoff {
                index: 1,
                fraction,
                step: 1,
                ..
            }),
        ..
    } = run.state
    else {
        panic!("{:?}", run.state)
    };
    assert!(near(fraction, 0.8), "{fraction}");
    assert_eq!(run.deferred_backoff, None);
}

#[test]
fn a_verification_that_missed_only_windows_is_told_as_at_its_target() {
    use crate::measure::Evaluation;
    use crate::outcome::as_failed;
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let defs = env.defs();
    let eval = |bound: f64| Evaluation {
        constraints: vec![bound],
        objectives: vec![2.0],
        ..Default::default()
    };
    // The /cmd_vel bound (target 35) missed: the models learn it as measured.
    assert_eq!(as_failed(&defs, eval(33.0)), eval(33.0));
    // Every bound held, yet windows missed: not a safe point, but at the target.
    assert_eq!(as_failed(&defs, eval(36.5)), eval(35.0));
}

#[test]
fn a_failed_verification_leaves_an_edge_that_a_trial_must_clear_to_be_verified_instead() {
    use crate::outcome::edges_after;
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let defs = env.defs();
    // Trial bound 36, verified at 33 against 35: out by the 2 Hz it fell short.
    let edges = edges_after(&defs, &[36.0], &[33.0]);
    assert_eq!(
        edges,
        vec![Edge {
            constraint: 0,
            beyond: 38.0,
            at_least: true
        }]
    );
    // Only windows missed (the bound held): the trial's own bound is the edge.
    assert_eq!(edges_after(&defs, &[36.0], &[35.5])[0].beyond, 36.0);
    // Trial 0 measured more than trial 1's back-off promises, but its
    // /cmd_vel bound (40 Hz) is no further from the target than trial 1's,
    // which failed: the back-off is verified, not trial 0.
    let mut run = with_two_trials(&env);
    run.trials.clear();
    for (x, det) in [([1.0, 1.5], 8.0), ([1.9, 1.5], 9.0)] {
        push_trial(&mut run, &env, &x, det);
    }
    let mut out = Vec::new();
    run.state = finish(&mut run, &env, &defs, &mut out);
    let (run, out) = verify(run, &env, &BAD);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
    let Output::Event { message, .. } = &out[0] else {
        panic!("{out:?}")
    };
    assert!(
        message
            .contains("trials are verified as measured first when their bound is cmd above 55.00"),
        "{message}"
    );
    assert_eq!(run.edges.len(), 1);
    assert_eq!(run.deferred_backoff, None);
    assert_eq!(search::best_clear_trial(&run), None);
    assert_eq!(
        search::best_trial(&run),
        Some(0),
        "still verified once the back-offs are spent"
    );
}

/// Once the back-offs of a failed trial are spent, a trial inside the edge
/// its failure left is verified before the one beyond it when it measured
/// clearly more objective (0.8 against 0.1), and says why; when it fails
/// too, the trial beyond the edge follows.
#[test]
fn with_the_back_offs_spent_a_trial_inside_an_edge_that_measured_more_is_verified_first() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let mut run = with_two_trials(&env);
    run.trials.clear();
    // Trial 0 gives the detector least and holds /cmd_vel at 60 Hz, beyond
    // the edge (55) trial 2's failure leaves; trial 1 sits as near 35 Hz
    // as trial 2.
    push_trial_at(&mut run, &env, &[0.1, 1.5], &[60.0; 5], 1.0);
    push_trial(&mut run, &env, &[1.0, 1.5], 8.0);
    push_trial(&mut run, &env, &[1.9, 1.5], 9.0);
    let mut out = Vec::new();
    run.state = finish(&mut run, &env, &env.defs(), &mut out);
    assert!(out.is_empty(), "no edge yet: {out:?}");
    assert_verifies_trial_as_measured(&run, 2);
    for _ in 0..3 {
        let (r, out) = verify(run, &env, &BAD);
        run = r;
        assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
    }
    assert_eq!(search::best_clear_trial(&run), Some(0));
    let (run, out) = verify(run, &env, &BAD);
    assert_eq!(
        reasons(&out),
        vec!["VerificationFailed", "VerifyingNextBest"]
    );
    assert!(
        event_text(&out[1]).contains(
            "trial 1 measured objective 0.800, more than trial 0 (0.100), the best beyond the edges"
        ),
        "{out:?}"
    );
    assert_verifies_trial_as_measured(&run, 1);
    let (run, out) = verify(run, &env, &BAD);
    assert_eq!(reasons(&out), vec!["VerificationFailed"]);
    assert_verifies_trial_as_measured(&run, 0);
    let (run, out) = verify(run, &env, &[60.0; 10]);
    assert_eq!(reasons(&out), vec!["Satisfied", "<save>"]);
    assert_eq!(run.rejected, vec![2, 1]);
}

/// What a shaped back-off is predicted to give is capped by what a
/// measurement that covers it gave: as much for the non-core apps on every
/// knob, the others the same.
#[test]
fn a_back_off_is_predicted_no_more_objective_than_a_measurement_that_covers_it() {
    use crate::outcome::objective_ceiling;
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let mut run = with_two_trials(&env);
    run.trials.clear();
    push_trial(&mut run, &env, &[1.0, 1.5], 4.0);
    push_trial(&mut run, &env, &[1.9, 1.5], 9.0);
    push_trial(&mut run, &env, &[1.9, 1.0], 2.0);
    let measured: Vec<&TrialRecord> = run.trials.iter().collect();
    let ceiling = |y: &[f64]| objective_ceiling(&run.knobs, y, &measured);
    let near = |a: Option<f64>, b: f64| a.is_some_and(|a| (a - b).abs() < 1e-9);
    // Covered by trials 0 and 1 (not 2: /planner, a core knob, differs):
    // the least of them plus a count's worth.
    assert!(near(ceiling(&[0.5, 1.5]), 0.4 + search::NEAR_BEST));
    assert!(near(ceiling(&[1.5, 1.5]), 0.9 + search::NEAR_BEST));
    assert!(near(ceiling(&[1.9, 1.0]), 0.2 + search::NEAR_BEST));
    // More for the detector than any measurement gave: nothing known.
    assert_eq!(ceiling(&[2.0, 1.5]), None);
    // A censored (stopped early) trial caps nothing.
    run.trials[0].censored = true;
    let measured: Vec<&TrialRecord> = run.trials.iter().collect();
    assert!(near(
        objective_ceiling(&run.knobs, &[0.5, 1.5], &measured),
        0.9 + search::NEAR_BEST
    ));
}

/// Drives a run from its baseline to Monitor (or Unsat) against a stand-in
/// robot: `trial` gives a config's /cmd_vel and detection rates as a trial
/// measures them, `verification` as a verification does (a trial's short
/// window may catch a luckier moment). Returns the run, every output and
/// each verified config with its candidate.
fn drive(
    run: Run,
    env: &Env<'_>,
    trial: impl Fn(&ResourceConfig) -> (f64, f64),
    verification: impl Fn(&ResourceConfig) -> (f64, f64),
) -> (Run, Vec<Output>, Vec<(Candidate, ResourceConfig)>) {
    let measured = |(cmd, det): (f64, f64)| {
        // ±0.2 Hz of window-to-window noise around the rate.
        let windows: Vec<f64> = (0..10)
            .map(|i| cmd + if i % 2 == 0 { 0.2 } else { -0.2 })
            .collect();
        report(&windows, det)
    };
    let (mut run, mut outs, mut verified) = (run, Vec::new(), Vec::new());
    for _ in 0..400 {
        let input = match &run.state {
            State::Monitor { .. } => return (run, outs, verified),
            State::TrialApply { .. }
            | State::VerifyApply { .. }
            | State::UnsatApply { .. }
            | State::Drain { applied: false, .. } => Input::Applied,
            State::Drain { config, .. } | State::TrialProfile { config, .. } => {
                measured(trial(config))
            }
            State::Baseline { .. } => measured(trial(&run.current)),
            State::Verify {
                candidate, config, ..
            } => {
                verified.push((candidate.clone(), config.clone()));
                measured(verification(config))
            }
            s => panic!("the driver does not answer {s:?}"),
        };
        let (next, out) = step(run, input, env);
        run = next;
        outs.extend(out);
    }
    panic!("no verdict after 400 steps: {:?}", run.state)
}

/// A failed verification backs off with each non-core knob at its own
/// fraction when the models predict more objective for that at no less
/// safety, says so, and never verifies a config that gives the non-core apps
/// as much on every knob as the failed trial or an earlier failed back-off.
/// Stand-in robot: as trials measure it, the detector's CPU costs navigation
/// little (0.5 Hz per CPU, 36.5 Hz at none), while detection is bounded by
/// the detector's CPU, the camera's and its input rate; a verification finds
/// /cmd_vel 2 Hz lower whenever the detector has more than 0.5 CPU, so the
/// capped trial (1.02 CPU) fails, the search goes on, its best new trial
/// fails too, and the capped trial backs off. (Measured with this seed:
/// three shaped back-offs, the first two failed, each moved the knobs
/// differently and none gave as much as an earlier failure.)
#[test]
fn a_shaped_back_off_is_verified_and_never_gives_as_much_as_a_failure() {
    let (st, sp) = (stack(), spec(0.0, 12));
    let env = env(&st, &sp);
    let cpu = |cfg: &ResourceConfig, n: &str| cfg.cpu.get(n).copied().unwrap_or(2.0);
    let trial = |cfg: &ResourceConfig| {
        let input = cfg
            .adaptors
            .iter()
            .find(|a| a.subscriber == "/detector")
            .map_or(30.0, |a| a.rate_hz);
        let (d, c) = (cpu(cfg, "/detector"), cpu(cfg, "/camera"));
        (36.5 - 0.5 * d, (10.0 * d).min(20.0 * c).min(input))
    };
    let verification = |cfg: &ResourceConfig| {
        let (cmd, det) = trial(cfg);
        let loss = if cpu(cfg, "/detector") > 0.5 {
            2.0
        } else {
            0.0
        };
        (cmd - loss, det)
    };
    let start = with(State::Baseline {
        graph: graph(),
        prior: None,
    });
    let (run, outs, verified) = drive(start, &env, trial, verification);
    // Each back-off against its trial and the back-offs verified before it
    // (all failed, or the run would have stopped there).
    let mut earlier: Vec<Vec<f64>> = Vec::new();
    let mut shaped = 0;
    for (candidate, cfg) in &verified {
        let Candidate::Backoff(b) = candidate else {
            continue;
        };
        shaped += usize::from(b.shaped);
        let y = run.knobs.from_config(cfg);
        for z in earlier.iter().chain([&run.trials[b.index].x]) {
            assert!(
                !run.knobs.gives_no_less(&y, z),
                "back-off {y:?} gives as much as the failed {z:?}"
            );
        }
        earlier.push(y);
    }
    let texts: Vec<&str> = outs
        .iter()
        .filter_map(|o| match o {
            Output::Event {
                reason: Reason::BackingOff,
                message,
                ..
            } => Some(message.as_str()),
            _ => None,
        })
        .collect();
    assert!(shaped >= 2, "two shaped back-offs: {texts:#?}");
    assert!(
        texts.iter().any(|t| t.contains("shaped by the models (")
            && t.contains("of the way from their minimum: predicted at least as safe")),
        "{texts:#?}"
    );
    let State::Monitor { satisfied, config } = &run.state else {
        unreachable!()
    };
    assert!(*satisfied, "{:?}", run.reason);
    assert!(verification(config).0 >= 35.0, "{config:?}");
}

#[test]
fn a_trial_whose_objective_measured_beyond_what_counts_is_verified_with_that_input_trimmed() {
    let (st, sp) = (stack(), spec(1.0, 5));
    let env = env(&st, &sp);
    let mut run = with_two_trials(&env);
    run.knobs.knobs.push(knobs::KnobDef {
        name: knobs::adaptor_knob_name("/image", "/detector"),
        target: knobs::KnobTarget::Adaptor {
            topic: "/image".into(),
            subscriber: "/detector".into(),
        },
        min: 0.5,
        max: 30.0,
        restricts_non_core: true,
        feeds: vec!["det".into()],
    });
    run.trials.clear();
    // `det` targets 10: at 30 Hz of input it measured 30, three times its cap.
    push_trial(&mut run, &env, &[1.9, 1.5, 30.0], 30.0);
    let mut out = Vec::new();
    run.state = finish(&mut run, &env, &env.defs(), &mut out);
    assert_eq!(reasons(&out), vec!["TrimmingSurplus"]);
    assert!(
        event_text(&out[0]).contains("rate:/image>/detector 30.00 -> 15.00 (det 3.0x)"),
        "{out:?}"
    );
    // Its input keeps 1.5 times the cap; the CPU knobs stay as measured.
    assert_eq!(
        run.state,
        State::VerifyApply {
            candidate: Candidate::Trial { index: 0 },
            config: run.knobs.to_config(&[1.9, 1.5, 15.0])
        }
    );
    // When that fails, the back-off backs off the trimmed point, not the
    // trial's 30 Hz: 80 % of the way from the minimum to 15 Hz.
    let (failed, out) = verify(run.clone(), &env, &[20.0; 10]);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "BackingOff"]);
    let State::VerifyApply { config, .. } = &failed.state else {
        panic!("{:?}", failed.state)
    };
    assert_eq!(config.adaptors[0].rate_hz, 12.1, "{config:?}");
    // Below 1.5 / 0.8 times its cap, the trial is verified as measured.
    run.trials.clear();
    push_trial(&mut run, &env, &[1.9, 1.5, 30.0], 18.0);
    let mut out = Vec::new();
    run.state = finish(&mut run, &env, &env.defs(), &mut out);
    assert!(out.is_empty(), "{out:?}");
    assert_verifies_trial_as_measured(&run, 0);
}

/// A spec whose detector has two objectives: `det` (≥ 10 Hz of
/// detections) and `img` (≥ 20 Hz of the camera's images, which the
/// reports give at 30 Hz); only `det` is fed by the detector's CPU.
fn two_objectives() -> PerformanceSpec {
    let mut sp = spec(1.0, 5);
    sp.spec.metrics.push(
        serde_json::from_value(serde_json::json!(
            {"name": "img", "app": "det", "source": {"topicRate": {"topic": "/image"}}, "target": {"atLeast": 20}}
        ))
        .unwrap(),
    );
    sp
}

/// A verification of `run`'s pending candidate, measured as `cmd` windows
/// with detection at `det`.
fn verify_det(run: Run, env: &Env<'_>, cmd: &[f64], det: f64) -> (Run, Vec<Output>) {
    assert_eq!(name(&run.state), "VerifyApply", "{:?}", run.state);
    let (run, _) = step(run, Input::Applied, env);
    let (run, _) = step(run, Input::Slept, env);
    assert_eq!(name(&run.state), "Verify");
    step(run, report(cmd, det), env)
}

/// A run about to verify its one trial, at detection 4 of 10 (objective
/// 0.4, below the images' 1.0), whose detector CPU works only for `det`.
fn held_at_detection_4(env: &Env<'_>) -> Run {
    let mut run = with_two_trials(env);
    run.knobs.knobs[0].feeds = vec!["det".into()];
    run.trials.clear();
    push_trial(&mut run, env, &[1.0, 1.5], 4.0);
    run.state = finish(&mut run, env, &env.defs(), &mut Vec::new());
    run
}

/// A held config whose worst objective sits below the next one up is
/// verified again with the knobs that work only for that objective raised
/// (here the detector's CPU: detection 4 of 10 against the images' cap,
/// so 3.75 times, to its 2 CPU maximum). When the lift holds with more
/// objective, the run monitors it; when it misses, or holds with no more,
/// the run goes back to the config it raised and monitors that, without
/// measuring it again.
#[test]
fn a_held_config_is_lifted_where_only_its_worst_objective_gains() {
    let (st, sp) = (stack(), two_objectives());
    let env = env(&st, &sp);
    let run = held_at_detection_4(&env);
    let held = run.knobs.to_config(&[1.0, 1.5]);
    let (lifting, out) = verify_det(run, &env, &OK, 4.0);
    assert_eq!(reasons(&out), vec!["Satisfied", "LiftingObjectives"]);
    assert!(
        event_text(&out[1])
            .contains("trial 0 held at objective 0.400, set by det, below img (1.000)")
            && event_text(&out[1]).contains("cpu:/detector 1.00 -> 2.00"),
        "{out:?}"
    );
    let lift = Candidate::Lift {
        base: Box::new(Candidate::Trial { index: 0 }),
        step: 1,
        halved: 0,
    };
    assert_eq!(
        lifting.state,
        State::VerifyApply {
            candidate: lift.clone(),
            config: lifting.knobs.to_config(&[2.0, 1.5]),
        }
    );
    // Held with more objective: a lift is measured on to the minute
    // whatever its margin, then monitored, and no second lift (two
    // objectives, one lift) ...
    let (on, out) = verify_det(lifting.clone(), &env, &OK, 9.0);
    assert_eq!(reasons(&out), vec!["NearBoundary"]);
    assert!(
        event_text(&out[0]).contains("a lift moves a config that held towards the boundary and no trial measured it, so it must hold the minute without a miss; measuring on to 60 s, stopping at the first miss"),
        "{out:?}"
    );
    let (up, out, secs) = measure_on(on.clone(), &env, 9.0, None);
    assert_eq!(secs, 60, "the minute, in the chunks the run asks for");
    assert_eq!(reasons(&out), vec!["Satisfied", "<save>"]);
    assert!(
        matches!(&up.state, State::Monitor { satisfied: true, config } if *config == up.knobs.to_config(&[2.0, 1.5]))
    );
    assert_eq!(up.applied, Some(lift.clone()));
    let status = crate::status::status(&Default::default(), &up, &env.defs(), 5, 1, "t");
    assert_eq!(
        (status.best_trial, status.best_trial_backoff),
        (Some(0), None)
    );
    // ... and one window missed on the way: the lift missed, tried
    // again halved.
    let (halved, out, secs) = measure_on(on, &env, 9.0, Some(32));
    assert_eq!(secs, 35);
    assert_eq!(
        reasons(&out),
        vec!["VerificationFailed", "LiftingObjectives"]
    );
    assert!(
        matches!(
            &halved.state,
            State::VerifyApply {
                candidate: Candidate::Lift { halved: 1, .. },
                ..
            }
        ),
        "{:?}",
        halved.state
    );
    // Missed: tried again with the factor's square root (3.75 → 1.94),
    // then its 4th, 8th and 16th roots (1.39, 1.18, 1.09), each from trial
    // 0's config, while the step still raises the CPU by LIFT_MIN_STEP
    // (the 32nd root, 1.04, would not) ...
    let mut missed = lifting.clone();
    for (halved, cpu) in [(1, 1.936), (2, 1.392), (3, 1.180), (4, 1.086)] {
        let (next, out) = verify_det(missed, &env, &BAD, 9.0);
        assert_eq!(
            reasons(&out),
            vec!["VerificationFailed", "LiftingObjectives"]
        );
        assert!(
            event_text(&out[0]).ends_with("; trying the step halved")
                && event_text(&out[1])
                    .contains("raised by the square root of the step that missed"),
            "{out:?}"
        );
        let State::VerifyApply { candidate, config } = &next.state else {
            panic!("{:?}", next.state)
        };
        assert_eq!(
            *candidate,
            Candidate::Lift {
                base: Box::new(Candidate::Trial { index: 0 }),
                step: 1,
                halved,
            }
        );
        let x = next.knobs.from_config(config);
        assert!((x[0] - cpu).abs() < 0.01 && x[1] == 1.5, "{x:?}");
        assert_eq!(next.held.len(), 1, "one config to go back to");
        missed = next;
    }
    // ... and when that misses too: back to trial 0's config, applied and
    // monitored.
    let (back, out) = verify_det(missed, &env, &BAD, 9.0);
    assert_eq!(reasons(&out), vec!["VerificationFailed", "<save>"]);
    assert!(
        event_text(&out[0]).contains("applying trial 0 again"),
        "{out:?}"
    );
    assert_eq!(
        back.state,
        State::RestoreApply {
            config: held.clone()
        }
    );
    assert_eq!(back.applied, Some(Candidate::Trial { index: 0 }));
    let (back, _) = step(back, Input::Applied, &env);
    assert_eq!(
        name(&back.state),
        "RestoreSettle",
        "settles before monitoring"
    );
    let (back, _) = step(back, Input::Slept, &env);
    assert_eq!(
        back.state,
        State::Monitor {
            satisfied: true,
            config: held.clone()
        }
    );
    assert!(back.held.is_empty() && back.lift_ended);
    // Held with no more objective: back too.
    let (same, out) = verify_det(lifting.clone(), &env, &OK, 4.0);
    assert_eq!(reasons(&out), vec!["LiftingObjectives", "<save>"]);
    assert!(
        event_text(&out[0]).contains("measured objective 0.400, short of 0.600"),
        "{out:?}"
    );
    assert_eq!(
        same.state,
        State::RestoreApply {
            config: held.clone()
        }
    );
    // The lift doubles the detector's CPU, promising detection 8 of 10
    // (0.800): a lift that measures less than half that rise (0.600) ends
    // at its first measurement, even one whose windows missed, and the
    // run goes back to trial 0's config; one that shows the rise holds.
    for (cmd, det) in [(&OK, 5.9), (&BAD, 5.9)] {
        let (short, out) = verify_det(lifting.clone(), &env, cmd, det);
        assert_eq!(reasons(&out), vec!["LiftingObjectives", "<save>"], "{det}");
        assert!(
            event_text(&out[0]).contains("measured objective 0.590, short of 0.600: 50 % of the rise from 0.400 to the 0.800 its raised knobs promise"),
            "{out:?}"
        );
        assert_eq!(
            short.state,
            State::RestoreApply {
                config: held.clone()
            }
        );
        assert!(short.lift_ended);
    }
    let (on, out) = verify_det(lifting, &env, &OK, 6.1);
    assert_eq!(reasons(&out), vec!["NearBoundary"]);
    let (up, out, _) = measure_on(on, &env, 6.1, None);
    assert_eq!(reasons(&out), vec!["Satisfied", "<save>"]);
    assert!(matches!(up.state, State::Monitor { .. }), "{:?}", up.state);
}

/// Measures a verification on in the chunks its effect asks for, every
/// window at 40 Hz but the one at second `miss` (30 Hz), detection at
/// `det`, until it leaves `Verify`: the run then, the last step's outputs
/// and the seconds measured in all.
fn measure_on(mut run: Run, env: &Env<'_>, det: f64, miss: Option<u64>) -> (Run, Vec<Output>, u64) {
    let State::Verify {
        so_far: Some(p), ..
    } = &run.state
    else {
        panic!("{:?}", run.state)
    };
    let mut secs = p.duration_ms / 1000;
    for _ in 0..20 {
        let Effect::Measure(req) = effect(&run, env) else {
            panic!("{:?}", run.state)
        };
        let n = req.duration_ms / 1000;
        let cmd: Vec<f64> = (secs..secs + n)
            .map(|t| if Some(t) == miss { 30.0 } else { 40.0 })
            .collect();
        secs += n;
        let (next, out) = step(run, report(&cmd, det), env);
        if name(&next.state) != "Verify" {
            return (next, out, secs);
        }
        assert!(out.is_empty(), "{out:?}");
        run = next;
    }
    panic!("a verification that never ends")
}

/// In a bursty run a verification measures on to its record; a lift whose
/// first measurement shows too little of its promised rise does not: it
/// ends there, and the run goes back to the config it raised.
#[test]
fn a_lift_that_shows_too_little_ends_before_its_record() {
    let (st, sp) = (stack(), two_objectives());
    let env = env(&st, &sp);
    let run = held_at_detection_4(&env);
    let (lifting, _) = verify_det(run, &env, &OK, 4.0);
    let mut bursty = lifting.clone();
    bursty.bursty = true;
    // Showing the rise, the lift measures on to its record ...
    let (on, out) = verify_det(bursty.clone(), &env, &OK, 8.0);
    assert_eq!(reasons(&out), vec!["NearBoundary"], "{out:?}");
    assert_eq!(name(&on.state), "Verify");
    // ... and not showing it, it ends after its first measurement.
    let (back, out) = verify_det(bursty, &env, &OK, 4.4);
    assert_eq!(
        reasons(&out),
        vec!["LiftingObjectives", "<save>"],
        "{out:?}"
    );
    assert_eq!(name(&back.state), "RestoreApply");
}

/// A held config goes back as its verification measured it: a lift of it
/// that missed in bursts weights the run's core nodes and is verified
/// again weighted, and when that shows too little of its rise the run
/// applies the held config without the weight it never held with, so the
/// objective the status reports is the one measured for what runs.
#[test]
fn a_config_restored_after_its_lift_weighted_the_run_runs_as_it_held() {
    let (st, sp) = (stack(), two_objectives());
    let env = env(&st, &sp);
    let mut run = held_at_detection_4(&env);
    run.knobs.core = vec!["/planner".into()];
    let held = run.knobs.to_config(&[1.0, 1.5]);
    assert!(held.cpu_weight.is_empty());
    let (lifting, out) = verify_det(run, &env, &OK, 4.0);
    assert_eq!(reasons(&out), vec!["Satisfied", "LiftingObjectives"]);
    // Two windows under target, the mean on it: bursts, so the lift is
    // verified again with the core nodes weighted ...
    let (weighted, out) = verify_det(lifting, &env, &[40.0, 30.0, 40.0, 30.0, 40.0], 8.0);
    assert_eq!(reasons(&out), vec!["CoreWeighted"], "{out:?}");
    let State::VerifyApply { config, .. } = &weighted.state else {
        panic!("{:?}", weighted.state)
    };
    assert!(!config.cpu_weight.is_empty(), "{config:?}");
    // ... where it shows too little of its rise: back to the held config,
    // unweighted as it held.
    let (back, out) = verify_det(weighted, &env, &OK, 4.4);
    assert_eq!(
        reasons(&out),
        vec!["LiftingObjectives", "<save>"],
        "{out:?}"
    );
    assert_eq!(back.state, State::RestoreApply { config: held });
    assert!(
        back.knobs.weighted,
        "later configs of the run stay weighted"
    );
    let objective = back.verified.as_ref().and_then(|e| e.objective);
    assert!(
        objective.is_some_and(|o| (o - 0.4).abs() < 1e-6),
        "{objective:?}"
    );
}

/// The harness stack with the camera in the core app: the detector's CPU
/// and its input are the only non-core knobs, both working for `det` alone.
fn camera_in_core() -> RobotStack {
    stack_of(&["/planner", "/camera"], &["/detector"])
}

/// What a detector costing 0.05 CPU per detection and 0.02 per frame
/// measures at `config`: as many detections as its frames (it drops one
/// in ten) and CPU allow,
/// the CPU it used, and cmd on target while it uses under 0.6 CPU.
fn detector_at(config: &ResourceConfig) -> Input {
    let cpu = config.cpu.get("/detector").copied().unwrap_or(2.0);
    let frames = config
        .adaptors
        .iter()
        .find(|a| a.subscriber == "/detector")
        .map_or(30.0, |a| a.rate_hz);
    let det = (0.9 * frames).min((cpu - 0.02 * frames).max(0.0) / 0.05);
    let used = (0.05 * det + 0.02 * frames).min(cpu);
    let cmd = if used < 0.6 { OK } else { BAD };
    let Input::Measured(mut r) = report(&cmd, det) else {
        unreachable!()
    };
    r.series.push(ProbeSeries {
        probe: Probe::CpuUsage {
            node: "/detector".into(),
        },
        values: vec![used; cmd.len()],
        mean: used,
    });
    Input::Measured(r)
}

/// A run of the detector harness under `sp`, to its end or 200 steps:
/// the run, for each balanced event the trials measured by then and the
/// design points left, and how many trials were proposed once the initial
/// design was measured (where a balanced trial may be).
fn balancing_run(sp: &PerformanceSpec) -> (Run, Vec<(usize, usize)>, usize) {
    let st = camera_in_core();
    let env = env(&st, sp);
    let mut run = with(State::Baseline {
        graph: graph(),
        prior: None,
    });
    let mut input = detector_at(&ResourceConfig::default());
    let mut balancing = Vec::new();
    let mut after_design = 0;
    for _ in 0..200 {
        let out;
        (run, out) = step(run, input, &env);
        if matches!(run.state, State::TrialApply { .. })
            && run.optimizer.as_ref().is_some_and(|o| o.design_left() == 0)
        {
            after_design += 1;
        }
        for o in &out {
            if let Output::Event {
                reason: Reason::Balancing,
                message,
                ..
            } = o
            {
                assert!(message.contains("det"), "{message}");
                let left = run.optimizer.as_ref().unwrap().design_left();
                balancing.push((run.trials.len(), left));
            }
        }
        input = match &run.state {
            State::TrialApply { .. } | State::Drain { applied: false, .. } => Input::Applied,
            State::TrialProfile { config, .. } | State::Drain { config, .. } => detector_at(config),
            _ => break,
        };
    }
    (run, balancing, after_design)
}

#[test]
fn once_the_design_is_measured_balanced_trials_are_measured_where_the_run_says() {
    let (run, balancing, _) = balancing_run(&spec(0.0, 20));
    // The detector wastes CPU on frames it cannot use in most trials, so
    // some balanced config promises more than the best trial so far.
    assert!(
        !balancing.is_empty(),
        "no balanced trial in {:?}",
        run.trials.len()
    );
    assert!(balancing.len() <= crate::search::BALANCE_TRIES);
    assert_eq!(balancing.len(), run.balanced.len());
    for ((at, left), x) in balancing.iter().zip(&run.balanced) {
        assert_eq!(*left, 0, "only once the initial design is measured");
        assert_eq!(
            &run.trials[*at].x, x,
            "the trial after the event is the balanced one"
        );
        assert!(
            !run.trials[*at].eval.usage.is_empty(),
            "its CPU use measured"
        );
    }
}

/// Under max-min a balanced config lifts only the objectives it balances:
/// when the worst is one whose app has no knobs of its own (here the core
/// camera's image rate, 30 of 150 Hz: 0.2), it promises no more than the
/// best trial and is not measured, though the detector's share could rise
/// past 0.2.
#[test]
fn no_balanced_trial_when_the_worst_objective_is_not_balanced() {
    let mut sp = spec(0.0, 20);
    sp.spec.metrics.push(
        serde_json::from_value(serde_json::json!(
            {"name": "img", "app": "det", "source": {"topicRate": {"topic": "/image"}}, "target": {"atLeast": 150}}
        ))
        .unwrap(),
    );
    let (run, balancing, after_design) = balancing_run(&sp);
    let best = run
        .trials
        .iter()
        .filter(|t| t.feasible())
        .filter_map(|t| t.eval.objective)
        .fold(0.0, f64::max);
    assert!((best - 0.2).abs() < 1e-6, "img bounds every trial: {best}");
    assert!(after_design > 0, "no trial after the initial design");
    assert!(balancing.is_empty(), "balanced at {balancing:?}");
    assert!(run.balanced.is_empty());
}
