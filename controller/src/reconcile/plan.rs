//! Pure status planning: from an object (and what it references) to the status
//! it should have and the events to record. No IO; `None` means "status is
//! already right", so timestamps alone never cause a write.

use configbot_manifests::meta::{condition_types as ct, set_condition};
use configbot_manifests::{
    Condition, ConditionStatus, Manifest, PerformanceSpecStatus, RobotStackStatus,
};
use serde_json::Value;

/// An event to record about the reconciled object.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlannedEvent {
    pub type_: &'static str,
    pub reason: &'static str,
    pub message: String,
}

/// Condition reasons (constants, never ad-hoc strings).
pub mod reasons {
    pub const VALID: &str = "Valid";
    pub const INVALID: &str = "Invalid";
    pub const STACK_FOUND: &str = "StackFound";
    pub const STACK_NOT_FOUND: &str = "StackNotFound";
    pub const STACK_MISMATCH: &str = "StackMismatch";
    pub const NOT_MEASURED: &str = "NotMeasured";
}

fn cond(
    type_: &str,
    status: ConditionStatus,
    reason: &str,
    message: String,
    generation: i64,
    now: &str,
) -> Condition {
    Condition {
        type_: type_.into(),
        status,
        reason: reason.into(),
        message,
        last_transition_time: now.into(),
        observed_generation: generation,
    }
}

fn generation(obj: &Value) -> i64 {
    obj["metadata"]["generation"].as_i64().unwrap_or(0)
}

/// Status of a RobotStack.
pub fn robot_stack_status(obj: &Value, now: &str) -> (Option<Value>, Vec<PlannedEvent>) {
    let g = generation(obj);
    let old: RobotStackStatus = obj
        .get("status")
        .and_then(|s| serde_json::from_value(s.clone()).ok())
        .unwrap_or_default();
    let mut new = old.clone();
    new.observed_generation = g;
    let mut events = Vec::new();
    match configbot_manifests::decode_and_validate(obj) {
        Ok(Manifest::RobotStack(s)) => {
            new.apps = s.spec.apps.len() as u32;
            new.nodes = s.spec.nodes().count() as u32;
            if new.phase.is_empty() || new.phase == "Invalid" {
                new.phase = "Accepted".into();
            }
            let msg = format!("{} apps, {} nodes", new.apps, new.nodes);
            if set_condition(
                &mut new.conditions,
                cond(
                    ct::ACCEPTED,
                    ConditionStatus::True,
                    reasons::VALID,
                    msg.clone(),
                    g,
                    now,
                ),
            ) {
                events.push(PlannedEvent {
                    type_: "Normal",
                    reason: "Accepted",
                    message: msg,
                });
            }
        }
        Ok(_) => {}
        Err(errs) => {
            new.phase = "Invalid".into();
            let msg = errs
                .iter()
                .map(|e| format!("{}: {}", e.path, e.message))
                .collect::<Vec<_>>()
                .join("; ");
            set_condition(
                &mut new.conditions,
                cond(
                    ct::ACCEPTED,
                    ConditionStatus::False,
                    reasons::INVALID,
                    msg,
                    g,
                    now,
                ),
            );
        }
    }
    finish(&old, new, events)
}

