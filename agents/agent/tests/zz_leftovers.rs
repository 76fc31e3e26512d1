//! Runs after the other test binaries (cargo runs test targets one at a time,
//! in name order): no `configbot-agtest-<pid>-*` cgroup of a finished test
//! process, and so no process inside one, may remain.

#[test]
fn no_test_cgroup_or_process_is_left_behind() {
    let layout = configbot_cgroups::Layout::detect().unwrap();
    let mounts: Vec<_> = [layout.v1_cpu, layout.v1_cpuacct]
        .into_iter()
        .flatten()
        .collect();
    let left = configbot_test_support::cgroup::leftovers(&mounts, "configbot-agtest");
    assert!(left.is_empty(), "left behind: {left:?}");
}
