//! The classes of `ether_ros.errors`, raised from Rust. They are defined once, in Python; the
//! bindings look them up here and set their data (the field, the reason code) as
//! attributes, so a caller decides by the data and never parses the text.

use std::fmt::Display;

use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::PyType;

/// A class of `ether_ros.errors` (`Exception` if that module cannot be imported).
pub(crate) fn errors_class<'py>(py: Python<'py>, name: &str) -> Bound<'py, PyType> {
    py.import("ether_ros.errors")
        .and_then(|m| m.getattr(name))
        .and_then(|c| c.cast_into::<PyType>().map_err(PyErr::from))
        .unwrap_or_else(|_| py.get_type::<PyException>())
}

/// Why an argument was refused: the `code` attribute of `InvalidRequest` (the constants of the
/// same names on that class list them for Python).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Reason {
    /// A number outside the range its field allows.
    OutOfRange,
    /// A value of the right type that the field does not allow (an unknown name, a bad form).
    BadValue,
    /// No slave at the position given.
    NoSlave,
    /// The slave has no object dictionary entry at the index and subindex given.
    NoEntry,
    /// Nothing is connected to the port given.
    NotConnected,
    /// The simulator already does what was asked to start (it serves an interface).
    Busy,
    /// The simulator cannot build what the spec describes (device model, topology, chip).
    Refused,
}

impl Reason {
    /// The code as Python sees it.
    fn code(self) -> &'static str {
        match self {
            Reason::OutOfRange => "out_of_range",
            Reason::BadValue => "bad_value",
            Reason::NoSlave => "no_slave",
            Reason::NoEntry => "no_entry",
            Reason::NotConnected => "not_connected",
            Reason::Busy => "busy",
            Reason::Refused => "refused",
        }
    }
}

/// `ether_ros.errors.InvalidRequest` (also a `ValueError`) with `message` as its text and the
/// refused `field` (`"SlaveSpec.pdram_kib"`, `"Drop.rate"`, `"SimNetwork.inject.slave"`) and
/// the reason's code as attributes.
pub(crate) fn invalid(field: &str, reason: Reason, message: impl Display) -> PyErr {
    Python::attach(|py| {
        let err = PyErr::from_type(errors_class(py, "InvalidRequest"), message.to_string());
        let value = err.value(py);
        // Setting an attribute on a fresh exception cannot fail short of memory exhaustion.
        let _ = value.setattr("field", field);
        let _ = value.setattr("code", reason.code());
        err
    })
}
