//! Measures the simnode's CPU models in-process (no ROS needed) and prints
//! tables, writing JSON with `--out PATH`:
//! 1. CPU-cost accuracy: requested vs consumed thread CPU time and wall time;
//! 2. periodic publisher: achieved vs requested rate as the cost grows;
//! 3. shared worker pool: a 20 Hz, 2 ms core callback beside a 10 Hz heavy
//!    callback of growing cost, with 1 and 2 workers.
//!
//! Usage: configbot-simnode-bench [--secs S] [--out PATH]

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use configbot_simnode::burn::{burn, thread_cpu_time};
use configbot_simnode::dispatch::{Callback, Dispatcher, Incoming, Pool};
use configbot_simnode::node::publisher_loop;
use configbot_simnode::publish::Topic;
use configbot_simnode::{CallbackSpec, PublishSpec};

fn cost_accuracy() -> Vec<(f64, f64, f64)> {
    let stop = AtomicBool::new(false);
    [1.0, 2.0, 5.0, 10.0, 25.0, 50.0]
        .into_iter()
        .map(|ms| {
            let n = 10;
            let (c0, w0) = (thread_cpu_time(), Instant::now());
            for _ in 0..n {
                burn(Duration::from_secs_f64(ms / 1000.0), &stop);
            }
            let cpu = (thread_cpu_time() - c0).as_secs_f64() * 1000.0 / f64::from(n);
            let wall = w0.elapsed().as_secs_f64() * 1000.0 / f64::from(n);
            (ms, cpu, wall)
        })
        .collect()
}

fn publisher(hz: f64, cost_ms: f64, secs: f64) -> f64 {
    let topic = Arc::new(Topic::default());
    let stop = Arc::new(AtomicBool::new(false));
    let spec = PublishSpec {
        topic: "/bench".into(),
        hz,
        bytes: 64,
    };
    let (t, s) = (topic.clone(), stop.clone());
    let cost = Duration::from_secs_f64(cost_ms / 1000.0);
    let h = std::thread::spawn(move || publisher_loop(spec, t, cost, s));
    std::thread::sleep(Duration::from_secs_f64(0.5));
    let (n0, t0) = (topic.published(), Instant::now());
    std::thread::sleep(Duration::from_secs_f64(secs));
    let rate = (topic.published() - n0) as f64 / t0.elapsed().as_secs_f64();
    stop.store(true, Ordering::Relaxed);
    let _ = h.join();
    rate
}

fn pool(heavy_ms: f64, workers: usize, secs: f64) -> anyhow::Result<f64> {
    let stop = Arc::new(AtomicBool::new(false));
    let spec = |cost_ms| CallbackSpec {
        input: "/in".into(),
        output: "/out".into(),
        cost_ms,
        bytes: Some(16),
    };
    let core = Arc::new(Callback::new(spec(2.0), Arc::new(Topic::default())));
    let heavy = Arc::new(Callback::new(spec(heavy_ms), Arc::new(Topic::default())));
    let d = Dispatcher::Pool(Pool::start(
        vec![core.clone(), heavy],
        workers,
        stop.clone(),
    )?);
    let msg = || Incoming {
        body: vec![0; 28],
        at: Instant::now(),
    };
    let (t0, mut k) = (Instant::now(), 0u32);
    let mut n0 = None;
    // Core input every 50 ms, heavy input every 100 ms; 0.5 s warm-up.
    while t0.elapsed().as_secs_f64() < secs + 0.5 {
        if n0.is_none() && t0.elapsed() >= Duration::from_millis(500) {
            n0 = Some((core.done.load(Ordering::Relaxed), Instant::now()));
        }
        d.deliver(0, msg());
        if k % 2 == 0 {
            d.deliver(1, msg());
        }
        k += 1;
        let next = t0 + Duration::from_millis(50) * k;
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
    }
    let (n0, t1) = n0.context("bench window never started")?;
    let rate = (core.done.load(Ordering::Relaxed) - n0) as f64 / t1.elapsed().as_secs_f64();
    stop.store(true, Ordering::Relaxed);
    d.shutdown();
    Ok(rate)
}

fn main() -> anyhow::Result<()> {
    let mut secs = 2.0;
    let mut out = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--secs" => secs = args.next().context("--secs needs a value")?.parse()?,
            "--out" => out = Some(args.next().context("--out needs a path")?),
            other => anyhow::bail!("unknown argument {other} (usage: --secs S --out PATH)"),
        }
    }
    let mut json = String::from("{\n");

    println!("CPU cost accuracy (10 calls each)\n requested ms | thread CPU ms | wall ms");
    let acc = cost_accuracy();
    for (ms, cpu, wall) in &acc {
        println!(" {ms:>12.1} | {cpu:>12.3} | {wall:>7.2}");
    }
    let rows: Vec<String> = acc
        .iter()
        .map(|(r, c, w)| format!("{{\"requested_ms\":{r},\"cpu_ms\":{c:.4},\"wall_ms\":{w:.3}}}"))
        .collect();
    json += &format!("  \"cost_accuracy\": [{}],\n", rows.join(","));

    println!("\nPeriodic publisher at 40 Hz\n cost ms | demand CPU | achieved Hz");
    let mut rows = Vec::new();
    for cost in [0.0, 5.0, 10.0, 20.0, 30.0, 40.0] {
        let r = publisher(40.0, cost, secs);
        println!(" {cost:>7.1} | {:>10.2} | {r:>11.1}", 40.0 * cost / 1000.0);
        rows.push(format!(
            "{{\"requested_hz\":40,\"cost_ms\":{cost},\"achieved_hz\":{r:.2}}}"
        ));
    }
    json += &format!("  \"publisher\": [{}],\n", rows.join(","));

    println!(
        "\nShared pool: core 20 Hz x 2 ms beside heavy 10 Hz x C ms\n heavy ms | core Hz, 1 worker | core Hz, 2 workers"
    );
    let mut rows = Vec::new();
    for heavy in [0.0, 40.0, 80.0, 100.0, 150.0] {
        let (one, two) = (pool(heavy, 1, secs)?, pool(heavy, 2, secs)?);
        println!(" {heavy:>8.1} | {one:>17.1} | {two:>18.1}");
        rows.push(format!(
            "{{\"heavy_ms\":{heavy},\"core_hz_1_worker\":{one:.2},\"core_hz_2_workers\":{two:.2}}}"
        ));
    }
    json += &format!("  \"pool\": [{}]\n}}\n", rows.join(","));
    if let Some(p) = out {
        std::fs::write(&p, json).with_context(|| format!("writing {p}"))?;
    }
    Ok(())
}
