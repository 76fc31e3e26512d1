//! Topic meters: a reader of the measured topic's tap ([`crate::tap`]: the
//! agent's hidden raw TCPROS subscription) that feeds arrival times and sizes
//! into a [`RateWindow`] and counts the messages with the last one's arrival
//! (the agent's `measure` reads that count), and for a type that starts with
//! a `Header` their latency: arrival minus the header's stamp.

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};
use std::time::{Instant, SystemTime, UNIX_EPOCH};

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
    /// Publishers (by API) whose type starts with a `Header`.
    stamped: BTreeSet<String>,
}

#[derive(Debug)]
struct Sink {
    arrivals: Mutex<Arrivals>,
    epoch: Instant,
}

impl FrameSink for Sink {
    fn on_header(&self, api: &str, header: &Header) {
        let stamped = header
            .get("message_definition")
            .is_some_and(|d| starts_with_header(d));
        if let Ok(mut a) = self.arrivals.lock() {
            if stamped {
                a.stamped.insert(api.to_owned());
            } else {
                a.stamped.remove(api);
            }
        }
    }
    fn on_frame(&self, api: &str, frame: Frame) {
        let now = Instant::now();
        let t = now.duration_since(self.epoch).as_secs_f64();
        if let Ok(mut a) = self.arrivals.lock() {
            a.window.record(t, frame.len());
            a.count.messages += 1;
            a.count.last_arrival = Some(now);
            if a.stamped.contains(api)
                && let Some(stamp) = header_stamp(&frame)
            {
                // The wall clock only for a stamped type's messages.
                let wall = SystemTime::now()
                    .duration_since(UNIX_EPOCH)
                    .map_or(0.0, |d| d.as_secs_f64());
                a.count.latency.record(wall - stamp);
            }
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
                stamped: BTreeSet::new(),
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

/// Whether a message definition (a publisher's `message_definition`) starts
/// with a `Header` field, so that its messages start with the header's
/// `seq`, then its stamp. Comments and blank lines are skipped; a
/// definition that starts with a constant says no (conservative: its
/// messages count without a latency).
pub fn starts_with_header(definition: &str) -> bool {
    let first = definition
        .lines()
        .map(|l| l.split('#').next().unwrap_or_default().trim())
        .find(|l| !l.is_empty());
    first.is_some_and(|l| {
        let words: Vec<&str> = l.split_whitespace().collect();
        matches!(words.as_slice(), ["Header" | "std_msgs/Header", name] if !name.contains('='))
    })
}

/// The stamp (seconds since the epoch) of a message that starts with a
/// `Header` (little-endian `seq`, `stamp.secs`, `stamp.nsecs`); `None` for a
/// frame too short to hold one or a zero stamp (never set).
pub fn header_stamp(frame: &[u8]) -> Option<f64> {
    let word = |i: usize| -> Option<u32> {
        Some(u32::from_le_bytes(frame.get(i..i + 4)?.try_into().ok()?))
    };
    let (secs, nsecs) = (word(4)?, word(8)?);
    if secs == 0 && nsecs == 0 {
        return None;
    }
    Some(f64::from(secs) + f64::from(nsecs) * 1e-9)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_definition_starts_with_a_header_only_when_its_first_field_is_one() {
        let image = "# This message contains an uncompressed image\n\nHeader header        # stamp\nuint32 height\n";
        assert!(starts_with_header(image));
        assert!(starts_with_header("std_msgs/Header header\nfloat64 x"));
        assert!(!starts_with_header("string data\n# x=y"));
        assert!(!starts_with_header(
            "uint32 seq\ntime stamp\nstring frame_id"
        ));
        assert!(
            !starts_with_header("uint8 OK=0\nHeader header"),
            "a constant first"
        );
        assert!(
            !starts_with_header("float64 x\nHeader header"),
            "not at the start"
        );
        assert!(!starts_with_header(""));
    }

    #[test]
    fn the_stamp_is_read_after_the_sequence_number() {
        let mut frame = Vec::new();
        frame.extend_from_slice(&7u32.to_le_bytes());
        frame.extend_from_slice(&1_700_000_000u32.to_le_bytes());
        frame.extend_from_slice(&250_000_000u32.to_le_bytes());
        frame.extend_from_slice(b"\x00\x00\x00\x00rest");
        assert_eq!(header_stamp(&frame), Some(1_700_000_000.25));
        assert_eq!(header_stamp(&frame[..11]), None, "too short");
        assert_eq!(header_stamp(&[0u8; 16]), None, "never stamped");
    }

    #[test]
    fn a_stamped_publisher_s_messages_are_counted_by_latency() {
        let m = Meter::new(5.0);
        let r = m.reader();
        let mut h = Header::new();
        h.insert(
            "message_definition".into(),
            "Header header\nfloat64 x".into(),
        );
        r.on_header("stamped", &h);
        h.insert("message_definition".into(), "string data".into());
        r.on_header("plain", &h);
        let now = SystemTime::now().duration_since(UNIX_EPOCH).unwrap();
        let stamped_at = |ago_ms: u64| {
            let t = now - std::time::Duration::from_millis(ago_ms);
            let mut f = 1u32.to_le_bytes().to_vec();
            f.extend_from_slice(&u32::try_from(t.as_secs()).unwrap().to_le_bytes());
            f.extend_from_slice(&t.subsec_nanos().to_le_bytes());
            f.extend_from_slice(&0u32.to_le_bytes());
            Arc::new(f)
        };
        r.on_frame("stamped", stamped_at(250));
        r.on_frame("plain", stamped_at(900));
        let c = m.messages();
        assert_eq!((c.messages, c.latency.stamped), (2, 1));
        let peak = c.latency.peak_since(&Default::default()).unwrap();
        assert!((0.2..=0.3).contains(&peak), "{peak}");
    }
}
