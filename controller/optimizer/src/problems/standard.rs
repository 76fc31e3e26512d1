//! Standard constrained test problems, as minimisation of `f` subject to
//! `g_i(x) <= 0` (constraint thresholds 0, `AtMost`; large constraints are
//! divided by their constants so all are O(1)).

use std::f64::consts::PI;

use super::TestProblem;
use crate::error::Result;
use crate::problem::{Constraint, Goal, Objective, Problem, Scalarization};
use crate::space::{Knob, Space};

fn minimise(knobs: Vec<Knob>, n_constraints: usize) -> Result<Problem> {
    let constraints = (1..=n_constraints)
        .map(|i| Constraint::at_most(&format!("g{i}"), 0.0))
        .collect();
    Problem::new(
        Space::new(knobs)?,
        vec![Objective::raw("f", Goal::Minimize)],
        constraints,
        Scalarization::MaxMin,
    )
}

/// Gardner et al. 2014, toy problem: min cos(2x1)cos(x2) + sin(x1) s.t.
/// cos(x1)cos(x2) - sin(x1)sin(x2) <= 0.5 on [0, 6]^2.
/// Best known: f = -2 exactly at (3π/2, 0) (cos 3π · cos 0 + sin 3π/2 = -2, and the
/// constraint is 0 <= 0.5 there; -2 is the least both terms can reach). Our
/// random search + refinement (`--search-best gardner`) finds the same point.
pub fn gardner() -> Result<TestProblem> {
    fn eval(x: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let f = (2.0 * x[0]).cos() * x[1].cos() + x[0].sin();
        let c = x[0].cos() * x[1].cos() - x[0].sin() * x[1].sin() - 0.5;
        (vec![f], vec![c])
    }
    Ok(TestProblem {
        name: "gardner",
        problem: minimise(
            vec![Knob::linear("x1", 0.0, 6.0), Knob::linear("x2", 0.0, 6.0)],
            1,
        )?,
        current: vec![3.0, 3.0],
        best_known: Some(GARDNER_BEST),
        best_x: Some(GARDNER_X.to_vec()),
        source: "dense grid search (3000^2) + local refinement, this crate",
        eval,
    })
}
pub(crate) const GARDNER_BEST: f64 = 2.0;
pub(crate) const GARDNER_X: [f64; 2] = [4.712_388_980_384_69, 0.0];

/// Gramacy et al. 2016 toy problem: min x1 + x2 s.t.
/// 1.5 - x1 - 2x2 - 0.5 sin(2π(x1² - 2x2)) <= 0 and x1² + x2² - 1.5 <= 0 on [0,1]².
/// Best known 0.5998 at (0.1954, 0.4044) (Gramacy et al. 2016). With
/// `infeasible`, the second constraint becomes x1² + x2² <= 0.1, which cannot
/// meet the first (x1 + 2x2 + 0.5 <= sqrt(5·0.1) + 0.5 < 1.5 in that disc).
pub fn gramacy(infeasible: bool) -> Result<TestProblem> {
    fn c1(x: &[f64]) -> f64 {
        1.5 - x[0] - 2.0 * x[1] - 0.5 * (2.0 * PI * (x[0] * x[0] - 2.0 * x[1])).sin()
    }
    fn eval(x: &[f64]) -> (Vec<f64>, Vec<f64>) {
        (
            vec![x[0] + x[1]],
            vec![c1(x), x[0] * x[0] + x[1] * x[1] - 1.5],
        )
    }
    fn eval_infeasible(x: &[f64]) -> (Vec<f64>, Vec<f64>) {
        (
            vec![x[0] + x[1]],
            vec![c1(x), x[0] * x[0] + x[1] * x[1] - 0.1],
        )
    }
    Ok(TestProblem {
        name: if infeasible {
            "gramacy-infeasible"
        } else {
            "gramacy"
        },
        problem: minimise(
            vec![Knob::linear("x1", 0.0, 1.0), Knob::linear("x2", 0.0, 1.0)],
            2,
        )?,
        current: vec![0.5, 0.5],
        best_known: (!infeasible).then_some(-0.599_8),
        best_x: (!infeasible).then(|| vec![0.195_4, 0.404_5]),
        source: "Gramacy et al. 2016 (0.5998 at (0.1954, 0.4044))",
        eval: if infeasible { eval_infeasible } else { eval },
    })
}

fn branin_fn(x1: f64, x2: f64) -> f64 {
    let b = 5.1 / (4.0 * PI * PI);
    let c = 5.0 / PI;
    let t = 1.0 / (8.0 * PI);
    (x2 - b * x1 * x1 + c * x1 - 6.0).powi(2) + 10.0 * (1.0 - t) * x1.cos() + 10.0
}

