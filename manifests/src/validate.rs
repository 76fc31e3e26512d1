//! Semantic validation: rules the types cannot express. Every rule reports a
//! field path and a message, and all violations are reported at once.

use std::collections::{BTreeMap, BTreeSet};

use crate::config::ResourceConfig;
use crate::config_profile::ConfigProfile;
use crate::names::{
    check_dns_label, check_env_name, check_label, check_object_name, check_ros_name,
};
use crate::performance_spec::{EdgeSelector, PerformanceSpec};
use crate::robot_stack::RobotStack;
use crate::{API_VERSION, Manifest, ObjectMeta};

/// One semantic error at a field path.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FieldError {
    pub path: String,
    pub message: String,
}

struct Errors(Vec<FieldError>);

impl Errors {
    fn add(&mut self, path: impl Into<String>, message: impl Into<String>) {
        self.0.push(FieldError {
            path: path.into(),
            message: message.into(),
        });
    }
    fn check(&mut self, path: impl Into<String>, r: Result<(), String>) {
        if let Err(m) = r {
            self.add(path, m);
        }
    }
    fn positive(&mut self, path: impl Into<String>, v: f64) {
        if !(v.is_finite() && v > 0.0) {
            self.add(path, format!("must be a positive number, got {v}"));
        }
    }
}

/// Validate one manifest on its own.
pub fn validate(m: &Manifest) -> Vec<FieldError> {
    let mut e = Errors(Vec::new());
    match m {
        Manifest::RobotStack(s) => {
            check_header(&mut e, &s.api_version, &s.metadata);
            robot_stack(&mut e, s);
        }
        Manifest::PerformanceSpec(p) => {
            check_header(&mut e, &p.api_version, &p.metadata);
            performance_spec(&mut e, p);
        }
        Manifest::ConfigProfile(c) => {
            check_header(&mut e, &c.api_version, &c.metadata);
            config_profile(&mut e, c);
        }
    }
    e.0
}

/// Validate a spec against the stack it names (unknown apps, nodes, bounds above the robot's CPUs).
pub fn validate_against_stack(p: &PerformanceSpec, stack: &RobotStack) -> Vec<FieldError> {
    let mut e = Errors(Vec::new());
    let nodes: BTreeSet<&str> = stack.spec.nodes().map(|(_, n)| n.name.as_str()).collect();
    for (i, m) in p.spec.metrics.iter().enumerate() {
        if stack.spec.app(&m.app).is_none() {
            e.add(
                format!("spec.metrics[{i}].app"),
                format!(
                    "app {:?} is not in RobotStack {:?} (apps: {})",
                    m.app,
                    stack.metadata.name,
                    join(stack.spec.apps.iter().map(|a| a.name.as_str()))
                ),
            );
        }
        if let Some(c) = &m.source.cpu_usage
            && !nodes.contains(c.node.as_str())
        {
            e.add(
                format!("spec.metrics[{i}].source.cpuUsage.node"),
                format!(
                    "node {:?} is not in RobotStack {:?}",
                    c.node, stack.metadata.name
                ),
            );
        }
    }
    for (i, b) in p.spec.knobs.cpu.nodes.iter().enumerate() {
        if !nodes.contains(b.node.as_str()) {
            e.add(
                format!("spec.knobs.cpu.nodes[{i}].node"),
                format!(
                    "node {:?} is not in RobotStack {:?}",
                    b.node, stack.metadata.name
                ),
            );
        }
    }
    if let (Some(max), Some(cpus)) = (p.spec.knobs.cpu.max, stack.spec.robot.cpus)
        && max > cpus
    {
        e.add(
            "spec.knobs.cpu.max",
            format!("{max} CPUs is more than the robot's {cpus}"),
        );
    }
    e.0
}

fn join<'a>(it: impl Iterator<Item = &'a str>) -> String {
    it.collect::<Vec<_>>().join(", ")
}

fn check_header(e: &mut Errors, api_version: &str, meta: &ObjectMeta) {
    if api_version != API_VERSION {
        e.add(
            "apiVersion",
            format!("{api_version:?} is not served; use {API_VERSION:?}"),
        );
    }
    e.check("metadata.name", check_object_name(&meta.name));
    if let Some(ns) = &meta.namespace {
        e.check("metadata.namespace", check_dns_label(ns));
    }
    for (k, v) in &meta.labels {
        e.check(
            crate::yaml::join_key("metadata.labels", k),
            check_label(k, v),
        );
    }
}

