//! Pure helpers around a run's outcome: the optimizer problem built from the
//! knobs and metrics, trials as optimizer observations and as library trials,
//! verification of a candidate config, the core nodes' weight that a trial
//! or verification missing in bursts calls for ([`weigh_on_bursts`]),
//! remediation (which apps, how, which topics to record), and the Unsat
//! explanation (which constraint, the best value reached, what to relax).

use std::collections::BTreeSet;

use configbot_api::graph::Graph;
use configbot_manifests::performance_spec::RemediationAction;
use configbot_manifests::{ProfileContext, ProfileTrial, Reason, ResourceConfig, RobotStack};
use configbot_optimizer::{Observation, Prediction};

use super::knobs::KnobSpace;
use super::library;
use super::machine::{
    BACKOFF_FASTEST, BACKOFF_MIN, BACKOFF_STEP, BACKOFF_STEPS, Backoff, Candidate, Edge, Env, Held,
    Output, Remedy, Run, SATISFIED, State, TrialRecord, drain_first, finish, normal, warning,
};
use super::measure::{self, MetricDef};
use super::monitor::{ConstraintMonitor, Trigger};

pub fn problem(
    knobs: &KnobSpace,
    defs: &[MetricDef],
    env: &Env<'_>,
) -> Result<configbot_optimizer::Problem, String> {
    use configbot_optimizer::{Constraint, Goal, Objective, Problem, Scalarization};
    let space = knobs.optimizer_space().map_err(|e| e.to_string())?;
    let objectives = defs
        .iter()
        .filter(|d| !d.core)
        .map(|d| Objective {
            name: d.name.clone(),
            goal: if d.at_least {
                Goal::Maximize
            } else {
                Goal::Minimize
            },
            cap: Some(d.target),
            weight: d.weight,
        })
        .collect();
    let constraints = defs
        .iter()
        .filter(|d| d.core)
        .map(|d| {
            if d.at_least {
                Constraint::at_least(&d.name, d.target)
            } else {
                Constraint::at_most(&d.name, d.target)
            }
        })
        .collect();
    let s = match env.spec.tuning.scalarization {
        configbot_manifests::performance_spec::Scalarization::MaxMin => Scalarization::MaxMin,
        configbot_manifests::performance_spec::Scalarization::Weighted => Scalarization::Weighted,
    };
    Problem::new(space, objectives, constraints, s).map_err(|e| e.to_string())
}

pub fn observation(rec: &TrialRecord) -> Observation {
    Observation {
        x: rec.x.clone(),
        objectives: rec.eval.objectives.clone(),
        constraints: rec.eval.constraints.clone(),
        censored: rec.censored,
    }
}

/// Trials of this run as library trials (optimizer-facing values by metric name).
pub fn profile_trials(run: &Run, defs: &[MetricDef]) -> Vec<ProfileTrial> {
    run.baseline
        .iter()
        .chain(&run.trials)
        .map(|t| {
            let (mut c, mut o) = (t.eval.constraints.iter(), t.eval.objectives.iter());
            let values = defs
                .iter()
                .filter_map(|d| {
                    let v = if d.core { c.next() } else { o.next() };
                    v.map(|v| (d.name.clone(), *v))
                })
                .collect();
            ProfileTrial {
                config: t.config.clone(),
                values,
                censored: t.censored,
            }
        })
        .collect()
}

/// The safest measured config and the message naming the constraint, the
/// best value reached and what to relax.
pub fn unsat_reason(run: &Run, defs: &[MetricDef]) -> (ResourceConfig, String) {
    let all: Vec<(String, &TrialRecord)> = run
        .baseline
        .iter()
        .map(|b| ("baseline".to_string(), b))
        .chain(
            run.trials
                .iter()
                .enumerate()
                .map(|(i, t)| (format!("trial {i}"), t)),
        )
        .collect();
    let safest = all
        .iter()
        .filter(|(_, t)| !t.censored)
        .max_by(|a, b| {
            a.1.eval
                .satisfaction
                .partial_cmp(&b.1.eval.satisfaction)
                .unwrap_or(std::cmp::Ordering::Equal)
        })
        .or(all.first());
    let config = safest.map(|(_, t)| t.config.clone()).unwrap_or_default();
    let mut parts = Vec::new();
    for (j, d) in defs.iter().filter(|d| d.core).enumerate() {
        let best = all
            .iter()
            .filter(|(_, t)| !t.censored)
            .filter_map(|(n, t)| {
                t.eval
                    .constraints
                    .get(j)
                    .map(|v| (n, *v, t.eval.means[&d.name]))
            })
            .max_by(|a, b| {
                let (x, y) = if d.at_least { (a.1, b.1) } else { (b.1, a.1) };
                x.partial_cmp(&y).unwrap_or(std::cmp::Ordering::Equal)
            });
        if let Some((n, robust, mean)) = best
            && !d.holds(robust)
        {
            // A relaxed target is only worth naming when a config could meet
            // it: a rate bound at or below zero says the windows varied too
            // much to promise anything, not that a negative rate would do.
            let relax = if robust > 0.0 {
                format!(
                    "; relax the target to {} {robust:.2}",
                    if d.at_least { "at most" } else { "at least" }
                )
            } else {
                String::new()
            };
            parts.push(format!(
                "constraint {} ({}) was not met: best value reached {:.2} in 99 % of 1 s windows (mean {mean:.2}, {n}){relax}",
                d.name,
                d.target_text(),
                robust.max(0.0),
            ));
        }
    }
    if parts.is_empty() {
        parts.push(met_but_unverified(run, defs, &all));
    }
    let msg = format!(
        "UNSAT after {} trials: {}; or give the stack more CPU or fewer non-core apps. Applied the safest config measured ({}).",
        run.trials.len(),
        parts.join("; "),
        safest.map_or("none", |(n, _)| n.as_str())
    );
    (config, msg)
}

/// Why a run ends Unsat when every core constraint's best bound met its
/// target (pure): trials met them but each config verified missed its
/// longer window; or, in a run judged by its windows, no trial held in every
/// window; or the constraints were met by different configs, never by one.
fn met_but_unverified(run: &Run, defs: &[MetricDef], all: &[(String, &TrialRecord)]) -> String {
    let names: Vec<&str> = defs
        .iter()
        .filter(|d| d.core)
        .map(|d| d.name.as_str())
        .collect();
    let names = names.join(", ");
    let met: Vec<&str> = all
        .iter()
        .filter(|(_, t)| t.feasible())
        .map(|(n, _)| n.as_str())
        .collect();
    if !met.is_empty() && !run.rejected.is_empty() {
        let missed: Vec<String> = run.rejected.iter().map(|i| format!("trial {i}")).collect();
        format!(
            "the core targets ({names}) were met in {}, but each config verified over a longer window missed ({})",
            list_some(&met),
            list_some(&missed)
        )
    } else if run.bursty {
        format!(
            "the core targets ({names}) were met in 99 % of some trial's 1 s windows, but no trial held in every window, as a run whose core windows miss in bursts is judged"
        )
    } else {
        format!("constraints {names} were each met by some config but never together")
    }
}

/// The first few names of `names` and how many more (for event text).
fn list_some<S: AsRef<str>>(names: &[S]) -> String {
    const SHOWN: usize = 4;
    let head: Vec<&str> = names.iter().take(SHOWN).map(AsRef::as_ref).collect();
    let head = head.join(", ");
    match names.len().saturating_sub(SHOWN) {
        0 => head,
        more => format!("{head} and {more} more"),
    }
}

