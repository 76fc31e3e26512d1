//! Atomic application of a whole CPU configuration (each node's quota, period
//! and weight): validate all, write all, read back all; on any failure
//! restore what was there before.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::backend::CgroupBackend;
use crate::error::{Error, Result};
use crate::limit::{CpuLimit, CpuMax, CpuWeight};
use crate::name::NodeName;

/// CPU limits for a set of nodes; nodes not listed are left as they are.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CgroupConfig {
    pub limits: BTreeMap<NodeName, CpuLimit>,
}

/// What [`apply`] did to one node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AppliedNode<'a> {
    pub node: &'a NodeName,
    pub previous: CpuMax,
    pub applied: CpuMax,
    pub previous_weight: CpuWeight,
    pub weight: CpuWeight,
}

/// Applies `config` to `backend` all-or-nothing.
///
/// Validation covers every limit before anything is written; missing node
/// cgroups are created (an empty cgroup without a limit changes nothing).
/// A failed write or a read-back mismatch rolls every touched node back to
/// its previous quota/period and weight (including the failing one, whose v1
/// write may be half done) and returns [`Error::Apply`] naming the node, with the
/// underlying error naming the file and value.
pub fn apply<'a>(
    backend: &dyn CgroupBackend,
    config: &'a CgroupConfig,
) -> Result<Vec<AppliedNode<'a>>> {
    let mut plan = Vec::with_capacity(config.limits.len());
    for (node, limit) in &config.limits {
        plan.push((node, limit.to_cpu_max(node.as_str())?, limit.weight));
    }
    let mut applied = Vec::with_capacity(plan.len());
    for (node, max, weight) in plan {
        if !backend.exists(node) {
            backend.create(node)?;
        }
        applied.push(AppliedNode {
            node,
            previous: backend.cpu_max(node)?,
            applied: max,
            previous_weight: backend.weight(node)?,
            weight,
        });
    }
    for (i, a) in applied.iter().enumerate() {
        let written = backend
            .set_cpu_max(a.node, a.applied)
            .and_then(|()| backend.set_weight(a.node, a.weight));
        if let Err(e) = written {
            return Err(roll_back(backend, &applied[..=i], a.node, e));
        }
    }
    for a in &applied {
        let got = match backend
            .cpu_max(a.node)
            .and_then(|m| Ok((m, backend.weight(a.node)?)))
        {
            Ok(got) => got,
            Err(e) => return Err(roll_back(backend, &applied, a.node, e)),
        };
        if got != (a.applied, a.weight) {
            let e = Error::ReadBack {
                path: backend.node_path(a.node),
                wanted: format!("{} weight {}", a.applied.to_v2(), a.weight.v2()),
                got: format!("{} weight {}", got.0.to_v2(), got.1.v2()),
            };
            return Err(roll_back(backend, &applied, a.node, e));
        }
    }
    Ok(applied)
}

fn roll_back(
    backend: &dyn CgroupBackend,
    touched: &[AppliedNode<'_>],
    failed: &NodeName,
    cause: Error,
) -> Error {
    let mut failures = 0;
    for a in touched.iter().rev() {
        let restored = backend
            .set_cpu_max(a.node, a.previous)
            .and_then(|()| backend.set_weight(a.node, a.previous_weight));
        if restored.is_err() {
            failures += 1;
        }
    }
    Error::Apply {
        node: failed.to_string(),
        rolled_back: touched.len(),
        rollback_failures: failures,
        source: Box::new(cause),
    }
}
