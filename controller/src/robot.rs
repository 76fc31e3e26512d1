//! The robots the controller drives, as the tuning loop's [`Robot`]: the node
//! runtime embedded in this process (`configbot serve --agent`) or a remote
//! agent over its API (`AgentClient`), one generic [`AgentRobot`] over the
//! agent's [`NodeApi`] that both implement. Both map the runtime's events
//! onto [`RobotEvent`]s.
//! [`sync_stacks`] keeps the robot running the newest valid RobotStack of the
//! store.

use std::path::PathBuf;
use std::sync::Arc;

use configbot_agent::client::AgentClient;
use configbot_agent::{AgentEvent, NodeRuntime, RuntimeEvent};
use configbot_api::graph::Graph;
use configbot_api::measure::{MeasureReport, MeasureRequest};
use configbot_manifests::{Kind, ResourceConfig, RobotStack, StackPhase};
use tokio::sync::broadcast;

use crate::store::Store;
use configbot_tuning::monitor::RobotEvent;

use crate::tuning::robot::{BoxFuture, NodeApi, Robot, RobotError};

/// The tuning loop's view of one runtime event; `None` for events it ignores.
pub fn robot_event(e: &RuntimeEvent) -> Option<RobotEvent> {
    Some(match e {
        RuntimeEvent::ProcessExec {
            pid,
            comm,
            at_unix_ms,
            ..
        } => RobotEvent::ProcessExec {
            pid: *pid,
            comm: comm.clone(),
            at_unix_ms: *at_unix_ms,
        },
        RuntimeEvent::ProcessExit { pid, .. } => RobotEvent::ProcessExit { pid: *pid },
        RuntimeEvent::GraphChanged { events } => RobotEvent::GraphChanged {
            events: events.clone(),
        },
        RuntimeEvent::Agent(AgentEvent::AppStopped { app }) => {
            RobotEvent::AppStopped { app: app.clone() }
        }
        RuntimeEvent::Agent(AgentEvent::AppStarted { app }) => {
            RobotEvent::AppStarted { app: app.clone() }
        }
        RuntimeEvent::Lagged { .. } => return None,
        RuntimeEvent::Agent(other) => RobotEvent::Other {
            name: serde_json::to_value(other)
                .ok()
                .and_then(|v| v["type"].as_str().map(str::to_owned))
                .unwrap_or_default(),
        },
    })
}

/// A robot driven through a node runtime's [`NodeApi`]: [`EmbeddedRobot`] or
/// [`RemoteRobot`]. Runtime events are mapped onto [`RobotEvent`]s by a
/// forwarding task that ends with the robot.
pub struct AgentRobot<N> {
    node: N,
    events: broadcast::Sender<RobotEvent>,
    /// Dropped with the robot: ends the event forwarding task.
    _stop: tokio::sync::oneshot::Sender<()>,
}

/// The node runtime in this process.
pub type EmbeddedRobot = AgentRobot<NodeRuntime>;
/// A node agent running alone, reached over its API.
pub type RemoteRobot = AgentRobot<AgentClient>;

impl<N> std::fmt::Debug for AgentRobot<N> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AgentRobot")
            .field("node", &std::any::type_name::<N>())
            .finish_non_exhaustive()
    }
}

impl AgentRobot<NodeRuntime> {
    /// Wraps `runtime`; must be called inside a tokio runtime.
    pub fn new(runtime: NodeRuntime) -> EmbeddedRobot {
        let (events, _) = broadcast::channel(1024);
        let (stop, mut stopped) = tokio::sync::oneshot::channel::<()>();
        let (rx, tx) = (runtime.events(), events.clone());
        tokio::spawn(async move {
            tokio::select! {
                _ = &mut stopped => {}
                () = forward_until_closed(rx, tx) => {}
            }
        });
        AgentRobot {
            node: runtime,
            events,
            _stop: stop,
        }
    }

    pub fn runtime(&self) -> &NodeRuntime {
        &self.node
    }
}

