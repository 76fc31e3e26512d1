//! `configbot serve --agent` under hostile input on its network ports: the
//! 200 000-level XML-RPC nesting bomb that used to abort the whole process
//! (stack overflow) and a streamed 100 MB body to the ROS master port, and a
//! YAML nesting bomb to the API socket. Each is answered with an error, the
//! process keeps running, and both the master and the API answer the next
//! request normally.

mod common;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::os::unix::net::UnixStream;
use std::time::Duration;

const WAIT: Duration = Duration::from_secs(30);

/// Writes `head` and `body` on a fresh connection and reads the answer until
/// the server closes (or resets after answering).
fn exchange<S: Read + Write>(mut s: S, head: &str, body: &[u8]) -> String {
    s.write_all(head.as_bytes()).unwrap();
    // A refused body may be cut short by the server: that is an answer too.
    let _ = s.write_all(body);
    let mut out = Vec::new();
    let mut buf = [0u8; 8192];
    loop {
        match s.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => out.extend_from_slice(&buf[..n]),
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

fn master(port: u16) -> TcpStream {
    let s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(WAIT)).unwrap();
    s.set_write_timeout(Some(WAIT)).unwrap();
    s
}

fn post_head(len: usize) -> String {
    format!(
        "POST / HTTP/1.1\r\nHost: localhost\r\nContent-Type: text/xml\r\nContent-Length: {len}\r\nConnection: close\r\n\r\n"
    )
}

#[test]
fn nesting_bombs_and_huge_bodies_are_refused_and_serving_goes_on() {
    let mut robot = common::Robot::start();
    let port = robot.ros_port;

    let depth = 200_000;
    let bomb = format!(
        "<?xml version=\"1.0\"?><methodCall><methodName>getSystemState</methodName><params><param><value>{}{}</value></param></params></methodCall>",
        "<array>".repeat(depth),
        "</array>".repeat(depth)
    );
    let r = exchange(master(port), &post_head(bomb.len()), bomb.as_bytes());
    assert!(r.contains("<i4>-32700</i4>"), "{r}\n{}", robot.server_log());
    assert!(r.contains("nested deeper than"), "{r}");

    // 100 MB streamed in 64 KiB writes from one buffer, announced up front.
    let mut s = master(port);
    s.write_all(post_head(100 << 20).as_bytes()).unwrap();
    let chunk = vec![b' '; 64 << 10];
    for _ in 0..(100 << 20) / chunk.len() {
        if s.write_all(&chunk).is_err() {
            break;
        }
    }
    let r = exchange(s, "", b"");
    assert!(r.contains("is larger than the"), "{r}");

    let call = "<?xml version=\"1.0\"?><methodCall><methodName>getSystemState</methodName><params><param><value><string>/probe</string></value></param></params></methodCall>";
    let r = exchange(master(port), &post_head(call.len()), call.as_bytes());
    assert!(r.starts_with("HTTP/1.1 200"), "{r}");
    assert!(r.contains("<i4>1</i4>"), "{r}");

    // A YAML body nested 60 deep (it overflowed the stack before the loader's limit).
    let yaml = format!("{}{}", "[".repeat(60), "]".repeat(60));
    let api = UnixStream::connect(robot.socket()).unwrap();
    api.set_read_timeout(Some(WAIT)).unwrap();
    let r = exchange(
        api,
        &format!(
            "POST /apis/configbot.dev/v1alpha1/namespaces/default/robotstacks HTTP/1.1\r\nHost: configbot\r\nContent-Type: application/yaml\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
            yaml.len()
        ),
        yaml.as_bytes(),
    );
    assert!(r.starts_with("HTTP/1.1 400"), "{r}");

    assert!(robot.server_running(), "{}", robot.server_log());
    let out = robot.cli(&["get", "rs"]);
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stderr),
        robot.server_log()
    );
}
