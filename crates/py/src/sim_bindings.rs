//! Python bindings for the simulator: `ether_ros._native.SimNetwork`.
//!
//! # Slave spec (`ether_ros._native.SlaveSpec`, passed to `SimNetwork.add_slave`)
//!
//! Built by `python/ether_ros/sim/spec.py` from the bus config and the ESI; documented for
//! people in `docs/simulator.md`. A frozen class with a keyword-only constructor: `name`,
//! `vendor_id`, `product_code`, `revision` and `sii` are required, the rest optional (None: the
//! default of `ether_ros_sim::SlaveSpec::default()`, the one place it lives); an unknown or
//! missing keyword is a `TypeError` naming it, a wrong value a `ValueError` naming
//! `SlaveSpec.field`. Fields:
//!
//! | field | type | meaning |
//! |---|---|---|
//! | `name` | str | slave name, for messages |
//! | `vendor_id`, `product_code`, `revision`, `serial` | int | identity (informational: the master reads it from the SII) |
//! | `alias` | int | station alias; used only when `sii` is shorter than 5 words (the ESC loads 0x0012 from SII word 4) |
//! | `sii` | bytes | the SII EEPROM image |
//! | `objects` | list[(index, name, object_code)] | CoE objects |
//! | `entries` | list[(index, subindex, name, data_type, bit_length, access, pdo_mappable, default)] | CoE entries; `access` is 'ro', 'rw' or 'wo'; `default` is little-endian bytes or None (zeros) |
//! | `idns` | list[(idn, name, data_type, bit_length, default)] | IDN dictionary of a drive with SoE (the same for each of its drives); the attribute follows from the ETG.1000.6 data type and bit length; `default` is little-endian bytes or None (zeros), a list IDN's the whole element (current length, maximum length, items) |
//! | `device` | str | firmware model for `devices::create` ("none" default, "laelaps_leg", "generic_io", "cia402", "loopback") |
//! | `params` | dict[str, float] | device parameters |
//! | `drift_ppm` | float | clock drift of the slave's local clock (default 0) |
//! | `delay_ns` | int | one-way delay of the link into this slave's port 0: cable + the upstream slave's forwarding (default 500) |
//! | `upstream` | (parent_index, port) or None | where port 0 is connected: port 1..=3 of an earlier slave; None: port 1 of the previous slave (a line). Slaves are added in the frame's visiting order |
//! | `dc_supported` | bool | the ESC has distributed clocks (feature bits 2/3 in 0x0008; default True) |
//! | `dc_required` | bool | PREOP->SAFEOP refuses (0x0030) unless SYNC0 is active with a cycle time (default False) |
//! | `mailbox` | `MailboxSpec(rx_offset, rx_size, tx_offset, tx_size)` or None | standard mailbox (SM0 = rx, master->slave; SM1 = tx), used when SII words 0x18..=0x1B are zero |
//! | `pdram_kib` | int | process-data RAM size in KiB (register 0x0006), 1..=60; default the chip's (ET1100 8, ET1200 1, LAN9252 4) |
//! | `loopback_links` | list[(out_index, out_sub, in_index, in_sub)] | output → input pairs of the `loopback` model (built by `ether_ros.sim.spec.loopback_pairs`) |
//! | `esc` | str | slave controller chip whose registers the ESC presents: "et1100" (default), "et1200", "lan9252" |
//! | `lrw` | bool | False: the ESC reports "LRW not supported" (0x0008 bit 9) and ignores LRW datagrams (no data, no working counter); default True |
//! | `safeop_op_timeout_ms` | int | how long a SAFEOP->OP request waits for valid outputs before it is refused (ESI `<SafeopOpTimeout>`, default 10000) |
//! | `foe` | `FoeSpec(capacity, password, files, firmware, busy)` or None | the FoE server's store of a slave whose SII announces FoE (`ether_ros_sim::foe`); None: an empty 64 KiB store without password |

use std::collections::BTreeMap;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use pyo3::exceptions::{PyOSError, PyRuntimeError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList, PyTuple};

use ether_ros_engine::LinkKind;
use ether_ros_protocol::{reg, Command};
use ether_ros_sim::chip::EscChip;
use ether_ros_sim::esc::Esc;
use ether_ros_sim::faults::Rng;
use ether_ros_sim::network::lock;
use ether_ros_sim::od::{Access, Entry, Object};
use ether_ros_sim::pi_mutex::PiGuard;
use ether_ros_sim::runner::{Runner, RunnerOptions, Timing};
use ether_ros_sim::soe::IdnSpec;
use ether_ros_sim::{FoeSpec, MailboxSpec, Network, SlaveSpec};

