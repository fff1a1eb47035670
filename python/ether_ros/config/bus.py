"""The bus configuration (YAML): models and the loader that checks it against the ESI files.

``load_bus_config(path)`` validates in two passes. The first is the schema (pydantic: unknown
keys, types, ranges); the second checks what needs the device descriptions: that every slave's
ESI device exists, that its PDO assignment, safe outputs, SDO init values and joint variables
name things the device has and that the values fit their types. Every error is a
:class:`ConfigError` ``FILE:LINE: key.path: what is wrong (got VALUE)``.
"""

from __future__ import annotations

import math
import re
import unicodedata
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, cast

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PrivateAttr,
    TypeAdapter,
    ValidationError,
    model_validator,
)

from ether_ros._native import protocol
from ether_ros._native.protocol import format_address
from ether_ros.config import cia402
from ether_ros.config import types as dt
from ether_ros.config.esi import (
    EsiDevice,
    default_modules,
    esi_files,
    load_esi,
    place_modules,
)
from ether_ros.config.files import MAX_PATH_CHARS
from ether_ros.config.process import ProcessLayout, ProcessValueError
from ether_ros.config.urdf import MOVABLE_TYPES, apply_urdf_limits, load_urdf_joints
from ether_ros.config.yamlsrc import KeyPath, SourceMap, load_yaml, shown
from ether_ros.errors import ConfigError
from ether_ros.topology import Link, visit_order

#: The group of the slaves no ``groups`` entry names: exchanged every bus cycle.
DEFAULT_GROUP = "default"

# The default simulator device model per ESI type (crates/sim/src/devices).
SIM_DEVICE_FOR_ESI = {"LaelapsII_Leg": "laelaps_leg", "GenericIO": "generic_io"}


# Device profile number of CiA 402 drives (IEC 61800-7-201), in ``<Profile><ProfileNo>``.
CIA402_PROFILE = 402


def default_sim_device(esi: EsiDevice) -> str:
    """The simulator's firmware model for a device when the config names none: the model
    written for it, the ``cia402`` drive model for any CiA 402 device (profile 402), else the
    generic ``loopback`` (outputs copied to matching inputs), so that any ESI runs on the
    simulator."""
    if esi.type_name in SIM_DEVICE_FOR_ESI:
        return SIM_DEVICE_FOR_ESI[esi.type_name]
    if CIA402_PROFILE in esi.profile_numbers:
        return "cia402"
    return "loopback"


def _parse_int(value: Any) -> Any:
    """Integers may be written as YAML ints (``0x0A12`` is an int in YAML 1.1) or strings
    ``"0x0A12"`` / ``"#x0A12"`` / ``"2578"``. Anything else is left for pydantic to reject."""
    if isinstance(value, bool):
        raise ValueError("expected an integer, not true/false")
    if isinstance(value, str):
        text = value.strip().replace("_", "")
        if len(text) > 20:  # 64 bits in decimal; longer text is not a number we take
            raise ValueError(f"not an integer: {shown(value)}")
        try:
            if text[:2].lower() in ("0x", "#x"):
                return int(text[2:], 16)
            return int(text, 10)
        except ValueError:
            raise ValueError(f"not an integer: {shown(value)}") from None
    return value


# --------------------------------------------------------------------------------------------
# Text fields. Every string of the configuration is checked where it enters: no control or
# format characters (NUL, escapes, bidirectional overrides, zero-width marks), bounded length,
# and the grammar of what it names.

#: Longest name or other text value (ESI type names, variable names, SDO text values).
MAX_TEXT_CHARS = 255
#: ROS 2 namespaces (rmw_validate_namespace: 255 with the node name; kept well below).
MAX_NAMESPACE_CHARS = 200
#: Linux interface names: IFNAMSIZ - 1.
MAX_IFNAME_CHARS = 15
#: ``[a-z_][a-z0-9_]*``: slave, joint, group, bus and node names.
IDENTIFIER_PATTERN = r"^[a-z_][a-z0-9_]*$"
MAX_IDENTIFIER_CHARS = 63
_NAMESPACE_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _plain_text(value: str) -> str:
    """No control, format, separator-line or surrogate characters."""
    for i, ch in enumerate(value):
        if unicodedata.category(ch) in ("Cc", "Cf", "Cs", "Zl", "Zp"):
            raise ValueError(f"character {i} is a control or format character ({ch!r})")
    return value


def ros_namespace(value: str) -> str:
    """A ROS 2 node namespace as rcl takes it (rmw_validate_namespace): empty, ``/``, or
    ``/``-separated tokens ``[A-Za-z_][A-Za-z0-9_]*`` (a relative one gets its leading ``/``)."""
    if value in ("", "/"):
        return value
    if len(value) > MAX_NAMESPACE_CHARS:
        raise ValueError(f"longer than {MAX_NAMESPACE_CHARS} characters")
    tokens = (value[1:] if value.startswith("/") else value).split("/")
    for token in tokens:
        if not _NAMESPACE_TOKEN.fullmatch(token):
            why = "an empty part (// or a trailing /)" if not token else f"the part {token!r}"
            raise ValueError(
                f"{why} is not a ROS name: letters, digits and _, not starting with a digit"
            )
    return "/" + "/".join(tokens)


def interface_name(value: str) -> str:
    """A Linux network interface name (dev_valid_name): 1..15 characters, none of them ``/``,
    ``:``, blank or control, and not ``.`` or ``..``."""
    if not 1 <= len(value) <= MAX_IFNAME_CHARS:
        raise ValueError(f"an interface name has 1..{MAX_IFNAME_CHARS} characters")
    if value in (".", "..") or any(c in "/:" or c.isspace() or not c.isprintable() for c in value):
        raise ValueError("not a network interface name (no '/', ':', blanks or control characters)")
    return value


def _nonzero(value: float) -> float:
    if value == 0:
        raise ValueError("must not be 0 (a scale of 0 makes every value 0)")
    return value


def _not_nan(value: float) -> float:
    if math.isnan(value):
        raise ValueError("must be a number, not NaN")
    return value


def _pair(value: Any) -> Any:
    """A YAML list of two items as the tuple the model holds (strict mode takes no list)."""
    return tuple(value) if isinstance(value, list) else value


