//! The command thread: waits on the `pdo_listener` subscription, applies every request the
//! table can resolve by itself straight to the engine and answers it on `write_results`, and
//! queues the rest for the node's Python code. A second thread serves `joint_commands` the same
//! way (`MessageKind::JointState`): certainly valid commands go into the engine's axis command
//! slots, unanswered (they come at a controller's rate); certainly invalid ones are refused
//! here; the rest go to Python, which refuses them on `joint_results`. A third kind
//! (`MessageKind::Passthrough`, `joint_trajectory`) hands every message to Python, but through
//! the same lease check and the same fair queue.
//!
//! The thread lives as long as the node; an engine and its table are attached while the node
//! is active. Detached, every request goes to Python (which refuses it while the bus is not
//! running), so no command waits in the middleware to be applied later.
//!
//! Who may command: with the control lease on ([`LeaseGate`]), a message whose publisher is not
//! the lease holder's is refused here, before it is decoded further or queued.
//!
//! Fairness: the queue for Python is kept per publisher (the GID rmw reports with each
//! message) and served round robin, each publisher with a bound of its own, so a publisher
//! flooding the node with requests Python must handle fills only its own queue (the excess is
//! refused here) and never delays another publisher's requests. Undecodable messages are
//! refused here at the cost of the decode.
//!
//! Order is kept per publisher across the two paths: while a request of a publisher waits in
//! (or is being handled from) the Python queue, its later requests are queued behind it too, so
//! an older value from it can never overwrite a newer one. Requests of different publishers
//! have no order between them (the middleware does not give them one either).
//!
//! This thread is not the engine's real-time thread and may allocate; it still avoids it in the
//! steady state (buffers are reused), and it never takes the GIL.

use std::collections::VecDeque;
use std::ffi::c_void;
use std::fmt::Write as _;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, AtomicUsize, Ordering};
use std::sync::{mpsc, Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use ether_ros_engine::{now_ns, Engine};

use crate::cdr::{
    decode_joint_state, decode_write_variable, encode_write_result, write_variable_request_id,
};
use crate::joints::{JointTable, Setpoint};
use crate::lease::{refusal_text, Gid, LeaseGate, Verdict};
use crate::rcl::{publish_serialized, Rcl, SubscriptionWaiter};
use crate::table::{CommandTable, Resolution};

/// The message type the subscription carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MessageKind {
    /// `ether_ros_msgs/WriteVariable` (`pdo_listener`), resolved with a [`CommandTable`].
    WriteVariable,
    /// `sensor_msgs/JointState` (`joint_commands`), resolved with a [`JointTable`].
    JointState,
    /// Any message (`trajectory_msgs/JointTrajectory` on `joint_trajectory`): every one goes to
    /// Python, after the lease check and through the fair queue.
    Passthrough,
}

impl MessageKind {
    /// How a refusal of this kind's messages starts on its results topic.
    fn refusal_prefix(self) -> &'static str {
        match self {
            MessageKind::WriteVariable => "",
            MessageKind::JointState => "joint_commands refused: ",
            MessageKind::Passthrough => "joint_trajectory refused: ",
        }
    }
}

/// What requests are resolved against (it must match the receiver's [`MessageKind`]).
#[derive(Debug, Clone)]
pub enum Resolver {
    /// Resolve `WriteVariable` requests against the output variables of the bus.
    Writes(CommandTable),
    /// Resolve `JointState` commands against the joints of the bus.
    Joints(JointTable),
}

/// How long one wait lasts before the thread looks at its stop flag.
const WAIT_NS: i64 = 50_000_000;
/// Requests queued for Python beyond this are refused (answered natively) rather than held.
const DEFERRED_LIMIT: usize = 1024;
/// Requests of one publisher queued for Python beyond this are refused likewise, so one
/// publisher cannot fill the whole queue.
pub const PUBLISHER_LIMIT: usize = 64;
/// Refusals answered per publisher: a burst of this many, then this many per second. Beyond
/// that a publisher's refused requests are only counted (`refusals_unanswered`): answering
/// every message of a flood would cost the node more than the flood itself.
pub const REFUSAL_ANSWERS_PER_S: u32 = 20;
/// Refusals answered by one thread in all, whatever the number of publishers: the answers of
/// every client share the results topic, so many flooding publishers must not crowd a client's
/// own answer out of its reader's history (`QOS_RESULTS` in `ros/node.py` holds 20 s of this).
pub const REFUSAL_ANSWERS_TOTAL_PER_S: u32 = 50;
/// Requests per publisher handed to Python: a burst of this many, then this many per second.
/// Beyond that they are refused here (`throttled`): a flood of requests only Python can answer
/// (values beyond the limits, text) would otherwise keep the node's Python busy, and with it the
/// thread that feeds the engine's command watchdog, which then trips and stops the robot.
pub const DEFERRALS_PER_S: u32 = 200;
/// Publishers the refusal answer budget is kept for (the least recently refused is forgotten).
pub const ANSWER_BUDGETS: usize = 64;
/// Initial size of the buffer serialized messages are taken into (rcl grows it if needed).
const MESSAGE_CAPACITY: usize = 4096;

