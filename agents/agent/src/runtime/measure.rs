//! `measure`: reads monotonic counters (messages received by a topic meter,
//! messages an adaptor forwarded to its subscriber, CPU nanoseconds of a node
//! cgroup) at every sub-window boundary and turns the differences into
//! honest per-sub-window values: count in the sub-window ÷ its length. The
//! length is the scheduled one when both readings came within
//! [`TIMER_SLACK`] of their boundary (timer jitter, not the topic), else the
//! measured one ([`snap`]). A counter that does not exist (topic not in the graph, subscriber
//! not subscribed) counts nothing: a starved topic is 0 Hz, not an error.
//! Each reading names its source (topic meter or adaptor), so a sub-window in
//! which the source changed counts nothing rather than mixing two counters.
//! The arithmetic is pure ([`series`]); the reading is in
//! [`NodeRuntime::measure`].

use std::time::{Duration, Instant};

use configbot_api::graph::EdgeId;
use configbot_api::measure::{MeasureReport, MeasureRequest, Probe, ProbeSeries};
use configbot_cgroups::NodeName;
use configbot_dataplane::DataPlane;

use super::NodeRuntime;
use crate::error::{Error, Result};

/// Longest window accepted (one hour) and most sub-windows.
const MAX_DURATION_MS: u64 = 3_600_000;
const MAX_SUB_WINDOWS: u64 = 10_000;
/// How long a topic meter started by this request may take to connect.
const METER_WARMUP: Duration = Duration::from_secs(3);

/// How late a reading may come after its scheduled boundary and still count
/// as taken at it. Readings come 0.1–1 ms late (tokio's timer has 1 ms
/// resolution); divided by the measured length, a second that received 25
/// messages read 24.98 Hz and missed a 25 Hz target. Measured on the real
/// nodelet stack: 8 of the 10 missed windows of its tuned rows were such
/// 25-message seconds. The count itself is exact to one message, so 5 ms
/// (0.5 % of a 1 s sub-window) changes no value by more than the count's own
/// resolution; a reading later than that (a starved agent) keeps its
/// measured time.
pub const TIMER_SLACK: f64 = 0.005;

/// What one probe reads.
#[derive(Debug, Clone)]
enum Counter {
    /// Messages received by the topic's meter.
    Topic(String),
    /// Messages forwarded to `subscriber` (adaptor), or the topic's count
    /// when the edge has no adaptor (the subscriber then gets everything).
    Delivered(EdgeId),
    /// CPU nanoseconds used by a node's cgroup.
    Cpu(NodeName),
}

impl Counter {
    /// Units per count: messages → messages, ns → CPU-seconds.
    fn scale(&self) -> f64 {
        match self {
            Counter::Topic(_) | Counter::Delivered(_) => 1.0,
            Counter::Cpu(_) => 1e-9,
        }
    }
}

/// One counter reading: which source (e.g. topic meter = 0, adaptor = 1)
/// and its value.
pub type Reading = Option<(u8, u64)>;

/// Values per sub-window and over the whole window from counter readings
/// taken at `times` (seconds from the start; `times[0]` is the start).
/// `None` is a counter that could not be read at that moment. A sub-window
/// counts `b - a` when both ends read the same source; nothing when either
/// end is missing or the source changed; and the new value when the counter
/// went backwards (recreated, e.g. a reconnected adaptor). Pure.
pub fn series(times: &[f64], readings: &[Reading], scale: f64) -> (Vec<f64>, f64) {
    let delta = |a: Reading, b: Reading| -> u64 {
        match (a, b) {
            (Some((sa, a)), Some((sb, b))) if sa == sb => {
                if b >= a {
                    b - a
                } else {
                    b
                }
            }
            _ => 0,
        }
    };
    let mut values = Vec::with_capacity(times.len().saturating_sub(1));
    let mut total = 0.0;
    for i in 1..times.len().min(readings.len()) {
        #[allow(clippy::cast_precision_loss)]
        let d = delta(readings[i - 1], readings[i]) as f64 * scale;
        total += d;
        let dt = times[i] - times[i - 1];
        values.push(if dt > 0.0 { d / dt } else { 0.0 });
    }
    let span = times.last().copied().unwrap_or(0.0) - times.first().copied().unwrap_or(0.0);
    let mean = if span > 0.0 { total / span } else { 0.0 };
    (values, mean)
}