use crate::errors::{invalid, Reason};
use crate::sim_faults::Fault;

/// Most firmware worker threads `run_on_interface` starts.
const MAX_FIRMWARE_THREADS: usize = 64;

/// `InvalidRequest("SlaveSpec.key: expected ...")` with the field `SlaveSpec.key`.
fn bad_key(key: &str, reason: Reason, expected: &str) -> PyErr {
    let field = format!("SlaveSpec.{key}");
    invalid(&field, reason, format!("{field}: expected {expected}"))
}

/// Little-endian bytes (`None`: empty, read as zeros).
fn bytes_of(v: &Bound<'_, PyAny>, key: &str) -> PyResult<Vec<u8>> {
    if v.is_none() {
        return Ok(Vec::new());
    }
    if let Ok(b) = v.cast::<PyBytes>() {
        return Ok(b.as_bytes().to_vec());
    }
    v.extract::<Vec<u8>>()
        .map_err(|_| bad_key(key, Reason::BadValue, "bytes"))
}

/// A standard mailbox (SM0 = rx, master → slave; SM1 = tx), used when SII words 0x18..=0x1B
/// are zero.
#[pyclass(name = "MailboxSpec", module = "ether_ros._native", frozen, get_all)]
pub struct PyMailboxSpec {
    rx_offset: u16,
    rx_size: u16,
    tx_offset: u16,
    tx_size: u16,
}

#[pymethods]
impl PyMailboxSpec {
    #[new]
    #[pyo3(signature = (*, rx_offset, rx_size, tx_offset, tx_size))]
    fn new(rx_offset: u16, rx_size: u16, tx_offset: u16, tx_size: u16) -> Self {
        Self {
            rx_offset,
            rx_size,
            tx_offset,
            tx_size,
        }
    }

    fn __repr__(&self) -> String {
        format!(
            "MailboxSpec(rx_offset={}, rx_size={}, tx_offset={}, tx_size={})",
            self.rx_offset, self.rx_size, self.tx_offset, self.tx_size
        )
    }
}

/// The FoE store of a slave that announces FoE (`ether_ros_sim::foe::FoeSpec`): `capacity`
/// (bytes all files may take), `password` (None: any), `files` ((name, contents) at power-on),
/// `firmware` (the firmware image's name, written in BOOT only), `busy` (data packets of each
/// write answered with BUSY first). Each left None takes the simulator's default; files that
/// do not fit the capacity are a `ValueError` saying by how much.
#[pyclass(name = "FoeSpec", module = "ether_ros._native", frozen)]
pub struct PyFoeSpec {
    inner: FoeSpec,
}

#[pymethods]
impl PyFoeSpec {
    #[new]
    #[pyo3(signature = (*, capacity = None, password = None, files = Vec::new(), firmware = None, busy = None))]
    fn new(
        capacity: Option<usize>,
        password: Option<u32>,
        files: Vec<(String, Vec<u8>)>,
        firmware: Option<String>,
        busy: Option<u32>,
    ) -> PyResult<Self> {
        let mut inner = FoeSpec {
            password,
            files,
            ..FoeSpec::default()
        };
        inner.capacity = capacity.unwrap_or(inner.capacity);
        inner.firmware = firmware.unwrap_or(inner.firmware);
        inner.busy = busy.unwrap_or(inner.busy);
        if inner.firmware.is_empty() {
            return Err(invalid(
                "FoeSpec.firmware",
                Reason::BadValue,
                "FoeSpec.firmware: expected a file name",
            ));
        }
        inner.check().map_err(|e| {
            invalid(
                "FoeSpec.files",
                Reason::Refused,
                format!("FoeSpec.files: {e}"),
            )
        })?;
        Ok(Self { inner })
    }

    #[getter]
    fn capacity(&self) -> usize {
        self.inner.capacity
    }
    #[getter]
    fn password(&self) -> Option<u32> {
        self.inner.password
    }
    #[getter]
    fn files<'py>(&self, py: Python<'py>) -> Vec<(String, Bound<'py, PyBytes>)> {
        self.inner
            .files
            .iter()
            .map(|(n, d)| (n.clone(), PyBytes::new(py, d)))
            .collect()
    }
    #[getter]
    fn firmware(&self) -> &str {
        &self.inner.firmware
    }
    #[getter]
    fn busy(&self) -> u32 {
        self.inner.busy
    }

    fn __repr__(&self) -> String {
        format!(
            "FoeSpec(capacity={}, password={:?}, files={:?}, firmware={:?}, busy={})",
            self.inner.capacity,
            self.inner.password,
            self.inner.files.iter().map(|(n, _)| n).collect::<Vec<_>>(),
            self.inner.firmware,
            self.inner.busy
        )
    }
}

