//! Validated names: ROS node names and the agent's subtree root.
//!
//! A ROS graph name such as `/nav/planner` becomes the directory `node-nav.planner`.
//! ROS names allow only `[A-Za-z0-9_/]`, so the mapping is injective and
//! reversible; the `node-` prefix keeps directories apart from kernel control
//! files (`tasks`, `cgroup.procs`, `cpu.max`, ...). Anything else is rejected
//! before it touches the filesystem, so no name can escape the subtree.

use std::fmt;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

const DIR_PREFIX: &str = "node-";
const MAX_NAME_LEN: usize = 200;

/// A validated, global ROS node name (always starts with `/`).
#[derive(
    Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(try_from = "String", into = "String")]
pub struct NodeName(String);

impl TryFrom<String> for NodeName {
    type Error = Error;
    fn try_from(s: String) -> Result<Self> {
        Self::new(&s)
    }
}

impl From<NodeName> for String {
    fn from(n: NodeName) -> String {
        n.0
    }
}

impl NodeName {
    /// Validates a ROS node name; a relative name (`talker`) is made global (`/talker`).
    pub fn new(name: &str) -> Result<Self> {
        let bad = |reason| Error::InvalidName {
            name: name.to_owned(),
            reason,
        };
        let rel = name.strip_prefix('/').unwrap_or(name);
        if rel.is_empty() {
            return Err(bad("empty"));
        }
        if name.len() > MAX_NAME_LEN {
            return Err(bad("longer than 200 bytes"));
        }
        for seg in rel.split('/') {
            let mut chars = seg.chars();
            match chars.next() {
                None => return Err(bad("empty segment")),
                Some(c) if !c.is_ascii_alphabetic() => {
                    return Err(bad("a segment must start with a letter"));
                }
                Some(_) => {}
            }
            if !chars.all(|c| c.is_ascii_alphanumeric() || c == '_') {
                return Err(bad("only letters, digits, '_' and '/' are allowed"));
            }
        }
        Ok(Self(format!("/{rel}")))
    }

    /// The global name, e.g. `/nav/planner`.
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// The single path component of this node's cgroup, e.g. `node-nav.planner`.
    pub fn dir_name(&self) -> String {
        format!("{DIR_PREFIX}{}", self.0[1..].replace('/', "."))
    }

    /// Inverse of [`NodeName::dir_name`]; `None` for directories that are not node cgroups.
    pub fn from_dir_name(dir: &str) -> Option<Self> {
        let rest = dir.strip_prefix(DIR_PREFIX)?;
        Self::new(&rest.replace('.', "/")).ok()
    }
}

impl fmt::Display for NodeName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

/// The agent's subtree below each hierarchy's mount point, e.g. `configbot`
/// or a delegated `system.slice/configbot.service`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct SubtreeRoot(PathBuf);

impl TryFrom<String> for SubtreeRoot {
    type Error = Error;
    fn try_from(s: String) -> Result<Self> {
        Self::new(&s)
    }
}

impl From<SubtreeRoot> for String {
    fn from(r: SubtreeRoot) -> String {
        r.0.to_string_lossy().into_owned()
    }
}

impl SubtreeRoot {
    /// Validates a relative path of plain components (`[A-Za-z0-9_.@-]`, no `.`/`..`).
    pub fn new(root: &str) -> Result<Self> {
        let bad = |reason| Error::InvalidRoot {
            root: root.to_owned(),
            reason,
        };
        if root.is_empty() || root.starts_with('/') {
            return Err(bad("must be a non-empty relative path"));
        }
        for seg in root.split('/') {
            if seg.is_empty() || seg == "." || seg == ".." {
                return Err(bad("empty, '.' or '..' component"));
            }
            if !seg
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.' | '@'))
            {
                return Err(bad("only letters, digits and '_-.@' are allowed"));
            }
        }
        Ok(Self(PathBuf::from(root)))
    }

    /// The relative path.
    pub fn as_path(&self) -> &Path {
        &self.0
    }
}

impl Default for SubtreeRoot {
    fn default() -> Self {
        Self(PathBuf::from("configbot"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_names_map_to_one_safe_component() {
        let cases = [
            ("/nav/planner", Some("node-nav.planner")),
            ("talker", Some("node-talker")),
            ("/a1/b_2/c", Some("node-a1.b_2.c")),
            ("", None),
            ("/", None),
            ("..", None),
            ("/nav/../etc", None),
            ("/nav//x", None),
            ("/nav/", None),
            ("/a\0b", None),
            ("/a.b", None),
            ("/a-b", None),
            ("/1abc", None),
            ("~private", None),
            ("/tasks ", None),
        ];
        for (input, want) in cases {
            let got = NodeName::new(input).ok().map(|n| n.dir_name());
            assert_eq!(got.as_deref(), want, "input {input:?}");
        }
        assert!(NodeName::new(&format!("/{}", "a".repeat(300))).is_err());
    }

    #[test]
    fn dir_name_round_trips() {
        for n in ["/nav/planner", "/talker", "/x/y/z_1"] {
            let name = NodeName::new(n).unwrap();
            assert_eq!(NodeName::from_dir_name(&name.dir_name()), Some(name));
        }
        assert_eq!(NodeName::from_dir_name("tasks"), None);
        assert_eq!(NodeName::from_dir_name("cgroup.procs"), None);
        assert_eq!(NodeName::from_dir_name("node-"), None);
    }

    #[test]
    fn subtree_roots_are_relative_and_plain() {
        for ok in [
            "configbot",
            "system.slice/configbot.service",
            "configbot-test-1-2",
        ] {
            assert!(SubtreeRoot::new(ok).is_ok(), "{ok}");
        }
        for bad in ["", "/abs", "a/../b", "..", "a//b", "a b", "a/./b"] {
            assert!(SubtreeRoot::new(bad).is_err(), "{bad:?}");
        }
    }
}
