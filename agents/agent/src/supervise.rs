//! The restart loop of a `run` node: start it, wait for it to end (or for a
//! stop), and restart it per its [`RestartPolicy`] after a [`Backoff`] that
//! grows with each quick failure and starts over after a healthy run. The
//! loop sees the node only through [`Supervised`], the few operations it
//! needs (the agent's are [`crate::agent::process::RunNode`]), and keeps
//! time with tokio's clock, so its tests run on a script of exits and paused
//! time, without processes.

use std::future::Future;
use std::time::Duration;

use configbot_api::backoff::Backoff;
use tokio::sync::watch;
use tokio::time::Instant;

use crate::policy::{ExitKind, STABLE_RUN, should_restart};
use crate::spec::RestartPolicy;

/// What supervising one node needs: start it, wait for its process, stop it,
/// and record what happened (events, state, metrics).
pub(crate) trait Supervised {
    /// A running process of the node.
    type Proc: Send;

    /// Starts the node, or re-attaches to the process `(pid, start time)` a
    /// previous agent started; `None` (recorded) when it could not start.
    fn start(&self, reattach: Option<(u32, u64)>) -> Option<Self::Proc>;

    /// Waits until the process ends.
    fn wait(&self, proc: &mut Self::Proc) -> impl Future<Output = ExitKind> + Send;

    /// Stops the process gracefully (a stop was asked for while it ran).
    fn terminate(&self, proc: &mut Self::Proc) -> impl Future<Output = ()> + Send;

    /// Records that the process ended with `exit`.
    fn exited(&self, proc: &Self::Proc, exit: ExitKind);

    /// Records that the node restarts after `delay`.
    fn restarting(&self, delay: Duration);

    /// Records that the node was stopped.
    fn stopped(&self);
}

