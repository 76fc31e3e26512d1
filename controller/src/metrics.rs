//! The control plane's Prometheus metrics, on a registry of its own.

use prometheus::{Encoder, IntCounterVec, IntGaugeVec, Opts, Registry, TextEncoder};

#[derive(Debug)]
pub struct Metrics {
    pub registry: Registry,
    pub api_requests: IntCounterVec,
    pub reconciles: IntCounterVec,
    pub objects: IntGaugeVec,
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
        Metrics {
            registry,
            api_requests,
            reconciles,
            objects,
        }
    }

    /// Text exposition format.
    pub fn render(&self) -> String {
        let mut buf = Vec::new();
        let _ = TextEncoder::new().encode(&self.registry.gather(), &mut buf);
        String::from_utf8(buf).unwrap_or_default()
    }
}

impl Default for Metrics {
    fn default() -> Self {
        Metrics::new()
    }
}
