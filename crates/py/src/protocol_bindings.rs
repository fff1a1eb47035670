//! `ether_ros._native.protocol`: the protocol crate seen from Python, so that no Python module
//! keeps a copy of an EtherCAT fact.
//!
//! Constants come in namespaces built from the crate's tables (`protocol.reg.AL_CONTROL`,
//! `protocol.sii.CHECKSUM_ERROR`, `protocol.cw.FAULT_RESET`, ...): each table is exported by
//! name, so a constant is written once, in Rust. Functions give the texts of codes, the CRC,
//! the object address grammar, the data types and the value checks; `AreaDecoder` decodes a
//! slave's process area per published sample.

use ether_ros_protocol as p;
use p::dtype::Kind;
use p::value::ValueError as CheckError;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyBytes, PyDict, PyList, PyTuple, PyType};

const MODULE: &str = "ether_ros._native.protocol";

static VALUE_CHECK_ERROR: PyOnceLock<Py<PyType>> = PyOnceLock::new();

/// `protocol.ValueCheckError(ValueError)`: a value that does not fit a type or a variable's
/// range. Carries `reason` (`not_finite`, `not_integer`, `out_of_range`, `not_numeric`),
/// `minimum` and `maximum` as data.
fn value_check_error(py: Python<'_>) -> &Bound<'_, PyType> {
    VALUE_CHECK_ERROR
        .get_or_init(py, || {
            PyErr::new_type(
                py,
                c"ether_ros._native.protocol.ValueCheckError",
                Some(
                    c"A value does not fit: `reason` says why (not_finite, not_integer, \
                      out_of_range, not_numeric); `minimum` and `maximum` give the range.",
                ),
                Some(&py.get_type::<PyValueError>()),
                None,
            )
            .expect("creating ValueCheckError")
        })
        .bind(py)
}

fn check_error(py: Python<'_>, e: CheckError) -> PyErr {
    let (minimum, maximum) = match e {
        CheckError::OutOfRange { minimum, maximum } => (Some(minimum), Some(maximum)),
        _ => (None, None),
    };
    let err = PyErr::from_type(value_check_error(py).clone(), e.to_string());
    let value = err.value(py);
    // Setting attributes on a fresh exception instance cannot fail short of memory exhaustion.
    let _ = value.setattr("reason", e.reason());
    let _ = value.setattr("minimum", minimum);
    let _ = value.setattr("maximum", maximum);
    err
}

fn kind(name: &str) -> PyResult<Kind> {
    Kind::from_name(name).ok_or_else(|| {
        PyValueError::new_err(format!(
            "unknown value kind '{name}' (bool, int, uint, real, string, bytes)"
        ))
    })
}

/// The name of the AL state in bits 0..=3 of `state`, or None.
#[pyfunction]
fn al_state_name(state: u8) -> Option<&'static str> {
    p::al::state_name(state)
}

/// Words for an AL status code (vendor-specific and unknown codes say so).
#[pyfunction]
fn al_status_text(code: u16) -> String {
    p::al::code_text(code)
}

/// Text of an SDO abort code ("unknown abort code" when not in the table).
#[pyfunction]
fn sdo_abort_text(code: u32) -> &'static str {
    p::coe::abort_text(code)
}

/// Text of a mailbox error code.
#[pyfunction]
fn mailbox_error_text(code: u16) -> &'static str {
    p::mailbox::error_text(code)
}

/// Name of a mailbox type ("CoE"), or None.
#[pyfunction]
fn mailbox_type_name(mbx_type: u8) -> Option<&'static str> {
    p::mailbox::type_name(mbx_type)
}

// ----- record codecs (one codec, crates/protocol; the master's Python wraps these) --------

/// The 8 register bytes of a SyncManager the master writes (status and PDI control 0).
#[pyfunction]
#[pyo3(signature = (start, length, control, enable = true))]
fn sm_record<'py>(
    py: Python<'py>,
    start: u16,
    length: u16,
    control: u8,
    enable: bool,
) -> Bound<'py, PyBytes> {
    PyBytes::new(
        py,
        &p::reg::sm::Record::new(start, length, control, enable).encode(),
    )
}

/// `(start, length, control, status, activate, pdi_control)` of the SyncManager record `data`
/// starts with, or None when it is shorter than 8 bytes.
#[pyfunction]
fn parse_sm_record(data: &[u8]) -> Option<(u16, u16, u8, u8, u8, u8)> {
    p::reg::sm::Record::decode(data).map(|r| {
        (
            r.start,
            r.length,
            r.control,
            r.status,
            r.activate,
            r.pdi_control,
        )
    })
}

/// The 16 register bytes of an FMMU: `kind` is `fmmu.READ` and/or `fmmu.WRITE`.
#[pyfunction]
#[pyo3(signature = (
    logical_start, length, physical_start, kind,
    logical_start_bit = 0, logical_stop_bit = 7, physical_start_bit = 0, enable = true
))]
#[allow(clippy::too_many_arguments)]
fn fmmu_record<'py>(
    py: Python<'py>,
    logical_start: u32,
    length: u16,
    physical_start: u16,
    kind: u8,
    logical_start_bit: u8,
    logical_stop_bit: u8,
    physical_start_bit: u8,
    enable: bool,
) -> Bound<'py, PyBytes> {
    let r = p::reg::fmmu::Record {
        logical_start,
        length,
        logical_start_bit,
        logical_stop_bit,
        physical_start,
        physical_start_bit,
        kind,
        activate: if enable {
            p::reg::fmmu::ACTIVATE_ENABLE
        } else {
            0
        },
    };
    PyBytes::new(py, &r.encode())
}

