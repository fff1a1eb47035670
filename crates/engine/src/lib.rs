//! The master's engine: owns the link, serves acyclic datagrams for the Python bring-up, and
//! runs the cyclic real-time thread in OP. See docs/engine.md and docs/architecture.md.
//!
//! Ownership of the link moves: while the bus is not cyclic, `transact` uses it in the calling
//! thread; `start_cyclic` hands it to the RT thread, which returns it when `stop_cyclic` joins
//! it. While cyclic, `transact` posts its frame to a one-slot mailbox that the RT thread sends
//! after the cyclic frame.

#![warn(missing_docs)]

pub mod cia402;
pub(crate) mod cyclic;
pub(crate) mod fields;
pub(crate) mod frames;
pub(crate) mod handover;
pub mod plan;
pub mod rt;
pub mod stats;

use std::sync::atomic::Ordering;
use std::sync::{mpsc, Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use cia402::AxisCommand;
pub use cia402::{AxisGate, AxisStatus, Mode, Point, SetpointKind};
use cyclic::{Cyclic, Exchange, Shared, RESET_ALL};
pub use fields::OutputField;
pub use frames::Request;
use frames::{build_request_frame, reply_datagrams, reply_matches};
use handover::mailbox_state;
pub use handover::{flags, SampleRecord, RECORD_LEN};
// The links live in their own crate (shared with the simulator); the engine's users reach
// them through it as before.
pub use ether_ros_link::{
    clock, now_ns, InProcessLink, Link, LinkKind, LinkOptions, RawSocketLink, Received, Responder,
    XdpLink, XdpMode,
};
pub use plan::Plan;

use stats::Summary;

use ether_ros_protocol::MAX_FRAME_LEN;

/// What went wrong, by kind, with its data (the Python binding maps each kind to an exception
/// class of `ether_ros.errors` and hands the data over as attributes).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Error {
    /// Bad argument: plan, datagrams, output write (what is wrong, in words; no protocol code).
    Invalid(String),
    /// The link failed: opening, sending or receiving.
    Link {
        /// The link (`packet on eth0`, or the interface when it could not be opened).
        link: String,
        /// What was being done.
        action: LinkAction,
        /// The OS error code, when the OS gave one.
        errno: Option<i32>,
        /// The OS's words for it.
        detail: String,
    },
    /// No reply to an acyclic frame within its retries.
    Timeout {
        /// The link.
        link: String,
        /// The frame's datagram commands.
        commands: Vec<&'static str>,
        /// Frames sent.
        attempts: u32,
        /// Wait per attempt, µs.
        timeout_us: i64,
    },
    /// Wrong state for the call.
    State(StateError),
    /// The real-time setup was refused (policy, affinity, memory lock).
    Realtime(rt::SetupError),
}

/// What a link was doing when it failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkAction {
    /// Opening the interface.
    Open,
    /// Sending a frame.
    Send,
    /// Receiving a frame.
    Receive,
}

/// A call the engine's state does not allow.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StateError {
    /// The engine on this link is closed.
    Closed(String),
    /// `start_cyclic` while the cyclic thread runs.
    AlreadyCyclic,
    /// Process data before `start_cyclic`.
    NoProcessImage,
    /// The RT thread ended during its setup.
    RtThreadEnded,
}

impl Error {
    /// The link error of `e` while doing `action` on `link`.
    pub fn link(link: &str, action: LinkAction, e: &std::io::Error) -> Error {
        Error::Link {
            link: link.to_string(),
            action,
            errno: e.raw_os_error(),
            detail: e.to_string(),
        }
    }
}

impl std::fmt::Display for Error {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Error::Invalid(m) => f.write_str(m),
            Error::Link {
                link,
                action,
                detail,
                ..
            } => match action {
                LinkAction::Open => f.write_str(detail),
                LinkAction::Send => write!(f, "cannot send on {link}: {detail}"),
                LinkAction::Receive => write!(f, "cannot receive on {link}: {detail}"),
            },
            Error::Timeout {
                link,
                commands,
                attempts,
                timeout_us,
            } => write!(
                f,
                "no reply to the frame [{}] on {link} after {attempts} attempt(s) of {timeout_us} µs",
                commands.join(", ")
            ),
            Error::State(StateError::Closed(link)) => write!(f, "the engine on {link} is closed"),
            Error::State(StateError::AlreadyCyclic) => {
                f.write_str("the cyclic thread is already running")
            }
            Error::State(StateError::NoProcessImage) => {
                f.write_str("no process image yet: call start_cyclic first")
            }
            Error::State(StateError::RtThreadEnded) => {
                f.write_str("the RT thread ended during setup")
            }
            Error::Realtime(e) => f.write_str(&e.message),
        }
    }
}

impl std::error::Error for Error {}

