//! A simulated robot stack: ROS-like nodes with CPU cost per message, publish
//! rates, per-node CPU quotas (cgroup `cpu.max`), CFS-like weighted
//! proportional sharing on N cores (`cpu.shares`), and adaptors limiting the
//! rate of high-volume topics into non-core apps.
//!
//! Nodes: core `lidar` (40 Hz scans), `amcl` and `costmap` (consume scans),
//! `planner` (periodic at `planner_hz`, publishes cmd_vel); non-core `camera`
//! (30 Hz frames, serialisation cost per delivered frame), `detector` (two
//! threads, expensive per frame) and `web` (dashboard: frames and scans).
//! Each node's demand (cores) = Σ input rate × cost; it gets
//! `min(demand, quota, threads)` if the machine has room, else a weighted
//! max-min fair share (water-filling, like CFS with shares); a node given a
//! fraction f of its demand processes a fraction f of its input. Downstream
//! rates depend on upstream ones, so the model iterates to a fixed point.
//!
//! Constraints (core): cmd_vel >= 35 Hz, localisation (amcl) >= 30 Hz.
//! Objectives (non-core, max-min): detector Hz capped at 10, web frames Hz
//! capped at 15. With 2 cores both targets cannot be met while the core
//! constraints hold, so the optimum (0.879 of target) is an interior trade-off
//! that needs quotas, shares and adaptor rates set together.

use super::TestProblem;
use crate::error::Result;
use crate::problem::{Constraint, Objective, Problem, Scalarization};
use crate::space::{Knob, Space};

const CORES: f64 = 2.0;
const LIDAR_HZ: f64 = 40.0;
const CAMERA_HZ: f64 = 30.0;
// CPU cost per message / cycle (core-seconds).
const C_LIDAR: f64 = 0.003;
const C_AMCL: f64 = 0.013;
const C_COSTMAP: f64 = 0.006;
const C_PLANNER: f64 = 0.007;
const C_CAMERA: f64 = 0.008;
const C_SERIALISE: f64 = 0.003;
const C_DETECT: f64 = 0.09;
const C_WEB_FRAME: f64 = 0.015;
const C_WEB_SCAN: f64 = 0.003;

/// Rates the model predicts for one config.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotRates {
    pub cmd_vel_hz: f64,
    pub amcl_hz: f64,
    pub detector_hz: f64,
    pub web_hz: f64,
    /// CPU each node gets (cores), in node order.
    pub alloc: [f64; 7],
}

/// The stack model (knob order below).
#[derive(Debug, Clone, Copy)]
pub struct RobotModel;

/// Knob names in order.
pub const KNOBS: [&str; 13] = [
    "quota_lidar",
    "quota_amcl",
    "quota_costmap",
    "quota_planner",
    "quota_camera",
    "quota_detector",
    "quota_web",
    "shares_detector",
    "shares_web",
    "adaptor_detector_hz",
    "adaptor_web_frames_hz",
    "adaptor_web_scans_hz",
    "planner_hz",
];

/// Weighted water-filling of `capacity` among nodes with caps and weights.
fn share(caps: &[f64; 7], weights: &[f64; 7], capacity: f64) -> [f64; 7] {
    let mut alloc = [0.0; 7];
    let mut active: Vec<usize> = (0..7).filter(|&i| caps[i] > 0.0).collect();
    let mut remaining = capacity;
    while !active.is_empty() {
        let wsum: f64 = active.iter().map(|&i| weights[i]).sum();
        let per_weight = remaining / wsum;
        let (sat, unsat): (Vec<usize>, Vec<usize>) = active
            .iter()
            .partition(|&&i| caps[i] <= weights[i] * per_weight);
        if sat.is_empty() {
            for &i in &unsat {
                alloc[i] = weights[i] * per_weight;
            }
            break;
        }
        for &i in &sat {
            alloc[i] = caps[i];
            remaining -= caps[i];
        }
        active = unsat;
    }
    alloc
}

impl RobotModel {
    /// Simulates the stack at knob values `x` (see [`KNOBS`]).
    pub fn rates(x: &[f64]) -> RobotRates {
        let quota = [x[0], x[1], x[2], x[3], x[4], x[5], x[6]];
        let weights = [1.0, 1.0, 1.0, 1.0, 1.0, x[7], x[8]];
        let threads = [1.0, 1.0, 1.0, 1.0, 1.0, 2.0, 1.0];
        let (ad_det, ad_web_f, ad_web_s, planner_hz) = (x[9], x[10], x[11], x[12]);
        let mut frac = [1.0f64; 7];
        let mut out = RobotRates {
            cmd_vel_hz: 0.0,
            amcl_hz: 0.0,
            detector_hz: 0.0,
            web_hz: 0.0,
            alloc: [0.0; 7],
        };
        for _ in 0..60 {
            let scans = LIDAR_HZ * frac[0];
            let frames = CAMERA_HZ * frac[4];
            let det_in = frames.min(ad_det);
            let web_f_in = frames.min(ad_web_f);
            let web_s_in = scans.min(ad_web_s);
            let demand = [
                LIDAR_HZ * C_LIDAR,
                scans * C_AMCL,
                scans * C_COSTMAP,
                planner_hz * C_PLANNER,
                CAMERA_HZ * C_CAMERA + (det_in + web_f_in) * C_SERIALISE,
                det_in * C_DETECT,
                web_f_in * C_WEB_FRAME + web_s_in * C_WEB_SCAN,
            ];
            let caps: [f64; 7] = std::array::from_fn(|i| demand[i].min(quota[i]).min(threads[i]));
            let alloc = share(&caps, &weights, CORES);
            let new_frac: [f64; 7] = std::array::from_fn(|i| {
                if demand[i] > 0.0 {
                    (alloc[i] / demand[i]).min(1.0)
                } else {
                    1.0
                }
            });
            // Damped update keeps the fixed-point iteration from oscillating.
            for i in 0..7 {
                frac[i] = 0.5 * frac[i] + 0.5 * new_frac[i];
            }
            let amcl_hz = scans * frac[1];
            let costmap_hz = scans * frac[2];
            out = RobotRates {
                cmd_vel_hz: planner_hz
                    * frac[3]
                    * (amcl_hz / 30.0).min(1.0)
                    * (costmap_hz / 25.0).min(1.0),
                amcl_hz,
                detector_hz: det_in * frac[5],
                web_hz: web_f_in * frac[6],
                alloc,
            };
        }
        out
    }
}