/// An FMMU record as Python gets it (the fields in register order).
type PyFmmu = (u32, u16, u8, u8, u16, u8, u8, u8);

/// `(logical_start, length, logical_start_bit, logical_stop_bit, physical_start,
/// physical_start_bit, kind, activate)` of the FMMU record `data` starts with, or None when it
/// is shorter than 13 bytes.
#[pyfunction]
fn parse_fmmu_record(data: &[u8]) -> Option<PyFmmu> {
    p::reg::fmmu::Record::decode(data).map(|r| {
        (
            r.logical_start,
            r.length,
            r.logical_start_bit,
            r.logical_stop_bit,
            r.physical_start,
            r.physical_start_bit,
            r.kind,
            r.activate,
        )
    })
}

/// The categories of an SII image: `(offset, type, data)` from word 0x40 up to the end
/// marker, stopping where a category runs past the image.
#[pyfunction]
fn sii_categories<'py>(py: Python<'py>, image: &[u8]) -> Vec<(usize, u16, Bound<'py, PyBytes>)> {
    p::sii::categories(image)
        .map(|c| (c.offset, c.kind, PyBytes::new(py, c.data)))
        .collect()
}

/// A category: its header (`kind`, size in words) and `data`, padded to a whole word.
#[pyfunction]
fn sii_category_bytes<'py>(py: Python<'py>, kind: u16, data: &[u8]) -> Bound<'py, PyBytes> {
    let mut out = Vec::with_capacity(data.len() + 5);
    p::sii::encode_category(kind, data, &mut out);
    PyBytes::new(py, &out)
}

/// Whether `image` holds the category list up to its end marker (a list running on past
/// `max_bytes` counts as complete).
#[pyfunction]
fn sii_list_complete(image: &[u8], max_bytes: usize) -> bool {
    p::sii::list_complete(image, max_bytes)
}

/// One 8-byte record of the SII SyncM category.
#[pyfunction]
fn sii_syncm_record<'py>(
    py: Python<'py>,
    start: u16,
    length: u16,
    control: u8,
    enable: u8,
    kind: u8,
) -> Bound<'py, PyBytes> {
    let r = p::sii::syncm::Record {
        start,
        length,
        control,
        status: 0,
        enable,
        kind,
    };
    PyBytes::new(py, &r.encode())
}

/// `(start, length, control, status, enable, type)` of every record of a SyncM category's data.
#[pyfunction]
fn parse_sii_syncms(data: &[u8]) -> Vec<(u16, u16, u8, u8, u8, u8)> {
    p::sii::syncm::Record::decode_all(data)
        .map(|r| (r.start, r.length, r.control, r.status, r.enable, r.kind))
        .collect()
}

/// The 8-byte record of one PDO of a TxPDO/RxPDO category (`sync_manager` `sii_pdo.NO_SM`
/// when not assigned by default).
#[pyfunction]
fn sii_pdo_record<'py>(
    py: Python<'py>,
    index: u16,
    entries: u8,
    sync_manager: u8,
    name: u8,
    flags: u16,
) -> Bound<'py, PyBytes> {
    let r = p::sii::pdo::Record {
        index,
        entries,
        sync_manager,
        synchronization: 0,
        name,
        flags,
    };
    PyBytes::new(py, &r.encode())
}

/// The 8-byte record of one PDO entry (`data_type` the low byte of the type code).
#[pyfunction]
fn sii_pdo_entry_record<'py>(
    py: Python<'py>,
    index: u16,
    subindex: u8,
    name: u8,
    data_type: u8,
    bit_length: u8,
) -> Bound<'py, PyBytes> {
    let e = p::sii::pdo::Entry {
        index,
        subindex,
        name,
        data_type,
        bit_length,
        flags: 0,
    };
    PyBytes::new(py, &e.encode())
}

/// A PDO as Python gets it: `(index, sync_manager, name, flags, entries)`, each entry
/// `(index, subindex, name, data_type, bit_length)`.
type PyPdo = (u16, u8, u8, u16, Vec<(u16, u8, u8, u8, u8)>);

/// The PDOs of a TxPDO/RxPDO category's data, and None; or, when a PDO's entry list runs past
/// the data, no PDOs and that PDO's index (the caller names it in its error).
#[pyfunction]
fn parse_sii_pdos(data: &[u8]) -> (Vec<PyPdo>, Option<u16>) {
    match p::sii::pdo::decode_all(data) {
        Ok(pdos) => (
            pdos.iter()
                .map(|pdo| {
                    let r = pdo.record;
                    let entries = pdo
                        .entries
                        .iter()
                        .map(|e| (e.index, e.subindex, e.name, e.data_type, e.bit_length))
                        .collect();
                    (r.index, r.sync_manager, r.name, r.flags, entries)
                })
                .collect(),
            None,
        ),
        Err(t) => (Vec::new(), Some(t.index)),
    }
}

