//! ConfigBot's control plane: the embedded store, the Kubernetes-style API
//! server, the reconcilers, and the `configbot` CLI with its client.
//!
//! Decisions (status planning, tables, selectors) are pure modules; IO lives in
//! `store`, `api` and `client`.

pub mod api;
pub mod cli;
pub mod client;
pub mod metrics;
pub mod reconcile;
pub mod report;
pub mod robot;
pub mod server;
pub mod store;
pub mod table;
pub mod tuning;
