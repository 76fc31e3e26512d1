//! The surrogates behind one `ask`: a GP per normalised objective and one
//! per constraint, and how candidates are scored with them (constrained EI,
//! probability of feasibility, safety bounds).
//!
//! Objectives are modelled one by one and combined by the known
//! scalarisation when scoring (composite BO): the max-min of several objectives
//! has a ridge where they cross that one GP on the scalar models badly, while
//! each objective alone is smooth. The scalar's distribution is moment-matched
//! by a normal (min of normals by Clark's formulas, capped objectives clipped
//! at 1, weighted sums exactly), and EI is taken on that normal. With one
//! uncapped objective this is exactly a GP on the scalar.

use serde::{Deserialize, Serialize};

use crate::acquisition::{
    log_expected_improvement, log_norm_cdf, normal_min_moments, probability_of_feasibility,
};
use crate::error::Result;
use crate::gp::{FitOptions, Gp, Hyper};
use crate::problem::{Constraint, Observation, Problem, Scalarization, Sense};
use crate::rng::Rng;

/// Safe exploration: never propose a config whose predicted core-constraint
/// bound (`mean - beta * sd` for at-least constraints, `mean + beta * sd` for
/// at-most ones) is on the wrong side of the floor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SafetyFloor {
    /// Floor as a fraction of the target, e.g. 0.8: a 35 Hz target gets a 28 Hz
    /// floor; an at-most target of 100 ms gets a 120 ms ceiling.
    pub fraction_of_target: f64,
    /// Confidence multiplier of the bound, e.g. 2 or 3.
    pub beta: f64,
}

impl SafetyFloor {
    /// The floor (at-least) or ceiling (at-most) for a constraint.
    pub fn floor(&self, c: &Constraint) -> f64 {
        let slack = (1.0 - self.fraction_of_target) * c.scale();
        match c.sense {
            Sense::AtLeast => c.threshold - slack,
            Sense::AtMost => c.threshold + slack,
        }
    }

    /// Does a measured value respect the floor?
    pub fn holds(&self, c: &Constraint, value: f64) -> bool {
        match c.sense {
            Sense::AtLeast => value >= self.floor(c),
            Sense::AtMost => value <= self.floor(c),
        }
    }
}

/// How one candidate scores.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Score {
    /// `ln(EI × Π PoF)`, or `ln Π PoF` with no feasible incumbent.
    pub log_acq: f64,
    /// `Π PoF` (independent constraint models).
    pub pof: f64,
    /// `EI × Π PoF` in objective units, when there is an incumbent.
    pub cei: Option<f64>,
    /// Passes the safety floor (always true without safety).
    pub safe: bool,
}

/// Fitted surrogates.
#[derive(Debug)]
pub(crate) struct Models {
    /// One per objective (normalised values); empty before any complete trial.
    objectives: Vec<Gp>,
    constraints: Vec<Gp>,
}

/// What to fit and how hard.
#[derive(Debug)]
pub(crate) struct FitPlan<'a> {
    pub fit: &'a FitOptions,
    /// Use random restarts this time (otherwise warm start + prior centre only).
    pub full: bool,
    /// Minimum standardisation scale for constraints as a fraction of `Constraint::scale`.
    pub constraint_min_scale: f64,
    /// Lengthscale cap for the constraint models (safe exploration, which also
    /// floors their signal variance at the standardisation scale).
    pub constraint_max_lengthscale: Option<f64>,
}

impl Models {
    /// Fits all surrogates on `data` (unit-cube inputs `u`), updating the cached hyperparameters.
    pub fn fit(
        problem: &Problem,
        u: &[Vec<f64>],
        data: &[&Observation],
        hypers: &mut Vec<Option<Hyper>>,
        plan: &FitPlan<'_>,
        rng: &mut Rng,
    ) -> Result<Self> {
        let m = problem.constraints.len();
        let k = problem.objectives.len();
        hypers.resize(k + m, None);
        let mut opts = plan.fit.clone();
        if !plan.full {
            // Between full refits: screen the previous optimum and the prior centre, one L-BFGS run.
            opts.random_starts = 0;
            opts.local_runs = 1;
            opts.max_iter = opts.max_iter.min(12);
        }
        // Objectives: complete trials only (a censored trial's objective is unknown).
        let complete: Vec<(&Vec<f64>, &&Observation)> =
            u.iter().zip(data).filter(|(_, o)| !o.censored).collect();
        let ux: Vec<Vec<f64>> = complete.iter().map(|(u, _)| (*u).clone()).collect();
        let mut objectives = Vec::with_capacity(k);
        if !ux.is_empty() {
            for (i, obj) in problem.objectives.iter().enumerate() {
                let y: Vec<f64> = complete
                    .iter()
                    .map(|(_, o)| obj.normalise(o.objectives[i]))
                    .collect();
                let gp = Gp::fit(&ux, &y, &opts, hypers[i].as_ref(), rng)?;
                hypers[i] = Some(gp.hyper().clone());
                objectives.push(gp);
            }
        }
        let mut constraints = Vec::with_capacity(m);
        for (j, c) in problem.constraints.iter().enumerate() {
            // Constraints: every trial; a censored trial contributes its partial value.
            let y: Vec<f64> = data.iter().map(|o| o.constraints[j]).collect();
            let mut copts = opts.clone();
            copts.min_scale = plan.constraint_min_scale * c.scale();
            copts.max_lengthscale = plan.constraint_max_lengthscale;
            if plan.constraint_max_lengthscale.is_some() {
                copts.min_signal_var = Some(1.0);
            }
            let gp = Gp::fit(u, &y, &copts, hypers[k + j].as_ref(), rng)?;
            hypers[k + j] = Some(gp.hyper().clone());
            constraints.push(gp);
        }
        Ok(Self {
            objectives,
            constraints,
        })
    }

