//! Python bindings of the native ROS command path (`ether_ros_commands`): `CommandTable`, the
//! bus's output variables as the fast path resolves them, and `CommandReceiver`, the thread that
//! takes `WriteVariable` messages from rcl and writes them into the engine. See
//! docs/ros.md ("The command path") and `ether_ros.ros.native_commands`, their only user.

use std::time::Duration;

use std::sync::Arc;

use ether_ros_commands::lease::{refusal_text, GID_LEN, MAX_WRITERS};
use ether_ros_commands::receiver::{
    MessageKind, Resolver, ANSWER_BUDGETS, PUBLISHER_LIMIT, REFUSAL_ANSWERS_PER_S,
    REFUSAL_ANSWERS_TOTAL_PER_S,
};
use ether_ros_commands::{
    check_joint_trajectory, decode_joint_state, decode_write_variable, CommandReceiver,
    CommandTable, Gid, JointEntry, JointTable, Kind, LeaseGate, PanicKeyHandles, PanicKeys,
    ReceiverHandles, Resolution, Sent, SlaveEntry, VariableEntry, Verdict, PANIC_KEYS,
};
use ether_ros_engine::SetpointKind;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use crate::engine_bindings::PyEngine;

/// (name, index, subindex, image bit offset, bit length, kind, minimum, maximum, deferred)
type VariableRow = (String, u16, u8, usize, u32, String, f64, f64, bool);
/// (name, position, output variables)
type SlaveRow = (String, i64, Vec<VariableRow>);
/// ([(bit offset, bit length, raw)], answer): what the native path writes and answers.
type Applied = (Vec<(usize, u32, u64)>, String);

/// The output variables of a bus, for the native command path.
#[pyclass(name = "CommandTable", module = "ether_ros._native", frozen)]
pub struct PyCommandTable {
    table: CommandTable,
}

#[pymethods]
impl PyCommandTable {
    /// `slaves`: (name, position, [(name, index, subindex, bit offset in the image, bit length,
    /// kind, minimum, maximum, deferred)]) with kind one of bool, int, uint, real32, real64;
    /// `deferred`: every write of the variable goes to Python (it checks more than the range).
    #[new]
    fn new(slaves: Vec<SlaveRow>) -> PyResult<Self> {
        let mut entries = Vec::with_capacity(slaves.len());
        for (name, position, rows) in slaves {
            let mut outputs = Vec::with_capacity(rows.len());
            for (var, index, subindex, bit_offset, bit_length, kind, minimum, maximum, deferred) in
                rows
            {
                let kind = Kind::parse(&kind).ok_or_else(|| {
                    PyValueError::new_err(format!(
                        "slave '{name}': variable '{var}' has the unknown kind '{kind}'"
                    ))
                })?;
                outputs.push(VariableEntry {
                    name: var,
                    index,
                    subindex,
                    bit_offset,
                    bit_length,
                    kind,
                    minimum,
                    maximum,
                    deferred,
                });
            }
            entries.push(SlaveEntry {
                name,
                position,
                outputs,
            });
        }
        let table = CommandTable::new(entries).map_err(PyValueError::new_err)?;
        Ok(PyCommandTable { table })
    }

    /// Resolve a serialized `WriteVariable` as the native path would: ([(bit offset, bit length,
    /// raw)], answer) when it applies it itself, None when it leaves it to Python. ValueError
    /// if the bytes are not a WriteVariable.
    fn resolve(&self, data: &[u8]) -> PyResult<Option<Applied>> {
        let request =
            decode_write_variable(data).map_err(|e| PyValueError::new_err(e.to_string()))?;
        let (mut fields, mut answer) = (Vec::new(), String::new());
        Ok(
            match self.table.resolve(&request, &mut fields, &mut answer) {
                Resolution::Apply => Some((
                    fields
                        .iter()
                        .map(|f| (f.bit_offset, f.bit_length, f.raw))
                        .collect(),
                    answer,
                )),
                Resolution::Defer | Resolution::Refuse => None,
            },
        )
    }
}

/// (joint, engine axis index, position min, position max, velocity limit, torque limit, kind)
type JointRow = (String, usize, f64, f64, f64, f64, Option<String>);
/// [(axis index, kind, value)]: the setpoints the native path writes.
type Setpoints = Vec<(usize, String, f64)>;

