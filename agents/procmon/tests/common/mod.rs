//! Helpers shared by the monitor integration tests: spawning uniquely
//! identifiable real processes and waiting for their events with timeouts.

#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

use configbot_procmon::{EventStream, ProcEvent, ProcEventKind};
pub use configbot_test_support::ChildGuard;

/// A unique tag `configbot-procmon-test-<pid>-<n>`.
pub fn unique_tag() -> String {
    configbot_test_support::unique("configbot-procmon-test", '-')
}

/// A temp working dir removed on drop.
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> TempDir {
        let dir = std::env::temp_dir().join(tag);
        std::fs::create_dir_all(&dir).expect("create temp dir");
        TempDir(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Spawns `/bin/true <tag>` in `dir`.
pub fn spawn_true(dir: &TempDir, tag: &str) -> ChildGuard {
    let child = Command::new("/bin/true")
        .arg(tag)
        .current_dir(&dir.0)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn /bin/true");
    ChildGuard(child)
}

/// Receives events until `pred` matches one, or fails after `timeout`.
pub async fn wait_for(
    stream: &mut EventStream,
    timeout: Duration,
    what: &str,
    mut pred: impl FnMut(&ProcEvent) -> bool,
) -> ProcEvent {
    let deadline = tokio::time::Instant::now() + timeout;
    loop {
        match tokio::time::timeout_at(deadline, stream.recv()).await {
            Ok(Some(event)) if pred(&event) => return event,
            Ok(Some(_)) => continue,
            Ok(None) => panic!("event stream closed while waiting for {what}"),
            Err(_) => panic!("no {what} within {timeout:?}"),
        }
    }
}

pub fn is(kind: ProcEventKind, pid: u32) -> impl Fn(&ProcEvent) -> bool {
    move |e| e.kind == kind && e.pid == pid
}

/// `/bin/true` stopped by ptrace right after its exec, so even a slow monitor
/// (the /proc scan) sees it alive; [`HeldChild::release`] lets it run to exit.
/// The ptrace calls must come from the thread that spawned it (the tracer),
/// so use it from a current-thread runtime test body.
pub struct HeldChild(pub ChildGuard);

impl HeldChild {
    pub fn spawn(dir: &TempDir, tag: &str) -> HeldChild {
        use std::os::unix::process::CommandExt;
        let mut cmd = Command::new("/bin/true");
        cmd.arg(tag)
            .current_dir(&dir.0)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        // SAFETY: the hook runs in the forked child before exec and only makes
        // one async-signal-safe syscall (ptrace TRACEME).
        #[allow(unsafe_code)]
        unsafe {
            cmd.pre_exec(|| {
                if libc::ptrace(libc::PTRACE_TRACEME, 0, 0, 0) == -1 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
        let child = ChildGuard(cmd.spawn().expect("spawn /bin/true under ptrace"));
        let pid = child.0.id() as libc::pid_t;
        let mut status = 0;
        // SAFETY: waits on our own child; `status` is a valid out pointer.
        #[allow(unsafe_code)]
        let rc = unsafe { libc::waitpid(pid, &mut status, 0) };
        assert_eq!(rc, pid, "waitpid for the exec stop");
        assert!(
            libc::WIFSTOPPED(status),
            "child stopped after exec, status {status:#x}"
        );
        HeldChild(child)
    }

    pub fn pid(&self) -> u32 {
        self.0.0.id()
    }

    /// Detaches ptrace so the child runs on and exits.
    pub fn release(&mut self) {
        let pid = self.pid() as libc::pid_t;
        // SAFETY: PTRACE_DETACH of our own stopped tracee; no pointers passed.
        #[allow(unsafe_code)]
        let rc = unsafe { libc::ptrace(libc::PTRACE_DETACH, pid, 0, 0) };
        assert_eq!(rc, 0, "ptrace detach: {}", std::io::Error::last_os_error());
    }
}
