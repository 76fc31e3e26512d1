//! The ask/tell optimizer: an initial design (the current config plus a
//! scrambled Sobol set), then Gaussian-process constrained expected
//! improvement (EI × Π P(feasible), Gardner et al. 2014), maximising the
//! probability of feasibility alone while no feasible trial is known.
//!
//! Choices worth knowing:
//! - **Objectives** are modelled one GP each and combined by the known
//!   scalarisation when scoring (see [`crate::models`]).
//! - **Trust region** ([`TrustRegionSettings`], off by default): after the
//!   initial design, candidates and acquisition refinement stay in a
//!   TuRBO-like box around the best trial that shrinks on failures and grows
//!   on successes (see [`crate::trust`]); UNSAT evidence still scores
//!   candidates over the whole space. Off because on the 13-knob robot model
//!   it locked runs into the basin of their first good trial (3 of 8 seeds
//!   within 5 % in 200 trials, vs 5 of 8 without it).
//! - **Safe exploration** ([`SafetyFloor`]): every proposal (initial design
//!   included, except the current config itself) must have each core
//!   constraint's confidence bound on the safe side of the floor, and lies in a
//!   trust region around the current config whose half-width grows by
//!   `trust_growth` with each trial that measured safe, and within `safe_reach`
//!   of a trial that measured safe and close enough to one that the steepest
//!   slope seen so far (tripled) cannot cross the floor. Constraint outputs are standardised with at
//!   least `constraint_min_scale × |target|` (in safe mode at least the floor's
//!   slack, `(1 - fraction) × |target|`), so a few similar values do not make
//!   the model overconfident; their signal variance is floored at that scale
//!   and their lengthscales are capped at
//!   `safe_max_lengthscale` (rates pinned at a publish rate form plateaus that
//!   otherwise teach the model long lengthscales and tiny uncertainty).
//! - **Warm start** ([`Optimizer::with_prior_observations`]): trials from a
//!   similar context join the models' data (not the budget, and never the
//!   reported best, which must be measured here); the best feasible prior
//!   config is re-measured right after the current one and the Sobol part of
//!   the initial design shrinks accordingly.
//! - **Anchored design** ([`Settings::design_anchor`], off by default): the
//!   initial design's space-filling points are drawn toward a config known
//!   to be feasible by a scale that halves with each infeasible trial of the
//!   design and grows by half (to at most 1) with each feasible one, so a
//!   design whose trials miss a constraint searches from the feasible side
//!   while one whose trials hold covers the whole space.
//! - **Censored trials** (early-stopped because clearly infeasible): the
//!   partial constraint values enter the constraint models as if measured
//!   (they are the evidence of infeasibility, and more trial time would not
//!   have made them feasible); the objective model leaves them out, since a
//!   partial window says little about the objective; they never count as
//!   feasible.
//! - **Stopping**: the budget; `stop_when_ei_below` (the best constrained EI,
//!   in scalarised-objective units, is not worth a trial); UNSAT when, after
//!   `min_trials_before_unsat` trials with none feasible, no candidate reaches
//!   `unsat_when_pof_below` probability of feasibility; or no safe candidate.
//! - **Determinism**: all randomness comes from the serialisable [`Rng`] in the
//!   state, hyperparameter warm starts are part of the state, so a resumed
//!   optimizer proposes exactly what the uninterrupted one would.

use serde::{Deserialize, Serialize};

use crate::design::Sobol;
use crate::error::{Error, Result};
use crate::gp::{FitOptions, Hyper};
use crate::models::{FitPlan, Models, Score};
pub use crate::models::{Prediction, SafetyFloor};
use crate::problem::{Observation, Problem, Sense};
use crate::rng::Rng;
use crate::safe_region::{SLOPE_FACTOR, SafeRegion};
use crate::trust::TrustRegion;
pub use crate::trust::TrustRegionSettings;

/// Two points this close in every unit-cube coordinate are the same config.
const MEASURED_TOLERANCE: f64 = 1e-6;