fn setpoint_kind(name: Option<&str>) -> PyResult<Option<SetpointKind>> {
    Ok(match name {
        None => None,
        Some("position") => Some(SetpointKind::Position),
        Some("velocity") => Some(SetpointKind::Velocity),
        Some("torque") => Some(SetpointKind::Torque),
        Some(other) => {
            return Err(PyValueError::new_err(format!(
                "unknown setpoint kind '{other}' (position, velocity, torque or None)"
            )))
        }
    })
}

fn kind_name(kind: SetpointKind) -> &'static str {
    match kind {
        SetpointKind::Position => "position",
        SetpointKind::Velocity => "velocity",
        SetpointKind::Torque => "torque",
    }
}

/// The CiA 402 axes of a bus, for the native `joint_commands` path.
#[pyclass(name = "JointTable", module = "ether_ros._native", frozen)]
pub struct PyJointTable {
    table: JointTable,
}

#[pymethods]
impl PyJointTable {
    /// `joints`: (name, engine axis index, position min, position max, velocity limit, torque
    /// limit, kind) with kind "position", "velocity", "torque" or None (the mode takes none).
    #[new]
    fn new(joints: Vec<JointRow>) -> PyResult<Self> {
        let mut entries = Vec::with_capacity(joints.len());
        for (name, axis, position_min, position_max, velocity_limit, torque_limit, kind) in joints {
            let kind = setpoint_kind(kind.as_deref())?;
            entries.push((
                JointEntry {
                    name,
                    axis,
                    position_min,
                    position_max,
                    velocity_limit,
                    torque_limit,
                },
                kind,
            ));
        }
        let table = JointTable::new(entries).map_err(PyValueError::new_err)?;
        Ok(PyJointTable { table })
    }

    /// The kind joint number `joint` (its row) takes from now on, also in attached receivers.
    #[pyo3(signature = (joint, kind))]
    fn set_kind(&self, joint: usize, kind: Option<&str>) -> PyResult<()> {
        self.table.set_kind(joint, setpoint_kind(kind)?);
        Ok(())
    }

    /// What stopped joint number `joint`'s axis, as the node saw it ("" nothing, "the command
    /// watchdog", "a panic", "a lapse of the control lease"): named when the native path
    /// refuses a command to it. ValueError for another text.
    fn set_cause(&self, joint: usize, cause: &str) -> PyResult<()> {
        self.table
            .set_cause(joint, cause)
            .map_err(PyValueError::new_err)
    }

    /// Resolve a serialized `JointState` as the native path would: the setpoints when it applies
    /// them itself, None when it leaves the message to Python. ValueError if the bytes are not
    /// a JointState.
    fn resolve(&self, data: &[u8]) -> PyResult<Option<Setpoints>> {
        let mut names = Vec::new();
        let command = decode_joint_state(data, &mut names)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        let mut out = Vec::new();
        Ok(match self.table.resolve(&command, &names, &mut out) {
            Resolution::Apply => Some(
                out.iter()
                    .map(|&(axis, kind, value)| (axis, kind_name(kind).to_string(), value))
                    .collect(),
            ),
            Resolution::Defer | Resolution::Refuse => None,
        })
    }

    /// The refusal the native path answers a serialized `JointState` with by itself (the words
    /// after "joint_commands refused: "), None when it applies the message or leaves it to
    /// Python. ValueError if the bytes are not a JointState.
    fn refusal(&self, data: &[u8]) -> PyResult<Option<String>> {
        let mut names = Vec::new();
        let command = decode_joint_state(data, &mut names)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        let (mut out, mut why) = (Vec::new(), String::new());
        Ok(
            match self
                .table
                .resolve_or_refuse(&command, &names, &mut out, &mut why)
            {
                Resolution::Refuse => Some(why),
                _ => None,
            },
        )
    }
}

fn verdict_name(v: Verdict) -> &'static str {
    match v {
        Verdict::Allowed => "allowed",
        Verdict::NoHolder => "no_holder",
        Verdict::HeldByOther => "held_by_other",
        Verdict::Lapsed => "lapsed",
    }
}

fn gid_of(data: &[u8]) -> PyResult<Gid> {
    data.try_into().map_err(|_| {
        PyValueError::new_err(format!(
            "a publisher GID has {GID_LEN} bytes, got {}",
            data.len()
        ))
    })
}

