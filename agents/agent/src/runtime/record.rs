//! Rosbag recordings on request. The controller records the inputs of the
//! apps a remediation pauses, so the robot's situation can be replayed when
//! relearning later. A recording is `rosbag record -O <dir>/<name>-<ms>.bag
//! --size=<max MB> <topics>` against the runtime's master (rosbag stops at
//! that size), in its own process group, with its output in
//! `<dir>/<name>.log`; stopping sends SIGINT so rosbag closes the bag (it
//! writes `<file>.active` and renames it when done) and waits for its
//! recorder process as well as its wrapper, SIGKILL after [`STOP_TIMEOUT`].
//! One recording per name. Recordings live as long as the runtime: a runtime
//! that stops stops them, and one that starts stops any that a killed
//! runtime left running ([`Recordings::stop_orphans`]), so no bag grows
//! unowned.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use tokio::process::{Child, Command};
use tokio::sync::Mutex;

use crate::agent::process::send_group;
use crate::error::{Error, Result};

/// How long rosbag gets to close its bag after SIGINT.
pub const STOP_TIMEOUT: Duration = Duration::from_secs(10);

/// The recordings of one runtime.
#[derive(Debug)]
pub struct Recordings {
    dir: PathBuf,
    /// Largest bag, in MB (`rosbag record --size`; rosbag stops there);
    /// 0: no cap.
    max_mb: u64,
    active: Mutex<BTreeMap<String, Active>>,
}

#[derive(Debug)]
struct Active {
    child: Child,
    path: PathBuf,
}

/// `rosbag` on `PATH` (or Debian's `/usr/bin/rosbag`), if installed.
pub fn find_rosbag() -> Option<PathBuf> {
    std::env::var_os("PATH")
        .into_iter()
        .flat_map(|p| std::env::split_paths(&p).collect::<Vec<_>>())
        .chain([PathBuf::from("/usr/bin")])
        .map(|d| d.join("rosbag"))
        .find(|p| p.is_file())
}

/// Longest recording name (the file name adds `-<ms>.bag`, within 255 bytes).
pub const MAX_NAME: usize = 200;

/// A recording name becomes a file name: letters, digits, `.`, `_`, `-`,
/// at most [`MAX_NAME`], not starting with `.`.
pub fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= MAX_NAME
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'))
}

impl Recordings {
    /// Recordings under `dir` (created on first use), each bag at most
    /// `max_mb` MB (0: no cap).
    pub fn new(dir: PathBuf, max_mb: u64) -> Recordings {
        Recordings {
            dir,
            max_mb,
            active: Mutex::new(BTreeMap::new()),
        }
    }

    /// Starts recording `topics` as `name` against `master_uri`: the bag's
    /// path and whether this call started it. `None` when there is nothing
    /// to record or rosbag is not installed; a recording of that name
    /// already running is kept and its file returned.
    pub async fn start(
        &self,
        name: &str,
        topics: &[String],
        master_uri: &str,
    ) -> Result<Option<(PathBuf, bool)>> {
        if !valid_name(name) {
            return Err(Error::InvalidRecording(format!(
                "recording name {name:?}: use letters, digits, '.', '_' and '-' (at most {MAX_NAME})"
            )));
        }
        if let Some(t) = topics.iter().find(|t| !t.starts_with('/')) {
            return Err(Error::InvalidRecording(format!(
                "topic {t:?} is not a global ROS name"
            )));
        }
        let mut active = self.active.lock().await;
        if let Some(a) = active.get(name) {
            return Ok(Some((a.path.clone(), false)));
        }
        let (Some(rosbag), false) = (find_rosbag(), topics.is_empty()) else {
            return Ok(None);
        };
        let io = |e: std::io::Error, path: &Path| Error::Io {
            path: path.to_path_buf(),
            source: e,
        };
        std::fs::create_dir_all(&self.dir).map_err(|e| io(e, &self.dir))?;
        // Canonical, as `stop_orphans` finds it in the command line.
        let dir = std::fs::canonicalize(&self.dir).map_err(|e| io(e, &self.dir))?;
        let path = dir.join(format!("{name}-{}.bag", super::unix_ms()));
        let log_path = dir.join(format!("{name}.log"));
        let log = crate::spawn::open_log(&log_path)?;
        let err = log.try_clone().map_err(|e| io(e, &log_path))?;
        let mut cmd = Command::new(&rosbag);
        cmd.arg("record")
            .arg("-O")
            .arg(&path)
            .args((self.max_mb > 0).then(|| format!("--size={}", self.max_mb)))
            .args(topics)
            .env("ROS_MASTER_URI", master_uri)
            .env("ROS_HOME", &dir)
            .stdin(std::process::Stdio::null())
            .stdout(log)
            .stderr(err)
            .process_group(0)
            .kill_on_drop(false);
        // Stopped by SIGINT, so that it closes its bag.
        crate::spawn::default_stop_signals(&mut cmd);
        if std::env::var_os("ROS_HOSTNAME").is_none() && std::env::var_os("ROS_IP").is_none() {
            cmd.env("ROS_HOSTNAME", "localhost");
        }
        let child = cmd.spawn().map_err(|e| io(e, &rosbag))?;
        active.insert(
            name.to_owned(),
            Active {
                child,
                path: path.clone(),
            },
        );
        Ok(Some((path, true)))
    }

