//! A TuRBO-like trust region for problems with many knobs (Eriksson et al.
//! 2019; constrained as in SCBO, Eriksson & Poloczek 2021): after the initial
//! design, candidates come from a box around the best trial (best feasible,
//! else least violating) whose side shrinks after a run of trials that did not
//! improve and grows after a run that did. Its per-knob widths follow the
//! objective model's lengthscales, so knobs the objective is sensitive to get a
//! narrow box.
//!
//! The state is replayed from the trial history (pure function of the
//! observations), so a resumed optimizer holds exactly the same region.

use serde::{Deserialize, Serialize};

use crate::problem::{Observation, Problem};

/// Trust-region settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrustRegionSettings {
    /// Use the trust region only with at least this many knobs (in few
    /// dimensions a global model searches well and needs no region).
    pub min_dim: usize,
    /// Initial side length (unit cube, before lengthscale weighting).
    pub length_init: f64,
    pub length_min: f64,
    pub length_max: f64,
    /// Consecutive improving trials that double the side.
    pub success_tolerance: usize,
    /// Consecutive non-improving trials that halve it; `None`: `max(4, dim / 2)`.
    pub failure_tolerance: Option<usize>,
    /// Relative improvement that counts as a success.
    pub min_relative_improvement: f64,
    /// When the region collapses below `length_min`, start a new region
    /// (TuRBO's restart): this many random trials, then a region around the
    /// best of them. 0 (and always in safe mode) re-grows the region around
    /// the best trial instead.
    pub restart_design: usize,
}

impl Default for TrustRegionSettings {
    fn default() -> Self {
        Self {
            min_dim: 6,
            length_init: 0.8,
            length_min: 0.5f64.powi(7),
            length_max: 1.6,
            success_tolerance: 3,
            failure_tolerance: None,
            min_relative_improvement: 1e-3,
            restart_design: 0,
        }
    }
}

/// A trial's rank: feasible ones by value, then infeasible ones by violation.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Rank {
    Feasible(f64),
    Infeasible(f64),
}

impl Rank {
    fn of(problem: &Problem, o: &Observation) -> Self {
        if problem.is_feasible(o) {
            Rank::Feasible(problem.scalarize(&o.objectives))
        } else {
            Rank::Infeasible(problem.violation(&o.constraints))
        }
    }

    /// Whether `self` beats `other` by more than the relative tolerance.
    fn improves_on(self, other: Self, tol: f64) -> bool {
        match (self, other) {
            (Rank::Feasible(a), Rank::Feasible(b)) => a > b + tol * b.abs().max(1e-9),
            (Rank::Feasible(_), Rank::Infeasible(_)) => true,
            (Rank::Infeasible(_), Rank::Feasible(_)) => false,
            (Rank::Infeasible(a), Rank::Infeasible(b)) => a < b - tol * b.abs().max(1e-9),
        }
    }

    fn better(self, other: Self) -> bool {
        self.improves_on(other, 0.0)
    }
}

/// The region proposals come from.
#[derive(Debug, Clone, PartialEq)]
pub struct TrustRegion {
    /// Side length before lengthscale weighting.
    pub length: f64,
    /// Index of the centre trial in the observations.
    pub centre: usize,
    /// After a restart: the next trial should be a random one (no region yet).
    pub restarting: bool,
    /// Box bounds (unit cube).
    pub lo: Vec<f64>,
    pub hi: Vec<f64>,
}

