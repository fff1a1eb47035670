//! The typed contracts between Python and the engine: the cyclic plan and its parts as frozen
//! `#[pyclass]` types that Python builds (`python/ether_ros/master/plan.py`,
//! `master/axis.py`) and that check themselves when they are made.
//!
//! Every constructor is keyword-only, so PyO3 itself refuses an unknown keyword
//! (`AxisPlan.__new__() got an unexpected keyword argument 'velocty_max'`) and names a missing
//! one (`Plan.__new__() missing 1 required keyword argument: 'cycle_ns'`): a misspelt field
//! can never pass as an absent one and take its default. Value checks (names of modes and
//! policies, ranges) are made here too, their messages naming the type and the field; the
//! checks that need the whole plan (image ranges, overlaps, the axes against the image) are
//! `ether_ros_engine::Plan::validate`, run when the `Plan` is made.
//!
//! Defaults: a field has one only when nothing above the engine decides it (an axis's
//! `interpolation_max_ns`, the plan's `trajectory_capacity`, an empty `axes`); everything the
//! master or the configuration decides is required here and has its one default there
//! (`master/plan.py`, the pydantic models of `config/bus.py`).

use std::fmt::Display;

use ether_ros_engine::cia402::{
    AxisMap as EngineAxisMap, AxisPlan as EngineAxisPlan, FaultReset, Limits, ModeChangeVelocity,
    OnStop, Restart, DEFAULT_TRAJECTORY_CAPACITY,
};
use ether_ros_engine::plan::{
    CyclicDatagram, DcMode, DcPlan, FramePlan, Logical, Order, Policy, RtPlan, MAX_EVERY,
};
use ether_ros_engine::{Mode, Plan as EnginePlan};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyTuple};

/// `ValueError("Type.field: why")`.
fn bad(ty: &str, field: &str, why: impl Display) -> PyErr {
    PyValueError::new_err(format!("{ty}.{field}: {why}"))
}

/// One of `choices` by name, else a ValueError naming the type, the field and the names.
fn pick<T: Copy>(ty: &str, field: &str, value: &str, choices: &[(&str, T)]) -> PyResult<T> {
    choices
        .iter()
        .find(|(n, _)| *n == value)
        .map(|(_, v)| *v)
        .ok_or_else(|| {
            let names: Vec<&str> = choices.iter().map(|(n, _)| *n).collect();
            bad(
                ty,
                field,
                format!("{value:?} is not one of {}", names.join(", ")),
            )
        })
}

/// The name of `v`'s Python type, for messages.
fn type_name(v: &Bound<'_, PyAny>) -> String {
    v.get_type()
        .name()
        .map(|n| n.to_string())
        .unwrap_or_default()
}

// ----- datagrams ---------------------------------------------------------------------------

const LOGICAL: [(&str, Logical); 3] = [
    ("lrw", Logical::Lrw),
    ("lrd", Logical::Lrd),
    ("lwr", Logical::Lwr),
];

/// A logical datagram of the process image: LRW, or LRD/LWR for slaves that refuse LRW.
#[pyclass(name = "LogicalDatagram", module = "ether_ros._native", frozen)]
pub struct LogicalDatagram {
    #[pyo3(get)]
    kind: String,
    #[pyo3(get)]
    address: u32,
    #[pyo3(get)]
    length: usize,
    #[pyo3(get)]
    image_offset: usize,
    #[pyo3(get)]
    expected_wkc: u16,
    inner: CyclicDatagram,
}

