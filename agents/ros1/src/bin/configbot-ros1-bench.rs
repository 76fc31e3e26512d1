//! Benchmark of the adaptor relay: the latency an adaptor adds (p50/p99)
//! and the relay's CPU per message, for 1 kHz small messages and 30 Hz × 1 MB
//! messages. A minimal in-process TCPROS publisher stamps each frame with its
//! send time; one subscriber connects directly, one through a pass-through
//! adaptor. CPU per message is the difference in process CPU between a run
//! with two direct subscribers and a run with one direct + one adapted.
//!
//! Usage: configbot-ros1-bench [--secs N] [--out bench.json]

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use configbot_dataplane::{AdaptorSetting, DataPlane, EdgeId};
use configbot_ros1::http::{self, BoxFut, Handler};
use configbot_ros1::tcpros::{self, Header};
use configbot_ros1::xmlrpc::{MethodCall, Response, Value};
use configbot_ros1::{Ros1Config, Ros1DataPlane};
use serde::Serialize;
use tokio::sync::broadcast;

/// Slave API of the bench publisher: answers requestTopic with its port.
struct PubSlave {
    port: u16,
}

impl Handler for PubSlave {
    fn handle(self: Arc<Self>, call: MethodCall) -> BoxFut<Response> {
        Box::pin(async move {
            let v = match call.method.as_str() {
                "requestTopic" => Value::ros(
                    1,
                    "",
                    Value::Array(vec![
                        Value::str("TCPROS"),
                        Value::str("localhost"),
                        Value::Int(i64::from(self.port)),
                    ]),
                ),
                "getPid" => Value::ros(1, "", Value::Int(i64::from(std::process::id()))),
                _ => Value::ros(1, "", Value::Int(0)),
            };
            Response::Ok(v)
        })
    }
}

/// Bench subscribers' slave API: accepts callbacks and ignores them.
struct NullSlave;

impl Handler for NullSlave {
    fn handle(self: Arc<Self>, _call: MethodCall) -> BoxFut<Response> {
        Box::pin(async { Response::Ok(Value::ros(1, "", Value::Int(0))) })
    }
}

