//! ConfigBot's control plane: the embedded store, the Kubernetes-style API
//! server, the reconcilers and the tuning runner. The `configbot` program
//! (crate `configbot`, `cli/`) runs it; the tuning decisions are the pure
//! `configbot-tuning` crate.
//!
//! Decisions (status planning, tables, selectors) are pure modules; IO lives in
//! `store`, `api`, `robot` and the tuning runner.

pub mod api;
pub mod metrics;
pub mod reconcile;
pub mod robot;
pub mod server;
pub mod store;
pub mod table;
pub mod tuning;