/// The control lease as every command entry point checks it (crates/commands/src/lease.rs):
/// written by the node's lease policy (`ether_ros.ros.lease`), read without a lock by the
/// native command threads and by Python.
#[pyclass(name = "LeaseGate", module = "ether_ros._native", frozen)]
pub struct PyLeaseGate {
    gate: Arc<LeaseGate>,
}

#[pymethods]
impl PyLeaseGate {
    #[new]
    fn new() -> Self {
        PyLeaseGate {
            gate: Arc::new(LeaseGate::new()),
        }
    }

    /// Most publisher GIDs a holder may register.
    #[classattr]
    const MAX_WRITERS: usize = MAX_WRITERS;
    /// Bytes of one publisher GID.
    #[classattr]
    const GID_LEN: usize = GID_LEN;

    fn set_enabled(&self, enabled: bool) {
        self.gate.set_enabled(enabled);
    }

    /// A holder: its name, token, publisher GIDs (16 bytes each) and the CLOCK_MONOTONIC ns
    /// its lease runs out.
    fn grant(&self, holder: &str, token: u64, gids: Vec<Vec<u8>>, expires_ns: i64) -> PyResult<()> {
        if gids.len() > MAX_WRITERS {
            return Err(PyValueError::new_err(format!(
                "{} publisher GIDs, at most {MAX_WRITERS}",
                gids.len()
            )));
        }
        let gids = gids
            .iter()
            .map(|g| gid_of(g))
            .collect::<PyResult<Vec<_>>>()?;
        self.gate.grant(holder, token, &gids, expires_ns);
        Ok(())
    }

    fn renew(&self, expires_ns: i64) {
        self.gate.renew(expires_ns);
    }

    fn revoke(&self) {
        self.gate.revoke();
    }

    /// {enabled, expires_ns, token, holder, gids}.
    fn state<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = self.gate.state();
        let d = PyDict::new(py);
        d.set_item("enabled", s.enabled)?;
        d.set_item("expires_ns", s.expires_ns)?;
        d.set_item("token", s.token)?;
        d.set_item("holder", s.holder)?;
        let gids: Vec<Bound<'py, PyBytes>> = s.gids.iter().map(|g| PyBytes::new(py, g)).collect();
        d.set_item("gids", gids)?;
        Ok(d)
    }

    /// (verdict, refusal text) for a service request carrying lease `token` at `now_ns`
    /// (CLOCK_MONOTONIC; default now, the clock the native threads check with): verdict
    /// "allowed" (text empty), "no_holder", "held_by_other" or "lapsed".
    #[pyo3(signature = (token, now_ns=None))]
    fn check_token(&self, token: u64, now_ns: Option<i64>) -> (&'static str, String) {
        let mut holder = String::new();
        let v = self.gate.check_token(
            token,
            now_ns.unwrap_or_else(ether_ros_engine::now_ns),
            &mut holder,
        );
        let mut text = String::new();
        refusal_text(v, &holder, &mut text);
        (verdict_name(v), text)
    }

    /// As `check_token`, for a message from publisher `gid` (16 bytes).
    #[pyo3(signature = (gid, now_ns=None))]
    fn check_gid(&self, gid: &[u8], now_ns: Option<i64>) -> PyResult<(&'static str, String)> {
        let mut holder = String::new();
        let now = now_ns.unwrap_or_else(ether_ros_engine::now_ns);
        let v = self.gate.check_gid(&gid_of(gid)?, now, &mut holder);
        let mut text = String::new();
        refusal_text(v, &holder, &mut text);
        Ok((verdict_name(v), text))
    }
}

/// The native command thread (see the module doc); it runs from construction until `stop` and
/// writes to an engine while one is attached.
#[pyclass(name = "CommandReceiver", module = "ether_ros._native", frozen)]
pub struct PyCommandReceiver {
    inner: CommandReceiver,
}