/// Status of a PerformanceSpec, given the stack it names (if it exists).
pub fn performance_spec_status(
    obj: &Value,
    stack: Option<&Value>,
    now: &str,
) -> (Option<Value>, Vec<PlannedEvent>) {
    let g = generation(obj);
    let old: PerformanceSpecStatus = obj
        .get("status")
        .and_then(|s| serde_json::from_value(s.clone()).ok())
        .unwrap_or_default();
    let mut new = old.clone();
    new.observed_generation = g;
    let mut events = Vec::new();
    let spec = match configbot_manifests::decode_and_validate(obj) {
        Ok(Manifest::PerformanceSpec(p)) => p,
        Ok(_) => return (None, events),
        Err(errs) => {
            new.phase = "Invalid".into();
            let msg = errs
                .iter()
                .map(|e| format!("{}: {}", e.path, e.message))
                .collect::<Vec<_>>()
                .join("; ");
            set_condition(
                &mut new.conditions,
                cond(
                    ct::ACCEPTED,
                    ConditionStatus::False,
                    reasons::INVALID,
                    msg,
                    g,
                    now,
                ),
            );
            return finish(&old, new, events);
        }
    };
    let stack_name = &spec.spec.stack_ref.name;
    let stack = stack.and_then(|s| match configbot_manifests::decode(s) {
        Ok(Manifest::RobotStack(s)) => Some(s),
        _ => None,
    });
    match stack {
        None => {
            new.phase = "Pending".into();
            let msg = format!(
                "RobotStack {stack_name:?} does not exist in namespace {:?}; apply it and this spec proceeds",
                spec.metadata.namespace()
            );
            if set_condition(
                &mut new.conditions,
                cond(
                    ct::STACK_RESOLVED,
                    ConditionStatus::False,
                    reasons::STACK_NOT_FOUND,
                    msg.clone(),
                    g,
                    now,
                ),
            ) {
                events.push(PlannedEvent {
                    type_: "Warning",
                    reason: reasons::STACK_NOT_FOUND,
                    message: msg,
                });
            }
            set_condition(
                &mut new.conditions,
                cond(
                    ct::READY,
                    ConditionStatus::False,
                    reasons::STACK_NOT_FOUND,
                    "waiting for the stack".into(),
                    g,
                    now,
                ),
            );
        }
        Some(stack) => {
            let errs = configbot_manifests::validate::validate_against_stack(&spec, &stack);
            if errs.is_empty() {
                let msg = format!("RobotStack {stack_name:?} found");
                if set_condition(
                    &mut new.conditions,
                    cond(
                        ct::STACK_RESOLVED,
                        ConditionStatus::True,
                        reasons::STACK_FOUND,
                        msg.clone(),
                        g,
                        now,
                    ),
                ) {
                    events.push(PlannedEvent {
                        type_: "Normal",
                        reason: reasons::STACK_FOUND,
                        message: msg,
                    });
                }
                set_condition(
                    &mut new.conditions,
                    cond(
                        ct::ACCEPTED,
                        ConditionStatus::True,
                        reasons::VALID,
                        format!("{} metrics", spec.spec.metrics.len()),
                        g,
                        now,
                    ),
                );
                if matches!(new.phase.as_str(), "" | "Pending" | "Invalid") {
                    new.phase = "Accepted".into();
                }
                // Once a tuning run reports readiness, the run owns `Ready`.
                let tuned = new.conditions.iter().any(|c| {
                    c.type_ == ct::READY
                        && ![reasons::NOT_MEASURED, reasons::STACK_NOT_FOUND]
                            .contains(&c.reason.as_str())
                });
                if !tuned {
                    set_condition(
                        &mut new.conditions,
                        cond(
                            ct::READY,
                            ConditionStatus::Unknown,
                            reasons::NOT_MEASURED,
                            "no agent has reported metrics for this stack yet".into(),
                            g,
                            now,
                        ),
                    );
                }
            } else {
                new.phase = "Invalid".into();
                let msg = errs
                    .iter()
                    .map(|e| format!("{}: {}", e.path, e.message))
                    .collect::<Vec<_>>()
                    .join("; ");
                set_condition(
                    &mut new.conditions,
                    cond(
                        ct::STACK_RESOLVED,
                        ConditionStatus::False,
                        reasons::STACK_MISMATCH,
                        msg.clone(),
                        g,
                        now,
                    ),
                );
                events.push(PlannedEvent {
                    type_: "Warning",
                    reason: reasons::STACK_MISMATCH,
                    message: msg,
                });
            }
        }
    }
    finish(&old, new, events)
}

fn finish<T: serde::Serialize + PartialEq>(
    old: &T,
    new: T,
    events: Vec<PlannedEvent>,
) -> (Option<Value>, Vec<PlannedEvent>) {
    if *old == new {
        return (None, events);
    }
    (serde_json::to_value(&new).ok(), events)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn spec() -> Value {
        json!({"apiVersion": "configbot.dev/v1alpha1", "kind": "PerformanceSpec",
               "metadata": {"name": "p", "namespace": "default", "generation": 3},
               "spec": {"stackRef": {"name": "s"}, "metrics": [{"name": "m", "app": "nav",
                        "source": {"topicRate": {"topic": "/cmd_vel"}}, "target": {"atLeast": 35}}]}})
    }

    fn stack(app: &str) -> Value {
        json!({"apiVersion": "configbot.dev/v1alpha1", "kind": "RobotStack", "metadata": {"name": "s", "generation": 1},
               "spec": {"apps": [{"name": app, "core": true, "nodes": [{"name": "/nav", "run": {"command": "x"}}]}]}})
    }

    fn condition(status: &Value, t: &str) -> (String, String) {
        let c = status["conditions"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["type"] == t)
            .unwrap();
        (
            c["status"].as_str().unwrap().into(),
            c["reason"].as_str().unwrap().into(),
        )
    }

    #[test]
    fn spec_status_table() {
        // (stack, phase, StackResolved condition)
        let cases = [
            (None, "Pending", ("False", reasons::STACK_NOT_FOUND)),
            (
                Some(stack("nav")),
                "Accepted",
                ("True", reasons::STACK_FOUND),
            ),
            (
                Some(stack("other")),
                "Invalid",
                ("False", reasons::STACK_MISMATCH),
            ),
        ];
        for (st, phase, (cs, reason)) in cases {
            let (status, events) = performance_spec_status(&spec(), st.as_ref(), "t");
            let status = status.unwrap();
            assert_eq!(status["phase"], phase);
            assert_eq!(status["observedGeneration"], 3);
            assert_eq!(
                condition(&status, "StackResolved"),
                (cs.to_string(), reason.to_string())
            );
            assert_eq!(events.len(), 1);
        }
    }

    #[test]
    fn unchanged_status_plans_no_write() {
        let mut obj = spec();
        let (status, _) = performance_spec_status(&obj, Some(&stack("nav")), "t1");
        obj["status"] = status.unwrap();
        let (again, events) = performance_spec_status(&obj, Some(&stack("nav")), "t2");
        assert_eq!(again, None, "only the time would change");
        assert!(events.is_empty());
    }

    #[test]
    fn missing_stack_heals_when_applied() {
        let mut obj = spec();
        obj["status"] = performance_spec_status(&obj, None, "t1").0.unwrap();
        let (status, _) = performance_spec_status(&obj, Some(&stack("nav")), "t2");
        let status = status.unwrap();
        assert_eq!(status["phase"], "Accepted");
        assert_eq!(condition(&status, "StackResolved").0, "True");
    }
}
