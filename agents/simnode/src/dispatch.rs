//! Callback execution. Two models, as in robot apps:
//! - a shared worker pool (`--workers N`, like `ros::AsyncSpinner`): every
//!   callback has a queue of size 1 (the newest message wins), ready
//!   callbacks are served in arrival order, and one callback never runs on
//!   two workers at once (roscpp's default) — so a heavy non-core callback
//!   delays a core one sharing the pool;
//! - thread-per-message (`--thread-per-message`, like the paper's object
//!   detector): each message gets its own thread; under a CPU limit the
//!   threads pile up (up to `--max-threads`) and share the CPU, and with
//!   `--contention-pct` each one pays for the others (see [`contended_cost_ms`]).
//!
//! [`PoolQueue`] is the pool's pure scheduling state; the rest runs threads.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use crate::burn;
use crate::msg;
use crate::publish::Topic;
use crate::spec::CallbackSpec;

/// A received message.
#[derive(Debug, Clone)]
pub struct Incoming {
    pub body: Vec<u8>,
    pub at: Instant,
}

/// What [`PoolQueue::push`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pushed {
    /// The callback became ready.
    Queued,
    /// The callback was already ready; its older message was dropped.
    Replaced,
}

/// Scheduling state of a worker pool: one size-1 slot per callback, the
/// ready callbacks in arrival order, and which callbacks are running.
#[derive(Debug, Default)]
pub struct PoolQueue {
    slots: Vec<Option<Incoming>>,
    busy: Vec<bool>,
    ready: VecDeque<usize>,
}

impl PoolQueue {
    pub fn new(callbacks: usize) -> Self {
        Self {
            slots: vec![None; callbacks],
            busy: vec![false; callbacks],
            ready: VecDeque::new(),
        }
    }

    /// A message for callback `i` (ignored when `i` is out of range).
    pub fn push(&mut self, i: usize, m: Incoming) -> Pushed {
        let Some(slot) = self.slots.get_mut(i) else {
            return Pushed::Replaced;
        };
        if slot.replace(m).is_some() {
            Pushed::Replaced
        } else {
            self.ready.push_back(i);
            Pushed::Queued
        }
    }

    /// The oldest ready callback that is not running, marked running.
    pub fn take(&mut self) -> Option<(usize, Incoming)> {
        let pos = self.ready.iter().position(|&i| !self.busy[i])?;
        let i = self.ready.remove(pos)?;
        self.busy[i] = true;
        Some((i, self.slots[i].take()?))
    }

    /// Callback `i` finished.
    pub fn done(&mut self, i: usize) {
        if let Some(b) = self.busy.get_mut(i) {
            *b = false;
        }
    }
}

/// One `--on` callback and its counters.
#[derive(Debug)]
pub struct Callback {
    pub spec: CallbackSpec,
    out: Arc<Topic>,
    pub received: AtomicU64,
    pub dropped: AtomicU64,
    pub done: AtomicU64,
    pub cpu_ns: AtomicU64,
}

impl Callback {
    pub fn new(spec: CallbackSpec, out: Arc<Topic>) -> Self {
        Self {
            spec,
            out,
            received: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            done: AtomicU64::new(0),
            cpu_ns: AtomicU64::new(0),
        }
    }

    /// Does the work for one message, then publishes one output message
    /// carrying the input's source stamp.
    /// Burns the callback's cost times `scale`, then publishes its output.
    fn run(&self, m: &Incoming, stop: &AtomicBool, scale: f64) {
        let cost = Duration::from_secs_f64(self.spec.cost_ms * scale / 1000.0);
        let used = burn::burn(cost, stop);
        self.cpu_ns.fetch_add(
            u64::try_from(used.as_nanos()).unwrap_or(u64::MAX),
            Ordering::Relaxed,
        );
        if stop.load(Ordering::Relaxed) {
            return;
        }
        let meta = msg::decode(&m.body);
        let stamp = meta.map_or_else(msg::now_ns, |x| x.stamp_ns);
        let bytes = self
            .spec
            .bytes
            .unwrap_or_else(|| meta.map_or(m.body.len(), |x| x.data_len));
        self.out
            .publish(msg::encode(self.out.next_seq(), stamp, bytes));
        self.done.fetch_add(1, Ordering::Relaxed);
    }
}

/// Runs the node's callbacks.
#[derive(Debug)]
pub enum Dispatcher {
    Pool(Arc<Pool>),
    PerMessage(Arc<PerMessage>),
}