/// Constrained Branin ("new Branin", Parr et al. 2012): min -(x1-10)² - (x2-15)²
/// s.t. branin(x) <= 5, x1 in [-5, 10], x2 in [0, 15].
/// Best known: f = -268.7879 at (3.2688, 0.0508) (random search of 200k points +
/// coordinate refinement, `--search-best branin`; matches the literature -268.79).
pub fn branin() -> Result<TestProblem> {
    fn eval(x: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let f = -(x[0] - 10.0).powi(2) - (x[1] - 15.0).powi(2);
        (vec![f], vec![branin_fn(x[0], x[1]) - 5.0])
    }
    Ok(TestProblem {
        name: "branin",
        problem: minimise(
            vec![
                Knob::linear("x1", -5.0, 10.0),
                Knob::linear("x2", 0.0, 15.0),
            ],
            1,
        )?,
        current: vec![2.5, 7.5],
        best_known: Some(BRANIN_BEST),
        best_x: Some(BRANIN_X.to_vec()),
        source: "Parr et al. 2012 new-Branin; value from our dense grid + refinement",
        eval,
    })
}
pub(crate) const BRANIN_BEST: f64 = 268.787_858;
pub(crate) const BRANIN_X: [f64; 2] = [3.268_842_088_316_544_5, 0.050_773_550_651_418_42];

/// Pressure-vessel design (Sandgren 1990; Coello 2000): shell/head thickness in
/// multiples of 0.0625 in, radius and length in [10, 200]; the length <= 240
/// constraint is implied by the bounds. Best known 6059.714 at (0.8125, 0.4375,
/// 42.0984, 176.6366) (e.g. Coello & Montes 2002).
pub fn pressure_vessel() -> Result<TestProblem> {
    fn eval(x: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let (ts, th, r, l) = (x[0], x[1], x[2], x[3]);
        let f =
            0.6224 * ts * r * l + 1.7781 * th * r * r + 3.1661 * ts * ts * l + 19.84 * ts * ts * r;
        let g3 = (1_296_000.0 - PI * r * r * l - 4.0 / 3.0 * PI * r * r * r) / 1_296_000.0;
        (vec![f], vec![-ts + 0.0193 * r, -th + 0.00954 * r, g3])
    }
    Ok(TestProblem {
        name: "pressure-vessel",
        problem: minimise(
            vec![
                Knob::linear("shell_thickness", 0.0625, 6.1875).with_step(0.0625),
                Knob::linear("head_thickness", 0.0625, 6.1875).with_step(0.0625),
                Knob::linear("radius", 10.0, 200.0),
                Knob::linear("length", 10.0, 200.0),
            ],
            3,
        )?,
        current: vec![3.0, 3.0, 100.0, 100.0],
        best_known: Some(-6059.714),
        best_x: Some(vec![0.8125, 0.4375, 42.098_445, 176.636_8]),
        source: "literature (Coello & Montes 2002): 6059.714",
        eval,
    })
}

/// Welded-beam design (Ragsdell & Phillips 1976; Coello 2000 formulation):
/// h, l, t, b with seven constraints (shear stress, bending stress, h <= b,
/// cost, h >= 0.125, deflection, buckling load). Best known 1.724852 at
/// (0.205730, 3.470489, 9.036624, 0.205730) (e.g. Coello & Montes 2002).
pub fn welded_beam() -> Result<TestProblem> {
    fn eval(x: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let (h, l, t, b) = (x[0], x[1], x[2], x[3]);
        let (p, len, e, g) = (6000.0, 14.0, 30e6, 12e6);
        let f = 1.10471 * h * h * l + 0.04811 * t * b * (14.0 + l);
        let tau_p = p / (2f64.sqrt() * h * l);
        let m = p * (len + l / 2.0);
        let r = (l * l / 4.0 + ((h + t) / 2.0).powi(2)).sqrt();
        let j = 2.0 * (2f64.sqrt() * h * l * (l * l / 12.0 + ((h + t) / 2.0).powi(2)));
        let tau_pp = m * r / j;
        let tau = (tau_p * tau_p + 2.0 * tau_p * tau_pp * l / (2.0 * r) + tau_pp * tau_pp).sqrt();
        let sigma = 6.0 * p * len / (b * t * t);
        let delta = 4.0 * p * len.powi(3) / (e * t.powi(3) * b);
        let pc = 4.013 * e * (t * t * b.powi(6) / 36.0).sqrt() / (len * len)
            * (1.0 - t / (2.0 * len) * (e / (4.0 * g)).sqrt());
        let cons = vec![
            tau / 13_600.0 - 1.0,
            sigma / 30_000.0 - 1.0,
            h - b,
            (0.10471 * h * h + 0.04811 * t * b * (14.0 + l) - 5.0) / 5.0,
            0.125 - h,
            delta / 0.25 - 1.0,
            1.0 - pc / p,
        ];
        (vec![f], cons)
    }
    Ok(TestProblem {
        name: "welded-beam",
        problem: minimise(
            vec![
                Knob::linear("h", 0.1, 2.0),
                Knob::linear("l", 0.1, 10.0),
                Knob::linear("t", 0.1, 10.0),
                Knob::linear("b", 0.1, 2.0),
            ],
            7,
        )?,
        current: vec![1.0, 5.0, 5.0, 1.0],
        best_known: Some(-1.724_852),
        best_x: Some(WELDED_X.to_vec()),
        source: "literature (Coello & Montes 2002): 1.724852",
        eval,
    })
}
pub(crate) const WELDED_X: [f64; 4] = [0.205_73, 3.470_49, 9.036_63, 0.205_73];
