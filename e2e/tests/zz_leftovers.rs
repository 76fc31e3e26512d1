//! Runs after the other test binaries (cargo runs test targets one at a time,
//! in name order): no `configbot-e2e-<pid>-*` cgroup of a finished test
//! process, and so no process inside one, may remain.

use std::path::Path;

#[test]
fn no_e2e_cgroup_or_process_is_left_behind() {
    let layout = configbot_cgroups::Layout::detect().unwrap();
    let mut left = Vec::new();
    for mount in [layout.v1_cpu, layout.v1_cpuacct, layout.v1_cpuset]
        .into_iter()
        .flatten()
    {
        for e in std::fs::read_dir(&mount).unwrap() {
            let name = e.unwrap().file_name().into_string().unwrap();
            let Some(rest) = name.strip_prefix("configbot-e2e-") else {
                continue;
            };
            let pid = rest.split('-').next().unwrap_or("");
            // A live owner (a test binary still running, e.g. another clone's) is not ours to judge.
            if pid != std::process::id().to_string() && Path::new("/proc").join(pid).exists() {
                continue;
            }
            left.push(mount.join(&name));
        }
    }
    assert!(left.is_empty(), "left behind: {left:?}");
}