impl Dispatcher {
    /// A message arrived for callback `i`.
    pub fn deliver(&self, i: usize, m: Incoming) {
        match self {
            Dispatcher::Pool(p) => p.deliver(i, m),
            Dispatcher::PerMessage(p) => p.deliver(i, m),
        }
    }

    pub fn callbacks(&self) -> &[Arc<Callback>] {
        match self {
            Dispatcher::Pool(p) => &p.callbacks,
            Dispatcher::PerMessage(p) => &p.callbacks,
        }
    }

    /// Threads currently running callbacks.
    pub fn active(&self) -> usize {
        match self {
            Dispatcher::Pool(p) => p.active.load(Ordering::Relaxed),
            Dispatcher::PerMessage(p) => p.active.load(Ordering::Relaxed),
        }
    }

    /// Stops the workers (running callbacks return early).
    pub fn shutdown(&self) {
        if let Dispatcher::Pool(p) = self {
            p.stop.store(true, Ordering::Relaxed);
            p.cv.notify_all();
        }
    }
}

/// A shared worker pool.
#[derive(Debug)]
pub struct Pool {
    queue: Mutex<PoolQueue>,
    cv: Condvar,
    callbacks: Vec<Arc<Callback>>,
    stop: Arc<AtomicBool>,
    active: AtomicUsize,
}

impl Pool {
    /// Starts `workers` threads serving `callbacks`.
    pub fn start(
        callbacks: Vec<Arc<Callback>>,
        workers: usize,
        stop: Arc<AtomicBool>,
    ) -> std::io::Result<Arc<Pool>> {
        let pool = Arc::new(Pool {
            queue: Mutex::new(PoolQueue::new(callbacks.len())),
            cv: Condvar::new(),
            callbacks,
            stop,
            active: AtomicUsize::new(0),
        });
        for k in 0..workers.max(1) {
            let p = pool.clone();
            std::thread::Builder::new()
                .name(format!("simnode-worker-{k}"))
                .spawn(move || p.work())?;
        }
        Ok(pool)
    }

    fn deliver(&self, i: usize, m: Incoming) {
        let Some(cb) = self.callbacks.get(i) else {
            return;
        };
        cb.received.fetch_add(1, Ordering::Relaxed);
        let Ok(mut q) = self.queue.lock() else { return };
        if q.push(i, m) == Pushed::Replaced {
            cb.dropped.fetch_add(1, Ordering::Relaxed);
        }
        drop(q);
        self.cv.notify_one();
    }

    fn work(&self) {
        while !self.stop.load(Ordering::Relaxed) {
            let Ok(mut q) = self.queue.lock() else { return };
            let job = loop {
                if self.stop.load(Ordering::Relaxed) {
                    return;
                }
                if let Some(j) = q.take() {
                    break j;
                }
                q = match self.cv.wait_timeout(q, Duration::from_millis(200)) {
                    Ok((q, _)) => q,
                    Err(_) => return,
                };
            };
            drop(q);
            let (i, m) = job;
            self.active.fetch_add(1, Ordering::Relaxed);
            self.callbacks[i].run(&m, &self.stop, 1.0);
            self.active.fetch_sub(1, Ordering::Relaxed);
            if let Ok(mut q) = self.queue.lock() {
                q.done(i);
            }
            // The finished callback may have a newer message waiting.
            self.cv.notify_all();
        }
    }
}

/// CPU cost of a message that starts while `others` message threads are
/// already running: `cost_ms × (1 + pct/100 × others)`. It models what
/// parallel inference threads do to each other's caches and memory
/// bandwidth — the paper's "compounding penalty" of an oversubscribed
/// detector (Fig. 2b): the more frames in flight, the more CPU each costs.
pub fn contended_cost_ms(cost_ms: f64, others: usize, pct: f64) -> f64 {
    cost_ms * (1.0 + pct.max(0.0) / 100.0 * others as f64)
}

/// Thread-per-message execution.
#[derive(Debug)]
pub struct PerMessage {
    callbacks: Vec<Arc<Callback>>,
    /// Most threads at once; 0 = unbounded.
    max_threads: usize,
    /// Extra cost per other running message thread, in percent.
    contention_pct: f64,
    active: Arc<AtomicUsize>,
    stop: Arc<AtomicBool>,
}

impl PerMessage {
    pub fn new(
        callbacks: Vec<Arc<Callback>>,
        max_threads: usize,
        contention_pct: f64,
        stop: Arc<AtomicBool>,
    ) -> Self {
        Self {
            callbacks,
            max_threads,
            contention_pct,
            active: Arc::new(AtomicUsize::new(0)),
            stop,
        }
    }

