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
//! The value over the whole window of a topic meter is refined by the
//! arrivals of the messages that bound its count ([`by_arrivals`]): a count
//! over a fixed window resolves one message (0.2 Hz in a 5 s trial, a fifth
//! of a 1 Hz objective), while the messages counted between two readings
//! arrived in the interval between the arrivals of the last message before
//! each. A topic's latency is read from the same meter's cumulative latency
//! classes ([`latency_series`]). The arithmetic is pure ([`series`],
//! [`latency_series`]); the reading is in [`NodeRuntime::measure`].

use std::time::{Duration, Instant};

use configbot_api::graph::EdgeId;
use configbot_api::measure::{MeasureReport, MeasureRequest, Probe, ProbeSeries};
use configbot_cgroups::NodeName;
use configbot_dataplane::{DataPlane, LatencyCounts, MessageCount};

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
    /// The latency classes of the messages received by the topic's meter.
    Latency(String),
}

impl Counter {
    /// Units per count: messages → messages, ns → CPU-seconds.
    fn scale(&self) -> f64 {
        match self {
            Counter::Topic(_) | Counter::Delivered(_) | Counter::Latency(_) => 1.0,
            Counter::Cpu(_) => 1e-9,
        }
    }
}

/// One counter reading: which source (e.g. topic meter or adaptor), its
/// value and, for a topic meter, when the last message it counted arrived
/// (seconds from the window's start: negative before it) and its messages'
/// latency classes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Counted {
    pub source: u8,
    pub count: u64,
    pub last_arrival: Option<f64>,
    pub latency: Option<LatencyCounts>,
}

impl Counted {
    /// A reading without arrivals (a cgroup, an adaptor).
    pub fn new(source: u8, count: u64) -> Self {
        Self {
            source,
            count,
            last_arrival: None,
            latency: None,
        }
    }

    fn of_meter(c: MessageCount, start: Instant) -> Self {
        let since = |at: Instant| {
            if at >= start {
                at.duration_since(start).as_secs_f64()
            } else {
                -start.duration_since(at).as_secs_f64()
            }
        };
        Self {
            source: SRC_METER,
            count: c.messages,
            last_arrival: c.last_arrival.map(since),
            latency: Some(c.latency),
        }
    }
}

/// A reading, or `None` for a counter that could not be read at that moment.
pub type Reading = Option<Counted>;

