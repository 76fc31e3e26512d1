//! Behaviour of the ask/tell optimizer on the benchmark problems (debug build,
//! small budgets; speed and search-quality numbers live in the bench binary).

use configbot_optimizer::problems::{self, TestProblem};
use configbot_optimizer::{
    Observation, Optimizer, Outcome, Proposal, SafetyFloor, Sense, Settings, StopReason,
};

fn problem(name: &str) -> TestProblem {
    problems::by_name(name).unwrap().unwrap()
}

fn small(seed: u64, budget: usize) -> Settings {
    Settings {
        seed,
        max_trials: budget,
        candidates: 300,
        refine_steps: 10,
        ..Settings::default()
    }
}

/// Runs ask/tell until a stop; returns the proposals.
fn drive(opt: &mut Optimizer, p: &TestProblem, max_asks: usize) -> Vec<Vec<f64>> {
    let mut out = Vec::new();
    for _ in 0..max_asks {
        match opt.ask().unwrap() {
            Proposal::Try(x) => {
                opt.tell(p.evaluate(&x)).unwrap();
                out.push(x);
            }
            Proposal::Stop(_) => break,
        }
    }
    out
}

#[test]
fn first_proposal_is_the_current_config_and_the_design_covers_the_space() {
    let p = problem("welded-beam"); // 4 dims
    let settings = Settings {
        initial_design_size: 17,
        ..small(3, 17)
    };
    let mut opt = Optimizer::new(p.problem.clone(), settings, &p.current).unwrap();
    let xs = drive(&mut opt, &p, 17);
    assert_eq!(xs[0], p.current);
    assert_eq!(xs.len(), 17);
    // 16 Sobol points: every 1-D projection hits each of 16 equal bins exactly once.
    for (k, knob) in p.problem.space.knobs().iter().enumerate() {
        let mut bins = [0; 16];
        for x in &xs[1..] {
            bins[(knob.to_unit(x[k]) * 16.0).min(15.0) as usize] += 1;
        }
        assert!(bins.iter().all(|&b| b == 1), "knob {}: {bins:?}", knob.name);
    }
}

#[test]
fn asking_twice_without_telling_repeats_the_proposal() {
    let p = problem("gardner");
    let mut opt = Optimizer::new(p.problem.clone(), small(1, 10), &p.current).unwrap();
    drive(&mut opt, &p, 3);
    let a = opt.ask().unwrap();
    let b = opt.ask().unwrap();
    assert_eq!(a, b);
}

#[test]
fn finds_the_gardner_optimum_region_quickly() {
    let p = problem("gardner");
    let mut opt = Optimizer::new(p.problem.clone(), small(0, 30), &p.current).unwrap();
    drive(&mut opt, &p, 31);
    let Outcome::Best { best, reason } = opt.outcome() else {
        panic!("{:?}", opt.outcome())
    };
    assert_eq!(reason, StopReason::Budget);
    assert!(
        p.within(best.value, 0.05),
        "best {} vs {:?}",
        best.value,
        p.best_known
    );
    assert!(p.problem.is_feasible(&best.observation));
}

#[test]
fn infeasible_problem_ends_in_unsat_with_evidence() {
    let p = problem("gramacy-infeasible");
    let settings = Settings {
        min_trials_before_unsat: 15,
        ..small(0, 30)
    };
    let mut opt = Optimizer::new(p.problem.clone(), settings, &p.current).unwrap();
    let xs = drive(&mut opt, &p, 31);
    assert!(xs.len() <= 30);
    let Outcome::Unsat { unsat, reason } = opt.outcome() else {
        panic!("{:?}", opt.outcome())
    };
    let nearest = unsat.nearest.expect("nearest trial");
    // The nearest trial really is the least-violating one measured.
    for x in &xs {
        assert!(p.problem.violation(&p.evaluate(x).constraints) >= unsat.nearest_violation - 1e-12);
    }
    assert!(unsat.nearest_violation > 0.0);
    assert_eq!(
        p.problem.violation(&nearest.constraints),
        unsat.nearest_violation
    );
    let pf = unsat.p_any_feasible.expect("model evidence");
    assert!(pf < 0.05, "p_any_feasible {pf}, reason {reason:?}");
    assert_eq!(unsat.trials, xs.len());
}

