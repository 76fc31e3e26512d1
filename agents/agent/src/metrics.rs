//! Prometheus metrics of the agent, registered in its own [`Registry`].

use prometheus::{GaugeVec, IntCounterVec, IntGaugeVec, Opts, Registry, TextEncoder};

/// All agent metrics. Label values are node names, app names or fixed strings.
#[derive(Debug, Clone)]
pub struct Metrics {
    pub registry: Registry,
    pub usage: GaugeVec,
    pub limit: GaugeVec,
    pub weight: IntGaugeVec,
    pub throttled_periods: IntGaugeVec,
    pub throttled_seconds: GaugeVec,
    pub restarts: IntCounterVec,
    pub monitor_events: IntCounterVec,
    pub active_monitor: IntGaugeVec,
}

impl Metrics {
    /// Creates and registers every metric.
    pub fn new() -> prometheus::Result<Self> {
        let registry = Registry::new();
        let node = &["node"];
        let usage = GaugeVec::new(
            Opts::new(
                "configbot_agent_node_cpu_usage_cpus",
                "CPU used by the node's cgroup over the last sample interval, in CPUs",
            ),
            node,
        )?;
        let limit = GaugeVec::new(
            Opts::new(
                "configbot_agent_node_cpu_limit_cpus",
                "CPU limit of the node's cgroup in CPUs; -1 = unlimited",
            ),
            node,
        )?;
        let weight = IntGaugeVec::new(
            Opts::new(
                "configbot_agent_node_cpu_weight",
                "CPU weight of the node's cgroup against the stack's other nodes (cgroup v2 units; 100 = default)",
            ),
            node,
        )?;
        let throttled_periods = IntGaugeVec::new(
            Opts::new(
                "configbot_agent_node_throttled_periods",
                "Kernel counter: periods in which the node was throttled",
            ),
            node,
        )?;
        let throttled_seconds = GaugeVec::new(
            Opts::new(
                "configbot_agent_node_throttled_seconds",
                "Kernel counter: total time the node was throttled",
            ),
            node,
        )?;
        let restarts = IntCounterVec::new(
            Opts::new(
                "configbot_agent_node_restarts_total",
                "Restarts of the node's process by the agent",
            ),
            node,
        )?;
        let monitor_events = IntCounterVec::new(
            Opts::new(
                "configbot_agent_monitor_events_total",
                "Process events received from the process monitor",
            ),
            &["kind"],
        )?;
        let active_monitor = IntGaugeVec::new(
            Opts::new(
                "configbot_agent_active_monitor",
                "1 for the process monitor in use (ebpf, proc_connector, proc_scan)",
            ),
            &["monitor"],
        )?;
        registry.register(Box::new(usage.clone()))?;
        registry.register(Box::new(limit.clone()))?;
        registry.register(Box::new(weight.clone()))?;
        registry.register(Box::new(throttled_periods.clone()))?;
        registry.register(Box::new(throttled_seconds.clone()))?;
        registry.register(Box::new(restarts.clone()))?;
        registry.register(Box::new(monitor_events.clone()))?;
        registry.register(Box::new(active_monitor.clone()))?;
        Ok(Self {
            registry,
            usage,
            limit,
            weight,
            throttled_periods,
            throttled_seconds,
            restarts,
            monitor_events,
            active_monitor,
        })
    }

    /// Marks `name` as the active monitor and every other known one inactive.
    pub fn set_active_monitor(&self, name: &str) {
        for m in ["ebpf", "proc_connector", "proc_scan"] {
            self.active_monitor
                .with_label_values(&[m])
                .set(i64::from(m == name));
        }
        self.active_monitor.with_label_values(&[name]).set(1);
    }

    /// The text exposition format.
    pub fn render(&self) -> prometheus::Result<String> {
        TextEncoder::new().encode_to_string(&self.registry.gather())
    }
}
