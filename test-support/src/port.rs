//! Free TCP ports on 127.0.0.1 for servers a test starts, never ROS's
//! default master port 11311 (a master on this machine may hold it).
//!
//! A port the kernel picks for `bind(…:0)` comes from the ephemeral range
//! (`net.ipv4.ip_local_port_range`), the same range every outgoing
//! connection takes its local port from: between the probe and the server's
//! own bind, another test's client could take it (`AddrInUse`). So ports
//! are drawn at random from below that range, where no connection goes,
//! each probed by binding it and none handed out twice in one process.

use std::collections::HashSet;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

/// ROS 1's default master port, never handed out.
pub const ROS_MASTER_PORT: u16 = 11311;

/// Lowest port handed out: above the well-known and most registered
/// services' ports.
const LOWEST: u16 = 12000;

/// Ports this process has handed out.
static HANDED_OUT: Mutex<Option<HashSet<u16>>> = Mutex::new(None);

/// A TCP port on 127.0.0.1 that was free a moment ago, outside the
/// ephemeral range, never [`ROS_MASTER_PORT`] and never handed out before
/// in this process.
pub fn free_port() -> u16 {
    free_ports(1)[0]
}

/// `n` distinct such ports.
pub fn free_ports(n: usize) -> Vec<u16> {
    let (lo, hi) = candidates(&ephemeral_range());
    let mut handed = HANDED_OUT.lock().unwrap_or_else(|e| e.into_inner());
    let handed = handed.get_or_insert_with(HashSet::new);
    let mut out = Vec::with_capacity(n);
    let mut tries = 0u32;
    while out.len() < n {
        tries += 1;
        assert!(
            tries < 100_000,
            "no free port on 127.0.0.1 in {lo}..{hi} after {tries} tries"
        );
        let port = lo + (next_random() % u64::from(hi - lo)) as u16;
        if port == ROS_MASTER_PORT || handed.contains(&port) {
            continue;
        }
        if std::net::TcpListener::bind(("127.0.0.1", port)).is_ok() {
            handed.insert(port);
            out.push(port);
        }
    }
    out
}

/// The kernel's ephemeral port range, `(first, last)` inclusive; Linux's
/// default when it cannot be read.
fn ephemeral_range() -> (u16, u16) {
    std::fs::read_to_string("/proc/sys/net/ipv4/ip_local_port_range")
        .ok()
        .and_then(|s| parse_range(&s))
        .unwrap_or((32768, 60999))
}

fn parse_range(s: &str) -> Option<(u16, u16)> {
    let mut it = s.split_whitespace().map(|p| p.parse::<u16>());
    match (it.next()?, it.next()?) {
        (Ok(a), Ok(b)) if a <= b => Some((a, b)),
        _ => None,
    }
}

/// The half-open range ports are drawn from (pure): below the ephemeral
/// range when there is room there (at least 4096 ports above [`LOWEST`]),
/// else above it when there is room there, else anywhere above [`LOWEST`].
fn candidates(&(first, last): &(u16, u16)) -> (u16, u16) {
    if first >= LOWEST + 4096 {
        (LOWEST, first)
    } else if last < u16::MAX - 1024 {
        (last.max(LOWEST) + 1, u16::MAX)
    } else {
        (LOWEST, u16::MAX)
    }
}

/// A splitmix64 stream seeded by the process id and the clock, so that
/// test processes running at once draw different ports.
fn next_random() -> u64 {
    static STATE: AtomicU64 = AtomicU64::new(0);
    if STATE.load(Ordering::Relaxed) == 0 {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(1, |d| d.as_nanos() as u64);
        let seed = (nanos ^ (u64::from(std::process::id()) << 32)) | 1;
        let _ = STATE.compare_exchange(0, seed, Ordering::Relaxed, Ordering::Relaxed);
    }
    let mut z = STATE
        .fetch_add(0x9E37_79B9_7F4A_7C15, Ordering::Relaxed)
        .wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ports_are_distinct_bindable_outside_the_ephemeral_range_and_never_the_ros_master_port() {
        let ports = free_ports(20);
        let mut sorted = ports.clone();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(sorted.len(), 20, "{ports:?}");
        assert!(!ports.contains(&ROS_MASTER_PORT));
        let (first, last) = ephemeral_range();
        for p in ports {
            assert!(!(first..=last).contains(&p), "{p} is in {first}..={last}");
            std::net::TcpListener::bind(("127.0.0.1", p))
                .unwrap_or_else(|e| panic!("port {p} was handed out but cannot be bound: {e}"));
        }
        let again = free_port();
        assert!(!sorted.contains(&again), "{again} was handed out twice");
    }

    #[test]
    fn ports_come_from_below_the_ephemeral_range_or_else_above_it() {
        assert_eq!(candidates(&(32768, 60999)), (LOWEST, 32768));
        assert_eq!(candidates(&(1024, 60000)), (60001, u16::MAX));
        assert_eq!(candidates(&(1024, 65535)), (LOWEST, u16::MAX));
        assert_eq!(parse_range("32768\t60999\n"), Some((32768, 60999)));
        assert_eq!(parse_range("9 3"), None);
        assert_eq!(parse_range("x"), None);
    }
}