/// What Python hands over: the loaded libraries and the rcl objects rclpy created (addresses
/// from their `handle.pointer`). `results` is the `write_results` publisher, 0 for none.
#[derive(Debug, Clone)]
pub struct ReceiverHandles {
    /// Path of the librcl rclpy loaded (the same copy, so the handles are compatible).
    pub librcl: String,
    /// Path of the librcutils rclpy loaded.
    pub librcutils: String,
    /// Address of the rcl context (`handle.pointer`), for the wait set.
    pub context: usize,
    /// Address of the rcl subscription the thread takes messages from.
    pub subscription: usize,
    /// Address of the `write_results` publisher (0: answers are not published).
    pub results: usize,
    /// The message type the subscription carries.
    pub message: MessageKind,
    /// The control lease to check every message against (None: everyone may command).
    pub lease: Option<Arc<LeaseGate>>,
}

/// Counters since start.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ReceiverCounters {
    /// Messages taken from the subscription.
    pub received: u64,
    /// Written to the engine by this thread.
    pub applied: u64,
    /// Handed to Python (text values, anything not certainly valid, or queued behind those).
    pub deferred: u64,
    /// Refused because the Python queue (or its publisher's share of it) was full.
    pub overflowed: u64,
    /// Refused here as certainly invalid (undecodable, or structurally wrong joint commands).
    pub refused: u64,
    /// Refused because the publisher does not hold the control lease.
    pub refused_lease: u64,
    /// Joint commands refused (not executed) because an axis they name cannot move (also
    /// counted in `refused`).
    pub blocked: u64,
    /// Refused because their publisher sent more than `DEFERRALS_PER_S` requests for Python.
    pub throttled: u64,
    /// Refusals not answered because their publisher's answer budget was spent (a flood).
    pub refusals_unanswered: u64,
    /// Serialized data this decoder did not understand (handed to Python too).
    pub undecodable: u64,
    /// rcl wait/take errors and failed result publications.
    pub rcl_errors: u64,
    /// Answers that could not be published (counted apart from the rcl wait/take errors).
    pub publish_errors: u64,
    /// Middleware delivery (publisher's source stamp to the subscription's receive stamp), for
    /// messages whose stamps are both set: last, largest and sum (ns).
    pub delivery_last_ns: u64,
    /// Largest middleware delivery seen (ns).
    pub delivery_max_ns: u64,
    /// Sum of the delivery times (ns), for the mean with `delivery_count`.
    pub delivery_sum_ns: u64,
    /// Messages whose delivery time is in the sum.
    pub delivery_count: u64,
}

