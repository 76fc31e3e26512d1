//! The problem form (paper §V-A): objectives are non-core metrics capped at
//! their targets and normalised, `min(J, J°) / J°`, combined by a stated
//! scalarisation; constraints are core metrics that must reach their targets.
//!
//! Scalarisation, stated once: each objective `i` is normalised to
//! `u_i = min(J_i, cap_i) / cap_i` (to maximise; `cap_i / max(J_i, cap_i)` for
//! metrics to minimise, such as latency), so `u_i = 1` means "at target" and
//! extra resources beyond the target are worth nothing. Without a cap (the
//! paper's `J° = ∞`) the raw value is used (`J` to maximise, `-J` to minimise).
//! Then `MaxMin` takes `min_i u_i` (as the paper's public code does: the worst
//! non-core app decides, weights ignored) and `Weighted` takes
//! `Σ w_i u_i / Σ w_i`. The optimizer always maximises this scalar.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::space::Space;

/// Whether larger or smaller metric values are better.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Goal {
    Maximize,
    Minimize,
}

/// A non-core app's metric to push towards its target.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Objective {
    pub name: String,
    pub goal: Goal,
    /// The target `J°`; `None` means no target (no cap, raw value used).
    pub cap: Option<f64>,
    /// Weight for [`Scalarization::Weighted`]; ignored by `MaxMin`.
    pub weight: f64,
}

impl Objective {
    /// A rate-like objective capped at its target.
    pub fn capped(name: &str, cap: f64) -> Self {
        Self {
            name: name.to_owned(),
            goal: Goal::Maximize,
            cap: Some(cap),
            weight: 1.0,
        }
    }

    /// An uncapped objective (used by the standard test problems).
    pub fn raw(name: &str, goal: Goal) -> Self {
        Self {
            name: name.to_owned(),
            goal,
            cap: None,
            weight: 1.0,
        }
    }

    /// This objective's normalised value `u`.
    pub fn normalise(&self, j: f64) -> f64 {
        match (self.goal, self.cap) {
            (Goal::Maximize, Some(cap)) => j.min(cap) / cap,
            (Goal::Minimize, Some(cap)) => cap / j.max(cap),
            (Goal::Maximize, None) => j,
            (Goal::Minimize, None) => -j,
        }
    }
}

/// Which side of the threshold is feasible.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Sense {
    /// Rates: feasible when `value >= threshold`.
    AtLeast,
    /// Latencies: feasible when `value <= threshold`.
    AtMost,
}

/// A core service's metric that must meet its target.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Constraint {
    pub name: String,
    pub threshold: f64,
    pub sense: Sense,
}

impl Constraint {
    pub fn at_least(name: &str, threshold: f64) -> Self {
        Self {
            name: name.to_owned(),
            threshold,
            sense: Sense::AtLeast,
        }
    }

    pub fn at_most(name: &str, threshold: f64) -> Self {
        Self {
            name: name.to_owned(),
            threshold,
            sense: Sense::AtMost,
        }
    }

    /// Scale used to normalise margins: `|threshold|`, or 1 for a zero threshold.
    pub fn scale(&self) -> f64 {
        if self.threshold.abs() > 0.0 {
            self.threshold.abs()
        } else {
            1.0
        }
    }

    /// Signed normalised margin: `>= 0` is feasible, `-0.1` is 10 % short.
    pub fn margin(&self, v: f64) -> f64 {
        match self.sense {
            Sense::AtLeast => (v - self.threshold) / self.scale(),
            Sense::AtMost => (self.threshold - v) / self.scale(),
        }
    }

    /// Normalised violation (0 when feasible).
    pub fn violation(&self, v: f64) -> f64 {
        (-self.margin(v)).max(0.0)
    }
}

/// How several normalised objectives become one number.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Scalarization {
    MaxMin,
    Weighted,
}

/// A constrained black-box problem over a knob space.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Problem {
    pub space: Space,
    pub objectives: Vec<Objective>,
    pub constraints: Vec<Constraint>,
    pub scalarization: Scalarization,
}

/// One measured trial.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Observation {
    /// Knob values in real units.
    pub x: Vec<f64>,
    /// One value per objective, in metric units.
    pub objectives: Vec<f64>,
    /// One value per constraint, in metric units.
    pub constraints: Vec<f64>,
    /// The trial was stopped early because it was clearly infeasible: the values
    /// are partial-window estimates, not full measurements (see the optimizer
    /// docs for how they are used). A censored trial never counts as feasible.
    pub censored: bool,
}

impl Problem {
    /// Validates objective caps/weights and constraint thresholds.
    pub fn new(
        space: Space,
        objectives: Vec<Objective>,
        constraints: Vec<Constraint>,
        scalarization: Scalarization,
    ) -> Result<Self> {
        for o in &objectives {
            if let Some(cap) = o.cap
                && !(cap.is_finite() && cap > 0.0)
            {
                return Err(Error::Problem(format!(
                    "objective {:?}: cap {cap} must be finite and > 0",
                    o.name
                )));
            }
            if !(o.weight.is_finite() && o.weight >= 0.0) {
                return Err(Error::Problem(format!(
                    "objective {:?}: weight {} must be >= 0",
                    o.name, o.weight
                )));
            }
        }
        if scalarization == Scalarization::Weighted
            && !objectives.is_empty()
            && objectives.iter().map(|o| o.weight).sum::<f64>() <= 0.0
        {
            return Err(Error::Problem(
                "weighted scalarisation needs a positive weight".into(),
            ));
        }
        if let Some(c) = constraints.iter().find(|c| !c.threshold.is_finite()) {
            return Err(Error::Problem(format!(
                "constraint {:?}: threshold must be finite",
                c.name
            )));
        }
        Ok(Self {
            space,
            objectives,
            constraints,
            scalarization,
        })
    }

