//! The command thread: waits on the `pdo_listener` subscription, applies every request the
//! table can resolve by itself straight to the engine and answers it on `write_results`, and
//! queues the rest, in order, for the node's Python code. A second thread serves
//! `joint_commands` the same way (`MessageKind::JointState`): certainly valid commands go into
//! the engine's axis command slots, unanswered (they come at a controller's rate); the rest to
//! Python, which refuses them on `joint_results`.
//!
//! The thread lives as long as the node; an engine and its table are attached while the node
//! is active. Detached, every request goes to Python (which refuses it while the bus is not
//! running), so no command waits in the middleware to be applied later.
//!
//! Order is kept across the two paths: while a request waits in (or is being handled from) the
//! Python queue, every later request is queued behind it too, so an older value can never
//! overwrite a newer one.
//!
//! This thread is not the engine's real-time thread and may allocate; it still avoids it in the
//! steady state (buffers are reused), and it never takes the GIL.

use std::collections::VecDeque;
use std::ffi::c_void;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU64, AtomicUsize, Ordering};
use std::sync::{mpsc, Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use ether_ros_engine::{now_ns, Engine};

use crate::cdr::{decode_joint_state, decode_write_variable, encode_write_result};
use crate::joints::{JointTable, Setpoint};
use crate::rcl::{publish_serialized, Rcl, SubscriptionWaiter};
use crate::table::{CommandTable, Resolution};

/// The message type the subscription carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MessageKind {
    /// `ether_ros_msgs/WriteVariable` (`pdo_listener`), resolved with a [`CommandTable`].
    WriteVariable,
    /// `sensor_msgs/JointState` (`joint_commands`), resolved with a [`JointTable`].
    JointState,
}

/// What requests are resolved against (it must match the receiver's [`MessageKind`]).
#[derive(Debug, Clone)]
pub enum Resolver {
    Writes(CommandTable),
    Joints(JointTable),
}

/// How long one wait lasts before the thread looks at its stop flag.
const WAIT_NS: i64 = 50_000_000;
/// Requests queued for Python beyond this are refused (answered natively) rather than held.
const DEFERRED_LIMIT: usize = 1024;
/// Initial size of the buffer serialized messages are taken into (rcl grows it if needed).
const MESSAGE_CAPACITY: usize = 4096;

/// What Python hands over: the loaded libraries and the rcl objects rclpy created (addresses
/// from their `handle.pointer`). `results` is the `write_results` publisher, 0 for none.
#[derive(Debug, Clone)]
pub struct ReceiverHandles {
    pub librcl: String,
    pub librcutils: String,
    pub context: usize,
    pub subscription: usize,
    pub results: usize,
    pub message: MessageKind,
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
    /// Refused because the Python queue was full.
    pub overflowed: u64,
    /// Serialized data this decoder did not understand (handed to Python too).
    pub undecodable: u64,
    /// rcl wait/take errors and failed result publications.
    pub rcl_errors: u64,
    pub publish_errors: u64,
    /// Middleware delivery (publisher's source stamp to the subscription's receive stamp), for
    /// messages whose stamps are both set: last, largest and sum (ns).
    pub delivery_last_ns: u64,
    pub delivery_max_ns: u64,
    pub delivery_sum_ns: u64,
    pub delivery_count: u64,
}

