//! Python bindings for the engine: `ether_ros._native.Engine` and its exceptions.
//!
//! Every call that can block (opening, transact, start/stop, close) releases the GIL. The plan
//! is a `ether_ros._native.Plan` (crate::contracts), checked when it was made.

use std::sync::{Arc, Mutex, Weak};

use ether_ros_engine::cia402::{status_flags, DriveState};
use ether_ros_engine::stats::Summary;
use ether_ros_engine::{
    flags, AxisStatus, Engine, Error, InProcessLink, LinkKind, LinkOptions, Mode, OutputField,
    Point, Request, Responder, SetpointKind, RECORD_LEN,
};
use ether_ros_protocol::{Command, MAX_FRAME_LEN};
use ether_ros_sim::network::Network;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList, PyTuple, PyType};

use crate::sim_bindings::SimNetwork;

use crate::errors::errors_class;

/// `ether_ros.errors.EngineError` (a `LinkError`).
fn engine_error(py: Python<'_>) -> Bound<'_, PyType> {
    errors_class(py, "EngineError")
}

/// `ether_ros.errors.EngineTimeout`: an `EngineError` and a `FrameTimeout`, with the frame's
/// commands, the attempts and the wait as data.
fn engine_timeout(py: Python<'_>) -> Bound<'_, PyType> {
    errors_class(py, "EngineTimeout")
}

/// The engine's error as the Python exception of its kind, its data as attributes.
fn to_py(py: Python<'_>, e: Error) -> PyErr {
    let text = e.to_string();
    let (err, attrs): (PyErr, Vec<(&str, Py<PyAny>)>) = match e {
        Error::Invalid(m) => (
            PyErr::from_type(errors_class(py, "InvalidRequest"), m),
            vec![],
        ),
        Error::Timeout {
            link,
            commands,
            attempts,
            timeout_us,
        } => {
            let attrs = (|| -> PyResult<Vec<(&str, Py<PyAny>)>> {
                Ok(vec![
                    ("link", link.into_pyobject(py)?.into_any().unbind()),
                    ("commands", PyTuple::new(py, commands)?.into_any().unbind()),
                    ("attempts", attempts.into_pyobject(py)?.into_any().unbind()),
                    (
                        "timeout_us",
                        timeout_us.into_pyobject(py)?.into_any().unbind(),
                    ),
                ])
            })()
            .unwrap_or_default();
            (PyErr::from_type(engine_timeout(py), text), attrs)
        }
        Error::Link { errno, .. }
        | Error::Realtime(ether_ros_engine::rt::SetupError { errno, .. }) => {
            let errno = errno
                .into_pyobject(py)
                .map(|v| v.into_any().unbind())
                .unwrap_or_else(|_| py.None());
            (
                PyErr::from_type(engine_error(py), text),
                vec![("errno", errno)],
            )
        }
        Error::State(_) => (PyErr::from_type(engine_error(py), text), vec![]),
    };
    let value = err.value(py);
    for (name, v) in attrs {
        // Setting an attribute on a fresh exception cannot fail short of memory exhaustion.
        let _ = value.setattr(name, v);
    }
    err
}

/// "pp, pv, hm, csp, csv, cst".
fn mode_names() -> String {
    Mode::ALL.map(|m| m.name()).join(", ")
}

/// A trajectory point as Python gives it: (t_ns, position, velocity).
type PointTuple = (i64, f64, f64);

fn setpoint_kind(kind: &str) -> PyResult<SetpointKind> {
    match kind {
        "position" => Ok(SetpointKind::Position),
        "velocity" => Ok(SetpointKind::Velocity),
        "torque" => Ok(SetpointKind::Torque),
        _ => Err(PyValueError::new_err(format!(
            "setpoint kind '{kind}': expected position, velocity or torque"
        ))),
    }
}

fn axis_status_dict<'py>(py: Python<'py>, s: &AxisStatus) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let state = DriveState::NAMES
        .get(s.state as usize)
        .copied()
        .unwrap_or("not_ready_to_switch_on");
    let mode = Mode::from_code(s.mode_display).map(Mode::name);
    d.set_item("cycle", s.cycle)?;
    d.set_item("state", state)?;
    d.set_item("statusword", s.statusword)?;
    d.set_item("controlword", s.controlword)?;
    d.set_item("mode_display", mode)?;
    d.set_item("mode_display_code", s.mode_display)?;
    d.set_item("flags", s.flags)?;
    for (name, bit) in [
        ("enable_wanted", status_flags::ENABLE_WANTED),
        ("mode_reached", status_flags::MODE_REACHED),
        ("trajectory_active", status_flags::TRAJECTORY_ACTIVE),
        ("trajectory_done", status_flags::TRAJECTORY_DONE),
        ("following_error_exceeded", status_flags::FOLLOWING_ERROR),
        ("retries_exhausted", status_flags::RETRIES_EXHAUSTED),
        ("halted", status_flags::HALTED),
        ("outside_limits", status_flags::OUTSIDE_LIMITS),
        ("restart_blocked", status_flags::RESTART_BLOCKED),
        ("limit_active", status_flags::LIMIT_ACTIVE),
        ("idle", status_flags::IDLE),
        ("homing_attained", status_flags::HOMING_ATTAINED),
        ("homing_error", status_flags::HOMING_ERROR),
        ("homing_active", status_flags::HOMING_ACTIVE),
        ("trajectory_stopped", status_flags::TRAJECTORY_STOPPED),
    ] {
        d.set_item(name, s.flags & bit != 0)?;
    }
    d.set_item("error_code", s.error_code)?;
    d.set_item("last_fault_code", s.last_fault_code)?;
    d.set_item("position_raw", s.position_raw)?;
    d.set_item("velocity_raw", s.velocity_raw)?;
    d.set_item("torque_raw", s.torque_raw)?;
    d.set_item("following_error_raw", s.following_error_raw)?;
    d.set_item("target_position_raw", s.target_position_raw)?;
    d.set_item("position", s.position)?;
    d.set_item("velocity", s.velocity)?;
    d.set_item("torque", s.torque)?;
    d.set_item("following_error", s.following_error)?;
    d.set_item("target_position", s.target_position)?;
    d.set_item("desired_velocity", s.desired_velocity)?;
    d.set_item("target_velocity", s.target_velocity)?;
    d.set_item("target_torque", s.target_torque)?;
    d.set_item("position_clamps", s.position_clamps)?;
    d.set_item("velocity_clamps", s.velocity_clamps)?;
    d.set_item("torque_clamps", s.torque_clamps)?;
    d.set_item("faults", s.faults)?;
    d.set_item("fault_resets", s.fault_resets)?;
    d.set_item("homing_runs", s.homing_runs)?;
    d.set_item("command_seq", s.command_seq)?;
    Ok(d)
}