/// Runs one node until `stop` changes (or its sender is dropped): start (or
/// re-attach), wait, then restart per `policy` after the next delay of
/// `backoff`, which is reset when the run lasted [`STABLE_RUN`]. A node that
/// could not start counts as failed with an unknown status. Returns when the
/// policy says not to restart.
pub(crate) async fn supervise<S: Supervised>(
    node: S,
    policy: RestartPolicy,
    mut backoff: Backoff,
    mut stop: watch::Receiver<bool>,
    mut reattach: Option<(u32, u64)>,
) {
    loop {
        let started = Instant::now();
        let exit = match node.start(reattach.take()) {
            None => ExitKind::Unknown,
            Some(mut proc) => {
                let exit = tokio::select! {
                    e = node.wait(&mut proc) => e,
                    _ = stop.changed() => {
                        node.terminate(&mut proc).await;
                        node.stopped();
                        return;
                    }
                };
                node.exited(&proc, exit);
                exit
            }
        };
        if !should_restart(policy, exit) {
            return;
        }
        if started.elapsed() >= STABLE_RUN {
            backoff.reset();
        }
        let delay = backoff.next_delay();
        node.restarting(delay);
        tokio::select! {
            () = tokio::time::sleep(delay) => {}
            _ = stop.changed() => {
                node.stopped();
                return;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::collections::VecDeque;
    use std::sync::Mutex;

    use super::*;

    /// What the loop did, in order (times in ms since the test started).
    #[derive(Debug, Clone, PartialEq, Eq)]
    enum Did {
        Start { at: u128, reattach: bool },
        SpawnFailed { at: u128 },
        Exited { at: u128, exit: ExitKind },
        Restarting { delay: u128 },
        Terminated { at: u128 },
        Stopped { at: u128 },
    }

    /// A node whose runs follow a script: each start takes the next entry,
    /// `Some((runs for, exit))` or `None` (it cannot start); once the script
    /// is used up, the process runs until stopped.
    struct Script {
        t0: Instant,
        runs: Mutex<VecDeque<Option<(Duration, ExitKind)>>>,
        log: Mutex<Vec<Did>>,
    }

    impl Script {
        fn new(runs: impl IntoIterator<Item = Option<(Duration, ExitKind)>>) -> Self {
            Self {
                t0: Instant::now(),
                runs: Mutex::new(runs.into_iter().collect()),
                log: Mutex::new(Vec::new()),
            }
        }

        fn at(&self) -> u128 {
            self.t0.elapsed().as_millis()
        }

        fn did(&self, d: Did) {
            self.log.lock().unwrap().push(d);
        }

        fn log(&self) -> Vec<Did> {
            self.log.lock().unwrap().clone()
        }

        fn delays(&self) -> Vec<u128> {
            self.log()
                .into_iter()
                .filter_map(|d| match d {
                    Did::Restarting { delay } => Some(delay),
                    _ => None,
                })
                .collect()
        }
    }

    impl Supervised for &Script {
        /// How long it runs and how it ends; `None`: until stopped.
        type Proc = Option<(Duration, ExitKind)>;

        fn start(&self, reattach: Option<(u32, u64)>) -> Option<Self::Proc> {
            let next = self.runs.lock().unwrap().pop_front();
            if let Some(None) = next {
                self.did(Did::SpawnFailed { at: self.at() });
                return None;
            }
            self.did(Did::Start {
                at: self.at(),
                reattach: reattach.is_some(),
            });
            Some(next.flatten())
        }

        async fn wait(&self, proc: &mut Self::Proc) -> ExitKind {
            match *proc {
                Some((runs_for, exit)) => {
                    tokio::time::sleep(runs_for).await;
                    exit
                }
                None => std::future::pending().await,
            }
        }

        async fn terminate(&self, _: &mut Self::Proc) {
            self.did(Did::Terminated { at: self.at() });
        }

        fn exited(&self, _: &Self::Proc, exit: ExitKind) {
            self.did(Did::Exited {
                at: self.at(),
                exit,
            });
        }

        fn restarting(&self, delay: Duration) {
            self.did(Did::Restarting {
                delay: delay.as_millis(),
            });
        }

        fn stopped(&self) {
            self.did(Did::Stopped { at: self.at() });
        }
    }

    fn backoff() -> Backoff {
        Backoff::new(Duration::from_millis(100), Duration::from_millis(1000))
    }

    fn quick(exit: ExitKind) -> Option<(Duration, ExitKind)> {
        Some((Duration::from_secs(1), exit))
    }

    const FAILED: ExitKind = ExitKind::Failed(3);

    /// Runs the loop on `script` until it returns by itself.
    async fn run(script: &Script, policy: RestartPolicy) {
        let (_tx, rx) = watch::channel(false);
        supervise(script, policy, backoff(), rx, None).await;
    }

    #[tokio::test(start_paused = true)]
    async fn a_crash_restarts_after_a_delay_that_doubles_up_to_the_cap() {
        let s = Script::new(
            [quick(FAILED); 6]
                .into_iter()
                .chain([quick(ExitKind::Success)]),
        );
        run(&s, RestartPolicy::OnFailure).await;
        assert_eq!(s.delays(), [100, 200, 400, 800, 1000, 1000]);
        // Each restart waits its delay after the exit.
        let log = s.log();
        assert_eq!(
            log[..5],
            [
                Did::Start {
                    at: 0,
                    reattach: false
                },
                Did::Exited {
                    at: 1000,
                    exit: FAILED
                },
                Did::Restarting { delay: 100 },
                Did::Start {
                    at: 1100,
                    reattach: false
                },
                Did::Exited {
                    at: 2100,
                    exit: FAILED
                },
            ]
        );
        assert_eq!(
            log.last(),
            Some(&Did::Exited {
                at: 10500,
                exit: ExitKind::Success
            })
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_healthy_run_resets_the_backoff() {
        let healthy = Some((STABLE_RUN, FAILED));
        let s = Script::new([
            quick(FAILED),
            quick(FAILED),
            quick(FAILED),
            healthy,
            quick(FAILED),
            quick(ExitKind::Success),
        ]);
        run(&s, RestartPolicy::OnFailure).await;
        assert_eq!(s.delays(), [100, 200, 400, 100, 200]);
    }

    #[tokio::test(start_paused = true)]
    async fn the_policy_decides_whether_an_exit_restarts() {
        use RestartPolicy::*;
        // (policy, how the one scripted run ends, restarted?)
        let table = [
            (OnFailure, ExitKind::Success, false),
            (OnFailure, ExitKind::Signaled(9), true),
            (Never, FAILED, false),
            (Always, ExitKind::Success, true),
        ];
        for (policy, exit, restarts) in table {
            // A restart finds the script used up and runs until stopped.
            let s = Script::new([quick(exit)]);
            let (tx, rx) = watch::channel(false);
            let stop_later = async {
                tokio::time::sleep(Duration::from_secs(60)).await;
                let _ = tx.send(true);
            };
            let ((), ()) = tokio::join!(supervise(&s, policy, backoff(), rx, None), stop_later);
            let log = s.log();
            assert_eq!(log[1], Did::Exited { at: 1000, exit }, "{policy:?}");
            if restarts {
                assert_eq!(
                    log[2..4],
                    [
                        Did::Restarting { delay: 100 },
                        Did::Start {
                            at: 1100,
                            reattach: false
                        }
                    ],
                    "{policy:?}"
                );
            } else {
                assert_eq!(log.len(), 2, "{policy:?}: {log:?}");
            }
        }
    }

    #[tokio::test(start_paused = true)]
    async fn a_node_that_cannot_start_is_retried_as_a_failure_with_backoff() {
        let s = Script::new([None, None, quick(ExitKind::Success)]);
        run(&s, RestartPolicy::OnFailure).await;
        assert_eq!(
            s.log(),
            [
                Did::SpawnFailed { at: 0 },
                Did::Restarting { delay: 100 },
                Did::SpawnFailed { at: 100 },
                Did::Restarting { delay: 200 },
                Did::Start {
                    at: 300,
                    reattach: false
                },
                Did::Exited {
                    at: 1300,
                    exit: ExitKind::Success
                },
            ]
        );
        // Under `Never`, a failed start is the end.
        let s = Script::new([None]);
        run(&s, RestartPolicy::Never).await;
        assert_eq!(s.log(), [Did::SpawnFailed { at: 0 }]);
    }

    #[tokio::test(start_paused = true)]
    async fn a_stop_terminates_a_running_node_and_ends_a_pending_restart() {
        // Running (re-attached to a previous agent's process): terminated, then stopped.
        let s = Script::new([]);
        let (tx, rx) = watch::channel(false);
        let stop = async {
            tokio::time::sleep(Duration::from_secs(5)).await;
            let _ = tx.send(true);
        };
        tokio::join!(
            supervise(&s, RestartPolicy::Always, backoff(), rx, Some((42, 7))),
            stop
        );
        assert_eq!(
            s.log(),
            [
                Did::Start {
                    at: 0,
                    reattach: true
                },
                Did::Terminated { at: 5000 },
                Did::Stopped { at: 5000 },
            ]
        );
        // Waiting to restart: stopped at once, nothing to terminate.
        let s = Script::new([Some((Duration::from_secs(1), FAILED))]);
        let (tx, rx) = watch::channel(false);
        let stop = async {
            tokio::time::sleep(Duration::from_millis(1050)).await;
            let _ = tx.send(true);
        };
        tokio::join!(
            supervise(&s, RestartPolicy::Always, backoff(), rx, None),
            stop
        );
        assert_eq!(
            s.log()[1..],
            [
                Did::Exited {
                    at: 1000,
                    exit: FAILED
                },
                Did::Restarting { delay: 100 },
                Did::Stopped { at: 1050 },
            ]
        );
        // A dropped stop sender counts as a stop.
        let s = Script::new([]);
        let (tx, rx) = watch::channel(false);
        drop(tx);
        supervise(&s, RestartPolicy::Always, backoff(), rx, None).await;
        assert_eq!(
            s.log()[1..],
            [Did::Terminated { at: 0 }, Did::Stopped { at: 0 }]
        );
    }
}