/// After the best trial (`index`) failed verification at `fraction` (1 =
/// as measured; `step` back-offs so far, with `bounds` its core constraints'
/// bounds, [`measure::robust_value`]): when it failed as measured and the
/// search stopped with trials left, the search goes on first
/// (`search::search_on`) and the back-off waits for the next failure
/// (`Run::deferred_backoff`); else verify it again with its non-core knobs lower (see
/// [`next_fraction`]), for a margin from the core constraint's edge (the
/// trial's short window may have caught a lucky moment, or a config whose
/// non-core node only keeps up from an empty backlog). Only the first
/// rejected trial backs off, at most [`BACKOFF_STEPS`] times and not below
/// [`BACKOFF_MIN`], and only while the back-off promises more than the next
/// best trial beyond the failed verifications' edges measured
/// ([`backoff_promise`], [`edges_after`]); otherwise that trial is
/// verified as measured and the back-off set aside, to be taken up again
/// when that trial fails too (`Run::deferred_backoff`).
#[allow(clippy::too_many_arguments)]
fn back_off(
    run: &mut Run,
    env: &Env<'_>,
    defs: &[MetricDef],
    index: usize,
    fraction: f64,
    step: u32,
    bounds: &[f64],
    out: &mut Vec<Output>,
) -> State {
    let planned = if run.rejected.first() == Some(&index) {
        let corner = run
            .corner()
            .filter(|c| c.feasible())
            .map(|c| c.eval.constraints.as_slice());
        let next = next_fraction(defs, corner, fraction, bounds);
        (step < BACKOFF_STEPS && next >= BACKOFF_MIN).then_some(Backoff {
            index,
            fraction: next,
            step: step + 1,
            shaped: false,
        })
    } else {
        run.deferred_backoff.take()
    };
    let Some(backoff) = planned else {
        return finish(run, env, defs, out);
    };
    // A trial as measured failed (not a back-off) and the search stopped
    // with trials left: spend them first, with the models told what the
    // verification measured, and keep the back-off for the next failure.
    if step == 0
        && let Some(next) = super::search::search_on(run, env, out)
    {
        run.deferred_backoff = Some(backoff);
        return next;
    }
    verify_backoff(run, env, defs, backoff, out)
}

/// The verification of `backoff`, a back-off of a rejected trial
/// ([`back_off`]): its point shaped by the models or uniform
/// ([`backoff_point`]), drained first; or, when a measured trial beyond
/// the failed verifications' edges promises as much ([`backoff_promise`]),
/// that trial, the back-off set aside; or, when the weighted config set
/// aside ([`unweigh`]) already gave as much, that config verified again
/// (`search::finish`).
fn verify_backoff(
    run: &mut Run,
    env: &Env<'_>,
    defs: &[MetricDef],
    backoff: Backoff,
    out: &mut Vec<Output>,
) -> State {
    let Backoff {
        index: pick,
        fraction: next,
        ..
    } = backoff;
    // A back-off backs off what the trial's verification measured: its
    // point with the surplus trimmed, when that was cut.
    let Some(base) = trimmed_trial(run, env, defs, pick)
        .map(|(y, _)| y)
        .or_else(|| run.trials.get(pick).map(|t| t.x.clone()))
    else {
        return finish(run, env, defs, out);
    };
    let Some(uniform) = run.knobs.backed_off(&base, next) else {
        return finish(run, env, defs, out);
    };
    let objective = |t: &TrialRecord| t.eval.objective.unwrap_or(0.0);
    let promise = backoff_promise(
        run.corner().filter(|c| c.feasible()).map(objective),
        objective(&run.trials[pick]),
        next,
    );
    if run
        .weighted_fallback
        .as_ref()
        .is_some_and(|h| h.eval.objective.unwrap_or(0.0) >= promise)
    {
        return finish(run, env, defs, out);
    }
    if let Some(alt) = super::search::best_clear_trial(run)
        && objective(&run.trials[alt]) >= promise
    {
        out.push(normal(
            Reason::VerifyingNextBest,
            format!(
                "trial {alt} measured objective {:.3}, no less than trial {pick} backed off to {:.0} % promises ({promise:.3}): verifying trial {alt} instead",
                objective(&run.trials[alt]),
                next * 100.0
            ),
        ));
        run.deferred_backoff = Some(backoff);
        let verify = verify_trial(run, env, defs, alt, out);
        return drain_first(run, env, verify);
    }
    let (y, shaped) = backoff_point(run, &base, uniform);
    let how = match &shaped {
        None => format!("at {:.0} % of the way from their minimum", next * 100.0),
        Some(parts) => format!(
            "shaped by the models ({parts} of the way from their minimum: predicted at least as safe for every core constraint as all at {:.0} %, with more objective)",
            next * 100.0
        ),
    };
    out.push(normal(
        Reason::BackingOff,
        format!(
            "verifying trial {pick} with its non-core knobs {how}, for a margin from the core constraints"
        ),
    ));
    let verify = State::VerifyApply {
        candidate: Candidate::Backoff(Backoff {
            shaped: shaped.is_some(),
            ..backoff
        }),
        config: run.knobs.to_config(&y),
    };
    drain_first(run, env, verify)
}

/// Candidates a shaped back-off weighs, at most (see
/// [`KnobSpace::backoff_shapes`]).
const SHAPES: usize = 4096;

/// The point to verify when `x`, the point a rejected trial was verified at
/// (its own, its surplus trimmed: [`trimmed_trial`]), backs off to
/// `uniform` (every non-core knob at the same fraction `f` of `x`), and,
/// when it is another point,
/// how far each knob that moves was taken. The uniform
/// back-off ([`KnobSpace::backed_off`]) moves every non-core knob by `f`,
/// so it gives up as much of a knob that does not threaten the core as of
/// one that does. With fitted models, each knob gets its own fraction
/// instead: of [`KnobSpace::backoff_shapes`], the point the models predict
/// the most objective for among those they predict at least as safe as the
/// uniform back-off ([`safest_best`]). Measured on real-nodelets
/// (2026-11-25): the uniform back-off took the brightness transform (its
/// own process) from 12 Hz to 6 Hz of its 15 Hz cap with the vision
/// manager's input, which alone moved the core rate (least squares over 44
/// trials: −16 Hz over the vision input's range, −2.5 over brightness's).
/// The models that shape it are the search's, fitted once more with the
/// failed verifications added (`Run::failed_verifications`: the trial's
/// and its back-offs'), so that they learn where the longer measurement
/// fell short; and a shape that gives the non-core apps on every knob as
/// much as the trial or one of its failed back-offs
/// ([`KnobSpace::gives_no_less`]) is no candidate, whatever they predict.
/// Measured on real-nodelets (2026-11-25), before both rules: the second
/// shaped back-off chose the failed trial itself.
/// The uniform back-off stays the fallback: without models, without a
/// complete trial to predict objective from, or when no shape qualifies.
fn backoff_point(run: &Run, x: &[f64], uniform: Vec<f64>) -> (Vec<f64>, Option<String>) {
    let Some(opt) = run.optimizer.as_ref() else {
        return (uniform, None);
    };
    let failed: Vec<&[f64]> = std::iter::once(x)
        .chain(run.failed_verifications.iter().map(|v| v.x.as_slice()))
        .collect();
    let shapes = run
        .knobs
        .backoff_shapes(x, SHAPES)
        .into_iter()
        .filter(|y| !failed.iter().any(|z| run.knobs.gives_no_less(y, z)));
    let points: Vec<Vec<f64>> = std::iter::once(uniform.clone()).chain(shapes).collect();
    let verified: Vec<Observation> = run.failed_verifications.iter().map(observation).collect();
    let Ok(mut preds) = opt.predict_many(&verified, &points) else {
        return (uniform, None);
    };
    let measured: Vec<&TrialRecord> = run.trials.iter().chain(&run.failed_verifications).collect();
    for (p, y) in preds.iter_mut().zip(&points) {
        if let (Some((mean, _)), Some(ceiling)) = (
            p.objective.as_mut(),
            objective_ceiling(&run.knobs, y, &measured),
        ) {
            *mean = mean.min(ceiling);
        }
    }
    let Some(best) = safest_best(&preds[0], &preds[1..], &opt.problem().constraints) else {
        return (uniform, None);
    };
    let y = points[best + 1].clone();
    if run.knobs.to_config(&y) == run.knobs.to_config(&uniform) {
        return (uniform, None);
    }
    let parts: Vec<String> = run
        .knobs
        .knobs
        .iter()
        .zip(x.iter().zip(&y))
        .filter(|&(k, (&xv, _))| k.restricts_non_core && xv > k.min)
        .map(|(k, (&xv, &yv))| format!("{} {:.0} %", k.name, (yv - k.min) / (xv - k.min) * 100.0))
        .collect();
    (y, Some(parts.join(", ")))
}