#[pymethods]
impl LogicalDatagram {
    #[new]
    #[pyo3(signature = (*, kind, address, length, image_offset, expected_wkc))]
    fn new(
        kind: String,
        address: u32,
        length: usize,
        image_offset: usize,
        expected_wkc: u16,
    ) -> PyResult<Self> {
        let command = pick("LogicalDatagram", "kind", &kind, &LOGICAL)?;
        if length == 0 || length > ether_ros_protocol::MAX_DATAGRAM_DATA {
            return Err(bad(
                "LogicalDatagram",
                "length",
                format!(
                    "{length} is outside 1..={}",
                    ether_ros_protocol::MAX_DATAGRAM_DATA
                ),
            ));
        }
        Ok(Self {
            kind,
            address,
            length,
            image_offset,
            expected_wkc,
            inner: CyclicDatagram::Logical {
                command,
                address,
                length,
                image_offset,
                expected_wkc,
            },
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "LogicalDatagram(kind={:?}, address={}, length={}, image_offset={}, expected_wkc={})",
            self.kind, self.address, self.length, self.image_offset, self.expected_wkc
        )
    }
}

/// A distributed-clock datagram of the first frame: `dc_write_ref` (FPWR 0x0910, the master's
/// time to the reference clock) or `dc_sync` (FRMW 0x0910, the reference time to the others).
#[pyclass(name = "DcDatagram", module = "ether_ros._native", frozen)]
pub struct DcDatagram {
    #[pyo3(get)]
    kind: String,
    #[pyo3(get)]
    station: u16,
    inner: CyclicDatagram,
}

#[pymethods]
impl DcDatagram {
    #[new]
    #[pyo3(signature = (*, kind, station))]
    fn new(kind: String, station: u16) -> PyResult<Self> {
        let inner = match kind.as_str() {
            "dc_write_ref" => CyclicDatagram::DcWriteRef { station },
            "dc_sync" => CyclicDatagram::DcSync { station },
            k => {
                return Err(bad(
                    "DcDatagram",
                    "kind",
                    format!("{k:?} is not one of dc_write_ref, dc_sync"),
                ))
            }
        };
        Ok(Self {
            kind,
            station,
            inner,
        })
    }

    fn __repr__(&self) -> String {
        format!("DcDatagram(kind={:?}, station={})", self.kind, self.station)
    }
}

// ----- frames ------------------------------------------------------------------------------

/// One cyclic frame: its datagrams, how often it goes out (`every` base cycles, a slave
/// group's own cycle) and the group's command watchdog (`watchdog_ns`, 0: none).
#[pyclass(name = "Frame", module = "ether_ros._native", frozen)]
pub struct Frame {
    datagrams: Py<PyTuple>,
    #[pyo3(get)]
    every: u32,
    #[pyo3(get)]
    watchdog_ns: u64,
    inner: FramePlan,
}

#[pymethods]
impl Frame {
    #[new]
    #[pyo3(signature = (*, datagrams, every, watchdog_ns))]
    fn new(datagrams: Vec<Bound<'_, PyAny>>, every: u32, watchdog_ns: u64) -> PyResult<Self> {
        if datagrams.is_empty() {
            return Err(bad("Frame", "datagrams", "a frame needs a datagram"));
        }
        if !(1..=MAX_EVERY).contains(&every) {
            return Err(bad(
                "Frame",
                "every",
                format!("{every} is outside 1..={MAX_EVERY}"),
            ));
        }
        let mut inner = Vec::with_capacity(datagrams.len());
        for (i, d) in datagrams.iter().enumerate() {
            if let Ok(l) = d.cast::<LogicalDatagram>() {
                inner.push(l.get().inner);
            } else if let Ok(dc) = d.cast::<DcDatagram>() {
                inner.push(dc.get().inner);
            } else {
                return Err(PyTypeError::new_err(format!(
                    "Frame.datagrams[{i}]: expected a LogicalDatagram or a DcDatagram, got {}",
                    type_name(d)
                )));
            }
        }
        let py = datagrams[0].py();
        Ok(Self {
            datagrams: PyTuple::new(py, &datagrams)?.unbind(),
            every,
            watchdog_ns,
            inner: FramePlan {
                datagrams: inner,
                every,
                watchdog_ns,
            },
        })
    }

    #[getter]
    fn datagrams<'py>(&self, py: Python<'py>) -> Bound<'py, PyTuple> {
        self.datagrams.bind(py).clone()
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "Frame(datagrams={}, every={}, watchdog_ns={})",
            self.datagrams.bind(py),
            self.every,
            self.watchdog_ns
        )
    }
}

// ----- dc and rt ---------------------------------------------------------------------------