    /// Stops recording `name`; the bag's path, or `None` if none was
    /// running or it wrote no bag (stopped before rosbag had opened it: a
    /// recorder starts in a second or two, longer on a busy machine).
    pub async fn stop(&self, name: &str) -> Option<PathBuf> {
        let a = self.active.lock().await.remove(name)?;
        finish(a).await
    }

    /// Stops (SIGINT, so their bags close) the `rosbag record` processes
    /// writing into this directory that no runtime owns: those of a runtime
    /// that was killed. Call before the first [`Recordings::start`].
    pub async fn stop_orphans(&self, proc_root: &Path) {
        let Ok(dir) = std::fs::canonicalize(&self.dir) else {
            return; // never recorded here
        };
        let orphans: Vec<u32> = crate::procfs::list_procs(proc_root)
            .into_iter()
            .filter(|p| is_recorder_in(&p.cmdline, &dir))
            .map(|p| p.pid)
            .collect();
        for pid in &orphans {
            // Each recorder leads its own process group (see `start`).
            send_group(*pid, libc::SIGINT);
        }
        // Gone, or a zombie (`read_proc` is `None` for both).
        let deadline = tokio::time::Instant::now() + STOP_TIMEOUT;
        while orphans
            .iter()
            .any(|p| crate::procfs::read_proc(proc_root, *p).is_some())
            && tokio::time::Instant::now() < deadline
        {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// Stops every recording (runtime shutdown).
    pub async fn stop_all(&self) {
        let all = std::mem::take(&mut *self.active.lock().await);
        for a in all.into_values() {
            finish(a).await;
        }
    }
}

/// Whether a command line (arguments joined by spaces) is a `rosbag record`
/// writing into `dir`.
fn is_recorder_in(cmdline: &str, dir: &Path) -> bool {
    let mut args = cmdline.split(' ');
    args.any(|a| a.ends_with("rosbag"))
        && cmdline.contains(" record ")
        && cmdline.contains(&format!(" -O {}/", dir.display()))
}

/// Stops a recording and waits for its processes: the bag, if rosbag wrote
/// one.
async fn finish(mut a: Active) -> Option<PathBuf> {
    let proc_root = Path::new("/proc");
    let group = a.child.id();
    // The `rosbag` wrapper (python) runs the recorder as its child and can
    // exit on SIGINT before the recorder has closed the bag (renamed
    // `<bag>.active`): wait for the recorder too.
    // Looked for before and after the signal: a wrapper that had just
    // started may spawn its recorder in between (the recorder, in the same
    // group, gets the signal too).
    let mut workers = group.map_or_else(Vec::new, |g| descendants(proc_root, g));
    if let Some(g) = group {
        send_group(g, libc::SIGINT);
        for w in descendants(proc_root, g) {
            if !workers.contains(&w) {
                workers.push(w);
            }
        }
    }
    let all_gone = async {
        let _ = a.child.wait().await;
        while workers.iter().any(|w| {
            crate::procfs::read_proc(proc_root, w.pid).is_some_and(|p| p.start_time == w.start_time)
        }) {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    };
    if tokio::time::timeout(STOP_TIMEOUT, all_gone).await.is_err() {
        if let Some(g) = group {
            send_group(g, libc::SIGKILL);
        }
        let _ = a.child.wait().await;
    }
    if a.path.is_file() {
        Some(a.path)
    } else {
        tracing::warn!(bag = %a.path.display(), "rosbag stopped before it wrote its bag");
        None
    }
}

/// Every process descending from `pid`, from `proc_root`.
fn descendants(proc_root: &Path, pid: u32) -> Vec<crate::procfs::ProcInfo> {
    let procs = crate::procfs::list_procs(proc_root);
    let mut out = Vec::new();
    let mut parents = vec![pid];
    while let Some(parent) = parents.pop() {
        for p in procs.iter().filter(|p| p.ppid == parent) {
            parents.push(p.pid);
            out.push(p.clone());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_stay_inside_the_directory() {
        assert!(valid_name("remedied-nav_1.0"));
        for bad in [
            "",
            ".hidden",
            "../x",
            "a/b",
            "a b",
            &"x".repeat(MAX_NAME + 1),
        ] {
            assert!(!valid_name(bad), "{bad:?}");
        }
    }

    #[test]
    fn recorders_are_told_by_their_output_directory() {
        let dir = Path::new("/var/lib/configbot/bags");
        let ours =
            "/usr/bin/python3 /usr/bin/rosbag record -O /var/lib/configbot/bags/x-1.bag /scan";
        assert!(is_recorder_in(ours, dir));
        assert!(!is_recorder_in(ours, Path::new("/tmp/bags")));
        let play = "/usr/bin/python3 /usr/bin/rosbag play /var/lib/configbot/bags/x-1.bag";
        assert!(!is_recorder_in(play, dir));
        assert!(!is_recorder_in(
            "vim -O /var/lib/configbot/bags/x record",
            dir
        ));
    }

    #[tokio::test]
    async fn nothing_to_record_is_no_recording() {
        let dir = tempfile::tempdir().unwrap();
        let r = Recordings::new(dir.path().join("bags"), 1);
        assert_eq!(
            r.start("x", &[], "http://localhost:1/").await.unwrap(),
            None
        );
        assert!(
            r.start("../x", &["/a".into()], "http://localhost:1/")
                .await
                .is_err()
        );
        assert!(
            r.start("x", &["a".into()], "http://localhost:1/")
                .await
                .is_err()
        );
        assert_eq!(r.stop("x").await, None);
        assert!(!dir.path().join("bags").exists());
    }
}