// ----- datagram requests -------------------------------------------------------------------

fn parse_command(v: &Bound<'_, PyAny>, i: usize) -> PyResult<Command> {
    if let Ok(code) = v.extract::<u8>() {
        return Command::from_u8(code).ok_or_else(|| {
            PyValueError::new_err(format!("datagram {i}: unknown command code {code}"))
        });
    }
    if let Ok(name) = v.extract::<String>() {
        return (0..=14u8)
            .filter_map(Command::from_u8)
            .find(|c| c.name().eq_ignore_ascii_case(&name))
            .ok_or_else(|| {
                PyValueError::new_err(format!("datagram {i}: unknown command '{name}'"))
            });
    }
    Err(PyValueError::new_err(format!(
        "datagram {i}: the command must be an int code or a name like 'FPRD'"
    )))
}

fn parse_requests(datagrams: &Bound<'_, PyAny>) -> PyResult<Vec<Request>> {
    let mut out = Vec::new();
    for (i, item) in datagrams.try_iter()?.enumerate() {
        let item = item?;
        let t = item.cast::<PyTuple>().map_err(|_| {
            PyValueError::new_err(format!(
                "datagram {i} must be a tuple (cmd, address, data or length)"
            ))
        })?;
        if t.len() != 3 {
            return Err(PyValueError::new_err(format!(
                "datagram {i} must be a tuple (cmd, address, data or length), got {} items",
                t.len()
            )));
        }
        let cmd = parse_command(&t.get_item(0)?, i)?;
        let address: u32 = t.get_item(1)?.extract().map_err(|_| {
            PyValueError::new_err(format!(
                "datagram {i}: the address must be an int 0..=2**32-1"
            ))
        })?;
        let third = t.get_item(2)?;
        let (data, len) = if let Ok(n) = third.extract::<usize>() {
            (None, n)
        } else if let Ok(b) = third.extract::<Vec<u8>>() {
            let n = b.len();
            (Some(b), n)
        } else {
            return Err(PyValueError::new_err(format!(
                "datagram {i}: the third item must be bytes to write or a length to read"
            )));
        };
        out.push(Request {
            cmd,
            address,
            data,
            len,
        });
    }
    Ok(out)
}