#[pymethods]
impl PyCommandReceiver {
    /// Refusals answered per publisher and second (a burst of as many): beyond that a
    /// flooding publisher's refusals are counted, not answered.
    #[classattr]
    const REFUSAL_ANSWERS_PER_S: u32 = REFUSAL_ANSWERS_PER_S;
    /// Refusals answered per second in all, by one thread, whatever the number of publishers.
    #[classattr]
    const REFUSAL_ANSWERS_TOTAL_PER_S: u32 = REFUSAL_ANSWERS_TOTAL_PER_S;
    /// Publishers whose answer budget is kept.
    #[classattr]
    const ANSWER_BUDGETS: usize = ANSWER_BUDGETS;
    /// Requests of one publisher that may wait for Python.
    #[classattr]
    const PUBLISHER_LIMIT: usize = PUBLISHER_LIMIT;

    #[new]
    /// `message`: "write_variable" (`pdo_listener`), "joint_state" (`joint_commands`) or
    /// "passthrough" (every message to Python: `joint_trajectory`). `lease`: the LeaseGate every
    /// message is checked against (None: everyone may command).
    #[pyo3(signature = (*, librcl, librcutils, context, subscription, results, priority, cpus=Vec::new(), message="write_variable", lease=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        librcl: String,
        librcutils: String,
        context: usize,
        subscription: usize,
        results: usize,
        priority: i32,
        cpus: Vec<usize>,
        message: &str,
        lease: Option<PyRef<'_, PyLeaseGate>>,
    ) -> PyResult<Self> {
        let message = match message {
            "write_variable" => MessageKind::WriteVariable,
            "joint_state" => MessageKind::JointState,
            "passthrough" => MessageKind::Passthrough,
            other => {
                return Err(PyValueError::new_err(format!(
                    "unknown message kind '{other}' (write_variable, joint_state, passthrough)"
                )))
            }
        };
        let handles = ReceiverHandles {
            librcl,
            librcutils,
            context,
            subscription,
            results,
            message,
            lease: lease.map(|g| g.gate.clone()),
        };
        let inner = py
            .detach(move || CommandReceiver::start(handles, priority, cpus))
            .map_err(PyRuntimeError::new_err)?;
        Ok(PyCommandReceiver { inner })
    }

    /// Write valid requests into `engine` from now on, resolved with `table` (a CommandTable
    /// for write_variable, a JointTable for joint_state).
    fn attach(&self, engine: PyRef<'_, PyEngine>, table: &Bound<'_, PyAny>) -> PyResult<()> {
        let resolver = if let Ok(t) = table.cast::<PyCommandTable>() {
            Resolver::Writes(t.get().table.clone())
        } else if let Ok(t) = table.cast::<PyJointTable>() {
            Resolver::Joints(t.get().table.clone())
        } else {
            return Err(PyValueError::new_err(
                "attach takes a CommandTable or a JointTable",
            ));
        };
        self.inner.attach(engine.inner.clone(), resolver);
        Ok(())
    }

    /// Stop writing to the engine (every request goes to Python); returns once no write is in
    /// progress.
    fn detach(&self, py: Python<'_>) {
        py.detach(|| self.inner.detach());
    }

    /// Stop and join the thread (idempotent).
    fn stop(&self, py: Python<'_>) {
        py.detach(|| self.inner.stop());
    }

    fn is_running(&self) -> bool {
        self.inner.is_running()
    }

    /// The next request left to Python (publishers in turn): (serialized message, publisher
    /// GID), or None after `timeout` seconds. Call `deferred_done()` once it is handled.
    fn next_deferred<'py>(
        &self,
        py: Python<'py>,
        timeout: f64,
    ) -> Option<(Bound<'py, PyBytes>, Bound<'py, PyBytes>)> {
        let timeout = Duration::from_secs_f64(timeout.clamp(0.0, 3600.0));
        py.detach(|| self.inner.next_deferred(timeout))
            .map(|(data, gid)| (PyBytes::new(py, &data), PyBytes::new(py, &gid)))
    }

    /// Publishers with requests waiting for Python (or in its hands) now.
    fn waiting_publishers(&self) -> usize {
        self.inner.waiting_publishers()
    }

    fn deferred_done(&self) {
        self.inner.deferred_done();
    }

    /// CLOCK_MONOTONIC ns of the last write applied natively (0: none yet).
    fn last_command_ns(&self) -> i64 {
        self.inner.last_command_ns()
    }

    fn last_error(&self) -> String {
        self.inner.last_error()
    }

    /// How the thread is scheduled ("SCHED_FIFO 50 on CPUs [0]", or "normal: ..." saying why).
    fn scheduling(&self) -> String {
        self.inner.scheduling()
    }

    fn counters<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (key, value) in self.inner.counters().pairs() {
            d.set_item(key, value)?;
        }
        Ok(d)
    }
}

