//! Helpers shared by every test directory of the workspace (a
//! dev-dependency only; it depends on no other workspace crate):
//! [`wait_until`] instead of fixed sleeps, [`free_port`], private v1 `cpu`
//! cgroups removed on drop ([`CpuCgroup`]), [`require`] (a missing
//! prerequisite skips locally and fails under CI), and child-process guards
//! ([`ChildGuard`], and [`GroupChild`] with its stdout lines).

pub mod cgroup;
pub mod port;
pub mod process;
pub mod require;
pub mod wait;

pub use cgroup::{CpuCgroup, unique};
pub use port::{free_port, free_ports};
pub use process::{ChildGuard, GroupChild, kill9, which};
pub use require::{require, required, skip};
pub use wait::{Ready, TimedOut, try_wait_until, wait_until};
#[cfg(feature = "tokio")]
pub use wait::{try_wait_until_async, wait_until_async};
