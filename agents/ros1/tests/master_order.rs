//! The master's publisher lists reach a subscriber in order: against a fake
//! subscriber slave that records every publisherUpdate it is sent, many
//! publishers registering at once leave it with the full list, and a
//! publisher registering while the subscriber's edge is being placed behind
//! an adaptor never hands it the direct connection, and an update the
//! subscriber was too busy to answer is sent again. Needs no ROS install.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use configbot_dataplane::EdgeId;
use configbot_ros1::http::{self, BoxFut, Handler};
use configbot_ros1::xmlrpc::{MethodCall, Response, Value};
use configbot_ros1::{Placement, Ros1Config, Ros1DataPlane};
use configbot_test_support::{free_port, try_wait_until_async};

const TIMEOUT: Duration = Duration::from_secs(5);
/// The master's timeout on calls to nodes in the stall test, and how long
/// a stalled publisherUpdate takes there.
const SHORT_CALL_TIMEOUT: Duration = Duration::from_millis(500);
const STALL: Duration = Duration::from_secs(3);

/// A subscriber's slave API that records the lists of its publisherUpdates
/// in the order they arrive.
#[derive(Default)]
struct Recorder {
    /// The lists of the updates answered, in order.
    updates: Mutex<Vec<Vec<String>>>,
    /// Whether the first publisherUpdate goes unanswered (a node too busy to
    /// answer before the master's call times out).
    stall_first: bool,
    stalled: std::sync::atomic::AtomicBool,
}

impl Handler for Recorder {
    fn handle(self: Arc<Self>, call: MethodCall) -> BoxFut<Response> {
        Box::pin(async move {
            if call.method == "publisherUpdate"
                && self.stall_first
                && !self.stalled.swap(true, std::sync::atomic::Ordering::SeqCst)
            {
                tokio::time::sleep(STALL).await;
                return Response::Ok(Value::ros(1, "", Value::Int(0)));
            }
            if call.method == "publisherUpdate" {
                let list = call
                    .params
                    .get(2)
                    .and_then(Value::as_array)
                    .map(|a| a.iter().filter_map(|u| u.as_str().map(String::from)));
                self.updates
                    .lock()
                    .unwrap()
                    .push(list.into_iter().flatten().collect());
            }
            let v = match call.method.as_str() {
                "getPid" => Value::Int(i64::from(std::process::id())),
                _ => Value::Int(0),
            };
            Response::Ok(Value::ros(1, "", v))
        })
    }
}

struct Fixture {
    dp: Ros1DataPlane,
    recorder: Arc<Recorder>,
    slave_api: String,
    _dir: tempfile::TempDir,
}

async fn start(placement: Option<Placement>) -> Fixture {
    let timeout = Ros1Config::default().call_timeout;
    start_with(placement, Recorder::default(), timeout).await
}

async fn start_with(
    placement: Option<Placement>,
    recorder: Recorder,
    call_timeout: Duration,
) -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let cfg = Ros1Config {
        master_uri: format!("http://localhost:{}/", free_port()),
        bind_host: "127.0.0.1".into(),
        advertise_host: "127.0.0.1".into(),
        refresh_period: Duration::from_secs(60),
        call_timeout,
        placement,
        ..Ros1Config::default()
    };
    let dp = Ros1DataPlane::start(
        cfg,
        &dir.path().join("ros1.db"),
        &prometheus::Registry::new(),
    )
    .await
    .unwrap();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let slave_api = format!(
        "http://127.0.0.1:{}/",
        listener.local_addr().unwrap().port()
    );
    let recorder = Arc::new(recorder);
    tokio::spawn(http::serve(listener, recorder.clone()));
    Fixture {
        dp,
        recorder,
        slave_api,
        _dir: dir,
    }
}

async fn register(master: &str, method: &str, node: &str, topic: &str, api: &str) -> Vec<String> {
    let v = http::call(
        master,
        method,
        &[
            Value::str(node),
            Value::str(topic),
            Value::str("std_msgs/String"),
            Value::str(api),
        ],
        TIMEOUT,
    )
    .await
    .unwrap();
    let list = v
        .as_array()
        .and_then(|a| a.get(2))
        .and_then(Value::as_array);
    list.into_iter()
        .flatten()
        .filter_map(|u| u.as_str().map(String::from))
        .collect()
}