    fn deliver(&self, i: usize, m: Incoming) {
        let Some(cb) = self.callbacks.get(i).cloned() else {
            return;
        };
        cb.received.fetch_add(1, Ordering::Relaxed);
        let n = self.active.fetch_add(1, Ordering::Relaxed);
        if self.max_threads > 0 && n >= self.max_threads {
            self.active.fetch_sub(1, Ordering::Relaxed);
            cb.dropped.fetch_add(1, Ordering::Relaxed);
            return;
        }
        let (active, stop) = (self.active.clone(), self.stop.clone());
        let scale = contended_cost_ms(1.0, n, self.contention_pct);
        let spawned = std::thread::Builder::new()
            .name("simnode-msg".into())
            .spawn(move || {
                cb.run(&m, &stop, scale);
                active.fetch_sub(1, Ordering::Relaxed);
            });
        if spawned.is_err() {
            self.active.fetch_sub(1, Ordering::Relaxed);
            if let Some(cb) = self.callbacks.get(i) {
                cb.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contention_scales_a_messages_cost_with_the_threads_already_running() {
        assert_eq!(contended_cost_ms(150.0, 0, 15.0), 150.0);
        assert!((contended_cost_ms(150.0, 9, 15.0) - 352.5).abs() < 1e-9);
        assert_eq!(contended_cost_ms(150.0, 9, 0.0), 150.0);
        assert_eq!(contended_cost_ms(150.0, 9, -5.0), 150.0, "no discount");
    }

    fn m(tag: u8) -> Incoming {
        Incoming {
            body: vec![tag],
            at: Instant::now(),
        }
    }

    #[test]
    fn newest_wins_and_ready_callbacks_are_served_in_order() {
        let mut q = PoolQueue::new(2);
        assert_eq!(q.push(1, m(1)), Pushed::Queued);
        assert_eq!(q.push(0, m(2)), Pushed::Queued);
        assert_eq!(q.push(1, m(3)), Pushed::Replaced);
        let (i, x) = q.take().unwrap();
        assert_eq!((i, x.body[0]), (1, 3));
        let (i, x) = q.take().unwrap();
        assert_eq!((i, x.body[0]), (0, 2));
        assert!(q.take().is_none());
    }

    #[test]
    fn a_callback_never_runs_twice_at_once() {
        let mut q = PoolQueue::new(2);
        q.push(0, m(1));
        let (i, _) = q.take().unwrap();
        assert_eq!(i, 0);
        // A new message for the running callback waits; another callback
        // that became ready later is served first.
        q.push(0, m(2));
        q.push(1, m(3));
        assert_eq!(q.take().map(|(i, _)| i), Some(1));
        assert!(q.take().is_none());
        q.done(0);
        assert_eq!(q.take().map(|(i, x)| (i, x.body[0])), Some((0, 2)));
    }

    #[test]
    fn one_worker_shared_with_a_heavy_callback_serves_the_light_one_less() {
        let stop = Arc::new(AtomicBool::new(false));
        let out = Arc::new(Topic::default());
        let spec = |cost_ms| CallbackSpec {
            input: "/in".into(),
            output: "/out".into(),
            cost_ms,
            bytes: Some(16),
        };
        let light = Arc::new(Callback::new(spec(1.0), out.clone()));
        let heavy = Arc::new(Callback::new(spec(40.0), out.clone()));
        let pool = Pool::start(vec![light.clone(), heavy.clone()], 1, stop.clone()).unwrap();
        // Both inputs arrive every 10 ms for 0.6 s: alone the light callback
        // would keep up; sharing one worker it runs about once per heavy run.
        let t0 = Instant::now();
        let mut k = 0u32;
        while t0.elapsed() < Duration::from_millis(600) {
            pool.deliver(0, m(0));
            pool.deliver(1, m(1));
            k += 1;
            std::thread::sleep(Duration::from_millis(10));
        }
        stop.store(true, Ordering::Relaxed);
        pool.cv.notify_all();
        let (l, h) = (
            light.done.load(Ordering::Relaxed),
            heavy.done.load(Ordering::Relaxed),
        );
        assert!(h >= 1 && l <= h + 1, "light {l} heavy {h} of {k}");
        assert!(light.dropped.load(Ordering::Relaxed) > u64::from(k) / 2);
    }
}
