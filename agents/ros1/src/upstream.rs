//! Keeps one TCPROS subscriber connection per publisher of a topic, feeding
//! raw frames to a sink; reconnects while the publisher stays listed.
//! Used by the taps ([`crate::tap`]) that feed topic meters and adaptor relays.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use configbot_api::backoff::Backoff;
use tokio::task::JoinHandle;

use crate::tcpros::{self, Header};

/// One raw message frame, shared by every reader of a tap.
pub type Frame = Arc<Vec<u8>>;

/// Receives what upstream connections read.
pub trait FrameSink: Send + Sync + 'static {
    /// A publisher's reply header after a (re)connect.
    fn on_header(&self, api: &str, header: &Header);
    /// One raw message frame from publisher `api`.
    fn on_frame(&self, api: &str, frame: Frame);
    /// Publisher `api` is no longer listed.
    fn on_gone(&self, _api: &str) {}
}

/// The set of publisher connections of one subscription.
pub struct UpstreamSet {
    caller_id: String,
    topic: String,
    msg_type: Mutex<String>,
    sink: Arc<dyn FrameSink>,
    tasks: Mutex<BTreeMap<String, JoinHandle<()>>>,
    timeout: Duration,
}

impl std::fmt::Debug for UpstreamSet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UpstreamSet")
            .field("caller_id", &self.caller_id)
            .field("topic", &self.topic)
            .finish_non_exhaustive()
    }
}

impl UpstreamSet {
    pub fn new(caller_id: &str, topic: &str, sink: Arc<dyn FrameSink>, timeout: Duration) -> Self {
        Self {
            caller_id: caller_id.into(),
            topic: topic.into(),
            msg_type: Mutex::new("*".into()),
            sink,
            tasks: Mutex::new(BTreeMap::new()),
            timeout,
        }
    }

    /// Connects to new publishers in `apis` and drops the ones gone.
    pub fn set_publishers(&self, apis: &[String], msg_type: &str) {
        if let Ok(mut t) = self.msg_type.lock() {
            *t = msg_type.to_string();
        }
        let Ok(mut tasks) = self.tasks.lock() else {
            return;
        };
        tasks.retain(|api, h| {
            let keep = apis.contains(api) && !h.is_finished();
            if !keep {
                h.abort();
                if !apis.contains(api) {
                    self.sink.on_gone(api);
                }
            }
            keep
        });
        for api in apis {
            if tasks.contains_key(api) {
                continue;
            }
            let (api2, caller, topic, ty, sink, timeout) = (
                api.clone(),
                self.caller_id.clone(),
                self.topic.clone(),
                msg_type.to_string(),
                self.sink.clone(),
                self.timeout,
            );
            tasks.insert(
                api.clone(),
                tokio::spawn(async move { run(api2, caller, topic, ty, sink, timeout).await }),
            );
        }
    }

    /// Number of publishers currently tracked.
    pub fn len(&self) -> usize {
        self.tasks.lock().map_or(0, |t| t.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl Drop for UpstreamSet {
    fn drop(&mut self) {
        if let Ok(t) = self.tasks.lock() {
            for h in t.values() {
                h.abort();
            }
        }
    }
}

async fn run(
    api: String,
    caller: String,
    topic: String,
    ty: String,
    sink: Arc<dyn FrameSink>,
    timeout: Duration,
) {
    let mut backoff = Backoff::new(Duration::from_millis(100), Duration::from_secs(2));
    loop {
        match tcpros::subscribe(&api, &caller, &topic, &ty, timeout).await {
            Ok(mut c) => {
                backoff.reset();
                sink.on_header(&api, &c.header);
                while let Ok(f) = tcpros::read_block(&mut c.stream, &c.peer).await {
                    sink.on_frame(&api, Arc::new(f));
                }
            }
            Err(_) => {
                tokio::time::sleep(backoff.next_delay()).await;
            }
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}