impl ReceiverCounters {
    /// (name, value) of every counter, named as the fields.
    pub fn pairs(&self) -> [(&'static str, u64); 16] {
        [
            ("received", self.received),
            ("applied", self.applied),
            ("deferred", self.deferred),
            ("overflowed", self.overflowed),
            ("refused", self.refused),
            ("refused_lease", self.refused_lease),
            ("blocked", self.blocked),
            ("throttled", self.throttled),
            ("refusals_unanswered", self.refusals_unanswered),
            ("undecodable", self.undecodable),
            ("rcl_errors", self.rcl_errors),
            ("publish_errors", self.publish_errors),
            ("delivery_last_ns", self.delivery_last_ns),
            ("delivery_max_ns", self.delivery_max_ns),
            ("delivery_sum_ns", self.delivery_sum_ns),
            ("delivery_count", self.delivery_count),
        ]
    }
}

#[derive(Default)]
struct Counters {
    received: AtomicU64,
    applied: AtomicU64,
    deferred: AtomicU64,
    overflowed: AtomicU64,
    refused: AtomicU64,
    refused_lease: AtomicU64,
    blocked: AtomicU64,
    throttled: AtomicU64,
    refusals_unanswered: AtomicU64,
    undecodable: AtomicU64,
    rcl_errors: AtomicU64,
    publish_errors: AtomicU64,
    delivery_last_ns: AtomicU64,
    delivery_max_ns: AtomicU64,
    delivery_sum_ns: AtomicU64,
    delivery_count: AtomicU64,
}

struct Shared {
    stop: AtomicBool,
    counters: Counters,
    /// CLOCK_MONOTONIC ns of the last request this thread applied (0: none yet).
    last_command_ns: AtomicI64,
    /// Requests queued for Python plus the one Python is handling (all publishers): while it
    /// is 0 the fast path needs no lock.
    pending: AtomicUsize,
    queue: Mutex<FairQueue>,
    /// The engine and table writes go to; None while the node is not active. Held during a
    /// write, so once `detach` returns no write reaches the engine.
    target: Mutex<Option<Target>>,
    queued: Condvar,
    last_error: Mutex<String>,
    scheduling: Mutex<String>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Shared {
    fn error(&self, text: String) {
        *lock(&self.last_error) = text;
    }
}

/// A running command thread; stopped (and joined) by `stop` or on drop.
pub struct CommandReceiver {
    shared: Arc<Shared>,
    thread: Mutex<Option<JoinHandle<()>>>,
}

impl CommandReceiver {
    /// Start the thread. `priority` > 0 asks for SCHED_FIFO at that priority (kept below the
    /// engine's RT thread by the caller); without CAP_SYS_NICE the thread runs with normal
    /// scheduling and `scheduling()` says why. Fails when the libraries or the rcl objects are
    /// not usable, before any message is taken.
    pub fn start(
        handles: ReceiverHandles,
        priority: i32,
        cpus: Vec<usize>,
    ) -> Result<CommandReceiver, String> {
        if handles.context == 0 || handles.subscription == 0 {
            return Err("the rcl context and subscription must be given".into());
        }
        let rcl = Rcl::load(&handles.librcl, &handles.librcutils)?;
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            counters: Counters::default(),
            last_command_ns: AtomicI64::new(0),
            pending: AtomicUsize::new(0),
            queue: Mutex::new(FairQueue::default()),
            target: Mutex::new(None),
            queued: Condvar::new(),
            last_error: Mutex::new(String::new()),
            scheduling: Mutex::new(String::new()),
        });
        let (ready_tx, ready_rx) = mpsc::channel();
        let thread_shared = shared.clone();
        let thread = std::thread::Builder::new()
            .name("ether_ros-cmd".into())
            .spawn(move || {
                let worker = Worker {
                    shared: thread_shared,
                    rcl,
                    results: handles.results,
                    message: handles.message,
                    lease: handles.lease.clone(),
                };
                worker.run(&handles, priority, &cpus, ready_tx);
            })
            .map_err(|e| format!("cannot start the command thread: {e}"))?;
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(CommandReceiver {
                shared,
                thread: Mutex::new(Some(thread)),
            }),
            Ok(Err(e)) => {
                let _ = thread.join();
                Err(e)
            }
            Err(_) => {
                let _ = thread.join();
                Err("the command thread ended during setup".into())
            }
        }
    }

    /// Stop and join the thread (idempotent). Requests still queued for Python stay queued.
    pub fn stop(&self) {
        self.shared.stop.store(true, Ordering::Release);
        self.shared.queued.notify_all();
        let thread = lock(&self.thread).take();
        if let Some(t) = thread {
            let _ = t.join();
        }
    }

    /// Apply valid requests to `engine` from now on, resolved with `resolver`.
    pub fn attach(&self, engine: Arc<Engine>, resolver: Resolver) {
        *lock(&self.shared.target) = Some(Target { engine, resolver });
    }

    /// Stop writing to the engine; returns once no write is in progress.
    pub fn detach(&self) {
        *lock(&self.shared.target) = None;
    }

    /// True while the receiver thread runs.
    pub fn is_running(&self) -> bool {
        lock(&self.thread)
            .as_ref()
            .is_some_and(|t| !t.is_finished())
    }

    /// A consistent copy of the counters, for the node's statistics.
    pub fn counters(&self) -> ReceiverCounters {
        let c = &self.shared.counters;
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        ReceiverCounters {
            received: get(&c.received),
            applied: get(&c.applied),
            deferred: get(&c.deferred),
            overflowed: get(&c.overflowed),
            refused: get(&c.refused),
            refused_lease: get(&c.refused_lease),
            blocked: get(&c.blocked),
            throttled: get(&c.throttled),
            refusals_unanswered: get(&c.refusals_unanswered),
            undecodable: get(&c.undecodable),
            rcl_errors: get(&c.rcl_errors),
            publish_errors: get(&c.publish_errors),
            delivery_last_ns: get(&c.delivery_last_ns),
            delivery_max_ns: get(&c.delivery_max_ns),
            delivery_sum_ns: get(&c.delivery_sum_ns),
            delivery_count: get(&c.delivery_count),
        }
    }

    /// CLOCK_MONOTONIC ns of the last request applied here (0: none yet).
    pub fn last_command_ns(&self) -> i64 {
        self.shared.last_command_ns.load(Ordering::Acquire)
    }

    /// The last rcl or decoding error the thread met, as text (empty: none).
    pub fn last_error(&self) -> String {
        lock(&self.shared.last_error).clone()
    }

    /// How the thread is scheduled ("SCHED_FIFO 50 on CPUs [0]", or "normal: <why not>").
    pub fn scheduling(&self) -> String {
        lock(&self.shared.scheduling).clone()
    }

    /// The next request queued for Python (publishers served in turn, each one's requests
    /// in order) with its publisher's GID, waiting up to `timeout`. The caller must call
    /// `deferred_done` once it has handled it (that publisher's later requests queue behind it
    /// until then). None on timeout or once stopped with nothing left.
    pub fn next_deferred(&self, timeout: Duration) -> Option<(Vec<u8>, Gid)> {
        let mut queue = lock(&self.shared.queue);
        if !queue.has_ready() && !self.shared.stop.load(Ordering::Acquire) {
            queue = self
                .shared
                .queued
                .wait_timeout_while(queue, timeout, |q| {
                    !q.has_ready() && !self.shared.stop.load(Ordering::Acquire)
                })
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
        queue.pop()
    }

    /// The request taken with `next_deferred` has been handled.
    pub fn deferred_done(&self) {
        if lock(&self.shared.queue).done() {
            let _ = self
                .shared
                .pending
                .fetch_update(Ordering::AcqRel, Ordering::Acquire, |p| p.checked_sub(1));
        }
    }

    /// Publishers with requests queued for Python or in hand right now.
    pub fn waiting_publishers(&self) -> usize {
        lock(&self.shared.queue).publishers()
    }
}

