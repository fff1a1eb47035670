//! Runs a `Network` on a network interface: the `AF_PACKET` raw socket of `ether_ros_link`
//! (`SlaveSocket`, bound to EtherType 0x88A4) or its AF_XDP link (so the simulator is never the
//! slower side of an xdp master), a background thread that receives a frame, processes it through the tree of slaves
//! and sends the answer back, and the device firmware on worker threads of its own
//! (`crate::firmware`). With no workers (`threads = 0`) the frame thread runs the firmware
//! itself, on each frame and every millisecond without one (the model before the workers).
//!
//! Timing: an answer leaves as soon as the frame is processed (`Timing::Fast`), or when the
//! modelled wire would have brought it back (`Timing::Wire`: the frame's bytes at 100 Mbit/s
//! behind the frames still on the master's link, plus the time its last bit takes through the
//! slaves and back; docs/simulator.md, "Threads and timing").

use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use ether_ros_link::{Link, LinkKind, LinkOptions, SlaveSocket, XdpLink, SLAVE_IDLE_POLL_US};

use crate::firmware::{available_cpus, Roster, WorkerStats, Workers};
use crate::network::{monotonic_ns, FirmwareMode, Network};

/// Receive timeout when the line is idle (µs): the link's blocking receive returns by then.
const IDLE_POLL_US: u32 = SLAVE_IDLE_POLL_US;
/// Real-time priority the frame thread asks for (ignored when not permitted).
const RT_PRIORITY: i32 = 70;
/// Receive buffer size (largest Ethernet frame without FCS, rounded up).
const FRAME_BUF: usize = 1536;
/// Answers the `delay` fault can hold back at once.
const DELAY_QUEUE: usize = 256;

fn try_realtime() {
    // SAFETY: best-effort scheduling and memory locking; failures are ignored on purpose.
    unsafe {
        let param = libc::sched_param {
            sched_priority: RT_PRIORITY,
        };
        libc::sched_setscheduler(0, libc::SCHED_FIFO, &param);
        libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE);
    }
}

/// Where the frame loop gets frames and puts answers.
trait FrameIo: Send {
    /// Wait up to `timeout_ns` for a frame; its length, or None when none came.
    fn recv(&mut self, buf: &mut [u8], timeout_ns: u64) -> Option<usize>;
    /// Send one frame; false when the kernel refused it.
    fn send(&mut self, frame: &[u8]) -> bool;
}

impl FrameIo for SlaveSocket {
    fn recv(&mut self, buf: &mut [u8], timeout_ns: u64) -> Option<usize> {
        SlaveSocket::recv(self, buf, timeout_ns)
    }

    fn send(&mut self, frame: &[u8]) -> bool {
        SlaveSocket::send(self, frame)
    }
}

impl FrameIo for XdpLink {
    fn recv(&mut self, buf: &mut [u8], timeout_ns: u64) -> Option<usize> {
        let deadline = ether_ros_link::now_ns() + timeout_ns as i64;
        Link::recv(self, buf, deadline)
            .ok()
            .flatten()
            .map(|r| r.len)
    }

    fn send(&mut self, frame: &[u8]) -> bool {
        Link::send(self, frame).is_ok()
    }
}

fn open_io(ifname: &str, kind: LinkKind) -> io::Result<Box<dyn FrameIo>> {
    match kind {
        LinkKind::Packet => Ok(Box::new(SlaveSocket::open(ifname)?)),
        LinkKind::Xdp => Ok(Box::new(XdpLink::open(ifname, &LinkOptions::default())?)),
    }
}

/// When an answer leaves the simulator.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Timing {
    /// As soon as the frame is processed.
    #[default]
    Fast,
    /// When the modelled 100 Mbit/s wire would have brought it back (never sooner).
    Wire,
}

impl std::str::FromStr for Timing {
    type Err = String;

    fn from_str(s: &str) -> Result<Timing, String> {
        match s {
            "fast" => Ok(Timing::Fast),
            "wire" => Ok(Timing::Wire),
            other => Err(format!("unknown timing '{other}' (fast, wire)")),
        }
    }
}

/// How the runner serves an interface.
#[derive(Clone, Copy, Debug)]
pub struct RunnerOptions {
    /// How frames are received and sent (AF_PACKET or AF_XDP).
    pub link: LinkKind,
    /// Firmware worker threads: None = one per CPU the process may use; 0 = none (the frame
    /// thread runs the firmware inline, the model before the workers).
    pub threads: Option<usize>,
    /// When answers are sent (as soon as processed, or when the modelled wire would bring them).
    pub timing: Timing,
}

