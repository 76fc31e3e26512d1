//! Taps: one upstream subscription per topic, shared by everything in the
//! agent that reads the topic (its meter and the relays of its adapted
//! subscribers). Each message travels once from a publisher to the agent,
//! however many readers it has there.
//!
//! Measured on a real stack (2-core VM, 2026-11-26): with a subscription per
//! relay and one per meter, the agent received the front camera's 30 Hz
//! 902x770 images four times over (three adapted subscribers and the meter
//! the knob space is measured with) and the rear camera's three times; the
//! publishers and the agent spent a fifth to a third of a core on copies
//! over loopback that nothing used.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::runtime::Handle;

use crate::core::lock;
use crate::tcpros::Header;
use crate::upstream::{Frame, FrameSink, UpstreamSet};

/// Caller id of a tap's connections to the publishers.
pub const TAP_CALLER_ID: &str = "/configbot/tap";

/// One topic's upstream connections and the readers they feed.
pub struct Tap {
    upstream: UpstreamSet,
    readers: Arc<Readers>,
    /// Whether a meter reads it: its connections then run on the metering
    /// threads (a meter stamps each message as it is read).
    metered: AtomicBool,
}

impl std::fmt::Debug for Tap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tap")
            .field("upstream", &self.upstream)
            .field("readers", &lock(&self.readers.sinks).len())
            .finish()
    }
}

impl Tap {
    /// A tap of `topic` whose connections run on `rt`; `metered` says
    /// whether `rt` is the metering threads' runtime.
    pub fn new(topic: &str, timeout: Duration, rt: Handle, metered: bool) -> Self {
        let readers = Arc::new(Readers::default());
        let upstream = UpstreamSet::new(TAP_CALLER_ID, topic, readers.clone(), timeout, rt);
        Self {
            upstream,
            readers,
            metered: AtomicBool::new(metered),
        }
    }

    /// Moves the connections to the metering threads' runtime `rt` unless
    /// they run there already (a meter joins a tap that fed only relays:
    /// its relays see a reconnect).
    pub fn meter_on(&self, rt: Handle) {
        if !self.metered.swap(true, Ordering::SeqCst) {
            self.upstream.move_to(rt);
        }
    }

    /// Connects to new publishers in `apis` and drops the ones gone.
    pub fn set_publishers(&self, apis: &[String], msg_type: &str) {
        self.upstream.set_publishers(apis, msg_type);
    }

    /// Adds (or replaces) the reader `key`. It is told at once every
    /// connected publisher's header and latched message, as a connection of
    /// its own would have been.
    pub fn add(&self, key: &str, sink: Arc<dyn FrameSink>) {
        self.readers.add(key, sink);
    }

    /// Removes the reader `key` if it is still `reader` (an edge adapted
    /// again meanwhile has a new reader under the same key, which stays);
    /// returns whether readers are left.
    pub fn remove(&self, key: &str, reader: &Arc<dyn FrameSink>) -> bool {
        let mut sinks = lock(&self.readers.sinks);
        if sinks
            .get(key)
            .is_some_and(|s| std::ptr::addr_eq(Arc::as_ptr(s), Arc::as_ptr(reader)))
        {
            sinks.remove(key);
        }
        !sinks.is_empty()
    }

    /// Number of publishers currently connected or being connected.
    pub fn publishers(&self) -> usize {
        self.upstream.len()
    }
}

/// The readers of one tap, with what a reader added later must be told.
#[derive(Default)]
struct Readers {
    sinks: Mutex<BTreeMap<String, Arc<dyn FrameSink>>>,
    headers: Mutex<BTreeMap<String, Header>>,
    latched: Mutex<BTreeMap<String, Frame>>,
}

impl Readers {
    fn add(&self, key: &str, sink: Arc<dyn FrameSink>) {
        // Hold the reader list while replaying, so no frame of a publisher
        // reaches the new reader before that publisher's header.
        let mut sinks = lock(&self.sinks);
        for (api, h) in lock(&self.headers).iter() {
            sink.on_header(api, h);
        }
        for (api, f) in lock(&self.latched).iter() {
            sink.on_frame(api, f.clone());
        }
        sinks.insert(key.to_string(), sink);
    }

