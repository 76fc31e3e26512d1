//! Pure restart decisions: whether to restart after an exit, and how long to wait.

use std::time::Duration;

use crate::spec::RestartPolicy;

/// How a supervised process ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "camelCase")]
pub enum ExitKind {
    /// Exit code 0.
    Success,
    /// Non-zero exit code.
    Failed(i32),
    /// Killed by a signal.
    Signaled(i32),
    /// Gone, status unknown (an adopted process is not our child).
    Unknown,
}

impl ExitKind {
    /// Converts a std exit status.
    pub fn from_status(s: std::process::ExitStatus) -> Self {
        use std::os::unix::process::ExitStatusExt;
        match (s.code(), s.signal()) {
            (Some(0), _) => Self::Success,
            (Some(c), _) => Self::Failed(c),
            (None, Some(sig)) => Self::Signaled(sig),
            (None, None) => Self::Unknown,
        }
    }
}

/// Whether `policy` restarts a process that ended with `exit`. An unknown
/// status counts as a failure: an adopted process that vanished is restarted
/// under `OnFailure`, which errs toward keeping the robot running.
pub fn should_restart(policy: RestartPolicy, exit: ExitKind) -> bool {
    match policy {
        RestartPolicy::Always => true,
        RestartPolicy::Never => false,
        RestartPolicy::OnFailure => exit != ExitKind::Success,
    }
}

/// Exponential backoff: `initial`, doubling per consecutive failure, capped at
/// `max`; reset after a run that lasted at least `stable`.
#[derive(Debug, Clone)]
pub struct Backoff {
    initial: Duration,
    max: Duration,
    attempt: u32,
}

impl Backoff {
    /// How long a run must last to count as healthy and reset the backoff.
    pub const STABLE: Duration = Duration::from_secs(10);

    pub fn new(initial: Duration, max: Duration) -> Self {
        Self {
            initial,
            max,
            attempt: 0,
        }
    }

    /// The delay before the next restart, given how long the last run lasted.
    pub fn next_delay(&mut self, ran_for: Duration) -> Duration {
        if ran_for >= Self::STABLE {
            self.attempt = 0;
        }
        let factor = 1u32.checked_shl(self.attempt.min(20)).unwrap_or(u32::MAX);
        self.attempt = self.attempt.saturating_add(1);
        self.initial.saturating_mul(factor).min(self.max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn restart_table() {
        use ExitKind::*;
        use RestartPolicy::*;
        let cases = [
            (Always, Success, true),
            (Always, Failed(1), true),
            (OnFailure, Success, false),
            (OnFailure, Failed(2), true),
            (OnFailure, Signaled(9), true),
            (OnFailure, Unknown, true),
            (Never, Failed(1), false),
            (Never, Success, false),
        ];
        for (p, e, want) in cases {
            assert_eq!(should_restart(p, e), want, "{p:?} {e:?}");
        }
    }

    #[test]
    fn backoff_doubles_caps_and_resets() {
        let mut b = Backoff::new(Duration::from_millis(100), Duration::from_millis(1000));
        let quick = Duration::from_millis(1);
        let got: Vec<u128> = (0..6).map(|_| b.next_delay(quick).as_millis()).collect();
        assert_eq!(got, [100, 200, 400, 800, 1000, 1000]);
        assert_eq!(b.next_delay(Backoff::STABLE).as_millis(), 100);
        for _ in 0..100 {
            b.next_delay(quick);
        }
        assert_eq!(b.next_delay(quick).as_millis(), 1000);
    }
}
