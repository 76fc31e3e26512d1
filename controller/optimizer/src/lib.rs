//! ConfigBot's constrained Bayesian optimizer: decides which configuration to
//! try next on a live robot. Pure (no IO) and deterministic given a seed.
//!
//! - [`space`]: knobs and the unit-cube map; [`problem`]: objectives,
//!   constraints, scalarisation, observations.
//! - [`design`]: scrambled Sobol initial designs; [`gp`]: Gaussian processes;
//!   [`acquisition`]: EI, probability of feasibility and the normal distribution.
//! - [`optimizer`]: the ask/tell loop with safe exploration, warm start,
//!   censored trials, stopping and serialisable state.
//! - [`problems`]: benchmark problems (standard constrained ones and a
//!   simulated robot stack), shared by tests and the bench binary.

pub mod acquisition;
pub mod design;
pub mod error;
pub mod gp;
mod models;
pub mod optimizer;
pub mod problem;
pub mod problems;
pub mod rng;
mod safe_region;
pub mod space;
pub mod trust;

pub use error::{Error, Result};
pub use optimizer::{
    Best, Optimizer, Outcome, Prediction, Proposal, SafetyFloor, Settings, StopReason, Unsat,
};

pub use problem::{Constraint, Goal, Objective, Observation, Problem, Scalarization, Sense};
pub use space::{Knob, Scale, Space};
