//! Topic meters: a reader of the measured topic's tap ([`crate::tap`]: the
//! agent's hidden raw TCPROS subscription) that feeds arrival times and sizes
//! into a [`RateWindow`].

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use configbot_dataplane::TopicStats;

use crate::stats::RateWindow;
use crate::tcpros::Header;
use crate::upstream::{Frame, FrameSink};

/// The meter's key among its tap's readers.
pub const METER_KEY: &str = "/configbot/meter";

#[derive(Debug)]
struct Sink {
    window: Mutex<RateWindow>,
    epoch: Instant,
    messages: AtomicU64,
}

impl FrameSink for Sink {
    fn on_header(&self, _api: &str, _header: &Header) {}
    fn on_frame(&self, _api: &str, frame: Frame) {
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
}

impl Meter {
    pub fn new(window_s: f64) -> Self {
        let sink = Arc::new(Sink {
            window: Mutex::new(RateWindow::new(window_s)),
            epoch: Instant::now(),
            messages: AtomicU64::new(0),
        });
        Self { sink }
    }

    /// What the meter's tap feeds.
    pub fn reader(&self) -> Arc<dyn FrameSink> {
        self.sink.clone()
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