/// The 24-byte record of one DC operation mode.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn sii_dc_record<'py>(
    py: Python<'py>,
    cycle_time_sync0: u32,
    shift_time_sync0: i32,
    shift_time_sync1: i32,
    sync1_cycle_factor: u16,
    assign_activate: u16,
    sync0_cycle_factor: u16,
    name: u8,
    description: u8,
) -> Bound<'py, PyBytes> {
    let r = p::sii::dc::Record {
        cycle_time_sync0,
        shift_time_sync0,
        shift_time_sync1,
        sync1_cycle_factor,
        assign_activate,
        sync0_cycle_factor,
        name,
        description,
    };
    PyBytes::new(py, &r.encode())
}

/// A DC record as Python gets it (the fields in record order).
type PyDc = (u32, i32, i32, u16, u16, u16, u8, u8);

/// `(cycle_time_sync0, shift_time_sync0, shift_time_sync1, sync1_cycle_factor,
/// assign_activate, sync0_cycle_factor, name, description)` of every record of a DC category.
#[pyfunction]
fn parse_sii_dcs(data: &[u8]) -> Vec<PyDc> {
    data.chunks_exact(p::sii::dc::RECORD_LEN)
        .filter_map(p::sii::dc::Record::decode)
        .map(|r| {
            (
                r.cycle_time_sync0,
                r.shift_time_sync0,
                r.shift_time_sync1,
                r.sync1_cycle_factor,
                r.assign_activate,
                r.sync0_cycle_factor,
                r.name,
                r.description,
            )
        })
        .collect()
}

/// The 2-byte CoE header of a message of `service` (number 0).
#[pyfunction]
fn coe_header<'py>(py: Python<'py>, service: u16) -> Bound<'py, PyBytes> {
    PyBytes::new(py, &p::coe::header(service))
}

/// An SDO segment message: CoE header of `service`, command byte (`specifier`, `toggle`,
/// unused bytes, `last`), `data` padded to 7 bytes.
#[pyfunction]
fn sdo_segment<'py>(
    py: Python<'py>,
    service: u16,
    specifier: u8,
    toggle: bool,
    last: bool,
    data: &[u8],
) -> Bound<'py, PyBytes> {
    let s = p::coe::Segment {
        service,
        specifier,
        toggle,
        last,
        data,
    };
    PyBytes::new(py, &s.encode())
}

/// A segment message without data (upload segment request, download segment response).
#[pyfunction]
fn sdo_toggle_message<'py>(
    py: Python<'py>,
    service: u16,
    specifier: u8,
    toggle: bool,
) -> Bound<'py, PyBytes> {
    PyBytes::new(py, &p::coe::toggle_message(service, specifier, toggle))
}

/// `(service, specifier, toggle, last, data)` of an SDO segment message (data without its
/// padding), or None when shorter than the CoE header and the command byte.
#[pyfunction]
fn parse_sdo_segment<'py>(
    py: Python<'py>,
    message: &[u8],
) -> Option<(u16, u8, bool, bool, Bound<'py, PyBytes>)> {
    p::coe::Segment::decode(message).map(|s| {
        (
            s.service,
            s.specifier,
            s.toggle,
            s.last,
            PyBytes::new(py, s.data),
        )
    })
}

/// The 10-byte header of an SDO initiate message without expedited data: with `size` a normal
/// transfer of that many bytes (size indicated; the first data follows, appended by the
/// caller), without it an upload initiate request or a download initiate response.
#[pyfunction]
#[pyo3(signature = (service, specifier, index, subindex, complete_access = false, size = None))]
fn sdo_initiate<'py>(
    py: Python<'py>,
    service: u16,
    specifier: u8,
    index: u16,
    subindex: u8,
    complete_access: bool,
    size: Option<u32>,
) -> Bound<'py, PyBytes> {
    let h = match size {
        Some(n) => {
            p::coe::SdoHeader::normal(service, specifier, index, subindex, complete_access, n)
        }
        None => p::coe::SdoHeader::new(service, specifier, index, subindex, complete_access),
    };
    PyBytes::new(py, &h.encode())
}

/// An expedited SDO initiate message carrying `data` (1 to 4 bytes) with its size indicated.
#[pyfunction]
#[pyo3(signature = (service, specifier, index, subindex, data, complete_access = false))]
fn sdo_expedited<'py>(
    py: Python<'py>,
    service: u16,
    specifier: u8,
    index: u16,
    subindex: u8,
    data: &[u8],
    complete_access: bool,
) -> PyResult<Bound<'py, PyBytes>> {
    let h =
        p::coe::SdoHeader::expedited(service, specifier, index, subindex, complete_access, data)
            .ok_or_else(|| {
                PyValueError::new_err(format!(
                    "an expedited SDO transfer carries 1 to 4 bytes, not {}",
                    data.len()
                ))
            })?;
    Ok(PyBytes::new(py, &h.encode()))
}

/// An SDO abort message of `service` for `index:subindex` with `code`.
#[pyfunction]
fn sdo_abort_message<'py>(
    py: Python<'py>,
    service: u16,
    index: u16,
    subindex: u8,
    code: u32,
) -> Bound<'py, PyBytes> {
    PyBytes::new(
        py,
        &p::coe::SdoHeader::abort(service, index, subindex, code).encode(),
    )
}

