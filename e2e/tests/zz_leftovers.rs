//! Runs after the other test binaries (cargo runs test targets one at a time,
//! in name order): no `configbot-e2e-<pid>-*` cgroup of a finished test
//! process, and so no process inside one, may remain.

#[test]
fn no_e2e_cgroup_or_process_is_left_behind() {
    let layout = configbot_cgroups::Layout::detect().unwrap();
    let mounts: Vec<_> = [layout.v1_cpu, layout.v1_cpuacct, layout.v1_cpuset]
        .into_iter()
        .flatten()
        .collect();
    let left = configbot_test_support::cgroup::leftovers(&mounts, "configbot-e2e");
    assert!(left.is_empty(), "left behind: {left:?}");
}
