//! Benchmark of the process monitors: for each kind (eBPF, proc connector,
//! /proc scan) spawns N real processes one after another and measures
//! spawn-to-Exec-event, kernel-exec-timestamp-to-event (where the monitor
//! has kernel timestamps) and kill-to-Exit-event latency (p50/p99/max), then
//! the monitor's own CPU use while idle. Prints a table and writes JSON.
//!
//! `configbot-procmon-bench [--n N] [--scan-n N] [--idle-secs S]
//!  [--scan-interval-ms MS] [--json PATH]`
//! `configbot-procmon-bench --status` prints which monitor `Auto` picks (JSON).

use std::collections::HashMap;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use configbot_procmon::{
    EventStream, MonitorConfig, MonitorKind, Preference, ProcEvent, ProcEventKind, ProcessMonitor,
    monotonic_now_ns,
};
use serde::Serialize;

const EVENT_TIMEOUT: Duration = Duration::from_secs(5);

#[derive(Debug, Clone)]
struct Args {
    n: usize,
    scan_n: usize,
    idle_secs: u64,
    scan_interval_ms: u64,
    json: String,
    status: bool,
}

fn parse_args(mut it: impl Iterator<Item = String>) -> Result<Args, String> {
    let mut args = Args {
        n: 200,
        scan_n: 40,
        idle_secs: 5,
        scan_interval_ms: 250,
        json: "configbot-procmon-bench.json".into(),
        status: false,
    };
    while let Some(flag) = it.next() {
        if flag == "--status" {
            args.status = true;
            continue;
        }
        let value = it.next().ok_or_else(|| format!("{flag} needs a value"))?;
        let num = || {
            value
                .parse::<u64>()
                .map_err(|e| format!("{flag} {value}: {e}"))
        };
        match flag.as_str() {
            "--n" => args.n = usize::try_from(num()?).map_err(|e| e.to_string())?,
            "--scan-n" => args.scan_n = usize::try_from(num()?).map_err(|e| e.to_string())?,
            "--idle-secs" => args.idle_secs = num()?,
            "--scan-interval-ms" => args.scan_interval_ms = num()?.max(1),
            "--json" => args.json = value,
            other => return Err(format!("unknown argument {other}")),
        }
    }
    Ok(args)
}

/// Nearest-rank percentiles of microsecond samples.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
struct Percentiles {
    p50_us: f64,
    p99_us: f64,
    max_us: f64,
}

fn percentiles(samples: &[f64]) -> Option<Percentiles> {
    if samples.is_empty() {
        return None;
    }
    let mut sorted = samples.to_vec();
    sorted.sort_by(f64::total_cmp);
    let rank = |p: f64| {
        let idx = ((p / 100.0) * sorted.len() as f64).ceil() as usize;
        sorted[idx.clamp(1, sorted.len()) - 1]
    };
    Some(Percentiles {
        p50_us: rank(50.0),
        p99_us: rank(99.0),
        max_us: sorted[sorted.len() - 1],
    })
}

#[derive(Debug, Serialize)]
struct KindResult {
    kind: MonitorKind,
    error: Option<String>,
    processes: usize,
    missed_exec: usize,
    missed_exit: usize,
    spawn_to_exec_event: Option<Percentiles>,
    kernel_exec_to_event: Option<Percentiles>,
    kill_to_exit_event: Option<Percentiles>,
    idle_secs: u64,
    idle_cpu_percent: Option<f64>,
    idle_events_seen: u64,
}

#[derive(Debug, Serialize)]
struct Report {
    kernel: String,
    cpus: usize,
    scan_interval_ms: u64,
    results: Vec<KindResult>,
}

/// CPU time of this whole process (all threads), ns.
fn process_cpu_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid writable timespec; the clock id is supported on Linux.
    #[allow(unsafe_code)]
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    if rc != 0 {
        return 0;
    }
    u64::try_from(ts.tv_sec).unwrap_or(0) * 1_000_000_000 + u64::try_from(ts.tv_nsec).unwrap_or(0)
}

/// Kills and reaps on drop.
struct Guard(Child);

