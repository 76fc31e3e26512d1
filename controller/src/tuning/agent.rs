//! [`Robot`] for the node runtime: embedded in the controller
//! ([`EmbeddedRobot`] over `NodeRuntime`, `configbot serve` on one robot) or
//! remote ([`RemoteRobot`] over `AgentClient`, `configbot agent` elsewhere).
//! Both forward the runtime's `RuntimeEvent`s as [`RobotEvent`]s through a
//! task that ends when the robot is dropped.

use std::sync::Arc;
use std::time::Duration;

use configbot_agent::AgentEvent;
use configbot_agent::client::AgentClient;
use configbot_agent::events::RuntimeEvent;
use configbot_agent::measure::{MeasureReport, MeasureRequest};
use configbot_agent::runtime::NodeRuntime;
use configbot_dataplane::Graph;
use configbot_manifests::ResourceConfig;
use tokio::sync::broadcast;
use tokio::task::JoinHandle;

use super::robot::{BoxFuture, Robot, RobotError, RobotEvent};

/// What the tuning loop needs of one runtime event.
pub fn robot_event(e: &RuntimeEvent) -> RobotEvent {
    match e {
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
        other => RobotEvent::Other {
            name: serde_json::to_value(other)
                .ok()
                .and_then(|v| v["type"].as_str().map(str::to_string))
                .unwrap_or_default(),
        },
    }
}

/// Aborts the forwarding task with the robot.
#[derive(Debug)]
struct Forwarder(JoinHandle<()>);

impl Drop for Forwarder {
    fn drop(&mut self) {
        self.0.abort();
    }
}

async fn forward(mut rx: broadcast::Receiver<RuntimeEvent>, tx: &broadcast::Sender<RobotEvent>) {
    loop {
        match rx.recv().await {
            Ok(e) => {
                let _ = tx.send(robot_event(&e));
            }
            Err(broadcast::error::RecvError::Lagged(_)) => {
                // The runner re-checks the graph when it lags, too.
                let _ = tx.send(RobotEvent::GraphChanged { events: Vec::new() });
            }
            Err(broadcast::error::RecvError::Closed) => return,
        }
    }
}

/// The node runtime in the controller's process.
#[derive(Debug)]
pub struct EmbeddedRobot {
    rt: NodeRuntime,
    tx: broadcast::Sender<RobotEvent>,
    _forwarder: Forwarder,
}

impl EmbeddedRobot {
    /// Wrap a runtime (inside a tokio runtime: the event forwarder is spawned).
    pub fn new(rt: NodeRuntime) -> Arc<EmbeddedRobot> {
        let tx = broadcast::channel(1024).0;
        let rx = rt.events();
        let ftx = tx.clone();
        let task = tokio::spawn(async move { forward(rx, &ftx).await });
        Arc::new(EmbeddedRobot {
            rt,
            tx,
            _forwarder: Forwarder(task),
        })
    }
}

/// A node agent reached over its HTTP API.
#[derive(Debug)]
pub struct RemoteRobot {
    client: AgentClient,
    tx: broadcast::Sender<RobotEvent>,
    _forwarder: Forwarder,
}

impl RemoteRobot {
    /// Wrap a client; the event stream is (re)connected in the background.
    pub fn new(client: AgentClient) -> Arc<RemoteRobot> {
        let tx = broadcast::channel(1024).0;
        let (c, ftx) = (client.clone(), tx.clone());
        let task = tokio::spawn(async move {
            loop {
                if let Ok(rx) = c.events().await {
                    forward(rx, &ftx).await;
                    // Reconnected: events may have been missed; make the runner look.
                    let _ = ftx.send(RobotEvent::GraphChanged { events: Vec::new() });
                }
                tokio::time::sleep(Duration::from_secs(1)).await;
            }
        });
        Arc::new(RemoteRobot {
            client,
            tx,
            _forwarder: Forwarder(task),
        })
    }
}

macro_rules! robot_impl {
    ($t:ty, $field:ident) => {
        impl Robot for $t {
            fn apply<'a>(
                &'a self,
                cfg: &'a ResourceConfig,
            ) -> BoxFuture<'a, Result<(), RobotError>> {
                Box::pin(async move {
                    self.$field
                        .apply(cfg)
                        .await
                        .map_err(|e| RobotError::wrap("apply", e))
                })
            }

            fn measure<'a>(
                &'a self,
                req: &'a MeasureRequest,
            ) -> BoxFuture<'a, Result<MeasureReport, RobotError>> {
                Box::pin(async move {
                    self.$field
                        .measure(req)
                        .await
                        .map_err(|e| RobotError::wrap("measure", e))
                })
            }

            fn graph(&self) -> BoxFuture<'_, Result<Graph, RobotError>> {
                Box::pin(async move {
                    self.$field
                        .graph()
                        .await
                        .map_err(|e| RobotError::wrap("graph", e))
                })
            }

            fn stop_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), RobotError>> {
                Box::pin(async move {
                    self.$field
                        .stop_app(app)
                        .await
                        .map_err(|e| RobotError::wrap("stop_app", e))
                })
            }

            fn start_app<'a>(&'a self, app: &'a str) -> BoxFuture<'a, Result<(), RobotError>> {
                Box::pin(async move {
                    self.$field
                        .start_app(app)
                        .await
                        .map_err(|e| RobotError::wrap("start_app", e))
                })
            }

            fn events(&self) -> broadcast::Receiver<RobotEvent> {
                self.tx.subscribe()
            }
        }
    };
}

robot_impl!(EmbeddedRobot, rt);
robot_impl!(RemoteRobot, client);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runtime_events_map_onto_robot_events() {
        let exec = RuntimeEvent::ProcessExec {
            pid: 7,
            ppid: Some(1),
            comm: Some("det".into()),
            filename: None,
            at_unix_ms: 5,
            seen_unix_ms: 6,
        };
        let cases = vec![
            (
                exec,
                RobotEvent::ProcessExec {
                    pid: 7,
                    comm: Some("det".into()),
                    at_unix_ms: 5,
                },
            ),
            (
                RuntimeEvent::ProcessExit {
                    pid: 7,
                    exit_code: None,
                },
                RobotEvent::ProcessExit { pid: 7 },
            ),
            (
                RuntimeEvent::GraphChanged { events: vec![] },
                RobotEvent::GraphChanged { events: vec![] },
            ),
            (
                RuntimeEvent::Agent(AgentEvent::AppStopped { app: "det".into() }),
                RobotEvent::AppStopped { app: "det".into() },
            ),
            (
                RuntimeEvent::Agent(AgentEvent::ConfigRejected { error: "x".into() }),
                RobotEvent::Other {
                    name: "configRejected".into(),
                },
            ),
            (
                RuntimeEvent::Lagged { missed: 3 },
                RobotEvent::Other {
                    name: "lagged".into(),
                },
            ),
        ];
        for (e, want) in cases {
            assert_eq!(robot_event(&e), want, "{e:?}");
        }
    }
}