/// A decoded SDO initiate or abort header, as `parse_sdo_header` returns it.
type PySdoHeader<'py> = (u16, u8, bool, u16, u8, Option<Bound<'py, PyBytes>>, u32);

/// `(service, specifier, complete_access, index, subindex, expedited_data, word)` of an SDO
/// initiate or abort message: `expedited_data` is the data of an expedited transfer (None
/// otherwise), `word` the data field as a number (the size of a normal transfer, an abort's
/// code). None when the message is shorter than the 10-byte header.
#[pyfunction]
fn parse_sdo_header<'py>(py: Python<'py>, message: &[u8]) -> Option<PySdoHeader<'py>> {
    p::coe::SdoHeader::decode(message).map(|h| {
        (
            h.service,
            h.command.specifier,
            h.command.complete_access,
            h.index,
            h.subindex,
            h.expedited_data().map(|d| PyBytes::new(py, d)),
            h.word(),
        )
    })
}

/// The 6-byte mailbox header of a message of `length` bytes after it.
#[pyfunction]
#[pyo3(signature = (length, mbx_type, counter, address = 0))]
fn mailbox_header<'py>(
    py: Python<'py>,
    length: u16,
    mbx_type: u8,
    counter: u8,
    address: u16,
) -> Bound<'py, pyo3::types::PyBytes> {
    let header = p::mailbox::Header {
        length,
        address,
        channel: 0,
        mbx_type,
        counter,
    };
    pyo3::types::PyBytes::new(py, &header.encode())
}

/// `(length, address, channel, type, counter)` of the header `data` starts with, or None when
/// it is shorter than a header.
#[pyfunction]
fn parse_mailbox_header(data: &[u8]) -> Option<(u16, u16, u8, u8, u8)> {
    p::mailbox::Header::decode(data)
        .map(|h| (h.length, h.address, h.channel, h.mbx_type, h.counter))
}

/// An FoE message (the bytes after the mailbox header): `opcode` (`foe.OPCODE_*`), the 32-bit
/// field of bytes 2..=5 (password, packet number, error code; for busy `done | entire << 16`)
/// and the variable part (file name, data, error or busy text). An opcode that is not one is
/// a `ValueError` naming it.
#[pyfunction]
#[pyo3(signature = (opcode, field, body = b"".as_slice()))]
fn foe_message<'py>(
    py: Python<'py>,
    opcode: u8,
    field: u32,
    body: &[u8],
) -> PyResult<Bound<'py, PyBytes>> {
    use p::foe::Message;
    let m = match opcode {
        p::foe::OPCODE_READ => Message::Read {
            password: field,
            name: body,
        },
        p::foe::OPCODE_WRITE => Message::Write {
            password: field,
            name: body,
        },
        p::foe::OPCODE_DATA => Message::Data {
            packet: field,
            data: body,
        },
        p::foe::OPCODE_ACK if body.is_empty() => Message::Ack { packet: field },
        p::foe::OPCODE_ACK => {
            return Err(PyValueError::new_err("an FoE acknowledge carries no data"));
        }
        p::foe::OPCODE_ERROR => Message::Error {
            code: field,
            text: body,
        },
        p::foe::OPCODE_BUSY => Message::Busy {
            done: (field & 0xFFFF) as u16,
            entire: (field >> 16) as u16,
            text: body,
        },
        op => {
            return Err(PyValueError::new_err(
                p::foe::ParseError::UnknownOpcode(op).to_string(),
            ))
        }
    };
    Ok(PyBytes::new(py, &m.encode()))
}

/// `(opcode, field, body)` of an FoE message (the bytes after the mailbox header, trimmed to
/// its length), as `foe_message` takes them; a message shorter than the FoE header or of an
/// unknown opcode is a `ValueError` saying which.
#[pyfunction]
fn parse_foe<'py>(py: Python<'py>, data: &[u8]) -> PyResult<(u8, u32, Bound<'py, PyBytes>)> {
    let m = p::foe::Message::parse(data).map_err(|e| PyValueError::new_err(e.to_string()))?;
    let field = u32::from_le_bytes([data[2], data[3], data[4], data[5]]);
    Ok((
        m.opcode(),
        field,
        PyBytes::new(py, &data[p::foe::HEADER_LEN..]),
    ))
}

/// Text of an FoE error code.
#[pyfunction]
fn foe_error_text(code: u32) -> &'static str {
    p::foe::error_text(code)
}

/// Text of an emergency / CiA 402 error code (its class when the exact code is not listed).
#[pyfunction]
fn emergency_text(code: u32) -> &'static str {
    p::emergency::text((code & 0xFFFF) as u16)
}

/// Name of a CoE object code ("VAR", "ARRAY", "RECORD"), or None.
#[pyfunction]
fn object_code_name(code: u8) -> Option<&'static str> {
    p::coe::object_code_name(code)
}

/// CRC-8 of the SII configuration area (the checksum in word 7).
#[pyfunction]
fn sii_checksum(data: &[u8]) -> u8 {
    p::sii::checksum(data)
}

/// Parse an object address (`0x7000:01`, `7000:1`, hexadecimal): `(index, subindex)`, or None
/// when the text is not of that shape (it may be a name). Raises `ValueError` when it is of
/// that shape but out of range (`28720:10`).
#[pyfunction]
fn parse_address(text: &str) -> PyResult<Option<(u16, u8)>> {
    match p::address::parse(text) {
        Ok(a) => Ok(Some(a)),
        Err(p::address::AddressError::NotAnAddress) => Ok(None),
        Err(e) => Err(PyValueError::new_err(format!("{text:?}: {e}"))),
    }
}

