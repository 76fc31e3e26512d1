//! The optimisation-progress chart (the paper's Fig. 5 style): each trial's
//! objective, marked feasible (dot), infeasible (cross) or rejected (ring:
//! feasible in its trial window but its config failed verification), and the
//! best-so-far line over the feasible trials that were not rejected, since a
//! rejected trial is not a confirmed best. Pure: the status's trial history
//! and `rejectedTrials` in, a [`Chart`] out.

use configbot_manifests::performance_spec::TrialStatus;

use super::svg::{Chart, Mark, Series, colors};

/// The progress chart of `trials` (the status's `trialHistory` entries, x =
/// 1-based trial number), with the trials whose index is in `rejected` (the
/// status's `rejectedTrials`) drawn as rings and left out of the best-so-far line.
pub fn chart(trials: &[TrialStatus], rejected: &[u32]) -> Chart {
    let mut feasible = Vec::new();
    let mut infeasible = Vec::new();
    let mut refused = Vec::new();
    let mut best = Vec::new();
    let mut best_so_far: Option<f64> = None;
    for t in trials {
        let x = f64::from(t.index) + 1.0;
        let o = t.objective.unwrap_or(0.0);
        if rejected.contains(&t.index) {
            refused.push((x, o));
        } else if t.feasible {
            feasible.push((x, o));
            best_so_far = Some(best_so_far.map_or(o, |b| b.max(o)));
        } else {
            infeasible.push((x, o));
        }
        if let Some(b) = best_so_far {
            best.push((x, b));
        }
    }
    let mut series = vec![
        Series {
            name: "feasible".into(),
            mark: Mark::Dot,
            color: colors::FEASIBLE,
            points: feasible,
        },
        Series {
            name: "infeasible".into(),
            mark: Mark::Cross,
            color: colors::INFEASIBLE,
            points: infeasible,
        },
    ];
    if !refused.is_empty() {
        series.push(Series {
            name: "rejected (failed verification)".into(),
            mark: Mark::Ring,
            color: colors::REJECTED,
            points: refused,
        });
    }
    series.push(Series {
        name: "best confirmed".into(),
        mark: Mark::Step,
        color: colors::BEST,
        points: best,
    });
    Chart {
        title: "Tuning progress".into(),
        x_label: "trial".into(),
        y_label: "non-core objective (1 = every target met)".into(),
        series,
        y_from_zero: true,
        ..Chart::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trial(index: u32, feasible: bool, objective: f64) -> TrialStatus {
        TrialStatus {
            index,
            feasible,
            objective: Some(objective),
            ..TrialStatus::default()
        }
    }

    fn points(c: &Chart, mark: Mark) -> &[(f64, f64)] {
        c.series
            .iter()
            .find(|s| s.mark == mark)
            .map_or(&[], |s| s.points.as_slice())
    }

    #[test]
    fn rejected_trials_get_rings_and_never_raise_the_best_line() {
        let trials = [
            trial(0, false, 0.1),
            trial(1, true, 0.4),
            trial(2, true, 0.9),
            trial(3, true, 0.6),
        ];
        let c = chart(&trials, &[2]);
        assert_eq!(points(&c, Mark::Dot), [(2.0, 0.4), (4.0, 0.6)]);
        assert_eq!(points(&c, Mark::Cross), [(1.0, 0.1)]);
        assert_eq!(points(&c, Mark::Ring), [(3.0, 0.9)]);
        // The best line holds 0.4 at the rejected trial 3 (not its 0.9).
        assert_eq!(points(&c, Mark::Step), [(2.0, 0.4), (3.0, 0.4), (4.0, 0.6)]);
        let legend: Vec<&str> = c.series.iter().map(|s| s.name.as_str()).collect();
        assert!(
            legend.contains(&"rejected (failed verification)"),
            "{legend:?}"
        );
        assert_eq!(c.to_svg().matches(r#"class="ring""#).count(), 1);
    }

    #[test]
    fn without_rejections_the_chart_has_no_ring_series() {
        let trials = [trial(0, true, 0.5), trial(1, true, 0.3)];
        let c = chart(&trials, &[]);
        assert!(c.series.iter().all(|s| s.mark != Mark::Ring));
        assert_eq!(points(&c, Mark::Step), [(1.0, 0.5), (2.0, 0.5)]);
        // A rejected first trial: no best yet, so no line point for it.
        let c = chart(&trials, &[0]);
        assert_eq!(points(&c, Mark::Step), [(2.0, 0.3)]);
    }
}