/// Tuning knobs of the optimizer itself.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Settings {
    pub seed: u64,
    /// Trials in the initial design, the current config included.
    pub initial_design_size: usize,
    /// Trials measured in this context before stopping.
    pub max_trials: usize,
    pub safety: Option<SafetyFloor>,
    /// Stop when the best constrained EI (scalarised-objective units) is below this.
    pub stop_when_ei_below: Option<f64>,
    /// Declare UNSAT early when no candidate's probability of feasibility reaches this.
    pub unsat_when_pof_below: Option<f64>,
    /// Trials before an early UNSAT may be declared.
    pub min_trials_before_unsat: usize,
    /// Random candidates scored per proposal (plus local ones around the best trials).
    pub candidates: usize,
    /// Local-refinement steps for each of the top three candidates.
    pub refine_steps: usize,
    pub fit: FitOptions,
    /// Refit hyperparameters with random restarts every this many trials (and
    /// always while there are fewer than 20 data points); otherwise only from
    /// the previous optimum and the prior centre.
    pub full_refit_every: usize,
    /// Constraint standardisation floor as a fraction of `|target|`.
    pub constraint_min_scale: f64,
    /// Safe mode: initial trust-region half-width in the unit cube.
    pub trust_initial: f64,
    /// Safe mode: trust-region growth per safe trial.
    pub trust_growth: f64,
    /// Safe mode: proposals also stay within this L∞ distance (unit cube) of a
    /// trial that measured safe, so the models extrapolate only a short way.
    pub safe_reach: f64,
    /// Safe mode: cap on the constraint models' lengthscales (unit cube), so
    /// plateaus in the data (a rate pinned at its publish rate) do not make the
    /// model confident about configs it has not seen.
    pub safe_max_lengthscale: f64,
    /// TuRBO-like trust region around the best trial for problems with many
    /// knobs (see [`crate::trust`]); `None` (the default) searches the whole space.
    #[serde(default)]
    pub trust_region: Option<TrustRegionSettings>,
    /// Anchored design (knob values in real units): the initial design's
    /// points after the current config are drawn toward this config, each
    /// `anchor + scale · (point − anchor)` in the unit cube, where `scale`
    /// starts at 1, halves with each infeasible (or censored) trial of the
    /// design and grows by half with each feasible one, to at most 1. A
    /// trial of the design: any told while design points remain (the
    /// current config, a config measured without asking) and the design's
    /// own points. `None` (the default): the design fills the space.
    #[serde(default)]
    pub design_anchor: Option<Vec<f64>>,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            seed: 0,
            initial_design_size: 8,
            max_trials: 60,
            safety: None,
            stop_when_ei_below: None,
            unsat_when_pof_below: Some(0.01),
            min_trials_before_unsat: 20,
            candidates: 1000,
            refine_steps: 25,
            fit: FitOptions::default(),
            full_refit_every: 10,
            constraint_min_scale: 0.05,
            trust_initial: 0.1,
            trust_growth: 1.1,
            safe_reach: 0.15,
            safe_max_lengthscale: 0.3,
            trust_region: None,
            design_anchor: None,
        }
    }
}

/// Why the optimizer stopped.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "reason")]
pub enum StopReason {
    /// `max_trials` trials were measured.
    Budget,
    /// No candidate's constrained EI was worth a trial.
    ExpectedImprovementBelow { max_cei: f64 },
    /// Nothing feasible was found and the model believes nothing is.
    LikelyInfeasible { p_any_feasible: f64 },
    /// With safe exploration on, no unmeasured candidate passed the floor.
    NoSafeCandidate,
}

/// What a user reads in the run's `TuningStopped` event.
impl std::fmt::Display for StopReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StopReason::Budget => write!(f, "every trial of the budget was measured"),
            StopReason::ExpectedImprovementBelow { max_cei } => write!(
                f,
                "the models expect no config to improve the objective by more than {max_cei:.4} (constrained expected improvement, below the stopping threshold)"
            ),
            StopReason::LikelyInfeasible { p_any_feasible } => write!(
                f,
                "no trial was feasible and the models give the most promising config a {:.1} % chance of being so",
                p_any_feasible * 100.0
            ),
            StopReason::NoSafeCandidate => write!(
                f,
                "no config that was not measured yet is predicted safe for the core services"
            ),
        }
    }
}

/// The answer to [`Optimizer::ask`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Proposal {
    /// Measure this config (knob values in real units).
    Try(Vec<f64>),
    Stop(StopReason),
}

/// The best feasible trial.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Best {
    pub x: Vec<f64>,
    pub observation: Observation,
    /// Scalarised objective (see [`crate::problem`]).
    pub value: f64,
}

/// Evidence that nothing is feasible.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Unsat {
    /// The trial with the least total normalised constraint violation.
    pub nearest: Option<Observation>,
    pub nearest_violation: f64,
    /// The model's highest probability of feasibility over the candidates it
    /// scored last (a lower bound on the probability that some config is feasible).
    pub p_any_feasible: Option<f64>,
    pub trials: usize,
}