impl Default for RunnerOptions {
    fn default() -> Self {
        RunnerOptions {
            link: LinkKind::Packet,
            threads: None,
            timing: Timing::Fast,
        }
    }
}

/// A running frame thread and its firmware workers.
pub struct Runner {
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
    workers: Option<Workers>,
    net: Arc<Mutex<Network>>,
    /// The interface the runner serves.
    pub interface: String,
    /// The answer timing it was started with.
    pub timing: Timing,
}

impl Runner {
    /// Open the socket (errors are reported here) and start the thread.
    pub fn start(net: Arc<Mutex<Network>>, ifname: &str) -> io::Result<Runner> {
        Runner::start_with(net, ifname, RunnerOptions::default())
    }

    /// Like `start`, through the link `kind` (an AF_XDP socket for `LinkKind::Xdp`).
    pub fn start_on(net: Arc<Mutex<Network>>, ifname: &str, kind: LinkKind) -> io::Result<Runner> {
        let options = RunnerOptions {
            link: kind,
            ..Default::default()
        };
        Runner::start_with(net, ifname, options)
    }

    /// Open the link, start the firmware workers and the frame thread.
    pub fn start_with(
        net: Arc<Mutex<Network>>,
        ifname: &str,
        options: RunnerOptions,
    ) -> io::Result<Runner> {
        let sock = open_io(ifname, options.link)?;
        let threads = options.threads.unwrap_or_else(available_cpus);
        let poisoned = || io::Error::other("simulator state poisoned by a panic");
        let workers = if threads == 0 {
            net.lock()
                .map_err(|_| poisoned())?
                .set_firmware_mode(FirmwareMode::Inline);
            None
        } else {
            let roster = {
                let mut n = net.lock().map_err(|_| poisoned())?;
                if matches!(n.clock, crate::network::Clock::Manual(_)) {
                    return Err(io::Error::new(
                        io::ErrorKind::InvalidInput,
                        "a network with a manual clock cannot run on an interface",
                    ));
                }
                n.set_firmware_mode(FirmwareMode::Threads);
                let roster = Roster::new(n.cells().to_vec(), n.generation());
                n.set_roster(roster.clone());
                roster
            };
            match Workers::start(roster, threads) {
                Ok(w) => Some(w),
                Err(e) => {
                    Self::firmware_inline(&net);
                    return Err(e);
                }
            }
        };
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let net2 = net.clone();
        let timing = options.timing;
        let inline = workers.is_none();
        let handle = std::thread::Builder::new()
            .name("ether-ros-sim".into())
            .spawn(move || frame_loop(sock, net2, stop2, timing, inline));
        let handle = match handle {
            Ok(h) => h,
            Err(e) => {
                drop(workers);
                Self::firmware_inline(&net);
                return Err(e);
            }
        };
        Ok(Runner {
            stop,
            handle: Some(handle),
            workers,
            net,
            interface: ifname.to_string(),
            timing,
        })
    }

    fn firmware_inline(net: &Arc<Mutex<Network>>) {
        if let Ok(mut n) = net.lock() {
            n.clear_roster();
            n.set_firmware_mode(FirmwareMode::Inline);
        }
    }

    /// Firmware worker threads (0: the frame thread runs the firmware).
    pub fn firmware_threads(&self) -> usize {
        self.workers.as_ref().map_or(0, Workers::threads)
    }

    /// The workers' counters (empty without workers).
    pub fn worker_stats(&self) -> Vec<Arc<WorkerStats>> {
        self.workers
            .as_ref()
            .map_or_else(Vec::new, |w| w.stats.clone())
    }

    /// Stop the frame thread and the firmware workers and wait for them.
    pub fn stop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
        if let Some(mut w) = self.workers.take() {
            w.stop();
            Self::firmware_inline(&self.net);
        }
    }

    /// True while the frame thread runs.
    pub fn is_running(&self) -> bool {
        self.handle.as_ref().is_some_and(|h| !h.is_finished())
    }
}

impl Drop for Runner {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Answers held back by the `delay` fault, sent when due. Preallocated so the frame path
/// never allocates; when full, further delayed answers are dropped (and counted).
struct DelayQueue {
    frames: Vec<[u8; FRAME_BUF]>,
    lens: Vec<usize>,
    due: Vec<u64>,
    head: usize,
    count: usize,
}

impl DelayQueue {
    fn new() -> Self {
        DelayQueue {
            frames: vec![[0u8; FRAME_BUF]; DELAY_QUEUE],
            lens: vec![0; DELAY_QUEUE],
            due: vec![0; DELAY_QUEUE],
            head: 0,
            count: 0,
        }
    }