/// Check a serialized command message with the native decoder (`message`: "write_variable",
/// "joint_state" or "joint_trajectory"): ValueError naming the field when it is not one it
/// accepts — truncated, not UTF-8, or a string with a NUL inside, which rclpy would hand to
/// Python cut short.
#[pyfunction]
fn check_command_message(message: &str, data: &[u8]) -> PyResult<()> {
    let result = match message {
        "write_variable" => decode_write_variable(data).map(|_| ()),
        "joint_state" => decode_joint_state(data, &mut Vec::new()).map(|_| ()),
        "joint_trajectory" => check_joint_trajectory(data),
        other => {
            return Err(PyValueError::new_err(format!(
                "unknown message '{other}' (write_variable, joint_state or joint_trajectory)"
            )))
        }
    };
    result.map_err(|e| PyValueError::new_err(e.to_string()))
}

/// The console's terminal reader that sends the panic request itself (see
/// `ether_ros_commands::panic_keys`); it runs from construction until `stop`.
#[pyclass(name = "PanicKeys", module = "ether_ros._native", frozen)]
pub struct PyPanicKeys {
    inner: PanicKeys,
}

/// (sequence number, CLOCK_MONOTONIC ns when the read holding the key returned and when the
/// request was sent, "") for a request sent, or (None, 0, 0, why) when none was.
type SentRow = (Option<i64>, i64, i64, String);

#[pymethods]
impl PyPanicKeys {
    /// `node`, `client`: `handle.pointer` of the rclpy node and its std_srvs/Trigger `panic`
    /// client; `terminal`: the terminal's descriptor (in raw mode; not closed here);
    /// `forward`: the write end of the pipe the bytes go on to (closed when the thread ends);
    /// `priority`: SCHED_FIFO priority to ask for (0: none; refused without CAP_SYS_NICE).
    #[new]
    #[pyo3(signature = (*, librcl, librcutils, node, client, terminal, forward, priority=0))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        librcl: String,
        librcutils: String,
        node: usize,
        client: usize,
        terminal: i32,
        forward: i32,
        priority: i32,
    ) -> PyResult<Self> {
        let handles = PanicKeyHandles {
            librcl,
            librcutils,
            node,
            client,
            terminal,
            forward,
            priority,
        };
        let inner = py
            .detach(move || PanicKeys::start(handles))
            .map_err(PyRuntimeError::new_err)?;
        Ok(PyPanicKeys { inner })
    }

    /// What the thread did for each read that held a panic key since the last call:
    /// (sequence number, read ns, sent ns, "") for a request sent (CLOCK_MONOTONIC), (None, 0,
    /// 0, why) when it could not send one.
    fn take_sent(&self) -> Vec<SentRow> {
        self.inner
            .take_sent()
            .into_iter()
            .map(|sent| match sent {
                Sent::Request {
                    sequence,
                    read_ns,
                    at_ns,
                } => (Some(sequence), read_ns, at_ns, String::new()),
                Sent::Failed(why) => (None, 0, 0, why),
            })
            .collect()
    }

    fn presses(&self) -> u64 {
        self.inner.presses()
    }

    fn dropped(&self) -> u64 {
        self.inner.dropped()
    }

    fn is_running(&self) -> bool {
        self.inner.is_running()
    }

    /// How the thread is scheduled ("SCHED_FIFO 50", or "normal: ..." saying why).
    fn scheduling(&self) -> String {
        self.inner.scheduling()
    }

    /// Stop and join the thread (idempotent).
    fn stop(&self, py: Python<'_>) {
        py.detach(|| self.inner.stop());
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(check_command_message, m)?)?;
    m.add_class::<PyCommandTable>()?;
    m.add_class::<PyJointTable>()?;
    m.add_class::<PyCommandReceiver>()?;
    m.add_class::<PyLeaseGate>()?;
    m.add_class::<PyPanicKeys>()?;
    let keys: Vec<&[u8]> = PANIC_KEYS.to_vec();
    m.add("PANIC_KEYS", keys)?;
    Ok(())
}
