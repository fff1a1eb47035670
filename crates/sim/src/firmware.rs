//! Device firmware on worker threads: each slave's microcontroller runs at its own clock, apart
//! from the frame path, as on a real bus where an ESC forwards a frame in under a microsecond
//! while its firmware keeps its control loop.
//!
//! A worker owns a share of the slaves (balanced by their event rate) and keeps each one's next
//! event in a heap: a device step at the device's period, a SYNC0 event, the watchdog running
//! out or a pending SAFEOP->OP request timing out (`Esc::next_firmware_event`). It sleeps until
//! the earliest, locks that slave and advances it to the present (`Esc::advance_firmware`):
//! events are run in time order with their exact simulated times, so a late wake-up changes
//! when the work is done, never what it computes. The worker and the frame path exchange
//! process data through the SyncManager buffers (the firmware latches them at SYNC0, or around
//! its own steps in free run), as a real PDI does; a frame that reaches a slave whose SYNC0 is
//! already due latches it itself (`Esc::frame_catch_up`).
//!
//! Device steps whose time has come are gathered into wake-ups at least `STEP_GRAIN_NS`
//! apart (SYNC0 events and deadlines wake at their own instant), so a hundred slaves whose
//! control loops run at 10 kHz on unrelated phases do not cost a hundred thousand wake-ups a
//! second.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use crate::network::{lock, monotonic_ns, SlaveCell};

/// Shortest time between two wake-ups for device steps (SYNC0 and deadlines are exact).
pub const STEP_GRAIN_NS: u64 = 250_000;
/// Longest sleep: a worker looks at its stop flag and at new slaves at least this often.
const MAX_SLEEP_NS: u64 = 10_000_000;
/// Most simulated time one advance of a slave runs while holding its lock: a firmware far
/// behind (a machine too busy for its buses) catches up in pieces, and the frame thread,
/// which may be waiting for the same slave, gets in between.
pub const CHUNK_NS: u64 = 500_000;
/// A slave with nothing scheduled is looked at again after this long.
const IDLE_RECHECK_NS: u64 = 10_000_000;
/// Real-time priority of the workers when permitted: below the frame thread (70) and a
/// master's RT thread (80), above ordinary work, so device loops keep their pace on a busy
/// machine as they did when the frame thread ran them.
const WORKER_PRIORITY: i32 = 60;
/// A worker that used more than this share of a CPU over a window steps down to an ordinary
/// thread at nice `DEMOTED_NICE` (firmware heavier than the machine can run in real time —
/// a thousand slaves on two cores — then falls behind and skips, counted in
/// `device_steps_skipped`, instead of starving every other process at real-time priority);
/// below `PROMOTE_SHARE` it is real-time again.
pub const DEMOTE_SHARE: f64 = 0.6;
const PROMOTE_SHARE: f64 = 0.3;
const DEMOTED_NICE: i32 = 10;
const DUTY_WINDOW_NS: u64 = 50_000_000;

/// Counters of one worker, readable while it runs.
#[derive(Default)]
pub struct WorkerStats {
    /// Times the worker stepped down from real-time priority (`DEMOTE_SHARE`).
    pub demoted: AtomicU64,
    /// 1 while it runs at real-time priority.
    pub realtime: AtomicU64,
    /// Slaves this worker advances.
    pub slaves: AtomicU64,
    /// Times the worker woke up to advance its slaves.
    pub wakeups: AtomicU64,
    /// Slaves advanced (one lock, one `advance_firmware`).
    pub advances: AtomicU64,
    /// Largest lateness of an advance behind the event it was for, ns.
    pub max_late_ns: AtomicU64,
    /// Advances more than one millisecond behind their event.
    pub late_1ms: AtomicU64,
    /// Time spent advancing slaves (not sleeping), ns.
    pub busy_ns: AtomicU64,
}

/// The slaves as workers see them: the cells, and a generation that changes when they do.
pub struct Roster {
    cells: Mutex<Vec<SlaveCell>>,
    generation: Arc<AtomicU64>,
}

impl Roster {
    /// The roster of `cells`, stamped with the network's `generation` so a worker notices when
    /// slaves were added or removed.
    pub fn new(cells: Vec<SlaveCell>, generation: Arc<AtomicU64>) -> Arc<Roster> {
        Arc::new(Roster {
            cells: Mutex::new(cells),
            generation,
        })
    }

    /// The network changed its slaves: hand the workers the new list.
    pub fn update(&self, cells: Vec<SlaveCell>) {
        *self.cells.lock().unwrap_or_else(|e| e.into_inner()) = cells;
    }
}

