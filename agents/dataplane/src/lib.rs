//! Backend-neutral view of a robot's message-passing data plane: the graph
//! (nodes, topics, edges, pids), per-topic rate statistics, and per-subscriber
//! adaptors that limit the rate a single subscriber receives.
//!
//! A backend (ROS 1 today, ROS 2 later) implements [`DataPlane`]; the agent
//! daemon only talks to this trait. The data the trait speaks in (graph,
//! stats, edges, adaptor settings) is plain wire data in
//! [`configbot_api::graph`], re-exported here as the trait's vocabulary; the
//! adaptor selection policy is the pure [`configbot_api::policy`].

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

// The trait's vocabulary: the types its methods take and return, and what
// those are made of.
pub use configbot_api::graph::{
    AdaptorSetting, Edge, EdgeCounters, EdgeId, Graph, GraphEvent, NodeInfo, TopicInfo, TopicStats,
};

/// Errors of a data-plane backend.
#[derive(Debug, thiserror::Error)]
pub enum DataPlaneError {
    #[error("unknown topic {0}")]
    UnknownTopic(String),
    #[error("no subscriber {subscriber} on topic {topic}")]
    UnknownEdge { topic: String, subscriber: String },
    #[error("invalid adaptor rate {0} (must be finite and > 0)")]
    InvalidRate(f64),
    #[error("data plane backend failed: {message}")]
    Backend {
        message: String,
        #[source]
        source: Option<Box<dyn std::error::Error + Send + Sync>>,
    },
}

/// What a backend's thread runs as it starts. A backend meters the
/// metrics, so it runs on threads of its own, and the agent gives them a
/// cgroup of their own through such a hook (`configbot-cgroups`'
/// `ThreadPlacement`).
pub type ThreadHook = Arc<dyn Fn() + Send + Sync>;

/// The hooks of a backend's two kinds of threads, by their job: the ones
/// that stamp messages as they arrive (meters, and the backend's own
/// servers) and the ones that copy messages for adapted subscribers
/// (relays). The agent gives the first the largest CPU weight and the
/// second a node's (`configbot-cgroups`' `AgentThreads`). `None`: the
/// threads stay where they start.
#[derive(Clone, Default)]
pub struct ThreadHooks {
    pub metering: Option<ThreadHook>,
    pub relaying: Option<ThreadHook>,
}

impl std::fmt::Debug for ThreadHooks {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ThreadHooks")
            .field("metering", &self.metering.is_some())
            .field("relaying", &self.relaying.is_some())
            .finish()
    }
}

/// A topic meter's reading: how many messages it has received, and when the
/// last of them arrived (`None` before the first). Read together, so the
/// count and the arrival belong to the same message: `n` messages counted
/// between two readings arrived in the interval between their two
/// `last_arrival`s, which measures a slow topic's rate below the one
/// message a count over a fixed window can resolve.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MessageCount {
    pub messages: u64,
    pub last_arrival: Option<Instant>,
    /// The stamped ones among them, by latency.
    pub latency: LatencyCounts,
}

/// The latency classes (ms) a meter counts stamped messages in. A message's
/// latency is its arrival (wall clock) minus the stamp in its header, which
/// the nodes that pass a camera frame's header on keep: the time the frame
/// took through them. Finer around a 30 Hz frame period (33 ms) and the
/// few periods a node's queue holds, where a pipeline falls behind and then
/// drops frames.
pub const LATENCY_BOUNDS_MS: [u32; 12] = [10, 20, 33, 50, 67, 100, 133, 167, 200, 300, 500, 1000];

/// Cumulative counts of a meter's stamped messages by latency: monotonic,
/// like the message count, so two readings give the classes of the
/// messages that arrived between them ([`LatencyCounts::peak_since`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LatencyCounts {
    /// Messages whose header carried a stamp.
    pub stamped: u64,
    /// `later_than[i]`: stamped messages later than [`LATENCY_BOUNDS_MS`]`[i]`.
    pub later_than: [u64; LATENCY_BOUNDS_MS.len()],
}

impl LatencyCounts {
    /// Counts one stamped message that arrived `latency_s` seconds after
    /// its stamp (negative: a clock ahead of ours, counted as on time).
    pub fn record(&mut self, latency_s: f64) {
        self.stamped += 1;
        let ms = latency_s * 1000.0;
        for (n, &b) in self.later_than.iter_mut().zip(&LATENCY_BOUNDS_MS) {
            if ms > f64::from(b) {
                *n += 1;
            }
        }
    }