    /// Scores candidates (unit-cube points).
    pub fn score(
        &self,
        problem: &Problem,
        us: &[Vec<f64>],
        incumbent: Option<f64>,
        safety: Option<&SafetyFloor>,
    ) -> Vec<Score> {
        let obj = match incumbent {
            Some(_) if !self.objectives.is_empty() => {
                let preds: Vec<Vec<(f64, f64)>> = self
                    .objectives
                    .iter()
                    .map(|gp| gp.predict_many(us))
                    .collect();
                Some(
                    (0..us.len())
                        .map(|i| scalar_prediction(problem, preds.iter().map(|p| p[i])))
                        .collect::<Vec<_>>(),
                )
            }
            _ => None,
        };
        let cons: Vec<Vec<(f64, f64)>> = self
            .constraints
            .iter()
            .map(|gp| gp.predict_many(us))
            .collect();
        (0..us.len())
            .map(|i| {
                let mut log_pof = 0.0;
                let mut safe = true;
                for (c, pred) in problem.constraints.iter().zip(&cons) {
                    let (mean, sd) = pred[i];
                    let margin = match c.sense {
                        Sense::AtLeast => mean - c.threshold,
                        Sense::AtMost => c.threshold - mean,
                    };
                    log_pof += if sd > 1e-12 {
                        log_norm_cdf(margin / sd)
                    } else {
                        probability_of_feasibility(mean, sd, c.threshold, c.sense)
                            .max(f64::MIN_POSITIVE)
                            .ln()
                    };
                    if let Some(s) = safety {
                        let bound = match c.sense {
                            Sense::AtLeast => mean - s.beta * sd,
                            Sense::AtMost => mean + s.beta * sd,
                        };
                        safe &= s.holds(c, bound);
                    }
                }
                let (log_acq, cei) = match (&obj, incumbent) {
                    (Some(pred), Some(best)) => {
                        let (mean, sd) = pred[i];
                        let log_ei = log_expected_improvement(mean, sd, best);
                        (log_ei + log_pof, Some((log_ei + log_pof).exp()))
                    }
                    _ => (log_pof, None),
                };
                Score {
                    log_acq,
                    pof: log_pof.exp(),
                    cei,
                    safe,
                }
            })
            .collect()
    }

    /// Predicted mean and sd of each constraint at a point.
    pub fn constraint_predictions(&self, u: &[f64]) -> Vec<(f64, f64)> {
        self.constraints.iter().map(|gp| gp.predict(u)).collect()
    }

    /// The scalarised objective's and every constraint's prediction at
    /// each point (unit-cube inputs).
    pub fn predictions(&self, problem: &Problem, us: &[Vec<f64>]) -> Vec<Prediction> {
        let objs: Vec<Vec<(f64, f64)>> = self
            .objectives
            .iter()
            .map(|gp| gp.predict_many(us))
            .collect();
        let cons: Vec<Vec<(f64, f64)>> = self
            .constraints
            .iter()
            .map(|gp| gp.predict_many(us))
            .collect();
        (0..us.len())
            .map(|i| Prediction {
                objective: (!objs.is_empty())
                    .then(|| scalar_prediction(problem, objs.iter().map(|p| p[i]))),
                constraints: cons.iter().map(|p| p[i]).collect(),
            })
            .collect()
    }
}

/// What the models predict at one config: (mean, sd) of the scalarised
/// objective (normalised units; `None` before any complete trial) and of
/// each constraint (its own units).
#[derive(Debug, Clone, PartialEq)]
pub struct Prediction {
    pub objective: Option<(f64, f64)>,
    pub constraints: Vec<(f64, f64)>,
}

/// Normal approximation of the scalarised objective from the objectives'
/// predictions (normalised units).
fn scalar_prediction(problem: &Problem, preds: impl Iterator<Item = (f64, f64)>) -> (f64, f64) {
    // A capped objective's normalised value never exceeds 1.
    let clipped = problem.objectives.iter().zip(preds).map(|(o, p)| {
        if o.cap.is_some() {
            normal_min_moments(p, (1.0, 0.0))
        } else {
            p
        }
    });
    match problem.scalarization {
        Scalarization::MaxMin => clipped.reduce(normal_min_moments).unwrap_or((0.0, 0.0)),
        Scalarization::Weighted => {
            let wsum: f64 = problem.objectives.iter().map(|o| o.weight).sum();
            let (mut m, mut v) = (0.0, 0.0);
            for (o, (mi, si)) in problem.objectives.iter().zip(clipped) {
                let w = o.weight / wsum;
                m += w * mi;
                v += w * w * si * si;
            }
            (m, v.sqrt())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floors_for_both_senses() {
        let s = SafetyFloor {
            fraction_of_target: 0.8,
            beta: 2.0,
        };
        let rate = Constraint::at_least("cmd_vel_hz", 35.0);
        assert!((s.floor(&rate) - 28.0).abs() < 1e-12);
        assert!(s.holds(&rate, 29.0) && !s.holds(&rate, 27.0));
        let lat = Constraint::at_most("latency_ms", 100.0);
        assert!((s.floor(&lat) - 120.0).abs() < 1e-12);
        assert!(s.holds(&lat, 110.0) && !s.holds(&lat, 130.0));
    }
}
