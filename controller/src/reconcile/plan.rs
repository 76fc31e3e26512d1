//! Pure status planning: from an object (and what it references) to the status
//! it should have and the events to record. No IO; `None` means "status is
//! already right", so timestamps alone never cause a write.

use configbot_manifests::meta::{condition_types as ct, set_condition};
use configbot_manifests::{
    Condition, ConditionStatus, Manifest, PerformanceSpecStatus, Phase, Reason, RobotStackStatus,
    StackPhase,
};
use serde_json::Value;

/// An event to record about the reconciled object.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlannedEvent {
    pub type_: &'static str,
    pub reason: Reason,
    pub message: String,
}

/// Writes conditions of one object at one generation and time, and collects
/// the events of the changes worth one.
struct Conditions<'a> {
    list: &'a mut Vec<Condition>,
    generation: i64,
    now: &'a str,
    events: Vec<PlannedEvent>,
}

impl Conditions<'_> {
    /// Sets a condition; true when it changed (a new status, reason or message).
    fn set(
        &mut self,
        type_: &str,
        status: ConditionStatus,
        reason: Reason,
        message: String,
    ) -> bool {
        set_condition(
            self.list,
            Condition {
                type_: type_.into(),
                status,
                reason,
                message,
                last_transition_time: self.now.into(),
                observed_generation: self.generation,
            },
        )
    }

    /// Sets a condition and, when it changed, records an event of `event`
    /// type (`Normal`/`Warning`) with `reason` and the same message.
    fn set_with_event(
        &mut self,
        type_: &str,
        status: ConditionStatus,
        event: &'static str,
        reason: Reason,
        message: String,
    ) {
        if self.set(type_, status, reason.clone(), message.clone()) {
            self.events.push(PlannedEvent {
                type_: event,
                reason,
                message,
            });
        }
    }
}

fn generation(obj: &Value) -> i64 {
    obj["metadata"]["generation"].as_i64().unwrap_or(0)
}

/// Validation errors as one condition message.
fn joined(errs: &[configbot_manifests::FieldError]) -> String {
    errs.iter()
        .map(|e| format!("{}: {}", e.path, e.message))
        .collect::<Vec<_>>()
        .join("; ")
}

/// The object's status as it is (default when absent or unreadable).
fn old_status<T: serde::de::DeserializeOwned + Default>(obj: &Value) -> T {
    configbot_manifests::decode_status(obj).unwrap_or_default()
}

/// Status of a RobotStack.
pub fn robot_stack_status(obj: &Value, now: &str) -> (Option<Value>, Vec<PlannedEvent>) {
    let old: RobotStackStatus = old_status(obj);
    let mut new = old.clone();
    new.observed_generation = generation(obj);
    let mut c = Conditions {
        list: &mut new.conditions,
        generation: new.observed_generation,
        now,
        events: Vec::new(),
    };
    let phase = match configbot_manifests::decode_and_validate(obj) {
        Ok(Manifest::RobotStack(s)) => {
            let (apps, nodes) = (s.spec.apps.len() as u32, s.spec.nodes().count() as u32);
            let msg = format!("{apps} apps, {nodes} nodes");
            c.set_with_event(
                ct::ACCEPTED,
                ConditionStatus::True,
                "Normal",
                Reason::Accepted,
                msg,
            );
            new.apps = apps;
            new.nodes = nodes;
            matches!(new.phase, StackPhase::Pending | StackPhase::Invalid)
                .then_some(StackPhase::Accepted)
        }
        Ok(_) => None,
        Err(errs) => {
            c.set(
                ct::ACCEPTED,
                ConditionStatus::False,
                Reason::Invalid,
                joined(&errs),
            );
            Some(StackPhase::Invalid)
        }
    };
    let events = c.events;
    if let Some(p) = phase {
        new.phase = p;
    }
    finish(&old, new, events)
}

/// Status of a PerformanceSpec, given the stack it names (if it exists).
pub fn performance_spec_status(
    obj: &Value,
    stack: Option<&Value>,
    now: &str,
) -> (Option<Value>, Vec<PlannedEvent>) {
    let old: PerformanceSpecStatus = old_status(obj);
    let mut new = old.clone();
    new.observed_generation = generation(obj);
    let mut phase = new.phase.clone();
    let mut c = Conditions {
        list: &mut new.conditions,
        generation: new.observed_generation,
        now,
        events: Vec::new(),
    };
    use ConditionStatus::{False, True, Unknown};
    let spec = match configbot_manifests::decode_and_validate(obj) {
        Ok(Manifest::PerformanceSpec(p)) => p,
        Ok(_) => return (None, Vec::new()),
        Err(errs) => {
            c.set(ct::ACCEPTED, False, Reason::Invalid, joined(&errs));
            new.phase = Phase::Invalid;
            return finish(&old, new, Vec::new());
        }
    };
    let stack_name = &spec.spec.stack_ref.name;
    let stack = stack.and_then(|s| match configbot_manifests::decode(s) {
        Ok(Manifest::RobotStack(s)) => Some(s),
        _ => None,
    });
    match stack {
        None => {
            phase = Phase::Pending;
            let msg = format!(
                "RobotStack {stack_name:?} does not exist in namespace {:?}; apply it and this spec proceeds",
                spec.metadata.namespace()
            );
            let r = Reason::StackNotFound;
            c.set_with_event(ct::STACK_RESOLVED, False, "Warning", r.clone(), msg);
            c.set(ct::READY, False, r, "waiting for the stack".into());
        }
        Some(stack) => {
            let errs = configbot_manifests::validate::validate_against_stack(&spec, &stack);
            if errs.is_empty() {
                let msg = format!("RobotStack {stack_name:?} found");
                c.set_with_event(ct::STACK_RESOLVED, True, "Normal", Reason::StackFound, msg);
                let metrics = format!("{} metrics", spec.spec.metrics.len());
                c.set(ct::ACCEPTED, True, Reason::Valid, metrics);
                if matches!(phase, Phase::Pending | Phase::Invalid) {
                    phase = Phase::Accepted;
                }
                // Once a tuning run reports readiness, the run owns `Ready`.
                let tuned = c.list.iter().any(|c| {
                    c.type_ == ct::READY
                        && !matches!(c.reason, Reason::NotMeasured | Reason::StackNotFound)
                });
                if !tuned {
                    let msg = "no agent has reported metrics for this stack yet".into();
                    c.set(ct::READY, Unknown, Reason::NotMeasured, msg);
                }
            } else {
                phase = Phase::Invalid;
                let msg = joined(&errs);
                c.set(
                    ct::STACK_RESOLVED,
                    False,
                    Reason::StackMismatch,
                    msg.clone(),
                );
                // A mismatch is reported on every reconcile while it lasts.
                c.events.push(PlannedEvent {
                    type_: "Warning",
                    reason: Reason::StackMismatch,
                    message: msg,
                });
            }
        }
    }
    let events = c.events;
    new.phase = phase;
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
            (None, "Pending", ("False", Reason::StackNotFound)),
            (Some(stack("nav")), "Accepted", ("True", Reason::StackFound)),
            (
                Some(stack("other")),
                "Invalid",
                ("False", Reason::StackMismatch),
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
