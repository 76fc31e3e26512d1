//! The tuning run as PerformanceSpec status (pure): phase, knobs, baseline,
//! every trial, the best, satisfaction (steady state while monitoring), non-core
//! performance, the context, the reason, and the `Ready`/`Tuned` conditions.
//! Fields the reconciler owns (`Accepted`, `StackResolved`) are left alone.

use configbot_manifests::meta::{condition_types as ct, set_condition};
use configbot_manifests::performance_spec::TrialStatus;
use configbot_manifests::{Condition, ConditionStatus, PerformanceSpecStatus, Reason};

use super::machine::{Candidate, Run, State, TrialRecord};
use super::measure::MetricDef;

/// Condition type written by the tuning loop: the run's outcome.
pub const TUNED: &str = "Tuned";

fn trial_status(index: usize, t: &TrialRecord) -> TrialStatus {
    TrialStatus {
        index: index as u32,
        config: t.config.clone(),
        values: t.eval.means.clone(),
        satisfaction: t.eval.satisfaction,
        objective: t.eval.objective,
        feasible: t.eval.feasible && !t.censored,
        censored: t.censored,
    }
}

/// The new status: `old` with the tuning fields replaced.
pub fn status(
    old: &PerformanceSpecStatus,
    run: &Run,
    defs: &[MetricDef],
    max_trials: u32,
    generation: i64,
    now: &str,
) -> PerformanceSpecStatus {
    let mut s = old.clone();
    s.phase = run.phase();
    s.trials = run.trials.len() as u32;
    s.max_trials = Some(max_trials);
    s.knobs = run.knobs.status();
    s.baseline = run.baseline.as_ref().map(|b| trial_status(0, b));
    s.trial_history = run
        .trials
        .iter()
        .enumerate()
        .map(|(i, t)| trial_status(i, t))
        .collect();
    s.context = run.context.as_ref().map(|c| c.key());
    s.reason = run.reason.clone();
    let monitored = match &run.state {
        State::Monitor { config, .. } => Some(config.clone()),
        _ => None,
    };
    (s.best_trial, s.best_trial_backoff) = match (&run.applied, &monitored) {
        (Some(c), Some(_)) => c
            .trial()
            .map_or((None, None), |(index, f)| (Some(index as u32), f)),
        _ => (None, None),
    };
    s.rejected_trials = run.rejected.iter().map(|&i| i as u32).collect();
    if let Some(cfg) = &monitored {
        s.best_config = Some(cfg.clone());
    }
    // Satisfaction: steady state while monitoring, else the latest measurement.
    let latest = run.trials.last().or(run.baseline.as_ref());
    s.satisfaction = match &run.state {
        State::Monitor { .. } | State::Remediating { .. } => run
            .monitor
            .satisfaction()
            .or(latest.map(|t| t.eval.satisfaction)),
        _ => latest.map(|t| t.eval.satisfaction),
    };
    // Non-core performance: the monitored config's verification, else the latest measurement.
    let source = match (&run.verified, &monitored) {
        (Some(v), Some(_)) => Some(v),
        _ => latest.map(|t| &t.eval),
    };
    s.non_core_performance = source
        .map(|e| {
            defs.iter()
                .filter(|d| !d.core)
                .filter_map(|d| e.means.get(&d.name).map(|v| (d.name.clone(), *v)))
                .collect()
        })
        .unwrap_or_default();
    let (ready, tuned) = conditions(run);
    for (type_, (status, reason, message)) in [(ct::READY, ready), (TUNED, tuned)] {
        set_condition(
            &mut s.conditions,
            Condition {
                type_: type_.into(),
                status,
                reason,
                message,
                last_transition_time: now.into(),
                observed_generation: generation,
            },
        );
    }
    s
}

type Cond = (ConditionStatus, Reason, String);

fn conditions(run: &Run) -> (Cond, Cond) {
    use ConditionStatus::{False, True, Unknown};
    let reason = run.reason.clone().unwrap_or_default();
    match &run.state {
        State::Monitor {
            satisfied: true, ..
        } => {
            let from = match &run.applied {
                Some(Candidate::Library { profile }) => (
                    Reason::LibraryConfig,
                    format!("re-applied library profile {}", profile.metadata.name),
                ),
                Some(Candidate::Trial { index }) => (
                    Reason::Satisfied,
                    format!("applied the best trial ({index})"),
                ),
                Some(c @ Candidate::Lift { .. }) => {
                    (Reason::Satisfied, format!("applied {}", c.text()))
                }
                Some(Candidate::Backoff(b)) => (
                    Reason::Satisfied,
                    format!(
                        "applied the best trial ({}) with its non-core knobs {}",
                        b.index,
                        b.text()
                    ),
                ),
                _ => (Reason::Satisfied, "the current config holds".to_string()),
            };
            (
                (
                    True,
                    Reason::Satisfied,
                    "core constraints hold; monitoring".into(),
                ),
                (True, from.0, from.1),
            )
        }
        State::Monitor {
            satisfied: false, ..
        }
        | State::UnsatApply { .. } => (
            (False, Reason::Unsat, reason.clone()),
            (False, Reason::Unsat, reason),
        ),
        State::RemediatePause { remedy }
        | State::RemediateApply { remedy }
        | State::Remediating { remedy }
        | State::RemediateUndo { remedy } => (
            (
                False,
                Reason::Remediating,
                format!(
                    "non-core apps {} until tuning is allowed",
                    if remedy.freeze { "frozen" } else { "stopped" }
                ),
            ),
            (
                Unknown,
                Reason::Remediating,
                "relearning queued until tuning is allowed".into(),
            ),
        ),
        _ => (
            (
                Unknown,
                Reason::Tuning,
                format!("{} in progress", run.phase()),
            ),
            (
                Unknown,
                Reason::Tuning,
                format!("{} trials measured", run.trials.len()),
            ),
        ),
    }
}
