// SPDX-License-Identifier: MIT OR GPL-2.0-only
//
// ConfigBot process monitor: reports process exec and process exit to
// userspace through a BPF ring buffer.
//
// Attached as BTF tracepoints (tp_btf/...) so it works without tracefs.
// Kernel structs are NOT taken from a generated vmlinux.h: the few fields we
// read are declared below with preserve_access_index, and the loader (aya)
// relocates every access against the running kernel's BTF (CO-RE). This keeps
// the build independent of bpftool and of the build machine's kernel.
//
// The event layout is mirrored by `decode_event` in src/ebpf.rs; keep them in
// sync (the Rust side checks the record size).

#include <linux/types.h>
#include <linux/bpf.h>
#include <bpf/bpf_helpers.h>
#include <bpf/bpf_core_read.h>

#define TASK_COMM_LEN 16
#define FILENAME_LEN 256

#define EVENT_EXEC 1
#define EVENT_EXIT 2

typedef struct {
	int counter;
} atomic_t;

struct signal_struct {
	atomic_t live;
} __attribute__((preserve_access_index));

struct task_struct {
	int pid;
	int tgid;
	int exit_code;
	struct task_struct *real_parent;
	struct signal_struct *signal;
} __attribute__((preserve_access_index));

struct linux_binprm {
	const char *filename;
} __attribute__((preserve_access_index));

// 304 bytes, 8-byte aligned; see src/ebpf.rs.
struct event {
	__u64 ts_ns;     // bpf_ktime_get_ns(): CLOCK_MONOTONIC
	__u64 cgroup_id; // cgroup v2 id of the task (unified hierarchy)
	__u32 kind;      // EVENT_EXEC or EVENT_EXIT
	__u32 pid;       // tgid (the process id seen by userspace)
	__u32 ppid;      // tgid of real_parent
	__s32 exit_code; // wait status (exit only)
	char comm[TASK_COMM_LEN];
	char filename[FILENAME_LEN]; // exec only
};

struct {
	__uint(type, BPF_MAP_TYPE_RINGBUF);
	__uint(max_entries, 256 * 1024);
} EVENTS SEC(".maps");

// Records dropped because the ring buffer was full (index 0).
struct {
	__uint(type, BPF_MAP_TYPE_ARRAY);
	__uint(max_entries, 1);
	__type(key, __u32);
	__type(value, __u64);
} DROPPED SEC(".maps");

static __always_inline void count_drop(void)
{
	__u32 key = 0;
	__u64 *value = bpf_map_lookup_elem(&DROPPED, &key);
	if (value)
		__sync_fetch_and_add(value, 1);
}

static __always_inline struct event *reserve(struct task_struct *task, __u32 kind)
{
	struct event *e = bpf_ringbuf_reserve(&EVENTS, sizeof(struct event), 0);
	if (!e) {
		count_drop();
		return 0;
	}
	e->ts_ns = bpf_ktime_get_ns();
	e->cgroup_id = bpf_get_current_cgroup_id();
	e->kind = kind;
	e->pid = BPF_CORE_READ(task, tgid);
	e->ppid = BPF_CORE_READ(task, real_parent, tgid);
	e->exit_code = 0;
	bpf_get_current_comm(e->comm, sizeof(e->comm));
	e->filename[0] = 0;
	return e;
}

// sched_process_exec(struct task_struct *p, pid_t old_pid, struct linux_binprm *bprm)
SEC("tp_btf/sched_process_exec")
int procmon_exec(unsigned long long *ctx)
{
	struct task_struct *task = (struct task_struct *)ctx[0];
	struct linux_binprm *bprm = (struct linux_binprm *)ctx[2];
	struct event *e = reserve(task, EVENT_EXEC);
	if (!e)
		return 0;
	const char *filename = BPF_CORE_READ(bprm, filename);
	bpf_probe_read_kernel_str(e->filename, sizeof(e->filename), filename);
	bpf_ringbuf_submit(e, 0);
	return 0;
}

// sched_process_exit(struct task_struct *p, ...): fires once per exiting
// thread; report only the last thread of the group (signal->live dropped to 0
// before the tracepoint), i.e. the process exit.
SEC("tp_btf/sched_process_exit")
int procmon_exit(unsigned long long *ctx)
{
	struct task_struct *task = (struct task_struct *)ctx[0];
	if (BPF_CORE_READ(task, signal, live.counter) != 0)
		return 0;
	struct event *e = reserve(task, EVENT_EXIT);
	if (!e)
		return 0;
	e->exit_code = BPF_CORE_READ(task, exit_code);
	bpf_ringbuf_submit(e, 0);
	return 0;
}

char LICENSE[] SEC("license") = "Dual MIT/GPL";
