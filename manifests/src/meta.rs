//! Kubernetes-shaped object metadata and conditions shared by every ConfigBot kind.

use std::collections::BTreeMap;

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::vocab::Reason;

/// The API group of every ConfigBot kind.
pub const GROUP: &str = "configbot.dev";
/// The API version served and accepted.
pub const VERSION: &str = "v1alpha1";
/// `apiVersion` as written in manifests.
pub const API_VERSION: &str = "configbot.dev/v1alpha1";
/// Namespace used when a manifest names none.
pub const DEFAULT_NAMESPACE: &str = "default";

/// Standard object metadata. Server-owned fields (`uid`, `generation`,
/// `resourceVersion`, `creationTimestamp`, `managedFields`) are ignored on
/// input and filled in by the control plane.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct ObjectMeta {
    /// Object name: lowercase letters, digits, '-' and '.', at most 253 characters.
    #[serde(default)]
    pub name: String,
    /// Namespace; `default` when omitted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub namespace: Option<String>,
    /// Labels used by selectors (`-l robot=spot`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub labels: BTreeMap<String, String>,
    /// Free-form annotations (e.g. `configbot.dev/tuning: paused`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub annotations: BTreeMap<String, String>,
    /// Unique id assigned by the control plane at creation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uid: Option<String>,
    /// Bumped by the control plane on every spec change (never on status).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub generation: Option<i64>,
    /// Opaque version for optimistic concurrency; a stale one gets 409 Conflict.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resource_version: Option<String>,
    /// RFC 3339 creation time.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub creation_timestamp: Option<String>,
    /// Set while a delete is in progress (accepted for Kubernetes compatibility).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deletion_timestamp: Option<String>,
    /// Which field manager set which fields (server-side apply); kept by the
    /// control plane, ignored on input.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub managed_fields: Vec<ManagedFieldsEntry>,
}

/// One manager's fields, as Kubernetes records them.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct ManagedFieldsEntry {
    /// The field manager (`kubectl`, `kubectl-client-side-apply`, `configbot`, ...).
    pub manager: String,
    /// `Apply` (server-side apply) or `Update` (any other write).
    pub operation: String,
    pub api_version: String,
    /// When this manager's fields last changed (RFC 3339).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time: Option<String>,
    /// Always `FieldsV1`.
    pub fields_type: String,
    /// The fields as a `FieldsV1` tree (`{"f:spec": {"f:robot": {"f:model": {}}}}`).
    #[serde(rename = "fieldsV1")]
    pub fields_v1: serde_json::Value,
}

impl ObjectMeta {
    /// The namespace, defaulted.
    pub fn namespace(&self) -> &str {
        self.namespace.as_deref().unwrap_or(DEFAULT_NAMESPACE)
    }
}

/// `True`, `False` or `Unknown`, as in Kubernetes conditions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
pub enum ConditionStatus {
    True,
    False,
    Unknown,
}

/// One observation about an object, Kubernetes style.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "camelCase", deny_unknown_fields)]
pub struct Condition {
    /// Condition type, e.g. `Accepted`, `Ready`, `StackResolved`.
    #[serde(rename = "type")]
    pub type_: String,
    pub status: ConditionStatus,
    /// CamelCase machine-readable reason.
    pub reason: Reason,
    /// Human-readable detail.
    #[serde(default)]
    pub message: String,
    /// RFC 3339 time of the last status change.
    #[serde(default)]
    pub last_transition_time: String,
    /// The generation this condition was computed for.
    #[serde(default)]
    pub observed_generation: i64,
}

/// Condition types written by the control plane.
pub mod condition_types {
    /// The spec passed validation and is being acted on.
    pub const ACCEPTED: &str = "Accepted";
    /// The object's goal is met.
    pub const READY: &str = "Ready";
    /// A PerformanceSpec's `stackRef` names an existing RobotStack.
    pub const STACK_RESOLVED: &str = "StackResolved";
}

/// Replace or insert `new` by type; keep the old transition time when the status
/// did not change. Returns true when anything changed.
pub fn set_condition(conditions: &mut Vec<Condition>, new: Condition) -> bool {
    match conditions.iter_mut().find(|c| c.type_ == new.type_) {
        Some(old) => {
            let same = old.status == new.status
                && old.reason == new.reason
                && old.message == new.message
                && old.observed_generation == new.observed_generation;
            if same {
                return false;
            }
            let keep_time = old.status == new.status;
            let time = if keep_time {
                old.last_transition_time.clone()
            } else {
                new.last_transition_time.clone()
            };
            *old = Condition {
                last_transition_time: time,
                ..new
            };
            true
        }
        None => {
            conditions.push(new);
            true
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cond(status: ConditionStatus, reason: Reason, time: &str) -> Condition {
        Condition {
            type_: "Ready".into(),
            status,
            reason,
            message: String::new(),
            last_transition_time: time.into(),
            observed_generation: 1,
        }
    }

    #[test]
    fn set_condition_keeps_transition_time_when_status_unchanged() {
        let mut cs = vec![cond(ConditionStatus::False, Reason::Tuning, "t1")];
        assert!(set_condition(
            &mut cs,
            cond(ConditionStatus::False, Reason::Satisfied, "t2")
        ));
        assert_eq!(cs[0].last_transition_time, "t1");
        assert_eq!(cs[0].reason, Reason::Satisfied);
        assert!(set_condition(
            &mut cs,
            cond(ConditionStatus::True, Reason::Satisfied, "t3")
        ));
        assert_eq!(cs[0].last_transition_time, "t3");
        assert!(!set_condition(
            &mut cs,
            cond(ConditionStatus::True, Reason::Satisfied, "t4")
        ));
        assert_eq!(cs.len(), 1);
    }
}