/// The times to divide by (pure): each reading's measured time (seconds from
/// the start), or its scheduled boundary when it came at most
/// [`TIMER_SLACK`] after it.
pub fn snap(measured: &[f64], scheduled_ms: &[u64]) -> Vec<f64> {
    measured
        .iter()
        .zip(scheduled_ms)
        .map(|(&m, &b)| {
            #[allow(clippy::cast_precision_loss)]
            let b = b as f64 / 1000.0;
            if (m - b).abs() <= TIMER_SLACK { b } else { m }
        })
        .collect()
}

/// Sub-window boundaries (ms from the start) of a request, checked.
pub fn boundaries(req: &MeasureRequest) -> Result<Vec<u64>> {
    let bad = |m: String| Err(Error::InvalidMeasure(m));
    if req.duration_ms == 0 || req.duration_ms > MAX_DURATION_MS {
        return bad(format!(
            "durationMs {} must be in 1..={MAX_DURATION_MS}",
            req.duration_ms
        ));
    }
    if req.sub_window_ms == 0 || req.sub_window_ms > req.duration_ms {
        return bad(format!(
            "subWindowMs {} must be in 1..=durationMs ({})",
            req.sub_window_ms, req.duration_ms
        ));
    }
    if req.duration_ms.div_ceil(req.sub_window_ms) > MAX_SUB_WINDOWS {
        return bad(format!("more than {MAX_SUB_WINDOWS} sub-windows"));
    }
    let mut b: Vec<u64> = (0..)
        .map(|k| k * req.sub_window_ms)
        .take_while(|t| *t < req.duration_ms)
        .collect();
    b.push(req.duration_ms);
    Ok(b)
}

impl NodeRuntime {
    /// Measures `req.probes` over `req.duration_ms` of live time (blocks for
    /// the window). TopicRate: messages per second received by the agent's
    /// meter on the topic; with `subscriber`, the messages delivered to that
    /// subscriber (after its adaptor when the edge is adapted). CpuUsage:
    /// CPUs used by the node's cgroup. An unknown node is an error; a topic
    /// without messages (or publishers) measures 0 Hz.
    pub(super) async fn measure_window(&self, req: &MeasureRequest) -> Result<MeasureReport> {
        let bounds = boundaries(req)?;
        let stack_nodes = crate::state::stack_nodes(&self.agent().stack());
        let mut counters = Vec::with_capacity(req.probes.len());
        for p in &req.probes {
            counters.push(match p {
                Probe::CpuUsage { node } => {
                    let n = NodeName::new(node)?;
                    if !stack_nodes.contains(&n) {
                        return Err(Error::UnknownNode(node.clone()));
                    }
                    Counter::Cpu(n)
                }
                Probe::TopicRate { topic, subscriber } => {
                    if self.data_plane().is_none() {
                        return Err(Error::NoDataPlane {
                            what: format!("topic rate of {topic}"),
                        });
                    }
                    match subscriber {
                        None => Counter::Topic(topic.clone()),
                        Some(s) => Counter::Delivered(EdgeId {
                            topic: topic.clone(),
                            subscriber: s.clone(),
                        }),
                    }
                }
            });
        }
        self.warm_up_meters(&counters).await;

        let started_unix_ms = super::unix_ms();
        let t0 = Instant::now();
        let mut times = Vec::with_capacity(bounds.len());
        let mut readings: Vec<Vec<Reading>> = vec![Vec::new(); counters.len()];
        for b in &bounds {
            tokio::time::sleep_until((t0 + Duration::from_millis(*b)).into()).await;
            let now = t0.elapsed().as_secs_f64();
            for (r, c) in readings.iter_mut().zip(&counters) {
                r.push(self.read(c));
            }
            times.push(now);
        }
        let times = snap(&times, &bounds);
        let mut out = Vec::with_capacity(counters.len());
        for ((probe, c), r) in req.probes.iter().zip(&counters).zip(&readings) {
            let (values, mean) = series(&times, r, c.scale());
            if let Probe::TopicRate { topic, subscriber } = probe {
                self.metrics_topic_rate(topic, subscriber.as_deref(), mean);
            }
            out.push(ProbeSeries {
                probe: probe.clone(),
                values,
                mean,
            });
        }
        Ok(MeasureReport {
            started_unix_ms,
            duration_ms: req.duration_ms,
            sub_window_ms: req.sub_window_ms,
            series: out,
        })
    }