/// Where a run stands.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    InProgress { best: Option<Best> },
    Best { best: Best, reason: StopReason },
    Unsat { unsat: Unsat, reason: StopReason },
}

/// The ask/tell optimizer; its whole state is serialisable.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Optimizer {
    problem: Problem,
    settings: Settings,
    rng: Rng,
    /// Current config (unit cube).
    current: Vec<f64>,
    /// Remaining initial-design points (unit cube), in order.
    design: Vec<Vec<f64>>,
    observations: Vec<Observation>,
    prior: Vec<Observation>,
    hypers: Vec<Option<Hyper>>,
    pending: Option<Vec<f64>>,
    stopped: Option<StopReason>,
    last_p_any_feasible: Option<f64>,
    /// The anchored design's scale (see [`Settings::design_anchor`]).
    #[serde(default = "full_scale")]
    design_scale: f64,
    /// Whether the pending proposal is a point of the initial design.
    #[serde(default)]
    pending_design: bool,
}

fn full_scale() -> f64 {
    1.0
}

/// How the anchored design's scale moves with each trial of the design
/// (see [`Settings::design_anchor`]): halved by an infeasible one, grown by
/// half by a feasible one.
const DESIGN_SHRINK: f64 = 0.5;
const DESIGN_GROWTH: f64 = 1.5;

impl Optimizer {
    /// A cold start from the current config (knob values in real units).
    pub fn new(problem: Problem, settings: Settings, current: &[f64]) -> Result<Self> {
        Self::with_prior_observations(problem, settings, current, Vec::new())
    }

    /// A warm start: `prior` are trials of a similar context (same problem shape).
    pub fn with_prior_observations(
        problem: Problem,
        settings: Settings,
        current: &[f64],
        prior: Vec<Observation>,
    ) -> Result<Self> {
        problem.space.check(current)?;
        if let Some(a) = &settings.design_anchor {
            problem.space.check(a)?;
        }
        for o in &prior {
            problem.check(o)?;
        }
        if settings.initial_design_size == 0 || settings.candidates == 0 {
            return Err(Error::Settings(
                "initial_design_size and candidates must be > 0".into(),
            ));
        }
        if let Some(s) = &settings.safety
            && !(s.fraction_of_target > 0.0 && s.fraction_of_target <= 1.0 && s.beta >= 0.0)
        {
            return Err(Error::Settings(format!(
                "safety floor fraction {} must be in (0, 1] and beta {} >= 0",
                s.fraction_of_target, s.beta
            )));
        }
        let mut rng = Rng::seed_from_u64(settings.seed);
        let dim = problem.space.dim();
        let current_u = problem.space.to_unit(current);
        let mut design = vec![current_u.clone()];
        let best_prior = prior
            .iter()
            .filter(|o| problem.is_feasible(o))
            .max_by(|a, b| {
                problem
                    .scalarize(&a.objectives)
                    .total_cmp(&problem.scalarize(&b.objectives))
            });
        if let Some(o) = best_prior {
            let u = problem.space.to_unit(&o.x);
            if u != current_u {
                design.push(u);
            }
        }
        let fill = settings
            .initial_design_size
            .saturating_sub(design.len() + prior.len() / 2);
        let sobol = Sobol::scrambled(dim, &mut rng);
        let half = settings.trust_initial;
        for p in sobol.points(0, fill) {
            let u: Vec<f64> = match settings.safety {
                // Safe mode: the space-filling set covers the initial trust region.
                Some(_) => p
                    .iter()
                    .zip(&current_u)
                    .map(|(p, c)| (c + half * (2.0 * p - 1.0)).clamp(0.0, 1.0))
                    .collect(),
                None => p,
            };
            design.push(problem.space.snap_unit(&u));
        }
        design.reverse(); // pop() from the back
        Ok(Self {
            hypers: vec![None; problem.objectives.len() + problem.constraints.len()],
            problem,
            settings,
            rng,
            current: current_u,
            design,
            observations: Vec::new(),
            prior,
            pending: None,
            stopped: None,
            last_p_any_feasible: None,
            design_scale: 1.0,
            pending_design: false,
        })
    }

    pub fn problem(&self) -> &Problem {
        &self.problem
    }

    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// Trials measured in this context.
    pub fn observations(&self) -> &[Observation] {
        &self.observations
    }