    fn push(&mut self, frame: &[u8], due: u64) -> bool {
        if self.count == DELAY_QUEUE || frame.len() > FRAME_BUF {
            return false;
        }
        let i = (self.head + self.count) % DELAY_QUEUE;
        self.frames[i][..frame.len()].copy_from_slice(frame);
        self.lens[i] = frame.len();
        self.due[i] = due;
        self.count += 1;
        true
    }

    fn next_due(&self) -> Option<u64> {
        (self.count > 0).then(|| self.due[self.head])
    }

    /// Send every answer due by `now`.
    fn send_due(&mut self, io: &mut dyn FrameIo, now: u64) -> u64 {
        let mut errors = 0;
        while self.count > 0 && self.due[self.head] <= now {
            let f = &self.frames[self.head][..self.lens[self.head]];
            if !io.send(f) {
                errors += 1;
            }
            self.head = (self.head + 1) % DELAY_QUEUE;
            self.count -= 1;
        }
        errors
    }
}

/// The master's side of the modelled wire: until when frames already sent occupy it.
struct WireModel {
    busy_until: u64,
}

impl WireModel {
    /// When the answer to a frame of `len` bytes received at `rx` would be back at the master.
    fn due(&mut self, net: &Network, len: usize, rx: u64) -> u64 {
        let (on_wire, through) = net.wire_time(len);
        self.busy_until = self.busy_until.max(rx) + on_wire;
        self.busy_until + through
    }
}

fn frame_loop(
    mut io: Box<dyn FrameIo>,
    net: Arc<Mutex<Network>>,
    stop: Arc<AtomicBool>,
    timing: Timing,
    inline: bool,
) {
    try_realtime();
    let mut buf = [0u8; FRAME_BUF];
    let mut delayed = DelayQueue::new();
    let mut wire_model = WireModel { busy_until: 0 };
    let mut last_poll = 0u64;
    let mut last_rx = 0u64;
    let idle_ns = IDLE_POLL_US as u64 * 1_000;
    while !stop.load(Ordering::Relaxed) {
        let mut wait = idle_ns;
        if delayed.next_due().is_some() {
            // Delayed answers pending: wait only until the first is due.
            let now = monotonic_ns();
            let errors = delayed.send_due(io.as_mut(), now);
            if errors > 0 {
                if let Ok(mut net) = net.lock() {
                    net.stats.send_errors += errors;
                }
            }
            if let Some(due) = delayed.next_due() {
                wait = due.saturating_sub(now).clamp(1_000, idle_ns - 1);
            }
        }
        let Some(len) = io.recv(&mut buf, wait) else {
            if wait == idle_ns && inline {
                if let Ok(mut net) = net.lock() {
                    net.poll();
                    last_poll = net.now();
                }
            }
            continue;
        };
        let rx = monotonic_ns();
        let gap = rx.saturating_sub(last_rx);
        last_rx = rx;
        let (answer, due) = match net.lock() {
            Ok(mut net) => {
                if gap < rx {
                    net.stats.max_frame_gap_ns = net.stats.max_frame_gap_ns.max(gap);
                }
                let a = net.process_frame(&mut buf[..len]);
                if inline {
                    // Frames advance the slaves they reach; a poll now and then keeps a slave
                    // behind a broken link (or a dropped-frame burst) running too.
                    let now = net.now();
                    if now.saturating_sub(last_poll) > 1_000_000 {
                        net.poll();
                        last_poll = now;
                    }
                }
                let modelled = match timing {
                    Timing::Fast => 0,
                    Timing::Wire if a => wire_model.due(&net, len, rx),
                    Timing::Wire => 0,
                };
                let fault = net.reply_delay_us() * 1_000;
                let due = if fault > 0 {
                    modelled.max(monotonic_ns() + fault)
                } else {
                    modelled
                };
                (a, due)
            }
            Err(_) => return,
        };
        if !answer {
            continue;
        }
        // Once answers are held back, later ones queue behind them: the order is kept.
        if due > monotonic_ns() || delayed.next_due().is_some() {
            if !delayed.push(&buf[..len], due) {
                if let Ok(mut net) = net.lock() {
                    net.stats.frames_dropped += 1;
                }
            }
            continue;
        }
        let sent = io.send(&buf[..len]);
        if let Ok(mut net) = net.lock() {
            let took = monotonic_ns().saturating_sub(rx);
            net.stats.max_frame_ns = net.stats.max_frame_ns.max(took);
            if !sent {
                net.stats.send_errors += 1;
            }
        }
    }
}
