//! ConfigBot's tuning core (issue 6, the paper's Fig. 3): from a
//! PerformanceSpec to a robot that stays within spec, as pure decisions.
//! Nothing here does IO, waits or reads a clock; the controller's runner
//! (`configbot_controller::tuning::runner`) drives [`machine`] against a
//! robot and the store.
//!
//! [`knobs`] (the knob space), [`measure`] (satisfaction and non-core
//! performance), [`machine`] (the run as one state enum and one transition
//! function), [`search`] (baseline → knobs → trials → the best to verify),
//! [`balance`] (the balanced config computed from the trials' costs),
//! [`outcome`] (verification, remediation, Unsat), [`settle`] (how long a
//! trial waits after its config is applied), [`startup`] (waiting for the
//! stack), [`monitor`] (constraint monitor, triggers, robot events),
//! [`status`] (the run as PerformanceSpec status), [`library`] (contexts and
//! ConfigProfiles).

pub mod balance;
pub mod knobs;
pub mod library;
pub mod machine;
pub mod measure;
pub mod monitor;
pub mod outcome;
pub mod search;
pub mod settle;
pub mod startup;
pub mod status;