def _bare_index(value: Any, parse: Any) -> Any:
    """An index or subindex from the configuration. Text follows the one rule of the protocol
    crate (``protocol.parse_index``): hexadecimal with or without ``0x`` — ``"6040"`` and
    ``"0x6040"`` are 0x6040, ``"#x6040"`` (the ESI's spelling) too. A YAML number is the
    number YAML read (``0x6040``; unquoted bare digits are YAML's decimal: what
    ``yaml.safe_dump`` writes for any int, so a dumped configuration reads back the same)."""
    if isinstance(value, bool):
        raise ValueError("expected an index, not true/false")
    if isinstance(value, str):
        text = value.strip()
        if text[:2].lower() == "#x":
            text = "0x" + text[2:]
        return parse(text)
    return value


def _parse_index(value: Any) -> Any:
    return _bare_index(value, protocol.parse_index)


def _parse_subindex(value: Any) -> Any:
    return _bare_index(value, protocol.parse_subindex)


HexInt = Annotated[int, BeforeValidator(_parse_int)]
#: An object index (0x6040), PDO index or subindex: hexadecimal with or without 0x.
ObjectIndex = Annotated[int, BeforeValidator(_parse_index)]
Subindex = Annotated[int, BeforeValidator(_parse_subindex)]
PdoIndex = Annotated[ObjectIndex, Field(ge=0x0001, le=0xFFFF)]
LinkName = Literal["packet", "xdp", "auto"]
Identifier = Annotated[str, Field(pattern=IDENTIFIER_PATTERN, max_length=MAX_IDENTIFIER_CHARS)]
Text = Annotated[str, Field(min_length=1, max_length=MAX_TEXT_CHARS), AfterValidator(_plain_text)]
PathText = Annotated[
    str, Field(min_length=1, max_length=MAX_PATH_CHARS), AfterValidator(_plain_text)
]
InterfaceName = Annotated[str, AfterValidator(interface_name)]
RosNamespace = Annotated[str, AfterValidator(ros_namespace)]
#: A finite scale other than 0 (finiteness: the models' allow_inf_nan=False).
Scale = Annotated[float, AfterValidator(_nonzero)]
#: A limit that may be infinite (no limit) but never NaN.
Limit = Annotated[float, Field(allow_inf_nan=True), AfterValidator(_not_nan)]


class _Model(BaseModel):
    # strict: true/false is never taken for a number, nor a number for text; NaN and ±inf are
    # refused wherever a number is expected unless a field allows them (Limit).
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)


class DcConfig(_Model):
    enabled: bool = True
    mode: Literal["ref_follows_master", "master_follows_ref"] = "ref_follows_master"
    reference: int | None = Field(default=None, ge=0, le=65535)
    sync0_shift_us: float = Field(default=0.0, ge=0, le=1_000_000)


class RealtimeConfig(_Model):
    policy: Literal["fifo", "deadline", "other"] = "fifo"
    priority: int = Field(default=80, ge=1, le=99)
    cpu: int | None = Field(default=None, ge=0, le=1023)
    deadline_runtime_us: int = Field(default=100, ge=1, le=1_000_000)
    lock_memory: bool = True


class BusSection(_Model):
    name: Identifier = "ethercat"
    interface: InterfaceName | None = None
    cycle_us: int = Field(default=1000, ge=20, le=1_000_000)
    cycle_order: Literal["send_at_wake", "send_then_wait"] = "send_at_wake"
    watchdog_ms: int = Field(default=100, ge=0, le=60_000)
    # How frames reach the interface (docs/engine.md, "Links"): AF_PACKET, AF_XDP, or AF_XDP
    # with a fallback to AF_PACKET.
    link: LinkName = "packet"
    # SO_BUSY_POLL time of the link's socket in µs (0: off): the kernel spins for a reply
    # before the RT thread sleeps.
    busy_poll_us: int = Field(default=0, ge=0, le=1_000_000)
    # AF_PACKET frames through the kernel's transmit queue instead of straight to the driver, so
    # a capture on the master's interface (tcpdump, tshark) sees them; costs a little per frame
    # (docs/benchmarks.md, "capture").
    capture: bool = False
    dc: DcConfig = Field(default_factory=DcConfig)
    realtime: RealtimeConfig = Field(default_factory=RealtimeConfig)

    @model_validator(mode="after")
    def _shift_inside_cycle(self) -> BusSection:
        if self.dc.sync0_shift_us >= self.cycle_us:
            raise ValueError(
                f"dc.sync0_shift_us ({self.dc.sync0_shift_us}) must be less than cycle_us"
                f" ({self.cycle_us})"
            )
        if (
            self.realtime.policy == "deadline"
            and self.realtime.deadline_runtime_us >= self.cycle_us
        ):
            raise ValueError(
                f"realtime.deadline_runtime_us ({self.realtime.deadline_runtime_us}) must be"
                f" less than cycle_us ({self.cycle_us})"
            )
        return self


#: Longest ROS period (snapshot_period_ms) and largest decimation: a period in ns must fit the
#: int64 rcl keeps it in, and a publisher that speaks less than once an hour is a mistake.
MAX_ROS_PERIOD_MS = 3_600_000
MAX_DECIMATION = 1_000_000


class LeaseConfig(_Model):
    """The control lease (docs/security.md): off by default, on in the shipped robot configs."""

    enabled: bool = False
    # Time to live a client gets when it asks for none (s), and the most it may ask for.
    ttl_s: float = Field(default=3.0, ge=0.1, le=600.0)
    max_ttl_s: float = Field(default=30.0, ge=0.1, le=3600.0)

    @model_validator(mode="after")
    def _default_within_max(self) -> LeaseConfig:
        if self.ttl_s > self.max_ttl_s:
            raise ValueError(f"ttl_s ({self.ttl_s}) must not exceed max_ttl_s ({self.max_ttl_s})")
        return self


