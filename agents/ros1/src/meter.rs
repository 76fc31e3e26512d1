//! Topic meters: a hidden raw TCPROS subscriber (`/configbot/meter`) per
//! measured topic that feeds arrival times and sizes into a [`RateWindow`].

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use configbot_dataplane::TopicStats;

use crate::stats::RateWindow;
use crate::tcpros::Header;
use crate::upstream::{FrameSink, UpstreamSet};

/// Caller id the meters use towards publishers.
pub const METER_CALLER_ID: &str = "/configbot/meter";

#[derive(Debug)]
struct Sink {
    window: Mutex<RateWindow>,
    epoch: Instant,
    messages: AtomicU64,
}

impl FrameSink for Sink {
    fn on_header(&self, _api: &str, _header: &Header) {}
    fn on_frame(&self, _api: &str, frame: Vec<u8>) {
        self.messages.fetch_add(1, Ordering::Relaxed);
        let t = self.epoch.elapsed().as_secs_f64();
        if let Ok(mut w) = self.window.lock() {
            w.record(t, frame.len());
        }
    }
}

/// One measured topic.
#[derive(Debug)]
pub struct Meter {
    sink: Arc<Sink>,
    pub upstream: UpstreamSet,
}

impl Meter {
    pub fn new(topic: &str, window_s: f64, timeout: Duration) -> Self {
        let sink = Arc::new(Sink {
            window: Mutex::new(RateWindow::new(window_s)),
            epoch: Instant::now(),
            messages: AtomicU64::new(0),
        });
        let upstream = UpstreamSet::new(METER_CALLER_ID, topic, sink.clone(), timeout);
        Self { sink, upstream }
    }

    /// Messages received since the meter started.
    pub fn messages(&self) -> u64 {
        self.sink.messages.load(Ordering::Relaxed)
    }

    pub fn stats(&self) -> Option<TopicStats> {
        let now = self.sink.epoch.elapsed().as_secs_f64();
        self.sink.window.lock().ok()?.stats(now)
    }
}
