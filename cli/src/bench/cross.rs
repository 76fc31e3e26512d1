//! The paper's Table IV: each stack's full-ConfigBot config applied on each
//! other stack (a fresh robot running that stack, no spec, measured over the
//! window). A config names nodes and edges; [`carry_over`] keeps the entries
//! the other stack has and says which it drops; nodes the config does not
//! name run unlimited, edges it does not name pass everything.

use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;

use configbot_manifests::ResourceConfig;
use serde::Serialize;

use super::owner::Current;
use super::{BenchArgs, MethodResult, Plan, example_for, start};
use crate::demo::{measure_defs, print_eval};
use configbot_controller::tuning::robot::NodeApi;
use configbot_tuning::measure;

/// One cell of the matrix: `from`'s best config measured on `on`.
#[derive(Debug, Clone, Serialize)]
#[serde(rename_all = "camelCase")]
pub struct CrossEntry {
    /// The stack the config was tuned for.
    pub from: String,
    /// The stack it ran on.
    pub on: String,
    /// The diagonal: the stack's own tuned measurement from the main table.
    pub own: bool,
    pub satisfaction: f64,
    /// Mean rate of each non-core metric of `on`'s spec over the window.
    pub non_core: BTreeMap<String, f64>,
    /// Config entries `on` lacks, left out (`cpu /node`, `adaptor /topic>/sub`).
    pub dropped: Vec<String>,
    /// What was applied.
    pub config: ResourceConfig,
}

/// A config restricted to another stack.
#[derive(Debug, Clone, PartialEq)]
pub struct CarryOver {
    pub config: ResourceConfig,
    pub dropped: Vec<String>,
}

/// Keeps the CPU limits and weights of nodes in `nodes` and the adaptor
/// rates of edges (topic, subscriber) in `edges`; everything else is dropped
/// and named (pure).
pub fn carry_over(
    cfg: &ResourceConfig,
    nodes: &BTreeSet<String>,
    edges: &BTreeSet<(String, String)>,
) -> CarryOver {
    let mut dropped = Vec::new();
    let mut out = ResourceConfig {
        cpu_period_micros: cfg.cpu_period_micros,
        ..ResourceConfig::default()
    };
    for (node, cpus) in &cfg.cpu {
        if nodes.contains(node) {
            out.cpu.insert(node.clone(), *cpus);
        } else {
            dropped.push(format!("cpu {node}"));
        }
    }
    for (node, w) in &cfg.cpu_weight {
        if nodes.contains(node) {
            out.cpu_weight.insert(node.clone(), *w);
        } else {
            dropped.push(format!("weight {node}"));
        }
    }
    for a in &cfg.adaptors {
        if edges.contains(&(a.topic.clone(), a.subscriber.clone())) {
            out.adaptors.push(a.clone());
        } else {
            dropped.push(format!("adaptor {}>{}", a.topic, a.subscriber));
        }
    }
    CarryOver {
        config: out,
        dropped,
    }
}

/// The rows (from) and columns (on) of the matrix, in first-seen order.
fn axes(entries: &[CrossEntry]) -> (Vec<String>, Vec<String>) {
    let mut rows: Vec<String> = Vec::new();
    let mut cols: Vec<String> = Vec::new();
    for e in entries {
        if !rows.contains(&e.from) {
            rows.push(e.from.clone());
        }
        if !cols.contains(&e.on) {
            cols.push(e.on.clone());
        }
    }
    (rows, cols)
}

/// The matrix as text: one row per tuned stack, one column per stack it ran
/// on, each cell `satisfaction% / non-core Hz` (`*` the stack's own) (pure).
pub fn matrix_table(entries: &[CrossEntry]) -> String {
    let (rows, cols) = axes(entries);
    let mut headers = vec!["CONFIG OF \\ RUN ON".to_string()];
    headers.extend(cols.iter().map(|c| c.to_uppercase()));
    let body: Vec<Vec<String>> = rows
        .iter()
        .map(|r| {
            let mut row = vec![r.clone()];
            row.extend(cols.iter().map(|c| {
                entries
                    .iter()
                    .find(|e| &e.from == r && &e.on == c)
                    .map_or("-".into(), |e| {
                        let nc: Vec<String> =
                            e.non_core.values().map(|v| format!("{v:.1}")).collect();
                        format!(
                            "{:.1}% / {}{}",
                            e.satisfaction * 100.0,
                            nc.join(","),
                            if e.own { " *" } else { "" }
                        )
                    })
            }));
            row
        })
        .collect();
    let names: Vec<&str> = entries
        .first()
        .map(|e| e.non_core.keys().map(String::as_str).collect())
        .unwrap_or_default();
    let mut out = format!(
        "Cross-evaluation (satisfaction / non-core Hz: {}; * = tuned on that stack):\n{}",
        names.join(","),
        configbot_controller::table::render(&headers, &body)
    );
    for e in entries.iter().filter(|e| !e.dropped.is_empty()) {
        out.push_str(&format!(
            "{} on {}: dropped {}\n",
            e.from,
            e.on,
            e.dropped.join(", ")
        ));
    }
    out
}