fn robot_stack(e: &mut Errors, s: &RobotStack) {
    let spec = &s.spec;
    if let Some(cpus) = spec.robot.cpus {
        e.positive("spec.robot.cpus", cpus);
    }
    for (k, v) in &spec.robot.labels {
        e.check(
            crate::yaml::join_key("spec.robot.labels", k),
            check_label(k, v),
        );
    }
    if spec.apps.is_empty() {
        e.add("spec.apps", "a stack needs at least one app");
    }
    let mut app_names = BTreeMap::new();
    let mut node_names: BTreeMap<&str, String> = BTreeMap::new();
    for (i, app) in spec.apps.iter().enumerate() {
        let ap = format!("spec.apps[{i}]");
        e.check(format!("{ap}.name"), check_dns_label(&app.name));
        if let Some(first) = app_names.insert(app.name.as_str(), i) {
            e.add(
                format!("{ap}.name"),
                format!(
                    "duplicate app name {:?} (also spec.apps[{first}])",
                    app.name
                ),
            );
        }
        if app.nodes.is_empty() {
            e.add(format!("{ap}.nodes"), "an app needs at least one node");
        }
        for (j, node) in app.nodes.iter().enumerate() {
            let np = format!("{ap}.nodes[{j}]");
            e.check(format!("{np}.name"), check_ros_name(&node.name));
            if let Some(first) = node_names.insert(node.name.as_str(), np.clone()) {
                e.add(
                    format!("{np}.name"),
                    format!("duplicate node name {:?} (also {first})", node.name),
                );
            }
            match (&node.run, &node.match_) {
                (Some(_), Some(_)) => e.add(np.clone(), "set only one of run and match"),
                (None, None) => e.add(np.clone(), "set one of run (start it) or match (adopt it)"),
                _ => {}
            }
            if let Some(run) = &node.run {
                if run.command.trim().is_empty() {
                    e.add(format!("{np}.run.command"), "must not be empty");
                }
                for k in run.env.keys() {
                    e.check(
                        crate::yaml::join_key(&format!("{np}.run.env"), k),
                        check_env_name(k),
                    );
                }
                if let Some(wd) = &run.working_dir
                    && !wd.starts_with('/')
                {
                    e.add(format!("{np}.run.workingDir"), "must be an absolute path");
                }
            }
            if let Some(m) = &node.match_ {
                let mp = format!("{np}.match");
                let set = [
                    m.ros_node.is_some(),
                    m.process_name.is_some(),
                    m.cmdline.is_some(),
                ]
                .iter()
                .filter(|b| **b)
                .count();
                if set != 1 {
                    e.add(
                        mp.clone(),
                        "set exactly one of rosNode, processName, cmdline",
                    );
                }
                if let Some(r) = &m.ros_node {
                    e.check(format!("{mp}.rosNode"), check_ros_name(r));
                }
                if let Some(p) = &m.process_name
                    && (p.is_empty() || p.len() > 15 || p.contains('/'))
                {
                    e.add(
                        format!("{mp}.processName"),
                        format!("{p:?} is not a process name (1-15 characters, no '/')"),
                    );
                }
                if let Some(c) = &m.cmdline
                    && let Err(err) = regex::Regex::new(c)
                {
                    e.add(
                        format!("{mp}.cmdline"),
                        format!(
                            "not a valid regular expression: {}",
                            first_line(&err.to_string())
                        ),
                    );
                }
            }
        }
    }
    app_inputs(e, spec, &node_names);
}

/// `apps[].inputs`: only non-core apps claim inputs, of a declared node of
/// another app, on an absolute topic.
fn app_inputs(
    e: &mut Errors,
    spec: &crate::robot_stack::RobotStackSpec,
    node_names: &BTreeMap<&str, String>,
) {
    for (i, app) in spec.apps.iter().enumerate() {
        for (j, input) in app.inputs.iter().enumerate() {
            let ip = format!("spec.apps[{i}].inputs[{j}]");
            if app.core {
                e.add(
                    ip.clone(),
                    "only a non-core app claims inputs (a core app's inputs are never throttled)",
                );
            }
            e.check(format!("{ip}.topic"), check_ros_name(&input.topic));
            match node_names.get(input.node.as_str()) {
                None => e.add(
                    format!("{ip}.node"),
                    format!("{:?} is not a node of this stack", input.node),
                ),
                Some(_) if app.nodes.iter().any(|n| n.name == input.node) => e.add(
                    format!("{ip}.node"),
                    format!(
                        "{:?} is this app's own node: its inputs are this app's already",
                        input.node
                    ),
                ),
                Some(_) => {}
            }
        }
    }
}

