//! Which cgroup hierarchies exist and where: parsed from `/proc/self/mountinfo`
//! by filesystem type (`cgroup` = v1, `cgroup2` = v2).

use std::path::PathBuf;

/// The kind of hierarchy found on the host.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HierarchyKind {
    /// Only v1 controllers.
    V1,
    /// Only the unified v2 hierarchy.
    V2,
    /// v1 controllers plus a v2 mount (as on this machine).
    Hybrid,
}

/// Mount points of the hierarchies the agent may use.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Layout {
    /// v1 hierarchy carrying the `cpu` controller.
    pub v1_cpu: Option<PathBuf>,
    /// v1 hierarchy carrying `cpuacct` (often the same as `cpu`).
    pub v1_cpuacct: Option<PathBuf>,
    /// v1 hierarchy carrying `cpuset`.
    pub v1_cpuset: Option<PathBuf>,
    /// The cgroup2 mount, if any.
    pub unified: Option<PathBuf>,
}

impl Layout {
    /// Parses mountinfo text. Unknown or malformed lines are skipped.
    pub fn from_mountinfo(text: &str) -> Self {
        let mut layout = Self::default();
        for line in text.lines() {
            let Some((left, right)) = line.split_once(" - ") else {
                continue;
            };
            let Some(mount_point) = left.split_whitespace().nth(4) else {
                continue;
            };
            let mut r = right.split_whitespace();
            let (Some(fstype), Some(_source), Some(super_opts)) = (r.next(), r.next(), r.next())
            else {
                continue;
            };
            let path = PathBuf::from(unescape_mount(mount_point));
            match fstype {
                "cgroup2" => layout.unified.get_or_insert(path),
                "cgroup" => {
                    for opt in super_opts.split(',') {
                        let slot = match opt {
                            "cpu" => &mut layout.v1_cpu,
                            "cpuacct" => &mut layout.v1_cpuacct,
                            "cpuset" => &mut layout.v1_cpuset,
                            _ => continue,
                        };
                        slot.get_or_insert_with(|| path.clone());
                    }
                    continue;
                }
                _ => continue,
            };
        }
        layout
    }

    /// Reads `/proc/self/mountinfo`.
    pub fn detect() -> std::io::Result<Self> {
        Ok(Self::from_mountinfo(&std::fs::read_to_string(
            "/proc/self/mountinfo",
        )?))
    }

    /// V1, V2 or hybrid; `None` when no cgroup filesystem is mounted.
    pub fn kind(&self) -> Option<HierarchyKind> {
        let v1 = self.v1_cpu.is_some() || self.v1_cpuacct.is_some() || self.v1_cpuset.is_some();
        match (v1, self.unified.is_some()) {
            (true, true) => Some(HierarchyKind::Hybrid),
            (true, false) => Some(HierarchyKind::V1),
            (false, true) => Some(HierarchyKind::V2),
            (false, false) => None,
        }
    }
}

/// mountinfo escapes space, tab, newline and backslash as octal.
fn unescape_mount(s: &str) -> String {
    s.replace("\\040", " ")
        .replace("\\011", "\t")
        .replace("\\012", "\n")
        .replace("\\134", "\\")
}

#[cfg(test)]
mod tests {
    use super::*;

    const HYBRID: &str = "\
31 23 0:28 / /sys/fs/cgroup rw,relatime - tmpfs tmpfs rw,mode=755
32 31 0:29 / /sys/fs/cgroup/cpu rw,relatime - cgroup cgroup rw,cpu
33 31 0:30 / /sys/fs/cgroup/cpuacct rw,relatime - cgroup cgroup rw,cpuacct
34 31 0:31 / /sys/fs/cgroup/cpuset rw,relatime - cgroup cgroup rw,cpuset
35 31 0:32 / /sys/fs/cgroup/memory rw,relatime - cgroup cgroup rw,memory
41 31 0:38 / /sys/fs/cgroup/unified rw,relatime - cgroup2 cgroup2 rw
";

    #[test]
    fn detects_hybrid_v1_and_v2() {
        let l = Layout::from_mountinfo(HYBRID);
        assert_eq!(l.kind(), Some(HierarchyKind::Hybrid));
        assert_eq!(l.v1_cpu.as_deref(), Some("/sys/fs/cgroup/cpu".as_ref()));
        assert_eq!(
            l.v1_cpuacct.as_deref(),
            Some("/sys/fs/cgroup/cpuacct".as_ref())
        );
        assert_eq!(
            l.unified.as_deref(),
            Some("/sys/fs/cgroup/unified".as_ref())
        );

        let v1 =
            "25 20 0:22 / /sys/fs/cgroup/cpu,cpuacct rw shared:9 - cgroup cgroup rw,cpu,cpuacct\n";
        let l = Layout::from_mountinfo(v1);
        assert_eq!(l.kind(), Some(HierarchyKind::V1));
        assert_eq!(l.v1_cpu, l.v1_cpuacct);

        let v2 = "29 23 0:26 / /sys/fs/cgroup rw,nosuid shared:4 - cgroup2 cgroup2 rw,nsdelegate\n";
        let l = Layout::from_mountinfo(v2);
        assert_eq!(l.kind(), Some(HierarchyKind::V2));
        assert_eq!(Layout::from_mountinfo("junk\n").kind(), None);
    }

    #[test]
    fn memory_hierarchy_is_never_picked() {
        let l = Layout::from_mountinfo(
            "35 31 0:32 / /sys/fs/cgroup/memory rw - cgroup cgroup rw,memory\n",
        );
        assert_eq!(l, Layout::default());
    }

    #[test]
    fn this_host_parses() {
        // Whatever the host is, detection must not fail to read mountinfo.
        let l = Layout::detect().unwrap();
        assert!(l.kind().is_some(), "no cgroup fs mounted: {l:?}");
    }
}
