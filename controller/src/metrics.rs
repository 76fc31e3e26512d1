//! The control plane's Prometheus metrics, on a registry of its own.

use prometheus::{Encoder, GaugeVec, IntCounterVec, IntGaugeVec, Opts, Registry, TextEncoder};

/// Another component's metrics in text format (the embedded node agent's),
/// appended to the control plane's `/metrics`.
pub type MetricsSource = Box<dyn Fn() -> String + Send + Sync>;

#[derive(Debug)]
pub struct Metrics {
    pub registry: Registry,
    pub api_requests: IntCounterVec,
    pub reconciles: IntCounterVec,
    pub objects: IntGaugeVec,
    pub tuning: TuningMetrics,
    sources: Sources,
}

#[derive(Default)]
struct Sources(std::sync::Mutex<Vec<MetricsSource>>);

impl std::fmt::Debug for Sources {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Sources")
    }
}

/// Metrics of the tuning loop, labelled by namespace and spec.
#[derive(Debug, Clone)]
pub struct TuningMetrics {
    /// 1 for the run's current phase, 0 for the others (of `configbot_tuning::machine::PHASES`).
    pub phase: IntGaugeVec,
    /// Trials measured in the current run.
    pub trials: IntGaugeVec,
    /// Constraint satisfaction (steady state while monitoring), 0..1.
    pub satisfaction: GaugeVec,
    /// Last measured value of each metric, and its target.
    pub metric_value: GaugeVec,
    pub metric_target: GaugeVec,
    pub library_hits: IntCounterVec,
    /// Relearning / re-check triggers by cause.
    pub triggers: IntCounterVec,
    /// Remediations and their undos.
    pub remediations: IntCounterVec,
}

fn gauge(name: &str, help: &str, labels: &[&str]) -> GaugeVec {
    GaugeVec::new(Opts::new(name, help), labels)
        .unwrap_or_else(|_| unreachable!("static metric definition"))
}

fn igauge(name: &str, help: &str, labels: &[&str]) -> IntGaugeVec {
    IntGaugeVec::new(Opts::new(name, help), labels)
        .unwrap_or_else(|_| unreachable!("static metric definition"))
}

fn counter(name: &str, help: &str, labels: &[&str]) -> IntCounterVec {
    IntCounterVec::new(Opts::new(name, help), labels)
        .unwrap_or_else(|_| unreachable!("static metric definition"))
}

impl TuningMetrics {
    fn new(registry: &Registry) -> TuningMetrics {
        let spec = &["namespace", "spec"];
        let m = TuningMetrics {
            phase: igauge(
                "configbot_tuning_phase",
                "1 for the current phase of a spec's tuning run",
                &["namespace", "spec", "phase"],
            ),
            trials: igauge(
                "configbot_tuning_trials",
                "Trials measured in the current run",
                spec,
            ),
            satisfaction: gauge(
                "configbot_tuning_satisfaction",
                "Share of 1 s windows in which every core constraint held",
                spec,
            ),
            metric_value: gauge(
                "configbot_tuning_metric_value",
                "Last measured value of a spec metric",
                &["namespace", "spec", "metric"],
            ),
            metric_target: gauge(
                "configbot_tuning_metric_target",
                "Target of a spec metric",
                &["namespace", "spec", "metric"],
            ),
            library_hits: counter(
                "configbot_tuning_library_hits_total",
                "Familiar contexts re-applied from the config library",
                spec,
            ),
            triggers: counter(
                "configbot_tuning_triggers_total",
                "Relearning and context re-check triggers by cause",
                &["namespace", "spec", "cause"],
            ),
            remediations: counter(
                "configbot_tuning_remediations_total",
                "Remediations (stop non-core apps) and their undos",
                &["namespace", "spec", "action"],
            ),
        };
        for c in [
            Box::new(m.phase.clone()) as Box<dyn prometheus::core::Collector>,
            Box::new(m.trials.clone()),
            Box::new(m.satisfaction.clone()),
            Box::new(m.metric_value.clone()),
            Box::new(m.metric_target.clone()),
            Box::new(m.library_hits.clone()),
            Box::new(m.triggers.clone()),
            Box::new(m.remediations.clone()),
        ] {
            let _ = registry.register(c);
        }
        m
    }
}

impl Metrics {
    pub fn new() -> Metrics {
        let registry = Registry::new();
        let api_requests = IntCounterVec::new(
            Opts::new(
                "configbot_api_requests_total",
                "API requests by verb and status code",
            ),
            &["verb", "code"],
        )
        .unwrap_or_else(|_| unreachable!("static metric definition"));
        let reconciles = IntCounterVec::new(
            Opts::new(
                "configbot_reconciles_total",
                "Reconciles by kind and result",
            ),
            &["kind", "result"],
        )
        .unwrap_or_else(|_| unreachable!("static metric definition"));
        let objects = IntGaugeVec::new(
            Opts::new("configbot_objects", "Objects by kind and phase"),
            &["kind", "phase"],
        )
        .unwrap_or_else(|_| unreachable!("static metric definition"));
        for c in [
            Box::new(api_requests.clone()) as Box<dyn prometheus::core::Collector>,
            Box::new(reconciles.clone()),
            Box::new(objects.clone()),
        ] {
            let _ = registry.register(c);
        }
        let tuning = TuningMetrics::new(&registry);
        Metrics {
            tuning,
            registry,
            api_requests,
            reconciles,
            objects,
            sources: Sources::default(),
        }
    }

    /// Text exposition format.
    pub fn render(&self) -> String {
        let mut buf = Vec::new();
        let _ = TextEncoder::new().encode(&self.registry.gather(), &mut buf);
        let mut text = String::from_utf8(buf).unwrap_or_default();
        let sources = self.sources.0.lock().unwrap_or_else(|e| e.into_inner());
        for source in sources.iter() {
            text.push_str(&source());
        }
        text
    }

    /// Appends `source`'s text to every rendering (metric names must not clash).
    pub fn add_source(&self, source: MetricsSource) {
        self.sources
            .0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(source);
    }
}

impl Default for Metrics {
    fn default() -> Self {
        Metrics::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sources_are_appended_to_the_exposition() {
        let m = Metrics::new();
        m.objects
            .with_label_values(&["RobotStack", "Accepted"])
            .set(1);
        m.add_source(Box::new(|| "configbot_agent_up 1\n".to_owned()));
        let text = m.render();
        assert!(text.contains("configbot_objects{kind=\"RobotStack\",phase=\"Accepted\"} 1"));
        assert!(text.ends_with("configbot_agent_up 1\n"));
    }
}