    /// Starts the meters of topics not measured before and waits (bounded)
    /// until each has a message, so the first sub-window does not count the
    /// meter's connection time as silence. Meters stay up afterwards.
    async fn warm_up_meters(&self, counters: &[Counter]) {
        let Some(dp) = self.data_plane() else {
            return;
        };
        let mut fresh: Vec<String> = Vec::new();
        for c in counters {
            let topic = match c {
                Counter::Topic(t) => t,
                Counter::Delivered(e) => &e.topic,
                Counter::Cpu(_) => continue,
            };
            if dp.topic_messages(topic).is_ok() && self.mark_metered(topic) {
                fresh.push(topic.clone());
            }
        }
        let deadline = Instant::now() + METER_WARMUP;
        while !fresh.is_empty() && Instant::now() < deadline {
            fresh.retain(|t| dp.topic_messages(t).is_ok_and(|n| n == 0));
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    fn read(&self, c: &Counter) -> Reading {
        match c {
            Counter::Cpu(n) => self
                .agent()
                .backend()
                .stats(n)
                .ok()
                .map(|s| (SRC_CGROUP, s.usage_ns)),
            Counter::Topic(t) => self
                .data_plane()?
                .topic_messages(t)
                .ok()
                .map(|n| (SRC_METER, n)),
            Counter::Delivered(e) => {
                let dp = self.data_plane()?;
                delivered(dp.as_ref(), e)
            }
        }
    }
}

const SRC_CGROUP: u8 = 0;
const SRC_METER: u8 = 1;
const SRC_ADAPTOR: u8 = 2;

/// Messages delivered to an edge's subscriber so far: the adaptor's
/// forwarded counter when the edge is adapted; else, while the node
/// subscribes to the topic, the topic's count (it gets every message);
/// else nothing.
fn delivered(dp: &dyn DataPlane, e: &EdgeId) -> Reading {
    if dp.adaptors().contains_key(e) {
        return dp
            .adaptor_counters()
            .get(e)
            .map(|c| (SRC_ADAPTOR, c.forwarded));
    }
    let subscribed = dp
        .graph()
        .topics
        .get(&e.topic)
        .is_some_and(|t| t.subscribers.contains(&e.subscriber));
    if !subscribed {
        return None;
    }
    dp.topic_messages(&e.topic).ok().map(|n| (SRC_METER, n))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn per_window_counts_over_measured_lengths() {
        let times = [0.0, 1.0, 2.0, 3.5];
        let r = [
            Some((1, 100)),
            Some((1, 130)),
            Some((1, 160)),
            Some((1, 160)),
        ];
        let (v, mean) = series(&times, &r, 1.0);
        assert_eq!(v, vec![30.0, 30.0, 0.0]);
        assert!((mean - 60.0 / 3.5).abs() < 1e-12);
    }

    #[test]
    fn missing_and_reset_counters() {
        let times = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        // appears in window 2 (nothing known before: 0), counts 30,
        // recreated (reset to 5), source switches (adaptor → meter): 0, gone
        let r = [
            None,
            Some((2, 70)),
            Some((2, 100)),
            Some((2, 5)),
            Some((1, 9000)),
            Some((1, 9030)),
            None,
        ];
        let (v, mean) = series(&times, &r, 1.0);
        assert_eq!(v, vec![0.0, 30.0, 5.0, 0.0, 30.0, 0.0]);
        assert!((mean - 65.0 / 6.0).abs() < 1e-12);
        let (v, mean) = series(&[0.0, 2.0], &[Some((0, 0)), Some((0, 1_000_000_000))], 1e-9);
        assert_eq!((v, mean), (vec![0.5], 0.5));
    }

    #[test]
    fn readings_within_the_timer_slack_count_at_their_boundary() {
        // 25 messages in a second whose readings came 0.2 and 0.9 ms late:
        // 25 Hz, not 24.98 (which misses a 25 Hz target).
        let times = snap(&[0.0002, 1.0009, 2.3], &[0, 1000, 2000]);
        assert_eq!(times, vec![0.0, 1.0, 2.3]);
        let (v, _) = series(&times, &[Some((1, 0)), Some((1, 25)), Some((1, 55))], 1.0);
        assert_eq!(v[0], 25.0);
        // A reading 300 ms late (a starved agent) keeps its measured time.
        assert!((v[1] - 30.0 / 1.3).abs() < 1e-9);
    }

    #[test]
    fn boundaries_cover_the_window() {
        let req = |d, s| MeasureRequest {
            probes: vec![],
            duration_ms: d,
            sub_window_ms: s,
        };
        assert_eq!(boundaries(&req(3000, 1000)).unwrap(), [0, 1000, 2000, 3000]);
        assert_eq!(boundaries(&req(2500, 1000)).unwrap(), [0, 1000, 2000, 2500]);
        assert!(boundaries(&req(0, 1000)).is_err());
        assert!(boundaries(&req(1000, 0)).is_err());
        assert!(boundaries(&req(1000, 2000)).is_err());
    }
}