impl AgentRobot<AgentClient> {
    /// Follows the agent's event stream, reconnecting every second when it drops.
    pub fn new(client: AgentClient) -> RemoteRobot {
        let (events, _) = broadcast::channel(1024);
        let (stop, mut stopped) = tokio::sync::oneshot::channel::<()>();
        let (c, tx) = (client.clone(), events.clone());
        tokio::spawn(async move {
            loop {
                tokio::select! {
                    _ = &mut stopped => return,
                    r = c.events() => match r {
                        Ok(rx) => tokio::select! {
                            _ = &mut stopped => return,
                            () = forward_until_closed(rx, tx.clone()) => {}
                        },
                        Err(e) => tracing::warn!(error = %e, "agent events (retrying in 1 s)"),
                    },
                }
                tokio::time::sleep(std::time::Duration::from_secs(1)).await;
            }
        });
        AgentRobot {
            node: client,
            events,
            _stop: stop,
        }
    }
}

/// Forwards `rx`'s runtime events, mapped, into `tx` until `rx` closes.
async fn forward_until_closed(
    mut rx: broadcast::Receiver<RuntimeEvent>,
    tx: broadcast::Sender<RobotEvent>,
) {
    loop {
        match rx.recv().await {
            Ok(e) => {
                if let Some(e) = robot_event(&e) {
                    let _ = tx.send(e);
                }
            }
            Err(broadcast::error::RecvError::Lagged(_)) => continue,
            Err(broadcast::error::RecvError::Closed) => return,
        }
    }
}

fn wrap<E: std::error::Error + Send + Sync + 'static>(
    op: &'static str,
) -> impl Fn(E) -> RobotError {
    move |e| RobotError::wrap(op, e)
}

impl<N: NodeApi> NodeApi for AgentRobot<N> {
    type Error = RobotError;

    fn apply<'a>(&'a self, cfg: &'a ResourceConfig) -> BoxFuture<'a, Result<(), RobotError>> {
        Box::pin(async move { self.node.apply(cfg).await.map_err(wrap("apply")) })
    }

    fn measure<'a>(
        &'a self,
        req: &'a MeasureRequest,
    ) -> BoxFuture<'a, Result<MeasureReport, RobotError>> {
        Box::pin(async move { self.node.measure(req).await.map_err(wrap("measure")) })
    }

    fn graph(&self) -> BoxFuture<'_, Result<Graph, RobotError>> {
        Box::pin(async move { self.node.graph().await.map_err(wrap("graph")) })
    }

    fn stop_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), RobotError>> {
        Box::pin(async move { self.node.stop_app(app).await.map_err(wrap("stop_app")) })
    }

    fn start_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), RobotError>> {
        Box::pin(async move { self.node.start_app(app).await.map_err(wrap("start_app")) })
    }

    fn freeze_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), RobotError>> {
        Box::pin(async move { self.node.freeze_app(app).await.map_err(wrap("freeze_app")) })
    }

    fn thaw_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), RobotError>> {
        Box::pin(async move { self.node.thaw_app(app).await.map_err(wrap("thaw_app")) })
    }

    fn start_recording<'a>(
        &'a self,
        name: &'a str,
        topics: &'a [String],
    ) -> BoxFuture<'a, Result<Option<PathBuf>, RobotError>> {
        Box::pin(async move {
            let p = self.node.start_recording(name, topics).await;
            p.map_err(wrap("start_recording"))
        })
    }

    fn stop_recording<'a>(
        &'a self,
        name: &'a str,
    ) -> BoxFuture<'a, Result<Option<PathBuf>, RobotError>> {
        Box::pin(async move {
            let p = self.node.stop_recording(name).await;
            p.map_err(wrap("stop_recording"))
        })
    }

    fn set_stack<'a>(
        &'a self,
        stack: Option<&'a RobotStack>,
    ) -> BoxFuture<'a, Result<(), RobotError>> {
        Box::pin(async move { self.node.set_stack(stack).await.map_err(wrap("set_stack")) })
    }
}

impl<N: NodeApi> Robot for AgentRobot<N> {
    fn events(&self) -> broadcast::Receiver<RobotEvent> {
        self.events.subscribe()
    }
}

