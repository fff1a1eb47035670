//! The simulator's faults as typed contracts, like the engine plan (`contracts.rs`): one frozen
//! `#[pyclass]` per fault kind, built by Python (`SimNetwork.inject(fault)`, the control
//! socket's `python/ether_ros/sim/control.py`) and checked when made.
//!
//! Every constructor is keyword-only, so PyO3 refuses an unknown keyword
//! (`Drop.__new__() got an unexpected keyword argument 'speed'`) and names a missing one
//! (`Drop.__new__() missing 1 required keyword argument: 'rate'`). Range checks name the type
//! and the field (`Drop.rate: 2 is outside 0..=1`). Each default (`burst=1`, `bytes=1`,
//! `on=True`, `axis=1`, ...) lives in the constructor's signature here and nowhere else.
//! What only the network can check (is there a slave at that position, does it run a drive)
//! is checked by `inject`.

use std::fmt::Display;

use ether_ros_sim::devices::cia402::{DriveFault as Cia402Fault, MAX_AXES};
use pyo3::exceptions::PyTypeError;

use crate::errors::{invalid, Reason};
use pyo3::prelude::*;

/// `InvalidRequest("Type.field: why")` with the field `Type.field` and the reason as data.
fn refused(ty: &str, field: &str, reason: Reason, why: impl Display) -> PyErr {
    let field = format!("{ty}.{field}");
    invalid(&field, reason, format!("{field}: {why}"))
}

/// A value the field does not allow (not a range question).
fn bad(ty: &str, field: &str, why: impl Display) -> PyErr {
    refused(ty, field, Reason::BadValue, why)
}

/// `v` as `T` when within `lo..=hi`, else a ValueError naming the type and the field. Integers
/// arrive as i64 so that a negative one gets this message rather than an OverflowError.
fn within<T: TryFrom<i64>>(ty: &str, field: &str, v: i64, lo: i64, hi: i64) -> PyResult<T> {
    if !(lo..=hi).contains(&v) {
        return Err(refused(
            ty,
            field,
            Reason::OutOfRange,
            format!("{v} is outside {lo}..={hi}"),
        ));
    }
    T::try_from(v).map_err(|_| refused(ty, field, Reason::OutOfRange, format!("{v} does not fit")))
}

fn within_f(ty: &str, field: &str, v: f64, lo: f64, hi: f64) -> PyResult<f64> {
    if !(lo..=hi).contains(&v) {
        return Err(refused(
            ty,
            field,
            Reason::OutOfRange,
            format!("{v} is outside {lo}..={hi}"),
        ));
    }
    Ok(v)
}

/// A slave position (the network checks that it exists when the fault is injected).
fn position(ty: &str, field: &str, v: i64) -> PyResult<usize> {
    usize::try_from(v).map_err(|_| {
        refused(
            ty,
            field,
            Reason::OutOfRange,
            format!("{v} is not a slave position"),
        )
    })
}

/// Largest `Drop.burst`: a burst longer than this is a link down, which `Link` says better.
const MAX_BURST: i64 = 1_000_000;
/// Largest `Corrupt.bytes` (a frame's header and first datagram header).
const MAX_CORRUPT_BYTES: i64 = 64;
/// Largest `Delay.us`: one second, beyond any master's timeout.
const MAX_DELAY_US: i64 = 1_000_000;
/// Largest port number of an ESC (0..=3).
const MAX_PORT: i64 = 3;
/// Largest `DriftStep.ppm` either way (crystals are tens of ppm; this is already absurd).
const MAX_DRIFT_STEP_PPM: f64 = 1000.0;

/// Drop frames at random: `rate` the chance a frame starts a burst of `burst` dropped frames;
/// `outbound` drops them on the way out (the slaves saw and processed them) instead of in.
#[pyclass(name = "Drop", module = "ether_ros._native", frozen, eq, get_all)]
#[derive(Clone, PartialEq)]
pub struct DropFault {
    pub rate: f64,
    pub burst: u32,
    pub outbound: bool,
}

#[pymethods]
impl DropFault {
    #[new]
    #[pyo3(signature = (*, rate, burst = 1, outbound = false))]
    fn new(rate: f64, burst: i64, outbound: bool) -> PyResult<Self> {
        Ok(Self {
            rate: within_f("Drop", "rate", rate, 0.0, 1.0)?,
            burst: within("Drop", "burst", burst, 1, MAX_BURST)?,
            outbound,
        })
    }

    fn __repr__(&self) -> String {
        let out = if self.outbound { "True" } else { "False" };
        format!(
            "Drop(rate={}, burst={}, outbound={out})",
            self.rate, self.burst
        )
    }
}

/// Corrupt frames at random: `rate` the chance per frame, `bytes` flipped in each.
#[pyclass(name = "Corrupt", module = "ether_ros._native", frozen, eq, get_all)]
#[derive(Clone, PartialEq)]
pub struct Corrupt {
    pub rate: f64,
    pub bytes: u32,
}