    /// Serialises the full state.
    pub fn to_json(&self) -> Result<String> {
        serde_json::to_string(self).map_err(Error::State)
    }

    /// Restores a state written by [`Optimizer::to_json`].
    pub fn from_json(json: &str) -> Result<Self> {
        serde_json::from_str(json).map_err(Error::State)
    }

    /// Records a measured trial (for any config, not only the proposed one).
    pub fn tell(&mut self, obs: Observation) -> Result<()> {
        self.problem.check(&obs)?;
        // A trial of the design: one told while design points remain (the
        // current config, a config measured without asking), or the
        // design's last point, proposed and now measured.
        let of_design = !self.design.is_empty() || self.pending_design;
        self.pending_design = false;
        if self.settings.design_anchor.is_some() && of_design {
            let step = if self.problem.is_feasible(&obs) {
                DESIGN_GROWTH
            } else {
                DESIGN_SHRINK
            };
            self.design_scale = (self.design_scale * step).min(1.0);
        }
        self.pending = None;
        self.observations.push(obs);
        Ok(())
    }

    /// Revises the constraint values measured at `x` (every observation there)
    /// to `constraints`, after a longer measurement of the same config
    /// contradicted them (a config that held its trial and missed its
    /// verification), and takes back a stop other than the budget's: the
    /// models that judged nothing worth another trial had learned that
    /// config as it was first measured, so the next [`Optimizer::ask`]
    /// proposes from the revised ones. Returns how many observations were
    /// revised; with none at `x`, nothing changes.
    pub fn revise(&mut self, x: &[f64], constraints: &[f64]) -> Result<usize> {
        let u = self.problem.space.to_unit(x);
        let Some(first) = self.observations.iter().find(|o| self.at(o, &u)) else {
            return Ok(0);
        };
        let revised = Observation {
            constraints: constraints.to_vec(),
            ..first.clone()
        };
        self.problem.check(&revised)?;
        let mut n = 0;
        for i in 0..self.observations.len() {
            if self.at(&self.observations[i], &u) {
                self.observations[i].constraints = constraints.to_vec();
                n += 1;
            }
        }
        self.pending = None;
        if !matches!(self.stopped, Some(StopReason::Budget)) {
            self.stopped = None;
        }
        Ok(n)
    }

    /// A design point drawn toward the anchor by the design's scale (see
    /// [`Settings::design_anchor`]); the point itself without an anchor.
    /// The current config and a prior's best stay where they are.
    fn anchored(&self, u: &[f64]) -> Vec<f64> {
        let fixed = u == self.current.as_slice() || self.prior.iter().any(|o| self.at(o, u));
        let Some(a) = self.settings.design_anchor.as_ref().filter(|_| !fixed) else {
            return u.to_vec();
        };
        let space = &self.problem.space;
        let a = space.to_unit(a);
        let s = self.design_scale;
        let v: Vec<f64> = u.iter().zip(&a).map(|(p, c)| c + s * (p - c)).collect();
        space.snap_unit(&v)
    }

    /// The anchored design's scale now (1 without an anchor).
    pub fn design_scale(&self) -> f64 {
        self.design_scale
    }

    /// Whether `o` was measured at `u` (unit cube, see [`Self::measured`]).
    fn at(&self, o: &Observation, u: &[f64]) -> bool {
        self.problem
            .space
            .to_unit(&o.x)
            .iter()
            .zip(u)
            .all(|(a, b)| (a - b).abs() <= MEASURED_TOLERANCE)
    }

    /// The next config to measure, or why to stop. Asking again before a
    /// `tell` returns the same proposal.
    pub fn ask(&mut self) -> Result<Proposal> {
        if let Some(r) = &self.stopped {
            return Ok(Proposal::Stop(r.clone()));
        }
        if let Some(p) = &self.pending {
            return Ok(Proposal::Try(p.clone()));
        }
        let proposal = self.next_proposal()?;
        match &proposal {
            Proposal::Try(x) => self.pending = Some(x.clone()),
            Proposal::Stop(r) => self.stopped = Some(r.clone()),
        }
        Ok(proposal)
    }

    fn incumbent(&self) -> Option<(usize, f64)> {
        self.observations
            .iter()
            .enumerate()
            .filter(|(_, o)| self.problem.is_feasible(o))
            .map(|(i, o)| (i, self.problem.scalarize(&o.objectives)))
            .max_by(|a, b| a.1.total_cmp(&b.1))
    }

