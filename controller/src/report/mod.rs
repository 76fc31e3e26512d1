//! Reports of tuning runs and benchmarks for people: SVG charts
//! ([`svg`]). Pure: data in, text out; the callers write the files.

pub mod svg;
