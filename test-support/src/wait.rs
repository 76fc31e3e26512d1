//! Waiting on a condition with a timeout instead of a fixed sleep: poll it
//! every `poll` until it holds (`true`, or `Some(value)`), or give up after
//! `timeout` with an error that names what was awaited and for how long.

use std::fmt;
use std::time::{Duration, Instant};

/// What a condition returns: `bool` (holds or not) or `Option<T>` (the
/// value it waited for, once there).
pub trait Ready {
    /// What the wait returns once the condition holds.
    type Output;
    /// `Some` once the condition holds.
    fn ready(self) -> Option<Self::Output>;
}

impl Ready for bool {
    type Output = ();
    fn ready(self) -> Option<()> {
        self.then_some(())
    }
}

impl<T> Ready for Option<T> {
    type Output = T;
    fn ready(self) -> Option<T> {
        self
    }
}

/// A condition did not hold within its timeout.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TimedOut {
    /// What was awaited.
    pub what: String,
    /// How long.
    pub timeout: Duration,
}

impl fmt::Display for TimedOut {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "timed out after {:?} waiting for {}",
            self.timeout, self.what
        )
    }
}

impl std::error::Error for TimedOut {}

/// Checks `cond` at once and then every `poll` (the last check falls on
/// the deadline) until it holds; its value, or [`TimedOut`] naming `what`
/// and `timeout`. For a failure message with more context than that.
pub fn try_wait_until<R: Ready>(
    what: &str,
    timeout: Duration,
    poll: Duration,
    mut cond: impl FnMut() -> R,
) -> Result<R::Output, TimedOut> {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(v) = cond().ready() {
            return Ok(v);
        }
        let now = Instant::now();
        if now >= deadline {
            return Err(TimedOut {
                what: what.to_owned(),
                timeout,
            });
        }
        std::thread::sleep(poll.min(deadline - now));
    }
}

/// [`try_wait_until`] that panics on timeout with `timed out after
/// {timeout:?} waiting for {what}`.
#[track_caller]
pub fn wait_until<R: Ready>(
    what: &str,
    timeout: Duration,
    poll: Duration,
    cond: impl FnMut() -> R,
) -> R::Output {
    match try_wait_until(what, timeout, poll, cond) {
        Ok(v) => v,
        Err(e) => panic!("{e}"),
    }
}

/// [`try_wait_until`] for async tests: `cond` may await, the pauses are
/// tokio sleeps, and the deadline is on tokio's clock (so a paused test
/// clock advances it too).
#[cfg(feature = "tokio")]
pub async fn try_wait_until_async<R: Ready>(
    what: &str,
    timeout: Duration,
    poll: Duration,
    mut cond: impl AsyncFnMut() -> R,
) -> Result<R::Output, TimedOut> {
    let deadline = tokio::time::Instant::now() + timeout;
    loop {
        if let Some(v) = cond().await.ready() {
            return Ok(v);
        }
        let now = tokio::time::Instant::now();
        if now >= deadline {
            return Err(TimedOut {
                what: what.to_owned(),
                timeout,
            });
        }
        tokio::time::sleep(poll.min(deadline - now)).await;
    }
}

/// [`try_wait_until_async`] that panics on timeout, as [`wait_until`] does.
#[cfg(feature = "tokio")]
pub async fn wait_until_async<R: Ready>(
    what: &str,
    timeout: Duration,
    poll: Duration,
    cond: impl AsyncFnMut() -> R,
) -> R::Output {
    match try_wait_until_async(what, timeout, poll, cond).await {
        Ok(v) => v,
        Err(e) => panic!("{e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const POLL: Duration = Duration::from_millis(1);

    #[test]
    fn returns_once_the_condition_holds() {
        let mut calls = 0;
        wait_until("the third call", Duration::from_secs(10), POLL, || {
            calls += 1;
            calls == 3
        });
        assert_eq!(calls, 3);
    }

    #[test]
    fn returns_the_value_an_option_condition_waited_for() {
        let mut calls = 0;
        let v = wait_until("a value", Duration::from_secs(10), POLL, || {
            calls += 1;
            (calls > 1).then_some(calls * 10)
        });
        assert_eq!(v, 20);
    }

    #[test]
    fn times_out_naming_what_and_how_long_after_checking_at_the_deadline() {
        let timeout = Duration::from_millis(50);
        let started = Instant::now();
        let mut last = None;
        let err = try_wait_until("nothing", timeout, Duration::from_millis(20), || {
            last = Some(Instant::now());
            false
        })
        .unwrap_err();
        assert!(started.elapsed() >= timeout);
        assert!(
            last.unwrap() >= started + timeout,
            "no check at the deadline"
        );
        assert_eq!(
            err,
            TimedOut {
                what: "nothing".into(),
                timeout
            }
        );
        assert_eq!(err.to_string(), "timed out after 50ms waiting for nothing");
    }

    #[test]
    #[should_panic(expected = "timed out after 10ms waiting for the impossible")]
    fn wait_until_panics_with_the_timeout_message() {
        wait_until("the impossible", Duration::from_millis(10), POLL, || false);
    }

    #[cfg(feature = "tokio")]
    #[tokio::test]
    async fn the_async_wait_awaits_its_condition_and_times_out_alike() {
        let mut calls = 0;
        let v = wait_until_async("a value", Duration::from_secs(10), POLL, async || {
            tokio::task::yield_now().await;
            calls += 1;
            (calls == 2).then_some("done")
        })
        .await;
        assert_eq!(v, "done");
        let err = try_wait_until_async("never", Duration::from_millis(10), POLL, async || false)
            .await
            .unwrap_err();
        assert_eq!(err.to_string(), "timed out after 10ms waiting for never");
    }

    #[cfg(feature = "tokio")]
    #[tokio::test(start_paused = true)]
    async fn the_async_deadline_is_on_tokios_clock() {
        let started = tokio::time::Instant::now();
        let err = try_wait_until_async(
            "a paused hour",
            Duration::from_secs(3600),
            Duration::from_secs(60),
            async || false,
        )
        .await
        .unwrap_err();
        assert_eq!(err.timeout, Duration::from_secs(3600));
        assert!(started.elapsed() >= Duration::from_secs(3600));
    }
}
