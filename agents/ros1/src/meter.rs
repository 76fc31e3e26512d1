//! Topic meters: a reader of the measured topic's tap ([`crate::tap`]: the
//! agent's hidden raw TCPROS subscription) that feeds arrival times and sizes
//! into a [`RateWindow`] and counts the messages with the last one's arrival
//! (the agent's `measure` reads that count).

use std::sync::{Arc, Mutex};
use std::time::Instant;

use configbot_dataplane::{MessageCount, TopicStats};

use crate::stats::RateWindow;
use crate::tcpros::Header;
use crate::upstream::{Frame, FrameSink};

/// The meter's key among its tap's readers.
pub const METER_KEY: &str = "/configbot/meter";

/// What the meter knows, under one lock so a reading's count and last
/// arrival belong to the same message.
#[derive(Debug)]
struct Arrivals {
    window: RateWindow,
    count: MessageCount,
}

#[derive(Debug)]
struct Sink {
    arrivals: Mutex<Arrivals>,
    epoch: Instant,
}

impl FrameSink for Sink {
    fn on_header(&self, _api: &str, _header: &Header) {}
    fn on_frame(&self, _api: &str, frame: Frame) {
        let now = Instant::now();
        let t = now.duration_since(self.epoch).as_secs_f64();
        if let Ok(mut a) = self.arrivals.lock() {
            a.window.record(t, frame.len());
            a.count.messages += 1;
            a.count.last_arrival = Some(now);
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
            arrivals: Mutex::new(Arrivals {
                window: RateWindow::new(window_s),
                count: MessageCount::default(),
            }),
            epoch: Instant::now(),
        });
        Self { sink }
    }

    /// What the meter's tap feeds.
    pub fn reader(&self) -> Arc<dyn FrameSink> {
        self.sink.clone()
    }

    /// Messages received since the meter started, and the last one's arrival.
    pub fn messages(&self) -> MessageCount {
        self.sink
            .arrivals
            .lock()
            .map(|a| a.count)
            .unwrap_or_default()
    }

    pub fn stats(&self) -> Option<TopicStats> {
        let now = self.sink.epoch.elapsed().as_secs_f64();
        self.sink.arrivals.lock().ok()?.window.stats(now)
    }
}