/// Values per sub-window and over the whole window from counter readings
/// taken at `times` (seconds from the start; `times[0]` is the start).
/// `None` is a counter that could not be read at that moment. A sub-window
/// counts `b - a` when both ends read the same source; nothing when either
/// end is missing or the source changed; and the new value when the counter
/// went backwards (recreated, e.g. a reconnected adaptor). The whole
/// window's value is refined by arrivals where the readings have them
/// ([`by_arrivals`]). Pure.
pub fn series(times: &[f64], readings: &[Reading], scale: f64) -> (Vec<f64>, f64) {
    let delta = |a: Reading, b: Reading| -> u64 {
        match (a, b) {
            (Some(a), Some(b)) if a.source == b.source => {
                if b.count >= a.count {
                    b.count - a.count
                } else {
                    b.count
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
    let n = times.len().min(readings.len());
    let span = if n > 1 { times[n - 1] - times[0] } else { 0.0 };
    let mean = if span > 0.0 { total / span } else { 0.0 };
    let mean = by_arrivals(&readings[..n], span).map_or(mean, |r| r * scale);
    (values, mean)
}

/// The whole window's rate from the arrivals that bound its count (pure):
/// the `n` messages counted between the first and the last reading arrived
/// after the last message of the first reading and up to the last message
/// of the last one, so `n` inter-arrival gaps span those two arrivals and
/// the rate is `n` over that time. A count over the fixed `span` says only
/// that the rate lies within one message of `n / span`; the result is held
/// within that (a topic that stopped or started within the window is not
/// rated by the stretch in which it flowed). `None` (count over the span
/// instead) when a reading is missing, has no arrival, or the counter
/// changed source or went backwards, or nothing was counted.
pub fn by_arrivals(readings: &[Reading], span: f64) -> Option<f64> {
    let (first, last) = (readings.first()?.as_ref()?, readings.last()?.as_ref()?);
    let steady = readings.windows(2).all(|w| match (w[0], w[1]) {
        (Some(a), Some(b)) => a.source == b.source && b.count >= a.count,
        _ => false,
    });
    let (a, b) = (first.last_arrival?, last.last_arrival?);
    let n = last.count.checked_sub(first.count)?;
    if !steady || n == 0 || b <= a || span <= 0.0 {
        return None;
    }
    #[allow(clippy::cast_precision_loss)]
    let n = n as f64;
    Some((n / (b - a)).clamp((n - 1.0) / span, (n + 1.0) / span))
}

/// Peak latencies per sub-window and over the whole window from a topic
/// meter's readings (pure, see [`LatencyCounts::peak_since`]): a
/// sub-window whose ends read the same meter gives the largest latency
/// class one of its messages exceeded; one without stamped messages, or
/// whose ends are missing or read different meters, gives 0 (nothing seen
/// late).
pub fn latency_series(readings: &[Reading]) -> (Vec<f64>, f64) {
    let peak = |a: &Reading, b: &Reading| -> f64 {
        match (a, b) {
            (Some(a), Some(b)) if a.source == b.source => match (a.latency, b.latency) {
                (Some(a), Some(b)) => b.peak_since(&a).unwrap_or(0.0),
                _ => 0.0,
            },
            _ => 0.0,
        }
    };
    let values: Vec<f64> = readings.windows(2).map(|w| peak(&w[0], &w[1])).collect();
    let whole = values.iter().copied().fold(0.0, f64::max);
    (values, whole)
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
                Probe::TopicLatency { topic } => {
                    self.need_data_plane(|| format!("latency of {topic}"))?;
                    Counter::Latency(topic.clone())
                }
                Probe::TopicRate { topic, subscriber } => {
                    self.need_data_plane(|| format!("topic rate of {topic}"))?;
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
                r.push(self.read(c, t0));
            }
            times.push(now);
        }
        let times = snap(&times, &bounds);
        let mut out = Vec::with_capacity(counters.len());
        for ((probe, c), r) in req.probes.iter().zip(&counters).zip(&readings) {
            let (values, mean) = match c {
                Counter::Latency(_) => latency_series(r),
                _ => series(&times, r, c.scale()),
            };
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
                Counter::Topic(t) | Counter::Latency(t) => t,
                Counter::Delivered(e) => &e.topic,
                Counter::Cpu(_) => continue,
            };
            if dp.topic_messages(topic).is_ok() && self.mark_metered(topic) {
                fresh.push(topic.clone());
            }
        }
        let deadline = Instant::now() + METER_WARMUP;
        while !fresh.is_empty() && Instant::now() < deadline {
            fresh.retain(|t| dp.topic_messages(t).is_ok_and(|c| c.messages == 0));
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// An error naming `what` needed it when the node has no data plane.
    fn need_data_plane(&self, what: impl FnOnce() -> String) -> Result<()> {
        match self.data_plane() {
            Some(_) => Ok(()),
            None => Err(Error::NoDataPlane { what: what() }),
        }
    }

    /// `c` now; arrivals in seconds from `start`, the window's start.
    fn read(&self, c: &Counter, start: Instant) -> Reading {
        match c {
            Counter::Cpu(n) => self
                .agent()
                .backend()
                .stats(n)
                .ok()
                .map(|s| Counted::new(SRC_CGROUP, s.usage_ns)),
            Counter::Topic(t) | Counter::Latency(t) => self
                .data_plane()?
                .topic_messages(t)
                .ok()
                .map(|m| Counted::of_meter(m, start)),
            Counter::Delivered(e) => {
                let dp = self.data_plane()?;
                delivered(dp.as_ref(), e, start)
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
fn delivered(dp: &dyn DataPlane, e: &EdgeId, start: Instant) -> Reading {
    if dp.adaptors().contains_key(e) {
        return dp
            .adaptor_counters()
            .get(e)
            .map(|c| Counted::new(SRC_ADAPTOR, c.forwarded));
    }
    let subscribed = dp
        .graph()
        .topics
        .get(&e.topic)
        .is_some_and(|t| t.subscribers.contains(&e.subscriber));
    if !subscribed {
        return None;
    }
    dp.topic_messages(&e.topic)
        .ok()
        .map(|m| Counted::of_meter(m, start))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(source: u8, count: u64) -> Reading {
        Some(Counted::new(source, count))
    }

    /// A meter's readings at `times`: how many of `arrivals` (seconds from
    /// the start) came by each, with the last one's arrival.
    fn metered(times: &[f64], arrivals: &[f64]) -> Vec<Reading> {
        times
            .iter()
            .map(|&t| {
                let by: Vec<f64> = arrivals.iter().copied().filter(|&a| a <= t).collect();
                Some(Counted {
                    source: SRC_METER,
                    count: by.len() as u64,
                    last_arrival: by.last().copied(),
                    latency: None,
                })
            })
            .collect()
    }

    #[test]
    fn each_sub_window_reads_the_peak_latency_of_the_messages_that_arrived_in_it() {
        let mut l = LatencyCounts::default();
        let mut at = |latencies: &[f64], source: u8| -> Reading {
            for &x in latencies {
                l.record(x);
            }
            Some(Counted {
                latency: Some(l),
                ..Counted::new(source, l.stamped)
            })
        };
        let readings = vec![
            at(&[], SRC_METER),
            at(&[0.030, 0.031], SRC_METER),
            at(&[0.150, 0.040], SRC_METER),
            at(&[], SRC_METER),
            at(&[0.5], SRC_ADAPTOR),
            None,
        ];
        let (values, whole) = latency_series(&readings);
        assert_eq!(values, vec![0.02, 0.133, 0.0, 0.0, 0.0]);
        assert_eq!(whole, 0.133, "the other meter's 500 ms is not this one's");
        let unstamped = [
            Some(Counted::new(SRC_METER, 3)),
            Some(Counted::new(SRC_METER, 9)),
        ];
        assert_eq!(latency_series(&unstamped), (vec![0.0], 0.0));
    }

    #[test]
    fn a_slow_topic_is_rated_by_its_arrivals_not_its_count() {
        // 0.7 Hz, one message 0.3 s before a 5 s window: three arrive in it
        // (0.6 Hz counted), and they span three gaps of 1/0.7 s.
        let times = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0];
        let arrivals: Vec<f64> = (0..8).map(|k| -1.7286 + f64::from(k) / 0.7).collect();
        let r = metered(&times, &arrivals);
        let (v, mean) = series(&times, &r, 1.0);
        assert!((v.iter().sum::<f64>() / 5.0 - 0.6).abs() < 1e-9, "{v:?}");
        assert!((mean - 0.7).abs() < 1e-9, "{mean}");
        // Without an arrival before the window (a fresh meter), the count.
        let r = metered(&times, &arrivals[2..]);
        assert!((series(&times, &r, 1.0).1 - 0.6).abs() < 1e-9);
    }

    #[test]
    fn arrivals_refine_a_count_but_stay_within_one_message_of_it() {
        let times = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0];
        // 30 Hz for the first second, then silence: 31 counted in 5 s. The
        // arrivals alone say 30 Hz; the window had at most 32 / 5.
        let flowed: Vec<f64> = (0..=31).map(|k| -0.02 + f64::from(k) / 30.0).collect();
        let (_, mean) = series(&times, &metered(&times, &flowed), 1.0);
        assert!((mean - 32.0 / 5.0).abs() < 1e-9, "{mean}");
        // Silent for 30 s before the window, then three messages: at least 2 / 5.
        let (_, mean) = series(&times, &metered(&times, &[-30.0, 1.0, 2.0, 4.0]), 1.0);
        assert!((mean - 2.0 / 5.0).abs() < 1e-9, "{mean}");
        // A counter that changed source keeps the count over the window.
        let mut r = metered(&times, &[-0.5, 0.5, 1.5, 2.5, 3.5, 4.5]);
        r[3] = c(SRC_ADAPTOR, 3);
        assert_eq!(by_arrivals(&r, 5.0), None);
        assert_eq!(by_arrivals(&r[..1], 0.0), None);
    }

    #[test]
    fn per_window_counts_over_measured_lengths() {
        let times = [0.0, 1.0, 2.0, 3.5];
        let r = [c(1, 100), c(1, 130), c(1, 160), c(1, 160)];
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
            c(2, 70),
            c(2, 100),
            c(2, 5),
            c(1, 9000),
            c(1, 9030),
            None,
        ];
        let (v, mean) = series(&times, &r, 1.0);
        assert_eq!(v, vec![0.0, 30.0, 5.0, 0.0, 30.0, 0.0]);
        assert!((mean - 65.0 / 6.0).abs() < 1e-12);
        let (v, mean) = series(&[0.0, 2.0], &[c(0, 0), c(0, 1_000_000_000)], 1e-9);
        assert_eq!((v, mean), (vec![0.5], 0.5));
    }

    #[test]
    fn readings_within_the_timer_slack_count_at_their_boundary() {
        // 25 messages in a second whose readings came 0.2 and 0.9 ms late:
        // 25 Hz, not 24.98 (which misses a 25 Hz target).
        let times = snap(&[0.0002, 1.0009, 2.3], &[0, 1000, 2000]);
        assert_eq!(times, vec![0.0, 1.0, 2.3]);
        let (v, _) = series(&times, &[c(1, 0), c(1, 25), c(1, 55)], 1.0);
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