#[pymethods]
impl Corrupt {
    #[new]
    #[pyo3(signature = (*, rate, bytes = 1))]
    fn new(rate: f64, bytes: i64) -> PyResult<Self> {
        Ok(Self {
            rate: within_f("Corrupt", "rate", rate, 0.0, 1.0)?,
            bytes: within("Corrupt", "bytes", bytes, 1, MAX_CORRUPT_BYTES)?,
        })
    }

    fn __repr__(&self) -> String {
        format!("Corrupt(rate={}, bytes={})", self.rate, self.bytes)
    }
}

/// Answer every frame `us` microseconds late (0 ends the delay).
#[pyclass(name = "Delay", module = "ether_ros._native", frozen, eq, get_all)]
#[derive(Clone, PartialEq)]
pub struct Delay {
    pub us: u64,
}

#[pymethods]
impl Delay {
    #[new]
    #[pyo3(signature = (*, us))]
    fn new(us: i64) -> PyResult<Self> {
        Ok(Self {
            us: within("Delay", "us", us, 0, MAX_DELAY_US)?,
        })
    }

    fn __repr__(&self) -> String {
        format!("Delay(us={})", self.us)
    }
}

/// Power-cycle the slave at position `slave` (it comes back in INIT).
#[pyclass(name = "Reset", module = "ether_ros._native", frozen, eq, get_all)]
#[derive(Clone, PartialEq)]
pub struct Reset {
    pub slave: usize,
}

#[pymethods]
impl Reset {
    #[new]
    #[pyo3(signature = (*, slave))]
    fn new(slave: i64) -> PyResult<Self> {
        Ok(Self {
            slave: position("Reset", "slave", slave)?,
        })
    }

    fn __repr__(&self) -> String {
        format!("Reset(slave={})", self.slave)
    }
}

fn py_bool(b: bool) -> &'static str {
    if b {
        "True"
    } else {
        "False"
    }
}

/// The slave refuses SAFEOP->OP (`on=False` ends the fault).
#[pyclass(name = "RefuseOp", module = "ether_ros._native", frozen, eq, get_all)]
#[derive(Clone, PartialEq)]
pub struct RefuseOp {
    pub slave: usize,
    pub on: bool,
}

#[pymethods]
impl RefuseOp {
    #[new]
    #[pyo3(signature = (*, slave, on = true))]
    fn new(slave: i64, on: bool) -> PyResult<Self> {
        Ok(Self {
            slave: position("RefuseOp", "slave", slave)?,
            on,
        })
    }

    fn __repr__(&self) -> String {
        format!("RefuseOp(slave={}, on={})", self.slave, py_bool(self.on))
    }
}

/// The slave's mailbox stops answering (`on=False` ends the fault).
#[pyclass(
    name = "StallMailbox",
    module = "ether_ros._native",
    frozen,
    eq,
    get_all
)]
#[derive(Clone, PartialEq)]
pub struct StallMailbox {
    pub slave: usize,
    pub on: bool,
}

#[pymethods]
impl StallMailbox {
    #[new]
    #[pyo3(signature = (*, slave, on = true))]
    fn new(slave: i64, on: bool) -> PyResult<Self> {
        Ok(Self {
            slave: position("StallMailbox", "slave", slave)?,
            on,
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "StallMailbox(slave={}, on={})",
            self.slave,
            py_bool(self.on)
        )
    }
}

/// Unplug (`up=False`) or plug back (`up=True`) a cable. Without `at`: the master's own cable
/// (and `up=True` plugs every cable back); `at` alone: the cable into port 0 of the slave at
/// that position; with `port`: the cable on that port of `at`.
#[pyclass(name = "Link", module = "ether_ros._native", frozen, eq, get_all)]
#[derive(Clone, PartialEq)]
pub struct Link {
    pub up: bool,
    pub at: Option<usize>,
    pub port: Option<u8>,
}

#[pymethods]
impl Link {
    #[new]
    #[pyo3(signature = (*, up, at = None, port = None))]
    fn new(up: bool, at: Option<i64>, port: Option<i64>) -> PyResult<Self> {
        if at.is_none() && port.is_some() {
            return Err(bad(
                "Link",
                "port",
                "needs 'at' (the slave whose port it is)",
            ));
        }
        Ok(Self {
            up,
            at: at.map(|a| position("Link", "at", a)).transpose()?,
            port: port
                .map(|p| within("Link", "port", p, 0, MAX_PORT))
                .transpose()?,
        })
    }

    fn __repr__(&self) -> String {
        let opt = |v: Option<String>| v.unwrap_or_else(|| "None".into());
        format!(
            "Link(up={}, at={}, port={})",
            py_bool(self.up),
            opt(self.at.map(|a| a.to_string())),
            opt(self.port.map(|p| p.to_string()))
        )
    }
}

/// Step the drift of the slave's local clock by `ppm`.
#[pyclass(name = "DriftStep", module = "ether_ros._native", frozen, eq, get_all)]
#[derive(Clone, PartialEq)]
pub struct DriftStep {
    pub slave: usize,
    pub ppm: f64,
}

#[pymethods]
impl DriftStep {
    #[new]
    #[pyo3(signature = (*, slave, ppm))]
    fn new(slave: i64, ppm: f64) -> PyResult<Self> {
        Ok(Self {
            slave: position("DriftStep", "slave", slave)?,
            ppm: within_f(
                "DriftStep",
                "ppm",
                ppm,
                -MAX_DRIFT_STEP_PPM,
                MAX_DRIFT_STEP_PPM,
            )?,
        })
    }