#[test]
fn resumed_optimizer_proposes_exactly_what_the_uninterrupted_one_does() {
    // The robot twice: the second time with the (history-replayed) trust region on.
    for (name, k, tr) in [
        ("gramacy", 10, false),
        ("robot", 12, false),
        ("robot", 12, true),
    ] {
        let p = problem(name);
        let n = 16;
        let settings = Settings {
            trust_region: tr.then(configbot_optimizer::trust::TrustRegionSettings::default),
            ..small(7, n)
        };
        let mut a = Optimizer::new(p.problem.clone(), settings.clone(), &p.current).unwrap();
        let full = drive(&mut a, &p, n);

        let mut b = Optimizer::new(p.problem.clone(), settings, &p.current).unwrap();
        let mut resumed = drive(&mut b, &p, k);
        let pending = b.ask().unwrap(); // a proposal in flight survives the restart too
        let json = b.to_json().unwrap();
        drop(b);
        let mut c = Optimizer::from_json(&json).unwrap();
        assert_eq!(c.ask().unwrap(), pending);
        resumed.extend(drive(&mut c, &p, n - k));
        assert_eq!(full.len(), resumed.len(), "{name}");
        for (i, (x, y)) in full.iter().zip(&resumed).enumerate() {
            let bits = |v: &Vec<f64>| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                bits(x),
                bits(y),
                "{name}: proposal {i} differs after resume at {k}"
            );
        }
        assert_eq!(a.outcome(), c.outcome());
    }
}

#[test]
fn safe_exploration_never_proposes_below_the_floor_on_the_robot() {
    let p = problem("robot");
    let floor = SafetyFloor {
        fraction_of_target: 0.8,
        beta: 3.0,
    };
    for seed in 0..2 {
        let settings = Settings {
            safety: Some(floor.clone()),
            ..small(seed, 25)
        };
        let (trust, growth) = (settings.trust_initial, settings.trust_growth);
        let size = settings.initial_design_size;
        let mut opt = Optimizer::new(p.problem.clone(), settings, &p.current).unwrap();
        let xs = drive(&mut opt, &p, 26);
        assert!(
            xs.len() >= 20,
            "seed {seed}: stopped after {} trials: {:?}",
            xs.len(),
            opt.ask()
        );
        let cur = p.problem.space.to_unit(&p.current);
        for (i, x) in xs.iter().enumerate() {
            let o = p.evaluate(x);
            for (c, v) in p.problem.constraints.iter().zip(&o.constraints) {
                assert!(
                    floor.holds(c, *v),
                    "seed {seed} trial {i}: {} = {v} below floor {}",
                    c.name,
                    floor.floor(c)
                );
            }
            if i < size {
                // The first trials stay in the trust region around the current config,
                // which grows by `growth` per safe trial (at most i before trial i).
                let half = trust * growth.powi(i.saturating_sub(1) as i32);
                let u = p.problem.space.to_unit(x);
                assert!(
                    u.iter()
                        .zip(&cur)
                        .all(|(a, b)| (a - b).abs() <= half + 1e-9),
                    "trial {i} left the trust region of half-width {half}"
                );
            }
        }
        // And it still makes progress over today's config.
        let today = p.problem.scalarize(&p.evaluate(&p.current).objectives);
        let best = match opt.outcome() {
            Outcome::Best { best, .. } => best.value,
            o => panic!("{o:?}"),
        };
        assert!(best > today, "seed {seed}: best {best} vs current {today}");
    }
}

#[test]
fn warm_start_remeasures_the_best_prior_config_and_uses_prior_data() {
    let p = problem("gramacy");
    let mut donor = Optimizer::new(p.problem.clone(), small(11, 20), &p.current).unwrap();
    drive(&mut donor, &p, 20);
    let prior: Vec<Observation> = donor.observations().to_vec();
    let best_prior = prior
        .iter()
        .filter(|o| p.problem.is_feasible(o))
        .max_by(|a, b| {
            p.problem
                .scalarize(&a.objectives)
                .total_cmp(&p.problem.scalarize(&b.objectives))
        })
        .unwrap()
        .clone();
    let mut warm =
        Optimizer::with_prior_observations(p.problem.clone(), small(12, 8), &p.current, prior)
            .unwrap();
    let xs = drive(&mut warm, &p, 9);
    assert_eq!(xs[0], p.current);
    assert_eq!(xs[1], best_prior.x);
    // Prior trials do not count against the budget nor as this context's best.
    assert_eq!(warm.observations().len(), 8);
    let Outcome::Best { best, .. } = warm.outcome() else {
        panic!()
    };
    assert!(warm.observations().iter().any(|o| o.x == best.x));
    // With 20 prior trials the model starts informed: 8 trials suffice to get within 5 %.
    assert!(
        p.within(best.value, 0.05),
        "warm best {} vs {:?}",
        best.value,
        p.best_known
    );
}