impl Drop for Guard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Waits for `kind` of `pid`; events for other pids are kept in `early`
/// (an Exit can arrive while we look for something else).
async fn wait_event(
    stream: &mut EventStream,
    early: &mut HashMap<(u32, ProcEventKind), (ProcEvent, u64)>,
    pid: u32,
    kind: ProcEventKind,
) -> Option<(ProcEvent, u64)> {
    if let Some(hit) = early.remove(&(pid, kind)) {
        return Some(hit);
    }
    let deadline = tokio::time::Instant::now() + EVENT_TIMEOUT;
    loop {
        let event = tokio::time::timeout_at(deadline, stream.recv())
            .await
            .ok()??;
        let received = monotonic_now_ns();
        if event.pid == pid && event.kind == kind {
            return Some((event, received));
        }
        if early.len() < 10_000 {
            early.insert((event.pid, event.kind), (event, received));
        }
    }
}

fn micros(later: u64, earlier: u64) -> f64 {
    later.saturating_sub(earlier) as f64 / 1000.0
}

async fn bench_kind(kind: MonitorKind, n: usize, args: &Args) -> KindResult {
    let mut result = KindResult {
        kind,
        error: None,
        processes: n,
        missed_exec: 0,
        missed_exit: 0,
        spawn_to_exec_event: None,
        kernel_exec_to_event: None,
        kill_to_exit_event: None,
        idle_secs: args.idle_secs,
        idle_cpu_percent: None,
        idle_events_seen: 0,
    };
    let config = MonitorConfig {
        scan_interval: Duration::from_millis(args.scan_interval_ms),
        ..MonitorConfig::with_preference(Preference::Only(kind))
    };
    let (handle, mut stream) = match ProcessMonitor::start(config).await {
        Ok(started) => started,
        Err(err) => {
            result.error = Some(err.to_string());
            return result;
        }
    };
    let mut spawn_lat = Vec::new();
    let mut kernel_lat = Vec::new();
    let mut exit_lat = Vec::new();
    let mut early = HashMap::new();
    let mut seed = monotonic_now_ns() | 1;
    for _ in 0..n {
        if kind == MonitorKind::ProcScan {
            // Random phase against the scan ticks (xorshift).
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            let jitter = seed % (args.scan_interval_ms * 1000);
            tokio::time::sleep(Duration::from_micros(jitter)).await;
        }
        let before_spawn = monotonic_now_ns();
        let child = match Command::new("/bin/sleep")
            .arg("30")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
        {
            Ok(child) => Guard(child),
            Err(err) => {
                result.error = Some(format!("spawning /bin/sleep: {err}"));
                break;
            }
        };
        let pid = child.0.id();
        match wait_event(&mut stream, &mut early, pid, ProcEventKind::Exec).await {
            Some((event, received)) => {
                spawn_lat.push(micros(received, before_spawn));
                if kind != MonitorKind::ProcScan {
                    kernel_lat.push(micros(received, event.timestamp_ns));
                }
            }
            None => result.missed_exec += 1,
        }
        if kind == MonitorKind::ProcScan {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            let jitter = seed % (args.scan_interval_ms * 1000);
            tokio::time::sleep(Duration::from_micros(jitter)).await;
        }
        let before_kill = monotonic_now_ns();
        drop(child); // SIGKILL + reap
        match wait_event(&mut stream, &mut early, pid, ProcEventKind::Exit).await {
            Some((_, received)) => exit_lat.push(micros(received, before_kill)),
            None => result.missed_exit += 1,
        }
        early.clear();
    }
    result.spawn_to_exec_event = percentiles(&spawn_lat);
    result.kernel_exec_to_event = percentiles(&kernel_lat);
    result.kill_to_exit_event = percentiles(&exit_lat);

    // Idle: drain whatever the rest of the machine does, measure our CPU.
    let cpu0 = process_cpu_ns();
    let wall0 = monotonic_now_ns();
    let end = tokio::time::Instant::now() + Duration::from_secs(args.idle_secs);
    while let Ok(Some(_)) = tokio::time::timeout_at(end, stream.recv()).await {
        result.idle_events_seen += 1;
    }
    let cpu = process_cpu_ns().saturating_sub(cpu0) as f64;
    let wall = monotonic_now_ns().saturating_sub(wall0).max(1) as f64;
    result.idle_cpu_percent = Some(100.0 * cpu / wall);
    handle.stop().await;
    result
}

