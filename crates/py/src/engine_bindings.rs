//! Python bindings for the engine: `ether_ros._native.Engine` and its exceptions.
//!
//! Every call that can block (opening, transact, start/stop, close) releases the GIL. The plan
//! dict is described in docs/engine.md; a missing or mistyped key is a `ValueError` naming it.

use std::sync::{Arc, Mutex, Weak};

use ether_ros_engine::cia402::{
    status_flags, AxisMap, AxisPlan, DriveState, FaultReset, Limits, ModeChangeVelocity, OnStop,
    Restart, DEFAULT_TRAJECTORY_CAPACITY,
};
use ether_ros_engine::plan::{
    CyclicDatagram, DcMode, DcPlan, FramePlan, Logical, Order, Policy, RtPlan,
};
use ether_ros_engine::stats::Summary;
use ether_ros_engine::{
    flags, AxisStatus, Engine, Error, InProcessLink, LinkKind, LinkOptions, Mode, OutputField,
    Plan, Point, Request, Responder, SetpointKind, RECORD_LEN,
};
use ether_ros_protocol::{Command, MAX_FRAME_LEN};
use ether_ros_sim::network::Network;
use pyo3::exceptions::{PyException, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyBytes, PyDict, PyList, PyTuple, PyType};

use crate::sim_bindings::SimNetwork;

static ENGINE_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();
static ENGINE_TIMEOUT: PyOnceLock<Py<PyType>> = PyOnceLock::new();

/// A class of `ether_ros.errors` (`Exception` if that module cannot be imported).
fn errors_class<'py>(py: Python<'py>, name: &str) -> Bound<'py, PyType> {
    py.import("ether_ros.errors")
        .and_then(|m| m.getattr(name))
        .and_then(|c| c.cast_into::<PyType>().map_err(PyErr::from))
        .unwrap_or_else(|_| py.get_type::<PyException>())
}

/// `EngineError` subclasses `ether_ros.errors.LinkError` (so the CLI reports it as a one-line
/// user error).
fn engine_error(py: Python<'_>) -> &Bound<'_, PyType> {
    ENGINE_ERROR
        .get_or_init(py, || {
            PyErr::new_type(
                py,
                c"ether_ros._native.EngineError",
                Some(
                    c"The engine cannot do what was asked: link failure, wrong state, or the \
                        real-time setup was refused.",
                ),
                Some(&errors_class(py, "LinkError")),
                None,
            )
            .expect("creating EngineError")
        })
        .bind(py)
}

/// `EngineTimeout` is an `EngineError` and an `ether_ros.errors.FrameTimeout`: no reply to a
/// frame within its retries, with the frame's commands, the attempts and the wait as data.
fn engine_timeout(py: Python<'_>) -> &Bound<'_, PyType> {
    ENGINE_TIMEOUT
        .get_or_init(py, || {
            let attrs = PyDict::new(py);
            let made = attrs
                .set_item("__module__", "ether_ros._native")
                .and_then(|_| {
                    attrs.set_item(
                        "__doc__",
                        "No reply to an acyclic frame within its retries.",
                    )
                })
                .and_then(|_| py.import("builtins"))
                .and_then(|b| b.getattr("type"))
                .and_then(|t| {
                    let bases = PyTuple::new(
                        py,
                        [engine_error(py).clone(), errors_class(py, "FrameTimeout")],
                    )?;
                    t.call1(("EngineTimeout", bases, attrs))
                })
                .and_then(|c| c.cast_into::<PyType>().map_err(PyErr::from));
            made.expect("creating EngineTimeout").unbind()
        })
        .bind(py)
}

/// The engine's error as the Python exception of its kind, its data as attributes.
fn to_py(py: Python<'_>, e: Error) -> PyErr {
    let text = e.to_string();
    let (err, attrs): (PyErr, Vec<(&str, Py<PyAny>)>) = match e {
        Error::Invalid(m) => (PyValueError::new_err(m), vec![]),
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
            (PyErr::from_type(engine_timeout(py).clone(), text), attrs)
        }
        Error::Link { errno, .. }
        | Error::Realtime(ether_ros_engine::rt::SetupError { errno, .. }) => {
            let errno = errno
                .into_pyobject(py)
                .map(|v| v.into_any().unbind())
                .unwrap_or_else(|_| py.None());
            (
                PyErr::from_type(engine_error(py).clone(), text),
                vec![("errno", errno)],
            )
        }
        Error::State(_) => (PyErr::from_type(engine_error(py).clone(), text), vec![]),
    };
    let value = err.value(py);
    for (name, v) in attrs {
        // Setting an attribute on a fresh exception cannot fail short of memory exhaustion.
        let _ = value.setattr(name, v);
    }
    err
}

// ----- plan dict ---------------------------------------------------------------------------

fn get<'py>(d: &Bound<'py, PyDict>, path: &str, key: &str) -> PyResult<Bound<'py, PyAny>> {
    d.get_item(key)?
        .ok_or_else(|| PyValueError::new_err(format!("plan is missing '{path}{key}'")))
}