/// The robot-stack problem (13 knobs).
pub fn problem() -> Result<TestProblem> {
    let q = |n: &str, hi: f64| Knob::linear(n, 0.05, hi);
    let knobs = vec![
        q(KNOBS[0], 1.0),
        q(KNOBS[1], 1.0),
        q(KNOBS[2], 1.0),
        q(KNOBS[3], 1.0),
        q(KNOBS[4], 1.0),
        q(KNOBS[5], 2.0),
        q(KNOBS[6], 1.0),
        Knob::log(KNOBS[7], 0.1, 10.0),
        Knob::log(KNOBS[8], 0.1, 10.0),
        Knob::log(KNOBS[9], 0.5, 30.0),
        Knob::log(KNOBS[10], 0.5, 30.0),
        Knob::log(KNOBS[11], 0.5, 40.0),
        Knob::linear(KNOBS[12], 10.0, 60.0),
    ];
    let problem = Problem::new(
        Space::new(knobs)?,
        vec![
            Objective::capped("detector_hz", 10.0),
            Objective::capped("web_hz", 15.0),
        ],
        vec![
            Constraint::at_least("cmd_vel_hz", 35.0),
            Constraint::at_least("amcl_hz", 30.0),
        ],
        Scalarization::MaxMin,
    )?;
    fn eval(x: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let r = RobotModel::rates(x);
        (vec![r.detector_hz, r.web_hz], vec![r.cmd_vel_hz, r.amcl_hz])
    }
    Ok(TestProblem {
        name: "robot",
        problem,
        // Today's deployment: core nodes unrestricted, non-core apps throttled hard.
        current: vec![
            1.0, 1.0, 1.0, 1.0, 1.0, 0.3, 0.2, 1.0, 1.0, 3.0, 2.0, 2.0, 40.0,
        ],
        best_known: Some(ROBOT_BEST),
        best_x: Some(ROBOT_X.to_vec()),
        source: "closed-form CPU budget (0.8795 bound) + hill climb to 0.879021; see ROBOT_BEST",
        eval,
    })
}
/// 0.879021, the true optimum to about 1e-3. The earlier best-known value
/// (0.874488, from 300k random configs and 12 optimizer runs refined by
/// coordinate search) was 0.5 % short: coordinate search cannot leave the
/// point where the detector adaptor passes every produced frame, but capping
/// it just below the detector's processing rate saves the serialisation of
/// frames the detector would drop. Derivation: the cheapest feasible core
/// (lidar throttled to 30 scans/s, amcl 30 Hz, costmap 25 Hz, planner 35 Hz)
/// takes 0.875 cores; spending the other 1.125 on a balanced non-core value t
/// (15t camera frames, 10t of them to the detector) gives
/// 0.0375 t^2 + 1.245 t = 1.1235, t = 0.8795. A hill climb with 1–3-knob
/// random moves from that design reaches this config (value 0.879021).
pub(crate) const ROBOT_BEST: f64 = 0.879_021;
pub(crate) const ROBOT_X: [f64; 13] = [
    0.090_000_007_886_762_09,
    0.402_242_306_473_108_05,
    0.149_896_159_816_336_2,
    0.937_241_404_404_478,
    0.134_535_496_124_898_2,
    0.841_807_611_247_112,
    0.419_840_618_559_853_83,
    0.425_313_557_588_898,
    9.999_702_763_087_024,
    8.849_039_210_281_104,
    29.996_472_228_747_33,
    0.5,
    35.024_258_293_153_73,
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn current_config_is_feasible_and_greedy_non_core_starves_the_core() {
        let p = problem().unwrap();
        let now = RobotModel::rates(&p.current);
        assert!(now.cmd_vel_hz >= 35.0 && now.amcl_hz >= 30.0, "{now:?}");
        assert!(now.alloc.iter().sum::<f64>() <= CORES + 1e-9);
        // Unthrottled non-core apps with default shares: CFS fair sharing squeezes amcl.
        let mut greedy = p.current.clone();
        greedy[5] = 2.0;
        greedy[6] = 1.0;
        greedy[9] = 30.0;
        greedy[10] = 30.0;
        greedy[11] = 40.0;
        let g = RobotModel::rates(&greedy);
        assert!(g.amcl_hz < 30.0 || g.cmd_vel_hz < 35.0, "{g:?}");
        assert!(
            (g.alloc.iter().sum::<f64>() - CORES).abs() < 1e-6,
            "saturated machine: {g:?}"
        );
    }

    #[test]
    fn water_filling_respects_caps_and_weights() {
        let a = share(
            &[0.1, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0],
            &[1.0, 1.0, 3.0, 1.0, 1.0, 1.0, 1.0],
            1.0,
        );
        assert!((a[0] - 0.1).abs() < 1e-12);
        assert!(
            (a[1] - 0.225).abs() < 1e-12 && (a[2] - 0.675).abs() < 1e-12,
            "{a:?}"
        );
    }
}
