//! The config library: the best known config per context, kept as
//! `ConfigProfile` objects in the store, so `configbot get cprof -o yaml`
//! exports them and `configbot apply -f` imports them on another robot of the
//! same model. Context = robot model + sorted running apps and nodes of the
//! stack + user labels (annotation `configbot.dev/context-labels: "k=v,k=v"`
//! on the PerformanceSpec or the RobotStack). Pure: the controller's
//! `tuning::profiles` looks entries up in the store and saves them.

use std::collections::BTreeMap;

use configbot_api::graph::Graph;
use configbot_manifests::{
    API_VERSION, ConfigProfile, ConfigProfileSpec, Kind, ObjectMeta, PerformanceSpecSpec,
    ProfileContext, ProfileTrial, ResourceConfig, RobotStack, RobotStackSpec,
};
use configbot_optimizer::Observation;

use super::knobs::KnobSpace;
use super::measure::MetricDef;

/// Annotation carrying user context labels.
pub const CONTEXT_LABELS: &str = "configbot.dev/context-labels";

/// Parse `k=v,k=v` (blank entries ignored; an entry without `=` gets an empty value).
pub fn parse_labels(s: &str) -> BTreeMap<String, String> {
    s.split(',')
        .map(str::trim)
        .filter(|e| !e.is_empty())
        .map(|e| match e.split_once('=') {
            Some((k, v)) => (k.trim().to_string(), v.trim().to_string()),
            None => (e.to_string(), String::new()),
        })
        .collect()
}

/// The context of a stack on a live graph.
pub fn context(
    stack: &RobotStack,
    graph: &Graph,
    labels: &BTreeMap<String, String>,
) -> ProfileContext {
    let mut apps = Vec::new();
    let mut nodes = Vec::new();
    for app in &stack.spec.apps {
        let running: Vec<&str> = app
            .nodes
            .iter()
            .filter(|n| graph.nodes.contains_key(&n.name))
            .map(|n| n.name.as_str())
            .collect();
        if !running.is_empty() {
            apps.push(app.name.clone());
            nodes.extend(running.into_iter().map(str::to_string));
        }
    }
    apps.sort();
    nodes.sort();
    ProfileContext {
        robot_model: stack
            .spec
            .robot
            .model
            .clone()
            .unwrap_or_else(|| stack.metadata.name.clone()),
        apps,
        nodes,
        labels: labels.clone(),
    }
}

/// FNV-1a: stable across builds and platforms (unlike std's hasher).
pub(crate) fn fnv(text: &str) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in text.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

/// Digest of what a learned config depends on: the spec's metrics and knobs.
pub fn spec_digest(spec: &PerformanceSpecSpec) -> String {
    let text = serde_json::to_string(&(&spec.metrics, &spec.knobs)).unwrap_or_default();
    format!("{:016x}", fnv(&text))
}

/// Digest of what a stack's measurements depend on: its apps and nodes (how
/// each is started) and the spec's metrics and knobs. The bench keeps it with
/// an oracle, so a later run reuses that oracle only for the same manifests.
pub fn stack_digest(stack: &RobotStackSpec, spec: &PerformanceSpecSpec) -> String {
    let text = serde_json::to_string(&(stack, &spec.metrics, &spec.knobs)).unwrap_or_default();
    format!("{:016x}", fnv(&text))
}

/// Whether a profile was learned for this spec's targets (an imported
/// profile without a digest is trusted).
pub fn learned_for(p: &ConfigProfile, spec: &PerformanceSpecSpec) -> bool {
    p.spec
        .spec_digest
        .as_ref()
        .is_none_or(|d| *d == spec_digest(spec))
}

/// Object name of a spec's entry for a context: `<spec>-<8 hex digits of the context key>`.
pub fn profile_name(spec_name: &str, ctx: &ProfileContext) -> String {
    let h = fnv(&ctx.key());
    let mut name = format!("{spec_name}-{:08x}", (h ^ (h >> 32)) as u32);
    if name.len() > 253 {
        name = name[name.len() - 253..]
            .trim_start_matches(['-', '.'])
            .to_string();
    }
    name
}