fn typed<'py, T: for<'a> FromPyObject<'a, 'py>>(
    v: &Bound<'py, PyAny>,
    path: &str,
    what: &str,
) -> PyResult<T> {
    v.extract::<T>().map_err(|_| {
        let ty = v
            .get_type()
            .name()
            .map(|n| n.to_string())
            .unwrap_or_default();
        PyValueError::new_err(format!("plan['{path}'] must be {what}, got {ty} {v}"))
    })
}

fn req<'py, T: for<'a> FromPyObject<'a, 'py>>(
    d: &Bound<'py, PyDict>,
    path: &str,
    key: &str,
    what: &str,
) -> PyResult<T> {
    typed(&get(d, path, key)?, &format!("{path}{key}"), what)
}

fn opt<'py, T: for<'a> FromPyObject<'a, 'py>>(
    d: &Bound<'py, PyDict>,
    path: &str,
    key: &str,
    what: &str,
    default: T,
) -> PyResult<T> {
    match d.get_item(key)? {
        Some(v) if !v.is_none() => typed(&v, &format!("{path}{key}"), what),
        _ => Ok(default),
    }
}

/// Refuse a key of `d` that is not in `keys`: a misspelt field (`velocty_max`) must not pass as
/// an absent one and take its default (an unlimited velocity), so the plan is a closed
/// contract. The message names the key where it is and the keys that are known there.
fn known_keys(d: &Bound<'_, PyDict>, path: &str, keys: &[&str]) -> PyResult<()> {
    for k in d.keys() {
        let name: String = k.extract().map_err(|_| {
            PyValueError::new_err(format!("plan['{path}']: keys must be str, got {k}"))
        })?;
        if !keys.contains(&name.as_str()) {
            return Err(PyValueError::new_err(format!(
                "plan['{path}{name}']: unknown key (known here: {})",
                keys.join(", ")
            )));
        }
    }
    Ok(())
}

/// The plan's top-level keys (`datagrams` alone for a one-frame plan, else `frames`).
const PLAN_KEYS: &[&str] = &[
    "cycle_ns",
    "order",
    "frames",
    "datagrams",
    "image_len",
    "output_ranges",
    "initial_image",
    "safe_image",
    "dc",
    "rt",
    "watchdog_ns",
    "ring_capacity",
    "axes",
    "trajectory_capacity",
];
const FRAME_KEYS: &[&str] = &["datagrams", "every", "watchdog_ns"];
const DC_KEYS: &[&str] = &["mode", "time_offset_ns", "sync0_shift_ns"];
const RT_KEYS: &[&str] = &["policy", "priority", "cpu", "runtime_ns", "lock_memory"];
const DC_DATAGRAM_KEYS: &[&str] = &["kind", "station"];
const LOGICAL_DATAGRAM_KEYS: &[&str] =
    &["kind", "address", "length", "image_offset", "expected_wkc"];
const AXIS_KEYS: &[&str] = &[
    "name",
    "map",
    "mode",
    "position_scale",
    "position_offset",
    "velocity_scale",
    "torque_scale",
    "position_min",
    "position_max",
    "velocity_max",
    "torque_max",
    "deceleration",
    "max_acceleration",
    "mode_change_velocity",
    "restart",
    "following_error_window",
    "on_stop",
    "fault_reset",
    "fault_retries",
    "fault_backoff_ns",
    "interpolation_max_ns",
];
/// The axis map's roles: the CiA 402 objects of `python/ether_ros/config/cia402.py` OBJECTS.
const AXIS_MAP_KEYS: &[&str] = &[
    "controlword",
    "statusword",
    "mode",
    "mode_display",
    "target_position",
    "target_velocity",
    "target_torque",
    "position",
    "velocity",
    "torque",
    "error_code",
    "following_error",
];