    fn safe_trials(&self) -> usize {
        let Some(s) = &self.settings.safety else {
            return 0;
        };
        self.observations
            .iter()
            .filter(|o| {
                self.problem
                    .constraints
                    .iter()
                    .zip(&o.constraints)
                    .all(|(c, &v)| s.holds(c, v))
            })
            .count()
    }

    /// Safe mode: the region proposals may come from, built from the trials.
    fn safe_region(&self) -> SafeRegion {
        let Some(floor) = &self.settings.safety else {
            return SafeRegion::default();
        };
        let cons = &self.problem.constraints;
        let pts: Vec<(Vec<f64>, &Observation)> = self
            .observations
            .iter()
            .filter(|o| !o.censored)
            .map(|o| (self.problem.space.to_unit(&o.x), o))
            .collect();
        // Steepest slope seen per constraint (value change per unit L∞ distance), tripled.
        let slopes = (0..cons.len())
            .map(|j| {
                let mut l: f64 = 0.0;
                for (a, (ua, oa)) in pts.iter().enumerate() {
                    for (ub, ob) in &pts[..a] {
                        let d = ua
                            .iter()
                            .zip(ub)
                            .map(|(x, y)| (x - y).abs())
                            .fold(0.0, f64::max);
                        if d > 1e-9 {
                            l = l.max((oa.constraints[j] - ob.constraints[j]).abs() / d);
                        }
                    }
                }
                SLOPE_FACTOR * l
            })
            .collect();
        let points = pts
            .iter()
            .filter(|(_, o)| {
                cons.iter()
                    .zip(&o.constraints)
                    .all(|(c, &v)| floor.holds(c, v))
            })
            .map(|(u, o)| {
                let margins = cons
                    .iter()
                    .zip(&o.constraints)
                    .map(|(c, &v)| match c.sense {
                        Sense::AtLeast => v - floor.floor(c),
                        Sense::AtMost => floor.floor(c) - v,
                    })
                    .collect();
                (u.clone(), margins)
            })
            .collect();
        SafeRegion {
            active: true,
            reach: self.settings.safe_reach,
            points,
            slopes,
        }
    }

    /// Half-width of the region proposals may come from (1 = whole cube).
    fn trust_half_width(&self) -> f64 {
        match self.settings.safety {
            None => 1.0,
            Some(_) => {
                let n = self.safe_trials().saturating_sub(1) as i32;
                (self.settings.trust_initial * self.settings.trust_growth.powi(n)).min(1.0)
            }
        }
    }

    /// The trust region (many knobs only), replayed from the trials.
    fn trust_region(&self) -> Option<TrustRegion> {
        let settings = self.settings.trust_region.as_ref()?;
        let units: Vec<Vec<f64>> = self
            .observations
            .iter()
            .map(|o| self.problem.space.to_unit(&o.x))
            .collect();
        // The objective models' lengthscales, averaged over objectives.
        let fitted: Vec<&Hyper> = self.hypers
            [..self.problem.objectives.len().min(self.hypers.len())]
            .iter()
            .flatten()
            .collect();
        let log_ls = fitted.first().map(|f| {
            (0..f.log_ls.len())
                .map(|d| fitted.iter().map(|h| h.log_ls[d]).sum::<f64>() / fitted.len() as f64)
                .collect::<Vec<f64>>()
        });
        TrustRegion::replay(
            settings,
            &self.problem,
            &self.observations,
            &units,
            self.settings.initial_design_size,
            log_ls.as_deref(),
            self.settings.safety.is_none(),
        )
    }

    /// Box proposals come from: the safe-mode trust region around the current
    /// config, intersected with the trust region around the best trial.
    fn bounds(&self, tr: Option<&TrustRegion>) -> (Vec<f64>, Vec<f64>) {
        let half = self.trust_half_width();
        let mut lo: Vec<f64> = self.current.iter().map(|c| (c - half).max(0.0)).collect();
        let mut hi: Vec<f64> = self.current.iter().map(|c| (c + half).min(1.0)).collect();
        if let Some(tr) = tr {
            for k in 0..lo.len() {
                let (l, h) = (lo[k].max(tr.lo[k]), hi[k].min(tr.hi[k]));
                // An empty intersection falls back to the safe-mode box.
                if l <= h {
                    lo[k] = l;
                    hi[k] = h;
                }
            }
        }
        (lo, hi)
    }