/// Requests for Python, one FIFO per publisher, served round robin. At most one request is in
/// Python's hands at a time (one consumer thread).
#[derive(Default)]
struct FairQueue {
    /// Publishers with something queued or in hand, with their queued requests.
    lanes: Vec<(Gid, VecDeque<Vec<u8>>)>,
    /// Where the round robin looks next.
    next: usize,
    /// Queued requests, all lanes.
    total: usize,
    /// The publisher whose request Python is handling.
    in_hand: Option<Gid>,
}

impl FairQueue {
    /// Requests of `publisher` queued or in hand.
    fn pending_of(&self, publisher: &Gid) -> usize {
        let queued = self
            .lanes
            .iter()
            .find(|(g, _)| g == publisher)
            .map_or(0, |(_, q)| q.len());
        queued + usize::from(self.in_hand.as_ref() == Some(publisher))
    }

    fn push(&mut self, publisher: Gid, data: Vec<u8>) {
        self.total += 1;
        match self.lanes.iter_mut().find(|(g, _)| *g == publisher) {
            Some((_, q)) => q.push_back(data),
            None => self.lanes.push((publisher, VecDeque::from([data]))),
        }
    }

    /// Something to hand out: queued requests and nothing in hand.
    fn has_ready(&self) -> bool {
        self.total > 0 && self.in_hand.is_none()
    }

    fn pop(&mut self) -> Option<(Vec<u8>, Gid)> {
        if !self.has_ready() {
            return None;
        }
        let n = self.lanes.len();
        for step in 0..n {
            let k = (self.next + step) % n;
            let (gid, q) = &mut self.lanes[k];
            if let Some(data) = q.pop_front() {
                let gid = *gid;
                self.total -= 1;
                self.in_hand = Some(gid);
                self.next = k + 1;
                return Some((data, gid));
            }
        }
        None
    }

    /// The request in hand is done; true if there was one.
    fn done(&mut self) -> bool {
        let Some(gid) = self.in_hand.take() else {
            return false;
        };
        if let Some(k) = self
            .lanes
            .iter()
            .position(|(g, q)| *g == gid && q.is_empty())
        {
            self.lanes.remove(k);
            if self.next > k {
                self.next -= 1;
            }
        }
        true
    }

    fn publishers(&self) -> usize {
        let holding = self
            .in_hand
            .is_some_and(|g| !self.lanes.iter().any(|(l, _)| *l == g));
        self.lanes.len() + usize::from(holding)
    }
}

impl Drop for CommandReceiver {
    fn drop(&mut self) {
        self.stop();
    }
}

struct Target {
    engine: Arc<Engine>,
    resolver: Resolver,
}

struct Worker {
    shared: Arc<Shared>,
    rcl: Rcl,
    results: usize,
    message: MessageKind,
    lease: Option<Arc<LeaseGate>>,
}

impl Worker {
    fn run(
        self,
        handles: &ReceiverHandles,
        priority: i32,
        cpus: &[usize],
        ready: mpsc::Sender<Result<(), String>>,
    ) {
        let mut scheduling = set_priority(priority);
        if let Some(placement) = set_affinity(cpus) {
            scheduling.push_str(&placement);
        }
        *lock(&self.shared.scheduling) = scheduling;
        // SAFETY: Python keeps the context and the subscription alive (and marked in use) until
        // it has stopped this thread.
        let waiter = unsafe {
            SubscriptionWaiter::new(
                &self.rcl,
                handles.context as *mut c_void,
                handles.subscription as *const c_void,
                MESSAGE_CAPACITY,
            )
        };
        let mut waiter = match waiter {
            Ok(w) => w,
            Err(e) => {
                let _ = ready.send(Err(e));
                return;
            }
        };
        let _ = ready.send(Ok(()));
        let mut scratch = Scratch::default();
        while !self.shared.stop.load(Ordering::Acquire) {
            match waiter.wait(WAIT_NS) {
                Ok(false) => continue,
                Ok(true) => {}
                Err(e) => {
                    self.failed(&self.shared.counters.rcl_errors, format!("waiting: {e}"));
                    std::thread::sleep(Duration::from_millis(10));
                    continue;
                }
            }
            loop {
                match waiter.take() {
                    Ok(Some((data, info))) => {
                        self.note_delivery(info.source_timestamp, info.received_timestamp);
                        let publisher = info.publisher_gid.data;
                        self.handle(data, &publisher, &mut scratch);
                    }
                    Ok(None) => break,
                    Err(e) => {
                        self.failed(&self.shared.counters.rcl_errors, format!("taking: {e}"));
                        break;
                    }
                }
            }
        }
    }

