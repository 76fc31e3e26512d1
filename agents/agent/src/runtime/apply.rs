//! `apply`: a [`ResourceConfig`] becomes one atomic CPU config for every node
//! of the stack (listed nodes limited or weighted, the rest unlimited at the
//! default weight) and per-edge
//! adaptor rates (listed edges limited, edges limited before and not listed
//! back to pass-through). The plan is pure ([`plan`]); the order of the IO is
//! validate everything → CPU limits atomically → adaptor rates.

use std::collections::{BTreeMap, BTreeSet};

use configbot_api::graph::{AdaptorSetting, EdgeId};
use configbot_cgroups::{CpuLimit, CpuWeight, DEFAULT_PERIOD_US, NodeName};
use configbot_manifests::ResourceConfig;

use super::NodeRuntime;
use crate::agent::ConfigUpdate;
use crate::error::{Error, Result};

/// What `apply` writes.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// A limit for every stack node (unlisted = unlimited), validated.
    pub update: ConfigUpdate,
    /// Rate per edge to set.
    pub rates: BTreeMap<EdgeId, f64>,
}

/// Checks `cfg` against the stack's nodes and builds the plan. Errors name
/// the node or edge. Pure.
pub fn plan(stack_nodes: &BTreeSet<NodeName>, cfg: &ResourceConfig) -> Result<Plan> {
    let period_us = cfg.cpu_period_micros.unwrap_or(DEFAULT_PERIOD_US);
    let mut limits: BTreeMap<NodeName, CpuLimit> = stack_nodes
        .iter()
        .map(|n| {
            (
                n.clone(),
                CpuLimit {
                    period_us,
                    ..CpuLimit::UNLIMITED
                },
            )
        })
        .collect();
    for (name, cpus) in &cfg.cpu {
        let n = NodeName::new(name)?;
        let Some(l) = limits.get_mut(&n) else {
            return Err(Error::UnknownNode(name.clone()));
        };
        l.cpus = Some(*cpus);
    }
    for (name, weight) in &cfg.cpu_weight {
        let n = NodeName::new(name)?;
        let Some(l) = limits.get_mut(&n) else {
            return Err(Error::UnknownNode(name.clone()));
        };
        l.weight = CpuWeight::named(*weight, name)?;
    }
    for (n, l) in &limits {
        l.to_cpu_max(n.as_str())?;
    }
    let mut rates = BTreeMap::new();
    for a in &cfg.adaptors {
        let edge = EdgeId {
            topic: a.topic.clone(),
            subscriber: a.subscriber.clone(),
        };
        if !(a.rate_hz.is_finite() && a.rate_hz > 0.0) {
            return Err(Error::InvalidConfig(format!(
                "adaptor rate {} Hz on edge {} -> {} must be finite and > 0",
                a.rate_hz, a.topic, a.subscriber
            )));
        }
        if rates.insert(edge, a.rate_hz).is_some() {
            return Err(Error::InvalidConfig(format!(
                "edge {} -> {} is listed twice",
                a.topic, a.subscriber
            )));
        }
    }
    Ok(Plan {
        update: ConfigUpdate {
            limits,
            adaptor_rates: cfg.adaptors.clone(),
        },
        rates,
    })
}

impl NodeRuntime {
    /// Applies a config: CPU limits of all nodes atomically (rolled back as a
    /// whole if one write fails), then adaptor rates per edge. Nodes and
    /// edges not listed are unlimited (edges keep a pass-through adaptor).
    pub(super) async fn apply_config(&self, cfg: &ResourceConfig) -> Result<()> {
        let _serial = self.inner.ops.lock().await;
        let stack_nodes = crate::state::stack_nodes(&self.agent().stack());
        let plan = plan(&stack_nodes, cfg)?;
        let dp = self.data_plane();
        if dp.is_none()
            && let Some(e) = plan.rates.keys().next()
        {
            return Err(Error::NoDataPlane {
                what: format!("adaptor on edge {} -> {}", e.topic, e.subscriber),
            });
        }
        let agent = self.agent().clone();
        let update = plan.update;
        // Cgroup writes are blocking file IO.
        tokio::task::spawn_blocking(move || agent.put_config(update))
            .await
            .map_err(|e| Error::InvalidConfig(format!("config task failed: {e}")))??;
        let Some(dp) = dp else {
            return Ok(());
        };
        let set = |edge: &EdgeId, rate_hz: Option<f64>| {
            dp.set_adaptor(edge, AdaptorSetting { rate_hz })
                .map_err(|source| Error::Adaptor {
                    topic: edge.topic.clone(),
                    subscriber: edge.subscriber.clone(),
                    source,
                })
        };
        for (edge, rate) in &plan.rates {
            set(edge, Some(*rate))?;
        }
        for (edge, s) in dp.adaptors() {
            if s.rate_hz.is_some() && !plan.rates.contains_key(&edge) {
                set(&edge, None)?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use configbot_manifests::AdaptorRate;

    use super::*;

    fn nodes(n: &[&str]) -> BTreeSet<NodeName> {
        n.iter().map(|s| NodeName::new(s).unwrap()).collect()
    }

    #[test]
    fn unlisted_nodes_are_unlimited_and_period_applies_to_all() {
        let cfg = ResourceConfig {
            cpu: BTreeMap::from([("/a".to_string(), 0.3)]),
            cpu_weight: BTreeMap::from([("/b".to_string(), 10_000)]),
            cpu_period_micros: Some(20_000),
            adaptors: vec![AdaptorRate {
                topic: "/t".into(),
                subscriber: "/b".into(),
                rate_hz: 10.0,
            }],
        };
        let p = plan(&nodes(&["/a", "/b"]), &cfg).unwrap();
        let a = &p.update.limits[&NodeName::new("/a").unwrap()];
        let b = &p.update.limits[&NodeName::new("/b").unwrap()];
        assert_eq!(
            (a.cpus, a.period_us, a.weight),
            (Some(0.3), 20_000, CpuWeight::DEFAULT)
        );
        assert_eq!(
            (b.cpus, b.period_us, b.weight),
            (None, 20_000, CpuWeight::MAX)
        );
        assert_eq!(p.rates.len(), 1);
    }

    #[test]
    fn errors_name_the_node_or_edge() {
        let mut cfg = ResourceConfig::default();
        cfg.cpu.insert("/zz".into(), 0.5);
        let e = plan(&nodes(&["/a"]), &cfg).unwrap_err().to_string();
        assert!(e.contains("/zz"), "{e}");
        cfg.cpu = BTreeMap::from([("/a".to_string(), -1.0)]);
        let e = plan(&nodes(&["/a"]), &cfg).unwrap_err().to_string();
        assert!(e.contains("/a"), "{e}");
        cfg.cpu.clear();
        cfg.cpu_weight = BTreeMap::from([("/a".to_string(), 0)]);
        let e = plan(&nodes(&["/a"]), &cfg).unwrap_err().to_string();
        assert!(e.contains("/a") && e.contains("weight 0"), "{e}");
        cfg.cpu_weight = BTreeMap::from([("/zz".to_string(), 200)]);
        let e = plan(&nodes(&["/a"]), &cfg).unwrap_err().to_string();
        assert!(e.contains("/zz"), "{e}");
        cfg.cpu_weight.clear();
        cfg.adaptors.push(AdaptorRate {
            topic: "/img".into(),
            subscriber: "/det".into(),
            rate_hz: f64::NAN,
        });
        let e = plan(&nodes(&["/a"]), &cfg).unwrap_err().to_string();
        assert!(e.contains("/img -> /det"), "{e}");
    }
}