/// The most objective point `y` can give by what was measured (pure): the
/// least objective measured at a config that [`KnobSpace::covers`] it (as
/// much for every non-core app, every other knob the same), plus
/// [`super::search::NEAR_BEST`] for a short window's count; `None` when no
/// complete measurement covers it. A model fitted to few trials can
/// predict an app more than its input or CPU allows. Measured on
/// real-nodelets (2026-11-25): a shaped back-off cut the brightness
/// transform to 0.05 CPU, predicted at objective 0.55 (sd 0.02), where a
/// trial with that CPU and twice the input had measured 0.31; it held at
/// 0.30, and the run ended there.
pub fn objective_ceiling(knobs: &KnobSpace, y: &[f64], measured: &[&TrialRecord]) -> Option<f64> {
    measured
        .iter()
        .filter(|t| !t.censored && knobs.covers(&t.x, y))
        .filter_map(|t| t.eval.objective)
        .min_by(f64::total_cmp)
        .map(|o| o + super::search::NEAR_BEST)
}

/// The candidate to prefer to a reference point (pure): the one with the
/// highest predicted objective, among those whose every constraint's
/// pessimistic prediction (mean − sd for at-least, mean + sd for at-most)
/// has at least the reference's margin; `None` when no such candidate
/// predicts more objective than the reference, or without objective
/// predictions.
pub fn safest_best(
    reference: &Prediction,
    candidates: &[Prediction],
    constraints: &[configbot_optimizer::Constraint],
) -> Option<usize> {
    let pessimistic = |c: &configbot_optimizer::Constraint, (m, sd): (f64, f64)| match c.sense {
        configbot_optimizer::Sense::AtLeast => c.margin(m - sd),
        configbot_optimizer::Sense::AtMost => c.margin(m + sd),
    };
    let safe = |p: &Prediction| {
        constraints
            .iter()
            .zip(p.constraints.iter().zip(&reference.constraints))
            .all(|(c, (&here, &there))| pessimistic(c, here) >= pessimistic(c, there))
    };
    let floor = reference.objective?.0;
    candidates
        .iter()
        .enumerate()
        .filter(|(_, p)| safe(p))
        .filter_map(|(i, p)| Some((i, p.objective?.0)))
        .filter(|&(_, o)| o > floor)
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(i, _)| i)
}

/// The objective a back-off to fraction `f` of the way from the restrictive
/// corner (objective `corner`, 0 when unmeasured) to the rejected trial
/// (`pick`) can be expected to give (pure): the straight line between them.
/// Objectives are capped and rates grow with the knobs, so the line
/// underrates the back-off; a trial that measured as much is still the better
/// bet, because its own windows held where the back-off has only the line.
/// Measured on real-nodelets (2026-11-24): a pick with objective 1.000 failed
/// and was backed off three times to 0.489, below a feasible trial's 0.660.
pub fn backoff_promise(corner: Option<f64>, pick: f64, f: f64) -> f64 {
    let c = corner.unwrap_or(0.0).min(pick);
    c + f.clamp(0.0, 1.0) * (pick - c)
}

/// The fraction to verify next after a verification at `f` failed (pure).
/// Along the back-off line, the restrictive corner (fraction 0, whose trial
/// held with `corner`'s bounds) and the failed verification (fraction `f`,
/// `bounds`) give each core constraint a secant; the next fraction is where
/// the first of them reaches its target, kept within
/// [[`BACKOFF_FASTEST`]·f, [`BACKOFF_STEP`]·f]. Without a measured corner,
/// or when every bound held (the windows missed), [`BACKOFF_STEP`]·f.
pub fn next_fraction(defs: &[MetricDef], corner: Option<&[f64]>, f: f64, bounds: &[f64]) -> f64 {
    let slowest = f * BACKOFF_STEP;
    let Some(corner) = corner else {
        return slowest;
    };
    let core = defs.iter().filter(|d| d.core);
    let crossing = core
        .zip(corner)
        .zip(bounds)
        .filter_map(|((d, &c), &b)| {
            let (at_corner, here) = (d.margin(c), d.margin(b));
            (at_corner > 0.0 && here < 0.0).then(|| f * at_corner / (at_corner - here))
        })
        .fold(slowest, f64::min);
    crossing.max(f * BACKOFF_FASTEST)
}

/// The edges a failed verification of a trial leaves (pure), from the
/// trial's core bounds `trial` and the verification's `verify`
/// ([`measure::robust_value`]): for each core constraint whose bound failed
/// in the verification (or, when only windows missed, the one nearest its
/// target relative to it), the trial's bound moved out by what the
/// verification fell short of the target (nothing when only windows
/// missed): a trial inside it has no more margin than the one that failed
/// had, plus what that one lacked, so it is no better bet.
/// Measured on real-nodelets (2026-11-24): after a pick failed, four trials
/// with bounds 25.25–25.65 Hz (target 25) were verified in turn, each
/// missing a window, before one at 25.9 Hz held.
pub fn edges_after(defs: &[MetricDef], trial: &[f64], verify: &[f64]) -> Vec<Edge> {
    let core: Vec<(usize, &MetricDef, f64, f64)> = defs
        .iter()
        .filter(|d| d.core)
        .zip(trial.iter().zip(verify))
        .enumerate()
        .map(|(j, (d, (&t, &v)))| (j, d, t, v))
        .collect();
    let failed: Vec<_> = core.iter().filter(|(_, d, _, v)| !d.holds(*v)).collect();
    let chosen = if failed.is_empty() {
        core.iter()
            .min_by(|a, b| relative_margin(a.1, a.3).total_cmp(&relative_margin(b.1, b.3)))
            .into_iter()
            .collect()
    } else {
        failed
    };
    chosen
        .into_iter()
        .map(|&(j, d, t, v)| {
            let short = (-d.margin(v)).max(0.0);
            Edge {
                constraint: j,
                beyond: if d.at_least { t + short } else { t - short },
                at_least: d.at_least,
            }
        })
        .collect()
}

/// How far `v` is inside `d`'s target, relative to the target (negative
/// when it misses).
fn relative_margin(d: &MetricDef, v: f64) -> f64 {
    d.margin(v) / d.target.abs().max(f64::MIN_POSITIVE)
}

/// A failed verification as the models that shape a back-off are told it
/// (pure): as measured when some core constraint's bound missed; when only
/// windows missed (every bound held), the constraint nearest its target
/// (relative to it, as in [`edges_after`]) at its target, so that the
/// models do not learn the config that failed as a safe one.
pub fn as_failed(defs: &[MetricDef], mut eval: measure::Evaluation) -> measure::Evaluation {
    let core: Vec<&MetricDef> = defs.iter().filter(|d| d.core).collect();
    if !core.iter().zip(&eval.constraints).all(|(d, &v)| d.holds(v)) {
        return eval;
    }
    let nearest = core
        .iter()
        .zip(&eval.constraints)
        .enumerate()
        .min_by(|(_, (a, va)), (_, (b, vb))| {
            relative_margin(a, **va).total_cmp(&relative_margin(b, **vb))
        })
        .map(|(j, (d, _))| (j, d.target));
    if let Some((j, target)) = nearest {
        eval.constraints[j] = target;
    }
    eval
}