// ----- the in-process link -----------------------------------------------------------------

/// A responder that lets the simulator's network process each frame in place. The network's
/// mutex is shared with the `SimNetwork` methods Python calls (slave_info, fault, ...), so the
/// in-process link is for tests and running without root, not for hard real time.
fn sim_responder(net: Arc<Mutex<Network>>) -> Responder {
    Box::new(move |buf: &mut [u8], len: usize| {
        let mut net = net.lock().ok()?;
        net.process_frame(&mut buf[..len]).then_some(len)
    })
}

/// A responder that hands each frame to `net.process_frame(bytes) -> bytes | None`. It takes
/// the GIL per frame: fine for tests and running without root, not for real-time use (the
/// veth/NIC path never touches Python).
fn python_responder(net: Py<PyAny>) -> Responder {
    Box::new(move |buf: &mut [u8], len: usize| {
        // SAFETY: a plain query of the interpreter state. After finalisation started (an engine
        // still running at exit) there is no Python left to answer: the frame is lost.
        if unsafe { pyo3::ffi::Py_IsInitialized() } == 0 {
            return None;
        }
        Python::attach(|py| {
            let reply = net
                .call_method1(py, "process_frame", (PyBytes::new(py, &buf[..len]),))
                .ok()?;
            if reply.is_none(py) {
                return None;
            }
            let bytes: Vec<u8> = reply.extract(py).ok()?;
            let n = bytes.len().min(MAX_FRAME_LEN);
            buf[..n].copy_from_slice(&bytes[..n]);
            Some(n)
        })
    })
}

// ----- the class ---------------------------------------------------------------------------

/// Every engine ever opened, so the interpreter's exit can stop RT threads that are still
/// running (they must not outlive Python, least of all one that calls into the simulator).
static ENGINES: Mutex<Vec<Weak<Engine>>> = Mutex::new(Vec::new());

fn track(engine: Engine) -> Arc<Engine> {
    let engine = Arc::new(engine);
    let mut all = ENGINES.lock().unwrap_or_else(|e| e.into_inner());
    all.retain(|w| w.strong_count() > 0);
    all.push(Arc::downgrade(&engine));
    engine
}

/// Registered with `atexit`: close every engine still alive.
#[pyfunction]
fn _close_all_engines(py: Python<'_>) {
    let all: Vec<Arc<Engine>> = ENGINES
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .iter()
        .filter_map(Weak::upgrade)
        .collect();
    py.detach(move || all.iter().for_each(|e| e.close()));
}

/// A histogram summary as `stats()` reports it.
fn summary_dict<'py>(py: Python<'py>, s: &Summary) -> PyResult<Bound<'py, PyDict>> {
    let h = PyDict::new(py);
    h.set_item("count", s.count)?;
    h.set_item("min", s.min)?;
    h.set_item("max", s.max)?;
    h.set_item("mean", s.mean)?;
    h.set_item("p50", s.p50)?;
    h.set_item("p99", s.p99)?;
    h.set_item("p999", s.p999)?;
    Ok(h)
}

/// The master's engine: the link, acyclic datagrams, and the cyclic real-time thread.
#[pyclass(name = "Engine", module = "ether_ros._native", frozen)]
pub struct PyEngine {
    pub(crate) inner: Arc<Engine>,
}

