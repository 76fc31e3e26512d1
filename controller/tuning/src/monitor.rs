//! Monitors (paper §V-B), pure parts: the constraint monitor (violations
//! sustained for `spec.monitoring.violationWindowSeconds` trigger relearning)
//! and the classification of robot events ([`RobotEvent`]) into context
//! re-checks (a process exec or a graph change may mean a new app). Every
//! trigger has a cause that becomes a condition and an event.

use configbot_api::graph::GraphEvent;
use configbot_manifests::Reason;
use serde::{Deserialize, Serialize};

/// What the tuning loop needs to know of the runtime's `RuntimeEvent`s. A
/// robot (an implementation of the controller's `tuning::robot::Robot`) maps
/// each `RuntimeEvent` onto one of these (others → `Other`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "camelCase")]
pub enum RobotEvent {
    /// A process exec seen by the process monitor.
    #[serde(rename_all = "camelCase")]
    ProcessExec {
        pid: u32,
        comm: Option<String>,
        at_unix_ms: u64,
    },
    #[serde(rename_all = "camelCase")]
    ProcessExit { pid: u32 },
    /// The ROS graph changed (nodes or edges came or went).
    #[serde(rename_all = "camelCase")]
    GraphChanged { events: Vec<GraphEvent> },
    #[serde(rename_all = "camelCase")]
    AppStopped { app: String },
    #[serde(rename_all = "camelCase")]
    AppStarted { app: String },
    /// Any other runtime event, by its type name.
    #[serde(rename_all = "camelCase")]
    Other { name: String },
}

/// Why a run (re)starts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "cause", rename_all = "camelCase")]
pub enum Trigger {
    /// The spec was created or changed.
    SpecChanged,
    /// A core constraint was violated for the whole violation window.
    #[serde(rename_all = "camelCase")]
    ConstraintViolated { seconds: f64, satisfaction: f64 },
    /// The set of running apps/nodes (or the labels) changed.
    #[serde(rename_all = "camelCase")]
    ContextChanged {
        from: String,
        to: String,
        by: String,
        /// Nodes in the new context that the old one did not have. Empty
        /// when nodes only left (or only the labels changed): nothing is
        /// starting, so the run skips the start-up wait.
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        joined: Vec<String>,
    },
    /// A config from the library did not hold.
    #[serde(rename_all = "camelCase")]
    LibraryConfigFailed { satisfaction: f64 },
    /// Tuning became allowed again after a remediation.
    TuningAllowed,
}

impl Trigger {
    /// CamelCase reason for conditions and events.
    pub fn reason(&self) -> Reason {
        match self {
            Trigger::SpecChanged => Reason::SpecChanged,
            Trigger::ConstraintViolated { .. } => Reason::ConstraintViolated,
            Trigger::ContextChanged { .. } => Reason::ContextChanged,
            Trigger::LibraryConfigFailed { .. } => Reason::LibraryConfigFailed,
            Trigger::TuningAllowed => Reason::TuningAllowed,
        }
    }

    pub fn message(&self) -> String {
        match self {
            Trigger::SpecChanged => "the spec changed".into(),
            Trigger::ConstraintViolated {
                seconds,
                satisfaction,
            } => format!(
                "core constraints violated for {seconds:.0} s (satisfaction {:.1} %)",
                satisfaction * 100.0
            ),
            Trigger::ContextChanged { from, to, by, .. } => {
                format!("context changed ({by}): {from} -> {to}")
            }
            Trigger::LibraryConfigFailed { satisfaction } => format!(
                "the library config held in only {:.1} % of the windows",
                satisfaction * 100.0
            ),
            Trigger::TuningAllowed => "tuning is allowed again".into(),
        }
    }
}

/// Counts consecutive violated sub-windows.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ConstraintMonitor {
    /// Seconds of consecutive violation so far.
    pub violated_for: f64,
    /// Sub-windows seen and how many held (steady-state satisfaction).
    pub windows: u64,
    pub ok_windows: u64,
}

impl ConstraintMonitor {
    /// Feed sub-window results; returns a trigger when the violation has
    /// lasted `window_s` seconds.
    pub fn observe(&mut self, ok: &[bool], sub_window_s: f64, window_s: f64) -> Option<Trigger> {
        for &b in ok {
            self.windows += 1;
            if b {
                self.ok_windows += 1;
                self.violated_for = 0.0;
            } else {
                self.violated_for += sub_window_s;
            }
        }
        (self.violated_for + 1e-9 >= window_s).then(|| Trigger::ConstraintViolated {
            seconds: self.violated_for,
            satisfaction: self.satisfaction().unwrap_or(0.0),
        })
    }

    /// Steady-state satisfaction since monitoring started.
    pub fn satisfaction(&self) -> Option<f64> {
        (self.windows > 0).then(|| self.ok_windows as f64 / self.windows as f64)
    }
}

/// Does this robot event call for a context re-check? Returns what to name as the cause.
pub fn recheck_cause(e: &RobotEvent) -> Option<String> {
    match e {
        RobotEvent::ProcessExec { pid, comm, .. } => Some(format!(
            "process exec pid {pid} ({})",
            comm.as_deref().unwrap_or("?")
        )),
        RobotEvent::GraphChanged { events } if !events.is_empty() => {
            Some(format!("ROS graph changed ({} changes)", events.len()))
        }
        RobotEvent::AppStarted { app } => Some(format!("app {app} started")),
        RobotEvent::AppStopped { app } => Some(format!("app {app} stopped")),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn violation_must_be_sustained() {
        // (sub-window results fed in order, trigger expected after the last batch)
        let cases: Vec<(Vec<Vec<bool>>, bool)> = vec![
            (vec![vec![false; 4]], false),
            (vec![vec![false; 5]], true),
            (vec![vec![false; 3], vec![false, false]], true),
            (vec![vec![false; 4], vec![true], vec![false; 4]], false),
            (vec![vec![true; 10]], false),
        ];
        for (batches, want) in cases {
            let mut m = ConstraintMonitor::default();
            let mut got = None;
            for b in &batches {
                got = m.observe(b, 1.0, 5.0);
            }
            assert_eq!(got.is_some(), want, "{batches:?}");
        }
        let mut m = ConstraintMonitor::default();
        m.observe(&[true, true, true, false], 1.0, 5.0);
        assert_eq!(m.satisfaction(), Some(0.75));
    }

    #[test]
    fn which_events_recheck_the_context() {
        let exec = RobotEvent::ProcessExec {
            pid: 7,
            comm: Some("detector".into()),
            at_unix_ms: 0,
        };
        assert_eq!(
            recheck_cause(&exec).as_deref(),
            Some("process exec pid 7 (detector)")
        );
        assert!(recheck_cause(&RobotEvent::ProcessExit { pid: 7 }).is_none());
        assert!(recheck_cause(&RobotEvent::GraphChanged { events: vec![] }).is_none());
        assert!(
            recheck_cause(&RobotEvent::Other {
                name: "configApplied".into()
            })
            .is_none()
        );
    }
}