const DC_MODES: [(&str, DcMode); 3] = [
    ("off", DcMode::Off),
    ("ref_follows_master", DcMode::RefFollowsMaster),
    ("master_follows_ref", DcMode::MasterFollowsRef),
];

/// Distributed clocks: the mode, DC system time = CLOCK_MONOTONIC + `time_offset_ns`, and the
/// SYNC0 shift.
#[pyclass(name = "DcSettings", module = "ether_ros._native", frozen)]
pub struct DcSettings {
    #[pyo3(get)]
    mode: String,
    #[pyo3(get)]
    time_offset_ns: i64,
    #[pyo3(get)]
    sync0_shift_ns: i64,
    inner: DcPlan,
}

#[pymethods]
impl DcSettings {
    #[new]
    #[pyo3(signature = (*, mode, time_offset_ns, sync0_shift_ns))]
    fn new(mode: String, time_offset_ns: i64, sync0_shift_ns: i64) -> PyResult<Self> {
        let m = pick("DcSettings", "mode", &mode, &DC_MODES)?;
        Ok(Self {
            mode,
            time_offset_ns,
            sync0_shift_ns,
            inner: DcPlan {
                mode: m,
                time_offset_ns,
                sync0_shift_ns,
            },
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "DcSettings(mode={:?}, time_offset_ns={}, sync0_shift_ns={})",
            self.mode, self.time_offset_ns, self.sync0_shift_ns
        )
    }
}

const POLICIES: [(&str, Policy); 3] = [
    ("fifo", Policy::Fifo),
    ("deadline", Policy::Deadline),
    ("other", Policy::Other),
];

/// The RT thread's scheduling: policy, priority (fifo), CPU, runtime (deadline), memory lock.
#[pyclass(name = "RtSettings", module = "ether_ros._native", frozen)]
pub struct RtSettings {
    #[pyo3(get)]
    policy: String,
    #[pyo3(get)]
    priority: i32,
    #[pyo3(get)]
    cpu: Option<usize>,
    #[pyo3(get)]
    runtime_ns: u64,
    #[pyo3(get)]
    lock_memory: bool,
    inner: RtPlan,
}

#[pymethods]
impl RtSettings {
    #[new]
    #[pyo3(signature = (*, policy, priority, cpu, runtime_ns, lock_memory))]
    fn new(
        policy: String,
        priority: i32,
        cpu: Option<usize>,
        runtime_ns: u64,
        lock_memory: bool,
    ) -> PyResult<Self> {
        let p = pick("RtSettings", "policy", &policy, &POLICIES)?;
        if p == Policy::Fifo && !(1..=99).contains(&priority) {
            return Err(bad(
                "RtSettings",
                "priority",
                format!("{priority} is outside 1..=99 (fifo)"),
            ));
        }
        Ok(Self {
            policy,
            priority,
            cpu,
            runtime_ns,
            lock_memory,
            inner: RtPlan {
                policy: p,
                priority,
                cpu,
                runtime_ns,
                lock_memory,
            },
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "RtSettings(policy={:?}, priority={}, cpu={:?}, runtime_ns={}, lock_memory={})",
            self.policy, self.priority, self.cpu, self.runtime_ns, self.lock_memory
        )
    }
}

// ----- axes --------------------------------------------------------------------------------

/// Byte offsets in the process image of a CiA 402 axis's objects (None: not mapped); the roles
/// are the objects of `python/ether_ros/config/cia402.py` OBJECTS.
#[pyclass(name = "AxisMap", module = "ether_ros._native", frozen, get_all)]
pub struct AxisMap {
    controlword: usize,
    statusword: usize,
    mode: Option<usize>,
    mode_display: Option<usize>,
    target_position: Option<usize>,
    target_velocity: Option<usize>,
    target_torque: Option<usize>,
    position: Option<usize>,
    velocity: Option<usize>,
    torque: Option<usize>,
    error_code: Option<usize>,
    following_error: Option<usize>,
}

impl AxisMap {
    fn engine(&self) -> EngineAxisMap {
        EngineAxisMap {
            controlword: self.controlword,
            statusword: self.statusword,
            mode: self.mode,
            mode_display: self.mode_display,
            target_position: self.target_position,
            target_velocity: self.target_velocity,
            target_torque: self.target_torque,
            position: self.position,
            velocity: self.velocity,
            torque: self.torque,
            error_code: self.error_code,
            following_error: self.following_error,
        }
    }
}

#[pymethods]
impl AxisMap {
    #[new]
    #[pyo3(signature = (
        *, controlword, statusword, mode = None, mode_display = None, target_position = None,
        target_velocity = None, target_torque = None, position = None, velocity = None,
        torque = None, error_code = None, following_error = None,
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        controlword: usize,
        statusword: usize,
        mode: Option<usize>,
        mode_display: Option<usize>,
        target_position: Option<usize>,
        target_velocity: Option<usize>,
        target_torque: Option<usize>,
        position: Option<usize>,
        velocity: Option<usize>,
        torque: Option<usize>,
        error_code: Option<usize>,
        following_error: Option<usize>,
    ) -> Self {
        Self {
            controlword,
            statusword,
            mode,
            mode_display,
            target_position,
            target_velocity,
            target_torque,
            position,
            velocity,
            torque,
            error_code,
            following_error,
        }
    }