impl Drop for PyEngine {
    /// An engine dropped while cyclic stops its RT thread here. Python holds the GIL during
    /// deallocation; it is released for the join, since an RT thread calling a Python
    /// responder needs it to finish its cycle.
    fn drop(&mut self) {
        if Arc::strong_count(&self.inner) == 1 && self.inner.is_running() {
            let engine = self.inner.clone();
            // SAFETY: a plain query of the interpreter state.
            if unsafe { pyo3::ffi::Py_IsInitialized() } != 0 {
                Python::attach(|py| py.detach(move || engine.stop_cyclic()));
            } else {
                engine.stop_cyclic();
            }
        }
    }
}

#[pymethods]
impl PyEngine {
    /// Open network interface `ifname` through `link`: "packet" (an AF_PACKET raw socket,
    /// needs CAP_NET_RAW) or "xdp" (an AF_XDP socket and its XDP program, needs CAP_NET_RAW,
    /// CAP_NET_ADMIN and CAP_BPF). `busy_poll_us` > 0 turns on the kernel's busy polling.
    /// `qdisc_bypass` false (AF_PACKET only) sends through the kernel's transmit queue, so a
    /// capture on the interface sees the master's frames.
    #[staticmethod]
    #[pyo3(signature = (ifname, link = "packet", busy_poll_us = 0, qdisc_bypass = true))]
    fn open_interface(
        py: Python<'_>,
        ifname: String,
        link: &str,
        busy_poll_us: u32,
        qdisc_bypass: bool,
    ) -> PyResult<PyEngine> {
        let kind: LinkKind = link.parse().map_err(PyValueError::new_err)?;
        let options = LinkOptions {
            busy_poll_us,
            qdisc_bypass,
        };
        let engine = py
            .detach(|| Engine::open_interface_with(&ifname, kind, &options))
            .map_err(|e| to_py(py, e))?;
        Ok(PyEngine {
            inner: track(engine),
        })
    }

    /// Talk to an in-process simulator: a `SimNetwork` (frames go straight to the Rust
    /// network, no GIL), or any object with `process_frame(bytes) -> bytes | None` (called
    /// with the GIL, for tests).
    #[staticmethod]
    fn open_sim(net: Bound<'_, PyAny>) -> PyResult<PyEngine> {
        let link = if let Ok(sim) = net.cast::<SimNetwork>() {
            InProcessLink::new("SimNetwork", sim_responder(sim.borrow().shared()))
        } else if net.hasattr("process_frame")? {
            let name = net
                .get_type()
                .name()
                .map(|n| n.to_string())
                .unwrap_or_default();
            InProcessLink::new(&name, python_responder(net.unbind()))
        } else {
            return Err(PyValueError::new_err(
                "open_sim needs a SimNetwork or an object with a process_frame(bytes) method",
            ));
        };
        Ok(PyEngine {
            inner: track(Engine::with_link(Box::new(link))),
        })
    }