/// One CoE entry of a spec: (index, subindex, name, data_type, bit_length, access,
/// pdo_mappable, default).
type EntryTuple<'py> = (u16, u8, String, u16, u16, String, bool, Bound<'py, PyAny>);
/// One IDN of a spec: (idn, name, data_type, bit_length, default).
type IdnTuple<'py> = (u16, String, u16, u16, Bound<'py, PyAny>);

/// A virtual slave for `SimNetwork.add_slave` (see the module documentation): built by
/// `python/ether_ros/sim/spec.py` from the bus config and the ESI, checked when made. Every
/// optional field left out (None) takes `ether_ros_sim::SlaveSpec::default()`'s value, the one
/// place those defaults live.
#[pyclass(name = "SlaveSpec", module = "ether_ros._native", frozen)]
pub struct PySlaveSpec {
    inner: SlaveSpec,
    objects: Py<PyTuple>,
    entries: Py<PyTuple>,
    idns: Py<PyTuple>,
    mailbox: Option<Py<PyMailboxSpec>>,
    foe: Option<Py<PyFoeSpec>>,
    #[pyo3(get)]
    device: String,
}

#[pymethods]
impl PySlaveSpec {
    #[new]
    #[pyo3(signature = (
        *, name, vendor_id, product_code, revision, sii, serial = None, alias = None,
        objects = Vec::new(), entries = Vec::new(), idns = Vec::new(), device = None,
        params = None, drift_ppm = None, delay_ns = None, upstream = None, dc_supported = None,
        dc_required = None, mailbox = None, pdram_kib = None, esc = None,
        safeop_op_timeout_ms = None, loopback_links = Vec::new(), lrw = None, foe = None,
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        name: String,
        vendor_id: u32,
        product_code: u32,
        revision: u32,
        sii: Bound<'_, PyAny>,
        serial: Option<u32>,
        alias: Option<u16>,
        objects: Vec<(u16, String, u8)>,
        entries: Vec<EntryTuple<'_>>,
        idns: Vec<IdnTuple<'_>>,
        device: Option<String>,
        params: Option<BTreeMap<String, f64>>,
        drift_ppm: Option<f64>,
        delay_ns: Option<u64>,
        upstream: Option<(usize, u8)>,
        dc_supported: Option<bool>,
        dc_required: Option<bool>,
        mailbox: Option<Bound<'_, PyMailboxSpec>>,
        pdram_kib: Option<u8>,
        esc: Option<String>,
        safeop_op_timeout_ms: Option<u32>,
        loopback_links: Vec<(u16, u8, u16, u8)>,
        lrw: Option<bool>,
        foe: Option<Bound<'_, PyFoeSpec>>,
    ) -> PyResult<Self> {
        let mut s = SlaveSpec {
            name,
            vendor_id,
            product_code,
            revision,
            ..SlaveSpec::default()
        };
        s.sii = bytes_of(&sii, "sii")?;
        s.serial = serial.unwrap_or(s.serial);
        s.alias = alias.unwrap_or(s.alias);
        let objects_py = PyTuple::new(py, &objects)?.unbind();
        for (index, name, object_code) in objects {
            s.objects.push(Object {
                index,
                name,
                object_code,
            });
        }
        let entries_py = PyTuple::new(py, &entries)?.unbind();
        for (index, subindex, name, data_type, bit_length, access, pdo_mappable, default) in entries
        {
            let access = match access.as_str() {
                "ro" => Access::ReadOnly,
                "rw" => Access::ReadWrite,
                "wo" => Access::WriteOnly,
                other => {
                    return Err(invalid(
                        "SlaveSpec.entries",
                        Reason::BadValue,
                        format!(
                            "SlaveSpec.entries: entry 0x{index:04X}:{subindex} has access \
                             '{other}', expected 'ro', 'rw' or 'wo'"
                        ),
                    ))
                }
            };
            let value = bytes_of(&default, "entries")?;
            s.entries.push(Entry {
                index,
                subindex,
                name,
                data_type,
                bit_length,
                access,
                pdo_mappable,
                value,
            });
        }
        let idns_py = PyTuple::new(py, &idns)?.unbind();
        for (idn, name, data_type, bit_length, default) in idns {
            let value = bytes_of(&default, "idns")?;
            s.idns
                .push(IdnSpec::typed(idn, name, data_type, bit_length, value));
        }
        if let Some(d) = device {
            s.device = d;
        }
        if let Some(p) = params {
            // Sorted by name (a BTreeMap): the device reads them in a stable order.
            s.params = p.into_iter().collect();
        }
        s.drift_ppm = drift_ppm.unwrap_or(s.drift_ppm);
        s.delay_ns = delay_ns.unwrap_or(s.delay_ns);
        s.upstream = upstream;
        s.dc_supported = dc_supported.unwrap_or(s.dc_supported);
        s.dc_required = dc_required.unwrap_or(s.dc_required);
        s.mailbox = mailbox.as_ref().map(|m| {
            let m = m.get();
            MailboxSpec {
                rx_offset: m.rx_offset,
                rx_size: m.rx_size,
                tx_offset: m.tx_offset,
                tx_size: m.tx_size,
            }
        });
        if let Some(k) = pdram_kib {
            if !(1..=60).contains(&k) {
                return Err(bad_key("pdram_kib", Reason::OutOfRange, "int 1..=60"));
            }
            s.pdram_kib = k;
        }
        if let Some(name) = esc {
            s.esc = EscChip::from_name(&name).map_err(|e| bad_key("esc", Reason::BadValue, &e))?;
        }
        s.lrw_supported = lrw.unwrap_or(s.lrw_supported);
        s.safeop_op_timeout_ms = safeop_op_timeout_ms.unwrap_or(s.safeop_op_timeout_ms);
        s.loopback_links = loopback_links;
        if let Some(f) = &foe {
            s.foe = f.get().inner.clone();
        }
        Ok(Self {
            device: s.device.clone(),
            inner: s,
            objects: objects_py,
            entries: entries_py,
            idns: idns_py,
            mailbox: mailbox.map(Bound::unbind),
            foe: foe.map(Bound::unbind),
        })
    }

    #[getter]
    fn name(&self) -> &str {
        &self.inner.name
    }
    #[getter]
    fn vendor_id(&self) -> u32 {
        self.inner.vendor_id
    }
    #[getter]
    fn product_code(&self) -> u32 {
        self.inner.product_code
    }
    #[getter]
    fn revision(&self) -> u32 {
        self.inner.revision
    }
    #[getter]
    fn serial(&self) -> u32 {
        self.inner.serial
    }
    #[getter]
    fn alias(&self) -> u16 {
        self.inner.alias
    }
    #[getter]
    fn sii<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, &self.inner.sii)
    }
    #[getter]
    fn objects<'py>(&self, py: Python<'py>) -> Bound<'py, PyTuple> {
        self.objects.bind(py).clone()
    }
    #[getter]
    fn entries<'py>(&self, py: Python<'py>) -> Bound<'py, PyTuple> {
        self.entries.bind(py).clone()
    }
    #[getter]
    fn idns<'py>(&self, py: Python<'py>) -> Bound<'py, PyTuple> {
        self.idns.bind(py).clone()
    }
    #[getter]
    fn params(&self) -> BTreeMap<String, f64> {
        self.inner.params.iter().cloned().collect()
    }
    #[getter]
    fn mailbox<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyMailboxSpec>> {
        self.mailbox.as_ref().map(|m| m.bind(py).clone())
    }
    #[getter]
    fn foe<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyFoeSpec>> {
        self.foe.as_ref().map(|f| f.bind(py).clone())
    }
    #[getter]
    fn drift_ppm(&self) -> f64 {
        self.inner.drift_ppm
    }
    #[getter]
    fn delay_ns(&self) -> u64 {
        self.inner.delay_ns
    }
    #[getter]
    fn upstream(&self) -> Option<(usize, u8)> {
        self.inner.upstream
    }
    #[getter]
    fn dc_supported(&self) -> bool {
        self.inner.dc_supported
    }
    #[getter]
    fn dc_required(&self) -> bool {
        self.inner.dc_required
    }
    #[getter]
    fn esc(&self) -> &'static str {
        self.inner.esc.name()
    }
    #[getter]
    fn lrw(&self) -> bool {
        self.inner.lrw_supported
    }
    #[getter]
    fn safeop_op_timeout_ms(&self) -> u32 {
        self.inner.safeop_op_timeout_ms
    }
    #[getter]
    fn loopback_links(&self) -> Vec<(u16, u8, u16, u8)> {
        self.inner.loopback_links.clone()
    }

    fn __repr__(&self) -> String {
        format!(
            "SlaveSpec(name={:?}, vendor_id={:#x}, product_code={:#x}, device={:?})",
            self.inner.name, self.inner.vendor_id, self.inner.product_code, self.device
        )
    }
}