    fn __repr__(&self) -> String {
        format!("DriftStep(slave={}, ppm={})", self.slave, self.ppm)
    }
}

/// Raise `error` in axis `axis` (1-based) of the CiA 402 drive at position `slave`; the
/// master's fault reset clears it.
#[pyclass(name = "DriveFault", module = "ether_ros._native", frozen, eq, get_all)]
#[derive(Clone, PartialEq)]
pub struct DriveFault {
    pub slave: usize,
    pub error: String,
    pub axis: usize,
}

#[pymethods]
impl DriveFault {
    /// The names `error` takes (the drive model's injectable faults).
    #[classattr]
    const ERRORS: [&'static str; 4] = {
        let t = Cia402Fault::INJECTABLE;
        [t[0].0, t[1].0, t[2].0, t[3].0]
    };

    #[new]
    #[pyo3(signature = (*, slave, error, axis = 1))]
    fn new(slave: i64, error: String, axis: i64) -> PyResult<Self> {
        if !Self::ERRORS.contains(&error.as_str()) {
            return Err(bad(
                "DriveFault",
                "error",
                format!("{error:?} is not one of {}", Self::ERRORS.join(", ")),
            ));
        }
        Ok(Self {
            slave: position("DriveFault", "slave", slave)?,
            error,
            axis: within("DriveFault", "axis", axis, 1, MAX_AXES as i64)?,
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "DriveFault(slave={}, error={:?}, axis={})",
            self.slave, self.error, self.axis
        )
    }
}

/// Reseed the fault-injection random generator (same seed, same faults).
#[pyclass(name = "Seed", module = "ether_ros._native", frozen, eq, get_all)]
#[derive(Clone, PartialEq)]
pub struct Seed {
    pub seed: u64,
}

#[pymethods]
impl Seed {
    #[new]
    #[pyo3(signature = (*, seed))]
    fn new(seed: u64) -> Self {
        Self { seed }
    }

    fn __repr__(&self) -> String {
        format!("Seed(seed={})", self.seed)
    }
}

/// Remove every fault: frames and slaves behave normally again.
#[pyclass(name = "Clear", module = "ether_ros._native", frozen, eq)]
#[derive(Clone, PartialEq)]
pub struct Clear;

#[pymethods]
impl Clear {
    #[new]
    #[pyo3(signature = (*))]
    fn new() -> Self {
        Self
    }

    fn __repr__(&self) -> &'static str {
        "Clear()"
    }
}

/// Any fault, as `SimNetwork.inject` takes it.
pub enum Fault {
    Drop(DropFault),
    Corrupt(Corrupt),
    Delay(Delay),
    Reset(Reset),
    RefuseOp(RefuseOp),
    StallMailbox(StallMailbox),
    Link(Link),
    DriftStep(DriftStep),
    DriveFault(DriveFault),
    Seed(Seed),
    Clear,
}

/// The Python names of the fault types, for the message when something else is injected.
const NAMES: &str =
    "Drop, Corrupt, Delay, Reset, RefuseOp, StallMailbox, Link, DriftStep, DriveFault, Seed, Clear";

impl Fault {
    pub fn of(v: &Bound<'_, PyAny>) -> PyResult<Self> {
        macro_rules! try_as {
            ($($ty:ty => $variant:ident),*) => {
                $(if let Ok(f) = v.cast::<$ty>() {
                    return Ok(Fault::$variant(f.get().clone()));
                })*
            };
        }
        try_as!(
            DropFault => Drop,
            Corrupt => Corrupt,
            Delay => Delay,
            Reset => Reset,
            RefuseOp => RefuseOp,
            StallMailbox => StallMailbox,
            Link => Link,
            DriftStep => DriftStep,
            DriveFault => DriveFault,
            Seed => Seed
        );
        if v.cast::<Clear>().is_ok() {
            return Ok(Fault::Clear);
        }
        let ty = v
            .get_type()
            .name()
            .map(|n| n.to_string())
            .unwrap_or_default();
        Err(PyTypeError::new_err(format!(
            "inject() takes a fault ({NAMES}), not {ty}"
        )))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<DropFault>()?;
    m.add_class::<Corrupt>()?;
    m.add_class::<Delay>()?;
    m.add_class::<Reset>()?;
    m.add_class::<RefuseOp>()?;
    m.add_class::<StallMailbox>()?;
    m.add_class::<Link>()?;
    m.add_class::<DriftStep>()?;
    m.add_class::<DriveFault>()?;
    m.add_class::<Seed>()?;
    m.add_class::<Clear>()?;
    Ok(())
}