class RosConfig(_Model):
    node_name: Identifier = "ether_comm"
    namespace: RosNamespace = ""
    raw_decimation: int = Field(default=1, ge=1, le=MAX_DECIMATION)
    decoded_decimation: int = Field(default=10, ge=1, le=MAX_DECIMATION)
    snapshot_period_ms: int = Field(default=100, ge=0, le=MAX_ROS_PERIOD_MS)
    # SCHED_FIFO priority of the native thread that serves pdo_listener (0: normal scheduling);
    # capped below rt.priority so commands never delay a cycle.
    command_priority: int = Field(default=50, ge=0, le=98)
    lease: LeaseConfig = Field(default_factory=LeaseConfig)
    # The FollowJointTrajectory action server of the CiA 402 axes, relative to the namespace
    # (MoveIt's simple controller manager: <controller name>/<action_ns>); empty: none.
    trajectory_action: str = Field(
        default="follow_joint_trajectory",
        pattern=r"^([A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*)?$",
    )
    # A goal's goal_time_tolerance of 0 takes this (s): how long after the trajectory's end the
    # joints may take to get within their goal tolerances.
    goal_time_tolerance_s: float = Field(default=1.0, ge=0.0, le=600.0)
    # Tolerances a goal leaves at 0 take these (SI; 0: not checked).
    path_tolerance: float = Field(default=0.0, ge=0.0)
    goal_tolerance: float = Field(default=0.0, ge=0.0)


class PdoAssign(_Model):
    # A SyncManager's assignment object (0x1C1n) has at most 254 entries.
    rx: list[PdoIndex] | None = Field(default=None, max_length=254)
    tx: list[PdoIndex] | None = Field(default=None, max_length=254)


class SdoInit(_Model):
    index: ObjectIndex = Field(ge=0x0001, le=0xFFFF)
    subindex: Subindex = Field(default=0, ge=0, le=255)
    value: int | float | bool | PathText
    type: Text | None = None  # uint8, int16, ... (default: the dictionary's type)
    _data: bytes = PrivateAttr(default=b"")

    @property
    def data(self) -> bytes:
        """The value encoded as it goes into the SDO download (little endian)."""
        return self._data


class Joint(_Model):
    """One joint of ROS ``joint_states``: SI value = raw * scale + offset."""

    name: Identifier
    position: Text
    position_scale: Scale = 1.0
    position_offset: float = 0.0
    velocity: Text | None = None
    velocity_scale: Scale = 1.0
    effort: Text | None = None
    effort_scale: Scale = 1.0


class AxisExtra(_Model):
    """One more object of a CiA 402 axis as a joint interface (docs/cia402.md, "Drive extras"):
    read from the process image and, when it is an output, commanded. ``object`` is an
    address (``0x60FD``, ``0x60FE:01``); a standard object of the profile area (0x6000-0x67FF)
    is taken at the axis's own index (+ n x 0x800), any other (a vendor object) as given.
    SI value = raw x ``scale``: ``position`` (and the position offset), ``velocity``,
    ``torque`` take the axis's scales, a number is its own."""

    name: Identifier
    object: int | str
    scale: Literal["position", "velocity", "torque"] | float = 1.0


class HomingConfig(_Model):
    """Homing of a CiA 402 axis (mode hm), written to the drive in PREOP: the method (0x6098),
    the search speeds for the switch and for the zero/index (0x6099:1/:2, SI/s), the
    acceleration (0x609A, SI/s²) and the position the home gets (0x607C, SI)."""

    method: int = Field(ge=-128, le=127)
    speed_switch: float | None = Field(default=None, gt=0)
    speed_zero: float | None = Field(default=None, gt=0)
    acceleration: float | None = Field(default=None, gt=0)
    offset: float = 0.0


class AxisConfig(_Model):
    """One axis (joint) of a CiA 402 drive: position = raw × position_scale + position_offset
    (rad or m), velocity = raw × velocity_scale, torque = raw × torque_scale."""

    # Limits may be infinite (no limit); the numbers are checked together in
    # cia402.check_axis (positive finite scales, min <= max, no NaN).
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=True)

    name: Identifier
    mode: Literal["csp", "csv", "cst", "pp", "pv", "hm"] = "csp"
    position_scale: float = 1.0
    position_offset: float = 0.0
    velocity_scale: float = 1.0
    torque_scale: float = 1.0
    # [min, max] in SI; velocity_limit and torque_limit are |max| in SI.
    position_limits: Annotated[tuple[float, float], BeforeValidator(_pair)] = (
        -math.inf,
        math.inf,
    )
    velocity_limit: float = math.inf
    torque_limit: float = math.inf
    following_error_window: float = 0.0
    # SI/s²: the quiet stop a mode change or an enable starts with, and the braking before the
    # position limits in csv/pv/cst (inf: at once, cut at the limit itself).
    deceleration: float = math.inf
    # SI/s²: the largest change of the commanded velocity; every hand-over (a new trajectory,
    # setpoints after one, a jump) is joined from the commanded state within it (csp, csv).
    # None: the URDF's <limit acceleration=…>, else `deceleration` (inf: velocity limit only).
    max_acceleration: float | None = None
    # The velocity a mode change's quiet stop starts from: the actual one, or zero.
    mode_change_velocity: Literal["actual", "zero"] = "actual"
    # manual: after a panic, watchdog stop or fault the axis waits for an explicit enable;
    # auto: it goes back to Operation Enabled by itself (never outside its position limits).
    restart: Literal["manual", "auto"] = "manual"
    # pp/pv: the drive's profile (0x6081 velocity, 0x6083 acceleration, 0x6084 deceleration) in
    # SI, written in PREOP when given (else the drive keeps its own).
    profile_velocity: float | None = None
    profile_acceleration: float | None = None
    profile_deceleration: float | None = None
    # More of the drive's objects as joint interfaces (0x60FD inputs, 0x60FE outputs, touch
    # probe, offsets, vendor objects) and the homing set-up.
    extras: list[AxisExtra] = Field(default_factory=list)
    homing: HomingConfig | None = None
    on_stop: Literal["quick_stop", "disable"] = "quick_stop"
    fault_reset: Literal["auto", "manual"] = "auto"
    fault_retries: int = Field(default=3, ge=0, le=100)
    fault_backoff_ms: float = Field(default=100.0, ge=0.0, le=60_000.0)