    fn failed(&self, counter: &AtomicU64, text: String) {
        counter.fetch_add(1, Ordering::Relaxed);
        self.shared.error(text);
    }

    fn note_delivery(&self, source_ns: i64, received_ns: i64) {
        if source_ns <= 0 || received_ns < source_ns {
            return;
        }
        let c = &self.shared.counters;
        let d = (received_ns - source_ns) as u64;
        c.delivery_last_ns.store(d, Ordering::Relaxed);
        c.delivery_max_ns.fetch_max(d, Ordering::Relaxed);
        c.delivery_sum_ns.fetch_add(d, Ordering::Relaxed);
        c.delivery_count.fetch_add(1, Ordering::Relaxed);
    }

    fn handle(&self, data: &[u8], publisher: &Gid, scratch: &mut Scratch) {
        self.shared
            .counters
            .received
            .fetch_add(1, Ordering::Relaxed);
        match self.message {
            MessageKind::WriteVariable => self.handle_write(data, publisher, scratch),
            MessageKind::JointState => self.handle_joints(data, publisher, scratch),
            MessageKind::Passthrough => {
                if self.may_command(publisher, 0, scratch) {
                    self.defer(data, publisher, 0, scratch);
                }
            }
        }
    }

    /// The lease check: true if `publisher` may command; else the request is answered as
    /// refused (with `request_id`) and false.
    fn may_command(&self, publisher: &Gid, request_id: u32, scratch: &mut Scratch) -> bool {
        let Some(gate) = self.lease.as_deref() else {
            return true;
        };
        let verdict = gate.check_gid(publisher, now_ns(), &mut scratch.holder);
        if verdict == Verdict::Allowed {
            return true;
        }
        self.shared
            .counters
            .refused_lease
            .fetch_add(1, Ordering::Relaxed);
        refusal_text(verdict, &scratch.holder, &mut scratch.why);
        self.refuse(publisher, request_id, scratch);
        false
    }

    /// Answer the request as refused with `self.message`'s prefix and `scratch.why`, unless
    /// `publisher` has spent its budget of refusal answers.
    fn refuse(&self, publisher: &Gid, request_id: u32, scratch: &mut Scratch) {
        let now = now_ns();
        if !scratch.budgets.spend(publisher, now) || !scratch.total.spend(now) {
            self.shared
                .counters
                .refusals_unanswered
                .fetch_add(1, Ordering::Relaxed);
            return;
        }
        scratch.answer.clear();
        scratch.answer.push_str(self.message.refusal_prefix());
        scratch.answer.push_str(&scratch.why);
        self.answer(request_id, false, &scratch.answer, &mut scratch.result);
    }

    fn handle_joints(&self, data: &[u8], publisher: &Gid, scratch: &mut Scratch) {
        let c = &self.shared.counters;
        if !self.may_command(publisher, 0, scratch) {
            return;
        }
        let mut names = recycle(std::mem::take(&mut scratch.names));
        let outcome = match decode_joint_state(data, &mut names) {
            Err(e) => {
                self.failed(&c.undecodable, format!("decoding a JointState: {e}"));
                scratch.why.clear();
                // The decoder's words, as Python answers a message it refuses before reading
                // it (native_commands.checked_message): "field 'name' holds a NUL at byte 5".
                let _ = write!(scratch.why, "{e}");
                Resolution::Refuse
            }
            Ok(_) if self.pending_of(publisher) > 0 => Resolution::Defer,
            Ok(command) => {
                let guard = lock(&self.shared.target);
                match guard.as_ref() {
                    Some(Target {
                        engine,
                        resolver: Resolver::Joints(table),
                    }) => match table.resolve_or_refuse(
                        &command,
                        &names,
                        &mut scratch.setpoints,
                        &mut scratch.why,
                    ) {
                        // An axis that cannot move (a fault, a blocked restart, disabled by
                        // the watchdog, a panic) gets no setpoint: the command is refused as
                        // not executed, with the reason, from the state the RT thread
                        // published last cycle (one atomic word per axis) — not the node's
                        // watch, which sees it only up to 20 ms later.
                        Resolution::Apply
                            if table.blocked(
                                &scratch.setpoints,
                                |axis| engine.axis_gate(axis).ok(),
                                engine.is_panicked(),
                                &mut scratch.why,
                            ) =>
                        {
                            c.blocked.fetch_add(1, Ordering::Relaxed);
                            Resolution::Refuse
                        }
                        Resolution::Apply if self.write_setpoints(engine, &scratch.setpoints) => {
                            Resolution::Apply
                        }
                        Resolution::Apply => Resolution::Defer,
                        other => other,
                    },
                    _ => Resolution::Defer,
                }
            }
        };
        scratch.names = recycle(names);
        match outcome {
            Resolution::Apply => {
                c.applied.fetch_add(1, Ordering::Relaxed);
            }
            Resolution::Refuse => {
                c.refused.fetch_add(1, Ordering::Relaxed);
                self.refuse(publisher, 0, scratch);
            }
            Resolution::Defer => self.defer(data, publisher, 0, scratch),
        }
    }

