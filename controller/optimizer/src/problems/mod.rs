//! Benchmark problems (pure functions), shared by the tests and the bench:
//! the standard constrained test problems and a simulated robot stack.
//!
//! Every problem states its best-known feasible value (as the scalar the
//! optimizer maximises, i.e. `-f` for minimisation problems) and a feasible
//! config that attains it, with where the number comes from.

mod robot;
mod standard;

pub use robot::{RobotModel, RobotRates};

use crate::error::Result;
use crate::problem::{Observation, Problem};

/// A simulator: objective and constraint values at a config.
pub type Simulator = fn(&[f64]) -> (Vec<f64>, Vec<f64>);

/// A problem with its simulator and reference answer.
#[derive(Debug, Clone)]
pub struct TestProblem {
    pub name: &'static str,
    pub problem: Problem,
    /// The "current config" a run starts from.
    pub current: Vec<f64>,
    /// Best-known feasible scalarised value; `None` for infeasible problems.
    pub best_known: Option<f64>,
    /// A feasible config attaining (within 0.1 %) `best_known`.
    pub best_x: Option<Vec<f64>>,
    /// Where `best_known` comes from.
    pub source: &'static str,
    eval: Simulator,
}

impl TestProblem {
    /// Runs the simulator: objective and constraint values at `x` (real units).
    pub fn evaluate(&self, x: &[f64]) -> Observation {
        let (objectives, constraints) = (self.eval)(x);
        Observation {
            x: x.to_vec(),
            objectives,
            constraints,
            censored: false,
        }
    }

    /// The scalar of a feasible evaluation, `None` if infeasible.
    pub fn feasible_value(&self, x: &[f64]) -> Option<f64> {
        let o = self.evaluate(x);
        self.problem
            .is_feasible(&o)
            .then(|| self.problem.scalarize(&o.objectives))
    }

    /// Whether `value` is within `frac` of the best-known value.
    pub fn within(&self, value: f64, frac: f64) -> bool {
        self.best_known.is_some_and(|b| value >= b - frac * b.abs())
    }
}

/// Names accepted by [`by_name`].
pub const NAMES: [&str; 7] = [
    "gardner",
    "gramacy",
    "branin",
    "pressure-vessel",
    "welded-beam",
    "robot",
    "gramacy-infeasible",
];

/// A problem by name.
pub fn by_name(name: &str) -> Option<Result<TestProblem>> {
    Some(match name {
        "gardner" => standard::gardner(),
        "gramacy" => standard::gramacy(false),
        "gramacy-infeasible" => standard::gramacy(true),
        "branin" => standard::branin(),
        "pressure-vessel" => standard::pressure_vessel(),
        "welded-beam" => standard::welded_beam(),
        "robot" => robot::problem(),
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_known_optimum_is_feasible_and_attains_its_value() {
        for name in NAMES {
            let p = by_name(name).unwrap().unwrap();
            assert_eq!(p.current.len(), p.problem.space.dim(), "{name}");
            p.problem.space.check(&p.current).unwrap();
            match (p.best_known, &p.best_x) {
                (Some(best), Some(x)) => {
                    let v = p.feasible_value(x).unwrap_or_else(|| {
                        panic!("{name}: best_x infeasible: {:?}", p.evaluate(x))
                    });
                    assert!(
                        (v - best).abs() <= 1e-3 * best.abs().max(1e-3),
                        "{name}: value {v} vs best-known {best}"
                    );
                    for (k, xv) in p.problem.space.knobs().iter().zip(x) {
                        assert!(
                            (k.lower..=k.upper).contains(xv),
                            "{name}: {} = {xv} out of bounds",
                            k.name
                        );
                    }
                }
                (None, None) => assert!(name.contains("infeasible")),
                _ => panic!("{name}: best_known and best_x must come together"),
            }
        }
    }
}
