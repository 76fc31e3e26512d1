//! The tuning and runtime loop's IO (issue 6, the paper's Fig. 3): from a
//! PerformanceSpec to a robot that stays within spec. The decisions are the
//! pure crate `configbot-tuning` (`controller/tuning/`: knobs, measures, the
//! state machine, search, settle, monitor, status, the library's rules); here
//! is what drives them: [`robot`] (the trait `crate::robot` implements for
//! the node runtime, and the clock), [`runner`] (one task per spec: drives
//! the machine, persists every step, writes status and events), [`profiles`]
//! (ConfigProfiles looked up in and saved to the store), [`sim`] (a
//! deterministic simulated robot on simulated time, for tests) and [`view`]
//! (`configbot get trials`).

pub mod profiles;
pub mod robot;
pub mod runner;
pub mod sim;
pub mod view;