/// `edges` for an event: "cmd above 36.20".
fn edges_text(defs: &[MetricDef], edges: &[Edge]) -> String {
    let core: Vec<&MetricDef> = defs.iter().filter(|d| d.core).collect();
    edges
        .iter()
        .filter_map(|e| {
            core.get(e.constraint).map(|d| {
                format!(
                    "{} {} {:.2}",
                    d.name,
                    if e.at_least { "above" } else { "below" },
                    e.beyond
                )
            })
        })
        .collect::<Vec<_>>()
        .join(" and ")
}

pub fn list_or_none(apps: &[String]) -> String {
    if apps.is_empty() {
        "no apps".into()
    } else {
        apps.join(", ")
    }
}

/// Enter remediation: stop or freeze the running non-core apps (per the
/// spec's action), recording their inputs when the spec asks.
pub fn remediate(env: &Env<'_>, ctx: Option<&ProfileContext>, out: &mut Vec<Output>) -> State {
    let r = &env.spec.remediation;
    let apps: Vec<String> = match r.action {
        RemediationAction::None => Vec::new(),
        RemediationAction::StopNonCore | RemediationAction::FreezeNonCore => env
            .stack
            .spec
            .apps
            .iter()
            .filter(|a| !a.core && ctx.is_none_or(|c| c.apps.contains(&a.name)))
            .map(|a| a.name.clone())
            .collect(),
    };
    let remedy = Remedy {
        freeze: r.action == RemediationAction::FreezeNonCore,
        record: r.record_rosbag && !apps.is_empty(),
        apps,
    };
    out.push(warning(
        Reason::Remediated,
        format!(
            "a core constraint is violated, no known config holds and tuning is not allowed now: {} {} and lifting CPU limits of core nodes; relearning is queued until tuning is allowed",
            if remedy.freeze { "freezing" } else { "stopping" },
            list_or_none(&remedy.apps)
        ),
    ));
    State::RemediatePause { remedy }
}

/// The name of a spec's remediation recording (the bag's file name starts
/// with it): `<namespace>.<name>`, unique because a namespace has no `.`;
/// past 200 characters cut, with a hash of the whole to keep it unique.
pub fn recording_name(namespace: &str, name: &str) -> String {
    let full = format!("{namespace}.{name}");
    if full.len() <= 200 {
        return full;
    }
    let cut: String = full.chars().take(183).collect();
    format!("{cut}-{:016x}", library::fnv(&full))
}

/// The topics a remediation records: every topic a node of the paused
/// `apps` subscribes to, by the live graph (sorted, once each).
pub fn paused_inputs(stack: &RobotStack, graph: &Graph, apps: &[String]) -> Vec<String> {
    let nodes: BTreeSet<&str> = stack
        .spec
        .apps
        .iter()
        .filter(|a| apps.contains(&a.name))
        .flat_map(|a| a.nodes.iter().map(|n| n.name.as_str()))
        .collect();
    graph
        .topics
        .iter()
        .filter(|(_, t)| t.subscribers.iter().any(|s| nodes.contains(s.as_str())))
        .map(|(name, _)| name.clone())
        .collect()
}

/// The config being monitored, which held its verification, has tipped (a
/// sustained violation; the context is the same, or a context change would
/// have come first). Either the workload changed, and the run's trials are
/// stale, or the config was one that keeps up only from an empty backlog
/// (it passed its trial and verification after a drain, then a burst filled
/// the backlog) and the run's other trials still hold. The second is cheaper
/// to try: when the config came from this run's trials, reject that trial and
/// verify the next best (drained first); if that fails too, relearn cold.
/// Once per run: a second tip relearns cold. `None`: nothing to try (a
/// library or baseline config, the retry spent, or no feasible trial left),
/// so relearn now.
pub fn after_tip(
    run: &mut Run,
    env: &Env<'_>,
    violation: &Trigger,
    out: &mut Vec<Output>,
) -> Option<State> {
    if let Some(lifted @ Candidate::Lift { .. }) = &run.applied
        && !run.tip_retried
    {
        // A lifted config tipped: the config it raised held before it.
        let h = run.held.pop()?;
        out.push(normal(
            Reason::VerifyingNextBest,
            format!(
                "the config of {} held its verification, then tipped; verifying {}, the config it raised, before relearning",
                lifted.text(),
                h.candidate.text()
            ),
        ));
        run.tipped = Some(violation.clone());
        run.tip_retried = true;
        run.lift_ended = true;
        let verify = State::VerifyApply {
            candidate: h.candidate,
            config: run.knobs.weigh(h.config),
        };
        return Some(drain_first(run, env, verify));
    }
    let (index, held) = match &run.applied {
        Some(c @ (Candidate::Trial { .. } | Candidate::Backoff(_))) => (c.trial()?.0, c.text()),
        _ => return None,
    };
    if run.tip_retried {
        return None;
    }
    if !run.rejected.contains(&index) {
        run.rejected.push(index);
    }
    let next = super::search::best_trial(run)?;
    out.push(normal(
        Reason::VerifyingNextBest,
        format!(
            "the config of {held} held its verification, then tipped; verifying trial {next}, the next best, before relearning"
        ),
    ));
    run.tipped = Some(violation.clone());
    run.tip_retried = true;
    let defs = measure::metric_defs(&env.stack.spec, env.spec);
    let verify = verify_trial(run, env, &defs, next, out);
    Some(drain_first(run, env, verify))
}

/// Trial `index`'s point with its surplus trimmed ([`KnobSpace::trimmed`]
/// on [`measure::surplus`] of the trial's means), and the event text that
/// says what was cut; `None` when nothing is. Measured on real-nodelets
/// (2026-11-26): the run's objective was the vision manager's input (about
/// 1 Hz against 3), and the brightness transform, its own process, was
/// verified at 27 Hz of input against the 5 Hz that objective level needs
/// of it (the scalarisation is max-min); its CPU took the core tracker's
/// margin and the config missed 3 windows of the next minute.
pub fn trimmed_trial(
    run: &Run,
    env: &Env<'_>,
    defs: &[MetricDef],
    index: usize,
) -> Option<(Vec<f64>, String)> {
    let t = run.trials.get(index)?;
    let s = env.spec.tuning.scalarization;
    let surplus = measure::surplus(defs, &t.eval.means, s);
    let y = run.knobs.trimmed(&t.x, &surplus)?;
    let cuts: Vec<String> = run
        .knobs
        .knobs
        .iter()
        .zip(t.x.iter().zip(&y))
        .filter(|(_, (a, b))| b < a)
        .map(|(k, (a, b))| {
            let most = k
                .feeds
                .iter()
                .filter_map(|m| surplus.get(m).map(|h| format!("{m} {h:.1}x")))
                .collect::<Vec<_>>()
                .join(", ");
            format!("{} {a:.2} -> {b:.2} ({most})", k.name)
        })
        .collect();
    let level = match s {
        configbot_manifests::performance_spec::Scalarization::MaxMin => format!(
            "the level of the worst objective ({:.3})",
            t.eval.objective.unwrap_or(0.0)
        ),
        configbot_manifests::performance_spec::Scalarization::Weighted => "their targets".into(),
    };
    Some((
        y,
        format!(
            "verifying trial {index} with the input of apps whose objectives measured more than counts cut to {} times {level}: {}; the CPU they took is margin for the core services",
            super::knobs::TRIM_HEADROOM,
            cuts.join(", ")
        ),
    ))
}