/// A library entry as a manifest.
#[allow(clippy::too_many_arguments)]
pub fn profile(
    namespace: &str,
    spec_name: &str,
    spec_digest: Option<String>,
    ctx: &ProfileContext,
    config: &ResourceConfig,
    satisfaction: f64,
    objective: Option<f64>,
    trials: Vec<ProfileTrial>,
) -> ConfigProfile {
    let mut labels = BTreeMap::new();
    labels.insert("configbot.dev/spec".to_string(), spec_name.to_string());
    ConfigProfile {
        api_version: API_VERSION.into(),
        kind: Kind::ConfigProfile.name().into(),
        metadata: ObjectMeta {
            name: profile_name(spec_name, ctx),
            namespace: Some(namespace.into()),
            labels,
            ..ObjectMeta::default()
        },
        spec: ConfigProfileSpec {
            context: ctx.clone(),
            spec_name: spec_name.into(),
            spec_digest,
            config: config.clone(),
            satisfaction: Some(satisfaction),
            objective,
            trials,
        },
    }
}

/// The entry for `spec_name` in `ctx` among stored profiles (any name: imported ones count).
pub fn find(
    profiles: &[serde_json::Value],
    spec_name: &str,
    ctx: &ProfileContext,
) -> Option<ConfigProfile> {
    profiles
        .iter()
        .filter_map(|v| serde_json::from_value::<ConfigProfile>(v.clone()).ok())
        .filter(|p| p.spec.spec_name == spec_name && p.spec.context == *ctx)
        .max_by(|a, b| {
            let k = |p: &ConfigProfile| {
                (
                    p.spec.satisfaction.unwrap_or(0.0),
                    p.spec.objective.unwrap_or(0.0),
                )
            };
            k(a).partial_cmp(&k(b)).unwrap_or(std::cmp::Ordering::Equal)
        })
}

/// Trials of a profile as optimizer observations in the current knob space
/// (values: constraint values as the optimizer saw them, objective means).
pub fn prior_observations(
    knobs: &KnobSpace,
    defs: &[MetricDef],
    p: &ConfigProfile,
) -> Vec<Observation> {
    p.spec
        .trials
        .iter()
        .filter_map(|t| {
            let pick = |core: bool| -> Option<Vec<f64>> {
                defs.iter()
                    .filter(|d| d.core == core)
                    .map(|d| t.values.get(&d.name).copied())
                    .collect()
            };
            Some(Observation {
                x: knobs.from_config(&t.config),
                objectives: pick(false)?,
                constraints: pick(true)?,
                censored: t.censored,
            })
        })
        .collect()
}

/// The config that drains the non-core apps before a library config is
/// verified — what `KnobSpace::drain_point` is to a trial (see
/// `super::settle`), taken from the config itself, since a run that reuses a
/// profile derives no knobs: every adaptor into a non-core node at the
/// spec's minimum rate (no new work) and every non-core node that feeds a
/// metric at its CPU bound (finish the old work fast); core limits, weights
/// and the nodes held at their minimum as in `config`. `None` when `config`
/// holds back no non-core input: nothing piles up, nothing to drain. Pure.
///
/// A profile was learned from drained states, but it is re-applied after
/// whatever ran before. The timeline's switch back to Basic-NAV re-applied
/// its profile onto a detector that Terrain-NAV's config had starved
/// (0.37 CPU, frames still in flight): with the detector's input opened,
/// its threads kept both CPUs, `/cmd_vel` read 20 Hz for 20 s, and the
/// profile was judged failed — the same config read 38 Hz from a drained
/// state moments later.
pub fn drain_before(
    config: &ResourceConfig,
    stack: &RobotStackSpec,
    spec: &PerformanceSpecSpec,
    graph: &Graph,
    cpus: f64,
) -> Option<ResourceConfig> {
    let non_core: std::collections::BTreeSet<&str> = stack
        .nodes()
        .filter(|(app, _)| !app.core)
        .map(|(_, n)| n.name.as_str())
        .collect();
    let is_non_core = |node: &str| non_core.contains(node);
    if !config.adaptors.iter().any(|a| is_non_core(&a.subscriber)) {
        return None;
    }
    let feeds = super::knobs::feeds_a_metric(graph, spec);
    let mut drain = config.clone();
    for a in drain
        .adaptors
        .iter_mut()
        .filter(|a| is_non_core(&a.subscriber))
    {
        a.rate_hz = a.rate_hz.min(spec.knobs.adaptors.min_rate_hz);
    }
    for (node, cpu) in drain.cpu.iter_mut() {
        if is_non_core(node) && feeds.contains(node) {
            *cpu = cpu.max(super::knobs::cpu_max(spec, node, cpus));
        }
    }
    Some(drain)
}