fn sub_dict<'py>(d: &Bound<'py, PyDict>, key: &str) -> PyResult<Bound<'py, PyDict>> {
    let v = get(d, "", key)?;
    v.cast_into::<PyDict>()
        .map_err(|_| PyValueError::new_err(format!("plan['{key}'] must be a dict")))
}

/// `{path}datagrams`: the datagrams of one cyclic frame.
fn parse_datagrams(d: &Bound<'_, PyDict>, path: &str) -> PyResult<Vec<CyclicDatagram>> {
    let list = get(d, path, "datagrams")?;
    let list = list.cast::<PyList>().map_err(|_| {
        PyValueError::new_err(format!("plan['{path}datagrams'] must be a list of dicts"))
    })?;
    let mut datagrams = Vec::new();
    for (i, item) in list.iter().enumerate() {
        let at = format!("{path}datagrams[{i}]");
        let path = format!("{at}.");
        let item = item
            .cast_into::<PyDict>()
            .map_err(|_| PyValueError::new_err(format!("plan['{at}'] must be a dict")))?;
        let kind: String = req(&item, &path, "kind", "a str")?;
        let keys = if kind.starts_with("dc_") {
            DC_DATAGRAM_KEYS
        } else {
            LOGICAL_DATAGRAM_KEYS
        };
        known_keys(&item, &path, keys)?;
        let logical = |command| -> PyResult<CyclicDatagram> {
            Ok(CyclicDatagram::Logical {
                command,
                address: req(&item, &path, "address", "an int 0..=2**32-1")?,
                length: req(&item, &path, "length", "a non-negative int")?,
                image_offset: req(&item, &path, "image_offset", "a non-negative int")?,
                expected_wkc: req(&item, &path, "expected_wkc", "an int 0..=65535")?,
            })
        };
        datagrams.push(match kind.as_str() {
            "dc_write_ref" => CyclicDatagram::DcWriteRef {
                station: req(&item, &path, "station", "an int 0..=65535")?,
            },
            "dc_sync" => CyclicDatagram::DcSync {
                station: req(&item, &path, "station", "an int 0..=65535")?,
            },
            "lrw" => logical(Logical::Lrw)?,
            "lrd" => logical(Logical::Lrd)?,
            "lwr" => logical(Logical::Lwr)?,
            k => {
                return Err(PyValueError::new_err(format!(
                    "plan['{at}']['kind'] = '{k}': expected 'dc_write_ref', 'dc_sync', 'lrw', \
                     'lrd' or 'lwr'"
                )))
            }
        });
    }
    Ok(datagrams)
}

