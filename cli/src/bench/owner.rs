//! The one owner of the bench's current robot. Every step of `configbot
//! bench` runs on a fresh robot (nodes in `configbot-demo-<pid>` cgroups);
//! the steps borrow it from here instead of holding it, so when the user
//! interrupts the bench (Ctrl-C, SIGTERM) [`bench::run`](super::run) can
//! still stop its nodes and remove its cgroups after dropping the step.

use std::path::Path;

use tokio::task::JoinHandle;

use crate::demo::PrivateRobot;

/// The robot a bench step runs on, or none between steps.
#[derive(Default)]
pub struct Current {
    /// CPU weight of each robot's subtree (`None`: the kernel's default).
    cpu_weight: Option<u32>,
    robot: Option<PrivateRobot>,
    /// A robot still starting: its start runs as its own task, so an
    /// interruption mid-start does not drop a half-started runtime; [`close`]
    /// waits for it and closes it.
    ///
    /// [`close`]: Current::close
    starting: Option<JoinHandle<anyhow::Result<PrivateRobot>>>,
    /// A robot being closed, also as its own task, so an interruption
    /// mid-close does not leave it half torn down; [`close`] waits for it.
    ///
    /// [`close`]: Current::close
    closing: Option<JoinHandle<anyhow::Result<()>>>,
}

impl Current {
    pub fn new(cpu_weight: Option<u32>) -> Current {
        Current {
            cpu_weight,
            ..Current::default()
        }
    }

    /// Closes the previous robot (if any), starts a fresh one with its files
    /// in `dir` and lends it out until the next [`start`](Current::start) or
    /// [`close`](Current::close).
    pub async fn start(&mut self, dir: &Path) -> anyhow::Result<&PrivateRobot> {
        self.close().await?;
        let (dir, weight) = (dir.to_path_buf(), self.cpu_weight);
        let handle = self.starting.insert(tokio::spawn(async move {
            PrivateRobot::start(&dir, weight).await
        }));
        let started = handle.await;
        self.starting = None;
        Ok(self.robot.insert(started??))
    }

    /// Stops the current robot's control plane and nodes and removes its
    /// cgroups (waiting for one still starting or closing); nothing when
    /// there is none. Each await leaves the pending task in `self`, so a
    /// cancelled call is finished by the next one.
    pub async fn close(&mut self) -> anyhow::Result<()> {
        if let Some(h) = self.starting.as_mut() {
            let started = h.await;
            self.starting = None;
            if let Ok(Ok(r)) = started {
                self.robot = Some(r);
            }
        }
        if let Some(r) = self.robot.take() {
            self.closing = Some(tokio::spawn(r.close()));
        }
        match self.closing.as_mut() {
            Some(h) => {
                let closed = h.await;
                self.closing = None;
                closed?
            }
            None => Ok(()),
        }
    }

    /// Whether a robot is running, starting or closing.
    pub fn is_open(&self) -> bool {
        self.robot.is_some() || self.starting.is_some() || self.closing.is_some()
    }
}