    /// role → byte offset of every mapped object.
    fn offsets(&self) -> Vec<(&'static str, usize)> {
        self.engine()
            .objects()
            .into_iter()
            .map(|(name, _, off, _)| (name, off))
            .collect()
    }

    fn __repr__(&self) -> String {
        let parts: Vec<String> = self
            .offsets()
            .into_iter()
            .map(|(n, o)| format!("{n}={o}"))
            .collect();
        format!("AxisMap({})", parts.join(", "))
    }
}

/// The modes by short name (the protocol crate's names and codes).
fn modes() -> [(&'static str, Mode); 6] {
    Mode::ALL.map(|m| (m.name(), m))
}

/// A CiA 402 axis driven by the engine's axis stage (docs/cia402.md): its objects in the
/// image, scales (raw → SI), limits and policies.
#[pyclass(name = "AxisPlan", module = "ether_ros._native", frozen)]
pub struct AxisPlan {
    map: Py<AxisMap>,
    #[pyo3(get)]
    mode: String,
    #[pyo3(get)]
    mode_change_velocity: String,
    #[pyo3(get)]
    restart: String,
    #[pyo3(get)]
    on_stop: String,
    #[pyo3(get)]
    fault_reset: String,
    /// SI/s²; None: the documented default. Carried for the motion work's acceleration limit;
    /// the engine's axis stage does not read it yet.
    #[pyo3(get)]
    max_acceleration: Option<f64>,
    inner: EngineAxisPlan,
}

#[pymethods]
impl AxisPlan {
    #[new]
    #[pyo3(signature = (
        *, name, map, mode, position_scale, position_offset, velocity_scale, torque_scale,
        position_min, position_max, velocity_max, torque_max, deceleration,
        mode_change_velocity, restart, following_error_window, on_stop, fault_reset,
        fault_retries, fault_backoff_ns, interpolation_max_ns = 100_000_000,
        max_acceleration = None,
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        name: String,
        map: Bound<'_, AxisMap>,
        mode: String,
        position_scale: f64,
        position_offset: f64,
        velocity_scale: f64,
        torque_scale: f64,
        position_min: f64,
        position_max: f64,
        velocity_max: f64,
        torque_max: f64,
        deceleration: f64,
        mode_change_velocity: String,
        restart: String,
        following_error_window: f64,
        on_stop: String,
        fault_reset: String,
        fault_retries: u32,
        fault_backoff_ns: i64,
        interpolation_max_ns: i64,
        max_acceleration: Option<f64>,
    ) -> PyResult<Self> {
        const T: &str = "AxisPlan";
        if let Some(a) = max_acceleration {
            if a.is_nan() || a <= 0.0 {
                return Err(bad(T, "max_acceleration", format!("{a} must be > 0")));
            }
        }
        if fault_backoff_ns < 0 {
            return Err(bad(
                T,
                "fault_backoff_ns",
                format!("{fault_backoff_ns} < 0"),
            ));
        }
        let inner = EngineAxisPlan {
            name: name.clone(),
            map: map.get().engine(),
            mode: pick(T, "mode", &mode, &modes())?,
            position_scale,
            position_offset,
            velocity_scale,
            torque_scale,
            limits: Limits {
                position_min,
                position_max,
                velocity_max,
                torque_max,
            },
            deceleration,
            mode_change_velocity: pick(
                T,
                "mode_change_velocity",
                &mode_change_velocity,
                &[
                    ("actual", ModeChangeVelocity::Actual),
                    ("zero", ModeChangeVelocity::Zero),
                ],
            )?,
            restart: pick(
                T,
                "restart",
                &restart,
                &[("manual", Restart::Manual), ("auto", Restart::Auto)],
            )?,
            following_error_window,
            on_stop: pick(
                T,
                "on_stop",
                &on_stop,
                &[
                    ("quick_stop", OnStop::QuickStop),
                    ("disable", OnStop::Disable),
                ],
            )?,
            fault_reset: pick(
                T,
                "fault_reset",
                &fault_reset,
                &[("auto", FaultReset::Auto), ("manual", FaultReset::Manual)],
            )?,
            fault_retries,
            fault_backoff_ns,
            interpolation_max_ns,
            // None: no acceleration bound of its own (the velocity limit still applies); the
            // config's default (the axis's deceleration) is decided in Python (config/bus.py).
            max_acceleration: max_acceleration.unwrap_or(f64::INFINITY),
        };
        Ok(Self {
            map: map.unbind(),
            mode,
            mode_change_velocity,
            restart,
            on_stop,
            fault_reset,
            max_acceleration,
            inner,
        })
    }

    #[getter]
    fn name(&self) -> &str {
        &self.inner.name
    }
    #[getter]
    fn map<'py>(&self, py: Python<'py>) -> Bound<'py, AxisMap> {
        self.map.bind(py).clone()
    }
    #[getter]
    fn position_scale(&self) -> f64 {
        self.inner.position_scale
    }
    #[getter]
    fn position_offset(&self) -> f64 {
        self.inner.position_offset
    }
    #[getter]
    fn velocity_scale(&self) -> f64 {
        self.inner.velocity_scale
    }
    #[getter]
    fn torque_scale(&self) -> f64 {
        self.inner.torque_scale
    }
    #[getter]
    fn position_min(&self) -> f64 {
        self.inner.limits.position_min
    }
    #[getter]
    fn position_max(&self) -> f64 {
        self.inner.limits.position_max
    }
    #[getter]
    fn velocity_max(&self) -> f64 {
        self.inner.limits.velocity_max
    }
    #[getter]
    fn torque_max(&self) -> f64 {
        self.inner.limits.torque_max
    }
    #[getter]
    fn deceleration(&self) -> f64 {
        self.inner.deceleration
    }
    #[getter]
    fn following_error_window(&self) -> f64 {
        self.inner.following_error_window
    }
    #[getter]
    fn fault_retries(&self) -> u32 {
        self.inner.fault_retries
    }
    #[getter]
    fn fault_backoff_ns(&self) -> i64 {
        self.inner.fault_backoff_ns
    }
    #[getter]
    fn interpolation_max_ns(&self) -> i64 {
        self.inner.interpolation_max_ns
    }

    fn __repr__(&self) -> String {
        format!(
            "AxisPlan(name={:?}, mode={:?}, ...)",
            self.inner.name, self.mode
        )
    }
}