/// Waits until the publisherUpdates `recorder` answered pass `done` (or 20 s
/// passed); returns them.
async fn updates_until(
    recorder: &Recorder,
    done: impl Fn(&[Vec<String>]) -> bool,
) -> Vec<Vec<String>> {
    let updates = || recorder.updates.lock().unwrap().clone();
    let waited = try_wait_until_async(
        "the publisherUpdates",
        Duration::from_secs(20),
        Duration::from_millis(20),
        async || Some(updates()).filter(|got| done(got)),
    )
    .await;
    waited.unwrap_or_else(|_| updates())
}

/// Waits until `recorder` has answered `n` publisherUpdates; returns them.
async fn updates(recorder: &Recorder, n: usize) -> Vec<Vec<String>> {
    updates_until(recorder, |got| got.len() >= n).await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn concurrent_publishers_leave_the_subscriber_with_all_of_them() {
    const PUBLISHERS: usize = 24;
    let f = start(None).await;
    let master = f.dp.master_uri().to_string();
    assert!(
        register(&master, "registerSubscriber", "/sub", "/t", &f.slave_api)
            .await
            .is_empty()
    );
    let apis: Vec<String> = (0..PUBLISHERS)
        .map(|i| format!("http://127.0.0.1:9/pub{i}"))
        .collect();
    let mut calls = tokio::task::JoinSet::new();
    for (i, api) in apis.iter().enumerate() {
        let (master, node, api) = (master.clone(), format!("/pub{i}"), api.clone());
        calls.spawn(async move { register(&master, "registerPublisher", &node, "/t", &api).await });
    }
    calls.join_all().await;
    // The update answered last is what a roscpp or simnode subscriber is
    // left connected to: eventually it lists every publisher.
    let mut want = apis.clone();
    want.sort();
    let sorted = |l: &Vec<String>| {
        let mut l = l.clone();
        l.sort();
        l
    };
    let got = updates_until(&f.recorder, |got| {
        got.last().map(sorted) == Some(want.clone())
    })
    .await;
    let last = got.last().map(sorted);
    assert_eq!(last, Some(want), "the last update arrived out of order");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_publisher_registering_during_placement_is_reached_through_the_adaptor() {
    // The placement runs inside registerSubscriber; it says it started and
    // waits until the publisher has registered, so the publisher's update
    // is due while the edge is being placed.
    let placing = Arc::new(tokio::sync::Notify::new());
    let signal = placing.clone();
    let (registered_tx, registered_rx) = std::sync::mpsc::channel::<()>();
    let registered_rx = Mutex::new(registered_rx);
    let placement: Placement = Arc::new(move |_: &EdgeId, _: &[String]| {
        signal.notify_one();
        // Hand this worker's queued tasks to another thread while blocking:
        // the master's accept loop may be among them, and the publisher's
        // registration must get through meanwhile.
        tokio::task::block_in_place(|| {
            let _ = registered_rx.lock().unwrap().recv_timeout(TIMEOUT);
        });
        true
    });
    let f = start(Some(placement)).await;
    let master = f.dp.master_uri().to_string();
    let (m, api) = (master.clone(), f.slave_api.clone());
    let subscribing =
        tokio::spawn(async move { register(&m, "registerSubscriber", "/sub", "/t", &api).await });
    placing.notified().await;
    register(
        &master,
        "registerPublisher",
        "/pub",
        "/t",
        "http://127.0.0.1:9/pub",
    )
    .await;
    registered_tx.send(()).unwrap();
    let reply = subscribing.await.unwrap();
    let adaptor = vec![f.dp.adaptor_uri().to_string()];
    let got = updates(&f.recorder, 1).await;
    assert_eq!(got.len(), 1, "the publisher's update never came");
    assert_eq!(got[0], adaptor, "the update bypasses the adaptor");
    assert!(
        reply.is_empty() || reply == adaptor,
        "the reply bypasses the adaptor: {reply:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn an_update_the_subscriber_did_not_answer_in_time_is_sent_again() {
    let recorder = Recorder {
        stall_first: true,
        ..Recorder::default()
    };
    let f = start_with(None, recorder, SHORT_CALL_TIMEOUT).await;
    let master = f.dp.master_uri().to_string();
    let reply = register(&master, "registerSubscriber", "/sub", "/t", &f.slave_api).await;
    assert!(reply.is_empty());
    let publisher = "http://127.0.0.1:9/pub".to_string();
    register(&master, "registerPublisher", "/pub", "/t", &publisher).await;
    let got = updates(&f.recorder, 1).await;
    assert_eq!(
        got,
        vec![vec![publisher]],
        "the stalled update was not sent again"
    );
}