#[cfg(test)]
mod tests {
    use super::*;
    use configbot_api::graph::NodeInfo;
    use configbot_manifests::AdaptorRate;

    fn stack() -> RobotStack {
        serde_json::from_value(serde_json::json!({
            "apiVersion": API_VERSION, "kind": "RobotStack", "metadata": {"name": "s"},
            "spec": {"robot": {"model": "spot"}, "apps": [
                {"name": "nav", "core": true, "nodes": [{"name": "/planner", "run": {"command": "x"}}]},
                {"name": "det", "nodes": [{"name": "/detector", "run": {"command": "x"}},
                                          {"name": "/camera", "run": {"command": "x"}}]}]}
        }))
        .unwrap()
    }

    fn graph(nodes: &[&str]) -> Graph {
        let mut g = Graph::default();
        for n in nodes {
            g.nodes.insert(
                n.to_string(),
                NodeInfo {
                    name: n.to_string(),
                    uri: String::new(),
                    pid: None,
                },
            );
        }
        g
    }

    #[test]
    fn context_table() {
        let none = BTreeMap::new();
        let outdoor = parse_labels("location=outdoor, ,site = a");
        assert_eq!(outdoor.len(), 2);
        let cases: Vec<(&[&str], &BTreeMap<String, String>, &str)> = vec![
            (&["/planner"], &none, "spot|nav|/planner|"),
            (
                &["/detector", "/planner", "/rosout"],
                &none,
                "spot|det,nav|/detector,/planner|",
            ),
            (
                &["/camera", "/detector", "/planner"],
                &outdoor,
                "spot|det,nav|/camera,/detector,/planner|location=outdoor,site=a",
            ),
        ];
        for (nodes, labels, key) in cases {
            assert_eq!(context(&stack(), &graph(nodes), labels).key(), key);
        }
    }

    #[test]
    fn find_matches_spec_and_context_and_names_are_stable() {
        let ctx = context(&stack(), &graph(&["/planner"]), &BTreeMap::new());
        let other = context(
            &stack(),
            &graph(&["/planner", "/detector"]),
            &BTreeMap::new(),
        );
        let p = profile(
            "default",
            "spec",
            None,
            &ctx,
            &ResourceConfig::default(),
            1.0,
            None,
            vec![],
        );
        assert_eq!(p.metadata.name, profile_name("spec", &ctx));
        assert_ne!(profile_name("spec", &ctx), profile_name("spec", &other));
        assert!(p.metadata.name.starts_with("spec-"));
        let stored = vec![serde_json::to_value(&p).unwrap()];
        assert!(find(&stored, "spec", &ctx).is_some());
        assert!(find(&stored, "spec", &other).is_none());
        assert!(find(&stored, "other-spec", &ctx).is_none());
        let m = configbot_manifests::decode_and_validate(&stored[0]);
        assert!(m.is_ok(), "a saved profile is a valid manifest: {m:?}");
    }

