//! The viewer's render queue: the frames waiting for the one render worker, bounded so that no
//! client, however many requests it sends, can grow the server's memory or delay other frames
//! without end.
//!
//! * **Per client** (the page's `client` id): at most one waiting frame. A new request
//!   supersedes the client's waiting one, which is answered at once as superseded (a 409, as a
//!   frame overtaken while rendering is). A request older than one already seen from its client
//!   is answered superseded without waiting. Requests without a `client` come one at a time per
//!   connection (HTTP/1.1 answers a connection's requests in order), so each connection is
//!   bounded the same way.
//! * **In all**: at most [`QUEUE_CAPACITY`] waiting frames. A request beyond that is given back
//!   to its handler, which answers 503 with `Retry-After`.
//! * **Abandoned frames** (their client hung up) leave the queue when the next request arrives
//!   and are skipped by the worker before any of their work starts. A hang-up is seen two
//!   ways: hyper drops the request's handler (a keep-alive connection it is still reading), and
//!   the job watches its own copy of the connection's socket ([`Peer`]), which also catches a
//!   `Connection: close` client, whose socket hyper no longer reads while the frame is made.
//!
//! A waiting frame is its checked query only (a few hundred bytes); the one frame rendering
//! holds one band of rays and its image, so memory is bounded by the image-size limit.

use std::collections::{HashMap, VecDeque};
use std::net::TcpStream;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};

use crate::view::request::ViewRequest;

/// Most frames waiting for the worker (the one rendering not counted).
pub const QUEUE_CAPACITY: usize = 8;

/// Most pages whose newest generation is remembered.
const MAX_CLIENTS: usize = 1024;

/// Counters shown in `/info.json`.
#[derive(Debug, Default)]
pub struct Stats {
    /// Frames sent.
    pub rendered: AtomicU64,
    /// Frames overtaken by a newer request of the same client (409).
    pub superseded: AtomicU64,
    /// Frames whose client hung up.
    pub cancelled: AtomicU64,
    /// Frames that failed to render (500).
    pub failed: AtomicU64,
    /// Requests refused because the queue was full (503).
    pub refused: AtomicU64,
}

/// A rendered frame, ready to send.
#[derive(Debug)]
pub struct Frame {
    /// The PNG file.
    pub png: Vec<u8>,
    /// Render time.
    pub seconds: f64,
    /// Samples drawn.
    pub total: usize,
    /// Samples evaluated.
    pub evaluated: usize,
}

/// How a job ended.
#[derive(Debug)]
pub enum Outcome {
    /// Rendered.
    Done(Frame),
    /// Overtaken by a newer request of the same client.
    Superseded,
    /// Its client hung up.
    Cancelled,
    /// Rendering failed; the reason.
    Failed(String),
}

impl Outcome {
    fn counter<'a>(&self, stats: &'a Stats) -> &'a AtomicU64 {
        match self {
            Outcome::Done(_) => &stats.rendered,
            Outcome::Superseded => &stats.superseded,
            Outcome::Cancelled => &stats.cancelled,
            Outcome::Failed(_) => &stats.failed,
        }
    }
}

/// A request's connection, watched for its client hanging up: a second handle on the socket,
/// so it stays valid (never another connection's) for as long as the job holds it.
#[derive(Debug, Clone)]
pub struct Peer(Arc<TcpStream>);

impl Peer {
    /// Watches `stream` (a clone of the connection's socket).
    pub fn new(stream: TcpStream) -> Self {
        Self(Arc::new(stream))
    }

    /// Whether the client has closed its side or the connection failed (Linux: `POLLRDHUP`,
    /// seen even with unread bytes waiting). Elsewhere always false: hyper's own notice of a
    /// hang-up is then the only one.
    pub fn hung_up(&self) -> bool {
        #[cfg(target_os = "linux")]
        {
            use std::os::fd::AsRawFd;
            let mut fd = libc::pollfd {
                fd: self.0.as_raw_fd(),
                events: libc::POLLRDHUP,
                revents: 0,
            };
            // SAFETY: one valid pollfd for a socket this value owns (kept open by the Arc),
            // and a zero timeout: poll only fills in `revents`.
            let ready = unsafe { libc::poll(&mut fd, 1, 0) };
            ready > 0 && fd.revents & (libc::POLLRDHUP | libc::POLLHUP | libc::POLLERR) != 0
        }
        #[cfg(not(target_os = "linux"))]
        {
            false
        }
    }
}

/// One frame to render, and where to send it.
#[derive(Debug)]
pub struct Job {
    /// The checked query.
    pub request: ViewRequest,
    /// Raised when the request's handler is dropped (its client hung up).
    pub cancel: Arc<AtomicBool>,
    /// The request's connection, when known.
    pub peer: Option<Peer>,
    /// Where the outcome goes.
    pub reply: tokio::sync::oneshot::Sender<Outcome>,
}