impl TrustRegion {
    /// Replays the history: trials before `start` (the initial design) set the
    /// first centre; each later trial is a success (it improved on the best of
    /// the current region's run) or a failure, and runs of either resize the
    /// region. A region that shrinks below `length_min` restarts (see
    /// [`TrustRegionSettings::restart_design`]; never when `may_restart` is false).
    /// `log_ls` are the objective model's log lengthscales (unit cube), if fitted.
    /// Returns `None` for problems with fewer than `min_dim` knobs or no trials.
    pub fn replay(
        settings: &TrustRegionSettings,
        problem: &Problem,
        observations: &[Observation],
        units: &[Vec<f64>],
        start: usize,
        log_ls: Option<&[f64]>,
        may_restart: bool,
    ) -> Option<Self> {
        let dim = problem.space.dim();
        if dim < settings.min_dim || observations.is_empty() {
            return None;
        }
        let fail_tol = settings.failure_tolerance.unwrap_or((dim / 2).max(4));
        let tol = settings.min_relative_improvement;
        let mut length = settings.length_init;
        let (mut succ, mut fail) = (0usize, 0usize);
        let mut design_end = start;
        // Best trial of the current run (since the last restart).
        let mut best: Option<(usize, Rank)> = None;
        let mut overall: Option<(usize, Rank)> = None;
        for (i, o) in observations.iter().enumerate() {
            let r = Rank::of(problem, o);
            if overall.is_none_or(|(_, b)| r.better(b)) {
                overall = Some((i, r));
            }
            if i >= design_end {
                match best {
                    Some((_, b)) if !r.improves_on(b, tol) => {
                        fail += 1;
                        succ = 0;
                    }
                    _ => {
                        succ += 1;
                        fail = 0;
                    }
                }
                if succ >= settings.success_tolerance {
                    length = (2.0 * length).min(settings.length_max);
                    succ = 0;
                }
                if fail >= fail_tol {
                    length /= 2.0;
                    fail = 0;
                }
                if length < settings.length_min {
                    length = settings.length_init;
                    (succ, fail) = (0, 0);
                    if may_restart && settings.restart_design > 0 {
                        design_end = i + 1 + settings.restart_design;
                        best = None;
                        continue;
                    }
                }
            }
            if best.is_none_or(|(_, b)| r.better(b)) {
                best = Some((i, r));
            }
        }
        let restarting = observations.len() < design_end && observations.len() > start;
        let (centre, _) = if restarting {
            overall?
        } else {
            best.or(overall)?
        };
        let c = units.get(centre)?;
        // TuRBO's weighting: lengthscales over their geometric mean.
        let weights: Vec<f64> = match log_ls {
            Some(l) if l.len() == dim => {
                let mean = l.iter().sum::<f64>() / dim as f64;
                l.iter()
                    .map(|v| (v - mean).exp().clamp(0.25, 4.0))
                    .collect()
            }
            _ => vec![1.0; dim],
        };
        let lo = c
            .iter()
            .zip(&weights)
            .map(|(c, w)| (c - 0.5 * w * length).max(0.0))
            .collect();
        let hi = c
            .iter()
            .zip(&weights)
            .map(|(c, w)| (c + 0.5 * w * length).min(1.0))
            .collect();
        Some(Self {
            length,
            centre,
            restarting,
            lo,
            hi,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::{Constraint, Goal, Objective, Scalarization};
    use crate::space::{Knob, Space};

    fn problem(dim: usize) -> Problem {
        let knobs = (0..dim)
            .map(|i| Knob::linear(&format!("k{i}"), 0.0, 1.0))
            .collect();
        Problem::new(
            Space::new(knobs).unwrap(),
            vec![Objective::raw("f", Goal::Maximize)],
            vec![Constraint::at_most("c", 1.0)],
            Scalarization::MaxMin,
        )
        .unwrap()
    }

    fn obs(dim: usize, x0: f64, f: f64, c: f64) -> Observation {
        let mut x = vec![0.5; dim];
        x[0] = x0;
        Observation {
            x,
            objectives: vec![f],
            constraints: vec![c],
            censored: false,
        }
    }

    fn replay(
        s: &TrustRegionSettings,
        p: &Problem,
        o: &[Observation],
        start: usize,
    ) -> Option<TrustRegion> {
        let u: Vec<Vec<f64>> = o.iter().map(|o| p.space.to_unit(&o.x)).collect();
        TrustRegion::replay(s, p, o, &u, start, None, true)
    }

    #[test]
    fn few_knobs_get_no_region() {
        let p = problem(4);
        let o = vec![obs(4, 0.5, 1.0, 0.0)];
        assert!(replay(&TrustRegionSettings::default(), &p, &o, 1).is_none());
    }

    #[test]
    fn centre_is_best_feasible_and_region_shrinks_grows_and_restarts() {
        let dim = 8;
        let p = problem(dim);
        let s = TrustRegionSettings::default();
        let fail_tol = 4; // max(4, 8 / 2)
        // Design: an infeasible trial with the best objective, a feasible one.
        let mut o = vec![obs(dim, 0.1, 9.0, 2.0), obs(dim, 0.3, 1.0, 0.0)];
        let t = replay(&s, &p, &o, 2).unwrap();
        assert_eq!((t.centre, t.length), (1, s.length_init));
        assert!(t.lo[0] == 0.0 && (t.hi[0] - 0.7).abs() < 1e-12 && (t.lo[1] - 0.1).abs() < 1e-12);
        // fail_tol failures halve the side.
        o.extend((0..fail_tol).map(|_| obs(dim, 0.9, 0.5, 0.0)));
        let t = replay(&s, &p, &o, 2).unwrap();
        assert_eq!((t.centre, t.length), (1, s.length_init / 2.0));
        // Three successes double it and move the centre.
        o.extend((0..3).map(|i| obs(dim, 0.6, 2.0 + i as f64, 0.0)));
        let t = replay(&s, &p, &o, 2).unwrap();
        assert_eq!((t.centre, t.length), (o.len() - 1, s.length_init));
        // A long stall collapses the region; without restarts it re-grows in place.
        o.extend((0..fail_tol * 8).map(|_| obs(dim, 0.9, 0.5, 0.0)));
        let t = replay(&s, &p, &o, 2).unwrap();
        assert!(t.length < s.length_init && !t.restarting);
        // With restarts on, the collapse starts a random run, then a region around its best.
        let r = TrustRegionSettings {
            restart_design: 2,
            ..s.clone()
        };
        // 0.8 / 2^7 < length_min: the 7th halving (28th failure) collapses the region.
        let collapse = 2 + 4 + 3 + fail_tol * 7 - 1;
        let mut early = o[..=collapse].to_vec();
        let t = replay(&r, &p, &early, 2).unwrap();
        assert!(t.restarting && t.length == s.length_init);
        early.push(obs(dim, 0.2, 0.1, 0.0));
        early.push(obs(dim, 0.25, 0.2, 0.0));
        let t = replay(&r, &p, &early, 2).unwrap();
        assert!(!t.restarting);
        assert_eq!(
            t.centre,
            early.len() - 1,
            "best of the new run, not the overall best"
        );
    }
}