    /// The largest bound (seconds) that some message counted since
    /// `earlier` was later than: a lower bound of their peak latency, 0 when
    /// none was later than the first. `None` when no stamped message came
    /// in between, or the counts went backwards (a new meter).
    pub fn peak_since(&self, earlier: &LatencyCounts) -> Option<f64> {
        if self.stamped <= earlier.stamped {
            return None;
        }
        let mut peak = 0.0;
        for ((now, before), &b) in self
            .later_than
            .iter()
            .zip(&earlier.later_than)
            .zip(&LATENCY_BOUNDS_MS)
        {
            if now < before {
                return None;
            }
            if now > before {
                peak = f64::from(b) / 1000.0;
            }
        }
        Some(peak)
    }
}

/// A backend of the data plane. Methods are cheap and non-blocking: IO runs
/// in the backend's own tasks, on the backend's own threads.
pub trait DataPlane: Send + Sync {
    /// The current graph, with pids known so far.
    fn graph(&self) -> Graph;
    /// Rate statistics of `topic` as seen by a plain subscriber. The first
    /// call starts measuring; `Ok(None)` until enough messages arrived.
    fn topic_stats(&self, topic: &str) -> Result<Option<TopicStats>, DataPlaneError>;
    /// Messages the topic's meter has received since it started (the first
    /// call starts it, like [`DataPlane::topic_stats`]), with the arrival of
    /// the last one: a monotonic counter, so callers get exact counts over
    /// any interval from two readings, and the arrivals that bound them.
    fn topic_messages(&self, topic: &str) -> Result<MessageCount, DataPlaneError> {
        Err(DataPlaneError::Backend {
            message: format!("message counts of {topic} are not supported by this backend"),
            source: None,
        })
    }
    /// Rate statistics of what an adaptor forwards to its subscriber.
    fn edge_stats(&self, edge: &EdgeId) -> Option<TopicStats>;
    /// Puts an adaptor on `edge` (if none) and sets its rate; applies to a
    /// running subscriber without reconnecting when the adaptor exists.
    fn set_adaptor(&self, edge: &EdgeId, setting: AdaptorSetting) -> Result<(), DataPlaneError>;
    /// Removes the adaptor: the subscriber is pointed back at the publishers.
    fn remove_adaptor(&self, edge: &EdgeId) -> Result<(), DataPlaneError>;
    /// Adapted edges and their settings.
    fn adaptors(&self) -> BTreeMap<EdgeId, AdaptorSetting>;
    /// Counters of every adaptor.
    fn adaptor_counters(&self) -> BTreeMap<EdgeId, EdgeCounters>;
    /// Graph change events from now on.
    fn subscribe_events(&self) -> tokio::sync::broadcast::Receiver<GraphEvent>;
    /// Refreshes the graph (pids, liveness) now instead of at the next period.
    fn wake(&self);
    /// Where the middleware's clients connect (ROS 1: the master URI), for
    /// status and tools such as rosbag.
    fn uri(&self) -> &str;
    /// The environment a node the agent starts needs to join this data plane
    /// (ROS 1: `ROS_MASTER_URI`); a node's own setting of a variable wins.
    fn node_env(&self) -> Vec<(String, String)>;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_peak_between_two_readings_is_the_largest_bound_a_message_between_them_passed() {
        let mut c = LatencyCounts::default();
        c.record(0.005);
        c.record(0.140);
        let first = c;
        assert_eq!(first.stamped, 2);
        assert_eq!(
            first.later_than[0], 1,
            "only the 140 ms one is later than 10 ms"
        );
        assert_eq!(first.peak_since(&LatencyCounts::default()), Some(0.133));
        c.record(0.030);
        c.record(-0.002);
        assert_eq!(
            c.peak_since(&first),
            Some(0.020),
            "30 ms: later than 20, not 33"
        );
        let second = c;
        c.record(0.002);
        assert_eq!(
            c.peak_since(&second),
            Some(0.0),
            "on time: below every bound"
        );
        assert_eq!(c.peak_since(&c), None, "nothing stamped in between");
        c.record(5.0);
        assert_eq!(c.peak_since(&second), Some(1.0), "past the last bound");
        assert_eq!(
            LatencyCounts::default().peak_since(&first),
            None,
            "went backwards"
        );
    }
}
