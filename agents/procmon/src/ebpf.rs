//! eBPF monitor: loads the C program from `bpf/procmon.bpf.c` (compiled by
//! build.rs, embedded 8-byte aligned), attaches it as BTF tracepoints
//! `sched_process_exec` / `sched_process_exit` (no tracefs needed; CO-RE
//! relocations against `/sys/kernel/btf/vmlinux`), and turns ring-buffer
//! records into [`ProcEvent`]s on a Tokio task.

// Without BPF (CONFIGBOT_PROCMON_NO_BPF=1) only the decoder's unit tests use it.
#![cfg_attr(procmon_no_bpf, allow(dead_code))]

use std::sync::Arc;

use tokio::sync::mpsc;

use crate::event::{MonitorKind, ProcEvent, ProcEventKind};
use crate::{MonitorConfig, Shared, Started};

/// Size of `struct event` in procmon.bpf.c.
pub(crate) const EVENT_SIZE: usize = 304;
const COMM_OFFSET: usize = 32;
const COMM_LEN: usize = 16;
const FILENAME_OFFSET: usize = 48;
const KIND_EXEC: u32 = 1;
const KIND_EXIT: u32 = 2;

/// Errors of the eBPF monitor.
#[derive(Debug, thiserror::Error)]
pub enum EbpfMonitorError {
    #[error("this build has no BPF object (built with CONFIGBOT_PROCMON_NO_BPF=1)")]
    NotBuilt,
    #[error("reading kernel BTF from /sys/kernel/btf/vmlinux")]
    Btf(#[source] aya::BtfError),
    #[error("loading the BPF object into the kernel")]
    Load(#[source] aya::EbpfError),
    #[error("BPF object has no program {0}")]
    MissingProgram(&'static str),
    #[error("BPF object has no map {0}")]
    MissingMap(&'static str),
    #[error("loading or attaching BPF program {program} to tp_btf/{tracepoint}")]
    Program {
        program: &'static str,
        tracepoint: &'static str,
        #[source]
        source: aya::programs::ProgramError,
    },
    #[error("opening BPF map {name}")]
    Map {
        name: &'static str,
        #[source]
        source: aya::maps::MapError,
    },
    #[error("registering the ring buffer with the Tokio reactor")]
    Reactor(#[source] std::io::Error),
}

/// A ring-buffer record decoded from the bytes of `struct event`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct RawEvent {
    pub(crate) ts_ns: u64,
    pub(crate) cgroup_id: u64,
    pub(crate) kind: ProcEventKind,
    pub(crate) pid: u32,
    pub(crate) ppid: u32,
    pub(crate) exit_code: i32,
    pub(crate) comm: String,
    pub(crate) filename: String,
}

/// Decodes one ring-buffer record (native endianness, layout of `struct event`).
pub(crate) fn decode_event(bytes: &[u8]) -> Option<RawEvent> {
    if bytes.len() < EVENT_SIZE {
        return None;
    }
    let u64_at = |o: usize| bytes.get(o..o + 8)?.try_into().ok().map(u64::from_ne_bytes);
    let u32_at = |o: usize| bytes.get(o..o + 4)?.try_into().ok().map(u32::from_ne_bytes);
    let kind = match u32_at(16)? {
        KIND_EXEC => ProcEventKind::Exec,
        KIND_EXIT => ProcEventKind::Exit,
        _ => return None,
    };
    Some(RawEvent {
        ts_ns: u64_at(0)?,
        cgroup_id: u64_at(8)?,
        kind,
        pid: u32_at(20)?,
        ppid: u32_at(24)?,
        exit_code: i32::from_ne_bytes(bytes.get(28..32)?.try_into().ok()?),
        comm: c_string(bytes.get(COMM_OFFSET..COMM_OFFSET + COMM_LEN)?),
        filename: c_string(bytes.get(FILENAME_OFFSET..EVENT_SIZE)?),
    })
}

fn c_string(bytes: &[u8]) -> String {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    String::from_utf8_lossy(bytes.get(..end).unwrap_or_default()).into_owned()
}

/// Turns a decoded record into a [`ProcEvent`]; exec events get their cgroup
/// path from /proc (if the process still exists).
pub(crate) fn to_proc_event(raw: RawEvent, proc_root: &std::path::Path) -> ProcEvent {
    let exec = raw.kind == ProcEventKind::Exec;
    ProcEvent {
        kind: raw.kind,
        pid: raw.pid,
        ppid: Some(raw.ppid),
        comm: Some(raw.comm),
        filename: exec.then_some(raw.filename),
        cgroup_id: Some(raw.cgroup_id),
        cgroup: if exec {
            crate::event::read_cgroup(proc_root, raw.pid)
        } else {
            None
        },
        exit_code: (!exec).then_some(raw.exit_code),
        timestamp_ns: raw.ts_ns,
        source: MonitorKind::Ebpf,
    }
}

#[cfg(procmon_no_bpf)]
pub(crate) use disabled::{DropCounter, start};
#[cfg(not(procmon_no_bpf))]
pub(crate) use enabled::{DropCounter, start};

#[cfg(procmon_no_bpf)]
mod disabled {
    use super::*;

    /// Placeholder: nothing to count without BPF.
    #[derive(Debug)]
    pub(crate) struct DropCounter;

    impl DropCounter {
        pub(crate) fn read(&self) -> u64 {
            0
        }
    }

    pub(crate) fn start(
        _config: &MonitorConfig,
        _tx: mpsc::Sender<ProcEvent>,
        _shared: Arc<Shared>,
    ) -> Result<Started, EbpfMonitorError> {
        Err(EbpfMonitorError::NotBuilt)
    }
}

#[cfg(not(procmon_no_bpf))]
mod enabled {
    use super::*;
    use aya::maps::{Array, MapData, RingBuf};
    use aya::programs::BtfTracePoint;
    use aya::{Btf, Ebpf, EbpfLoader};
    use std::path::PathBuf;
    use tokio::io::Interest;
    use tokio::io::unix::AsyncFd;

    static BPF_OBJECT: &[u8] =
        aya::include_bytes_aligned!(concat!(env!("OUT_DIR"), "/procmon.bpf.o"));

    const PROGRAMS: [(&str, &str); 2] = [
        ("procmon_exec", "sched_process_exec"),
        ("procmon_exit", "sched_process_exit"),
    ];

    /// Reads the BPF `DROPPED` counter (records lost to a full ring buffer).
    pub(crate) struct DropCounter(Array<MapData, u64>);

    impl std::fmt::Debug for DropCounter {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("DropCounter")
        }
    }

    impl DropCounter {
        pub(crate) fn read(&self) -> u64 {
            self.0.get(&0, 0).unwrap_or(0)
        }
    }

    pub(crate) fn start(
        config: &MonitorConfig,
        tx: mpsc::Sender<ProcEvent>,
        shared: Arc<Shared>,
    ) -> Result<Started, EbpfMonitorError> {
        let btf = Btf::from_sys_fs().map_err(EbpfMonitorError::Btf)?;
        let mut bpf = EbpfLoader::new()
            .btf(Some(&btf))
            .load(BPF_OBJECT)
            .map_err(EbpfMonitorError::Load)?;
        for (program, tracepoint) in PROGRAMS {
            let prog_err = |source| EbpfMonitorError::Program {
                program,
                tracepoint,
                source,
            };
            let prog: &mut BtfTracePoint = bpf
                .program_mut(program)
                .ok_or(EbpfMonitorError::MissingProgram(program))?
                .try_into()
                .map_err(prog_err)?;
            prog.load(tracepoint, &btf).map_err(prog_err)?;
            prog.attach().map_err(prog_err)?;
        }
        let ring = take_map(&mut bpf, "EVENTS", RingBuf::try_from)?;
        let dropped = take_map(&mut bpf, "DROPPED", Array::<MapData, u64>::try_from)?;
        // SAFETY: the RingBuf owns its map's fd; it stays open and is the
        // value of `as_raw_fd()` for as long as the RingBuf lives, i.e. for the
        // whole lifetime of the AsyncFd that takes ownership of it.
        #[allow(unsafe_code)]
        let ring = unsafe { AsyncFd::register_with_interest(ring, Interest::READABLE) }
            .map_err(|e| EbpfMonitorError::Reactor(e.into_parts().1))?;
        let proc_root = config.proc_root.clone();
        let task = tokio::spawn(run(bpf, ring, tx, shared, proc_root));
        Ok(Started {
            task,
            lost_counter: Some(DropCounter(dropped)),
        })
    }

    fn take_map<M>(
        bpf: &mut Ebpf,
        name: &'static str,
        convert: impl FnOnce(aya::maps::Map) -> Result<M, aya::maps::MapError>,
    ) -> Result<M, EbpfMonitorError> {
        let map = bpf
            .take_map(name)
            .ok_or(EbpfMonitorError::MissingMap(name))?;
        convert(map).map_err(|source| EbpfMonitorError::Map { name, source })
    }

    /// Reader loop. Owns `bpf` so the programs stay attached until the task ends.
    async fn run(
        bpf: Ebpf,
        mut ring: AsyncFd<RingBuf<MapData>>,
        tx: mpsc::Sender<ProcEvent>,
        shared: Arc<Shared>,
        proc_root: PathBuf,
    ) {
        let _attached = bpf;
        let mut batch = Vec::new();
        loop {
            let mut guard = match ring.readable_mut().await {
                Ok(guard) => guard,
                Err(err) => {
                    shared.fail(format!("waiting on the BPF ring buffer: {err}"));
                    return;
                }
            };
            let buffer = guard.get_inner_mut();
            while let Some(item) = buffer.next() {
                match decode_event(&item) {
                    Some(raw) => batch.push(raw),
                    None => {
                        shared
                            .lost
                            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    }
                }
            }
            guard.clear_ready();
            drop(guard);
            for raw in batch.drain(..) {
                if tx.send(to_proc_event(raw, &proc_root)).await.is_err() {
                    return; // receiver dropped: nobody listens any more
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(kind: u32, comm: &[u8], filename: &[u8]) -> Vec<u8> {
        let mut b = vec![0u8; EVENT_SIZE];
        b[0..8].copy_from_slice(&123_456_789u64.to_ne_bytes());
        b[8..16].copy_from_slice(&42u64.to_ne_bytes());
        b[16..20].copy_from_slice(&kind.to_ne_bytes());
        b[20..24].copy_from_slice(&1000u32.to_ne_bytes());
        b[24..28].copy_from_slice(&999u32.to_ne_bytes());
        b[28..32].copy_from_slice(&256i32.to_ne_bytes());
        b[COMM_OFFSET..COMM_OFFSET + comm.len()].copy_from_slice(comm);
        b[FILENAME_OFFSET..FILENAME_OFFSET + filename.len()].copy_from_slice(filename);
        b
    }

    #[test]
    fn decodes_exec_record() {
        let raw = decode_event(&record(KIND_EXEC, b"true\0", b"/bin/true\0junk")).expect("decodes");
        assert_eq!(raw.kind, ProcEventKind::Exec);
        assert_eq!((raw.pid, raw.ppid, raw.cgroup_id), (1000, 999, 42));
        assert_eq!(raw.ts_ns, 123_456_789);
        assert_eq!(raw.comm, "true");
        assert_eq!(raw.filename, "/bin/true");
        let event = to_proc_event(raw, std::path::Path::new("/nonexistent-proc"));
        assert_eq!(event.filename.as_deref(), Some("/bin/true"));
        assert_eq!(event.exit_code, None);
        assert_eq!(event.cgroup, None);
    }

    #[test]
    fn decodes_exit_record_with_full_comm() {
        let raw = decode_event(&record(KIND_EXIT, b"0123456789abcdef", b"")).expect("decodes");
        assert_eq!(raw.kind, ProcEventKind::Exit);
        assert_eq!(raw.comm, "0123456789abcdef");
        let event = to_proc_event(raw, std::path::Path::new("/proc"));
        assert_eq!(event.exit_code, Some(256));
        assert_eq!(event.filename, None);
    }

    #[test]
    fn rejects_short_and_unknown_records() {
        assert_eq!(decode_event(&[0u8; 10]), None);
        assert_eq!(decode_event(&record(7, b"x", b"")), None);
    }
}