    fn fit_models(&mut self) -> Result<Models> {
        let data: Vec<&Observation> = self.prior.iter().chain(&self.observations).collect();
        let u: Vec<Vec<f64>> = data
            .iter()
            .map(|o| self.problem.space.to_unit(&o.x))
            .collect();
        let n = self.observations.len();
        let plan = FitPlan {
            fit: &self.settings.fit,
            full: data.len() < 20 || n.is_multiple_of(self.settings.full_refit_every.max(1)),
            constraint_min_scale: match &self.settings.safety {
                Some(f) => self
                    .settings
                    .constraint_min_scale
                    .max(1.0 - f.fraction_of_target),
                None => self.settings.constraint_min_scale,
            },
            constraint_max_lengthscale: self
                .settings
                .safety
                .as_ref()
                .map(|_| self.settings.safe_max_lengthscale),
        };
        Models::fit(
            &self.problem,
            &u,
            &data,
            &mut self.hypers,
            &plan,
            &mut self.rng,
        )
    }

    /// Whether a point was measured already. Compared in the unit cube with a
    /// tolerance: the current config arrives in real units and comes back
    /// from the cube a rounding error away, and an exact comparison let the
    /// initial design measure the current config a second time.
    fn measured(&self, u: &[f64]) -> bool {
        self.observations.iter().any(|o| self.at(o, u))
    }

    fn next_proposal(&mut self) -> Result<Proposal> {
        let space = self.problem.space.clone();
        if self.observations.len() >= self.settings.max_trials {
            if self.incumbent().is_none() && self.settings.max_trials > 0 {
                // Gather the model's evidence for the UNSAT report.
                let models = self.fit_models()?;
                let cands = self.candidates(None, false);
                let scores = models.score(&self.problem, &cands, None, None);
                self.last_p_any_feasible = Some(scores.iter().map(|s| s.pof).fold(0.0, f64::max));
            }
            return Ok(Proposal::Stop(StopReason::Budget));
        }
        // The current config first: it is what runs today, so it is safe by definition.
        if self.observations.is_empty()
            && self.prior.is_empty()
            && let Some(u) = self.design.pop()
        {
            return Ok(Proposal::Try(space.from_unit(&u)));
        }
        let models = if self.observations.is_empty() && self.prior.is_empty() {
            None
        } else {
            Some(self.fit_models()?)
        };
        // Initial design (safety-checked when safe exploration is on).
        while let Some(u) = self.design.pop() {
            let u = self.anchored(&u);
            if self.measured(&u) {
                continue;
            }
            let safe = match (&self.settings.safety, &models) {
                (Some(s), Some(m)) => {
                    m.score(&self.problem, std::slice::from_ref(&u), None, Some(s))[0].safe
                        && self.safe_region().allows(&u)
                }
                _ => true,
            };
            if safe {
                self.pending_design = true;
                return Ok(Proposal::Try(space.from_unit(&u)));
            }
        }
        let Some(models) = models else {
            return Ok(Proposal::Stop(StopReason::NoSafeCandidate));
        };
        if self.trust_region().is_some_and(|t| t.restarting) {
            // A fresh trust-region run starts from random trials (never in safe mode).
            let u: Vec<f64> = (0..space.dim()).map(|_| self.rng.uniform()).collect();
            return Ok(Proposal::Try(space.from_unit(&space.snap_unit(&u))));
        }
        let incumbent = self.incumbent().map(|(_, v)| v);
        let cands = self.candidates(incumbent, true);
        let safety = self.settings.safety.clone();
        let scores = models.score(&self.problem, &cands, incumbent, safety.as_ref());
        let mut p_any = scores.iter().map(|s| s.pof).fold(0.0, f64::max);
        let n = self.observations.len();
        if incumbent.is_none()
            && n >= self.settings.min_trials_before_unsat
            && self.trust_region().is_some()
        {
            // The trust region is local; UNSAT evidence must look everywhere.
            let global = self.candidates(None, false);
            let g = models.score(&self.problem, &global, None, safety.as_ref());
            p_any = g.iter().map(|s| s.pof).fold(p_any, f64::max);
        }
        self.last_p_any_feasible = Some(p_any);
        if incumbent.is_none()
            && n >= self.settings.min_trials_before_unsat
            && let Some(t) = self.settings.unsat_when_pof_below
            && p_any < t
        {
            return Ok(Proposal::Stop(StopReason::LikelyInfeasible {
                p_any_feasible: p_any,
            }));
        }
        let mut order: Vec<usize> = (0..cands.len())
            .filter(|&i| scores[i].safe && !self.measured(&cands[i]))
            .collect();
        order.sort_by(|&a, &b| {
            scores[b]
                .log_acq
                .total_cmp(&scores[a].log_acq)
                .then(a.cmp(&b))
        });
        if order.is_empty() {
            return Ok(Proposal::Stop(StopReason::NoSafeCandidate));
        }
        let mut best = (cands[order[0]].clone(), scores[order[0]]);
        for &i in order.iter().take(3) {
            let refined = self.refine(&models, cands[i].clone(), scores[i], incumbent);
            if refined.1.log_acq > best.1.log_acq {
                best = refined;
            }
        }
        if let (Some(t), Some(cei)) = (self.settings.stop_when_ei_below, best.1.cei)
            && n >= self.settings.initial_design_size
            && cei < t
        {
            return Ok(Proposal::Stop(StopReason::ExpectedImprovementBelow {
                max_cei: cei,
            }));
        }
        Ok(Proposal::Try(space.from_unit(&best.0)))
    }