/// Parse an index on its own (`6040`, `0x6040`: hexadecimal either way, the one rule for a
/// bare index): PDO and `sdo_init` indices, extras' objects, register addresses. Raises
/// `ValueError` naming the text when it is not hexadecimal or larger than 0xFFFF.
#[pyfunction]
fn parse_index(text: &str) -> PyResult<u16> {
    p::address::parse_index(text).map_err(|e| index_error(text, e, "an index"))
}

/// Parse a subindex on its own (`10` = 0x10, `0x0a`: hexadecimal either way); `ValueError`
/// when it is not hexadecimal or larger than 0xFF.
#[pyfunction]
fn parse_subindex(text: &str) -> PyResult<u8> {
    p::address::parse_subindex(text).map_err(|e| index_error(text, e, "a subindex"))
}

fn index_error(text: &str, e: p::address::AddressError, what: &str) -> PyErr {
    match e {
        p::address::AddressError::NotAnAddress => PyValueError::new_err(format!(
            "{text:?} is not {what} (hexadecimal, with or without 0x: 6040 is 0x6040)"
        )),
        e => PyValueError::new_err(format!("{text:?}: {e}")),
    }
}

/// The canonical form of an object address: `0x7000:01`.
#[pyfunction]
fn format_address(index: u16, subindex: u8) -> String {
    p::address::format(index, subindex)
}

/// Parse an object address with an optional PDO in front (`0x1600/0x0005:01`): `(pdo or None,
/// index, subindex)`, or None when the text is not of that shape; `ValueError` when out of
/// range.
#[pyfunction]
fn parse_pdo_address(text: &str) -> PyResult<Option<(Option<u16>, u16, u8)>> {
    match p::address::parse_in_pdo(text) {
        Ok(a) => Ok(Some(a)),
        Err(p::address::AddressError::NotAnAddress) => Ok(None),
        Err(e) => Err(PyValueError::new_err(format!("{text:?}: {e}"))),
    }
}

/// The canonical form of an address in a PDO: `0x1600/0x0005:01`.
#[pyfunction]
fn format_pdo_address(pdo: u16, index: u16, subindex: u8) -> String {
    p::address::format_in_pdo(pdo, index, subindex)
}

/// Every basic data type: `(code, name, bit_length, kind)`.
#[pyfunction]
fn data_types() -> Vec<(u16, &'static str, u16, &'static str)> {
    p::dtype::TYPES
        .iter()
        .map(|t| (t.code, t.name, t.bits, t.kind.name()))
        .collect()
}

/// The code of the basic type an ESI type name denotes, or None.
#[pyfunction]
fn esi_type(name: &str) -> Option<u16> {
    p::dtype::esi_type(name).map(|t| t.code)
}

/// The code of the type a configuration's `type:` names, or None.
#[pyfunction]
fn config_type(name: &str) -> Option<u16> {
    p::dtype::config_type(name).map(|t| t.code)
}

/// The ESI name a type is usually written with (`UINT`), or None.
#[pyfunction]
fn esi_type_name(code: u16) -> Option<&'static str> {
    p::dtype::esi_name(code)
}

/// Inclusive range of a numeric kind at a bit length: ints for bool/int/uint, floats for real.
#[pyfunction]
fn value_range<'py>(py: Python<'py>, kind_name: &str, bits: u32) -> PyResult<Bound<'py, PyTuple>> {
    let k = kind(kind_name)?;
    if let Some((lo, hi)) = p::value::int_range(k, bits) {
        return PyTuple::new(py, [lo, hi]);
    }
    match p::value::range(k, bits) {
        Some((lo, hi)) => PyTuple::new(py, [lo, hi]),
        None => Err(check_error(py, CheckError::NotNumeric)),
    }
}

/// The raw bits of an integer for an integral kind; `ValueCheckError` when it does not fit.
#[pyfunction]
fn encode_int(
    py: Python<'_>,
    kind_name: &str,
    bits: u32,
    value: &Bound<'_, PyAny>,
) -> PyResult<u64> {
    let k = kind(kind_name)?;
    // Python ints beyond i128 are out of range for every type here.
    let v: i128 = match value.extract() {
        Ok(v) => v,
        Err(_) if value.is_instance_of::<pyo3::types::PyInt>() => {
            let range = p::value::range(k, bits).unwrap_or((0.0, 0.0));
            return Err(check_error(
                py,
                CheckError::OutOfRange {
                    minimum: range.0,
                    maximum: range.1,
                },
            ));
        }
        Err(_) => return Err(PyTypeError::new_err("encode_int needs an int")),
    };
    p::value::encode_int(k, bits, v).map_err(|e| check_error(py, e))
}

/// The value of raw bits for an integral kind (sign extended for int).
#[pyfunction]
fn decode_int(kind_name: &str, bits: u32, raw: u64) -> PyResult<i128> {
    Ok(p::value::decode_int(kind(kind_name)?, bits, raw))
}

