//! Reports of tuning runs and benchmarks for people: SVG charts
//! ([`svg`]) and the optimisation-progress chart ([`progress`]). Pure: data
//! in, text out; the callers write the files.

pub mod progress;
pub mod svg;