    /// The scalar to maximise (see the module docs). Zero objectives give 0.
    pub fn scalarize(&self, objectives: &[f64]) -> f64 {
        let u = self
            .objectives
            .iter()
            .zip(objectives)
            .map(|(o, &j)| o.normalise(j));
        match self.scalarization {
            Scalarization::MaxMin => {
                let m = u.fold(f64::INFINITY, f64::min);
                if m.is_finite() { m } else { 0.0 }
            }
            Scalarization::Weighted => {
                let wsum: f64 = self.objectives.iter().map(|o| o.weight).sum();
                if wsum <= 0.0 {
                    return 0.0;
                }
                self.objectives
                    .iter()
                    .zip(u)
                    .map(|(o, u)| o.weight * u)
                    .sum::<f64>()
                    / wsum
            }
        }
    }

    /// Sum of normalised constraint violations (0 when all constraints hold).
    pub fn violation(&self, constraints: &[f64]) -> f64 {
        self.constraints
            .iter()
            .zip(constraints)
            .map(|(c, &v)| c.violation(v))
            .sum()
    }

    /// Feasible: complete (not censored) and every constraint met.
    pub fn is_feasible(&self, obs: &Observation) -> bool {
        !obs.censored && self.violation(&obs.constraints) == 0.0
    }

    /// Checks an observation's shape and finiteness against this problem.
    pub fn check(&self, obs: &Observation) -> Result<()> {
        self.space.check(&obs.x)?;
        if obs.objectives.len() != self.objectives.len()
            || obs.constraints.len() != self.constraints.len()
        {
            return Err(Error::Observation(format!(
                "expected {} objective and {} constraint values, got {} and {}",
                self.objectives.len(),
                self.constraints.len(),
                obs.objectives.len(),
                obs.constraints.len()
            )));
        }
        if obs
            .objectives
            .iter()
            .chain(&obs.constraints)
            .any(|v| !v.is_finite())
        {
            return Err(Error::Observation(format!(
                "non-finite metric in observation at {:?}",
                obs.x
            )));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::space::Knob;

    fn problem(s: Scalarization) -> Problem {
        let space = Space::new(vec![Knob::linear("q", 0.0, 1.0)]).unwrap();
        let mut web = Objective::capped("web_hz", 20.0);
        web.weight = 3.0;
        Problem::new(
            space,
            vec![Objective::capped("detector_hz", 10.0), web],
            vec![],
            s,
        )
        .unwrap()
    }

    #[test]
    fn scalarisation_table() {
        // (detector Hz, web Hz) -> (max-min, weighted with weights 1 and 3)
        let table = [
            ((5.0, 20.0), (0.5, (0.5 + 3.0 * 1.0) / 4.0)),
            ((10.0, 10.0), (0.5, (1.0 + 3.0 * 0.5) / 4.0)),
            ((30.0, 40.0), (1.0, 1.0)), // beyond target is capped: worth nothing extra
            ((0.0, 5.0), (0.0, (0.0 + 3.0 * 0.25) / 4.0)),
            ((8.0, 16.0), (0.8, 0.8)),
        ];
        let mm = problem(Scalarization::MaxMin);
        let w = problem(Scalarization::Weighted);
        for ((d, web), (want_mm, want_w)) in table {
            assert!(
                (mm.scalarize(&[d, web]) - want_mm).abs() < 1e-12,
                "max-min at {d},{web}"
            );
            assert!(
                (w.scalarize(&[d, web]) - want_w).abs() < 1e-12,
                "weighted at {d},{web}"
            );
        }
    }

    #[test]
    fn minimised_and_uncapped_objectives() {
        let lat = Objective {
            name: "lat".into(),
            goal: Goal::Minimize,
            cap: Some(50.0),
            weight: 1.0,
        };
        assert_eq!(lat.normalise(25.0), 1.0);
        assert_eq!(lat.normalise(100.0), 0.5);
        assert_eq!(Objective::raw("cost", Goal::Minimize).normalise(3.0), -3.0);
        assert_eq!(Objective::raw("hz", Goal::Maximize).normalise(3.0), 3.0);
    }

    #[test]
    fn constraint_margins_and_violation() {
        let rate = Constraint::at_least("cmd_vel_hz", 35.0);
        assert!((rate.margin(42.0) - 0.2).abs() < 1e-12);
        assert!((rate.violation(28.0) - 0.2).abs() < 1e-12);
        assert_eq!(rate.violation(35.0), 0.0);
        let lat = Constraint::at_most("latency_ms", 100.0);
        assert!((lat.violation(150.0) - 0.5).abs() < 1e-12);
        let g = Constraint::at_most("g", 0.0);
        assert_eq!(g.violation(0.25), 0.25);
    }
}