/// The check of a numeric write: finite, whole for integral kinds, inside
/// `minimum..=maximum`; `ValueCheckError` otherwise.
#[pyfunction]
fn check_value(
    py: Python<'_>,
    kind_name: &str,
    value: f64,
    minimum: f64,
    maximum: f64,
) -> PyResult<()> {
    p::value::check(kind(kind_name)?, value, minimum, maximum).map_err(|e| check_error(py, e))
}

/// Datagram address of register `offset` of the slave at auto-increment `position`.
#[pyfunction]
fn auto_increment_address(position: u16, offset: u16) -> u32 {
    p::auto_increment_address(position, offset)
}

/// Datagram address of register `offset` of the slave with station address `station`.
#[pyfunction]
fn fixed_address(station: u16, offset: u16) -> u32 {
    p::fixed_address(station, offset)
}

/// Ports after port 0 in `mask` (bit p = port p), in the order a frame uses them.
#[pyfunction]
fn forwarding_ports(mask: u8) -> Vec<u32> {
    // u32, not u8: PyO3 turns a Vec<u8> into bytes.
    p::topology::forwarding_ports_of_mask(mask)
        .map(u32::from)
        .collect()
}

/// Ports a frame leaves through to another slave, from DL status (bit p = port p).
#[pyfunction]
fn open_ports(dl_status: u16) -> u8 {
    p::reg::dl::open_ports(dl_status)
}

/// The signed system time difference (local − received, ns) of DC register 0x092C.
#[pyfunction]
fn dc_time_difference(raw: u32) -> i64 {
    p::reg::dc::difference_ns(raw)
}

/// The CiA 402 state a statusword codes, by name (`operation_enabled`), or None.
#[pyfunction]
fn cia402_state(statusword: u16) -> Option<&'static str> {
    p::cia402::State::from_statusword(statusword).map(|s| s.name())
}

/// One field of an area: bit offset, bit length, kind.
struct Field {
    bit_offset: usize,
    bit_length: u32,
    kind: Kind,
}

/// Decodes one slave's input or output area into floats, in the order its fields were given,
/// for every published sample. Gives the values `ProcessLayout.unpack` gives; a field the area
/// is too short for decodes as 0.0. Decoding the same bytes twice returns the same list.
#[pyclass(module = "ether_ros._native.protocol")]
struct AreaDecoder {
    fields: Vec<Field>,
    last: Option<(Vec<u8>, Py<PyList>)>,
}

#[pymethods]
impl AreaDecoder {
    /// `fields`: `(bit_offset, bit_length, kind)` per variable (kind bool, int, uint or real;
    /// reals of 32 or 64 bits).
    #[new]
    fn new(fields: Vec<(usize, u32, String)>) -> PyResult<Self> {
        let mut out = Vec::with_capacity(fields.len());
        for (i, (bit_offset, bit_length, kind_name)) in fields.into_iter().enumerate() {
            let k = kind(&kind_name)?;
            let ok = match k {
                Kind::Real => bit_length == 32 || bit_length == 64,
                Kind::Bool | Kind::Int | Kind::Uint => (1..=64).contains(&bit_length),
                Kind::String | Kind::Bytes => false,
            };
            if !ok {
                return Err(PyValueError::new_err(format!(
                    "field {i}: {kind_name} of {bit_length} bits cannot be decoded as a number"
                )));
            }
            out.push(Field {
                bit_offset,
                bit_length,
                kind: k,
            });
        }
        Ok(AreaDecoder {
            fields: out,
            last: None,
        })
    }

    /// Number of fields.
    fn __len__(&self) -> usize {
        self.fields.len()
    }

    /// The values of the fields in `area`.
    fn decode<'py>(&mut self, py: Python<'py>, area: &[u8]) -> PyResult<Bound<'py, PyList>> {
        if let Some((bytes, list)) = &self.last {
            if bytes.as_slice() == area {
                return Ok(list.bind(py).clone());
            }
        }
        let values = self.fields.iter().map(|f| {
            p::value::read_bits(area, f.bit_offset, f.bit_length)
                .map_or(0.0, |raw| p::value::decode(f.kind, f.bit_length, raw))
        });
        let list = PyList::new(py, values)?;
        match &mut self.last {
            Some((bytes, cached)) => {
                bytes.clear();
                bytes.extend_from_slice(area);
                *cached = list.clone().unbind();
            }
            None => self.last = Some((area.to_vec(), list.clone().unbind())),
        }
        Ok(list)
    }
}