/// The engine's result: every failure is an [`Error`] that the bindings turn into the
/// typed Python error of its kind.
pub type Result<T> = std::result::Result<T, Error>;

enum LinkState {
    Idle(Box<dyn Link>),
    Cyclic(JoinHandle<Box<dyn Link>>),
    Closed,
}

/// Counters and histogram summaries, as `stats()` reports them.
#[derive(Clone, Debug, Default)]
pub struct StatsSnapshot {
    /// Counters by name (cycles, lost frames, ...).
    pub counters: Vec<(&'static str, u64)>,
    /// Histogram summaries by name (wake latency, execution, period, round trip).
    pub histograms: Vec<(&'static str, Summary)>,
    /// Per cyclic frame of the current (or last) run, in plan order.
    pub frames: Vec<FrameSnapshot>,
}

/// One cyclic frame's counters and round trip.
#[derive(Clone, Debug, Default)]
pub struct FrameSnapshot {
    /// Sent every this many cycles.
    pub every: u32,
    /// The frame's counters by name (sent, lost, late, ...).
    pub counters: Vec<(&'static str, u64)>,
    /// The frame's round trip.
    pub rtt: Summary,
    /// 1 + the cycle whose reply last came back whole (0: none yet) and its arrival
    /// (CLOCK_MONOTONIC ns): how fresh the frame's inputs in the image are.
    pub last_good_cycle: u64,
    /// When that reply arrived (CLOCK_MONOTONIC ns).
    pub last_good_ns: u64,
}

/// The real-time EtherCAT engine: owns the link, runs the cyclic exchange on its RT thread,
/// passes acyclic frames through it, and hands the image, samples and axis statuses to Python.
pub struct Engine {
    shared: Arc<Shared>,
    state: Mutex<LinkState>,
    exchange: Mutex<Option<Arc<Exchange>>>,
    /// Serialises `transact` callers: the mailbox has one slot.
    acyclic: Mutex<()>,
    /// Serialises writers of the output buffer (the seqlock allows one writer); holds the
    /// scratch bytes `write_output_fields` merges fields into, reused from call to call.
    output_writer: Mutex<Vec<u8>>,
    /// Serialises writers of the axis command slots; holds each axis's command as last written,
    /// with the cyclic run (`Exchange::run`) they belong to, so a new run starts afresh.
    axis_writer: Mutex<AxisWriter>,
    /// Serialises consumers of the sample ring.
    drain: Mutex<()>,
    description: String,
}

/// The axis commands as last written, with the cyclic run (`Exchange::run`) they belong to
/// (a new run starts afresh) and the number of the last setpoint or trajectory.
#[derive(Default)]
struct AxisWriter {
    run: u64,
    commands: Vec<AxisCommand>,
    seq: u64,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

enum MailboxOutcome {
    Reply(Vec<u8>),
    Timeout,
    Aborted,
}

impl Engine {
    /// An engine on a raw socket bound to `ifname`.
    pub fn open_interface(ifname: &str) -> Result<Engine> {
        Engine::open_interface_with(ifname, LinkKind::Packet, &LinkOptions::default())
    }

    /// An engine on `ifname` through the link `kind`.
    pub fn open_interface_with(
        ifname: &str,
        kind: LinkKind,
        options: &LinkOptions,
    ) -> Result<Engine> {
        let link: Box<dyn Link> = match kind {
            LinkKind::Packet => {
                RawSocketLink::open_with(ifname, options).map(|l| Box::new(l) as Box<dyn Link>)
            }
            LinkKind::Xdp => XdpLink::open(ifname, options).map(|l| Box::new(l) as Box<dyn Link>),
        }
        .map_err(|e| Error::link(ifname, LinkAction::Open, &e))?;
        Ok(Engine::with_link(link))
    }

    /// An engine on any link (in-process simulator, test responders).
    pub fn with_link(link: Box<dyn Link>) -> Engine {
        let description = link.describe();
        Engine {
            shared: Arc::new(Shared::default()),
            state: Mutex::new(LinkState::Idle(link)),
            exchange: Mutex::new(None),
            acyclic: Mutex::new(()),
            output_writer: Mutex::new(Vec::new()),
            axis_writer: Mutex::new(AxisWriter::default()),
            drain: Mutex::new(()),
            description,
        }
    }

    /// The link's description (interface and kind), for messages.
    pub fn describe(&self) -> &str {
        &self.description
    }

    /// Join an RT thread that ended on its own (it never does unless it panicked), so the link
    /// is back in our hands.
    fn reap(&self, state: &mut LinkState) {
        if let LinkState::Cyclic(h) = state {
            if h.is_finished() {
                self.join_into(state);
            }
        }
    }

    fn join_into(&self, state: &mut LinkState) {
        if let LinkState::Cyclic(h) = std::mem::replace(state, LinkState::Closed) {
            self.shared.stop.store(true, Ordering::Release);
            *state = match h.join() {
                Ok(link) => LinkState::Idle(link),
                Err(_) => LinkState::Closed,
            };
            self.shared.mailbox.abort_pending();
        }
    }

    /// Send `requests` in one frame and return each datagram's (data, working counter).
    pub fn transact(
        &self,
        requests: &[Request],
        timeout_ns: i64,
        retries: u32,
    ) -> Result<Vec<(Vec<u8>, u16)>> {
        let _serial = lock(&self.acyclic);
        let mut frame = [0u8; MAX_FRAME_LEN];
        let mut attempts = 0u32;
        while attempts <= retries {
            let index = self.shared.acyclic_index.fetch_add(1, Ordering::Relaxed) & 0x7f;
            let n = build_request_frame(&mut frame, index, requests).map_err(Error::Invalid)?;
            let request = &frame[..n];
            let mut state = lock(&self.state);
            self.reap(&mut state);
            match &mut *state {
                LinkState::Idle(link) => {
                    attempts += 1;
                    if let Some(reply) = self.direct_attempt(link.as_mut(), request, timeout_ns)? {
                        return Ok(reply_datagrams(&reply));
                    }
                }
                LinkState::Cyclic(_) => {
                    drop(state);
                    match self.mailbox_attempt(request, timeout_ns) {
                        MailboxOutcome::Reply(reply) => return Ok(reply_datagrams(&reply)),
                        MailboxOutcome::Timeout => attempts += 1,
                        // The RT thread stopped meanwhile: try again on the direct path.
                        MailboxOutcome::Aborted => {}
                    }
                }
                LinkState::Closed => return Err(self.closed()),
            }
        }
        Err(Error::Timeout {
            link: self.description.clone(),
            commands: requests.iter().map(|r| r.cmd.name()).collect(),
            attempts: retries + 1,
            timeout_us: timeout_ns / 1000,
        })
    }

    fn closed(&self) -> Error {
        Error::State(StateError::Closed(self.description.clone()))
    }

    fn direct_attempt(
        &self,
        link: &mut dyn Link,
        request: &[u8],
        timeout_ns: i64,
    ) -> Result<Option<Vec<u8>>> {
        link.send(request)
            .map_err(|e| Error::link(&self.description, LinkAction::Send, &e))?;
        let deadline = now_ns() + timeout_ns;
        let mut buf = vec![0u8; MAX_FRAME_LEN];
        loop {
            match link.recv(&mut buf, deadline) {
                Ok(Some(r)) => {
                    let reply = &buf[..r.len];
                    if reply_matches(request, reply, false) {
                        return Ok(Some(reply.to_vec()));
                    }
                    self.shared
                        .stats
                        .counters
                        .unmatched_frames
                        .fetch_add(1, Ordering::Relaxed);
                }
                Ok(None) => return Ok(None),
                Err(e) => return Err(Error::link(&self.description, LinkAction::Receive, &e)),
            }
        }
    }

    fn mailbox_attempt(&self, request: &[u8], timeout_ns: i64) -> MailboxOutcome {
        let mb = &self.shared.mailbox;
        mb.post(request, timeout_ns);
        let cycle = self.shared.cycle_ns.load(Ordering::Relaxed);
        // The RT thread picks the request up within a cycle; allow generous slack before
        // concluding it never will.
        let give_up = now_ns() + timeout_ns + 4 * cycle + 200_000_000;
        let nap = Duration::from_nanos((cycle / 8).clamp(10_000, 200_000) as u64);
        loop {
            match mb.state.load(Ordering::Acquire) {
                mailbox_state::DONE => {
                    let reply = mb.reply();
                    mb.state.store(mailbox_state::EMPTY, Ordering::Release);
                    return MailboxOutcome::Reply(reply);
                }
                mailbox_state::TIMEOUT => {
                    mb.state.store(mailbox_state::EMPTY, Ordering::Release);
                    return MailboxOutcome::Timeout;
                }
                mailbox_state::ABORTED => {
                    mb.state.store(mailbox_state::EMPTY, Ordering::Release);
                    return MailboxOutcome::Aborted;
                }
                mailbox_state::REQUESTED if now_ns() > give_up && mb.cancel() => {
                    return MailboxOutcome::Timeout;
                }
                _ => {}
            }
            if !self.shared.alive.load(Ordering::Acquire) {
                // The loop ended (stop or crash): nothing will answer from there any more.
                mb.abort_pending();
            }
            std::thread::sleep(nap);
        }
    }

    /// Start the RT thread with `plan`. Fails if the plan is invalid, the thread is already
    /// running, or the real-time setup is refused.
    pub fn start_cyclic(&self, plan: Plan) -> Result<()> {
        plan.validate()
            .map_err(|e| Error::Invalid(format!("invalid cyclic plan: {e}")))?;
        let layout = plan.layout().map_err(Error::Invalid)?;
        let mut state = lock(&self.state);
        self.reap(&mut state);
        let link = match std::mem::replace(&mut *state, LinkState::Closed) {
            LinkState::Idle(link) => link,
            other => {
                let running = matches!(other, LinkState::Cyclic(_));
                *state = other;
                return Err(if running {
                    Error::State(StateError::AlreadyCyclic)
                } else {
                    self.closed()
                });
            }
        };
        let rt = plan.rt;
        let cycle_ns = plan.cycle_ns;
        let mut ex = Exchange::new(plan, &layout);
        ex.run = self.shared.runs.fetch_add(1, Ordering::Relaxed) + 1;
        let ex = Arc::new(ex);
        let shared = self.shared.clone();
        shared.stop.store(false, Ordering::Release);
        shared.alive.store(false, Ordering::Release);
        shared.cycle_ns.store(cycle_ns as i64, Ordering::Relaxed);
        // start_cyclic counts as a command for every watchdog.
        shared.last_command_ns.store(now_ns(), Ordering::Release);
        ex.note_command_all(now_ns());
        let mut cyclic = Cyclic::new(link, shared.clone(), ex.clone(), layout);
        let (ready_tx, ready_rx) = mpsc::sync_channel::<std::result::Result<(), rt::SetupError>>(1);
        let spawned = std::thread::Builder::new()
            .name("ether_ros-rt".into())
            .stack_size(rt::RT_STACK)
            .spawn(move || {
                let setup = rt::apply(&rt, cycle_ns);
                let ok = setup.is_ok();
                // Alive from before start_cyclic returns, so is_running() is true at once.
                shared.alive.store(ok, Ordering::Release);
                let _ = ready_tx.send(setup);
                if ok {
                    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| cyclic.run()));
                    if r.is_err() {
                        shared.alive.store(false, Ordering::Release);
                    }
                }
                cyclic.link
            });
        let handle = match spawned {
            Ok(h) => h,
            Err(e) => {
                return Err(Error::Realtime(rt::SetupError {
                    message: format!("cannot start the RT thread: {e}"),
                    errno: e.raw_os_error(),
                }))
            }
        };
        match ready_rx.recv() {
            Ok(Ok(())) => {
                *state = LinkState::Cyclic(handle);
                *lock(&self.exchange) = Some(ex);
                Ok(())
            }
            Ok(Err(msg)) => {
                *state = LinkState::Cyclic(handle);
                self.join_into(&mut state);
                Err(Error::Realtime(msg))
            }
            Err(_) => {
                *state = LinkState::Cyclic(handle);
                self.join_into(&mut state);
                Err(Error::State(StateError::RtThreadEnded))
            }
        }
    }

    /// Stop and join the RT thread (no-op when not running).
    pub fn stop_cyclic(&self) {
        let mut state = lock(&self.state);
        self.join_into(&mut state);
    }

    /// Stop and release the link (closes the socket).
    pub fn close(&self) {
        let mut state = lock(&self.state);
        self.join_into(&mut state);
        *state = LinkState::Closed;
    }

    /// True once `close` gave the link back.
    pub fn is_closed(&self) -> bool {
        matches!(*lock(&self.state), LinkState::Closed)
    }

    /// True while the cyclic RT thread runs.
    pub fn is_running(&self) -> bool {
        matches!(*lock(&self.state), LinkState::Cyclic(_))
            && self.shared.alive.load(Ordering::Acquire)
    }

    fn exchange(&self) -> Result<Arc<Exchange>> {
        lock(&self.exchange)
            .clone()
            .ok_or(Error::State(StateError::NoProcessImage))
    }

    /// Write output bytes at image `offset`; the range must lie inside the plan's outputs.
    /// A command: feeds the watchdogs of the frames it touches. After a watchdog trip or a
    /// clear_panic only these bytes go live; the rest stays at the safe image's values until
    /// written (`command_write`).
    pub fn write_outputs(&self, offset: usize, data: &[u8]) -> Result<()> {
        let ex = self.exchange()?;
        let end = offset.saturating_add(data.len());
        ex.check_output_span(
            offset,
            end,
            &format!("write of {} byte(s) at image offset {offset}", data.len()),
        )
        .map_err(Error::Invalid)?;
        let mut scratch = lock(&self.output_writer);
        self.command_write(&ex, offset, end, &mut scratch, |ex, _| {
            ex.outputs.write(offset, data)
        });
        Ok(())
    }

    /// A command's write into the output buffer, under the output writer lock (`scratch`):
    /// feed the watchdogs of the bytes `begin..end`, put the safe image back where a stop
    /// voided the commands (`Exchange::apply_resets`), then `write`. A write changes only what
    /// it writes: after a stop every other output stays at its safe value until a command
    /// for it arrives.
    ///
    /// The feed comes first: a watchdog that trips after it would void this very command. If
    /// a trip's reset bit shows up all the same before the write is done (the writer was
    /// preempted for a whole watchdog period, or the RT thread read the old command time an
    /// instant before), the reset and the write are done again, so the command wins over the
    /// stop it arrived after. A bit the RT thread publishes after this check (a trip decided
    /// in the same instant as the feed) voids the command with the trip: the safe side.
    fn command_write(
        &self,
        ex: &Exchange,
        begin: usize,
        end: usize,
        scratch: &mut Vec<u8>,
        mut write: impl FnMut(&Exchange, &mut Vec<u8>),
    ) {
        let now = now_ns();
        self.shared.last_command_ns.store(now, Ordering::Release);
        ex.note_command(begin, end, now);
        for _ in 0..3 {
            ex.apply_resets(0);
            write(ex, scratch);
            if ex.reset_pending.load(Ordering::Acquire) == 0 {
                break;
            }
        }
    }

    /// Put the configured safe values (the plan's `safe_image`) into the output buffer at
    /// image bytes `offset..offset + len` (inside one output range), e.g. for a slave that
    /// comes back to OP after it dropped out: it starts from its safe values, not from what
    /// was commanded before. Not a command: it feeds no watchdog.
    pub fn reset_outputs(&self, offset: usize, len: usize) -> Result<()> {
        let ex = self.exchange()?;
        let end = offset.saturating_add(len);
        ex.check_output_span(
            offset,
            end,
            &format!("reset of {len} byte(s) at image offset {offset}"),
        )
        .map_err(Error::Invalid)?;
        let _w = lock(&self.output_writer);
        ex.apply_resets(0);
        ex.outputs.write(offset, &ex.plan.safe_image[offset..end]);
        Ok(())
    }

    /// Write several output fields at once: they reach the wire in the same cycle (one seqlock
    /// write over the byte span they cover) and bits outside the fields keep their value, so
    /// writers of different variables never undo each other. Every field must lie inside the
    /// plan's output ranges and be well formed (bit_length 1..=64, raw fits), else nothing is
    /// written (Error::Invalid naming the bad field). Feeds the watchdog like write_outputs,
    /// and like it makes only its own bits live after a stop (the other bits of the span are
    /// read after the reset a stop owes the buffer, so they keep their safe values).
    pub fn write_output_fields(&self, fields: &[OutputField]) -> Result<()> {
        if fields.is_empty() {
            return Ok(());
        }
        let ex = self.exchange()?;
        let (mut first, mut end) = (usize::MAX, 0);
        for (i, f) in fields.iter().enumerate() {
            let describe = || {
                format!(
                    "output field #{i} (bit offset {}, {} bit(s), raw {:#x})",
                    f.bit_offset, f.bit_length, f.raw
                )
            };
            if let Some(why) = f.form_error() {
                return Err(Error::Invalid(format!("{}: {why}", describe())));
            }
            let (a, b) = f.byte_span().expect("checked by form_error");
            ex.check_output_span(
                a,
                b,
                &format!("{} covers image bytes {a}..{b}, which", describe()),
            )
            .map_err(Error::Invalid)?;
            first = first.min(a);
            end = end.max(b);
        }
        // Holding the writer lock makes us the buffer's only writer, so the bytes read here
        // are current (a reset owed already applied) and nobody changes them before the write.
        let mut scratch = lock(&self.output_writer);
        self.command_write(&ex, first, end, &mut scratch, |ex, scratch| {
            scratch.clear();
            scratch.resize(end - first, 0);
            ex.outputs.read_as_writer(first, scratch);
            for f in fields {
                f.apply(scratch, first);
            }
            ex.outputs.write(first, scratch);
        });
        Ok(())
    }

    /// Names of the plan's CiA 402 axes, in plan order (their indices for the axis calls).
    pub fn axis_names(&self) -> Result<Vec<String>> {
        Ok(self
            .exchange()?
            .plan
            .axes
            .iter()
            .map(|a| a.name.clone())
            .collect())
    }

    /// Change the commands of the axes in `axes` with `change` (under the axis writer mutex,
    /// so the Python API and a native command thread never undo each other's requests) and
    /// hand all commands to the RT thread in one write: the axes named take their new
    /// commands in the same cycle. Feeds the watchdog first (an axis command is a command;
    /// an enable that ends a watchdog stop then arrives after the stop's end, see
    /// `AxisController::restart_blocked`).
    fn update_axes(
        &self,
        axes: &[usize],
        mut change: impl FnMut(usize, &mut AxisCommand, u64),
    ) -> Result<u64> {
        let ex = self.exchange()?;
        let mut slots = lock(&self.axis_writer);
        if slots.run != ex.run {
            // A new cyclic run: start again from the plan's initial commands.
            slots.run = ex.run;
            slots.commands = ex
                .plan
                .axes
                .iter()
                .map(|a| AxisCommand::initial(a.mode))
                .collect();
        }
        let n = ex.plan.axes.len();
        if let Some(&bad) = axes.iter().find(|&&a| a >= n) {
            return Err(Error::Invalid(format!(
                "axis index {bad} is out of range (the plan has {n} axes)"
            )));
        }
        slots.seq += 1;
        let seq = slots.seq;
        for (k, &axis) in axes.iter().enumerate() {
            change(k, &mut slots.commands[axis], seq);
        }
        let mut bytes = vec![0u8; n * cia402::COMMAND_LEN];
        for (c, b) in slots
            .commands
            .iter()
            .zip(bytes.chunks_exact_mut(cia402::COMMAND_LEN))
        {
            c.encode(b);
        }
        self.feed_watchdog();
        ex.axes.commands.write(0, &bytes);
        Ok(seq)
    }

    fn update_axis(&self, axis: usize, change: impl FnOnce(&mut AxisCommand)) -> Result<()> {
        let mut change = Some(change);
        self.update_axes(&[axis], |_, c, _| {
            if let Some(f) = change.take() {
                f(c)
            }
        })
        .map(|_| ())
    }

    /// Ask for Operation Enabled (`true`: an explicit enable, also the deliberate action a
    /// blocked restart waits for) or the axis's `on_stop` command (`false`).
    pub fn axis_enable(&self, axis: usize, enable: bool) -> Result<()> {
        self.update_axis(axis, |c| {
            c.enable = enable;
            if enable {
                c.enable_count = c.enable_count.wrapping_add(1);
            }
        })
    }

    /// Ask for a fault reset (a rising edge of controlword bit 7 while the drive is in Fault);
    /// also gives the automatic reset its retries back. It does not enable the axis.
    pub fn axis_reset_fault(&self, axis: usize) -> Result<()> {
        self.update_axis(axis, |c| c.reset_count = c.reset_count.wrapping_add(1))
    }

    /// Command a mode of operation (0x6060); targets wait until 0x6061 shows it, and the new
    /// mode starts from the actual state (docs/cia402.md, "Mode changes").
    pub fn axis_set_mode(&self, axis: usize, mode: Mode) -> Result<()> {
        self.update_axis(axis, |c| c.mode = mode)
    }

    /// A quiet stop on the axes named, all in the same cycle: each decelerates from the state
    /// it is commanded to have to rest at its `deceleration`, then holds (docs/cia402.md,
    /// "Quiet stop"). Ends trajectories and setpoint streams.
    pub fn axis_stop(&self, axes: &[usize]) -> Result<()> {
        self.update_axes(axes, |_, c, seq| {
            c.seq = seq;
            c.setpoint_kind = cia402::STOP_COMMAND;
        })
        .map(|_| ())
    }

    /// Start homing (mode hm; controlword bit 4 until the drive reports attained or error).
    pub fn axis_home(&self, axis: usize) -> Result<()> {
        self.update_axis(axis, |c| c.homing_count = c.homing_count.wrapping_add(1))
    }

    /// A setpoint in SI units, stamped with its arrival time; it replaces any trajectory.
    pub fn axis_setpoint(&self, axis: usize, kind: SetpointKind, value: f64) -> Result<()> {
        self.axis_setpoints(&[(axis, kind, value)])
    }

    /// Setpoints for several axes, taken over by all of them in the same cycle.
    pub fn axis_setpoints(&self, setpoints: &[(usize, SetpointKind, f64)]) -> Result<()> {
        for &(axis, _, value) in setpoints {
            if !value.is_finite() {
                return Err(Error::Invalid(format!(
                    "axis {axis}: setpoint {value} is not a finite number"
                )));
            }
        }
        let axes: Vec<usize> = setpoints.iter().map(|s| s.0).collect();
        if let Some(twice) = axes
            .iter()
            .enumerate()
            .find(|(i, a)| axes[..*i].contains(a))
        {
            return Err(Error::Invalid(format!("axis {} is given twice", twice.1)));
        }
        let t = now_ns();
        self.update_axes(&axes, |k, c, seq| {
            c.seq = seq;
            c.setpoint_kind = setpoints[k].1 as u8;
            c.value = setpoints[k].2;
            c.t_ns = t;
        })
        .map(|_| ())
    }

    /// Execute `points` (times from `start_ns`, CLOCK_MONOTONIC; strictly increasing, finite
    /// values, at most the plan's trajectory_capacity) on the engine's clock. Returns the
    /// command's number (`AxisStatus::command_seq` once taken over).
    pub fn axis_follow(&self, axis: usize, start_ns: i64, points: &[Point]) -> Result<u64> {
        self.axis_follow_many(start_ns, &[(axis, points)])
    }

    /// One trajectory for several axes, handed over at once: every axis starts it in the same
    /// cycle (once all of them have their points), from the state it is commanded to have
    /// then, on the common `start_ns` (docs/cia402.md, "Trajectories"). Returns the command's
    /// number, the same for all of them.
    pub fn axis_follow_many(&self, start_ns: i64, tracks: &[(usize, &[Point])]) -> Result<u64> {
        let ex = self.exchange()?;
        let cap = ex.axes.trajectory_capacity;
        if tracks.is_empty() {
            return Err(Error::Invalid("a trajectory names no axis".into()));
        }
        for (k, &(axis, points)) in tracks.iter().enumerate() {
            if tracks[..k].iter().any(|t| t.0 == axis) {
                return Err(Error::Invalid(format!("axis {axis} is given twice")));
            }
            if points.is_empty() || points.len() > cap {
                return Err(Error::Invalid(format!(
                    "axis {axis}: a trajectory takes 1..={cap} points, got {}",
                    points.len()
                )));
            }
            for (i, p) in points.iter().enumerate() {
                let ordered = i == 0 || p.t_ns > points[i - 1].t_ns;
                if p.t_ns < 0 || !ordered || !p.position.is_finite() || !p.velocity.is_finite() {
                    return Err(Error::Invalid(format!(
                        "axis {axis}: trajectory point #{i} ({p:?}): times must be >= 0 and \
                         strictly increasing, positions and velocities finite"
                    )));
                }
            }
        }
        let axes: Vec<usize> = tracks.iter().map(|t| t.0).collect();
        // The points first, tagged with the seq the commands will carry; then the commands of
        // all axes in one write.
        self.update_axes(&axes, |k, c, seq| {
            let (axis, points) = tracks[k];
            let mut bytes = vec![0u8; cia402::TRAJECTORY_HEADER + points.len() * cia402::POINT_LEN];
            bytes[..8].copy_from_slice(&seq.to_le_bytes());
            for (p, b) in points
                .iter()
                .zip(bytes[cia402::TRAJECTORY_HEADER..].chunks_exact_mut(cia402::POINT_LEN))
            {
                p.encode(b);
            }
            ex.axes.trajectories[axis].write(0, &bytes);
            c.seq = seq;
            c.setpoint_kind = cia402::TRAJECTORY_COMMAND;
            c.t_ns = start_ns;
            c.trajectory_len = points.len() as u32;
        })
    }

    /// The axis's status as the RT thread last published it.
    pub fn axis_status(&self, axis: usize) -> Result<AxisStatus> {
        let ex = self.exchange()?;
        if axis >= ex.plan.axes.len() {
            return Err(Error::Invalid(format!(
                "axis index {axis} is out of range (the plan has {} axes)",
                ex.plan.axes.len()
            )));
        }
        let all = ex.axes.status.read();
        Ok(AxisStatus::decode(
            &all[axis * cia402::STATUS_LEN..(axis + 1) * cia402::STATUS_LEN],
        ))
    }

    /// Whether the axis is in a state to move, as the RT thread published it last cycle: one
    /// atomic load (no lock on the axis state, no allocation), for the command paths that must
    /// refuse a setpoint to an axis that cannot follow it (docs/ros.md, "The command path").
    pub fn axis_gate(&self, axis: usize) -> Result<AxisGate> {
        let ex = self.exchange()?;
        let word = ex.axes.gates.get(axis).ok_or_else(|| {
            Error::Invalid(format!(
                "axis index {axis} is out of range (the plan has {} axes)",
                ex.plan.axes.len()
            ))
        })?;
        Ok(AxisGate::unpack(word.load(Ordering::Acquire)))
    }

    /// The latest process image (inputs as last received, outputs as last sent).
    pub fn read_inputs(&self) -> Result<Vec<u8>> {
        Ok(self.exchange()?.image.read())
    }

    /// Bit k: cyclic frame k's inputs in the image are stale now (no reply to it came back
    /// whole within two of its periods); every bit set while no cyclic exchange runs.
    pub fn stale_mask(&self) -> u32 {
        if !self.is_running() {
            return u32::MAX;
        }
        match self.exchange() {
            Ok(ex) => ex.stale_mask.load(Ordering::Acquire),
            Err(_) => u32::MAX,
        }
    }

    /// The output buffer as commanded (what goes on the wire unless panic/watchdog), with the
    /// resets a watchdog trip owes it applied: after a stop it shows the safe values.
    pub fn outputs(&self) -> Result<Vec<u8>> {
        let ex = self.exchange()?;
        let _w = lock(&self.output_writer);
        ex.apply_resets(0);
        Ok(ex.outputs.read())
    }

    /// Move up to `max` samples out: (records, images), `RECORD_LEN` and image_len bytes each.
    pub fn drain_samples(&self, max: usize) -> (Vec<u8>, Vec<u8>, usize) {
        let Ok(ex) = self.exchange() else {
            return (Vec::new(), Vec::new(), 0);
        };
        let _d = lock(&self.drain);
        let (mut records, mut images) = (Vec::new(), Vec::new());
        ex.ring.drain(max, &mut records, &mut images);
        (records, images, ex.plan.image_len)
    }

    /// A consistent copy of the counters and histograms.
    pub fn stats(&self) -> StatsSnapshot {
        let s = &self.shared.stats;
        StatsSnapshot {
            counters: s
                .counters
                .named()
                .iter()
                .map(|(n, c)| (*n, c.load(Ordering::Relaxed)))
                .collect(),
            histograms: s
                .histograms()
                .iter()
                .map(|(n, h)| (*n, h.summary()))
                .collect(),
            frames: lock(&self.exchange)
                .as_ref()
                .map(|ex| {
                    ex.frames
                        .iter()
                        .zip(&ex.plan.frames)
                        .map(|(f, p)| FrameSnapshot {
                            every: p.every,
                            counters: f
                                .named()
                                .iter()
                                .map(|(n, c)| (*n, c.load(Ordering::Relaxed)))
                                .collect(),
                            rtt: f.rtt.summary(),
                            last_good_cycle: f.last_good_cycle.load(Ordering::Acquire),
                            last_good_ns: f.last_good_ns.load(Ordering::Acquire),
                        })
                        .collect()
                })
                .unwrap_or_default(),
        }
    }

    /// Zero counters and histograms. While cyclic, the RT thread does it at its next wake-up
    /// (it is the histograms' only writer); this waits for that.
    pub fn reset_stats(&self) {
        if self.is_running() {
            self.shared.reset_requested.store(true, Ordering::Release);
            let cycle = self.shared.cycle_ns.load(Ordering::Relaxed);
            let until = now_ns() + 4 * cycle + 500_000_000;
            while self.shared.reset_requested.load(Ordering::Acquire)
                && self.shared.alive.load(Ordering::Acquire)
                && now_ns() < until
            {
                std::thread::sleep(Duration::from_micros(50));
            }
            if !self.shared.reset_requested.swap(false, Ordering::AcqRel) {
                return;
            }
        }
        self.shared.stats.reset();
        if let Some(ex) = lock(&self.exchange).as_ref() {
            ex.frames.iter().for_each(stats::FrameStats::reset);
        }
    }

    /// Latch the safe image onto the wire from the next cyclic frame on.
    pub fn panic(&self) {
        if !self.shared.panic.swap(true, Ordering::AcqRel) {
            self.shared
                .stats
                .counters
                .panics
                .fetch_add(1, Ordering::Relaxed);
        }
    }

    /// End the panic without restarting anything (ISO 13850): the output buffer is reset to
    /// the safe image first, so every slave's outputs stay at their safe values until a new
    /// command for them arrives (a partial write changes only what it writes), and CiA 402
    /// axes stay stopped as their `restart` rule says. Also feeds the watchdog.
    ///
    /// Order: under the output writer lock, the watchdogs are fed, the buffer reset (and the
    /// RT thread told so, `Exchange::reset_done`), and only then the panic flag cleared: the
    /// first cycle that sees the flag cleared also sees the reset, and sends the safe image
    /// for any frame whose copy of the buffer predates it.
    pub fn clear_panic(&self) {
        let Ok(ex) = self.exchange() else {
            self.feed_watchdog();
            self.shared.panic.store(false, Ordering::Release);
            return;
        };
        let _w = lock(&self.output_writer);
        let now = now_ns();
        self.shared.last_command_ns.store(now, Ordering::Release);
        ex.note_command_all(now);
        ex.apply_resets(RESET_ALL);
        self.shared.panic.store(false, Ordering::Release);
    }

    /// True after a panic stop until the panic is reset.
    pub fn is_panicked(&self) -> bool {
        self.shared.panic.load(Ordering::Acquire)
    }

    /// Count as a fresh command for the watchdog without writing outputs. Not a command for
    /// any output: after a watchdog trip the outputs stay at their safe values (the reset it
    /// owes the buffer is applied here, so `outputs()` shows them) until written again.
    pub fn feed_watchdog(&self) {
        let now = now_ns();
        self.shared.last_command_ns.store(now, Ordering::Release);
        let ex = lock(&self.exchange).clone();
        if let Some(ex) = ex {
            ex.note_command_all(now);
            let _w = lock(&self.output_writer);
            ex.apply_resets(0);
        }
    }
}

impl Drop for Engine {
    fn drop(&mut self) {
        self.stop_cyclic();
    }
}