    /// Send the datagrams `[(cmd, address, data or length), ...]` in one frame; returns
    /// `[(data, wkc), ...]`. `cmd` is a code or a name ('FPRD').
    #[pyo3(signature = (datagrams, timeout_us = 2000, retries = 3))]
    fn transact<'py>(
        &self,
        py: Python<'py>,
        datagrams: Bound<'py, PyAny>,
        timeout_us: u64,
        retries: u32,
    ) -> PyResult<Bound<'py, PyList>> {
        let requests = parse_requests(&datagrams)?;
        let engine = self.inner.clone();
        let timeout_ns = (timeout_us as i64).saturating_mul(1000);
        let replies = py
            .detach(move || engine.transact(&requests, timeout_ns, retries))
            .map_err(|e| to_py(py, e))?;
        let items: Vec<Bound<'py, PyTuple>> = replies
            .into_iter()
            .map(|(data, wkc)| {
                PyTuple::new(
                    py,
                    [
                        PyBytes::new(py, &data).into_any(),
                        wkc.into_pyobject(py)?.into_any(),
                    ],
                )
            })
            .collect::<PyResult<_>>()?;
        PyList::new(py, items)
    }

    /// Start the cyclic RT thread with `plan` (see docs/engine.md).
    fn start_cyclic(
        &self,
        py: Python<'_>,
        plan: PyRef<'_, crate::contracts::Plan>,
    ) -> PyResult<()> {
        let plan = plan.engine();
        let engine = self.inner.clone();
        py.detach(move || engine.start_cyclic(plan))
            .map_err(|e| to_py(py, e))
    }

    /// Stop and join the RT thread (no-op when it is not running).
    fn stop_cyclic(&self, py: Python<'_>) {
        let engine = self.inner.clone();
        py.detach(move || engine.stop_cyclic());
    }

    /// Write output bytes at image `offset` (inside the plan's output ranges); feeds the
    /// watchdog.
    fn write_outputs(&self, py: Python<'_>, offset: usize, data: Vec<u8>) -> PyResult<()> {
        self.inner
            .write_outputs(offset, &data)
            .map_err(|e| to_py(py, e))
    }

    /// Write output variables `[(bit_offset, bit_length, raw), ...]` in one go: only their bits
    /// change, all reach the wire in the same cycle, and a bad field writes nothing (see
    /// docs/engine.md); feeds the watchdog.
    fn write_output_fields(&self, py: Python<'_>, fields: Vec<(usize, u32, u64)>) -> PyResult<()> {
        let fields: Vec<OutputField> = fields
            .into_iter()
            .map(|(bit_offset, bit_length, raw)| OutputField {
                bit_offset,
                bit_length,
                raw,
            })
            .collect();
        let engine = self.inner.clone();
        py.detach(move || engine.write_output_fields(&fields))
            .map_err(|e| to_py(py, e))
    }

    /// Names of the plan's CiA 402 axes; an axis's index in this list is its `axis` argument.
    fn axis_names(&self, py: Python<'_>) -> PyResult<Vec<String>> {
        self.inner.axis_names().map_err(|e| to_py(py, e))
    }

    /// Ask axis `axis` for Operation Enabled (True) or its on_stop command (False).
    fn axis_enable(&self, py: Python<'_>, axis: usize, enable: bool) -> PyResult<()> {
        self.inner
            .axis_enable(axis, enable)
            .map_err(|e| to_py(py, e))
    }

    /// Ask for a fault reset (rising edge of controlword bit 7).
    fn axis_reset_fault(&self, py: Python<'_>, axis: usize) -> PyResult<()> {
        self.inner.axis_reset_fault(axis).map_err(|e| to_py(py, e))
    }

    /// Command a mode of operation by name: pp, pv, hm, csp, csv, cst.
    fn axis_set_mode(&self, py: Python<'_>, axis: usize, mode: &str) -> PyResult<()> {
        let m = Mode::from_name(mode).ok_or_else(|| {
            PyValueError::new_err(format!("mode '{mode}': expected one of {}", mode_names()))
        })?;
        self.inner.axis_set_mode(axis, m).map_err(|e| to_py(py, e))
    }

    /// A setpoint in SI units: kind 'position', 'velocity' or 'torque'.
    fn axis_setpoint(&self, py: Python<'_>, axis: usize, kind: &str, value: f64) -> PyResult<()> {
        let k = setpoint_kind(kind)?;
        self.inner
            .axis_setpoint(axis, k, value)
            .map_err(|e| to_py(py, e))
    }

    /// Setpoints `[(axis, kind, value), ...]` taken over by all axes in the same cycle.
    fn axis_setpoints(&self, py: Python<'_>, setpoints: Vec<(usize, String, f64)>) -> PyResult<()> {
        let mut list = Vec::with_capacity(setpoints.len());
        for (axis, kind, value) in setpoints {
            list.push((axis, setpoint_kind(&kind)?, value));
        }
        self.inner.axis_setpoints(&list).map_err(|e| to_py(py, e))
    }

    /// A quiet stop on the axes named (engine indices), all in the same cycle.
    fn axis_stop(&self, py: Python<'_>, axes: Vec<usize>) -> PyResult<()> {
        self.inner.axis_stop(&axes).map_err(|e| to_py(py, e))
    }

    /// Start homing on axis `axis` (in mode hm).
    fn axis_home(&self, py: Python<'_>, axis: usize) -> PyResult<()> {
        self.inner.axis_home(axis).map_err(|e| to_py(py, e))
    }

    /// One trajectory for several axes `[(axis, [(t_ns, position, velocity), ...]), ...]`,
    /// all started in the same cycle, times from `start_ns` (engine clock).
    fn axis_follow_many(
        &self,
        py: Python<'_>,
        start_ns: i64,
        tracks: Vec<(usize, Vec<PointTuple>)>,
    ) -> PyResult<u64> {
        let tracks: Vec<(usize, Vec<Point>)> = tracks
            .into_iter()
            .map(|(axis, pts)| {
                let pts = pts
                    .into_iter()
                    .map(|(t_ns, position, velocity)| Point {
                        t_ns,
                        position,
                        velocity,
                    })
                    .collect();
                (axis, pts)
            })
            .collect();
        let refs: Vec<(usize, &[Point])> = tracks.iter().map(|(a, p)| (*a, p.as_slice())).collect();
        self.inner
            .axis_follow_many(start_ns, &refs)
            .map_err(|e| to_py(py, e))
    }

    /// Run a trajectory `[(t_ns, position, velocity), ...]` (t from `start_ns`, engine clock).
    fn axis_follow(
        &self,
        py: Python<'_>,
        axis: usize,
        start_ns: i64,
        points: Vec<(i64, f64, f64)>,
    ) -> PyResult<u64> {
        let points: Vec<Point> = points
            .into_iter()
            .map(|(t_ns, position, velocity)| Point {
                t_ns,
                position,
                velocity,
            })
            .collect();
        self.inner
            .axis_follow(axis, start_ns, &points)
            .map_err(|e| to_py(py, e))
    }

    /// The axis's status as last published by the RT thread (a dict; docs/cia402.md).
    fn axis_status<'py>(&self, py: Python<'py>, axis: usize) -> PyResult<Bound<'py, PyDict>> {
        let s = self.inner.axis_status(axis).map_err(|e| to_py(py, e))?;
        axis_status_dict(py, &s)
    }

    /// The latest process image: inputs as last received, outputs as last sent.
    fn read_inputs<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        let image = self.inner.read_inputs().map_err(|e| to_py(py, e))?;
        Ok(PyBytes::new(py, &image))
    }

    /// The output buffer as commanded (what goes on the wire unless panic or watchdog; after
    /// a watchdog trip the safe values until written again).
    fn outputs<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        let engine = self.inner.clone();
        let out = py
            .detach(move || engine.outputs())
            .map_err(|e| to_py(py, e))?;
        Ok(PyBytes::new(py, &out))
    }

    /// Up to `max` samples: (records, images) as bytes; decode with
    /// `ether_ros.master.samples.decode_samples`.
    #[pyo3(signature = (max = 1 << 20))]
    fn drain_samples<'py>(
        &self,
        py: Python<'py>,
        max: usize,
    ) -> (Bound<'py, PyBytes>, Bound<'py, PyBytes>) {
        let (records, images, _) = self.inner.drain_samples(max);
        (PyBytes::new(py, &records), PyBytes::new(py, &images))
    }

    /// Counters plus, per histogram (wake_latency, exec, period, rtt), a dict
    /// {count, min, max, mean, p50, p99, p999} in ns.
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let snap = self.inner.stats();
        let out = PyDict::new(py);
        for (name, v) in snap.counters {
            out.set_item(name, v)?;
        }
        for (name, s) in snap.histograms {
            out.set_item(name, summary_dict(py, &s)?)?;
        }
        let frames = PyList::empty(py);
        for f in snap.frames {
            let d = PyDict::new(py);
            d.set_item("every", f.every)?;
            for (name, v) in f.counters {
                d.set_item(name, v)?;
            }
            d.set_item("rtt", summary_dict(py, &f.rtt)?)?;
            d.set_item("last_good_cycle", f.last_good_cycle)?;
            d.set_item("last_good_ns", f.last_good_ns)?;
            frames.append(d)?;
        }
        out.set_item("frames", frames)?;
        Ok(out)
    }

    /// Bit k: cyclic frame k's inputs are stale now (every bit set while not cyclic).
    fn stale_mask(&self) -> u32 {
        self.inner.stale_mask()
    }

    fn reset_stats(&self, py: Python<'_>) {
        let engine = self.inner.clone();
        py.detach(move || engine.reset_stats());
    }

    /// Put the safe image on the wire from the next cyclic frame on, until `clear_panic()`.
    fn panic(&self) {
        self.inner.panic();
    }

    /// End the panic without restarting: the output buffer is reset to the safe image first,
    /// so every slave's outputs stay at their safe values until a new command for them (a
    /// partial write changes only what it writes); CiA 402 axes follow their `restart` rule.
    /// Feeds the watchdog. Waits for the output writer mutex (GIL released).
    fn clear_panic(&self, py: Python<'_>) {
        let engine = self.inner.clone();
        py.detach(move || engine.clear_panic());
    }

    /// Count as a fresh command for the watchdog without writing outputs (after a watchdog
    /// trip the outputs stay at their safe values until written again).
    fn feed_watchdog(&self, py: Python<'_>) {
        let engine = self.inner.clone();
        py.detach(move || engine.feed_watchdog());
    }

    /// Put the safe image's bytes into the output buffer at image bytes `offset..offset+len`
    /// (inside one output range): a slave back in OP starts from its safe values. Not a
    /// command (feeds no watchdog).
    fn reset_outputs(&self, py: Python<'_>, offset: usize, len: usize) -> PyResult<()> {
        let engine = self.inner.clone();
        py.detach(move || engine.reset_outputs(offset, len))
            .map_err(|e| to_py(py, e))
    }

    #[getter]
    fn is_running(&self) -> bool {
        self.inner.is_running()
    }

    #[getter]
    fn is_panicked(&self) -> bool {
        self.inner.is_panicked()
    }

    #[getter]
    fn is_closed(&self) -> bool {
        self.inner.is_closed()
    }

    /// What the engine is attached to ("interface 'veth0'", "in-process SimNetwork").
    #[getter]
    fn link(&self) -> String {
        self.inner.describe().to_string()
    }

    /// Stop the RT thread and close the link.
    fn close(&self, py: Python<'_>) {
        let engine = self.inner.clone();
        py.detach(move || engine.close());
    }

    /// CLOCK_MONOTONIC in ns (the engine's time base).
    #[staticmethod]
    fn now_ns() -> i64 {
        ether_ros_engine::now_ns()
    }

    fn __enter__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    fn __exit__(
        &self,
        py: Python<'_>,
        _t: Option<Bound<'_, PyAny>>,
        _v: Option<Bound<'_, PyAny>>,
        _tb: Option<Bound<'_, PyAny>>,
    ) {
        self.close(py);
    }

    fn __repr__(&self) -> String {
        format!(
            "<Engine on {}{}>",
            self.inner.describe(),
            if self.inner.is_running() {
                ", cyclic"
            } else {
                ""
            }
        )
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add_class::<PyEngine>()?;
    let close_all = wrap_pyfunction!(_close_all_engines, m)?;
    py.import("atexit")?
        .call_method1("register", (close_all,))?;
    m.add("EngineError", engine_error(py))?;
    m.add("EngineTimeout", engine_timeout(py))?;
    m.add("SAMPLE_RECORD_LEN", RECORD_LEN)?;
    let f = PyDict::new(py);
    for (name, bit) in [
        ("lost", flags::LOST),
        ("late", flags::LATE),
        ("wkc_error", flags::WKC_ERROR),
        ("panic", flags::PANIC),
        ("watchdog", flags::WATCHDOG),
        ("unmatched", flags::UNMATCHED),
        ("dc_adjusted", flags::DC_ADJUSTED),
        ("acyclic", flags::ACYCLIC),
        ("overrun", flags::OVERRUN),
        ("send_error", flags::SEND_ERROR),
    ] {
        f.set_item(name, bit)?;
    }
    m.add("SAMPLE_FLAGS", f)?;
    Ok(())
}
