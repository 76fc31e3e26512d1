//! Fallback monitor on the netlink proc connector (`NETLINK_CONNECTOR`,
//! multicast group `CN_IDX_PROC`): subscribes with `PROC_CN_MCAST_LISTEN`,
//! waits for the kernel's acknowledgement, then turns `PROC_EVENT_EXEC` and
//! `PROC_EVENT_EXIT` (of thread-group leaders) into [`ProcEvent`]s. Works
//! only from the initial pid and user namespaces (the kernel silently ignores
//! other subscribers: we then fail on the missing ack); older kernels need
//! CAP_NET_ADMIN, newer ones (6.18 here) also accept unprivileged listeners.
//! Exec events carry only pids, so `comm`, `ppid`,
//! `filename` (`/proc/<pid>/exe`) and `cgroup` are read from /proc on receipt.
//!
//! The socket calls are raw `libc` (no extra crate); message bytes are built
//! and parsed by the pure functions below.

use std::collections::HashMap;
use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

use tokio::io::Interest;
use tokio::io::unix::AsyncFd;
use tokio::sync::mpsc;

use crate::event::{MonitorKind, ProcEvent, ProcEventKind, read_cgroup, read_exe, read_stat};
use crate::{MonitorConfig, Shared, Started};

const CN_IDX_PROC: u32 = 1;
const CN_VAL_PROC: u32 = 1;
const PROC_CN_MCAST_LISTEN: u32 = 1;
const PROC_CN_MCAST_IGNORE: u32 = 2;
const PROC_EVENT_NONE: u32 = 0;
const PROC_EVENT_EXEC: u32 = 2;
const PROC_EVENT_EXIT: u32 = 0x8000_0000;
const NLMSG_HDRLEN: usize = 16;
const CN_MSG_LEN: usize = 20;
/// Offset of `struct proc_event` in a datagram.
const EVENT_OFFSET: usize = NLMSG_HDRLEN + CN_MSG_LEN;
/// Offset of `proc_event.event_data`.
const DATA_OFFSET: usize = EVENT_OFFSET + 16;
/// How long to wait for the kernel to acknowledge the subscription.
const ACK_TIMEOUT: Duration = Duration::from_secs(2);
/// Exec'd pids remembered (for the comm of their exit); cleared when exceeded.
const CACHE_LIMIT: usize = 65_536;

