//! Free TCP ports on 127.0.0.1 for servers a test starts, never ROS's
//! default master port 11311 (a master on this machine may hold it).

/// ROS 1's default master port, never handed out.
pub const ROS_MASTER_PORT: u16 = 11311;

/// A TCP port on 127.0.0.1 that was free a moment ago (the kernel's pick),
/// never [`ROS_MASTER_PORT`].
pub fn free_port() -> u16 {
    free_ports(1)[0]
}

/// `n` distinct such ports, all bound at once while picking so that none
/// is handed out twice.
pub fn free_ports(n: usize) -> Vec<u16> {
    let mut held = Vec::with_capacity(n);
    while held.len() < n {
        let l = std::net::TcpListener::bind("127.0.0.1:0").expect("bind a port on 127.0.0.1");
        let port = l.local_addr().expect("a bound listener's address").port();
        if port != ROS_MASTER_PORT {
            held.push((port, l));
        }
    }
    held.into_iter().map(|(p, _)| p).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ports_are_distinct_bindable_and_never_the_ros_master_port() {
        let ports = free_ports(20);
        let mut sorted = ports.clone();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(sorted.len(), 20, "{ports:?}");
        assert!(!ports.contains(&ROS_MASTER_PORT));
        for p in ports {
            std::net::TcpListener::bind(("127.0.0.1", p))
                .unwrap_or_else(|e| panic!("port {p} was handed out but cannot be bound: {e}"));
        }
        assert_ne!(free_port(), ROS_MASTER_PORT);
    }
}
