//! The publisher side: the node's topics, their subscriber connections and
//! the TCPROS server that accepts them. Publishing is non-blocking (callable
//! from CPU threads): each connection has a small outgoing queue and a writer
//! task; a full queue drops the message for that subscriber only, as a ROS
//! publisher's queue does.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use configbot_ros1::tcpros::{self, Header};
use tokio::io::AsyncWriteExt;
use tokio::net::TcpListener;
use tokio::sync::mpsc;

use crate::msg;

/// Outgoing messages a slow subscriber may have queued before drops.
pub const OUT_QUEUE: usize = 4;

/// One subscriber connection of a topic.
#[derive(Debug)]
struct Outlet {
    id: u32,
    subscriber: String,
    tx: mpsc::Sender<Arc<Vec<u8>>>,
}

/// One published topic.
#[derive(Debug, Default)]
pub struct Topic {
    seq: AtomicU64,
    published: AtomicU64,
    outlets: Mutex<Vec<Outlet>>,
}

impl Topic {
    /// Next sequence number (starts at 0).
    pub fn next_seq(&self) -> u64 {
        self.seq.fetch_add(1, Ordering::Relaxed)
    }

    /// Messages published so far.
    pub fn published(&self) -> u64 {
        self.published.load(Ordering::Relaxed)
    }

    /// Hands `body` (a serialised message) to every connected subscriber.
    pub fn publish(&self, body: Vec<u8>) {
        self.published.fetch_add(1, Ordering::Relaxed);
        let body = Arc::new(body);
        if let Ok(mut outs) = self.outlets.lock() {
            outs.retain(|o| match o.tx.try_send(body.clone()) {
                Ok(()) | Err(mpsc::error::TrySendError::Full(_)) => true,
                Err(mpsc::error::TrySendError::Closed(_)) => false,
            });
        }
    }

    fn attach(&self, o: Outlet) {
        if let Ok(mut outs) = self.outlets.lock() {
            outs.push(o);
        }
    }

    fn detach(&self, id: u32) {
        if let Ok(mut outs) = self.outlets.lock() {
            outs.retain(|o| o.id != id);
        }
    }
}

/// All topics the node publishes (fixed at start), by resolved name.
#[derive(Debug)]
pub struct Publications {
    pub caller_id: String,
    topics: BTreeMap<String, Arc<Topic>>,
    next_id: AtomicU32,
}

/// A row of `getBusInfo`: (connection id, peer, direction, topic).
pub type BusRow = (u32, String, char, String);

impl Publications {
    pub fn new(caller_id: &str, topics: impl IntoIterator<Item = String>) -> Self {
        Self {
            caller_id: caller_id.into(),
            topics: topics
                .into_iter()
                .map(|t| (t, Arc::new(Topic::default())))
                .collect(),
            next_id: AtomicU32::new(1),
        }
    }

    pub fn topic(&self, name: &str) -> Option<Arc<Topic>> {
        self.topics.get(name).cloned()
    }

    pub fn names(&self) -> impl Iterator<Item = &String> {
        self.topics.keys()
    }

    /// A fresh connection id (shared with inbound connections).
    pub fn next_id(&self) -> u32 {
        self.next_id.fetch_add(1, Ordering::Relaxed)
    }

    /// Outbound connections, for `getBusInfo`.
    pub fn bus_rows(&self) -> Vec<BusRow> {
        let mut rows = Vec::new();
        for (name, t) in &self.topics {
            if let Ok(outs) = t.outlets.lock() {
                for o in outs.iter() {
                    rows.push((o.id, o.subscriber.clone(), 'o', name.clone()));
                }
            }
        }
        rows
    }