/// The stack the robot should run: the newest (by creation time, then name)
/// RobotStack whose status is not `Invalid`/`Pending`.
pub fn choose_stack(stacks: &[serde_json::Value]) -> Option<RobotStack> {
    stacks
        .iter()
        .filter(|s| {
            let phase = s["status"]["phase"].as_str().map(StackPhase::parse);
            !matches!(
                phase,
                None | Some(StackPhase::Invalid | StackPhase::Pending)
            )
        })
        .max_by(|a, b| {
            let key = |o: &serde_json::Value| {
                (
                    o["metadata"]["creationTimestamp"]
                        .as_str()
                        .unwrap_or("")
                        .to_owned(),
                    o["metadata"]["name"].as_str().unwrap_or("").to_owned(),
                )
            };
            key(a).cmp(&key(b))
        })
        .and_then(|s| serde_json::from_value(s.clone()).ok())
}

/// Keeps `robot` running the stack [`choose_stack`] picks, re-checking after
/// every RobotStack change. Failures are logged and retried on the next change.
pub async fn sync_stacks(store: Arc<Store>, robot: Arc<dyn Robot>) {
    let mut changes = store.subscribe();
    let mut current: Option<RobotStack> = None;
    let mut first = true;
    loop {
        match store.list(Kind::RobotStack, None) {
            Ok((stacks, _)) => {
                let want = choose_stack(&stacks);
                let same = match (&want, &current) {
                    (Some(a), Some(b)) => a.spec == b.spec && a.metadata.name == b.metadata.name,
                    (None, None) => !first,
                    _ => false,
                };
                if !same {
                    match robot.set_stack(want.as_ref()).await {
                        Ok(()) => {
                            current = want;
                            first = false;
                        }
                        Err(e) => tracing::warn!(error = %e, "setting the robot's stack"),
                    }
                }
            }
            Err(e) => tracing::warn!(error = %e, "listing stacks"),
        }
        // Wait for the next RobotStack change (status writes included: a
        // stack becomes eligible when it is accepted).
        loop {
            match changes.recv().await {
                Ok(c) if c.kind == Kind::RobotStack => break,
                Ok(_) => continue,
                Err(broadcast::error::RecvError::Lagged(_)) => break,
                Err(broadcast::error::RecvError::Closed) => return,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn stack(name: &str, created: &str, phase: &str) -> serde_json::Value {
        json!({"apiVersion": "configbot.dev/v1alpha1", "kind": "RobotStack",
            "metadata": {"name": name, "creationTimestamp": created},
            "spec": {"apps": [{"name": "a", "nodes": [{"name": "/n", "run": {"command": "x"}}]}]},
            "status": {"phase": phase}})
    }

    #[test]
    fn the_newest_accepted_stack_is_chosen() {
        let s = [
            stack("old", "2026-01-01T00:00:00Z", "Accepted"),
            stack("new", "2026-02-01T00:00:00Z", "Accepted"),
            stack("newest-invalid", "2026-03-01T00:00:00Z", "Invalid"),
        ];
        assert_eq!(choose_stack(&s).unwrap().metadata.name, "new");
        assert!(choose_stack(&s[2..]).is_none());
    }

    #[test]
    fn runtime_events_map_to_robot_events() {
        let e = RuntimeEvent::ProcessExec {
            pid: 7,
            ppid: Some(1),
            comm: Some("x".into()),
            filename: None,
            at_unix_ms: 5,
            seen_unix_ms: 6,
        };
        assert_eq!(
            robot_event(&e),
            Some(RobotEvent::ProcessExec {
                pid: 7,
                comm: Some("x".into()),
                at_unix_ms: 5
            })
        );
        assert_eq!(robot_event(&RuntimeEvent::Lagged { missed: 3 }), None);
        let stopped = RuntimeEvent::Agent(AgentEvent::AppStopped { app: "obj".into() });
        assert_eq!(
            robot_event(&stopped),
            Some(RobotEvent::AppStopped { app: "obj".into() })
        );
    }
}