/// A table of named constants, as the protocol crate defines them.
type Table<'a> = &'a [(&'a str, u64)];

/// A class named `name` whose attributes are the constants of `table` (a namespace).
fn namespace<'py>(
    py: Python<'py>,
    name: &str,
    doc: &str,
    tables: &[Table<'_>],
) -> PyResult<Bound<'py, PyAny>> {
    let attrs = PyDict::new(py);
    attrs.set_item("__module__", MODULE)?;
    attrs.set_item("__doc__", doc)?;
    for table in tables {
        for (key, value) in table.iter() {
            attrs.set_item(*key, *value)?;
        }
    }
    py.import("builtins")?
        .getattr("type")?
        .call1((name, PyTuple::empty(py), attrs))
}

/// Build the `protocol` submodule and add it to `parent` (and to `sys.modules`, so that
/// `import ether_ros._native.protocol` works too).
pub fn register(parent: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = parent.py();
    let m = PyModule::new(py, MODULE)?;
    m.add(
        "__doc__",
        "EtherCAT facts from the protocol crate (crates/protocol): registers, bits, codes and \
         their texts, CRC, object addresses, data types and value checks, CiA 402 words.",
    )?;
    let commands: Vec<(&str, u64)> = p::Command::ALL
        .iter()
        .map(|c| (c.name(), *c as u64))
        .collect();
    let namespaces: [(&str, &str, Vec<Table<'_>>); 32] = [
        ("frame", "Frame and datagram layout.", vec![p::frame::TABLE]),
        ("cmd", "Datagram command codes.", vec![&commands]),
        ("reg", "ESC register addresses.", vec![p::reg::TABLE]),
        (
            "features",
            "ESC features (0x0008) bits.",
            vec![p::reg::features::TABLE],
        ),
        (
            "port_desc",
            "Port descriptor (0x0007) values.",
            vec![p::reg::port_desc::TABLE],
        ),
        ("dl", "DL control and status bits.", vec![p::reg::dl::TABLE]),
        (
            "sm",
            "SyncManager register offsets and bits.",
            vec![p::reg::sm::TABLE],
        ),
        (
            "fmmu",
            "FMMU register offsets and bits.",
            vec![p::reg::fmmu::TABLE],
        ),
        ("dc", "Distributed clock bits.", vec![p::reg::dc::TABLE]),
        (
            "esc_config",
            "ESC configuration (0x0141) bits.",
            vec![p::reg::esc_config::TABLE],
        ),
        (
            "al",
            "AL states and control/status bits.",
            vec![p::al::TABLE],
        ),
        ("al_code", "AL status codes.", vec![p::al::CODES]),
        (
            "sii",
            "SII control/status bits and commands.",
            vec![p::sii::TABLE],
        ),
        (
            "sii_word",
            "SII header word addresses.",
            vec![p::sii::word::TABLE],
        ),
        (
            "sii_category",
            "SII category types.",
            vec![p::sii::category::TABLE],
        ),
        (
            "sii_syncm",
            "SII SyncM category: SyncManager types and enable bits.",
            vec![p::sii::syncm::TABLE],
        ),
        (
            "sii_general",
            "SII General category: byte offsets, CoE details, flags, port types.",
            vec![p::sii::general::TABLE],
        ),
        (
            "sii_fmmu",
            "SII FMMU category: what each FMMU is for.",
            vec![p::sii::fmmu_usage::TABLE],
        ),
        (
            "sii_pdo",
            "SII TxPDO/RxPDO categories: PDO flags, record length.",
            vec![p::sii::pdo::TABLE],
        ),
        (
            "mailbox",
            "Mailbox header length and types.",
            vec![p::mailbox::TABLE],
        ),
        (
            "mailbox_error",
            "Mailbox error codes.",
            vec![p::mailbox::ERRORS],
        ),
        (
            "coe",
            "CoE services, SDO specifiers, SDO information.",
            vec![p::coe::TABLE],
        ),
        ("sdo_abort", "SDO abort codes.", vec![p::coe::ABORTS]),
        (
            "soe",
            "SoE header, opcodes, element flags, IDN and attribute fields.",
            vec![p::soe::TABLE],
        ),
        ("soe_error", "SoE error codes.", vec![p::soe::ERRORS]),
        ("foe", "FoE header length and opcodes.", vec![p::foe::TABLE]),
        ("foe_error", "FoE error codes.", vec![p::foe::ERRORS]),
        ("dtype", "CoE data type codes.", vec![p::dtype::TABLE]),
        (
            "cw",
            "CiA 402 controlword bits.",
            vec![p::cia402::cw::TABLE],
        ),
        ("sw", "CiA 402 statusword bits.", vec![p::cia402::sw::TABLE]),
        (
            "cia402",
            "CiA 402 commands, objects and mode codes.",
            vec![p::cia402::command::TABLE, p::cia402::object::TABLE],
        ),
        (
            "mode",
            "CiA 402 modes of operation (0x6060 values).",
            vec![p::cia402::mode::TABLE],
        ),
    ];
    for (name, doc, tables) in namespaces.iter() {
        m.add(*name, namespace(py, name, doc, tables)?)?;
    }
    m.add("PORT_ORDER", PyTuple::new(py, p::topology::PORT_ORDER)?)?;
    m.add("AL_STATES", PyTuple::new(py, p::al::STATES)?)?;
    m.add("CIA402_STATES", PyTuple::new(py, p::cia402::State::NAMES)?)?;
    let modes: Vec<(&str, i8, u32)> = p::cia402::Mode::ALL
        .iter()
        .map(|m| (m.name(), m.code(), m.supported_bit()))
        .collect();
    m.add("CIA402_MODES", PyTuple::new(py, modes)?)?;
    let al_texts = PyDict::new(py);
    for (code, text) in p::al::CODE_TEXTS {
        al_texts.set_item(code, text)?;
    }
    m.add("AL_STATUS_TEXTS", al_texts)?;
    let abort_texts = PyDict::new(py);
    for (code, text) in p::coe::ABORT_TEXTS {
        abort_texts.set_item(code, text)?;
    }
    m.add("SDO_ABORT_TEXTS", abort_texts)?;
    let emergency = PyDict::new(py);
    for (code, text) in p::emergency::CODES {
        emergency.set_item(code, text)?;
    }
    m.add("EMERGENCY_TEXTS", emergency)?;
    let foe_texts = PyDict::new(py);
    for (code, text) in p::foe::ERROR_TEXTS {
        foe_texts.set_item(code, text)?;
    }
    m.add("FOE_ERROR_TEXTS", foe_texts)?;
    m.add("ValueCheckError", value_check_error(py))?;
    m.add_class::<AreaDecoder>()?;
    m.add_function(wrap_pyfunction!(al_state_name, &m)?)?;
    m.add_function(wrap_pyfunction!(al_status_text, &m)?)?;
    m.add_function(wrap_pyfunction!(sdo_abort_text, &m)?)?;
    m.add_function(wrap_pyfunction!(mailbox_error_text, &m)?)?;
    m.add_function(wrap_pyfunction!(mailbox_type_name, &m)?)?;
    m.add_function(wrap_pyfunction!(emergency_text, &m)?)?;
    m.add_function(wrap_pyfunction!(mailbox_header, &m)?)?;
    m.add_function(wrap_pyfunction!(parse_mailbox_header, &m)?)?;
    m.add_function(wrap_pyfunction!(object_code_name, &m)?)?;
    m.add_function(wrap_pyfunction!(sii_checksum, &m)?)?;
    m.add_function(wrap_pyfunction!(parse_address, &m)?)?;
    m.add_function(wrap_pyfunction!(parse_index, &m)?)?;
    m.add_function(wrap_pyfunction!(parse_subindex, &m)?)?;
    m.add_function(wrap_pyfunction!(format_address, &m)?)?;
    m.add_function(wrap_pyfunction!(parse_pdo_address, &m)?)?;
    m.add_function(wrap_pyfunction!(format_pdo_address, &m)?)?;
    m.add_function(wrap_pyfunction!(data_types, &m)?)?;
    m.add_function(wrap_pyfunction!(esi_type, &m)?)?;
    m.add_function(wrap_pyfunction!(config_type, &m)?)?;
    m.add_function(wrap_pyfunction!(esi_type_name, &m)?)?;
    m.add_function(wrap_pyfunction!(value_range, &m)?)?;
    m.add_function(wrap_pyfunction!(encode_int, &m)?)?;
    m.add_function(wrap_pyfunction!(decode_int, &m)?)?;
    m.add_function(wrap_pyfunction!(check_value, &m)?)?;
    m.add_function(wrap_pyfunction!(auto_increment_address, &m)?)?;
    m.add_function(wrap_pyfunction!(fixed_address, &m)?)?;
    m.add_function(wrap_pyfunction!(forwarding_ports, &m)?)?;
    m.add_function(wrap_pyfunction!(open_ports, &m)?)?;
    m.add_function(wrap_pyfunction!(cia402_state, &m)?)?;
    m.add_function(wrap_pyfunction!(dc_time_difference, &m)?)?;
    m.add_function(wrap_pyfunction!(sm_record, &m)?)?;
    m.add_function(wrap_pyfunction!(parse_sm_record, &m)?)?;
    m.add_function(wrap_pyfunction!(fmmu_record, &m)?)?;
    m.add_function(wrap_pyfunction!(parse_fmmu_record, &m)?)?;
    m.add_function(wrap_pyfunction!(sii_categories, &m)?)?;
    m.add_function(wrap_pyfunction!(sii_category_bytes, &m)?)?;
    m.add_function(wrap_pyfunction!(sii_list_complete, &m)?)?;
    m.add_function(wrap_pyfunction!(sii_syncm_record, &m)?)?;
    m.add_function(wrap_pyfunction!(parse_sii_syncms, &m)?)?;
    m.add_function(wrap_pyfunction!(sii_pdo_record, &m)?)?;
    m.add_function(wrap_pyfunction!(sii_pdo_entry_record, &m)?)?;
    m.add_function(wrap_pyfunction!(parse_sii_pdos, &m)?)?;
    m.add_function(wrap_pyfunction!(sii_dc_record, &m)?)?;
    m.add_function(wrap_pyfunction!(parse_sii_dcs, &m)?)?;
    m.add_function(wrap_pyfunction!(coe_header, &m)?)?;
    m.add_function(wrap_pyfunction!(sdo_segment, &m)?)?;
    m.add_function(wrap_pyfunction!(sdo_toggle_message, &m)?)?;
    m.add_function(wrap_pyfunction!(parse_sdo_segment, &m)?)?;
    m.add_function(wrap_pyfunction!(foe_message, &m)?)?;
    m.add_function(wrap_pyfunction!(parse_foe, &m)?)?;
    m.add_function(wrap_pyfunction!(foe_error_text, &m)?)?;
    m.add_function(wrap_pyfunction!(sdo_initiate, &m)?)?;
    m.add_function(wrap_pyfunction!(sdo_expedited, &m)?)?;
    m.add_function(wrap_pyfunction!(sdo_abort_message, &m)?)?;
    m.add_function(wrap_pyfunction!(parse_sdo_header, &m)?)?;
    parent.add("protocol", &m)?;
    py.import("sys")?.getattr("modules")?.set_item(MODULE, &m)?;
    Ok(())
}