class SimFoeFile(_Model):
    """A file of a simulated slave's FoE store: its contents as ``text`` (UTF-8), as ``hex``
    or from the file at ``path`` (relative to the bus config), exactly one of them."""

    name: Text
    text: str | None = Field(default=None, max_length=1 << 20)
    hex: str | None = Field(default=None, max_length=2 << 20)
    path: PathText | None = None

    @model_validator(mode="after")
    def _one_source(self) -> SimFoeFile:
        given = [k for k in ("text", "hex", "path") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of text, hex or path (got {given or 'none'})")
        if self.hex is not None:
            try:
                bytes.fromhex(self.hex)
            except ValueError:
                raise ValueError("hex: not hexadecimal bytes") from None
        return self


class SimFoeConfig(_Model):
    """The FoE server's store of a simulated slave whose ESI announces FoE (docs/simulator.md,
    section FoE). Left out: the simulator's defaults (ether_ros_sim::foe::FoeSpec)."""

    capacity: int | None = Field(default=None, ge=0, le=64 << 20)
    password: HexInt | None = Field(default=None, ge=0, le=0xFFFFFFFF)
    firmware: Text | None = None
    busy: int | None = Field(default=None, ge=0, le=1000)
    files: list[SimFoeFile] = Field(default_factory=list, max_length=1024)


class SimConfig(_Model):
    device: Literal["laelaps_leg", "generic_io", "cia402", "loopback", "none"] | None = None
    # The slave controller chip whose registers the virtual slave presents (docs/simulator.md).
    esc: Literal["et1100", "et1200", "lan9252"] = "et1100"
    params: dict[Text, float] = Field(default_factory=dict)
    drift_ppm: float = Field(default=0.0, ge=-1000.0, le=1000.0)
    # One-way delay of the link into port 0 (ns); default from the device's physics: an E-bus
    # hop 150 ns, a 100BASE-TX hop 700 ns (ether_ros.sim.spec.default_delay_ns).
    delay_ns: int | None = Field(default=None, ge=0, le=1_000_000)
    serial: HexInt | None = Field(default=None, ge=0, le=0xFFFFFFFF)
    # False: the virtual ESC reports "LRW not supported" (0x0008 bit 9) and ignores LRW.
    lrw: bool = True
    # The FoE file store of a device that announces FoE (ether_ros.sim.spec.foe_spec).
    foe: SimFoeConfig | None = None


class GroupConfig(_Model):
    """Slaves exchanged at their own cycle, in frames of their own (docs/configuration.md)."""

    name: Identifier
    # An integer multiple of bus.cycle_us.
    cycle_us: int = Field(ge=20, le=1_000_000)
    slaves: list[Identifier] = Field(default_factory=list)
    # False: every slave of the group gets LRD + LWR instead of LRW.
    lrw: bool = True
    # The group's own command watchdog: no write to its slaves' outputs for this long puts its
    # safe outputs on the wire (0: none; the bus watchdog still covers every slave).
    watchdog_ms: int = Field(default=0, ge=0, le=60_000)


class ConnectedTo(_Model):
    """Where a slave's port 0 is cabled: port ``port`` of the slave named ``slave``."""

    slave: Identifier
    port: int = Field(ge=1, le=3)


class SlaveConfig(_Model):
    name: Identifier
    position: int | None = Field(default=None, ge=0, le=65534)
    alias: HexInt | None = Field(default=None, ge=1, le=65535)
    vendor_id: HexInt | None = Field(default=None, ge=0, le=0xFFFFFFFF)
    product_code: HexInt | None = Field(default=None, ge=0, le=0xFFFFFFFF)
    revision: HexInt | None = Field(default=None, ge=0, le=0xFFFFFFFF)
    device: Text | None = None
    pdo_assign: PdoAssign | None = None
    # ETG.2001 modular devices: the module in each slot (its type name or ModuleIdent; null
    # leaves the slot empty). Default: the ESI's default module of each slot.
    modules: list[str | HexInt | None] | None = Field(default=None, max_length=256)
    sdo_init: list[SdoInit] = Field(default_factory=list)
    safe_outputs: dict[Text, int | float | bool] = Field(default_factory=dict)
    joints: list[Joint] = Field(default_factory=list)
    # False: LRD + LWR instead of LRW (also chosen when the ESC reports LRW unsupported).
    lrw: bool = True
    # CiA 402 drives (docs/cia402.md): the profile (also taken from the ESI's ProfileNo 402
    # when axes are given) and one entry per axis.
    profile: Literal["cia402"] | None = None
    axes: list[AxisConfig] = Field(default_factory=list, max_length=cia402.MAX_AXES)
    sim: SimConfig = Field(default_factory=SimConfig)
    # Default: port 1 of the slave before it (a line); the first slave is on the master.
    connected_to: ConnectedTo | None = None
    _esi: EsiDevice | None = PrivateAttr(default=None)
    _layout: ProcessLayout | None = PrivateAttr(default=None)
    _safe_image: bytes = PrivateAttr(default=b"")
    _axis_specs: list[cia402.AxisSpec] = PrivateAttr(default_factory=list)

    @model_validator(mode="after")
    def _identified(self) -> SlaveConfig:
        if self.position is not None and self.alias is not None:
            raise ValueError("give either position or alias, not both")
        if self.device is None and (self.vendor_id is None or self.product_code is None):
            raise ValueError("give device, or vendor_id and product_code")
        return self

    @property
    def esi(self) -> EsiDevice:
        """The ESI device this slave was matched to."""
        assert self._esi is not None, "only configs from load_bus_config are resolved"
        return self._esi

    @property
    def resolved_esi(self) -> EsiDevice | None:
        """The ESI device ``load_bus_config`` matched this slave to (None: not resolved)."""
        return self._esi

    @property
    def layout(self) -> ProcessLayout:
        """Process variables for this slave's PDO assignment."""
        assert self._layout is not None, "only configs from load_bus_config are resolved"
        return self._layout

    @property
    def safe_output_image(self) -> bytes:
        """The slave's output area with ``safe_outputs`` applied (other variables 0)."""
        return self._safe_image

    @property
    def axis_specs(self) -> list[cia402.AxisSpec]:
        """The slave's CiA 402 axes, resolved against its PDO layout."""
        return list(self._axis_specs)

    @property
    def sim_device(self) -> str:
        """The simulator device model: ``sim.device`` or the default for the ESI type."""
        if self.sim.device is not None:
            return self.sim.device
        return default_sim_device(self.esi)


class BusConfig(_Model):
    bus: BusSection = Field(default_factory=BusSection)
    esi: Annotated[list[PathText], BeforeValidator(lambda v: [v] if isinstance(v, str) else v)] = (
        Field(default_factory=list)
    )
    ros: RosConfig = Field(default_factory=RosConfig)
    # The robot's URDF (relative to this file): limits for the axes named like its joints, where
    # an axis does not set them itself (config/urdf.py, docs/cia402.md).
    urdf: PathText | None = None
    # Positions 0..65534: the auto-increment address space.
    slaves: list[SlaveConfig] = Field(min_length=1, max_length=65535)
    groups: list[GroupConfig] = Field(default_factory=list)
    _source: Path | None = PrivateAttr(default=None)
    _devices: list[EsiDevice] = PrivateAttr(default_factory=list)

    @property
    def source(self) -> Path | None:
        """The YAML file this configuration was loaded from."""
        return self._source

    @property
    def esi_devices(self) -> list[EsiDevice]:
        return list(self._devices)

    def slave(self, name: str) -> SlaveConfig:
        for s in self.slaves:
            if s.name == name:
                return s
        known = ", ".join(s.name for s in self.slaves)
        raise ConfigError(f"no slave named {name!r} (slaves: {known})")

    @property
    def declares_topology(self) -> bool:
        """True when some slave says where it is connected (``connected_to``)."""
        return any(s.connected_to is not None for s in self.slaves)

    def by_position(self) -> list[SlaveConfig]:
        """The slaves sorted by position (every slave has one unless addressed by alias)."""
        return sorted(self.slaves, key=lambda s: s.position if s.position is not None else 0)

    def tree(self) -> list[Link]:
        """The expected tree by position: ``connected_to``, or port 1 of the slave before."""
        ordered = self.by_position()
        index = {s.name: k for k, s in enumerate(ordered)}
        return [
            Link(None, 0)
            if k == 0
            else Link(index[s.connected_to.slave], s.connected_to.port)
            if s.connected_to is not None
            else Link(k - 1, 1)
            for k, s in enumerate(ordered)
        ]

    def group_cycles(self) -> list[tuple[str, int]]:
        """(group name, cycle in base cycles) of every group, the default group first."""
        return [(DEFAULT_GROUP, 1)] + [
            (g.name, g.cycle_us // self.bus.cycle_us) for g in self.groups
        ]

    def group_of(self, slave: str) -> GroupConfig | None:
        """The group ``slave`` belongs to; None for the default group."""
        return next((g for g in self.groups if slave in g.slaves), None)

    def axis_specs(self) -> list[cia402.AxisSpec]:
        """Every CiA 402 axis of the bus, in bus order."""
        return [a for s in self.slaves for a in s.axis_specs]

    def joint_specs(self) -> list[JointSpec]:
        """Every slave's ``joints``, in bus order, each with the slave it reads from."""
        return [
            JointSpec(
                name=j.name,
                slave=s.name,
                position=j.position,
                position_scale=float(j.position_scale),
                position_offset=float(j.position_offset),
                velocity=j.velocity,
                velocity_scale=float(j.velocity_scale),
                effort=j.effort,
                effort_scale=float(j.effort_scale),
            )
            for s in self.slaves
            for j in s.joints
        ]


@dataclass(frozen=True)
class JointSpec:
    """One ROS joint read from a slave's inputs (``joint_states`` on the node and in
    recordings): position = raw × scale + offset, velocity and effort = raw × scale, in SI."""

    name: str
    slave: str
    position: str
    position_scale: float = 1.0
    position_offset: float = 0.0
    velocity: str | None = None
    velocity_scale: float = 1.0
    effort: str | None = None
    effort_scale: float = 1.0


# --------------------------------------------------------------------------------------------
# Loader


def load_bus_config(
    path: str | Path, interface: str | None = None, link: str | None = None
) -> BusConfig:
    """Load and fully validate a bus configuration; ``interface`` overrides ``bus.interface``
    and ``link`` overrides ``bus.link``."""
    file = Path(path)
    data, smap = load_yaml(file)
    if not isinstance(data, dict):
        raise ConfigError(f"{file}: a bus configuration is a mapping with 'bus' and 'slaves'")
    try:
        cfg = BusConfig.model_validate(data)
    except ValidationError as exc:
        raise _schema_error(exc, data, smap) from None
    if interface is not None:
        try:
            cfg.bus.interface = interface_name(interface)
        except ValueError as exc:
            raise ConfigError(
                f"--interface: {exc} (got {shown(interface)})", field="interface"
            ) from None
    if link is not None:
        if link not in ("packet", "xdp", "auto"):
            raise ConfigError(f"link must be packet, xdp or auto, got {shown(link)}", field="link")
        cfg.bus.link = cast(LinkName, link)
    cfg._source = file.resolve()
    _resolve(cfg, file, smap)
    return cfg


_NODE_NAME: TypeAdapter[str] = TypeAdapter(Identifier)


def check_node_name(name: str) -> str:
    """A node name given outside the file (``--node-name``), checked as ``ros.node_name``."""
    try:
        return _NODE_NAME.validate_python(name, strict=True)
    except ValidationError as exc:
        msg = exc.errors()[0]["msg"]
        raise ConfigError(f"node name: {msg} (got {shown(name)})", field="ros.node_name") from None


# pydantic's words for a wrong type, said the way a configuration's reader needs them.
_TYPE_MESSAGES = {
    "int_type": "an integer is expected here",
    "float_type": "a number is expected here",
    "bool_type": "true or false is expected here",
    "string_type": "text is expected here",
    "finite_number": "must be a finite number (not nan or inf)",
}


def _schema_error(exc: ValidationError, data: Any, smap: SourceMap) -> ConfigError:
    errors = exc.errors()
    first = errors[0]
    path: list[str | int] = []
    node: Any = data
    loc = list(first["loc"])
    for i, part in enumerate(loc):
        in_dict = isinstance(node, dict) and part in node
        in_list = isinstance(node, list) and isinstance(part, int) and part < len(node)
        if in_dict or in_list:
            path.append(part)
            node = node[part]
        elif i == len(loc) - 1 and first["type"] in ("missing", "extra_forbidden"):
            path.append(part)
        # else: a union member tag such as 'int' or 'function-after[...]': not a key
    msg = first["msg"]
    if first["type"] == "extra_forbidden":
        msg = "unknown key"
    elif msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    elif first["type"] in _TYPE_MESSAGES:
        msg = _TYPE_MESSAGES[first["type"]]
        if isinstance(first.get("input"), bool) and first["type"] != "bool_type":
            msg += ", not true/false"
    show = first["type"] != "missing"
    err = smap.error(tuple(path), msg, first.get("input"), show_value=show)
    if len(errors) > 1:
        return ConfigError(
            f"{err} [and {len(errors) - 1} more error(s)]",
            file=err.file,
            line=err.line,
            field=err.field,
            value=err.value,
        )
    return err


def _apply_urdf(cfg: BusConfig, base: Path, smap: SourceMap) -> None:
    """Fill the axes' limits from ``urdf:`` before the axes are checked and resolved."""
    item = cfg.urdf
    assert item is not None
    try:
        p = (base / item).resolve() if not Path(item).is_absolute() else Path(item)
        found = p.exists()
    except (OSError, RuntimeError) as exc:  # a name too long, a symlink loop
        raise smap.error(("urdf",), f"not a usable path: {exc}", item) from None
    if not found:
        raise smap.error(("urdf",), f"URDF file not found ({p})", item)
    joints = load_urdf_joints(p)
    axes = [a for s in cfg.slaves for a in s.axes]
    if apply_urdf_limits(p, joints, axes) == 0:
        movable = ", ".join(sorted(n for n, j in joints.items() if j.type in MOVABLE_TYPES))
        names = ", ".join(a.name for a in axes)
        raise smap.error(
            ("urdf",),
            f"no axis is named like a movable joint of {p} (its joints: {movable or 'none'};"
            f" the axes: {names or 'none'})",
            item,
        )


def _resolve(cfg: BusConfig, file: Path, smap: SourceMap) -> None:
    base = file.parent
    devices: list[EsiDevice] = []
    for i, item in enumerate(cfg.esi):
        try:
            p = (base / item).resolve() if not Path(item).is_absolute() else Path(item)
            is_dir, is_file = p.is_dir(), p.is_file()
        except (OSError, RuntimeError) as exc:  # a name too long, a symlink loop
            raise smap.error(("esi", i), f"not a usable path: {exc}", item) from None
        if is_dir:
            files = esi_files(p)
            if not files:
                raise smap.error(("esi", i), "directory holds no *.xml ESI files", item)
        elif is_file:
            files = [p]
        else:
            raise smap.error(("esi", i), f"ESI file or directory not found ({p})", item)
        for f in files:
            devices.extend(load_esi(f))
    cfg._devices = devices
    if cfg.urdf is not None:
        _apply_urdf(cfg, base, smap)

    def err(path: KeyPath, msg: str, value: Any = None, show: bool = True) -> ConfigError:
        return smap.error(path, msg, value, show_value=show)

    names: dict[str, int] = {}
    positions: dict[int, int] = {}
    aliases: dict[int, int] = {}
    joints: dict[str, str] = {}
    for i, s in enumerate(cfg.slaves):
        at = ("slaves", i)
        if s.name in names:
            raise err((*at, "name"), f"duplicate slave name (also slaves[{names[s.name]}])", s.name)
        names[s.name] = i
        if s.position is not None:
            if s.position in positions:
                raise err(
                    (*at, "position"),
                    f"duplicate position (also slaves[{positions[s.position]}])",
                    s.position,
                )
            positions[s.position] = i
        if s.alias is not None:
            if s.alias in aliases:
                raise err(
                    (*at, "alias"), f"duplicate alias (also slaves[{aliases[s.alias]}])", s.alias
                )
            aliases[s.alias] = i
        dev = _match_device(s, devices, at, err)
        s._esi = dev
        if s.vendor_id is None:
            s.vendor_id = dev.vendor_id
        if s.product_code is None:
            s.product_code = dev.product_code
        _resolve_slave(s, dev, at, err, joints)
    if all(s.position is None and s.alias is None for s in cfg.slaves):
        for i, s in enumerate(cfg.slaves):
            s.position = i
    elif any(s.position is None and s.alias is None for s in cfg.slaves):
        i = next(i for i, s in enumerate(cfg.slaves) if s.position is None and s.alias is None)
        raise err(("slaves", i), "give position (or alias) for every slave, or for none", None,
                  show=False)  # fmt: skip
    if cfg.declares_topology:
        _check_topology(cfg, err)
    _check_groups(cfg, err)
    ref = cfg.bus.dc.reference
    if ref is not None and cfg.bus.dc.enabled:
        slave = next((s for s in cfg.slaves if s.position == ref), None)
        if slave is None:
            raise err(("bus", "dc", "reference"), "no slave at this position", ref)
        if not slave.esi.dc_supported:
            raise err(
                ("bus", "dc", "reference"),
                f"slave {slave.name} ({slave.esi.type_name}) has no distributed clock",
                ref,
            )
    for i, s in enumerate(cfg.slaves):
        if s.esi.dc_required and not cfg.bus.dc.enabled:
            raise err(
                ("bus", "dc", "enabled"),
                f"slave {s.name} ({s.esi.type_name}) requires distributed clocks (slaves[{i}])",
                False,
            )


def _check_topology(cfg: BusConfig, err: Any) -> None:
    """``connected_to``: every slave placed, on an earlier slave's free port, and positions in
    the order a frame visits them (depth first, ports 0 → 3 → 1 → 2)."""
    where = {s.name: i for i, s in enumerate(cfg.slaves)}
    for i, s in enumerate(cfg.slaves):
        if s.position is None:
            raise err(("slaves", i), "connected_to needs every slave to have a position", None,
                      show=False)  # fmt: skip
    positions = sorted(s.position or 0 for s in cfg.slaves)
    if positions != list(range(len(positions))):
        raise err(("slaves",), f"connected_to needs positions 0..{len(positions) - 1} without"
                  f" gaps, got {positions}", None, show=False)  # fmt: skip
    taken: dict[tuple[str, int], str] = {}
    for i, s in enumerate(cfg.slaves):
        link = s.connected_to
        if link is None:
            continue
        at = ("slaves", i, "connected_to")
        if link.slave not in where:
            raise err((*at, "slave"), "no slave by this name", link.slave)
        parent = cfg.slaves[where[link.slave]]
        if (parent.position or 0) >= (s.position or 0):
            raise err((*at, "slave"), f"'{link.slave}' is at position {parent.position}, not"
                      f" before this slave (position {s.position}): a frame reaches a slave"
                      " after the one it hangs on", link.slave)  # fmt: skip
        if (link.slave, link.port) in taken:
            raise err((*at, "port"), f"port {link.port} of '{link.slave}' is taken by"
                      f" '{taken[(link.slave, link.port)]}'", link.port)  # fmt: skip
        taken[(link.slave, link.port)] = s.name
    names = [s.name for s in cfg.by_position()]
    order = visit_order(cfg.tree())
    for pos, visited in enumerate(order):
        if visited != pos:
            i = where[names[pos]]
            raise err(("slaves", i, "position"), f"the frame reaches '{names[visited]}' (position"
                      f" {visited}) before '{names[pos]}': ports are visited 0, 3, 1, 2, depth"
                      " first, and positions follow that order", pos)  # fmt: skip


def _check_groups(cfg: BusConfig, err: Any) -> None:
    """Groups name known slaves, each slave at most once, and run at a whole multiple of the
    bus cycle."""
    known = {s.name for s in cfg.slaves}
    member: dict[str, str] = {}
    names: set[str] = set()
    for i, g in enumerate(cfg.groups):
        at = ("groups", i)
        if g.name == DEFAULT_GROUP or g.name in names:
            why = (
                "is the group of slaves in no group" if g.name == DEFAULT_GROUP else "is used twice"
            )
            raise err((*at, "name"), f"group name {g.name!r} {why}", g.name)
        names.add(g.name)
        if g.cycle_us % cfg.bus.cycle_us:
            raise err(
                (*at, "cycle_us"),
                f"group {g.name}: cycle_us must be a whole multiple of bus.cycle_us "
                f"({cfg.bus.cycle_us})",
                g.cycle_us,
            )
        if not g.slaves:
            raise err((*at, "slaves"), f"group {g.name} has no slaves", g.slaves)
        for k, name in enumerate(g.slaves):
            if name not in known:
                raise err((*at, "slaves", k), f"group {g.name}: no slave named {name!r}", name)
            if name in member:
                raise err(
                    (*at, "slaves", k),
                    f"slave {name} is in two groups ({member[name]} and {g.name})",
                    name,
                )
            member[name] = g.name


def _match_device(s: SlaveConfig, devices: list[EsiDevice], at: KeyPath, err: Any) -> EsiDevice:
    if not devices:
        raise err(("esi",), "no ESI devices loaded; list ESI files or directories under 'esi'", [])
    if s.device is not None:
        cands = [d for d in devices if d.type_name == s.device]
        if not cands:
            known = ", ".join(sorted({d.type_name for d in devices}))
            raise err((*at, "device"), f"no such ESI device (known: {known})", s.device)
        identity: tuple[tuple[str, int | None, Callable[[EsiDevice], int]], ...] = (
            ("vendor_id", s.vendor_id, lambda d: d.vendor_id),
            ("product_code", s.product_code, lambda d: d.product_code),
        )
        for key, have, of in identity:
            if have is not None and all(of(d) != have for d in cands):
                actual = of(cands[0])
                raise err(
                    (*at, key),
                    f"does not match ESI device {s.device} ({key} {actual:#010x})",
                    f"{have:#010x}",
                )
            if have is not None:
                # Vendors give several products one type name (Elmo's "Elmo Drive").
                cands = [d for d in cands if of(d) == have]
    else:
        cands = [
            d for d in devices if d.vendor_id == s.vendor_id and d.product_code == s.product_code
        ]
        if not cands:
            raise err(
                (*at, "product_code"),
                f"no ESI device with vendor {s.vendor_id:#010x} and this product code",
                f"{s.product_code:#010x}",
            )
    cands = [d for d in cands if not d.passive] or cands
    if all(d.passive for d in cands):
        raise err((*at, "device" if s.device is not None else "product_code"),
                  f"{cands[0].type_name} is a passive terminal: it has no EtherCAT slave "
                  "controller and is not on the bus; leave it out of slaves",
                  cands[0].type_name)  # fmt: skip
    if s.revision is not None:
        exact = [d for d in cands if d.revision == s.revision]
        if not exact:
            revs = ", ".join(f"{d.revision:#010x}" for d in cands)
            raise err((*at, "revision"), f"no ESI device with this revision (have: {revs})",
                      f"{s.revision:#010x}")  # fmt: skip
        cands = exact
    return max(cands, key=lambda d: d.revision)


def _place_modules(s: SlaveConfig, dev: EsiDevice, at: KeyPath, err: Any) -> EsiDevice:
    """``dev`` with the configured modules (or the ESI's defaults) in its slots."""
    if not dev.slots:
        if s.modules:
            raise err((*at, "modules"), f"{dev.type_name} has no slots (no ETG.2001 <Slots> in "
                      "its ESI)", s.modules)  # fmt: skip
        return dev
    if s.modules is None:
        return place_modules(dev, default_modules(dev))
    if len(s.modules) > len(dev.slots):
        raise err((*at, "modules"), f"{dev.type_name} has {len(dev.slots)} slots",
                  s.modules)  # fmt: skip
    by_name = {m.type_name: m.ident for m in dev.modules}
    idents: list[int | None] = []
    for k, item in enumerate(s.modules):
        slot = dev.slots[k]
        ident = by_name.get(item) if isinstance(item, str) else item
        if item is not None and (ident is None or ident not in slot.module_idents):
            names = [m.type_name for m in dev.modules if m.ident in slot.module_idents]
            raise err((*at, "modules", k), f"slot {k + 1} ({slot.name or 'unnamed'}) of "
                      f"{dev.type_name} takes: {', '.join(names) or 'nothing'}",
                      item)  # fmt: skip
        if item is None and slot.min_instances > 0:
            raise err((*at, "modules", k), f"slot {k + 1} ({slot.name or 'unnamed'}) must hold "
                      "a module", item)  # fmt: skip
        idents.append(ident)
    idents += [None] * (len(dev.slots) - len(idents))
    return place_modules(dev, idents)


def _resolve_slave(
    s: SlaveConfig, dev: EsiDevice, at: KeyPath, err: Any, joints: dict[str, str]
) -> None:
    dev = s._esi = _place_modules(s, dev, at, err)
    rx = s.pdo_assign.rx if s.pdo_assign is not None else None
    tx = s.pdo_assign.tx if s.pdo_assign is not None else None
    is_drive = s.profile == "cia402" or (
        bool(s.axes) and cia402.PROFILE_NUMBER in dev.profile_numbers
    )
    if s.axes and not is_drive:
        raise err((*at, "axes"), f"axes need a CiA 402 drive: {dev.type_name} has no ProfileNo "
                  "402 in its ESI; give profile: cia402 if it is one", None, False)  # fmt: skip
    if is_drive and not s.axes:
        raise err((*at, "profile"), "a cia402 slave needs axes: (one entry per axis)", s.profile)
    if is_drive:
        s.profile = "cia402"
        auto_rx, auto_tx = cia402.auto_assign(dev, len(s.axes))
        if rx is None and tuple(auto_rx) != dev.default_rx_pdos():
            rx = auto_rx
        if tx is None and tuple(auto_tx) != dev.default_tx_pdos():
            tx = auto_tx
        mapped = cia402.extend_mapping(
            dev,
            rx if rx is not None else dev.default_rx_pdos(),
            tx if tx is not None else dev.default_tx_pdos(),
            s.axes,
        )
        if mapped is not dev:
            # The PDO contents change: the master writes assignment and mapping in PREOP.
            dev = s._esi = mapped
            rx = list(rx if rx is not None else dev.default_rx_pdos())
            tx = list(tx if tx is not None else dev.default_tx_pdos())
        if rx is not None or tx is not None:
            s.pdo_assign = PdoAssign(rx=rx, tx=tx)
    for kind, chosen, pdos in (("rx", rx, dev.rx_pdos), ("tx", tx, dev.tx_pdos)):
        if chosen is None:
            continue
        have = {p.index for p in pdos}
        for j, index in enumerate(chosen):
            if index not in have:
                listed = ", ".join(f"{x:#06x}" for x in sorted(have)) or "none"
                raise err((*at, "pdo_assign", kind, j),
                          f"{dev.type_name} has no {kind.upper()}PDO with this index"
                          f" (it has: {listed})", f"{index:#06x}")  # fmt: skip
        if len(set(chosen)) != len(chosen):
            raise err((*at, "pdo_assign", kind), "PDO assigned twice", chosen)
        for p in pdos:
            if p.index in chosen:
                clash = sorted(set(p.excludes) & set(chosen))
                if clash:
                    raise err((*at, "pdo_assign", kind),
                              f"PDO {p.index:#06x} excludes {', '.join(f'{x:#06x}' for x in clash)}"
                              " (ESI <Exclude>): assign one of them",
                              [f"{x:#06x}" for x in chosen])  # fmt: skip
            if p.mandatory and p.index not in chosen and p.sm is not None:
                raise err((*at, "pdo_assign", kind), f"PDO {p.index:#06x} is mandatory",
                          [f"{x:#06x}" for x in chosen])  # fmt: skip
    try:
        layout = ProcessLayout.for_device(dev, rx, tx)
    except ConfigError as exc:
        raise err((*at, "pdo_assign"), str(exc), None, False) from None
    s._layout = layout

    for j, axis in enumerate(s.axes):
        if axis.name in joints:
            raise err((*at, "axes", j, "name"), f"duplicate joint name (also in slave "
                      f"{joints[axis.name]})", axis.name)  # fmt: skip
        joints[axis.name] = s.name
    s._axis_specs = cia402.resolve_axes(dev, layout, s.name, s.axes, at, err)
    # What the drives get once, in PREOP (an entry of the configuration's own wins): the mode
    # of an axis whose 0x6060 is not in the PDOs, the software position limits (0x607D).
    given = {(i.index, i.subindex) for i in s.sdo_init}
    for index, subindex, raw, type_name in cia402.axis_sdo_inits(s._axis_specs, dev):
        if (index, subindex) not in given:
            s.sdo_init.append(SdoInit(index=index, subindex=subindex, value=raw, type=type_name))

    safe = bytearray(layout.output_bytes)
    for var_name, value in s.safe_outputs.items():
        path = (*at, "safe_outputs", var_name)
        try:
            var = layout.variable(var_name, "output")
        except ProcessValueError as exc:
            names = ", ".join(v.name for v in layout.outputs)
            raise err(path, f"{exc}; output variables of {dev.type_name}: {names}", var_name,
                      False) from None  # fmt: skip
        if var.direction != "output":
            raise err(path, "is an input variable; safe_outputs take output variables", var_name)
        try:
            layout.write(safe, var, value)
        except ProcessValueError as exc:
            raise err(path, str(exc), value) from None
    s._safe_image = bytes(safe)

    for j, init in enumerate(s.sdo_init):
        path = (*at, "sdo_init", j)
        entry = dev.od_entry(init.index, init.subindex)
        if init.type is not None:
            t = dt.config_type(init.type)
            if t is None:
                known = ", ".join(x.name for x in dt.ALL_TYPES)
                raise err((*path, "type"), f"unknown data type (known: {known})", init.type)
            bits = t.bit_length or (entry.bit_length if entry is not None else 0)
        elif entry is not None:
            t = dt.BY_CODE.get(entry.data_type) or dt.OCTET_STRING
            bits = entry.bit_length
        else:
            address = format_address(init.index, init.subindex)
            raise err((*path, "index"),
                      f"object {address} is not in the {dev.type_name} dictionary; give its type",
                      f"{init.index:#06x}")  # fmt: skip
        if entry is not None and entry.access == "ro":
            address = format_address(init.index, init.subindex)
            raise err((*path, "index"), f"object {address} ({entry.name}) is read-only",
                      f"{init.index:#06x}")  # fmt: skip
        if dev.objects and entry is None and dev.od_object(init.index) is None:
            raise err((*path, "index"), f"no object {init.index:#06x} in the {dev.type_name}"
                      " dictionary", f"{init.index:#06x}")  # fmt: skip
        try:
            init._data = dt.encode_value(t, init.value, bits)
        except ValueError as exc:
            raise err((*path, "value"), str(exc), init.value) from None
        init.type = t.name

    for j, joint in enumerate(s.joints):
        path = (*at, "joints", j)
        if joint.name in joints:
            raise err((*path, "name"), f"duplicate joint name (also in slave {joints[joint.name]})",
                      joint.name)  # fmt: skip
        joints[joint.name] = s.name
        for key, named in (("position", joint.position), ("velocity", joint.velocity),
                           ("effort", joint.effort)):  # fmt: skip
            if named is None:
                continue
            var_name = named
            try:
                var = layout.variable(var_name, "input")
            except ProcessValueError as exc:
                names = ", ".join(v.name for v in layout.inputs)
                raise err((*path, key), f"{exc}; input variables of {dev.type_name}: {names}",
                          var_name, False) from None  # fmt: skip
            if var.dtype.kind not in ("int", "uint", "real", "bool"):
                raise err((*path, key), "joint variables must be numeric", var_name)