fn non_core(defs: &[measure::MetricDef], means: &BTreeMap<String, f64>) -> BTreeMap<String, f64> {
    defs.iter()
        .filter(|d| !d.core)
        .map(|d| (d.name.clone(), means.get(&d.name).copied().unwrap_or(0.0)))
        .collect()
}

/// The configs the matrix carries: each simulated stack's full-ConfigBot
/// config. A real stack's config names none of a simulated stack's nodes or
/// edges, so on one it would drop every entry and measure the default; it
/// is left out (pure), as is a run that had not settled in its time.
fn sources(results: &[MethodResult]) -> Vec<(&MethodResult, ResourceConfig)> {
    results
        .iter()
        .filter(|r| r.method == "configbot" && !super::real::is_real(&r.stack) && !r.unfinished())
        .filter_map(|r| Some((r, serde_json::from_value(r.config.clone()).ok()?)))
        .collect()
}

/// Measures every simulated stack's tuned config on every `plan.cross_on`
/// stack.
pub async fn run(
    cur: &mut Current,
    a: &BenchArgs,
    p: &Plan,
    results: &[MethodResult],
) -> anyhow::Result<Vec<CrossEntry>> {
    let tuned = sources(results);
    let mut out = Vec::new();
    for (r, cfg) in &tuned {
        if p.cross_on.contains(&r.stack) {
            let (stack, spec) = example_for(&r.stack, p)?;
            let defs = measure::metric_defs(&stack.spec, &spec.spec);
            out.push(CrossEntry {
                from: r.stack.clone(),
                on: r.stack.clone(),
                own: true,
                satisfaction: r.satisfaction,
                non_core: non_core(&defs, &r.metrics),
                dropped: Vec::new(),
                config: cfg.clone(),
            });
        }
    }
    for on in &p.cross_on {
        let sources: Vec<_> = tuned.iter().filter(|(r, _)| &r.stack != on).collect();
        if sources.is_empty() {
            continue;
        }
        let (stack, spec) = example_for(on, p)?;
        let defs = measure::metric_defs(&stack.spec, &spec.spec);
        println!("==> cross-evaluation on {on}");
        let robot = start(cur, &a.out, on, "cross", &stack, &defs).await?;
        let measured = async {
            let graph = robot.robot.graph().await?;
            let nodes: BTreeSet<String> = stack.spec.nodes().map(|(_, n)| n.name.clone()).collect();
            let edges: BTreeSet<(String, String)> = graph
                .edges()
                .into_iter()
                .map(|e| (e.topic, e.subscriber))
                .collect();
            let mut cells = Vec::new();
            for (r, cfg) in &sources {
                let c = carry_over(cfg, &nodes, &edges);
                if !c.dropped.is_empty() {
                    println!(
                        "    {}'s config on {on}: dropped {} ({on} lacks them)",
                        r.stack,
                        c.dropped.join(", ")
                    );
                }
                robot.robot.apply(&c.config).await?;
                tokio::time::sleep(Duration::from_secs(2)).await;
                let rep = measure_defs(robot.robot.as_ref(), &defs, p.window).await?;
                print_eval(&format!("{}'s config", r.stack), &defs, &rep);
                let e = measure::evaluate(&defs, &rep, spec.spec.tuning.scalarization);
                cells.push(CrossEntry {
                    from: r.stack.clone(),
                    on: on.clone(),
                    own: false,
                    satisfaction: e.satisfaction,
                    non_core: non_core(&defs, &e.means),
                    dropped: c.dropped,
                    config: c.config,
                });
            }
            anyhow::Ok(cells)
        }
        .await;
        cur.close().await?;
        out.extend(measured?);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use configbot_manifests::AdaptorRate;

    use super::*;

    fn set(v: &[&str]) -> BTreeSet<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn entries_the_other_stack_lacks_are_dropped_and_named() {
        let ad = |t: &str, s: &str, r: f64| AdaptorRate {
            topic: t.into(),
            subscriber: s.into(),
            rate_hz: r,
        };
        let cfg = ResourceConfig {
            cpu: [("/nav", 0.6), ("/terrain", 0.4), ("/det", 0.2)]
                .into_iter()
                .map(|(n, c)| (n.to_string(), c))
                .collect(),
            cpu_weight: [("/nav", 10_000), ("/terrain", 10_000)]
                .into_iter()
                .map(|(n, w)| (n.to_string(), w))
                .collect(),
            cpu_period_micros: Some(20_000),
            adaptors: vec![ad("/image", "/det", 4.0), ad("/points", "/terrain", 2.0)],
        };
        let nodes = set(&["/nav", "/det", "/lidar"]);
        let edges: BTreeSet<(String, String)> = [("/image".to_string(), "/det".to_string())]
            .into_iter()
            .collect();
        let c = carry_over(&cfg, &nodes, &edges);
        assert_eq!(c.config.cpu.keys().collect::<Vec<_>>(), ["/det", "/nav"]);
        assert_eq!(c.config.cpu_period_micros, Some(20_000));
        assert_eq!(c.config.adaptors, vec![ad("/image", "/det", 4.0)]);
        assert_eq!(c.config.cpu_weight.keys().collect::<Vec<_>>(), ["/nav"]);
        assert_eq!(
            c.dropped,
            [
                "cpu /terrain",
                "weight /terrain",
                "adaptor /points>/terrain"
            ]
        );
        // An adaptor whose subscriber exists but whose edge does not is dropped too.
        let only_nodes = carry_over(&cfg, &set(&["/nav", "/det", "/terrain"]), &BTreeSet::new());
        assert_eq!(only_nodes.config.cpu.len(), 3);
        assert!(only_nodes.config.adaptors.is_empty());
        assert_eq!(only_nodes.dropped.len(), 2);
        // Everything fits: nothing dropped, the config unchanged.
        let all = carry_over(
            &cfg,
            &set(&["/nav", "/det", "/terrain"]),
            &[("/image", "/det"), ("/points", "/terrain")]
                .iter()
                .map(|(t, s)| (t.to_string(), s.to_string()))
                .collect(),
        );
        assert_eq!(all.config, cfg);
        assert!(all.dropped.is_empty());
    }

    #[test]
    fn only_the_simulated_stacks_tuned_configs_are_carried() {
        let r = |stack: &str, method: &str| MethodResult {
            stack: stack.into(),
            method: method.into(),
            satisfaction: 1.0,
            metrics: BTreeMap::new(),
            config: serde_json::to_value(ResourceConfig::default()).unwrap(),
            tuning: None,
            core_series: Vec::new(),
            core_latency: BTreeMap::new(),
        };
        let results = [
            r("real-perception", "configbot"),
            r("basic-nav", "cgroup-only"),
            r("basic-nav", "configbot"),
            r("real-nodelets", "oracle"),
            r("terrain-nav", "configbot"),
        ];
        let from: Vec<&str> = sources(&results)
            .iter()
            .map(|(r, _)| r.stack.as_str())
            .collect();
        assert_eq!(from, ["basic-nav", "terrain-nav"]);
    }

    #[test]
    fn matrix_has_one_row_per_config_and_one_column_per_stack() {
        let e = |from: &str, on: &str, sat: f64, own: bool, dropped: Vec<String>| CrossEntry {
            from: from.into(),
            on: on.into(),
            own,
            satisfaction: sat,
            non_core: [("det".to_string(), 4.2)].into_iter().collect(),
            dropped,
            config: ResourceConfig::default(),
        };
        let t = matrix_table(&[
            e("basic", "basic", 1.0, true, vec![]),
            e("basic", "terrain", 0.25, false, vec![]),
            e("terrain", "basic", 0.5, false, vec!["cpu /terrain".into()]),
        ]);
        let lines: Vec<&str> = t.lines().collect();
        assert!(
            lines[1].contains("BASIC") && lines[1].contains("TERRAIN"),
            "{t}"
        );
        assert!(lines[2].starts_with("basic"), "{t}");
        assert!(lines[2].contains("100.0% / 4.2 *"), "{t}");
        assert!(lines[2].contains("25.0% / "), "{t}");
        assert!(
            lines[3].starts_with("terrain") && lines[3].contains("50.0%"),
            "{t}"
        );
        assert!(
            lines[3].trim_end().ends_with('-'),
            "terrain was not measured on itself: {t}"
        );
        assert_eq!(lines[4], "terrain on basic: dropped cpu /terrain");
    }
}