    /// Requests of `publisher` queued for Python or in hand (0 without a lock while nothing
    /// at all is).
    fn pending_of(&self, publisher: &Gid) -> usize {
        if self.shared.pending.load(Ordering::Acquire) == 0 {
            return 0;
        }
        lock(&self.shared.queue).pending_of(publisher)
    }

    /// Write checked setpoints into the axes' command slots; false (nothing more written) on
    /// an engine error, which is not expected while the node is active.
    fn write_setpoints(&self, engine: &Engine, setpoints: &[Setpoint]) -> bool {
        for &(axis, kind, value) in setpoints {
            if let Err(e) = engine.axis_setpoint(axis, kind, value) {
                self.shared.error(format!("writing axis {axis}: {e}"));
                return false;
            }
        }
        self.shared
            .last_command_ns
            .store(now_ns(), Ordering::Release);
        true
    }

    fn handle_write(&self, data: &[u8], publisher: &Gid, scratch: &mut Scratch) {
        let c = &self.shared.counters;
        let request = match decode_write_variable(data) {
            Ok(r) => r,
            Err(e) => {
                self.failed(&c.undecodable, format!("decoding a WriteVariable: {e}"));
                c.refused.fetch_add(1, Ordering::Relaxed);
                // The decoder's words and the request's id, as Python answers a message it
                // refuses before reading it (native_commands.checked_message).
                scratch.why.clear();
                let _ = write!(scratch.why, "pdo_listener refused: {e}");
                let request_id = write_variable_request_id(data).unwrap_or(0);
                return self.refuse(publisher, request_id, scratch);
            }
        };
        if !self.may_command(publisher, request.request_id, scratch) {
            return;
        }
        if self.pending_of(publisher) > 0 {
            return self.defer(data, publisher, request.request_id, scratch);
        }
        {
            let guard = lock(&self.shared.target);
            let Some(Target {
                engine,
                resolver: Resolver::Writes(table),
            }) = guard.as_ref()
            else {
                return self.defer(data, publisher, request.request_id, scratch);
            };
            let resolution = table.resolve(&request, &mut scratch.fields, &mut scratch.answer);
            if resolution != Resolution::Apply {
                drop(guard);
                return self.defer(data, publisher, request.request_id, scratch);
            }
            if let Err(e) = engine.write_output_fields(&scratch.fields) {
                drop(guard);
                // Not expected while the node is active; Python answers it with the reason.
                self.shared.error(format!("writing to the engine: {e}"));
                return self.defer(data, publisher, request.request_id, scratch);
            }
            self.shared
                .last_command_ns
                .store(now_ns(), Ordering::Release);
        }
        c.applied.fetch_add(1, Ordering::Relaxed);
        self.answer(
            request.request_id,
            true,
            &scratch.answer,
            &mut scratch.result,
        );
    }

    /// Queue the request for Python behind its publisher's earlier ones, or refuse it when
    /// the queue or the publisher's share of it is full.
    fn defer(&self, data: &[u8], publisher: &Gid, request_id: u32, scratch: &mut Scratch) {
        // First the publisher's rate (no lock taken: a flood refused here never contends with
        // the Python thread for the queue).
        if !scratch.deferrals.spend(publisher, now_ns()) {
            self.shared
                .counters
                .throttled
                .fetch_add(1, Ordering::Relaxed);
            scratch.why.clear();
            if self.message == MessageKind::WriteVariable {
                scratch.why.push_str("refused: ");
            }
            let _ = write!(
                scratch.why,
                "more than {DEFERRALS_PER_S} requests per second of this publisher need the \
                 node's Python checks"
            );
            self.refuse(publisher, request_id, scratch);
            return;
        }
        let mut queue = lock(&self.shared.queue);
        let full = if queue.total >= DEFERRED_LIMIT {
            Some("the node's queue of requests for Python is full")
        } else if queue.pending_of(publisher) >= PUBLISHER_LIMIT {
            Some("too many requests of this publisher wait for the node")
        } else {
            None
        };
        if let Some(why) = full {
            drop(queue);
            self.shared
                .counters
                .overflowed
                .fetch_add(1, Ordering::Relaxed);
            scratch.why.clear();
            if self.message == MessageKind::WriteVariable {
                scratch.why.push_str("refused: ");
            }
            scratch.why.push_str(why);
            self.refuse(publisher, request_id, scratch);
            return;
        }
        self.shared.pending.fetch_add(1, Ordering::AcqRel);
        queue.push(*publisher, data.to_vec());
        drop(queue);
        self.shared.queued.notify_one();
        self.shared
            .counters
            .deferred
            .fetch_add(1, Ordering::Relaxed);
    }