impl Job {
    /// Whether the client hung up (remembered once seen).
    pub fn cancelled(&self) -> bool {
        if self.cancel.load(Ordering::Relaxed) {
            return true;
        }
        let gone = self.peer.as_ref().is_some_and(Peer::hung_up);
        if gone {
            self.cancel.store(true, Ordering::Relaxed);
        }
        gone
    }
}

/// [`Queue::push`]'s refusal: [`QUEUE_CAPACITY`] jobs are already waiting.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QueueFull;

/// What the lock guards.
#[derive(Debug, Default)]
struct State {
    waiting: VecDeque<Job>,
    /// The newest generation each page has asked for.
    latest: HashMap<String, u64>,
}

impl State {
    /// Whether a newer request of the same page has arrived.
    fn is_stale(&self, request: &ViewRequest) -> bool {
        let Some(c) = &request.client else {
            return false;
        };
        self.latest.get(c).is_some_and(|&g| g > request.generation)
    }

    /// Records a request's generation; a lower one than already seen changes nothing.
    fn register(&mut self, request: &ViewRequest) {
        if let Some(c) = &request.client {
            // Bounded: a script inventing client ids cannot grow the map without end (the
            // pages forgotten here merely lose the dropping of their stale frames).
            if self.latest.len() >= MAX_CLIENTS && !self.latest.contains_key(c) {
                self.latest.clear();
            }
            let g = self.latest.entry(c.clone()).or_insert(request.generation);
            *g = (*g).max(request.generation);
        }
    }
}

/// The bounded queue between the handlers and the render worker.
#[derive(Debug, Default)]
pub struct Queue {
    state: Mutex<State>,
    ready: Condvar,
    /// The counters, updated by [`Queue::answer`].
    pub stats: Stats,
}

impl Queue {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Sends `outcome` to `job`'s handler (if it is still there) and counts it.
    pub fn answer(&self, job: Job, outcome: Outcome) {
        outcome.counter(&self.stats).fetch_add(1, Ordering::Relaxed);
        // The handler may be gone (client hung up): nothing to send to.
        let _ = job.reply.send(outcome);
    }

    /// Queues `job` for the worker, after answering the waiting jobs it supersedes and those
    /// abandoned. [`QueueFull`] (and the job dropped) when [`QUEUE_CAPACITY`] jobs are already
    /// waiting: the caller answers 503.
    pub fn push(&self, job: Job) -> Result<(), QueueFull> {
        let mut state = self.lock();
        state.register(&job.request);
        if state.is_stale(&job.request) {
            drop(state);
            self.answer(job, Outcome::Superseded);
            return Ok(());
        }
        let client = job.request.client.as_deref();
        let mut kept = VecDeque::with_capacity(state.waiting.len() + 1);
        for old in std::mem::take(&mut state.waiting) {
            if old.cancelled() {
                self.answer(old, Outcome::Cancelled);
            } else if client.is_some() && old.request.client.as_deref() == client {
                self.answer(old, Outcome::Superseded);
            } else {
                kept.push_back(old);
            }
        }
        state.waiting = kept;
        if state.waiting.len() >= QUEUE_CAPACITY {
            self.stats.refused.fetch_add(1, Ordering::Relaxed);
            return Err(QueueFull);
        }
        state.waiting.push_back(job);
        self.ready.notify_one();
        Ok(())
    }

    /// The next job still wanted, waiting for one; the unwanted ones met on the way are
    /// answered without any work.
    pub fn pop(&self) -> Job {
        let mut state = self.lock();
        loop {
            while let Some(job) = state.waiting.pop_front() {
                if job.cancelled() {
                    self.answer(job, Outcome::Cancelled);
                } else if state.is_stale(&job.request) {
                    self.answer(job, Outcome::Superseded);
                } else {
                    return job;
                }
            }
            state = self.ready.wait(state).unwrap_or_else(|e| e.into_inner());
        }
    }

    /// Whether `job` is no longer wanted: its client hung up or sent a newer request.
    pub fn unwanted(&self, job: &Job) -> bool {
        job.cancelled() || self.lock().is_stale(&job.request)
    }