    /// The reply header to a subscriber's connection header (pure).
    pub fn reply_header(&self, h: &Header) -> Header {
        let mut r = Header::new();
        let topic = h.get("topic").cloned().unwrap_or_default();
        if !self.topics.contains_key(&topic) {
            r.insert(
                "error".into(),
                format!("{} does not publish {topic:?}", self.caller_id),
            );
            return r;
        }
        if let Some(want) = h.get("md5sum")
            && want != "*"
            && want != msg::MD5SUM
        {
            r.insert(
                "error".into(),
                format!(
                    "md5sum mismatch on {topic}: subscriber wants {want}, {} publishes {} ({})",
                    self.caller_id,
                    msg::MD5SUM,
                    msg::MSG_TYPE
                ),
            );
            return r;
        }
        r.insert("callerid".into(), self.caller_id.clone());
        r.insert("topic".into(), topic);
        r.insert("type".into(), msg::MSG_TYPE.into());
        r.insert("md5sum".into(), msg::MD5SUM.into());
        r.insert("message_definition".into(), msg::DEFINITION.into());
        r.insert("latching".into(), "0".into());
        r
    }
}

/// Accepts TCPROS subscriber connections until the task is aborted.
pub async fn serve_tcpros(listener: TcpListener, pubs: Arc<Publications>, timeout: Duration) {
    loop {
        let Ok((mut stream, addr)) = listener.accept().await else {
            tokio::time::sleep(Duration::from_millis(50)).await;
            continue;
        };
        let pubs = pubs.clone();
        tokio::spawn(async move {
            let peer = addr.to_string();
            let Ok(Ok(h)) =
                tokio::time::timeout(timeout, tcpros::read_header(&mut stream, &peer)).await
            else {
                return;
            };
            let reply = pubs.reply_header(&h);
            if stream
                .write_all(&tcpros::encode_header(&reply))
                .await
                .is_err()
                || reply.contains_key("error")
            {
                return;
            }
            if h.get("tcp_nodelay").is_some_and(|v| v == "1") {
                let _ = stream.set_nodelay(true);
            }
            let Some(t) = h.get("topic").and_then(|t| pubs.topic(t)) else {
                return;
            };
            let id = pubs.next_id();
            let (tx, mut rx) = mpsc::channel::<Arc<Vec<u8>>>(OUT_QUEUE);
            t.attach(Outlet {
                id,
                subscriber: h.get("callerid").cloned().unwrap_or(peer.clone()),
                tx,
            });
            while let Some(body) = rx.recv().await {
                if tcpros::write_frame(&mut stream, &body, &peer)
                    .await
                    .is_err()
                {
                    break;
                }
            }
            t.detach(id);
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(pairs: &[(&str, &str)]) -> Header {
        pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    #[test]
    fn replies_with_type_or_error() {
        let p = Publications::new("/n", ["/scan".to_string()]);
        let r = p.reply_header(&header(&[("topic", "/scan"), ("md5sum", "*")]));
        assert_eq!(r.get("type").map(String::as_str), Some(msg::MSG_TYPE));
        assert_eq!(r.get("md5sum").map(String::as_str), Some(msg::MD5SUM));
        assert_eq!(r.get("callerid").map(String::as_str), Some("/n"));
        let r = p.reply_header(&header(&[("topic", "/scan"), ("md5sum", msg::MD5SUM)]));
        assert!(!r.contains_key("error"));
        let r = p.reply_header(&header(&[("topic", "/scan"), ("md5sum", "abc")]));
        assert!(r["error"].contains("md5sum mismatch"), "{r:?}");
        let r = p.reply_header(&header(&[("topic", "/other"), ("md5sum", "*")]));
        assert!(r["error"].contains("/other"), "{r:?}");
    }

    #[tokio::test]
    async fn full_queues_drop_and_closed_connections_go() {
        let p = Publications::new("/n", ["/t".to_string()]);
        let t = p.topic("/t").unwrap();
        let (tx, mut rx) = mpsc::channel(OUT_QUEUE);
        t.attach(Outlet {
            id: 1,
            subscriber: "/s".into(),
            tx,
        });
        for i in 0..10u8 {
            t.publish(vec![i]);
        }
        assert_eq!(t.published(), 10);
        let mut got = Vec::new();
        while let Ok(b) = rx.try_recv() {
            got.push(b[0]);
        }
        assert_eq!(got, (0..OUT_QUEUE as u8).collect::<Vec<_>>());
        assert_eq!(p.bus_rows().len(), 1);
        drop(rx);
        t.publish(vec![0]);
        assert!(p.bus_rows().is_empty());
    }
}