/// The verification of trial `index`: its config with the surplus trimmed
/// ([`trimmed_trial`], with an event) and the core weights of the run.
pub fn verify_trial(
    run: &Run,
    env: &Env<'_>,
    defs: &[MetricDef],
    index: usize,
    out: &mut Vec<Output>,
) -> State {
    let config = match trimmed_trial(run, env, defs, index) {
        Some((y, text)) => {
            out.push(normal(Reason::TrimmingSurplus, text));
            run.knobs.to_config(&y)
        }
        None => run.trials[index].config.clone(),
    };
    State::VerifyApply {
        candidate: Candidate::Trial { index },
        config: run.knobs.weigh(config),
    }
}

/// Whether a measurement missed core targets in bursts rather than on
/// average (pure): some window missed while every core metric's mean over
/// the measurement held its target. A CPU limit on the non-core apps caps
/// what they take on average; when they burst at once (detectors whose
/// frames arrive together), the core nodes wait for a CPU and drop a
/// second's worth of frames, whatever the limits. Measured on the real
/// two-path stack (2026-11-26): verifications of trials whose every window
/// held missed 18–24 Hz windows against 25 at a mean of 28–30 Hz, and a
/// config that missed 11 of 90 windows unweighted missed none with the
/// core nodes weighted ([`super::knobs::CORE_WEIGHT`]); three runs that
/// weighted on this rule after their second or third trial had every one
/// of their 53 later trials hold every window.
pub fn bursts(defs: &[MetricDef], eval: &measure::Evaluation) -> bool {
    eval.satisfaction < 1.0
        && defs
            .iter()
            .filter(|d| d.core)
            .all(|d| eval.means.get(&d.name).is_some_and(|&m| d.holds(m)))
}

/// Windows a run's measurements must have missed in bursts ([`bursts`]),
/// together, before the run counts as bursty and weights its core nodes:
/// the weight holds for the rest of the run and costs the non-core apps
/// CPU whenever a core node wants it, while one window under target with
/// every mean on it is what a measurement's ordinary spread gives now and
/// then (the 2.33·sd bound predicts about one in a hundred). A second
/// window, in the same measurement or a later one, shows the dips recur.
/// Measured on Basic-NAV: in sessions 35 and 46 and in a `./x demo` of
/// 2026-12-01 a capped config (detection 4.3 Hz) missed one window of ten,
/// the run weighted on it, and its detector fell to 1.35, 1.4 and 3.5 Hz
/// under the weight (212–216 s to Monitoring against 85–105 s when that
/// window held); on real-two-paths the configs that weighted runs missed
/// 11 of 90 windows unweighted.
pub const BURST_EVIDENCE: u32 = 2;

/// Counts the windows `eval`, a complete measurement of `what` (a trial, or
/// a verification's candidate), missed when it missed in bursts
/// ([`bursts`]; `Run::burst_windows`); once they reach [`BURST_EVIDENCE`],
/// marks the run bursty (`Run::bursty`: its verifications must hold a
/// longer record) and weights the run's core nodes if it is not weighted
/// yet: from now on every config
/// of the run gives them [`super::knobs::CORE_WEIGHT`]
/// ([`KnobSpace::weighted`]). Returns whether it weighted them. The trials measured
/// before stay as measured (a weight only helps the core nodes, so a trial
/// that held still holds). Weighting only on this evidence keeps a stack
/// whose core targets are missed on average, or not at all, unweighted: on
/// Basic-NAV weighted core nodes cost the detector its objective
/// (docs/tuning-history.md, session 23).
pub fn weigh_on_bursts(
    run: &mut Run,
    defs: &[MetricDef],
    what: &str,
    eval: &measure::Evaluation,
    then: &str,
    out: &mut Vec<Output>,
) -> bool {
    if !bursts(defs, eval) {
        return false;
    }
    run.burst_windows = run.burst_windows.saturating_add(eval.missed.max(1));
    if run.burst_windows < BURST_EVIDENCE {
        return false;
    }
    run.bursty = true;
    if run.knobs.weighted || run.knobs.core.is_empty() || run.weight_declined {
        return false;
    }
    run.knobs.weighted = true;
    let means: Vec<String> = defs
        .iter()
        .filter(|d| d.core)
        .map(|d| {
            format!(
                "{} {:.1}",
                d.name,
                eval.means.get(&d.name).copied().unwrap_or(0.0)
            )
        })
        .collect();
    out.push(normal(
        Reason::CoreWeighted,
        format!(
            "{what} held {:.1} % of the windows while every core mean held its target ({}): the core nodes miss when the non-core apps burst, not for want of CPU; every config from now on gives the core nodes ({}) CPU weight {}{then}",
            eval.satisfaction * 100.0,
            means.join(", "),
            run.knobs.core.join(", "),
            super::knobs::CORE_WEIGHT
        ),
    ));
    true
}

/// A verification of `candidate` missed in bursts and weighted the run
/// ([`weigh_on_bursts`]): the same candidate is verified again, weighted,
/// before anything is backed off. The run's failed verifications and the
/// edges they left were measured unweighted and are dropped.
fn verify_weighted(
    run: &mut Run,
    env: &Env<'_>,
    candidate: Candidate,
    config: ResourceConfig,
) -> State {
    run.failed_verifications.clear();
    run.edges.clear();
    let config = run.knobs.weigh(config);
    drain_first(run, env, State::VerifyApply { candidate, config })
}

/// When `candidate`, a trial verified again with the core nodes weighted
/// ([`verify_weighted`]), measured `eval` with every window on target and
/// its objective below what backing the trial off unweighted promises
/// (the first back-off step's [`backoff_promise`], by more than
/// [`super::search::NEAR_BEST`]): the trial's objective as measured
/// unweighted, its objective now and that promise (pure). `None` when
/// the run has rejected a trial, retries a tip or already set a weighted
/// config aside. A weight and a back-off both buy the core nodes margin;
/// the weight costs the non-core apps little when the core nodes' demand
/// is fixed, but all the CPU they would take when it grows with what they
/// get. Measured on Basic-NAV (sessions 46, 48 and 56, the bench's row):
/// its capped trial (objective 1.000) missed windows in bursts, held
/// weighted at 0.48 (detection 1.5 Hz, 0.83× the default), and the run
/// kept that, where the same trial unweighted measured 4.4 Hz in
/// `./x demo`; its navigation loop runs as fast as its CPU allows.
pub fn weight_cost(
    run: &Run,
    candidate: &Candidate,
    config: &ResourceConfig,
    eval: &measure::Evaluation,
) -> Option<(f64, f64, f64)> {
    let Candidate::Trial { index } = *candidate else {
        return None;
    };
    let trial = run.trials.get(index)?;
    let reweighted =
        run.knobs.weighted && !config.cpu_weight.is_empty() && trial.config.cpu_weight.is_empty();
    if !reweighted
        || eval.satisfaction < 1.0
        || !run.rejected.is_empty()
        || run.tipped.is_some()
        || run.tip_retried
        || run.weighted_fallback.is_some()
    {
        return None;
    }
    let objective = |o: Option<f64>| o.unwrap_or(0.0);
    let (was, now) = (objective(trial.eval.objective), objective(eval.objective));
    let corner = run.corner().filter(|c| c.feasible());
    let promise = backoff_promise(
        corner.map(|c| objective(c.eval.objective)),
        was,
        BACKOFF_STEP,
    );
    (promise > now + super::search::NEAR_BEST).then_some((was, now, promise))
}

