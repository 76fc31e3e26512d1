//! Keeps one TCPROS subscriber connection per publisher of a topic, feeding
//! raw frames to a sink; reconnects while the publisher stays listed.
//! Used by the taps ([`crate::tap`]) that feed topic meters and adaptor relays.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use configbot_api::backoff::Backoff;
use tokio::runtime::Handle;
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
    /// The runtime the connections run on.
    rt: Mutex<Handle>,
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
    /// No connections yet; they will run on `rt`.
    pub fn new(
        caller_id: &str,
        topic: &str,
        sink: Arc<dyn FrameSink>,
        timeout: Duration,
        rt: Handle,
    ) -> Self {
        Self {
            caller_id: caller_id.into(),
            topic: topic.into(),
            msg_type: Mutex::new("*".into()),
            sink,
            tasks: Mutex::new(BTreeMap::new()),
            timeout,
            rt: Mutex::new(rt),
        }
    }

    /// Runs the connections on `rt` from now on: the open ones are closed
    /// and made again there (the sink sees each publisher's header again,
    /// as after a reconnect).
    pub fn move_to(&self, rt: Handle) {
        let apis: Vec<String> = {
            let Ok(mut tasks) = self.tasks.lock() else {
                return;
            };
            if let Ok(mut r) = self.rt.lock() {
                *r = rt;
            }
            for h in tasks.values() {
                h.abort();
            }
            std::mem::take(&mut *tasks).into_keys().collect()
        };
        let ty = self.msg_type.lock().map(|t| t.clone()).unwrap_or_default();
        self.set_publishers(&apis, &ty);
    }

    /// Connects to new publishers in `apis` and drops the ones gone.
    pub fn set_publishers(&self, apis: &[String], msg_type: &str) {
        if let Ok(mut t) = self.msg_type.lock() {
            *t = msg_type.to_string();
        }
        let Ok(mut tasks) = self.tasks.lock() else {
            return;
        };
        let Ok(rt) = self.rt.lock().map(|r| r.clone()) else {
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
                rt.spawn(async move { run(api2, caller, topic, ty, sink, timeout).await }),
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

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicUsize, Ordering};

    use super::*;
    use crate::http::{self, BoxFut, Handler};
    use crate::xmlrpc::{MethodCall, Response, Value};

    /// A publisher's slave API that hands out one TCPROS port.
    struct Slave(u16);

    impl Handler for Slave {
        fn handle(self: Arc<Self>, _: MethodCall) -> BoxFut<Response> {
            let port = i64::from(self.0);
            Box::pin(async move {
                let proto = Value::Array(vec![
                    Value::str("TCPROS"),
                    Value::str("127.0.0.1"),
                    Value::Int(port),
                ]);
                Response::Ok(Value::ros(1, "", proto))
            })
        }
    }

    /// Writes down the name of the thread each header arrives on.
    #[derive(Default)]
    struct Threads(Mutex<Vec<String>>);

    impl FrameSink for Threads {
        fn on_header(&self, _: &str, _: &Header) {
            let name = std::thread::current().name().unwrap_or("").to_string();
            self.0.lock().unwrap().push(name);
        }
        fn on_frame(&self, _: &str, _: Frame) {}
    }

    fn runtime(name: &str) -> tokio::runtime::Runtime {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name(name)
            .enable_all()
            .build()
            .unwrap()
    }

    /// Moving a subscription to another runtime closes its connection and
    /// makes it again there.
    #[test]
    fn moved_connections_are_made_again_on_the_new_runtime() {
        let (first, second, publisher) = (runtime("first"), runtime("second"), runtime("pub"));
        let accepted = Arc::new(AtomicUsize::new(0));
        let api = publisher.block_on(async {
            let (tcp, tcp_addr) = http::bind("127.0.0.1", 0).await.unwrap();
            let n = accepted.clone();
            tokio::spawn(async move {
                let mut open = Vec::new();
                while let Ok((mut s, _)) = tcp.accept().await {
                    n.fetch_add(1, Ordering::SeqCst);
                    let _ = tcpros::read_header(&mut s, "test").await;
                    let mut h = Header::new();
                    h.insert("type".into(), "std_msgs/Empty".into());
                    h.insert("md5sum".into(), "*".into());
                    let _ = tokio::io::AsyncWriteExt::write_all(&mut s, &tcpros::encode_header(&h))
                        .await;
                    open.push(s);
                }
            });
            let (xml, xml_addr) = http::bind("127.0.0.1", 0).await.unwrap();
            tokio::spawn(http::serve(xml, Arc::new(Slave(tcp_addr.port()))));
            format!("http://127.0.0.1:{}/", xml_addr.port())
        });
        let sink = Arc::new(Threads::default());
        let set = UpstreamSet::new(
            "/tap",
            "/t",
            sink.clone(),
            Duration::from_secs(5),
            first.handle().clone(),
        );
        let headers = |want: usize| {
            let what = format!("{want} publisher headers");
            configbot_test_support::wait_until(
                &what,
                Duration::from_secs(10),
                Duration::from_millis(10),
                || {
                    let seen = sink.0.lock().unwrap().clone();
                    (seen.len() >= want).then_some(seen)
                },
            )
        };
        set.set_publishers(std::slice::from_ref(&api), "std_msgs/Empty");
        assert_eq!(headers(1), ["first"]);
        set.move_to(second.handle().clone());
        assert_eq!(headers(2), ["first", "second"]);
        assert_eq!(accepted.load(Ordering::SeqCst), 2, "one new connection");
        assert_eq!(set.len(), 1);
    }
}