fn first_line(s: &str) -> String {
    s.lines().last().unwrap_or(s).trim().to_string()
}

fn performance_spec(e: &mut Errors, p: &PerformanceSpec) {
    let spec = &p.spec;
    e.check(
        "spec.stackRef.name",
        check_object_name(&spec.stack_ref.name),
    );
    if spec.metrics.is_empty() {
        e.add("spec.metrics", "a spec needs at least one metric");
    }
    let mut names = BTreeMap::new();
    for (i, m) in spec.metrics.iter().enumerate() {
        let mp = format!("spec.metrics[{i}]");
        e.check(format!("{mp}.name"), check_dns_label(&m.name));
        if let Some(first) = names.insert(m.name.as_str(), i) {
            e.add(
                format!("{mp}.name"),
                format!(
                    "duplicate metric name {:?} (also spec.metrics[{first}])",
                    m.name
                ),
            );
        }
        e.check(format!("{mp}.app"), check_dns_label(&m.app));
        match (&m.source.topic_rate, &m.source.cpu_usage) {
            (Some(t), None) => {
                e.check(
                    format!("{mp}.source.topicRate.topic"),
                    check_ros_name(&t.topic),
                );
                if let Some(s) = &t.subscriber {
                    e.check(
                        format!("{mp}.source.topicRate.subscriber"),
                        check_ros_name(s),
                    );
                }
            }
            (None, Some(c)) => e.check(
                format!("{mp}.source.cpuUsage.node"),
                check_ros_name(&c.node),
            ),
            _ => e.add(
                format!("{mp}.source"),
                "set exactly one of topicRate, cpuUsage",
            ),
        }
        match (m.target.at_least, m.target.at_most) {
            (Some(v), None) => e.positive(format!("{mp}.target.atLeast"), v),
            (None, Some(v)) => e.positive(format!("{mp}.target.atMost"), v),
            _ => e.add(format!("{mp}.target"), "set exactly one of atLeast, atMost"),
        }
        e.positive(format!("{mp}.windowSeconds"), m.window_seconds);
        e.positive(format!("{mp}.weight"), m.weight);
    }
    let cpu = &spec.knobs.cpu;
    e.positive("spec.knobs.cpu.min", cpu.min);
    if let Some(max) = cpu.max {
        e.positive("spec.knobs.cpu.max", max);
        if cpu.min > max {
            e.add(
                "spec.knobs.cpu",
                format!("min {} is greater than max {max}", cpu.min),
            );
        }
    }
    if !(1_000..=1_000_000).contains(&cpu.period_micros) {
        e.add(
            "spec.knobs.cpu.periodMicros",
            format!(
                "{} is outside 1000..=1000000 microseconds",
                cpu.period_micros
            ),
        );
    }
    // The kernel refuses a CFS quota under 1000 µs (v1 cfs_quota_us and v2 cpu.max).
    let quota_floor = |e: &mut Errors, path: String, min: f64| {
        let quota = min * cpu.period_micros as f64;
        if min > 0.0 && quota < 1000.0 - 1e-6 {
            e.add(
                path,
                format!(
                    "{min} CPU × periodMicros {} is a {quota:.0} µs quota, below the kernel's 1000 µs minimum; raise it to at least {} or lengthen the period",
                    cpu.period_micros,
                    1000.0 / cpu.period_micros as f64
                ),
            );
        }
    };
    quota_floor(e, "spec.knobs.cpu.min".into(), cpu.min);
    let mut seen = BTreeMap::new();
    for (i, b) in cpu.nodes.iter().enumerate() {
        if let Some(min) = b.min {
            quota_floor(e, format!("spec.knobs.cpu.nodes[{i}].min"), min);
        }
        let bp = format!("spec.knobs.cpu.nodes[{i}]");
        e.check(format!("{bp}.node"), check_ros_name(&b.node));
        if let Some(first) = seen.insert(b.node.as_str(), i) {
            e.add(
                format!("{bp}.node"),
                format!(
                    "node {:?} is listed twice (also spec.knobs.cpu.nodes[{first}])",
                    b.node
                ),
            );
        }
        for (field, v) in [("min", b.min), ("max", b.max)] {
            if let Some(v) = v {
                e.positive(format!("{bp}.{field}"), v);
            }
        }
        let (lo, hi) = (b.min.unwrap_or(cpu.min), b.max.or(cpu.max));
        if let Some(hi) = hi
            && lo > hi
        {
            e.add(bp, format!("min {lo} is greater than max {hi}"));
        }
    }
    let a = &spec.knobs.adaptors;
    e.positive("spec.knobs.adaptors.minTopicRateHz", a.min_topic_rate_hz);
    e.positive("spec.knobs.adaptors.minRateHz", a.min_rate_hz);
    for (list, sel) in [("include", &a.include), ("exclude", &a.exclude)] {
        edge_selectors(e, &format!("spec.knobs.adaptors.{list}"), sel);
    }
    let t = &spec.tuning;
    e.positive("spec.tuning.trialSeconds", t.trial_seconds);
    if !(t.settle_seconds.is_finite() && t.settle_seconds >= 0.0) {
        e.add("spec.tuning.settleSeconds", "must be zero or more");
    }
    if !(t.startup_timeout_seconds.is_finite() && t.startup_timeout_seconds >= 0.0) {
        e.add("spec.tuning.startupTimeoutSeconds", "must be zero or more");
    }
    if !(1..=1000).contains(&t.max_trials) {
        e.add(
            "spec.tuning.maxTrials",
            format!("{} is outside 1..=1000", t.max_trials),
        );
    }
    if let Some(f) = t.safety_floor
        && !(f > 0.0 && f <= 1.0)
    {
        e.add("spec.tuning.safetyFloor", format!("{f} is outside (0, 1]"));
    }
    if !(t.record_seconds.is_finite() && t.record_seconds >= 1.0) {
        e.add("spec.tuning.recordSeconds", "must be 1 or more");
    }
    e.positive(
        "spec.monitoring.graphIntervalSeconds",
        spec.monitoring.graph_interval_seconds,
    );
    e.positive(
        "spec.monitoring.violationWindowSeconds",
        spec.monitoring.violation_window_seconds,
    );
}