/// Errors of the proc connector monitor.
#[derive(Debug, thiserror::Error)]
pub enum ConnectorError {
    #[error("opening a NETLINK_CONNECTOR socket")]
    Socket(#[source] io::Error),
    #[error(
        "binding the netlink socket to the proc connector group (CAP_NET_ADMIN on older kernels)"
    )]
    Bind(#[source] io::Error),
    #[error("sending the proc connector subscription")]
    Subscribe(#[source] io::Error),
    #[error("receiving from the proc connector")]
    Receive(#[source] io::Error),
    #[error("registering the netlink socket with the Tokio reactor")]
    Reactor(#[source] io::Error),
    #[error("the kernel refused the proc connector subscription (errno {0})")]
    Refused(u32),
    #[error("no acknowledgement of the proc connector subscription within {0:?}")]
    NoAck(Duration),
}

/// One decoded proc connector message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Message {
    Ack {
        seq: u32,
        ack: u32,
        err: u32,
    },
    Exec {
        pid: u32,
        tgid: u32,
        ts_ns: u64,
    },
    Exit {
        pid: u32,
        tgid: u32,
        exit_code: u32,
        parent_tgid: u32,
        ts_ns: u64,
    },
}

/// A `PROC_CN_MCAST_*` control datagram (netlink header + cn_msg + op).
/// `token` goes into `cn_msg.seq` and `cn_msg.ack`; the kernel's
/// acknowledgement (multicast to every listener) carries `ack = token + 1`
/// (its `seq` is overwritten by a per-CPU counter), which is how a monitor
/// recognises its own.
pub(crate) fn control_message(op: u32, token: u32) -> Vec<u8> {
    let seq = token;
    let total = NLMSG_HDRLEN + CN_MSG_LEN + 4;
    let mut b = Vec::with_capacity(total);
    b.extend_from_slice(&(total as u32).to_ne_bytes()); // nlmsg_len
    b.extend_from_slice(&(libc::NLMSG_DONE as u16).to_ne_bytes()); // nlmsg_type
    b.extend_from_slice(&0u16.to_ne_bytes()); // nlmsg_flags
    b.extend_from_slice(&seq.to_ne_bytes()); // nlmsg_seq
    b.extend_from_slice(&0u32.to_ne_bytes()); // nlmsg_pid: kernel fills the port
    b.extend_from_slice(&CN_IDX_PROC.to_ne_bytes()); // cn_msg.id.idx
    b.extend_from_slice(&CN_VAL_PROC.to_ne_bytes()); // cn_msg.id.val
    b.extend_from_slice(&seq.to_ne_bytes()); // cn_msg.seq
    b.extend_from_slice(&token.to_ne_bytes()); // cn_msg.ack
    b.extend_from_slice(&4u16.to_ne_bytes()); // cn_msg.len
    b.extend_from_slice(&0u16.to_ne_bytes()); // cn_msg.flags
    b.extend_from_slice(&op.to_ne_bytes());
    b
}

/// Decodes the netlink messages of one datagram; unknown events are skipped.
pub(crate) fn parse_datagram(buf: &[u8]) -> Vec<Message> {
    let mut out = Vec::new();
    let mut offset = 0;
    while let Some(msg) = buf.get(offset..) {
        let Some(len) = read_u32(msg, 0).map(|l| l as usize) else {
            break;
        };
        if len < NLMSG_HDRLEN || len > msg.len() {
            break;
        }
        if let Some(m) = msg.get(..len).and_then(parse_message) {
            out.push(m);
        }
        offset += (len + 3) & !3; // NLMSG_ALIGN
    }
    out
}

fn parse_message(msg: &[u8]) -> Option<Message> {
    let nl_type = u16::from_ne_bytes(msg.get(4..6)?.try_into().ok()?);
    if nl_type != libc::NLMSG_DONE as u16 {
        return None;
    }
    let idx = read_u32(msg, NLMSG_HDRLEN)?;
    let val = read_u32(msg, NLMSG_HDRLEN + 4)?;
    if (idx, val) != (CN_IDX_PROC, CN_VAL_PROC) {
        return None;
    }
    let u32_at = |o: usize| read_u32(msg, DATA_OFFSET + o);
    let ts_ns = u64::from_ne_bytes(
        msg.get(EVENT_OFFSET + 8..EVENT_OFFSET + 16)?
            .try_into()
            .ok()?,
    );
    match read_u32(msg, EVENT_OFFSET)? {
        PROC_EVENT_NONE => Some(Message::Ack {
            seq: read_u32(msg, NLMSG_HDRLEN + 8)?,
            ack: read_u32(msg, NLMSG_HDRLEN + 12)?,
            err: u32_at(0)?,
        }),
        PROC_EVENT_EXEC => Some(Message::Exec {
            pid: u32_at(0)?,
            tgid: u32_at(4)?,
            ts_ns,
        }),
        PROC_EVENT_EXIT => Some(Message::Exit {
            pid: u32_at(0)?,
            tgid: u32_at(4)?,
            exit_code: u32_at(8)?,
            parent_tgid: u32_at(20)?,
            ts_ns,
        }),
        _ => None,
    }
}

fn read_u32(b: &[u8], o: usize) -> Option<u32> {
    Some(u32::from_ne_bytes(b.get(o..o + 4)?.try_into().ok()?))
}

/// The subscribed socket; unsubscribes (best effort) when dropped.
#[derive(Debug)]
struct ConnectorSocket {
    fd: OwnedFd,
}

impl AsRawFd for ConnectorSocket {
    fn as_raw_fd(&self) -> RawFd {
        self.fd.as_raw_fd()
    }
}

impl Drop for ConnectorSocket {
    fn drop(&mut self) {
        let _ = send(
            self.fd.as_raw_fd(),
            &control_message(PROC_CN_MCAST_IGNORE, 0),
        );
    }
}

#[allow(unsafe_code)]
fn open_socket() -> Result<OwnedFd, ConnectorError> {
    // SAFETY: plain socket(2) call without pointers.
    let fd = unsafe {
        libc::socket(
            libc::AF_NETLINK,
            libc::SOCK_DGRAM | libc::SOCK_NONBLOCK | libc::SOCK_CLOEXEC,
            libc::NETLINK_CONNECTOR,
        )
    };
    if fd < 0 {
        return Err(ConnectorError::Socket(io::Error::last_os_error()));
    }
    // SAFETY: `fd` was just returned by socket(2) and is owned by nobody else.
    let fd = unsafe { OwnedFd::from_raw_fd(fd) };
    // SAFETY: all-zero bytes are a valid `sockaddr_nl` (plain integers).
    let mut addr: libc::sockaddr_nl = unsafe { std::mem::zeroed() };
    addr.nl_family = libc::AF_NETLINK as libc::sa_family_t;
    addr.nl_pid = 0; // let the kernel pick a unique port: several monitors may coexist
    addr.nl_groups = CN_IDX_PROC;
    let addr_len = std::mem::size_of::<libc::sockaddr_nl>() as libc::socklen_t;
    // SAFETY: `addr` is a valid sockaddr_nl of `addr_len` bytes that outlives the call.
    let rc = unsafe {
        libc::bind(
            fd.as_raw_fd(),
            (&raw const addr).cast::<libc::sockaddr>(),
            addr_len,
        )
    };
    if rc != 0 {
        return Err(ConnectorError::Bind(io::Error::last_os_error()));
    }
    // A bigger receive buffer rides out bursts of execs (best effort; capped by rmem_max).
    let size: libc::c_int = 1 << 20;
    // SAFETY: `size` is a valid c_int that outlives the call; the length matches.
    unsafe {
        libc::setsockopt(
            fd.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_RCVBUF,
            (&raw const size).cast::<libc::c_void>(),
            std::mem::size_of::<libc::c_int>() as libc::socklen_t,
        );
    }
    Ok(fd)
}

#[allow(unsafe_code)]
fn send(fd: RawFd, bytes: &[u8]) -> io::Result<()> {
    // SAFETY: `bytes` is valid for `bytes.len()` bytes for the duration of the call.
    let n = unsafe { libc::send(fd, bytes.as_ptr().cast(), bytes.len(), 0) };
    if n < 0 {
        Err(io::Error::last_os_error())
    } else {
        Ok(())
    }
}

#[allow(unsafe_code)]
fn recv(fd: RawFd, buf: &mut [u8]) -> io::Result<usize> {
    // SAFETY: `buf` is valid and writable for `buf.len()` bytes during the call.
    let n = unsafe { libc::recv(fd, buf.as_mut_ptr().cast(), buf.len(), 0) };
    usize::try_from(n).map_err(|_| io::Error::last_os_error())
}

/// Reads every datagram available now; returns `Ok(None)` at end-of-data.
/// `ENOBUFS` (the kernel dropped messages for us) is counted as one lost event.
fn drain(
    sock: &mut AsyncFd<ConnectorSocket>,
    buf: &mut [u8],
    shared: &Shared,
    out: &mut Vec<Message>,
) -> io::Result<()> {
    loop {
        match recv(sock.get_ref().as_raw_fd(), buf) {
            Ok(n) => out.extend(parse_datagram(buf.get(..n).unwrap_or_default())),
            Err(e) if e.raw_os_error() == Some(libc::ENOBUFS) => {
                shared.lost.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => return Ok(()),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
}

static SEQ: AtomicU32 = AtomicU32::new(1);

pub(crate) async fn start(
    config: &MonitorConfig,
    tx: mpsc::Sender<ProcEvent>,
    shared: Arc<Shared>,
) -> Result<Started, ConnectorError> {
    let fd = open_socket()?;
    let socket = ConnectorSocket { fd };
    // Unique per subscription so we recognise our own ack among other listeners'.
    let token = (std::process::id() << 12) ^ SEQ.fetch_add(1, Ordering::Relaxed);
    send(
        socket.as_raw_fd(),
        &control_message(PROC_CN_MCAST_LISTEN, token),
    )
    .map_err(ConnectorError::Subscribe)?;
    // SAFETY: the socket owns its fd, which stays open and is returned by
    // `as_raw_fd()` for as long as the AsyncFd owns the socket.
    #[allow(unsafe_code)]
    let mut sock = unsafe { AsyncFd::register_with_interest(socket, Interest::READABLE) }
        .map_err(|e| ConnectorError::Reactor(e.into_parts().1))?;

    let mut buf = vec![0u8; 16 * 1024];
    let mut pending = Vec::new();
    let deadline = tokio::time::Instant::now() + ACK_TIMEOUT;
    loop {
        let ready = tokio::time::timeout_at(deadline, sock.readable_mut()).await;
        let mut guard = match ready {
            Err(_) => return Err(ConnectorError::NoAck(ACK_TIMEOUT)),
            Ok(guard) => guard.map_err(ConnectorError::Receive)?,
        };
        guard.clear_ready();
        drop(guard);
        drain(&mut sock, &mut buf, &shared, &mut pending).map_err(ConnectorError::Receive)?;
        let ack = pending.iter().find_map(|m| match m {
            Message::Ack { ack, err, .. } if *ack == token.wrapping_add(1) => Some(*err),
            _ => None,
        });
        match ack {
            Some(0) => break,
            Some(err) => return Err(ConnectorError::Refused(err)),
            None => {}
        }
    }
    let proc_root = config.proc_root.clone();
    let task = tokio::spawn(run(sock, buf, pending, tx, shared, proc_root));
    Ok(Started {
        task,
        lost_counter: None,
    })
}

async fn run(
    mut sock: AsyncFd<ConnectorSocket>,
    mut buf: Vec<u8>,
    mut batch: Vec<Message>,
    tx: mpsc::Sender<ProcEvent>,
    shared: Arc<Shared>,
    proc_root: PathBuf,
) {
    let mut comms: HashMap<u32, String> = HashMap::new();
    loop {
        for message in batch.drain(..) {
            let Some(event) = to_event(message, &proc_root, &mut comms) else {
                continue;
            };
            if tx.send(event).await.is_err() {
                return;
            }
        }
        let mut guard = match sock.readable_mut().await {
            Ok(guard) => guard,
            Err(err) => {
                shared.fail(format!("waiting on the proc connector socket: {err}"));
                return;
            }
        };
        guard.clear_ready();
        drop(guard);
        if let Err(err) = drain(&mut sock, &mut buf, &shared, &mut batch) {
            shared.fail(crate::error_chain(&ConnectorError::Receive(err)));
            return;
        }
    }
}

/// Enriches a message from /proc; `None` for acks and non-leader thread exits.
fn to_event(
    message: Message,
    proc_root: &Path,
    comms: &mut HashMap<u32, String>,
) -> Option<ProcEvent> {
    match message {
        Message::Ack { .. } => None,
        Message::Exec { tgid, ts_ns, .. } => {
            let stat = read_stat(proc_root, tgid);
            if let Some(stat) = &stat {
                if comms.len() >= CACHE_LIMIT {
                    comms.clear();
                }
                comms.insert(tgid, stat.comm.clone());
            }
            Some(ProcEvent {
                kind: ProcEventKind::Exec,
                pid: tgid,
                ppid: stat.as_ref().map(|s| s.ppid),
                comm: stat.map(|s| s.comm),
                filename: read_exe(proc_root, tgid),
                cgroup_id: None,
                cgroup: read_cgroup(proc_root, tgid),
                exit_code: None,
                timestamp_ns: ts_ns,
                source: MonitorKind::ProcConnector,
            })
        }
        Message::Exit {
            pid,
            tgid,
            exit_code,
            parent_tgid,
            ts_ns,
        } => {
            if pid != tgid {
                return None; // a thread, not the process
            }
            Some(ProcEvent {
                kind: ProcEventKind::Exit,
                pid: tgid,
                ppid: Some(parent_tgid),
                comm: comms.remove(&tgid),
                filename: None,
                cgroup_id: None,
                cgroup: None,
                exit_code: i32::try_from(exit_code).ok(),
                timestamp_ns: ts_ns,
                source: MonitorKind::ProcConnector,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A datagram as the kernel sends it: header, cn_msg, proc_event.
    fn datagram(what: u32, seq: u32, ack: u32, data: &[u32]) -> Vec<u8> {
        let len = DATA_OFFSET + 24;
        let mut b = vec![0u8; len];
        b[0..4].copy_from_slice(&(len as u32).to_ne_bytes());
        b[4..6].copy_from_slice(&(libc::NLMSG_DONE as u16).to_ne_bytes());
        b[16..20].copy_from_slice(&CN_IDX_PROC.to_ne_bytes());
        b[20..24].copy_from_slice(&CN_VAL_PROC.to_ne_bytes());
        b[24..28].copy_from_slice(&seq.to_ne_bytes());
        b[28..32].copy_from_slice(&ack.to_ne_bytes());
        b[EVENT_OFFSET..EVENT_OFFSET + 4].copy_from_slice(&what.to_ne_bytes());
        b[EVENT_OFFSET + 8..EVENT_OFFSET + 16].copy_from_slice(&777u64.to_ne_bytes());
        for (i, v) in data.iter().enumerate() {
            b[DATA_OFFSET + 4 * i..DATA_OFFSET + 4 * i + 4].copy_from_slice(&v.to_ne_bytes());
        }
        b
    }

    #[test]
    fn control_message_layout() {
        let m = control_message(PROC_CN_MCAST_LISTEN, 9);
        assert_eq!(m.len(), 40);
        assert_eq!(read_u32(&m, 0), Some(40));
        assert_eq!(read_u32(&m, 16), Some(CN_IDX_PROC));
        assert_eq!(read_u32(&m, 24), Some(9));
        assert_eq!(read_u32(&m, 28), Some(9));
        assert_eq!(u16::from_ne_bytes([m[32], m[33]]), 4);
        assert_eq!(read_u32(&m, 36), Some(PROC_CN_MCAST_LISTEN));
    }

    #[test]
    fn parses_ack_exec_exit_and_skips_fork() {
        let mut buf = datagram(PROC_EVENT_NONE, 5, 1, &[0]);
        buf.extend(datagram(PROC_EVENT_EXEC, 0, 0, &[100, 100]));
        buf.extend(datagram(1, 0, 0, &[1, 1, 2, 2])); // fork: ignored
        buf.extend(datagram(
            PROC_EVENT_EXIT,
            0,
            0,
            &[100, 100, 256, 17, 42, 40],
        ));
        assert_eq!(
            parse_datagram(&buf),
            vec![
                Message::Ack {
                    seq: 5,
                    ack: 1,
                    err: 0
                },
                Message::Exec {
                    pid: 100,
                    tgid: 100,
                    ts_ns: 777
                },
                Message::Exit {
                    pid: 100,
                    tgid: 100,
                    exit_code: 256,
                    parent_tgid: 40,
                    ts_ns: 777
                },
            ]
        );
    }

    #[test]
    fn truncated_datagram_stops_parsing() {
        let buf = datagram(PROC_EVENT_EXEC, 0, 0, &[1, 1]);
        assert!(parse_datagram(&buf[..30]).is_empty());
        assert!(parse_datagram(&[]).is_empty());
    }

    #[test]
    fn thread_exit_is_not_a_process_exit() {
        let mut comms = HashMap::new();
        let exit = Message::Exit {
            pid: 101,
            tgid: 100,
            exit_code: 0,
            parent_tgid: 1,
            ts_ns: 1,
        };
        assert_eq!(to_event(exit, Path::new("/proc"), &mut comms), None);
    }
}
