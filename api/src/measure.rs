//! What the controller asks the node to measure, and what it gets back: a
//! window of live time split into sub-windows (1 s by default), one value per
//! sub-window for each probe. The same types are the body of `POST
//! /v1/measure` and the arguments of the in-process call, so the tuning loop
//! measures an embedded and a remote robot the same way.

use serde::{Deserialize, Serialize};

/// A measurement of `probes` over `duration_ms`, split into sub-windows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct MeasureRequest {
    pub probes: Vec<Probe>,
    pub duration_ms: u64,
    #[serde(default = "default_sub_window_ms")]
    pub sub_window_ms: u64,
}

fn default_sub_window_ms() -> u64 {
    1000
}

/// One quantity to measure.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "camelCase")]
pub enum Probe {
    /// Messages per second on `topic`; with `subscriber`, the rate delivered
    /// to that node (after its adaptor, when the edge is adapted).
    #[serde(rename_all = "camelCase")]
    TopicRate {
        topic: String,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        subscriber: Option<String>,
    },
    /// CPUs used by the node's cgroup.
    #[serde(rename_all = "camelCase")]
    CpuUsage { node: String },
    /// How late `topic`'s messages arrive after the stamp in their header
    /// (a type that starts with a `Header`; the nodes that pass a frame's
    /// header on keep its camera's stamp): per sub-window, the largest of
    /// the agent's latency classes (seconds) that one of its messages
    /// exceeded, 0 when none did or none was stamped; over the whole window,
    /// the same over all of them. A pipeline that falls behind shows here
    /// before it drops a frame and its rate misses. Stamps are taken as
    /// wall-clock time: on a robot that runs on simulated time
    /// (`/use_sim_time`) the values mean nothing.
    #[serde(rename_all = "camelCase")]
    TopicLatency { topic: String },
}

/// The result of a [`MeasureRequest`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct MeasureReport {
    pub started_unix_ms: u64,
    pub duration_ms: u64,
    pub sub_window_ms: u64,
    /// One series per probe, in the request's order.
    pub series: Vec<ProbeSeries>,
}

/// The values of one probe.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct ProbeSeries {
    pub probe: Probe,
    /// One value per sub-window (Hz, CPUs or seconds of latency).
    pub values: Vec<f64>,
    /// The value over the whole window (for a topic's rate, refined by the
    /// arrivals of the messages that bound its count: finer than the
    /// sub-windows' mean for a slow topic; for a latency, its peak).
    pub mean: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn probes_are_tagged_camel_case() {
        let p = Probe::TopicRate {
            topic: "/cmd_vel".into(),
            subscriber: None,
        };
        let j = serde_json::to_string(&p).unwrap();
        assert_eq!(j, r#"{"kind":"topicRate","topic":"/cmd_vel"}"#);
        let back: MeasureRequest = serde_json::from_str(
            r#"{"probes":[{"kind":"cpuUsage","node":"/nav"}],"durationMs":3000}"#,
        )
        .unwrap();
        assert_eq!(back.sub_window_ms, 1000);
        assert_eq!(
            back.probes[0],
            Probe::CpuUsage {
                node: "/nav".into()
            }
        );
    }

    /// The bodies of `POST /v1/measure` as the agent has always read and
    /// written them.
    #[test]
    fn wire_format_is_stable() {
        let req = MeasureRequest {
            probes: vec![
                Probe::TopicRate {
                    topic: "/t".into(),
                    subscriber: Some("/b".into()),
                },
                Probe::CpuUsage { node: "/a".into() },
            ],
            duration_ms: 3000,
            sub_window_ms: 500,
        };
        let j = serde_json::to_string(&req).unwrap();
        assert_eq!(
            j,
            r#"{"probes":[{"kind":"topicRate","topic":"/t","subscriber":"/b"},{"kind":"cpuUsage","node":"/a"}],"durationMs":3000,"subWindowMs":500}"#
        );
        assert_eq!(serde_json::from_str::<MeasureRequest>(&j).unwrap(), req);
        let report = MeasureReport {
            started_unix_ms: 5,
            duration_ms: 3000,
            sub_window_ms: 1000,
            series: vec![ProbeSeries {
                probe: Probe::CpuUsage { node: "/a".into() },
                values: vec![0.5, 0.25],
                mean: 0.375,
            }],
        };
        let j = serde_json::to_string(&report).unwrap();
        assert_eq!(
            j,
            r#"{"startedUnixMs":5,"durationMs":3000,"subWindowMs":1000,"series":[{"probe":{"kind":"cpuUsage","node":"/a"},"values":[0.5,0.25],"mean":0.375}]}"#
        );
        assert_eq!(serde_json::from_str::<MeasureReport>(&j).unwrap(), report);
    }
}
