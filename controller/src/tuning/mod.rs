//! The tuning and runtime loop (issue 6, the paper's Fig. 3): from a
//! PerformanceSpec to a robot that stays within spec.
//!
//! Pure decisions: [`knobs`] (the knob space), [`measure`] (satisfaction and
//! non-core performance), [`machine`] (the run as one state enum and one
//! transition function), [`search`] (baseline → knobs → trials → the best
//! to verify), [`settle`] (how long a trial waits after its config
//! is applied), [`monitor`] (constraint monitor, triggers),
//! [`library`] (contexts and ConfigProfiles). IO at the edges: [`robot`] (the
//! trait `crate::robot` implements for the node runtime), [`runner`] (one task per
//! spec: drives the machine, persists every step, writes status and events),
//! [`sim`] (a deterministic simulated robot on simulated time, for tests).

pub mod knobs;
pub mod library;
pub mod machine;
pub mod measure;
pub mod monitor;
pub mod outcome;
pub mod robot;
pub mod runner;
pub mod search;
pub mod settle;
pub mod sim;
pub mod startup;
pub mod status;
pub mod view;