#[test]
fn censored_trials_are_infeasible_evidence_not_results() {
    let p = problem("robot");
    let mut opt = Optimizer::new(p.problem.clone(), small(5, 10), &p.current).unwrap();
    drive(&mut opt, &p, 3);
    // An early-stopped trial: great objectives, cmd_vel clearly short after part of its window.
    let mut x = p.current.clone();
    x[3] = 0.1; // planner quota slashed
    let censored = Observation {
        x: x.clone(),
        objectives: vec![10.0, 15.0],
        constraints: vec![12.0, 40.0],
        censored: true,
    };
    opt.tell(censored.clone()).unwrap();
    if let Outcome::InProgress { best: Some(b) } = opt.outcome() {
        assert_ne!(b.x, x, "a censored trial never becomes the best");
    }
    let pred = opt.predict_constraints(&x).unwrap();
    assert!(
        pred[0].0 < 20.0,
        "the constraint model learned the partial cmd_vel value: {pred:?}"
    );
    // The same values uncensored would be feasible for amcl but still not for cmd_vel; the
    // point is that objectives of censored trials never enter the incumbent.
    assert!(!p.problem.is_feasible(&censored));
}

#[test]
fn stops_when_no_candidate_is_worth_a_trial() {
    let p = problem("gramacy");
    let settings = Settings {
        stop_when_ei_below: Some(1e9),
        ..small(2, 30)
    };
    let mut opt = Optimizer::new(p.problem.clone(), settings.clone(), &p.current).unwrap();
    let xs = drive(&mut opt, &p, 30);
    assert!(xs.len() >= settings.initial_design_size && xs.len() < 30);
    match opt.outcome() {
        Outcome::Best {
            reason: StopReason::ExpectedImprovementBelow { max_cei },
            ..
        } => {
            assert!(max_cei < 1e9);
            // The event a user reads names the threshold in words, not as a
            // Rust value.
            let text = StopReason::ExpectedImprovementBelow { max_cei }.to_string();
            assert!(
                text.starts_with(
                    "the models expect no config to improve the objective by more than"
                ),
                "{text}"
            );
            assert!(!text.contains('{'), "{text}");
        }
        o => panic!("{o:?}"),
    }
}

#[test]
fn predictions_learn_from_extra_measurements() {
    let p = problem("robot");
    let mut opt = Optimizer::new(p.problem.clone(), small(5, 10), &p.current).unwrap();
    let xs = drive(&mut opt, &p, 6);
    // A longer measurement at a tried config that read far lower, as a
    // verification that failed after its trial held.
    let x = xs[xs.len() - 1].clone();
    let mut lower = p.evaluate(&x);
    lower.constraints[0] -= 15.0;
    let alone = opt.predict_many(&[], std::slice::from_ref(&x)).unwrap();
    let with = opt
        .predict_many(std::slice::from_ref(&lower), std::slice::from_ref(&x))
        .unwrap();
    assert!(
        with[0].constraints[0].0 < alone[0].constraints[0].0 - 3.0,
        "the extra measurement pulls the prediction down: {:?} vs {:?}",
        with[0].constraints[0],
        alone[0].constraints[0]
    );
}