fn parse_plan(d: &Bound<'_, PyDict>) -> PyResult<Plan> {
    known_keys(d, "", PLAN_KEYS)?;
    let order = match req::<String>(d, "", "order", "a str")?.as_str() {
        "send_at_wake" => Order::SendAtWake,
        "send_then_wait" => Order::SendThenWait,
        o => {
            return Err(PyValueError::new_err(format!(
                "plan['order'] = '{o}': expected 'send_at_wake' or 'send_then_wait'"
            )))
        }
    };
    // `frames` (a list of {"datagrams": [...], "every": n}) or, for a one-frame plan,
    // `datagrams` alone.
    let frames = match d.get_item("frames")? {
        Some(list) => {
            let list = list
                .cast_into::<PyList>()
                .map_err(|_| PyValueError::new_err("plan['frames'] must be a list of dicts"))?;
            let mut frames = Vec::new();
            for (k, item) in list.iter().enumerate() {
                let path = format!("frames[{k}].");
                let item = item.cast_into::<PyDict>().map_err(|_| {
                    PyValueError::new_err(format!("plan['frames'][{k}] must be a dict"))
                })?;
                known_keys(&item, &path, FRAME_KEYS)?;
                frames.push(FramePlan {
                    datagrams: parse_datagrams(&item, &path)?,
                    every: opt(&item, &path, "every", "an int 1..=10000", 1)?,
                    watchdog_ns: opt(&item, &path, "watchdog_ns", "a non-negative int", 0)?,
                });
            }
            frames
        }
        None => vec![FramePlan {
            datagrams: parse_datagrams(d, "")?,
            every: 1,
            watchdog_ns: 0,
        }],
    };
    let dc = sub_dict(d, "dc")?;
    known_keys(&dc, "dc.", DC_KEYS)?;
    let mode = match req::<String>(&dc, "dc.", "mode", "a str")?.as_str() {
        "off" => DcMode::Off,
        "ref_follows_master" => DcMode::RefFollowsMaster,
        "master_follows_ref" => DcMode::MasterFollowsRef,
        m => {
            return Err(PyValueError::new_err(format!(
                "plan['dc']['mode'] = '{m}': expected 'off', 'ref_follows_master' or 'master_follows_ref'"
            )))
        }
    };
    let rt = sub_dict(d, "rt")?;
    known_keys(&rt, "rt.", RT_KEYS)?;
    let policy = match req::<String>(&rt, "rt.", "policy", "a str")?.as_str() {
        "fifo" => Policy::Fifo,
        "deadline" => Policy::Deadline,
        "other" => Policy::Other,
        p => {
            return Err(PyValueError::new_err(format!(
                "plan['rt']['policy'] = '{p}': expected 'fifo', 'deadline' or 'other'"
            )))
        }
    };
    Ok(Plan {
        cycle_ns: req(d, "", "cycle_ns", "a positive int")?,
        order,
        frames,
        image_len: req(d, "", "image_len", "a non-negative int")?,
        output_ranges: opt(
            d,
            "",
            "output_ranges",
            "a list of (offset, length) pairs",
            Vec::new(),
        )?,
        initial_image: req(d, "", "initial_image", "bytes")?,
        safe_image: req(d, "", "safe_image", "bytes")?,
        dc: DcPlan {
            mode,
            time_offset_ns: opt(&dc, "dc.", "time_offset_ns", "an int", 0)?,
            sync0_shift_ns: opt(&dc, "dc.", "sync0_shift_ns", "an int", 0)?,
        },
        // No defaults here for what Python's plan.py decides (RtPlan, build_plan): a default
        // in two places is two defaults, and they had drifted apart (priority 80 vs 0, ...).
        rt: RtPlan {
            policy,
            priority: req(&rt, "rt.", "priority", "an int")?,
            cpu: opt(&rt, "rt.", "cpu", "an int or None", None)?,
            runtime_ns: req(&rt, "rt.", "runtime_ns", "a non-negative int")?,
            lock_memory: req(&rt, "rt.", "lock_memory", "a bool")?,
        },
        watchdog_ns: req(d, "", "watchdog_ns", "a non-negative int")?,
        ring_capacity: req(d, "", "ring_capacity", "a positive int")?,
        axes: parse_axes(d)?,
        trajectory_capacity: opt(
            d,
            "",
            "trajectory_capacity",
            "a positive int",
            DEFAULT_TRAJECTORY_CAPACITY,
        )?,
    })
}

/// One of the `choices` (name, value) by name, else a ValueError naming the key and the names.
fn choice<T: Copy>(
    d: &Bound<'_, PyDict>,
    path: &str,
    key: &str,
    choices: &[(&str, T)],
) -> PyResult<T> {
    let name: String = req(d, path, key, "a str")?;
    choices
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, v)| *v)
        .ok_or_else(|| {
            let names: Vec<&str> = choices.iter().map(|(n, _)| *n).collect();
            PyValueError::new_err(format!(
                "plan['{path}{key}'] = '{name}': expected one of {}",
                names.join(", ")
            ))
        })
}