    /// Random candidates in the trust region plus local ones around the best trials.
    /// With `local`, inside the trust region around the best trial (if any).
    fn candidates(&mut self, incumbent: Option<f64>, local: bool) -> Vec<Vec<f64>> {
        let dim = self.problem.space.dim();
        let half = self.trust_half_width();
        let tr = if local { self.trust_region() } else { None };
        let (lo, hi) = self.bounds(tr.as_ref());
        // Spread of the local candidates: the trust region's half side if any.
        let local_r = tr.as_ref().map_or(half.max(0.1), |t| 0.5 * t.length);
        let mut out = Vec::with_capacity(self.settings.candidates + 200);
        let region = self.safe_region();
        for _ in 0..self.settings.candidates {
            let u: Vec<f64> = if region.active && !region.points.is_empty() {
                // Safe mode: uniform in the box of a random safe trial whose half-width
                // is what the safe region allows there, inside the trust region.
                let (a, _) =
                    &region.points[(self.rng.next_u64() % region.points.len() as u64) as usize];
                let r = region.radius(a);
                (0..dim)
                    .map(|k| {
                        self.rng
                            .range((a[k] - r).max(lo[k]), (a[k] + r).min(hi[k]).max(lo[k]))
                    })
                    .collect()
            } else {
                (0..dim).map(|k| self.rng.range(lo[k], hi[k])).collect()
            };
            out.push(self.problem.space.snap_unit(&u));
        }
        // Local candidates around the best few trials (by objective if feasible, else by violation).
        let mut ranked: Vec<&Observation> =
            self.observations.iter().filter(|o| !o.censored).collect();
        ranked.sort_by(|a, b| {
            let key = |o: &Observation| {
                let v = self.problem.violation(&o.constraints);
                if v == 0.0 && incumbent.is_some() {
                    -self.problem.scalarize(&o.objectives)
                } else {
                    1e9 + v
                }
            };
            key(a).total_cmp(&key(b))
        });
        let anchors: Vec<Vec<f64>> = ranked
            .iter()
            .take(4)
            .map(|o| self.problem.space.to_unit(&o.x))
            .collect();
        for a in &anchors {
            let r = if region.active {
                region.radius(a)
            } else {
                local_r
            };
            for j in 0..50 {
                let sigma = if j % 2 == 0 { 0.1 } else { 0.5 } * r;
                let u: Vec<f64> = a
                    .iter()
                    .enumerate()
                    .map(|(k, v)| (v + sigma * self.rng.normal()).clamp(lo[k], hi[k]))
                    .collect();
                out.push(self.problem.space.snap_unit(&u));
            }
        }
        // Around the best trial, also move only a few coordinates at a time
        // (in many dimensions, small subspace moves find improvements far more often).
        if let Some(a) = anchors.first() {
            let r = if region.active {
                region.radius(a)
            } else {
                local_r
            };
            let p = (3.0 / dim as f64).min(1.0);
            for j in 0..200 {
                let sigma = if j % 2 == 0 { 0.1 } else { 0.4 } * r;
                let mut u = a.clone();
                let mut moved = false;
                for (k, v) in u.iter_mut().enumerate() {
                    if self.rng.uniform() < p {
                        *v = (*v + sigma * self.rng.normal()).clamp(lo[k], hi[k]);
                        moved = true;
                    }
                }
                if !moved {
                    let k = (self.rng.next_u64() % dim as u64) as usize;
                    u[k] = (u[k] + sigma * self.rng.normal()).clamp(lo[k], hi[k]);
                }
                out.push(self.problem.space.snap_unit(&u));
            }
        }
        out.retain(|u| region.allows(u));
        out
    }