impl ReceiverCounters {
    /// (name, value) of every counter, named as the fields.
    pub fn pairs(&self) -> [(&'static str, u64); 11] {
        [
            ("received", self.received),
            ("applied", self.applied),
            ("deferred", self.deferred),
            ("overflowed", self.overflowed),
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
    /// Requests queued for Python plus the one Python is handling.
    pending: AtomicUsize,
    queue: Mutex<VecDeque<Vec<u8>>>,
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
            queue: Mutex::new(VecDeque::new()),
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

    pub fn is_running(&self) -> bool {
        lock(&self.thread)
            .as_ref()
            .is_some_and(|t| !t.is_finished())
    }

    pub fn counters(&self) -> ReceiverCounters {
        let c = &self.shared.counters;
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        ReceiverCounters {
            received: get(&c.received),
            applied: get(&c.applied),
            deferred: get(&c.deferred),
            overflowed: get(&c.overflowed),
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

    pub fn last_error(&self) -> String {
        lock(&self.shared.last_error).clone()
    }

    /// How the thread is scheduled ("SCHED_FIFO 50 on CPUs [0]", or "normal: <why not>").
    pub fn scheduling(&self) -> String {
        lock(&self.shared.scheduling).clone()
    }

    /// The oldest request queued for Python, waiting up to `timeout`. The caller must call
    /// `deferred_done` once it has handled it (later requests queue behind it until then).
    /// None on timeout or once stopped with nothing left.
    pub fn next_deferred(&self, timeout: Duration) -> Option<Vec<u8>> {
        let mut queue = lock(&self.shared.queue);
        if queue.is_empty() && !self.shared.stop.load(Ordering::Acquire) {
            queue = self
                .shared
                .queued
                .wait_timeout_while(queue, timeout, |q| {
                    q.is_empty() && !self.shared.stop.load(Ordering::Acquire)
                })
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
        queue.pop_front()
    }

    /// One request taken with `next_deferred` has been handled.
    pub fn deferred_done(&self) {
        let _ = self
            .shared
            .pending
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |p| p.checked_sub(1));
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
                        self.handle(data, &mut scratch);
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

    fn handle(&self, data: &[u8], scratch: &mut Scratch) {
        self.shared
            .counters
            .received
            .fetch_add(1, Ordering::Relaxed);
        match self.message {
            MessageKind::WriteVariable => self.handle_write(data, scratch),
            MessageKind::JointState => self.handle_joints(data, scratch),
        }
    }

    fn handle_joints(&self, data: &[u8], scratch: &mut Scratch) {
        let c = &self.shared.counters;
        let mut names = recycle(std::mem::take(&mut scratch.names));
        let decoded = decode_joint_state(data, &mut names);
        let applied = match decoded {
            Err(e) => {
                self.failed(&c.undecodable, format!("decoding a JointState: {e}"));
                false
            }
            Ok(_) if self.shared.pending.load(Ordering::Acquire) > 0 => false,
            Ok(command) => {
                let guard = lock(&self.shared.target);
                match guard.as_ref() {
                    Some(Target {
                        engine,
                        resolver: Resolver::Joints(table),
                    }) if table.resolve(&command, &names, &mut scratch.setpoints)
                        == Resolution::Apply =>
                    {
                        self.write_setpoints(engine, &scratch.setpoints)
                    }
                    _ => false,
                }
            }
        };
        scratch.names = recycle(names);
        if applied {
            c.applied.fetch_add(1, Ordering::Relaxed);
        } else {
            self.defer(data, 0, scratch);
        }
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

    fn handle_write(&self, data: &[u8], scratch: &mut Scratch) {
        let c = &self.shared.counters;
        let request = match decode_write_variable(data) {
            Ok(r) => r,
            Err(e) => {
                self.failed(&c.undecodable, format!("decoding a WriteVariable: {e}"));
                return self.defer(data, 0, scratch);
            }
        };
        if self.shared.pending.load(Ordering::Acquire) > 0 {
            return self.defer(data, request.request_id, scratch);
        }
        {
            let guard = lock(&self.shared.target);
            let Some(Target {
                engine,
                resolver: Resolver::Writes(table),
            }) = guard.as_ref()
            else {
                return self.defer(data, request.request_id, scratch);
            };
            let resolution = table.resolve(&request, &mut scratch.fields, &mut scratch.answer);
            if resolution == Resolution::Defer {
                drop(guard);
                return self.defer(data, request.request_id, scratch);
            }
            if let Err(e) = engine.write_output_fields(&scratch.fields) {
                drop(guard);
                // Not expected while the node is active; Python answers it with the reason.
                self.shared.error(format!("writing to the engine: {e}"));
                return self.defer(data, request.request_id, scratch);
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

    fn defer(&self, data: &[u8], request_id: u32, scratch: &mut Scratch) {
        let mut queue = lock(&self.shared.queue);
        if queue.len() >= DEFERRED_LIMIT {
            drop(queue);
            self.shared
                .counters
                .overflowed
                .fetch_add(1, Ordering::Relaxed);
            self.answer(
                request_id,
                false,
                "refused: the node's queue of requests for Python is full",
                &mut scratch.result,
            );
            return;
        }
        self.shared.pending.fetch_add(1, Ordering::AcqRel);
        queue.push_back(data.to_vec());
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
    result: Vec<u8>,
    setpoints: Vec<Setpoint>,
    /// The joint names of the message being handled borrow from it; between messages the
    /// (empty) vector is kept with a 'static element type so its allocation is reused.
    names: Vec<&'static str>,
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