fn cpu_seconds() -> f64 {
    // utime + stime of this process, in clock ticks (USER_HZ = 100 on Linux)
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let rest = s.rsplit_once(')').map_or("", |r| r.1);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|x| x.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

fn pct(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

#[derive(Debug, Serialize)]
struct CaseResult {
    case: String,
    rate_hz: f64,
    size_bytes: usize,
    messages: usize,
    direct_p50_us: f64,
    direct_p99_us: f64,
    adapted_p50_us: f64,
    adapted_p99_us: f64,
    added_p50_us: f64,
    added_p99_us: f64,
    relay_cpu_us_per_msg: f64,
}

struct Bench {
    dp: Ros1DataPlane,
    master: String,
    epoch: Instant,
    n: Mutex<u32>,
}

impl Bench {
    fn name(&self, p: &str) -> String {
        let mut n = self
            .n
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        *n += 1;
        format!("/bench_{p}_{}", *n)
    }

    /// Starts a publisher of `topic`; returns the frame sender.
    async fn publisher(&self, topic: &str) -> anyhow::Result<broadcast::Sender<Arc<Vec<u8>>>> {
        let (tcp, tcp_addr) = http::bind("127.0.0.1", 0).await?;
        let (xl, xaddr) = http::bind("127.0.0.1", 0).await?;
        tokio::spawn(http::serve(
            xl,
            Arc::new(PubSlave {
                port: tcp_addr.port(),
            }),
        ));
        let (tx, _) = broadcast::channel::<Arc<Vec<u8>>>(64);
        let tx2 = tx.clone();
        tokio::spawn(async move {
            while let Ok((mut s, addr)) = tcp.accept().await {
                let _ = s.set_nodelay(true);
                let mut rx = tx2.subscribe();
                tokio::spawn(async move {
                    let peer = addr.to_string();
                    if tcpros::read_header(&mut s, &peer).await.is_err() {
                        return;
                    }
                    let mut h = Header::new();
                    h.insert("type".into(), "std_msgs/UInt8MultiArray".into());
                    h.insert("md5sum".into(), "82373f1612381bb6ee473b5cd6f5d89c".into());
                    h.insert("callerid".into(), "/bench_pub".into());
                    h.insert("latching".into(), "0".into());
                    if tokio::io::AsyncWriteExt::write_all(&mut s, &tcpros::encode_header(&h))
                        .await
                        .is_err()
                    {
                        return;
                    }
                    while let Ok(f) = rx.recv().await {
                        if tcpros::write_frame(&mut s, &f, &peer).await.is_err() {
                            return;
                        }
                    }
                });
            }
        });
        let name = self.name("pub");
        let api = format!("http://localhost:{}/", xaddr.port());
        http::call(
            &self.master,
            "registerPublisher",
            &[
                Value::str(&name),
                Value::str(topic),
                Value::str("std_msgs/UInt8MultiArray"),
                Value::str(api),
            ],
            Duration::from_secs(5),
        )
        .await?;
        Ok(tx)
    }

    /// Registers a subscriber and connects it to what the master returns;
    /// latencies (µs) go to the returned vector.
    async fn subscriber(&self, topic: &str, adapted: bool) -> anyhow::Result<Arc<Mutex<Vec<f64>>>> {
        let name = self.name(if adapted { "adapted" } else { "direct" });
        if adapted {
            let edge = EdgeId {
                topic: topic.into(),
                subscriber: name.clone(),
            };
            self.dp
                .set_adaptor(&edge, AdaptorSetting { rate_hz: None })?;
        }
        let (xl, xaddr) = http::bind("127.0.0.1", 0).await?;
        tokio::spawn(http::serve(xl, Arc::new(NullSlave)));
        let api = format!("http://localhost:{}/", xaddr.port());
        let v = http::call(
            &self.master,
            "registerSubscriber",
            &[
                Value::str(&name),
                Value::str(topic),
                Value::str("std_msgs/UInt8MultiArray"),
                Value::str(api),
            ],
            Duration::from_secs(5),
        )
        .await?;
        let pubs: Vec<String> = v
            .as_array()
            .and_then(|a| a.get(2))
            .and_then(Value::as_array)
            .context("registerSubscriber reply")?
            .iter()
            .filter_map(|x| x.as_str().map(String::from))
            .collect();
        let uri = pubs.first().context("no publisher")?.clone();
        let mut c = tcpros::subscribe(&uri, &name, topic, "*", Duration::from_secs(5)).await?;
        let lat = Arc::new(Mutex::new(Vec::new()));
        let l2 = lat.clone();
        let epoch = self.epoch;
        tokio::spawn(async move {
            while let Ok(f) = tcpros::read_block(&mut c.stream, &c.peer).await {
                let now = epoch.elapsed().as_nanos() as f64;
                let mut b = [0u8; 8];
                b.copy_from_slice(&f[..8]);
                let sent = u64::from_le_bytes(b) as f64;
                if let Ok(mut l) = l2.lock() {
                    l.push((now - sent) / 1000.0);
                }
            }
        });
        Ok(lat)
    }

    async fn run_case(
        &self,
        case: &str,
        rate_hz: f64,
        size: usize,
        secs: f64,
    ) -> anyhow::Result<CaseResult> {
        // phase 1: two direct subscribers; phase 2: one direct + one adapted
        let mut cpu = Vec::new();
        let mut lats = Vec::new();
        for adapted in [false, true] {
            let topic = self.name(case);
            let tx = self.publisher(&topic).await?;
            let d = self.subscriber(&topic, false).await?;
            let o = self.subscriber(&topic, adapted).await?;
            let deadline = Instant::now() + Duration::from_secs(10);
            while tx.receiver_count() < 2 && Instant::now() < deadline {
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
            // warm-up (adaptor upstream connects lazily)
            tokio::time::sleep(Duration::from_millis(500)).await;
            let n = (rate_hz * secs) as usize;
            let period = Duration::from_secs_f64(1.0 / rate_hz);
            let mut payload = vec![0u8; size.max(8)];
            let c0 = cpu_seconds();
            let start = tokio::time::Instant::now();
            for i in 0..n {
                tokio::time::sleep_until(start + period * i as u32).await;
                let t = self.epoch.elapsed().as_nanos() as u64;
                payload[..8].copy_from_slice(&t.to_le_bytes());
                let _ = tx.send(Arc::new(payload.clone()));
            }
            tokio::time::sleep(Duration::from_millis(300)).await;
            cpu.push(cpu_seconds() - c0);
            lats.push((d, o, n));
        }
        let (d, o, n) = &lats[1];
        let mut dl = d.lock().map(|v| v.clone()).unwrap_or_default();
        let mut al = o.lock().map(|v| v.clone()).unwrap_or_default();
        let (dp50, dp99, ap50, ap99) = (
            pct(&mut dl, 0.5),
            pct(&mut dl, 0.99),
            pct(&mut al, 0.5),
            pct(&mut al, 0.99),
        );
        Ok(CaseResult {
            case: case.into(),
            rate_hz,
            size_bytes: size,
            messages: *n,
            direct_p50_us: dp50,
            direct_p99_us: dp99,
            adapted_p50_us: ap50,
            adapted_p99_us: ap99,
            added_p50_us: ap50 - dp50,
            added_p99_us: ap99 - dp99,
            relay_cpu_us_per_msg: (cpu[1] - cpu[0]) / *n as f64 * 1e6,
        })
    }
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> anyhow::Result<()> {
    let mut secs = 10.0;
    let mut out = std::path::PathBuf::from("configbot-ros1-bench.json");
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--secs" => secs = args.next().context("--secs N")?.parse()?,
            "--out" => out = args.next().context("--out PATH")?.into(),
            other => anyhow::bail!("unknown argument {other}"),
        }
    }
    let dir = tempfile_dir()?;
    let port = std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port();
    let cfg = Ros1Config {
        master_uri: format!("http://localhost:{port}/"),
        bind_host: "127.0.0.1".into(),
        ..Ros1Config::default()
    };
    let dp = Ros1DataPlane::start(cfg, &dir.join("bench.db"), &prometheus::Registry::new()).await?;
    let bench = Bench {
        master: dp.master_uri().to_string(),
        dp,
        epoch: Instant::now(),
        n: Mutex::new(0),
    };
    let results = vec![
        bench.run_case("small_1khz", 1000.0, 64, secs).await?,
        bench
            .run_case("image_30hz_1mb", 30.0, 1 << 20, secs)
            .await?,
    ];
    println!(
        "{:<16} {:>6} {:>9} {:>11} {:>11} {:>12} {:>12} {:>12} {:>12} {:>14}",
        "case",
        "msgs",
        "bytes",
        "direct p50",
        "direct p99",
        "adapted p50",
        "adapted p99",
        "added p50",
        "added p99",
        "relay cpu/msg"
    );
    for r in &results {
        println!(
            "{:<16} {:>6} {:>9} {:>9.0}us {:>9.0}us {:>10.0}us {:>10.0}us {:>10.0}us {:>10.0}us {:>12.1}us",
            r.case,
            r.messages,
            r.size_bytes,
            r.direct_p50_us,
            r.direct_p99_us,
            r.adapted_p50_us,
            r.adapted_p99_us,
            r.added_p50_us,
            r.added_p99_us,
            r.relay_cpu_us_per_msg
        );
    }
    let mut json = BTreeMap::new();
    json.insert("results", serde_json::to_value(&results)?);
    json.insert("secs_per_case", serde_json::json!(secs));
    std::fs::write(&out, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("writing {}", out.display()))?;
    println!("wrote {}", out.display());
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

fn tempfile_dir() -> anyhow::Result<std::path::PathBuf> {
    let d = std::env::temp_dir().join(format!("configbot-ros1-bench-{}", std::process::id()));
    std::fs::create_dir_all(&d)?;
    Ok(d)
}