    /// Publish a WriteResult, serialized into `buffer` (reused).
    fn answer(&self, request_id: u32, success: bool, message: &str, buffer: &mut Vec<u8>) {
        if self.results == 0 {
            return;
        }
        encode_write_result(buffer, request_id, success, message);
        // SAFETY: Python keeps the write_results publisher alive until this thread is stopped.
        let r = unsafe { publish_serialized(&self.rcl, self.results as *const c_void, buffer) };
        if let Err(e) = r {
            self.failed(
                &self.shared.counters.publish_errors,
                format!("publishing a WriteResult: {e}"),
            );
        }
    }
}

/// Buffers reused from one request to the next.
#[derive(Default)]
struct Scratch {
    fields: Vec<ether_ros_engine::OutputField>,
    answer: String,
    /// Why a request is refused (before its prefix), and the lease holder it names.
    why: String,
    holder: String,
    result: Vec<u8>,
    setpoints: Vec<Setpoint>,
    /// Refusal answers left per publisher.
    budgets: AnswerBudgets,
    /// Refusal answers left in all.
    total: TokenBucket<{ REFUSAL_ANSWERS_TOTAL_PER_S as u64 }>,
    /// Requests for Python left per publisher.
    deferrals: DeferralBudgets,
    /// The joint names of the message being handled borrow from it; between messages the
    /// (empty) vector is kept with a 'static element type so its allocation is reused.
    names: Vec<&'static str>,
}

/// Per publisher, a token bucket of `PER_S` per second (a burst of `PER_S`), for the
/// `ANSWER_BUDGETS` publishers seen most recently; at most that many slots.
#[derive(Default)]
struct Budgets<const PER_S: u64> {
    /// (publisher, tokens × 1e9 — token-nanoseconds, so refilling needs no division —, last
    /// refill ns)
    slots: Vec<(Gid, u64, i64)>,
}

/// Refusal answers (`REFUSAL_ANSWERS_PER_S`).
type AnswerBudgets = Budgets<{ REFUSAL_ANSWERS_PER_S as u64 }>;
/// Requests handed to Python (`DEFERRALS_PER_S`).
type DeferralBudgets = Budgets<{ DEFERRALS_PER_S as u64 }>;

impl<const PER_S: u64> Budgets<PER_S> {
    const FULL: u64 = PER_S * 1_000_000_000;
    const ONE: u64 = 1_000_000_000;

    /// Take one token from `publisher`'s budget: false when it is spent.
    fn spend(&mut self, publisher: &Gid, now: i64) -> bool {
        let k = match self.slots.iter().position(|(g, _, _)| g == publisher) {
            Some(k) => k,
            None if self.slots.len() < ANSWER_BUDGETS => {
                self.slots.push((*publisher, Self::FULL, now));
                self.slots.len() - 1
            }
            None => {
                // Forget the publisher refused longest ago.
                let k = (0..self.slots.len())
                    .min_by_key(|&k| self.slots[k].2)
                    .expect("slots are full");
                self.slots[k] = (*publisher, Self::FULL, now);
                k
            }
        };
        let (_, tokens, last) = &mut self.slots[k];
        let elapsed = (now - *last).max(0) as u64;
        *tokens = tokens
            .saturating_add(elapsed.saturating_mul(PER_S))
            .min(Self::FULL);
        *last = now;
        if *tokens >= Self::ONE {
            *tokens -= Self::ONE;
            true
        } else {
            false
        }
    }
}

/// One token bucket of `PER_S` per second (a burst of `PER_S`), full at first.
struct TokenBucket<const PER_S: u64> {
    /// Tokens × 1e9 (token-nanoseconds) and the last refill, ns (None: never spent, full).
    tokens: u64,
    last: Option<i64>,
}

impl<const PER_S: u64> Default for TokenBucket<PER_S> {
    fn default() -> Self {
        Self {
            tokens: PER_S * 1_000_000_000,
            last: None,
        }
    }
}

impl<const PER_S: u64> TokenBucket<PER_S> {
    /// Take one token: false when the bucket is empty.
    fn spend(&mut self, now: i64) -> bool {
        let elapsed = self.last.map_or(0, |last| (now - last).max(0) as u64);
        self.tokens = self
            .tokens
            .saturating_add(elapsed.saturating_mul(PER_S))
            .min(PER_S * 1_000_000_000);
        self.last = Some(now);
        if self.tokens >= 1_000_000_000 {
            self.tokens -= 1_000_000_000;
            true
        } else {
            false
        }
    }
}

/// An emptied vector of string slices with another lifetime, reusing its allocation (the
/// in-place collect of a same-layout element type; no element is ever converted).
fn recycle<'b>(mut v: Vec<&str>) -> Vec<&'b str> {
    v.clear();
    v.into_iter().map(|_| "").collect()
}

/// Keep the calling thread on `cpus` (none given: wherever the process may run); describe it.
fn set_affinity(cpus: &[usize]) -> Option<String> {
    if cpus.is_empty() {
        return None;
    }
    // SAFETY: the cpu_set_t is a plain bitmap initialised by CPU_ZERO; CPU_SET is bounded below.
    let r = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_ZERO(&mut set);
        for &cpu in cpus.iter().filter(|&&c| c < libc::CPU_SETSIZE as usize) {
            libc::CPU_SET(cpu, &mut set);
        }
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set)
    };
    Some(if r == 0 {
        format!(" on CPUs {cpus:?}")
    } else {
        format!(
            " (CPUs {cpus:?} refused: {})",
            std::io::Error::last_os_error()
        )
    })
}