/// The weight of [`weight_cost`] is dropped, once its first piece of
/// measurement (`eval`, `seconds` long) shows the cost: the core nodes are
/// not weighted for the rest of the run (`Run::weight_declined`), the
/// weighted config is set aside (`Run::weighted_fallback`;
/// `search::finish` verifies it again, weighted, when no back-off holds
/// with more) and the trial's first back-off is verified unweighted.
/// `None` when the weight does not cost that much. Its record is not
/// measured first: the objective it would keep is what decides.
#[allow(clippy::too_many_arguments)]
pub fn unweigh(
    run: &mut Run,
    env: &Env<'_>,
    defs: &[MetricDef],
    candidate: &Candidate,
    config: &ResourceConfig,
    eval: &measure::Evaluation,
    seconds: u64,
    out: &mut Vec<Output>,
) -> Option<State> {
    let (was, now, promise) = weight_cost(run, candidate, config, eval)?;
    let index = candidate.trial()?.0;
    out.push(normal(
        Reason::CoreUnweighted,
        format!(
            "trial {index} held every window of {seconds} s weighted at objective {now:.3}, where it measured {was:.3} unweighted: the core nodes' weight takes more from the non-core apps than backing the trial off to {:.0} % promises ({promise:.3}); the back-off is verified without the weight, and the weighted config again if nothing holds with more",
            BACKOFF_STEP * 100.0
        ),
    ));
    run.weighted_fallback = Some(Held {
        candidate: candidate.clone(),
        config: config.clone(),
        eval: eval.clone(),
    });
    run.knobs.weighted = false;
    run.weight_declined = true;
    run.rejected.push(index);
    let backoff = Backoff {
        index,
        fraction: BACKOFF_STEP,
        step: 1,
        shaped: false,
    };
    Some(verify_backoff(run, env, defs, backoff, out))
}

/// The weighted config [`unweigh`] set aside, verified again with the
/// core nodes weighted (`search::finish` calls this first): no unweighted
/// back-off held with more objective. `None` without one.
pub(crate) fn fall_back(run: &mut Run, env: &Env<'_>, out: &mut Vec<Output>) -> Option<State> {
    let h = run.weighted_fallback.take()?;
    out.push(normal(
        Reason::CoreWeighted,
        format!(
            "no unweighted config held with more objective than {} weighted ({:.3}): verifying it again, the core nodes weighted",
            h.candidate.text(),
            h.eval.objective.unwrap_or(0.0)
        ),
    ));
    run.knobs.weighted = true;
    let verify = State::VerifyApply {
        candidate: h.candidate,
        config: h.config,
    };
    Some(drain_first(run, env, verify))
}

/// Why a verification failed, for its event: too few windows held (by the
/// rule [`holds`] judged it by: `minute` when it was measured on), or they
/// held but their spread predicts misses (the bound of [`measure::robust_value`]).
pub fn shortfall(defs: &[MetricDef], eval: &measure::Evaluation, minute: bool) -> String {
    let held = format!("{:.1} % of the windows", eval.satisfaction * 100.0);
    let enough = if minute {
        measure::BAR_SATISFACTION
    } else {
        SATISFIED
    };
    if eval.satisfaction < enough {
        return format!("held in only {held}");
    }
    let core = defs.iter().filter(|d| d.core);
    match core.zip(&eval.constraints).find(|(d, v)| !d.holds(**v)) {
        Some((d, v)) => format!(
            "held in {held}, but their spread predicts misses: {} of {:.1} by mean {} {}·sd, target {}",
            d.name,
            v,
            if d.at_least { "−" } else { "+" },
            measure::BOUND_Z,
            d.target_text()
        ),
        None => format!("held in {held}"),
    }
}

/// Whether a verification's measurement holds. A first measurement holds
/// when ≥ [`SATISFIED`] of its windows held and every core constraint's
/// bound holds over them (the same rule as a trial's); one shorter than
/// the minute, every window on target, but with less margin than the bar
/// needs, its bound missed or not, is not judged by this but measured on
/// (the runner's `Verify` step, [`measure::short_of_bar`]). One measured on to
/// the minute because its margin was short of the bar, and every
/// measurement of a run whose core windows miss in bursts (measured on to
/// its record; `minute`, see [`measure::short_of_bar`],
/// `tuning.recordSeconds`), is judged as the bar judges a minute, by its
/// windows alone ([`measure::BAR_SATISFACTION`]): in a bursty run a dip
/// does not scale with the spread, and the record is the stronger test.
/// Measured on
/// real-nodelets (2026-11-25): with the bound applied over the minute too,
/// a back-off that held all 60 windows, its bound 24.99 against 25 Hz, was
/// rejected, and the run verified a trial with a tenth of its objective.
pub fn holds(eval: &measure::Evaluation, minute: bool) -> bool {
    if minute {
        eval.satisfaction >= measure::BAR_SATISFACTION
    } else {
        eval.satisfaction >= SATISFIED && eval.feasible
    }
}

/// Tells the optimizer what a failed verification of trial `index`
/// measured, as `eval`: each of the trial's core values becomes the worst of
/// the trial's own, the verification's bound and its worst window, so that
/// the models no longer count the config as feasible and a stop they made
/// on it is taken back ([`configbot_optimizer::Optimizer::revise`]; the
/// search may then go on, `search::search_on`). The trial's record stays as
/// its trial measured it. Nothing is revised when those values still hold
/// every target.
fn revise_failed_trial(
    run: &mut Run,
    defs: &[MetricDef],
    index: usize,
    eval: &measure::Evaluation,
    out: &mut Vec<Output>,
) {
    let Some(trial) = run.trials.get(index) else {
        return;
    };
    let core = defs.iter().filter(|d| d.core);
    let revised: Vec<f64> = core
        .clone()
        .enumerate()
        .map(|(j, d)| {
            let measured: Vec<f64> = [
                trial.eval.constraints.get(j),
                eval.constraints.get(j),
                eval.worst.get(j),
            ]
            .into_iter()
            .flatten()
            .copied()
            .collect();
            measure::worst_window(d, &measured)
        })
        .collect();
    if core.zip(&revised).all(|(d, &v)| d.holds(v)) {
        return;
    }
    let x = trial.x.clone();
    if let Some(o) = run.optimizer.as_mut()
        && let Err(e) = o.revise(&x, &revised)
    {
        out.push(warning(Reason::OptimizerFailed, e.to_string()));
    }
}