    fn each(&self, f: impl Fn(&dyn FrameSink)) {
        for s in lock(&self.sinks).values() {
            f(s.as_ref());
        }
    }
}

impl FrameSink for Readers {
    fn on_header(&self, api: &str, header: &Header) {
        lock(&self.headers).insert(api.to_string(), header.clone());
        lock(&self.latched).remove(api);
        self.each(|s| s.on_header(api, header));
    }

    fn on_frame(&self, api: &str, frame: Frame) {
        let latching = lock(&self.headers)
            .get(api)
            .is_some_and(|h| h.get("latching").is_some_and(|v| v == "1"));
        if latching {
            lock(&self.latched).insert(api.to_string(), frame.clone());
        }
        self.each(|s| s.on_frame(api, frame.clone()));
    }

    fn on_gone(&self, api: &str) {
        lock(&self.headers).remove(api);
        lock(&self.latched).remove(api);
        self.each(|s| s.on_gone(api));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A reader that writes down what it is told.
    #[derive(Default)]
    struct Log(Mutex<Vec<String>>);

    impl FrameSink for Log {
        fn on_header(&self, api: &str, _: &Header) {
            lock(&self.0).push(format!("header {api}"));
        }
        fn on_frame(&self, api: &str, frame: Frame) {
            lock(&self.0).push(format!("frame {api} {}", frame.len()));
        }
        fn on_gone(&self, api: &str) {
            lock(&self.0).push(format!("gone {api}"));
        }
    }

    fn header(latching: bool) -> Header {
        let mut h = Header::new();
        h.insert("latching".into(), if latching { "1" } else { "0" }.into());
        h
    }

    #[test]
    fn every_reader_gets_each_frame_once() {
        let r = Readers::default();
        let (a, b) = (Arc::new(Log::default()), Arc::new(Log::default()));
        r.add("a", a.clone());
        r.add("b", b.clone());
        r.on_header("pub1", &header(false));
        r.on_frame("pub1", Arc::new(vec![0; 3]));
        r.on_gone("pub1");
        let want = ["header pub1", "frame pub1 3", "gone pub1"];
        assert_eq!(*lock(&a.0), want);
        assert_eq!(*lock(&b.0), want);
    }

    #[test]
    fn a_late_reader_is_told_the_headers_and_latched_messages_first() {
        let r = Readers::default();
        r.on_header("latched", &header(true));
        r.on_header("plain", &header(false));
        r.on_frame("latched", Arc::new(vec![0; 5]));
        r.on_frame("plain", Arc::new(vec![0; 7]));
        let late = Arc::new(Log::default());
        r.add("late", late.clone());
        assert_eq!(
            *lock(&late.0),
            ["header latched", "header plain", "frame latched 5"],
            "only the latching publisher's last message is replayed"
        );
        r.on_gone("latched");
        let again = Arc::new(Log::default());
        r.add("again", again.clone());
        assert_eq!(
            *lock(&again.0),
            ["header plain"],
            "a gone publisher is forgotten"
        );
    }

    /// A runtime for taps whose connections are never made.
    fn idle_rt() -> tokio::runtime::Runtime {
        tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap()
    }

    #[test]
    fn removing_the_last_reader_says_so() {
        let rt = idle_rt();
        let t = Tap::new("/t", Duration::from_secs(1), rt.handle().clone(), false);
        let (meter, relay): (Arc<dyn FrameSink>, Arc<dyn FrameSink>) =
            (Arc::new(Log::default()), Arc::new(Log::default()));
        t.add("meter", meter.clone());
        t.add("adaptor/s", relay.clone());
        assert!(t.remove("meter", &meter), "the adaptor still reads");
        assert!(!t.remove("adaptor/s", &relay));
    }

    #[test]
    fn a_replaced_reader_leaving_late_keeps_its_successor() {
        let rt = idle_rt();
        let t = Tap::new("/t", Duration::from_secs(1), rt.handle().clone(), false);
        let (old, new): (Arc<dyn FrameSink>, Arc<dyn FrameSink>) =
            (Arc::new(Log::default()), Arc::new(Log::default()));
        t.add("adaptor/s", old.clone());
        t.add("adaptor/s", new.clone());
        assert!(t.remove("adaptor/s", &old), "the new relay still reads");
        assert!(!t.remove("adaptor/s", &new));
    }
}