/// Which worker runs which slave: greedy by event rate (device steps per second), heaviest
/// first, onto the least loaded worker.
pub fn share(cells: &[SlaveCell], workers: usize) -> Vec<Vec<usize>> {
    let workers = workers.max(1);
    let mut rates: Vec<(u64, usize)> = cells
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let esc = lock(c);
            let rate = esc
                .device
                .as_ref()
                .map_or(1, |d| 1_000_000_000 / d.period_ns().max(1_000));
            (rate, k)
        })
        .collect();
    rates.sort_unstable_by(|a, b| b.cmp(a));
    let mut load = vec![0u64; workers];
    let mut out = vec![Vec::new(); workers];
    for (rate, k) in rates {
        let w = (0..workers).min_by_key(|&w| load[w]).unwrap_or(0);
        load[w] += rate;
        out[w].push(k);
    }
    for v in &mut out {
        v.sort_unstable();
    }
    out
}

/// The running workers.
pub struct Workers {
    stop: Arc<AtomicBool>,
    handles: Vec<JoinHandle<()>>,
    /// Per-worker counters, for the simulator's statistics.
    pub stats: Vec<Arc<WorkerStats>>,
}

impl Workers {
    /// Start `n` workers (at least one) over the roster's slaves.
    pub fn start(roster: Arc<Roster>, n: usize) -> std::io::Result<Workers> {
        let n = n.max(1);
        let stop = Arc::new(AtomicBool::new(false));
        let mut handles = Vec::with_capacity(n);
        let mut stats = Vec::with_capacity(n);
        for index in 0..n {
            let st = Arc::new(WorkerStats::default());
            let (roster, stop2, st2) = (roster.clone(), stop.clone(), st.clone());
            let spawned = std::thread::Builder::new()
                .name(format!("ether-ros-fw{index}"))
                .spawn(move || worker(index, n, roster, stop2, st2));
            match spawned {
                Ok(h) => handles.push(h),
                Err(e) => {
                    stop.store(true, Ordering::SeqCst);
                    for h in handles {
                        let _ = h.join();
                    }
                    return Err(e);
                }
            }
            stats.push(st);
        }
        Ok(Workers {
            stop,
            handles,
            stats,
        })
    }

    /// Number of worker threads.
    pub fn threads(&self) -> usize {
        self.handles.len()
    }

    /// Stop the workers and wait for them to end.
    pub fn stop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        for h in self.handles.drain(..) {
            let _ = h.join();
        }
    }
}

impl Drop for Workers {
    fn drop(&mut self) {
        self.stop();
    }
}

/// CPUs this process may run on (its affinity mask).
pub fn available_cpus() -> usize {
    // SAFETY: sched_getaffinity fills the cpu_set_t we own.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        if libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) == 0 {
            let n = libc::CPU_COUNT(&set);
            if n > 0 {
                return n as usize;
            }
        }
    }
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Run the calling thread at `WORKER_PRIORITY` (true), or as an ordinary thread at
/// `DEMOTED_NICE` (false). Best effort: without permission it stays as it is.
fn set_realtime(on: bool) -> bool {
    // SAFETY: scheduling calls on the calling thread with valid arguments.
    unsafe {
        if on {
            let param = libc::sched_param {
                sched_priority: WORKER_PRIORITY,
            };
            libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) == 0
        } else {
            let param = libc::sched_param { sched_priority: 0 };
            libc::sched_setscheduler(0, libc::SCHED_OTHER, &param);
            libc::setpriority(
                libc::PRIO_PROCESS,
                libc::gettid() as libc::id_t,
                DEMOTED_NICE,
            );
            false
        }
    }
}

/// CPU time of the calling thread, ns.
fn thread_cpu_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we own.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// The worker's CPU share per window, and its priority from it.
struct Duty {
    window_start: u64,
    cpu_start: u64,
    realtime: bool,
}

impl Duty {
    fn new(now: u64) -> Duty {
        Duty {
            window_start: now,
            cpu_start: thread_cpu_ns(),
            realtime: set_realtime(true),
        }
    }

    /// At the end of each window: step down or up. Returns true when it stepped down.
    fn check(&mut self, now: u64) -> bool {
        let wall = now.saturating_sub(self.window_start);
        if wall < DUTY_WINDOW_NS {
            return false;
        }
        let cpu = thread_cpu_ns();
        let share = cpu.saturating_sub(self.cpu_start) as f64 / wall as f64;
        self.window_start = now;
        self.cpu_start = cpu;
        if self.realtime && share > DEMOTE_SHARE {
            self.realtime = set_realtime(false);
            return true;
        }
        if !self.realtime && share < PROMOTE_SHARE {
            self.realtime = set_realtime(true);
        }
        false
    }
}

fn sleep_until(t_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (t_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (t_ns % 1_000_000_000) as libc::c_long,
    };
    // SAFETY: a valid absolute timespec; an interruption just ends the sleep early.
    unsafe {
        libc::clock_nanosleep(
            libc::CLOCK_MONOTONIC,
            libc::TIMER_ABSTIME,
            &ts,
            std::ptr::null_mut(),
        );
    }
}