    /// Stochastic hill climbing on the acquisition from `start`.
    fn refine(
        &mut self,
        models: &Models,
        start: Vec<f64>,
        score: Score,
        incumbent: Option<f64>,
    ) -> (Vec<f64>, Score) {
        let half = self.trust_half_width();
        let tr = self.trust_region();
        let (lo, hi) = self.bounds(tr.as_ref());
        let (mut x, mut s) = (start, score);
        let mut step = 0.05 * half.max(0.1);
        if let Some(t) = &tr {
            step = step.min(0.1 * t.length);
        }
        let safety = self.settings.safety.clone();
        let region = self.safe_region();
        for _ in 0..self.settings.refine_steps {
            let batch: Vec<Vec<f64>> = (0..4)
                .map(|_| {
                    let u: Vec<f64> = x
                        .iter()
                        .enumerate()
                        .map(|(k, v)| (v + step * self.rng.normal()).clamp(lo[k], hi[k]))
                        .collect();
                    self.problem.space.snap_unit(&u)
                })
                .collect();
            let scores = models.score(&self.problem, &batch, incumbent, safety.as_ref());
            let mut improved = false;
            for (u, sc) in batch.into_iter().zip(scores) {
                if sc.safe && sc.log_acq > s.log_acq && !self.measured(&u) && region.allows(&u) {
                    x = u;
                    s = sc;
                    improved = true;
                }
            }
            step *= if improved { 1.2 } else { 0.7 };
        }
        (x, s)
    }

    /// The best feasible trial so far, or the UNSAT evidence once stopped.
    pub fn outcome(&self) -> Outcome {
        let best = self.incumbent().map(|(i, value)| {
            let o = &self.observations[i];
            Best {
                x: o.x.clone(),
                observation: o.clone(),
                value,
            }
        });
        match (&self.stopped, best) {
            (None, best) => Outcome::InProgress { best },
            (Some(r), Some(best)) => Outcome::Best {
                best,
                reason: r.clone(),
            },
            (Some(r), None) => {
                let nearest = self
                    .observations
                    .iter()
                    .map(|o| (o, self.problem.violation(&o.constraints)))
                    .min_by(|a, b| a.1.total_cmp(&b.1));
                Outcome::Unsat {
                    unsat: Unsat {
                        nearest: nearest.map(|(o, _)| o.clone()),
                        nearest_violation: nearest.map_or(f64::INFINITY, |(_, v)| v),
                        p_any_feasible: self.last_p_any_feasible,
                        trials: self.observations.len(),
                    },
                    reason: r.clone(),
                }
            }
        }
    }

    /// What the models predict at each config (knob units), from one fit
    /// of the observations and `extra` (measurements the search itself
    /// does not count, such as verifications): for choosing among configs
    /// that were not measured.
    pub fn predict_many(&self, extra: &[Observation], xs: &[Vec<f64>]) -> Result<Vec<Prediction>> {
        let mut copy = self.clone();
        for o in extra {
            copy.tell(o.clone())?;
        }
        let models = copy.fit_models()?;
        let us: Vec<Vec<f64>> = xs.iter().map(|x| self.problem.space.to_unit(x)).collect();
        Ok(models.predictions(&self.problem, &us))
    }

    /// The initial design's points not yet proposed.
    pub fn design_left(&self) -> usize {
        self.design.len()
    }

    /// Drops the initial design's points not yet proposed: from the next
    /// ask on, the models choose every proposal. For a caller that learned
    /// where to look (say, a trial reached every objective's cap and missed
    /// a constraint only just), when more space-filling would spend trials
    /// far from it.
    pub fn end_design(&mut self) {
        self.design.clear();
    }

    /// Predicted (mean, sd) of each constraint at a config; for diagnostics and tests.
    pub fn predict_constraints(&mut self, x: &[f64]) -> Result<Vec<(f64, f64)>> {
        let mut copy = self.clone();
        let models = copy.fit_models()?;
        Ok(models.constraint_predictions(&self.problem.space.to_unit(x)))
    }
}