/// A virtual EtherCAT network (a line of virtual slaves).
#[pyclass(name = "SimNetwork", module = "ether_ros._native")]
pub struct SimNetwork {
    net: Arc<Mutex<Network>>,
    runner: Option<Runner>,
}

impl SimNetwork {
    /// The shared network, for the engine's in-process link.
    pub fn shared(&self) -> Arc<Mutex<Network>> {
        self.net.clone()
    }

    fn lock(&self) -> PyResult<MutexGuard<'_, Network>> {
        self.net
            .lock()
            .map_err(|_| PyRuntimeError::new_err("simulator state poisoned by a panic"))
    }
}

fn slave(net: &Network, pos: usize) -> PyResult<PiGuard<'_, Esc>> {
    let n = net.len();
    net.try_slave(pos).ok_or_else(|| {
        invalid(
            "slave",
            Reason::NoSlave,
            format!("no slave at position {pos} (the network has {n})"),
        )
    })
}

/// The refusal of an object dictionary access to an entry slave `pos` does not have.
fn no_entry(pos: usize, index: u16, subindex: u8) -> PyErr {
    invalid(
        "index",
        Reason::NoEntry,
        format!("slave {pos} has no object entry 0x{index:04X}:{subindex}"),
    )
}

#[pymethods]
impl SimNetwork {
    /// `SimNetwork(seed=1, manual_clock_ns=None)`: with `manual_clock_ns` time stands still
    /// until `advance_clock` moves it (deterministic tests); otherwise CLOCK_MONOTONIC.
    #[new]
    #[pyo3(signature = (seed = 1, manual_clock_ns = None))]
    fn new(seed: u64, manual_clock_ns: Option<u64>) -> Self {
        let mut net = match manual_clock_ns {
            Some(t) => Network::with_manual_clock(t),
            None => Network::new(),
        };
        net.rng = Rng::new(seed);
        SimNetwork {
            net: Arc::new(Mutex::new(net)),
            runner: None,
        }
    }