/// A verification measured, as `eval` (over the minute when `minute`):
/// monitor the candidate when it [`holds`], or try the next one.
#[allow(clippy::too_many_arguments)]
pub fn verified(
    run: &mut Run,
    env: &Env<'_>,
    defs: &[MetricDef],
    candidate: Candidate,
    config: ResourceConfig,
    eval: measure::Evaluation,
    minute: bool,
    out: &mut Vec<Output>,
) -> State {
    let sat = eval.satisfaction;
    if holds(&eval, minute) {
        out.push(normal(
            Reason::Satisfied,
            format!(
                "config from {} holds: satisfaction {:.1} %, objective {}",
                candidate.text(),
                sat * 100.0,
                eval.objective
                    .map_or("-".to_string(), |o| format!("{o:.3}"))
            ),
        ));
        // An unweighted config that holds with less objective than the
        // weighted one set aside gives way to it (`search::finish`).
        let objective = eval.objective.unwrap_or(0.0);
        if run
            .weighted_fallback
            .as_ref()
            .is_some_and(|h| h.eval.objective.unwrap_or(0.0) > objective)
        {
            return finish(run, env, defs, out);
        }
        run.weighted_fallback = None;
        if let Some(next) = lift(run, env, defs, &candidate, &config, &eval, out) {
            return next;
        }
        adopt(run, env, defs, candidate, &config, eval, out);
        return State::Monitor {
            satisfied: true,
            config,
        };
    }
    if matches!(
        candidate,
        Candidate::Trial { .. } | Candidate::Backoff(_) | Candidate::Lift { .. }
    ) && weigh_on_bursts(
        run,
        defs,
        &candidate.text(),
        &eval,
        "; verifying it again",
        out,
    ) {
        return verify_weighted(run, env, candidate, config);
    }
    match candidate {
        Candidate::Trial { index } => {
            let edges = run
                .trials
                .get(index)
                .map(|t| edges_after(defs, &t.eval.constraints, &eval.constraints))
                .unwrap_or_default();
            out.push(warning(
                Reason::VerificationFailed,
                format!(
                    "trial {index} {}{}",
                    shortfall(defs, &eval, minute),
                    if edges.is_empty() {
                        String::new()
                    } else {
                        format!(
                            "; trials are verified as measured first when their bound is {}",
                            edges_text(defs, &edges)
                        )
                    }
                ),
            ));
            run.edges.extend(edges);
            run.rejected.push(index);
            revise_failed_trial(run, defs, index, &eval, out);
            if run.rejected.first() == Some(&index)
                && let Some(t) = run.trials.get(index)
            {
                run.failed_verifications.push(TrialRecord {
                    x: if config == t.config {
                        t.x.clone()
                    } else {
                        run.knobs.from_config(&config)
                    },
                    config: config.clone(),
                    eval: as_failed(defs, eval.clone()),
                    censored: false,
                });
            }
            match run.tipped.take() {
                // The next best after a tip failed too: the workload changed.
                Some(t) => State::Observe {
                    trigger: t,
                    skip_library: true,
                },
                None => back_off(run, env, defs, index, 1.0, 0, &eval.constraints, out),
            }
        }
        Candidate::Backoff(b) => {
            run.failed_verifications.push(TrialRecord {
                x: run.knobs.from_config(&config),
                config,
                eval: as_failed(defs, eval.clone()),
                censored: false,
            });
            out.push(warning(
                Reason::VerificationFailed,
                format!(
                    "trial {} {} {}",
                    b.index,
                    b.text(),
                    shortfall(defs, &eval, minute)
                ),
            ));
            back_off(
                run,
                env,
                defs,
                b.index,
                b.fraction,
                b.step,
                &eval.constraints,
                out,
            )
        }
        Candidate::Lift {
            ref base,
            step,
            halved,
        } => {
            let halfway = run
                .held
                .last()
                .and_then(|h| lift_from(run, env, defs, h, (**base).clone(), step, halved + 1));
            let then = match (&halfway, run.held.last()) {
                (Some(_), _) => "trying the step halved".to_string(),
                (None, Some(h)) => format!("applying {} again", h.candidate.text()),
                (None, None) => "applying the config it raised again".to_string(),
            };
            out.push(warning(
                Reason::VerificationFailed,
                format!(
                    "{} {}; {then}",
                    candidate.text(),
                    shortfall(defs, &eval, minute)
                ),
            ));
            if let Some((event, verify)) = halfway {
                out.push(event);
                return drain_first(run, env, verify);
            }
            run.lift_ended = true;
            restore(run, env, defs, out)
        }
        Candidate::Baseline => {
            if env.tuning_allowed {
                let (config, reason) = unsat_reason(run, defs);
                out.push(warning(Reason::Unsat, reason.clone()));
                run.reason = Some(reason);
                State::UnsatApply { config }
            } else {
                remediate(env, run.context.as_ref(), out)
            }
        }
        Candidate::Library { .. } => {
            let t = Trigger::LibraryConfigFailed { satisfaction: sat };
            out.push(warning(t.reason(), t.message()));
            if env.tuning_allowed {
                // Relearn (fresh graph), warm-started from the profile's trials:
                // Observe skips the library hit and hands the profile to Baseline.
                State::Observe {
                    trigger: t,
                    skip_library: true,
                }
            } else {
                remediate(env, run.context.as_ref(), out)
            }
        }
    }
}

/// The config a verification held becomes the run's: saved to the library
/// when this run learned it, and what status and a tip refer to.
fn adopt(
    run: &mut Run,
    env: &Env<'_>,
    defs: &[MetricDef],
    candidate: Candidate,
    config: &ResourceConfig,
    eval: measure::Evaluation,
    out: &mut Vec<Output>,
) {
    let learned = matches!(
        candidate,
        Candidate::Trial { .. } | Candidate::Backoff(_) | Candidate::Lift { .. }
    );
    if let (true, Some(ctx)) = (learned, &run.context) {
        out.push(Output::SaveProfile(Box::new(library::profile(
            env.namespace,
            env.spec_name,
            Some(library::spec_digest(env.spec)),
            ctx,
            config,
            eval.satisfaction,
            eval.objective,
            profile_trials(run, defs),
        ))));
    }
    if !matches!(candidate, Candidate::Baseline) {
        run.reason = None;
    }
    run.tipped = None;
    run.applied = Some(candidate);
    run.verified = Some(eval);
    run.monitor = ConstraintMonitor::default();
}

/// Most lifts one run tries from a held config, one after another: each
/// raises the worst objectives past the next one up, so more than one
/// fewer than the objectives would lift objectives already lifted.
fn max_lifts(defs: &[MetricDef]) -> u32 {
    let objectives = defs.iter().filter(|d| !d.core).count();
    u32::try_from(objectives.saturating_sub(1)).unwrap_or(u32::MAX)
}

/// After `candidate` held its verification (`config`, measured as
/// `eval`): under max-min scalarisation, when its worst objectives sit
/// below the next one up ([`measure::lift`]), the same config with the
/// knobs that work only for them raised ([`KnobSpace::lifted`]) is
/// verified next, drained first, and `candidate` is kept (`Run::held`) to
/// go back to. `None` when nothing is to be lifted: the search chose
/// its trials by what the models predicted from short trials, while a
/// held config is the one point known to hold, and raising only what
/// its worst objectives' apps get is the nearest step up from it. The
/// rest of the config stays as it held, so a core constraint that the
/// raised apps do not load stays where it was. Measured on real-nodelets
/// (2026-11-28): three runs of four ended on the restrictive corner, at
/// objective 0.033 by the brightness transform's 0.5 Hz of input, while
/// the vision manager's 0.5 Hz there gave people and flow 0.167. Two
/// lifts measured there since (session 39) each missed one window of 30
/// and gave way, 36 s each.
#[allow(clippy::too_many_arguments)]
fn lift(
    run: &mut Run,
    env: &Env<'_>,
    defs: &[MetricDef],
    candidate: &Candidate,
    config: &ResourceConfig,
    eval: &measure::Evaluation,
    out: &mut Vec<Output>,
) -> Option<State> {
    if run.lift_ended || run.tipped.is_some() || run.tip_retried {
        return None;
    }
    let (base, step) = match candidate {
        Candidate::Trial { .. } | Candidate::Backoff(_) => (candidate.clone(), 1),
        Candidate::Lift { base, step, .. } => ((**base).clone(), step + 1),
        Candidate::Baseline | Candidate::Library { .. } => return None,
    };
    if step > max_lifts(defs) {
        return None;
    }
    let held = Held {
        candidate: candidate.clone(),
        config: config.clone(),
        eval: eval.clone(),
    };
    let (event, verify) = lift_from(run, env, defs, &held, base, step, 0)?;
    out.push(event);
    run.held.push(held);
    Some(drain_first(run, env, verify))
}

/// The least step a lift takes: some knob it raises grows by at least
/// this factor, or the lift is not verified. A lift that missed is tried
/// again from the config it raised with its factors halved (their square
/// root: the geometric midpoint of the held knobs and the missed ones), so
/// the run bisects the line from the config known to hold towards the
/// miss, and stops once the next point would be within this of the held
/// one: a step that small buys less objective than the trials' noise
/// ([`super::search::NEAR_BEST`] of a capped objective) and costs a
/// verification. Measured on real-nodelets (2026-11-28, seed 3): a held
/// config at objective 0.167 (the vision manager's input at 0.5 Hz) was
/// lifted to 1.13 Hz, missed 4 windows of 30 and gave way; this machine's
/// oracle holds at 0.257 (0.77 Hz), between the two. With a fixed two
/// halvings (sessions 43–46), seed 2 of session 46 held at 1.03 Hz after
/// lifts to 2.62, 1.64 and 1.30 Hz missed, where the oracle held at 1.2 Hz:
/// the next two points of the bisection (1.16 and 1.09 Hz) were never
/// measured.
pub const LIFT_MIN_STEP: f64 = 1.05;