/// Ask for SCHED_FIFO `priority` for the calling thread; describe what it got.
pub(crate) fn set_priority(priority: i32) -> String {
    if priority <= 0 {
        return "normal (not asked for real-time priority)".into();
    }
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: sched_setscheduler on the calling thread (pid 0) with a valid parameter.
    let r = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
    if r == 0 {
        format!("SCHED_FIFO {priority}")
    } else {
        format!(
            "normal: SCHED_FIFO {priority} refused ({}; needs CAP_SYS_NICE)",
            std::io::Error::last_os_error()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gid(n: u8) -> Gid {
        [n; 16]
    }

    #[test]
    fn publishers_are_served_in_turn_each_in_order() {
        let mut q = FairQueue::default();
        for i in 0..5u8 {
            q.push(gid(1), vec![i]); // a flood from publisher 1
        }
        q.push(gid(2), vec![100]);
        q.push(gid(2), vec![101]);
        q.push(gid(3), vec![200]);
        let mut order = Vec::new();
        while let Some((data, g)) = q.pop() {
            assert!(q.pop().is_none(), "one request in hand at a time");
            order.push((g[0], data[0]));
            assert!(q.done());
        }
        assert_eq!(
            order,
            [
                (1, 0),
                (2, 100),
                (3, 200),
                (1, 1),
                (2, 101),
                (1, 2),
                (1, 3),
                (1, 4)
            ]
        );
        assert_eq!((q.total, q.publishers()), (0, 0));
        assert!(!q.done());
    }

    #[test]
    fn refusal_answers_are_bounded_in_all() {
        let mut b = TokenBucket::<{ REFUSAL_ANSWERS_TOTAL_PER_S as u64 }>::default();
        let burst = REFUSAL_ANSWERS_TOTAL_PER_S as usize;
        assert_eq!((0..burst * 2).filter(|_| b.spend(0)).count(), burst);
        // Refilled at REFUSAL_ANSWERS_TOTAL_PER_S: one more answer after 1/rate s.
        let step = 1_000_000_000 / REFUSAL_ANSWERS_TOTAL_PER_S as i64;
        assert!(!b.spend(step - 1));
        // 2 × step after the burst: two tokens back, never more than the burst.
        assert!(b.spend(2 * step) && b.spend(2 * step));
        assert!(!b.spend(2 * step));
    }

    #[test]
    fn refusal_answers_are_budgeted_per_publisher() {
        let mut b = AnswerBudgets::default();
        let burst = REFUSAL_ANSWERS_PER_S as usize;
        let answered = (0..1000).filter(|_| b.spend(&gid(1), 0)).count();
        assert_eq!(answered, burst, "a flood gets its burst, then nothing");
        assert!(b.spend(&gid(2), 0), "another publisher has its own budget");
        // Refilled at REFUSAL_ANSWERS_PER_S: one more answer after 1/rate s.
        let step = 1_000_000_000 / REFUSAL_ANSWERS_PER_S as i64;
        assert!(!b.spend(&gid(1), step - 1_000));
        assert!(b.spend(&gid(1), step + 1_000));
        for n in 3..(3 + ANSWER_BUDGETS as u8) {
            b.spend(&gid(n), 10);
        }
        assert!(b.slots.len() <= ANSWER_BUDGETS);
    }

    #[test]
    fn requests_for_python_are_budgeted_per_publisher() {
        let mut b = DeferralBudgets::default();
        let burst = DEFERRALS_PER_S as usize;
        let taken = (0..10_000).filter(|_| b.spend(&gid(1), 0)).count();
        assert_eq!(taken, burst, "a flood gets its burst, then nothing");
        assert!(b.spend(&gid(2), 0), "another publisher has its own budget");
        // A second later the flooding publisher has its rate again.
        let later = (0..10_000)
            .filter(|_| b.spend(&gid(1), 1_000_000_000))
            .count();
        assert_eq!(later, burst);
    }

    #[test]
    fn a_publisher_is_pending_while_its_request_is_in_hand() {
        let mut q = FairQueue::default();
        q.push(gid(7), vec![1]);
        assert_eq!(q.pending_of(&gid(7)), 1);
        let (_, g) = q.pop().unwrap();
        assert_eq!(g, gid(7));
        assert_eq!((q.pending_of(&gid(7)), q.pending_of(&gid(8))), (1, 0));
        assert_eq!(q.publishers(), 1);
        q.push(gid(7), vec![2]); // queued behind the one in hand
        assert!(!q.has_ready());
        q.done();
        assert_eq!(q.pop().map(|(d, _)| d), Some(vec![2]));
        q.done();
        assert_eq!(q.pending_of(&gid(7)), 0);
    }
}