    /// Append a slave made from `spec` (a `SlaveSpec`); returns its position.
    fn add_slave(&self, spec: PyRef<'_, PySlaveSpec>) -> PyResult<usize> {
        let s = spec.inner.clone();
        let name = s.name.clone();
        self.lock()?.add_slave(s).map_err(|e| {
            let field = format!("SlaveSpec.{}", e.field);
            // Some reasons already name the slave; say it once.
            let prefix = format!("slave '{name}': ");
            let why = e.message.strip_prefix(&prefix).unwrap_or(&e.message);
            invalid(&field, Reason::Refused, format!("{prefix}{why}"))
        })
    }

    fn __len__(&self) -> PyResult<usize> {
        Ok(self.lock()?.len())
    }

    /// Process one frame; returns the answer, or None when it is dropped or not EtherCAT.
    fn process_frame<'py>(
        &self,
        py: Python<'py>,
        frame: &[u8],
    ) -> PyResult<Option<Bound<'py, PyBytes>>> {
        let mut buf = frame.to_vec();
        let net = self.net.clone();
        let answered = py.detach(move || -> Result<Option<Vec<u8>>, ()> {
            let (ok, delay) = {
                let mut n = net.lock().map_err(|_| ())?;
                let ok = n.process_frame(&mut buf);
                (ok, n.reply_delay_us())
            };
            if ok && delay > 0 {
                std::thread::sleep(Duration::from_micros(delay));
            }
            Ok(if ok { Some(buf) } else { None })
        });
        match answered {
            Ok(Some(b)) => Ok(Some(PyBytes::new(py, &b))),
            Ok(None) => Ok(None),
            Err(()) => Err(PyRuntimeError::new_err(
                "simulator state poisoned by a panic",
            )),
        }
    }

    /// Advance device models, SYNC0 and watchdogs to now without a frame.
    fn poll(&self, py: Python<'_>) -> PyResult<()> {
        let net = self.net.clone();
        py.detach(move || net.lock().map(|mut n| n.poll()).map_err(|_| ()))
            .map_err(|_| PyRuntimeError::new_err("simulator state poisoned by a panic"))
    }

    /// Move a manual clock forward (no effect with the monotonic clock).
    fn advance_clock(&self, ns: u64) -> PyResult<()> {
        self.lock()?.advance_clock(ns);
        Ok(())
    }

    /// Serve frames on a network interface from a background thread, through `link`:
    /// "packet" (AF_PACKET) or "xdp" (AF_XDP with its XDP program). The device firmware runs
    /// on `threads` worker threads (None: one per CPU the process may use; 0: in the frame
    /// thread, the older model). `timing`: "fast" (answer when processed) or "wire" (when the
    /// modelled 100 Mbit/s wire would have brought the answer back).
    #[pyo3(signature = (ifname, link = "packet", threads = None, timing = "fast"))]
    fn run_on_interface(
        &mut self,
        py: Python<'_>,
        ifname: &str,
        link: &str,
        threads: Option<usize>,
        timing: &str,
    ) -> PyResult<()> {
        let kind: LinkKind = link
            .parse()
            .map_err(|e: String| invalid("link", Reason::BadValue, e))?;
        let timing: Timing = timing
            .parse()
            .map_err(|e: String| invalid("timing", Reason::BadValue, e))?;
        if threads.is_some_and(|n| n > MAX_FIRMWARE_THREADS) {
            return Err(invalid(
                "threads",
                Reason::OutOfRange,
                format!(
                    "threads = {}: at most {MAX_FIRMWARE_THREADS} firmware threads",
                    threads.unwrap_or(0)
                ),
            ));
        }
        if self.runner.as_ref().is_some_and(|r| r.is_running()) {
            return Err(invalid(
                "ifname",
                Reason::Busy,
                "the simulator already runs on an interface; call stop() first",
            ));
        }
        let options = RunnerOptions {
            link: kind,
            threads,
            timing,
        };
        let net = self.net.clone();
        let name = ifname.to_string();
        let r = py
            .detach(move || Runner::start_with(net, &name, options))
            // An OSError (the CLI falls back from AF_XDP to AF_PACKET on it).
            .map_err(|e| PyOSError::new_err(format!("cannot serve EtherCAT on '{ifname}': {e}")))?;
        self.runner = Some(r);
        Ok(())
    }

    /// Stop the interface thread (no effect when not running).
    fn stop(&mut self, py: Python<'_>) {
        if let Some(mut r) = self.runner.take() {
            py.detach(move || r.stop());
        }
    }

    #[getter]
    fn running(&self) -> bool {
        self.runner.as_ref().is_some_and(|r| r.is_running())
    }

    /// Inject a fault: one of the fault types of `sim_faults.rs` (`Drop(rate=0.01)`,
    /// `Reset(slave=2)`, `Link(up=False, at=3)`, `Clear()`, ...), each checked when it was made;
    /// here only what needs the network (is there a slave at that position, a drive) is checked.
    fn inject(&self, fault: &Bound<'_, PyAny>) -> PyResult<()> {
        let fault = Fault::of(fault)?;
        let mut net = self.lock()?;
        match fault {
            Fault::Drop(f) => {
                net.faults.drop_rate = f.rate;
                net.faults.drop_burst = f.burst;
                net.faults.drop_outbound = f.outbound;
            }
            Fault::Corrupt(f) => {
                net.faults.corrupt_rate = f.rate;
                net.faults.corrupt_bytes = f.bytes;
            }
            Fault::Delay(f) => net.faults.delay_us = f.us,
            Fault::Reset(f) => {
                drop(slave(&net, f.slave)?);
                net.reset_slave(f.slave);
            }
            Fault::RefuseOp(f) => slave(&net, f.slave)?.refuse_op = f.on,
            Fault::StallMailbox(f) => slave(&net, f.slave)?.mailbox_stalled = f.on,
            Fault::Link(f) => match f.at {
                // Without `at`: the master's own link. `up` plugs every cable back in, the
                // cuts inside the bus too (`link --at 2 down` is undone by `link up`).
                None if f.up => net.mend_all_links(),
                None => net.faults.link_down = true,
                // `at` alone: the link into that slave's port 0 (in a line, the one between
                // `at - 1` and `at`); with `port`: the link on that port of `at`.
                Some(pos) => {
                    let name = slave(&net, pos)?.spec.name.clone();
                    let target = match f.port {
                        None | Some(0) => pos,
                        Some(p) => net.slave_on_port(pos, p).ok_or_else(|| {
                            invalid(
                                "Link.port",
                                Reason::NotConnected,
                                format!(
                                    "Link.port: nothing is connected to port {p} of slave {pos} \
                                     ('{name}')"
                                ),
                            )
                        })?,
                    };
                    net.set_link_cut(target, !f.up);
                }
            },
            Fault::DriftStep(f) => {
                let now = net.now();
                let mut s = slave(&net, f.slave)?;
                let d = s.dc.drift_ppm();
                s.dc.set_drift(now, d + f.ppm);
            }
            Fault::DriveFault(f) => net
                .inject_device_fault(f.slave, &f.error, f.axis)
                .map_err(|e| invalid("DriveFault", Reason::Refused, e))?,
            Fault::Seed(f) => net.rng = Rng::new(f.seed),
            Fault::Clear => {
                net.faults = Default::default();
                for cell in net.cells() {
                    let mut s = lock(cell);
                    s.refuse_op = false;
                    s.mailbox_stalled = false;
                }
                net.update_topology();
            }
        }
        Ok(())
    }

    /// State of one slave: AL state/code, addresses, DC, watchdog, counters.
    fn slave_info<'py>(&self, py: Python<'py>, pos: usize) -> PyResult<Bound<'py, PyDict>> {
        let net = self.lock()?;
        let now = net.now();
        let frames = net.slave_frames(pos);
        let s = slave(&net, pos)?;
        let d = PyDict::new(py);
        let offset = s.get64(reg::DC_SYSTEM_TIME_OFFSET);
        let local = s.dc.local(now);
        d.set_item("name", &s.spec.name)?;
        d.set_item("position", pos)?;
        d.set_item("al_state", s.al_state)?;
        d.set_item(
            "al_state_name",
            ether_ros_protocol::al::state_name(s.al_state).unwrap_or("UNKNOWN"),
        )?;
        d.set_item("al_error", s.al_error)?;
        d.set_item("al_status_code", s.al_code)?;
        d.set_item("station_address", s.station_address())?;
        d.set_item("upstream", s.spec.upstream)?;
        d.set_item("open_ports", s.open_ports)?;
        d.set_item("alias", s.alias())?;
        d.set_item("dc_local_time", local)?;
        d.set_item("dc_system_time", local.wrapping_add(offset))?;
        d.set_item("dc_system_time_offset", offset)?;
        d.set_item("dc_system_time_delay", s.get32(reg::DC_SYSTEM_TIME_DELAY))?;
        let diff = s.get32(reg::DC_SYSTEM_TIME_DIFF);
        let diff_ns = if diff & 0x8000_0000 != 0 {
            -((diff & 0x7fff_ffff) as i64)
        } else {
            diff as i64
        };
        d.set_item("dc_system_time_difference", diff_ns)?;
        d.set_item("dc_drift_ppm", s.dc.drift_ppm())?;
        d.set_item("dc_correction_ppm", s.dc.correction_ppm())?;
        d.set_item("sync0_active", s.sync0_active())?;
        d.set_item("sync0_cycle_ns", s.get32(reg::DC_SYNC0_CYCLE))?;
        d.set_item("watchdog_expired", s.watchdog_expired)?;
        d.set_item("refuse_op", s.refuse_op)?;
        d.set_item("mailbox_stalled", s.mailbox_stalled)?;
        d.set_item("mailbox_queue", s.mailbox_queue_len())?;
        d.set_item("outputs_bytes", s.output_bytes())?;
        d.set_item("inputs_bytes", s.input_bytes())?;
        // The SyncManagers as the master configured them, and what the PDOs of each
        // process-data SM need: (number, start, length, control, activate, needed bytes).
        let sms: Vec<(usize, u16, u16, u8, u8, Option<usize>)> =
            s.sm.iter()
                .enumerate()
                .map(|(k, sm)| {
                    let need = s
                        .pd_sms
                        .iter()
                        .find(|p| p.number == k)
                        .map(|p| p.map.bytes());
                    (k, sm.start, sm.len, sm.control, sm.activate, need)
                })
                .filter(|t| t.2 > 0 || t.5.is_some())
                .collect();
        d.set_item("sync_managers", sms)?;
        d.set_item("eeprom_at_pdi", s.eeprom_at_pdi())?;
        let c = &s.counters;
        d.set_item("sync0_frame_latches", c.sync0_frame_latches)?;
        d.set_item("frames", frames)?;
        d.set_item("process_data_frames", c.process_data_frames)?;
        d.set_item("device_steps", c.device_steps)?;
        d.set_item("device_steps_skipped", c.device_steps_skipped)?;
        d.set_item("sync0_events", c.sync0_events)?;
        d.set_item("sync0_late_starts", c.sync0_late_starts)?;
        d.set_item("watchdog_expirations", c.watchdog_expirations)?;
        d.set_item("mailbox_received", c.mailbox_received)?;
        d.set_item("mailbox_sent", c.mailbox_sent)?;
        d.set_item("mailbox_errors", c.mailbox_errors)?;
        d.set_item("al_errors", c.al_errors)?;
        Ok(d)
    }

    /// Device physics of one slave (SI units), empty without a device model.
    fn probe<'py>(&self, py: Python<'py>, pos: usize) -> PyResult<Bound<'py, PyDict>> {
        let net = self.lock()?;
        let s = slave(&net, pos)?;
        let d = PyDict::new(py);
        for (k, v) in s.probe() {
            d.set_item(k, v)?;
        }
        Ok(d)
    }

    /// Raw value of an object-dictionary entry (little endian).
    fn od_read<'py>(
        &self,
        py: Python<'py>,
        pos: usize,
        index: u16,
        subindex: u8,
    ) -> PyResult<Bound<'py, PyBytes>> {
        let net = self.lock()?;
        let s = slave(&net, pos)?;
        match s.od.get_bytes(index, subindex) {
            Some(b) => Ok(PyBytes::new(py, b)),
            None => Err(no_entry(pos, index, subindex)),
        }
    }

    /// Set an object-dictionary entry from raw bytes (padded/truncated to its size).
    fn od_write(&self, pos: usize, index: u16, subindex: u8, data: &[u8]) -> PyResult<()> {
        let net = self.lock()?;
        let mut s = slave(&net, pos)?;
        if s.od.set_bytes(index, subindex, data) {
            Ok(())
        } else {
            Err(no_entry(pos, index, subindex))
        }
    }

    /// Raw ESC memory (registers and process RAM as stored, without access side effects).
    fn memory<'py>(
        &self,
        py: Python<'py>,
        pos: usize,
        address: usize,
        length: usize,
    ) -> PyResult<Bound<'py, PyBytes>> {
        let net = self.lock()?;
        let s = slave(&net, pos)?;
        let m = s.memory();
        let end = address.saturating_add(length).min(m.len());
        let start = address.min(end);
        Ok(PyBytes::new(py, &m[start..end]))
    }

    /// Network counters: frames seen/answered/dropped/corrupted/malformed, per-command counts.
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let net = self.lock()?;
        let st = &net.stats;
        let d = PyDict::new(py);
        d.set_item("slaves", net.len())?;
        d.set_item("frames_seen", st.frames_seen)?;
        d.set_item("frames_answered", st.frames_answered)?;
        d.set_item("frames_dropped", st.frames_dropped)?;
        d.set_item("frames_corrupted", st.frames_corrupted)?;
        d.set_item("frames_malformed", st.frames_malformed)?;
        d.set_item("frames_not_ethercat", st.frames_not_ethercat)?;
        d.set_item("datagrams", st.datagrams)?;
        d.set_item("unknown_commands", st.unknown_commands)?;
        d.set_item("polls", st.polls)?;
        d.set_item("send_errors", st.send_errors)?;
        d.set_item("max_frame_gap_ns", st.max_frame_gap_ns)?;
        d.set_item("max_frame_ns", st.max_frame_ns)?;
        let cmds = PyDict::new(py);
        for c in 0..15u8 {
            if let Some(cmd) = Command::from_u8(c) {
                cmds.set_item(cmd.name(), st.per_command[c as usize])?;
            }
        }
        d.set_item("commands", cmds)?;
        d.set_item(
            "running",
            self.runner.as_ref().is_some_and(|r| r.is_running()),
        )?;
        let fw = PyDict::new(py);
        let runner = self.runner.as_ref();
        fw.set_item("threads", runner.map_or(0, Runner::firmware_threads))?;
        fw.set_item("cpus", ether_ros_sim::firmware::available_cpus())?;
        fw.set_item(
            "timing",
            match runner.map_or(Timing::Fast, |r| r.timing) {
                Timing::Fast => "fast",
                Timing::Wire => "wire",
            },
        )?;
        let workers = PyList::empty(py);
        for w in runner.map_or_else(Vec::new, Runner::worker_stats) {
            let wd = PyDict::new(py);
            wd.set_item("slaves", w.slaves.load(Ordering::Relaxed))?;
            wd.set_item("wakeups", w.wakeups.load(Ordering::Relaxed))?;
            wd.set_item("advances", w.advances.load(Ordering::Relaxed))?;
            wd.set_item("max_late_ns", w.max_late_ns.load(Ordering::Relaxed))?;
            wd.set_item("late_1ms", w.late_1ms.load(Ordering::Relaxed))?;
            wd.set_item("busy_ns", w.busy_ns.load(Ordering::Relaxed))?;
            wd.set_item("demoted", w.demoted.load(Ordering::Relaxed))?;
            wd.set_item("realtime", w.realtime.load(Ordering::Relaxed) != 0)?;
            workers.append(wd)?;
        }
        fw.set_item("workers", workers)?;
        d.set_item("firmware", fw)?;
        let faults = PyList::empty(py);
        let f = &net.faults;
        if f.drop_rate > 0.0 {
            faults.append("drop")?;
        }
        if f.corrupt_rate > 0.0 {
            faults.append("corrupt")?;
        }
        if f.delay_us > 0 {
            faults.append("delay")?;
        }
        if f.link_down || !f.cut_links.is_empty() {
            faults.append("link")?;
        }
        d.set_item("active_faults", faults)?;
        Ok(d)
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<SimNetwork>()?;
    m.add_class::<PySlaveSpec>()?;
    m.add_class::<PyMailboxSpec>()?;
    m.add_class::<PyFoeSpec>()?;
    Ok(())
}