/// The modes by short name (the protocol crate's names and codes).
fn modes() -> [(&'static str, Mode); 6] {
    Mode::ALL.map(|m| (m.name(), m))
}

/// "pp, pv, hm, csp, csv, cst".
fn mode_names() -> String {
    Mode::ALL.map(|m| m.name()).join(", ")
}

/// `plan['axes']`: CiA 402 axes (docs/engine.md, "The axis stage").
fn parse_axes(d: &Bound<'_, PyDict>) -> PyResult<Vec<AxisPlan>> {
    let Some(list) = d.get_item("axes")? else {
        return Ok(Vec::new());
    };
    let list = list
        .cast::<PyList>()
        .map_err(|_| PyValueError::new_err("plan['axes'] must be a list of dicts"))?;
    let mut axes = Vec::new();
    for (i, item) in list.iter().enumerate() {
        let path = format!("axes[{i}].");
        let a = item
            .cast_into::<PyDict>()
            .map_err(|_| PyValueError::new_err(format!("plan['axes'][{i}] must be a dict")))?;
        known_keys(&a, &path, AXIS_KEYS)?;
        let m = a
            .get_item("map")?
            .ok_or_else(|| PyValueError::new_err(format!("plan is missing '{path}map'")))?
            .cast_into::<PyDict>()
            .map_err(|_| PyValueError::new_err(format!("plan['{path}map'] must be a dict")))?;
        let mp = format!("{path}map.");
        known_keys(&m, &mp, AXIS_MAP_KEYS)?;
        let off = "a byte offset or None";
        let map = AxisMap {
            controlword: req(&m, &mp, "controlword", "a byte offset")?,
            statusword: req(&m, &mp, "statusword", "a byte offset")?,
            mode: opt(&m, &mp, "mode", off, None)?,
            mode_display: opt(&m, &mp, "mode_display", off, None)?,
            target_position: opt(&m, &mp, "target_position", off, None)?,
            target_velocity: opt(&m, &mp, "target_velocity", off, None)?,
            target_torque: opt(&m, &mp, "target_torque", off, None)?,
            position: opt(&m, &mp, "position", off, None)?,
            velocity: opt(&m, &mp, "velocity", off, None)?,
            torque: opt(&m, &mp, "torque", off, None)?,
            error_code: opt(&m, &mp, "error_code", off, None)?,
            following_error: opt(&m, &mp, "following_error", off, None)?,
        };
        let num = "a number";
        axes.push(AxisPlan {
            name: req(&a, &path, "name", "a str")?,
            map,
            mode: choice(&a, &path, "mode", &modes())?,
            position_scale: opt(&a, &path, "position_scale", num, 1.0)?,
            position_offset: opt(&a, &path, "position_offset", num, 0.0)?,
            velocity_scale: opt(&a, &path, "velocity_scale", num, 1.0)?,
            torque_scale: opt(&a, &path, "torque_scale", num, 1.0)?,
            limits: Limits {
                position_min: opt(&a, &path, "position_min", num, f64::NEG_INFINITY)?,
                position_max: opt(&a, &path, "position_max", num, f64::INFINITY)?,
                velocity_max: opt(&a, &path, "velocity_max", num, f64::INFINITY)?,
                torque_max: opt(&a, &path, "torque_max", num, f64::INFINITY)?,
            },
            deceleration: opt(&a, &path, "deceleration", num, f64::INFINITY)?,
            max_acceleration: opt(&a, &path, "max_acceleration", num, f64::INFINITY)?,
            mode_change_velocity: match a.get_item("mode_change_velocity")? {
                None => ModeChangeVelocity::Actual,
                Some(_) => choice(
                    &a,
                    &path,
                    "mode_change_velocity",
                    &[
                        ("actual", ModeChangeVelocity::Actual),
                        ("zero", ModeChangeVelocity::Zero),
                    ],
                )?,
            },
            restart: match a.get_item("restart")? {
                None => Restart::Manual,
                Some(_) => choice(
                    &a,
                    &path,
                    "restart",
                    &[("manual", Restart::Manual), ("auto", Restart::Auto)],
                )?,
            },
            following_error_window: opt(&a, &path, "following_error_window", num, 0.0)?,
            on_stop: choice(
                &a,
                &path,
                "on_stop",
                &[
                    ("quick_stop", OnStop::QuickStop),
                    ("disable", OnStop::Disable),
                ],
            )?,
            fault_reset: choice(
                &a,
                &path,
                "fault_reset",
                &[("auto", FaultReset::Auto), ("manual", FaultReset::Manual)],
            )?,
            fault_retries: opt(&a, &path, "fault_retries", "a non-negative int", 3)?,
            fault_backoff_ns: opt(
                &a,
                &path,
                "fault_backoff_ns",
                "a non-negative int",
                100_000_000,
            )?,
            interpolation_max_ns: opt(
                &a,
                &path,
                "interpolation_max_ns",
                "a positive int",
                100_000_000,
            )?,
        });
    }
    Ok(axes)
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
    fn start_cyclic(&self, py: Python<'_>, plan: Bound<'_, PyDict>) -> PyResult<()> {
        let plan = parse_plan(&plan)?;
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