/// The lift of `held` ([`measure::lift`] on its measured means, the knobs
/// that work only for its worst objectives raised by the plan's factors,
/// each factor's square root taken `halved` times): its event and the
/// verification to apply (pure). `None` when nothing is to be lifted or
/// no knob would grow by [`LIFT_MIN_STEP`].
fn lift_from(
    run: &Run,
    env: &Env<'_>,
    defs: &[MetricDef],
    held: &Held,
    base: Candidate,
    step: u32,
    halved: u32,
) -> Option<(Output, State)> {
    let (plan, x, y) = lift_plan(run, env, defs, held, halved)?;
    let raised: Vec<String> = run
        .knobs
        .knobs
        .iter()
        .zip(x.iter().zip(&y))
        .filter(|(_, (a, b))| b > a)
        .map(|(k, (a, b))| format!("{} {a:.2} -> {b:.2}", k.name))
        .collect();
    let worst: Vec<&str> = plan.factors.keys().map(String::as_str).collect();
    let reach = if halved == 0 {
        format!("to reach {} times that", super::knobs::TRIM_HEADROOM)
    } else {
        "by the square root of the step that missed".to_string()
    };
    let event = normal(
        Reason::LiftingObjectives,
        format!(
            "{} held at objective {:.3}, set by {}, below {} ({:.3}): verifying it with the knobs that work only for them raised {reach}: {}",
            held.candidate.text(),
            plan.level,
            worst.join(", "),
            plan.next.0,
            plan.next.1,
            raised.join(", ")
        ),
    );
    let verify = State::VerifyApply {
        candidate: Candidate::Lift {
            base: Box::new(base),
            step,
            halved,
        },
        config: run.knobs.weigh(run.knobs.to_config(&y)),
    };
    Some((event, verify))
}

/// The lift of `held` as points (pure): the plan ([`measure::lift`] on its
/// measured means, each factor's square root taken `halved` times), the
/// held config's point `x` and the lifted one `y`. `None` when nothing is
/// to be lifted or no knob would grow by [`LIFT_MIN_STEP`].
fn lift_plan(
    run: &Run,
    env: &Env<'_>,
    defs: &[MetricDef],
    held: &Held,
    halved: u32,
) -> Option<(measure::Lift, Vec<f64>, Vec<f64>)> {
    let mut plan = measure::lift(defs, &held.eval.means, env.spec.tuning.scalarization)?;
    let root = 0.5_f64.powi(i32::try_from(halved).unwrap_or(i32::MAX));
    for f in plan.factors.values_mut() {
        *f = f.powf(root);
    }
    let x = run.knobs.from_config(&held.config);
    let y = run.knobs.lifted(&x, &plan.factors).filter(|y| {
        y.iter()
            .zip(&x)
            .any(|(b, a)| b > a && *b >= a * LIFT_MIN_STEP)
    })?;
    Some((plan, x, y))
}

/// The objective a lift from `x` to `y` promises (pure): each of the
/// plan's worst objectives, its mean in `means` times the most any knob
/// that works for it rose (the CPU of its app or an input into it: an
/// app's output follows whichever of them limits it), capped; and no more
/// than the next objective up, which the lift leaves as it was.
pub fn lift_promise(
    knobs: &KnobSpace,
    defs: &[MetricDef],
    plan: &measure::Lift,
    means: &std::collections::BTreeMap<String, f64>,
    x: &[f64],
    y: &[f64],
) -> f64 {
    let rise = |m: &str| {
        knobs
            .knobs
            .iter()
            .zip(x.iter().zip(y))
            .filter(|(k, (a, b))| **a > 0.0 && b > a && k.feeds.iter().any(|f| f == m))
            .map(|(_, (a, b))| b / a)
            .fold(1.0_f64, f64::max)
    };
    plan.factors
        .keys()
        .filter_map(|m| {
            let d = defs.iter().find(|d| &d.name == m)?;
            Some(measure::normalise(
                d,
                means.get(m).copied().unwrap_or(0.0) * rise(m),
            ))
        })
        .fold(plan.next.1.min(1.0), f64::min)
}

/// The share of the rise a lift promises ([`lift_promise`]) over the
/// config it raised that its measurement must show, or the lift ends
/// there: the apps it raised are then held back by the CPU they share
/// with the other non-core apps, not by their own knobs, and measuring it
/// on to its record buys nothing. Measured on real-perception (session
/// 49, seed 1): under the core weight, a held config at 0.682 was lifted
/// (the flow and lines detectors' CPU and input raised 1.8–2×, promising
/// the next objective's 0.898); it measured 0.690 over its 120 s record,
/// a second lift 0.608, and the two took 250 s of the run's 611.
pub const LIFT_SHOWN: f64 = 0.5;

/// When `candidate` is a lift whose measurement `eval` shows less than
/// [`LIFT_SHOWN`] of the rise it promises over the config it raised (or
/// no rise at all), what its event says after the candidate's name
/// (pure); `None` otherwise.
pub fn lift_short(
    run: &Run,
    env: &Env<'_>,
    defs: &[MetricDef],
    candidate: &Candidate,
    eval: &measure::Evaluation,
) -> Option<String> {
    let Candidate::Lift { halved, .. } = candidate else {
        return None;
    };
    let h = run.held.last()?;
    let level = h.eval.objective.unwrap_or(0.0);
    let promise = lift_plan(run, env, defs, h, *halved)
        .map(|(plan, x, y)| lift_promise(&run.knobs, defs, &plan, &h.eval.means, &x, &y))
        .unwrap_or(level);
    let need = level + LIFT_SHOWN * (promise - level).max(0.0);
    let got = eval.objective.unwrap_or(0.0);
    (got <= level || got < need).then(|| {
        format!(
            "measured objective {got:.3}, short of {need:.3}: {:.0} % of the rise from {level:.3} to the {promise:.3} its raised knobs promise; the apps it raised are held back by the CPU they share, not by their knobs: applying {} again",
            LIFT_SHOWN * 100.0,
            h.candidate.text()
        )
    })
}

/// Goes back to the config the last lift raised (`Run::held`), drained
/// first and settled after (`State::RestoreSettle`), and keeps it as its
/// verification measured it: with the core nodes' weights it held with,
/// also when a lift of it has weighted the run since, for what runs is
/// then what the status and the library say was measured. Measured on
/// Terrain-NAV (session 60's bench): a config held unweighted at
/// objective 0.350; its lift missed in bursts and weighted the run; the
/// config restored with the weight gave detection 0.5 Hz, objective
/// 0.17, in the bench's measurement after tuning, while its status said
/// 0.350.
pub(crate) fn restore(
    run: &mut Run,
    env: &Env<'_>,
    defs: &[MetricDef],
    out: &mut Vec<Output>,
) -> State {
    let Some(h) = run.held.pop() else {
        return finish(run, env, defs, out);
    };
    let config = h.config;
    adopt(run, env, defs, h.candidate, &config, h.eval, out);
    drain_first(run, env, State::RestoreApply { config })
}

#[cfg(test)]
mod tests {
    use super::list_some;

    #[test]
    fn list_some_names_four_and_counts_the_rest() {
        assert_eq!(list_some::<&str>(&[]), "");
        assert_eq!(list_some(&["trial 1", "trial 0"]), "trial 1, trial 0");
        let six = ["a", "b", "c", "d", "e", "f"];
        assert_eq!(list_some(&six[..4]), "a, b, c, d");
        assert_eq!(list_some(&six), "a, b, c, d and 2 more");
    }
}
