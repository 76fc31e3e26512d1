//! Pure restart decisions: whether to restart after an exit, and which run
//! counts as healthy (the delays are `configbot_api::backoff`'s).

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

/// How long a run must last to count as healthy: the restart after it
/// starts the backoff over.
pub const STABLE_RUN: Duration = Duration::from_secs(10);

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
}