    /// Frames waiting now.
    pub fn waiting(&self) -> usize {
        self.lock().waiting.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::view::request::{parse_view_query, ViewDefaults};
    use glam::DVec3;
    use tokio::sync::oneshot;

    fn job(client: Option<&str>, generation: u64) -> (Job, oneshot::Receiver<Outcome>) {
        let defaults = ViewDefaults {
            eye: DVec3::new(0.0, 0.0, -3.0),
            at: DVec3::ZERO,
            up: DVec3::Y,
            focal: 1.0,
            width: 8,
            height: 8,
        };
        let mut request = parse_view_query(&[], &defaults).unwrap();
        request.client = client.map(str::to_string);
        request.generation = generation;
        let (reply, outcome) = oneshot::channel();
        let cancel = Arc::new(AtomicBool::new(false));
        let job = Job {
            request,
            cancel,
            peer: None,
            reply,
        };
        (job, outcome)
    }

    #[test]
    fn a_peer_that_closes_is_seen_as_hung_up() {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        for (how, close) in [
            ("close", None),
            ("shutdown write", Some(std::net::Shutdown::Write)),
        ] {
            let client = TcpStream::connect(listener.local_addr().unwrap()).unwrap();
            let (server, _) = listener.accept().unwrap();
            let (mut j, _rx) = job(None, 0);
            j.peer = Some(Peer::new(server.try_clone().unwrap()));
            // Bytes waiting unread do not hide the hang-up.
            std::io::Write::write_all(&mut &client, b"GET / HTTP/1.1\r\n").unwrap();
            assert!(!j.cancelled(), "{how}");
            match close {
                None => drop(client),
                Some(how) => client.shutdown(how).unwrap(),
            }
            let start = std::time::Instant::now();
            while !j.cancelled() && start.elapsed().as_secs() < 5 {
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
            assert!(j.cancelled(), "{how}");
            assert!(j.cancel.load(Ordering::Relaxed), "remembered");
        }
    }

    fn answered(rx: &mut oneshot::Receiver<Outcome>) -> Option<Outcome> {
        rx.try_recv().ok()
    }

    #[test]
    fn a_clients_new_request_supersedes_its_waiting_one() {
        let q = Queue::default();
        let (a1, mut r1) = job(Some("a"), 1);
        let (b1, mut rb) = job(Some("b"), 1);
        let (a2, mut r2) = job(Some("a"), 2);
        q.push(a1).unwrap();
        q.push(b1).unwrap();
        assert!(answered(&mut r1).is_none());
        q.push(a2).unwrap();
        assert!(matches!(answered(&mut r1), Some(Outcome::Superseded)));
        assert_eq!(q.waiting(), 2);
        // An older request than one already seen is answered at once.
        let (a0, mut r0) = job(Some("a"), 0);
        q.push(a0).unwrap();
        assert!(matches!(answered(&mut r0), Some(Outcome::Superseded)));
        // The worker gets b, then a's newest.
        assert_eq!(q.pop().request.client.as_deref(), Some("b"));
        let newest = q.pop();
        assert_eq!(newest.request.generation, 2);
        assert!(!q.unwanted(&newest));
        // While it renders, a newer request of its client makes it unwanted.
        let (a3, _) = job(Some("a"), 3);
        q.push(a3).unwrap();
        assert!(q.unwanted(&newest));
        assert!(answered(&mut rb).is_none() && answered(&mut r2).is_none());
        assert_eq!(q.stats.superseded.load(Ordering::Relaxed), 2);
    }

    #[test]
    fn the_queue_is_bounded_and_abandoned_jobs_make_room() {
        let q = Queue::default();
        let mut cancels = Vec::new();
        let mut receivers = Vec::new();
        for _ in 0..QUEUE_CAPACITY {
            let (j, rx) = job(None, 0);
            cancels.push(j.cancel.clone());
            receivers.push(rx);
            q.push(j).unwrap();
        }
        let (extra, _) = job(Some("x"), 0);
        assert!(q.push(extra).is_err(), "a full queue refuses");
        assert_eq!(q.stats.refused.load(Ordering::Relaxed), 1);
        // Two clients hang up: their jobs leave at the next push, which then fits.
        cancels[0].store(true, Ordering::Relaxed);
        cancels[3].store(true, Ordering::Relaxed);
        let (next, _) = job(None, 0);
        q.push(next).unwrap();
        assert_eq!(q.waiting(), QUEUE_CAPACITY - 1);
        assert!(matches!(
            answered(&mut receivers[0]),
            Some(Outcome::Cancelled)
        ));
        assert!(matches!(
            answered(&mut receivers[3]),
            Some(Outcome::Cancelled)
        ));
        // One hangs up while waiting: the worker skips it.
        cancels[1].store(true, Ordering::Relaxed);
        let first = q.pop();
        assert!(!first.cancelled());
        assert!(matches!(
            answered(&mut receivers[1]),
            Some(Outcome::Cancelled)
        ));
        assert_eq!(q.stats.cancelled.load(Ordering::Relaxed), 3);
        assert!(!q.unwanted(&first));
        first.cancel.store(true, Ordering::Relaxed);
        assert!(q.unwanted(&first));
    }
}