    #[test]
    fn a_library_config_is_drained_into_like_a_trial_before_it_is_verified() {
        // /camera -> /image -> /detector -> /detections (a metric); /logger
        // takes /image too but feeds no metric (held at its minimum).
        let st: RobotStack = serde_json::from_value(serde_json::json!({
            "apiVersion": API_VERSION, "kind": "RobotStack", "metadata": {"name": "s"},
            "spec": {"apps": [
                {"name": "nav", "core": true, "nodes": [{"name": "/planner", "run": {"command": "x"}}]},
                {"name": "det", "nodes": [{"name": "/camera", "run": {"command": "x"}},
                                          {"name": "/detector", "run": {"command": "x"}},
                                          {"name": "/logger", "run": {"command": "x"}}]}]}
        }))
        .unwrap();
        let sp: configbot_manifests::PerformanceSpec = serde_json::from_value(serde_json::json!({
            "apiVersion": API_VERSION, "kind": "PerformanceSpec", "metadata": {"name": "p"},
            "spec": {"stackRef": {"name": "s"}, "metrics": [
                {"name": "cmd", "app": "nav", "source": {"topicRate": {"topic": "/cmd_vel"}}, "target": {"atLeast": 35}},
                {"name": "det", "app": "det", "source": {"topicRate": {"topic": "/detections"}}, "target": {"atLeast": 3}}],
              "knobs": {"cpu": {"max": 1.5}, "adaptors": {"minRateHz": 0.5}}}
        }))
        .unwrap();
        let mut g = graph(&["/planner", "/camera", "/detector", "/logger"]);
        for (topic, publisher, subscribers) in [
            ("/image", "/camera", vec!["/detector", "/logger"]),
            ("/detections", "/detector", vec![]),
            ("/cmd_vel", "/planner", vec![]),
        ] {
            g.topics.insert(
                topic.into(),
                configbot_api::graph::TopicInfo {
                    name: topic.into(),
                    msg_type: "m/M".into(),
                    publishers: [publisher.to_string()].into(),
                    subscribers: subscribers.into_iter().map(String::from).collect(),
                },
            );
        }
        let rate = |topic: &str, subscriber: &str, rate_hz: f64| AdaptorRate {
            topic: topic.into(),
            subscriber: subscriber.into(),
            rate_hz,
        };
        let learned = ResourceConfig {
            cpu: BTreeMap::from([
                ("/detector".to_string(), 0.37),
                ("/logger".to_string(), 0.05),
                ("/planner".to_string(), 1.2),
            ]),
            cpu_weight: BTreeMap::from([("/planner".to_string(), 10_000)]),
            cpu_period_micros: Some(20_000),
            adaptors: vec![
                rate("/image", "/detector", 4.36),
                rate("/image", "/logger", 0.5),
            ],
        };
        let drain = drain_before(&learned, &st.spec, &sp.spec, &g, 2.0).unwrap();
        assert_eq!(drain.cpu["/detector"], 1.5, "freed up to the spec's bound");
        assert_eq!(
            drain.cpu["/logger"], 0.05,
            "feeds no metric: stays at its minimum"
        );
        assert_eq!(drain.cpu["/planner"], 1.2, "core limits as learned");
        assert_eq!(drain.cpu_weight, learned.cpu_weight);
        assert_eq!(drain.cpu_period_micros, Some(20_000));
        assert_eq!(
            drain.adaptors,
            vec![
                rate("/image", "/detector", 0.5),
                rate("/image", "/logger", 0.5)
            ],
            "no new work for the non-core apps"
        );
        // Nothing held back from a non-core app: nothing piled up.
        let open = ResourceConfig {
            adaptors: vec![],
            ..learned.clone()
        };
        assert_eq!(drain_before(&open, &st.spec, &sp.spec, &g, 2.0), None);
        let core_edge = ResourceConfig {
            adaptors: vec![rate("/image", "/planner", 5.0)],
            ..learned
        };
        assert_eq!(drain_before(&core_edge, &st.spec, &sp.spec, &g, 2.0), None);
    }
}