fn edge_selectors(e: &mut Errors, path: &str, sel: &[EdgeSelector]) {
    for (i, s) in sel.iter().enumerate() {
        e.check(format!("{path}[{i}].topic"), check_ros_name(&s.topic));
        if let Some(sub) = &s.subscriber {
            e.check(format!("{path}[{i}].subscriber"), check_ros_name(sub));
        }
    }
}

fn config_profile(e: &mut Errors, c: &ConfigProfile) {
    let spec = &c.spec;
    let ctx = &spec.context;
    if ctx.robot_model.is_empty() {
        e.add(
            "spec.context.robotModel",
            "must name the robot model the config is for",
        );
    }
    for (i, a) in ctx.apps.iter().enumerate() {
        e.check(format!("spec.context.apps[{i}]"), check_dns_label(a));
    }
    for (i, n) in ctx.nodes.iter().enumerate() {
        e.check(format!("spec.context.nodes[{i}]"), check_ros_name(n));
    }
    for (k, v) in &ctx.labels {
        e.check(
            crate::yaml::join_key("spec.context.labels", k),
            check_label(k, v),
        );
    }
    e.check("spec.specName", check_object_name(&spec.spec_name));
    resource_config(e, "spec.config", &spec.config);
    for (i, t) in spec.trials.iter().enumerate() {
        resource_config(e, &format!("spec.trials[{i}].config"), &t.config);
        for (k, v) in &t.values {
            if !v.is_finite() {
                e.add(
                    crate::yaml::join_key(&format!("spec.trials[{i}].values"), k),
                    format!("must be a finite number, got {v}"),
                );
            }
        }
    }
    if let Some(s) = spec.satisfaction
        && !(0.0..=1.0).contains(&s)
    {
        e.add("spec.satisfaction", format!("{s} is outside 0..=1"));
    }
}

fn resource_config(e: &mut Errors, path: &str, c: &ResourceConfig) {
    for (node, v) in &c.cpu {
        let p = crate::yaml::join_key(&format!("{path}.cpu"), node);
        e.check(p.clone(), check_ros_name(node));
        e.positive(p, *v);
    }
    for (node, w) in &c.cpu_weight {
        let p = crate::yaml::join_key(&format!("{path}.cpuWeight"), node);
        e.check(p.clone(), check_ros_name(node));
        if !(1..=10_000).contains(w) {
            e.add(p, format!("{w} is outside 1..=10000"));
        }
    }
    for (i, a) in c.adaptors.iter().enumerate() {
        let ap = format!("{path}.adaptors[{i}]");
        e.check(format!("{ap}.topic"), check_ros_name(&a.topic));
        e.check(format!("{ap}.subscriber"), check_ros_name(&a.subscriber));
        e.positive(format!("{ap}.rateHz"), a.rate_hz);
    }
}