fn fmt_p(p: Option<Percentiles>) -> String {
    p.map_or_else(
        || "-".to_owned(),
        |p| format!("{:.0}/{:.0}/{:.0}", p.p50_us, p.p99_us, p.max_us),
    )
}

fn print_table(report: &Report) {
    println!(
        "process monitor latency (us, p50/p99/max), kernel {}, {} cpus, scan interval {} ms",
        report.kernel, report.cpus, report.scan_interval_ms
    );
    println!(
        "{:<15} {:>5} {:>7} {:>22} {:>22} {:>22} {:>9} {:>8}",
        "monitor",
        "n",
        "missed",
        "spawn->exec event",
        "kernel exec->event",
        "kill->exit event",
        "idle cpu%",
        "idle ev"
    );
    for r in &report.results {
        if let Some(err) = &r.error {
            println!("{:<15} failed: {err}", r.kind.label());
            if r.spawn_to_exec_event.is_none() {
                continue;
            }
        }
        println!(
            "{:<15} {:>5} {:>7} {:>22} {:>22} {:>22} {:>9} {:>8}",
            r.kind.label(),
            r.processes,
            r.missed_exec + r.missed_exit,
            fmt_p(r.spawn_to_exec_event),
            fmt_p(r.kernel_exec_to_event),
            fmt_p(r.kill_to_exit_event),
            r.idle_cpu_percent
                .map_or_else(|| "-".to_owned(), |c| format!("{c:.3}")),
            r.idle_events_seen
        );
    }
}

async fn status() -> Result<(), String> {
    let (handle, _stream) = ProcessMonitor::start(MonitorConfig::default())
        .await
        .map_err(|e| e.to_string())?;
    let out = serde_json::json!({
        "active": handle.kind(),
        "label": handle.label(),
        "failed": handle.status().failed,
        "summary": handle.status().summary(),
    });
    println!("{out}");
    Ok(())
}

async fn run(args: Args) -> Result<(), String> {
    if args.status {
        return status().await;
    }
    let mut results = Vec::new();
    for kind in MonitorKind::ALL {
        let n = if kind == MonitorKind::ProcScan {
            args.scan_n
        } else {
            args.n
        };
        eprintln!("benchmarking {kind} with {n} processes ...");
        results.push(bench_kind(kind, n, &args).await);
    }
    let report = Report {
        kernel: std::fs::read_to_string("/proc/sys/kernel/osrelease")
            .unwrap_or_default()
            .trim()
            .to_owned(),
        cpus: std::thread::available_parallelism().map_or(1, |n| n.get()),
        scan_interval_ms: args.scan_interval_ms,
        results,
    };
    print_table(&report);
    let json = serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?;
    std::fs::write(&args.json, json).map_err(|e| format!("writing {}: {e}", args.json))?;
    println!("wrote {}", args.json);
    Ok(())
}

fn main() -> std::process::ExitCode {
    let args = match parse_args(std::env::args().skip(1)) {
        Ok(args) => args,
        Err(err) => {
            eprintln!("configbot-procmon-bench: {err}");
            return std::process::ExitCode::from(2);
        }
    };
    let runtime = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(err) => {
            eprintln!("configbot-procmon-bench: tokio runtime: {err}");
            return std::process::ExitCode::FAILURE;
        }
    };
    match runtime.block_on(run(args)) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("configbot-procmon-bench: {err}");
            std::process::ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_percentiles() {
        let samples: Vec<f64> = (1..=100).map(f64::from).collect();
        let p = percentiles(&samples).expect("some");
        assert_eq!((p.p50_us, p.p99_us, p.max_us), (50.0, 99.0, 100.0));
        let one = percentiles(&[7.0]).expect("some");
        assert_eq!((one.p50_us, one.p99_us), (7.0, 7.0));
        assert_eq!(percentiles(&[]), None);
    }

    #[test]
    fn args_parse_and_reject() {
        let a = parse_args(
            ["--n", "5", "--json", "x.json"]
                .map(String::from)
                .into_iter(),
        )
        .expect("parses");
        assert_eq!((a.n, a.json.as_str()), (5, "x.json"));
        assert!(parse_args(["--bogus", "1"].map(String::from).into_iter()).is_err());
        assert!(parse_args(["--n"].map(String::from).into_iter()).is_err());
    }
}