/// Due times of a worker's slaves: exact events (SYNC0, deadlines) and device steps, which
/// are gathered.
struct Schedule {
    exact: BinaryHeap<Reverse<(u64, usize)>>,
    steps: BinaryHeap<Reverse<(u64, usize)>>,
}

impl Schedule {
    fn new(n: usize, now: u64) -> Schedule {
        let mut exact = BinaryHeap::with_capacity(n);
        exact.extend((0..n).map(|i| Reverse((now, i))));
        Schedule {
            exact,
            steps: BinaryHeap::with_capacity(n),
        }
    }

    /// The next slave due by `now`, with its due time.
    fn pop_due(&mut self, now: u64) -> Option<(u64, usize)> {
        let e = self.exact.peek().map(|r| r.0);
        let s = self.steps.peek().map(|r| r.0);
        let heap = match (e, s) {
            (Some(e), Some(s)) if s < e => &mut self.steps,
            (Some(_), _) => &mut self.exact,
            (None, Some(_)) => &mut self.steps,
            (None, None) => return None,
        };
        let &Reverse((due, i)) = heap.peek()?;
        if due > now {
            return None;
        }
        heap.pop();
        Some((due, i))
    }

    fn push(&mut self, due: u64, exact: bool, i: usize) {
        let heap = if exact {
            &mut self.exact
        } else {
            &mut self.steps
        };
        heap.push(Reverse((due, i)));
    }

    /// When to wake: the next exact event, or the next device step but not sooner than
    /// `grain_from`.
    fn wake(&self, grain_from: u64) -> Option<u64> {
        let e = self.exact.peek().map(|r| r.0 .0);
        let s = self.steps.peek().map(|r| r.0 .0.max(grain_from));
        match (e, s) {
            (Some(e), Some(s)) => Some(e.min(s)),
            (e, s) => e.or(s),
        }
    }
}

/// One worker: its share of the slaves, each at its next event.
fn worker(
    index: usize,
    workers: usize,
    roster: Arc<Roster>,
    stop: Arc<AtomicBool>,
    stats: Arc<WorkerStats>,
) {
    let mut duty = Duty::new(monotonic_ns());
    stats
        .realtime
        .store(duty.realtime as u64, Ordering::Relaxed);
    let mut generation = u64::MAX;
    let mut mine: Vec<SlaveCell> = Vec::new();
    let mut schedule = Schedule::new(0, 0);
    let mut last_steps = 0u64;
    while !stop.load(Ordering::Acquire) {
        let g = roster.generation.load(Ordering::Acquire);
        if g != generation {
            generation = g;
            let cells = roster
                .cells
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .clone();
            let shares = share(&cells, workers);
            mine = shares[index].iter().map(|&k| cells[k].clone()).collect();
            schedule = Schedule::new(mine.len(), monotonic_ns());
            stats.slaves.store(mine.len() as u64, Ordering::Relaxed);
        }
        let now = monotonic_ns();
        let mut worked = false;
        while let Some((due, i)) = schedule.pop_due(now) {
            worked = true;
            let late = now - due;
            stats.max_late_ns.fetch_max(late, Ordering::Relaxed);
            if late > 1_000_000 {
                stats.late_1ms.fetch_add(1, Ordering::Relaxed);
            }
            let (caught_up, next) = {
                let mut esc = lock(&mine[i]);
                let caught_up = esc.advance_firmware(now, CHUNK_NS);
                (caught_up, esc.next_firmware_event(now))
            };
            stats.advances.fetch_add(1, Ordering::Relaxed);
            // A long catch-up must not run a whole window at real-time priority unchecked.
            if duty.check(monotonic_ns()) {
                stats.demoted.fetch_add(1, Ordering::Relaxed);
            }
            if !caught_up {
                // Still behind: the next piece at once (after the others due now).
                schedule.push(now, false, i);
                continue;
            }
            let (t, exact) = next.unwrap_or((now + IDLE_RECHECK_NS, true));
            schedule.push(t.clamp(now + 1, now + IDLE_RECHECK_NS), exact, i);
        }
        let done = monotonic_ns();
        if worked {
            last_steps = now;
            stats.wakeups.fetch_add(1, Ordering::Relaxed);
            stats.busy_ns.fetch_add(done - now, Ordering::Relaxed);
        }
        if duty.check(done) {
            stats.demoted.fetch_add(1, Ordering::Relaxed);
        }
        stats
            .realtime
            .store(duty.realtime as u64, Ordering::Relaxed);
        let wake = schedule
            .wake(last_steps + STEP_GRAIN_NS)
            .unwrap_or(u64::MAX)
            .min(done + MAX_SLEEP_NS);
        if wake > done {
            sleep_until(wake);
        }
    }
}