// ----- the plan ----------------------------------------------------------------------------

const ORDERS: [(&str, Order); 2] = [
    ("send_at_wake", Order::SendAtWake),
    ("send_then_wait", Order::SendThenWait),
];

/// What `Engine.start_cyclic` runs: the cyclic frames, the image, DC, RT, watchdog, ring and
/// axes (docs/engine.md). Made only whole and checked (`ether_ros_engine::Plan::validate`).
#[pyclass(name = "Plan", module = "ether_ros._native", frozen)]
pub struct Plan {
    #[pyo3(get)]
    order: String,
    frames: Py<PyTuple>,
    dc: Py<DcSettings>,
    rt: Py<RtSettings>,
    axes: Py<PyTuple>,
    inner: EnginePlan,
}

impl Plan {
    /// The engine's plan (a copy: `start_cyclic` hands it to the RT thread).
    pub fn engine(&self) -> EnginePlan {
        self.inner.clone()
    }
}

#[pymethods]
impl Plan {
    #[new]
    #[pyo3(signature = (
        *, cycle_ns, order, frames, image_len, output_ranges, initial_image, safe_image, dc,
        rt, watchdog_ns, ring_capacity, axes = Vec::new(), trajectory_capacity = None,
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        cycle_ns: u64,
        order: String,
        frames: Vec<Bound<'_, Frame>>,
        image_len: usize,
        output_ranges: Vec<(usize, usize)>,
        initial_image: Vec<u8>,
        safe_image: Vec<u8>,
        dc: Bound<'_, DcSettings>,
        rt: Bound<'_, RtSettings>,
        watchdog_ns: u64,
        ring_capacity: usize,
        axes: Vec<Bound<'_, AxisPlan>>,
        trajectory_capacity: Option<usize>,
    ) -> PyResult<Self> {
        let inner = EnginePlan {
            cycle_ns,
            order: pick("Plan", "order", &order, &ORDERS)?,
            frames: frames.iter().map(|f| f.get().inner.clone()).collect(),
            image_len,
            output_ranges,
            initial_image,
            safe_image,
            dc: dc.get().inner,
            rt: rt.get().inner,
            watchdog_ns,
            ring_capacity,
            axes: axes.iter().map(|a| a.get().inner.clone()).collect(),
            trajectory_capacity: trajectory_capacity.unwrap_or(DEFAULT_TRAJECTORY_CAPACITY),
        };
        inner
            .validate()
            .map_err(|e| PyValueError::new_err(format!("Plan: {e}")))?;
        Ok(Self {
            order,
            frames: PyTuple::new(py, &frames)?.unbind(),
            dc: dc.unbind(),
            rt: rt.unbind(),
            axes: PyTuple::new(py, &axes)?.unbind(),
            inner,
        })
    }

    #[getter]
    fn cycle_ns(&self) -> u64 {
        self.inner.cycle_ns
    }
    #[getter]
    fn frames<'py>(&self, py: Python<'py>) -> Bound<'py, PyTuple> {
        self.frames.bind(py).clone()
    }
    #[getter]
    fn image_len(&self) -> usize {
        self.inner.image_len
    }
    #[getter]
    fn output_ranges(&self) -> Vec<(usize, usize)> {
        self.inner.output_ranges.clone()
    }
    #[getter]
    fn initial_image<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, &self.inner.initial_image)
    }
    #[getter]
    fn safe_image<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, &self.inner.safe_image)
    }
    #[getter]
    fn dc<'py>(&self, py: Python<'py>) -> Bound<'py, DcSettings> {
        self.dc.bind(py).clone()
    }
    #[getter]
    fn rt<'py>(&self, py: Python<'py>) -> Bound<'py, RtSettings> {
        self.rt.bind(py).clone()
    }
    #[getter]
    fn watchdog_ns(&self) -> u64 {
        self.inner.watchdog_ns
    }
    #[getter]
    fn ring_capacity(&self) -> usize {
        self.inner.ring_capacity
    }
    #[getter]
    fn axes<'py>(&self, py: Python<'py>) -> Bound<'py, PyTuple> {
        self.axes.bind(py).clone()
    }
    #[getter]
    fn trajectory_capacity(&self) -> usize {
        self.inner.trajectory_capacity
    }

    fn __repr__(&self) -> String {
        format!(
            "Plan(cycle_ns={}, order={:?}, frames={}, image_len={}, axes={})",
            self.inner.cycle_ns,
            self.order,
            self.inner.frames.len(),
            self.inner.image_len,
            self.inner.axes.len()
        )
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<LogicalDatagram>()?;
    m.add_class::<DcDatagram>()?;
    m.add_class::<Frame>()?;
    m.add_class::<DcSettings>()?;
    m.add_class::<RtSettings>()?;
    m.add_class::<AxisMap>()?;
    m.add_class::<AxisPlan>()?;
    m.add_class::<Plan>()?;
    Ok(())
}