/// A config revised after a longer measurement missed (`Optimizer::revise`)
/// no longer counts as the best, and a stop on expected improvement is
/// taken back so that the search can go on; a stop on the budget stays.
#[test]
fn a_revised_best_trial_takes_back_a_stop_on_expected_improvement_not_the_budget() {
    let p = problem("gramacy");
    let settings = Settings {
        stop_when_ei_below: Some(1e9),
        ..small(2, 30)
    };
    let mut opt = Optimizer::new(p.problem.clone(), settings, &p.current).unwrap();
    drive(&mut opt, &p, 30);
    let Outcome::Best { best, .. } = opt.outcome() else {
        panic!("{:?}", opt.outcome())
    };
    let missed: Vec<f64> = p
        .problem
        .constraints
        .iter()
        .map(|c| match c.sense {
            Sense::AtLeast => c.threshold - 1.0,
            Sense::AtMost => c.threshold + 1.0,
        })
        .collect();
    assert_eq!(opt.revise(&best.x, &missed).unwrap(), 1);
    let revised = opt
        .observations()
        .iter()
        .find(|o| o.x == best.x)
        .expect("still measured");
    assert_eq!(revised.constraints, missed);
    assert!(!p.problem.is_feasible(revised));
    match opt.outcome() {
        Outcome::InProgress { best: Some(next) } => assert_ne!(next.x, best.x),
        o => panic!("the stop is taken back and another trial is the best: {o:?}"),
    }
    // Nothing measured there: nothing changes.
    let elsewhere: Vec<f64> = best.x.iter().map(|v| v + 1e-3).collect();
    assert_eq!(opt.revise(&elsewhere, &missed).unwrap(), 0);
    // A revision of the wrong shape is refused.
    assert!(opt.revise(&best.x, &missed[..0]).is_err());

    let mut spent = Optimizer::new(p.problem.clone(), small(2, 9), &p.current).unwrap();
    drive(&mut spent, &p, 30);
    let Outcome::Best { best, reason } = spent.outcome() else {
        panic!("{:?}", spent.outcome())
    };
    assert_eq!(reason, StopReason::Budget);
    spent.revise(&best.x, &missed).unwrap();
    assert_eq!(spent.ask().unwrap(), Proposal::Stop(StopReason::Budget));
}

/// A design anchored at a feasible config: while its trials miss the
/// constraint, its points are drawn toward the anchor (the scale halves per
/// miss), and once they hold it spreads out again (grows by half per
/// feasible trial); the current config stays where it is.
#[test]
fn an_anchored_design_searches_from_the_feasible_side_while_its_trials_miss() {
    use configbot_optimizer::{Constraint, Knob, Objective, Problem, Scalarization, Space};
    let space = Space::new(vec![
        Knob::linear("a", 0.0, 1.0),
        Knob::linear("b", 0.0, 1.0),
    ])
    .unwrap();
    let problem = Problem::new(
        space,
        vec![Objective::capped("rate", 2.0)],
        vec![Constraint::at_most("load", 0.5)],
        Scalarization::MaxMin,
    )
    .unwrap();
    // The load is a + b: only the part of the box near (0, 0) is feasible.
    let measure = |x: &[f64]| Observation {
        x: x.to_vec(),
        objectives: vec![x[0] + x[1]],
        constraints: vec![x[0] + x[1]],
        censored: false,
    };
    let settings = Settings {
        design_anchor: Some(vec![0.0, 0.0]),
        initial_design_size: 8,
        ..small(7, 20)
    };
    let mut opt = Optimizer::new(problem.clone(), settings.clone(), &[1.0, 1.0]).unwrap();
    // The current config (everything at its maximum) misses.
    assert_eq!(opt.ask().unwrap(), Proposal::Try(vec![1.0, 1.0]));
    opt.tell(measure(&[1.0, 1.0])).unwrap();
    assert_eq!(opt.design_scale(), 0.5);
    let mut scales = Vec::new();
    for _ in 0..7 {
        let scale = opt.design_scale();
        let Proposal::Try(x) = opt.ask().unwrap() else {
            panic!("the design has points left")
        };
        assert!(
            x.iter().all(|v| *v <= scale + 1e-9),
            "{x:?} outside the box of scale {scale}"
        );
        let feasible = x[0] + x[1] <= 0.5;
        opt.tell(measure(&x)).unwrap();
        let next = opt.design_scale();
        if feasible {
            assert_eq!(next, (scale * 1.5).min(1.0));
        } else {
            assert_eq!(next, scale * 0.5);
        }
        scales.push(scale);
    }
    assert!(
        scales.iter().any(|s| *s < 0.5),
        "missed trials shrank it: {scales:?}"
    );
    assert!(
        scales.windows(2).any(|w| w[1] > w[0]),
        "held trials grew it: {scales:?}"
    );
    // Without an anchor the design fills the whole box, whatever its trials measure.
    let mut free = Optimizer::new(
        problem,
        Settings {
            design_anchor: None,
            ..settings
        },
        &[1.0, 1.0],
    )
    .unwrap();
    let mut xs = Vec::new();
    for _ in 0..8 {
        let Proposal::Try(x) = free.ask().unwrap() else {
            panic!("the design has points left")
        };
        free.tell(measure(&x)).unwrap();
        xs.push(x);
    }
    assert_eq!(free.design_scale(), 1.0);
    assert!(
        xs.iter().skip(1).any(|x| x[0] > 0.5 || x[1] > 0.5),
        "{xs:?}"
    );
}
