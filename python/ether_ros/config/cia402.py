"""CiA 402 (IEC 61800-7-201) drives in the bus configuration: a slave's ``profile: cia402`` and
its ``axes:``, checked against the ESI, and the PDO entries each axis needs.

Axis ``n`` (0-based) of a multi-axis drive has its objects at the standard index + n × 0x800
(ETG.6010: 0x6040 → 0x6840 for the second axis). Each axis needs the controlword and the
statusword, the target of its mode(s), and — when the ESI maps them — the mode objects, the
actual values, the error code and the following error (docs/cia402.md). When the bus
configuration gives no ``pdo_assign``, the PDOs that carry those objects are assigned
automatically (the ESI's default assignment plus any PDO that maps a missing object).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

from ether_ros._native import protocol
from ether_ros._native.protocol import CIA402_MODES
from ether_ros._native.protocol import cia402 as cia402_facts
from ether_ros.config.esi import EsiDevice, Pdo, PdoEntry
from ether_ros.config.process import ProcessLayout, ProcessVariable

if TYPE_CHECKING:
    from ether_ros.config.bus import AxisConfig, HomingConfig

PROFILE_NUMBER = 402
# The index distance between axes, the axis limit, the objects and the mode codes are the
# protocol crate's (``ether_ros._native.protocol.cia402``, ``CIA402_MODES``).
AXIS_STRIDE = cia402_facts.AXIS_OFFSET
MAX_AXES = cia402_facts.MAX_AXES

# Standard objects of axis 0 by role: (index, direction, bit length).
CONTROLWORD = cia402_facts.CONTROLWORD
STATUSWORD = cia402_facts.STATUSWORD
OBJECTS: dict[str, tuple[int, str, int]] = {
    "controlword": (cia402_facts.CONTROLWORD, "output", 16),
    "statusword": (cia402_facts.STATUSWORD, "input", 16),
    "mode": (cia402_facts.MODES_OF_OPERATION, "output", 8),
    "mode_display": (cia402_facts.MODES_OF_OPERATION_DISPLAY, "input", 8),
    "target_position": (cia402_facts.TARGET_POSITION, "output", 32),
    "target_velocity": (cia402_facts.TARGET_VELOCITY, "output", 32),
    "target_torque": (cia402_facts.TARGET_TORQUE, "output", 16),
    "position": (cia402_facts.POSITION_ACTUAL, "input", 32),
    "velocity": (cia402_facts.VELOCITY_ACTUAL, "input", 32),
    "torque": (cia402_facts.TORQUE_ACTUAL, "input", 16),
    "error_code": (cia402_facts.ERROR_CODE, "input", 16),
    "following_error": (cia402_facts.FOLLOWING_ERROR_ACTUAL, "input", 32),
}
SUPPORTED_MODES = cia402_facts.SUPPORTED_MODES

# The target object each mode needs in the PDOs (None: homing needs none).
_MODE_TARGETS: dict[str, str | None] = {
    "pp": "target_position",
    "pv": "target_velocity",
    "hm": None,
    "csp": "target_position",
    "csv": "target_velocity",
    "cst": "target_torque",
}
# Mode name → (0x6060 value, bit in 0x6502, the target object it needs in the PDOs).
MODES: dict[str, tuple[int, int, str | None]] = {
    name: (code, bit, _MODE_TARGETS[name]) for name, code, bit in CIA402_MODES
}
# Objects a profile mode (pp, pv, hm) needs in the dictionary besides its target (SDO set-up
# the drive must have: profile velocity/acceleration, homing method).
MODE_DICTIONARY: dict[str, tuple[int, ...]] = {
    "pp": (
        cia402_facts.TARGET_POSITION,
        cia402_facts.PROFILE_VELOCITY,
        cia402_facts.PROFILE_ACCELERATION,
    ),
    "pv": (cia402_facts.TARGET_VELOCITY, cia402_facts.PROFILE_ACCELERATION),
    "hm": (cia402_facts.HOMING_METHOD,),
}
# Objects the axis stage cannot work without, whatever the mode.
REQUIRED = ("controlword", "statusword")


@dataclass(frozen=True)
class ExtraSpec:
    """A resolved axis extra: its process variable and SI value = raw x factor + offset."""

    name: str
    variable: ProcessVariable
    factor: float
    offset: float

    @property
    def writable(self) -> bool:
        return self.variable.direction == "output"


@dataclass(frozen=True)
class AxisSpec:
    """A resolved axis: its configuration, its index on the drive and where its objects are
    in the slave's process areas (variables by role; roles the PDOs do not map are absent)."""

    config: AxisConfig
    slave: str
    axis_index: int
    variables: dict[str, ProcessVariable]
    # Modes the ESI offers (names), from 0x6502's default when it has one, else from the
    # objects of its dictionary.
    modes: tuple[str, ...]
    # The axis's extras by name, in configuration order.
    extras: dict[str, ExtraSpec] = field(default_factory=dict)
    # Homing methods the drive announces (0x60E3), when its ESI says.
    homing_methods: tuple[int, ...] | None = None

    @property
    def name(self) -> str:
        return self.config.name


ErrorFn = Callable[..., Exception]


def object_index(role: str, axis: int) -> int:
    return OBJECTS[role][0] + axis * AXIS_STRIDE


#: The objects a mode cannot run without, by which the dictionary shows what a drive offers
#: when 0x6502 does not say (CiA 402: the mode's target, and for homing its method).
MODE_OBJECTS: dict[str, tuple[int, ...]] = {
    "pp": (0x607A,),
    "pv": (0x60FF,),
    "hm": (0x6098,),
    "csp": (0x607A,),
    "csv": (0x60FF,),
    "cst": (0x6071,),
}


def offered_modes(dev: EsiDevice, axis: int) -> tuple[str, ...]:
    """The modes 0x6502 (supported drive modes) announces. Many ESIs give 0x6502 a default of
    0, a placeholder the drive fills in at run time (IS620N, STMBL): then — and when the ESI
    has no default for it — the modes are those whose objects the dictionary holds (or a PDO
    maps); all of them when the ESI has no dictionary (the drive is asked at run time)."""
    entry = dev.od_entry(SUPPORTED_MODES + axis * AXIS_STRIDE, 0)
    default = entry.default if entry is not None else None
    bits = int.from_bytes(default[:4], "little") if isinstance(default, bytes | bytearray) else 0
    if bits:
        return tuple(name for name, (_, bit, _t) in MODES.items() if bits >> bit & 1)
    if not dev.objects:
        return tuple(MODES)
    shift = axis * AXIS_STRIDE
    # An object a PDO maps is the device's too, whether its dictionary lists it or not (an
    # ETG.2001 drive's module objects).
    mapped = {e.index for p in (*dev.rx_pdos, *dev.tx_pdos) for e in p.entries}
    return tuple(
        name
        for name, needed in MODE_OBJECTS.items()
        if all(dev.od_object(i + shift) is not None or i + shift in mapped for i in needed)
    )


def needed_roles(mode: str) -> tuple[str, ...]:
    """Objects the axis cannot run without: controlword, statusword, the mode's target and, in
    the position modes, the actual position (the target before enabling: no jump)."""
    target = MODES[mode][2]
    extra = ("position",) if target == "target_position" else ()
    return (*REQUIRED, *((target,) if target else ()), *extra)


# Objects mapped into a configurable PDO when missing: the needed ones, and the mode objects
# (so that 0x6060 is written every cycle and 0x6061 confirms it).
MAPPED_IF_POSSIBLE = ("mode", "mode_display")


def extend_mapping(
    dev: EsiDevice, rx: Sequence[int], tx: Sequence[int], axes: Sequence[AxisConfig]
) -> EsiDevice:
    """``dev`` with the objects the axes need appended to the assigned PDOs that lack them, when
    the device allows PDO configuration (ESI ``<CoE PdoConfig="true">``), the PDO is not fixed
    and the dictionary marks the object mappable in that direction; else ``dev`` unchanged (the
    check in ``resolve_axes`` then names what is missing). The master writes the new mapping in
    PREOP (master/pdo.py)."""
    if dev.mailbox is None or not dev.mailbox.pdo_config:
        return dev
    pdos = {p.index: p for p in (*dev.rx_pdos, *dev.tx_pdos)}
    chosen = {"rx": [i for i in rx if i in pdos], "tx": [i for i in tx if i in pdos]}
    changed = False
    for n, cfg in enumerate(axes):
        for role in (*needed_roles(cfg.mode), *MAPPED_IF_POSSIBLE):
            idx = object_index(role, n)
            kind = "rx" if OBJECTS[role][1] == "output" else "tx"
            if any(_maps(pdos[i], (idx, 0)) for i in chosen[kind]):
                continue
            entry = dev.od_entry(idx, 0)
            flag = "R" if kind == "rx" else "T"
            if entry is None or flag not in entry.pdo_mapping:
                continue
            target = _pdo_for_axis([pdos[i] for i in chosen[kind]], n)
            if target is None:
                continue
            new = PdoEntry(idx, 0, entry.bit_length, entry.name, entry.data_type, entry.type_name)
            pdos[target.index] = replace(target, entries=(*target.entries, new))
            changed = True
        for extra in cfg.extras:
            address = extra_address(extra.object, n)
            direction = extra_direction(dev, *address) if address is not None else None
            if address is None or direction is None:
                continue  # resolve_axes names what is wrong
            kind = "rx" if direction == "output" else "tx"
            if any(_maps(pdos[i], address) for i in chosen[kind]):
                continue
            target = _pdo_for_axis([pdos[i] for i in chosen[kind]], n)
            entry = dev.od_entry(*address)
            if target is None or entry is None:
                continue
            new = PdoEntry(*address, entry.bit_length, entry.name, entry.data_type, entry.type_name)
            pdos[target.index] = replace(target, entries=(*target.entries, new))
            changed = True
    if not changed:
        return dev
    return replace(
        dev,
        rx_pdos=tuple(pdos[p.index] for p in dev.rx_pdos),
        tx_pdos=tuple(pdos[p.index] for p in dev.tx_pdos),
    )


def _pdo_for_axis(candidates: Sequence[Pdo], axis: int) -> Pdo | None:
    """The configurable PDO that already carries objects of ``axis`` (else the first
    configurable one)."""
    lo, hi = 0x6000 + axis * AXIS_STRIDE, 0x6000 + (axis + 1) * AXIS_STRIDE
    free = [p for p in candidates if not p.fixed]
    for p in free:
        if any(lo <= e.index < hi for e in p.entries):
            return p
    return free[0] if free else None


# The profile area of axis 0's standard objects: an extra there is taken at the axis's own
# index (ETG.6010: + n x 0x800); outside it (a vendor object) as given.
PROFILE_AREA = range(0x6000, 0x6000 + AXIS_STRIDE)


def extra_address(obj: int | str, axis: int) -> tuple[int, int] | None:
    """The (index, subindex) of an extra's ``object`` on axis ``axis``; None when it is no
    address."""
    if isinstance(obj, int):
        index, subindex = obj, 0
    else:
        try:
            parsed = protocol.parse_address(obj)
        except ValueError:
            return None
        if parsed is None:
            try:  # an index alone: hexadecimal with or without 0x, the one rule (protocol)
                parsed = (protocol.parse_index(obj), 0)
            except ValueError:
                return None
        index, subindex = parsed
    if not 0 <= index <= 0xFFFF:
        return None
    if index in PROFILE_AREA:
        index += axis * AXIS_STRIDE
    return index, subindex


def extra_direction(dev: EsiDevice, index: int, subindex: int) -> str | None:
    """``output`` for an object the dictionary maps into RxPDOs only, ``input`` for one it maps
    into TxPDOs; None when it maps it neither way."""
    entry = dev.od_entry(index, subindex)
    if entry is None or not entry.pdo_mapping:
        return None
    return "output" if entry.pdo_mapping == "R" else "input"


def wanted_roles() -> tuple[str, ...]:
    return tuple(OBJECTS)


def auto_assign(dev: EsiDevice, axes: int) -> tuple[list[int], list[int]]:
    """The ESI's default PDO assignment plus every other PDO that maps an object the axes use
    and the default lacks (skipping PDOs excluded by one already chosen)."""
    chosen: dict[str, list[int]] = {
        "rx": list(dev.default_rx_pdos()),
        "tx": list(dev.default_tx_pdos()),
    }
    for kind, pdos in (("rx", dev.rx_pdos), ("tx", dev.tx_pdos)):
        by_index = {p.index: p for p in pdos}
        mapped = {
            (e.index, e.subindex)
            for i in chosen[kind]
            if i in by_index
            for e in by_index[i].entries
        }
        direction = "output" if kind == "rx" else "input"
        for axis in range(axes):
            for role, (_idx, d, _bits) in OBJECTS.items():
                want = (object_index(role, axis), 0)
                if d != direction or want in mapped:
                    continue
                for p in pdos:
                    if p.index in chosen[kind] or not _maps(p, want):
                        continue
                    if any(x in chosen[kind] for x in p.excludes):
                        continue
                    chosen[kind].append(p.index)
                    mapped |= {(e.index, e.subindex) for e in p.entries}
                    break
    return chosen["rx"], chosen["tx"]


def _maps(p: Pdo, key: tuple[int, int]) -> bool:
    return any((e.index, e.subindex) == key for e in p.entries)


SOFTWARE_POSITION_LIMIT = cia402_facts.SOFTWARE_POSITION_LIMIT
INT32_MIN, INT32_MAX = (int(x) for x in protocol.value_range("int", 32))
UINT32_MAX = int(protocol.value_range("uint", 32)[1])
# A position, velocity or torque scale (SI units per count) outside this range is refused: a
# 32-bit encoder behind a 10⁴:1 gear is 1.5e-13 rad per count, and no drive counts in
# kilometres or kiloradians. Beyond it the conversions to counts overflow or round to 0.
SCALE_RANGE = (1e-15, 1e3)
# The pp/pv profile (config key → object): in the drive's velocity units (per second for the
# accelerations), i.e. SI / velocity_scale.
PROFILE_OBJECTS = {
    "profile_velocity": cia402_facts.PROFILE_VELOCITY,
    "profile_acceleration": cia402_facts.PROFILE_ACCELERATION,
    "profile_deceleration": cia402_facts.PROFILE_DECELERATION,
}


SUPPORTED_HOMING_METHODS = cia402_facts.SUPPORTED_HOMING_METHODS


# The homing set-up (config key → object of axis 0): 0x6098, 0x6099 (:1 switch, :2 zero),
# 0x609A, 0x607C.
def profile_values(cfg: AxisConfig) -> dict[str, float | None]:
    """The axis's profile settings by the keys of PROFILE_OBJECTS (None: not given)."""
    return {
        "profile_velocity": cfg.profile_velocity,
        "profile_acceleration": cfg.profile_acceleration,
        "profile_deceleration": cfg.profile_deceleration,
    }


def homing_values(h: HomingConfig) -> dict[str, float | None]:
    """The homing settings by the keys of HOMING_OBJECTS (None: not given)."""
    return {
        "method": h.method,
        "speed_switch": h.speed_switch,
        "speed_zero": h.speed_zero,
        "acceleration": h.acceleration,
        "offset": h.offset,
    }


HOMING_OBJECTS = {
    "method": cia402_facts.HOMING_METHOD,
    "speed_switch": cia402_facts.HOMING_SPEEDS,
    "speed_zero": cia402_facts.HOMING_SPEEDS,
    "acceleration": cia402_facts.HOMING_ACCELERATION,
    "offset": cia402_facts.HOME_OFFSET,
}


def profile_raw(cfg: AxisConfig, key: str, value: float) -> int:
    """A profile value in SI as the drive's raw UDINT (velocity units, /s for accelerations);
    ValueError when it does not fit."""
    ratio = value / cfg.velocity_scale
    raw = round(ratio) if math.isfinite(ratio) else ratio
    if not 1 <= raw <= UINT32_MAX:
        raise ValueError(f"{key} {value:g} is {raw:g} in the drive's units (velocity_scale "
                         f"{cfg.velocity_scale:g}): outside 1..{UINT32_MAX}")  # fmt: skip
    return int(raw)


def software_limits_raw(cfg: AxisConfig) -> tuple[int, int] | None:
    """``position_limits`` in the drive's position units (0x607D:1 min, :2 max), rounded
    inwards, or None when a limit is infinite (the drive's own limits stay as they are)."""
    lo, hi = cfg.position_limits
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return None
    # A limit beyond what an INT32 holds is the drive's own end of range (clamped before the
    # rounding: a huge limit over a tiny scale is no integer at all, but infinity).
    raw_lo = min(max((lo - cfg.position_offset) / cfg.position_scale, INT32_MIN), INT32_MAX)
    raw_hi = min(max((hi - cfg.position_offset) / cfg.position_scale, INT32_MIN), INT32_MAX)
    return max(math.ceil(raw_lo - 1e-9), INT32_MIN), min(math.floor(raw_hi + 1e-9), INT32_MAX)


def axis_sdo_inits(specs: Sequence[AxisSpec], dev: EsiDevice) -> list[tuple[int, int, int, str]]:
    """(index, subindex, value, type) the master writes once in PREOP for the axes:

    - 0x6060 with the mode of every axis whose mode object is not in the PDOs, so the drive
      never runs without one;
    - 0x607D:1/:2, the software position limits, from ``position_limits`` when both are finite
      and the dictionary has the object: the drive holds them too, whatever the master sends;
    - 0x6081/0x6083/0x6084, the pp/pv profile, from ``profile_*`` when given.
    """
    out: list[tuple[int, int, int, str]] = []
    for a in specs:
        n = a.axis_index
        if "mode" not in a.variables:
            out.append((object_index("mode", n), 0, MODES[a.config.mode][0], "int8"))
        limits = software_limits_raw(a.config)
        index = SOFTWARE_POSITION_LIMIT + n * AXIS_STRIDE
        if limits is not None and dev.od_object(index) is not None:
            out.append((index, 1, limits[0], "int32"))
            out.append((index, 2, limits[1], "int32"))
        profile = profile_values(a.config)
        for key, base in PROFILE_OBJECTS.items():
            value = profile[key]
            if value is not None:
                raw = profile_raw(a.config, key, value)
                out.append((base + n * AXIS_STRIDE, 0, raw, "uint32"))
        out.extend(homing_sdo_inits(a.config, n))
    return out


def homing_sdo_inits(cfg: AxisConfig, n: int) -> list[tuple[int, int, int, str]]:
    """The homing set-up of one axis in the drive's units: method, speeds, acceleration (raw =
    SI / velocity_scale) and home offset (raw position of the home)."""
    h = cfg.homing
    if h is None:
        return []
    at = n * AXIS_STRIDE
    out = [(HOMING_OBJECTS["method"] + at, 0, h.method, "int8")]
    for key, sub, value in (("speed_switch", 1, h.speed_switch), ("speed_zero", 2, h.speed_zero)):
        if value is not None:
            out.append((HOMING_OBJECTS[key] + at, sub, profile_raw(cfg, key, value), "uint32"))
    if h.acceleration is not None:
        raw = profile_raw(cfg, "acceleration", h.acceleration)
        out.append((HOMING_OBJECTS["acceleration"] + at, 0, raw, "uint32"))
    offset = min(max((h.offset - cfg.position_offset) / cfg.position_scale, INT32_MIN), INT32_MAX)
    out.append((HOMING_OBJECTS["offset"] + at, 0, round(offset), "int32"))
    return out


def acceleration_limit(cfg: AxisConfig) -> float:
    """The axis's acceleration limit (SI/s²) for the engine's hand-overs: ``max_acceleration``
    (from the configuration or the URDF), else the axis's ``deceleration`` — the rate it is
    configured to stop at, so a hand-over never asks more of it than a stop — which is inf
    (only the velocity limit) when that is not given either (docs/configuration.md)."""
    return cfg.max_acceleration if cfg.max_acceleration is not None else cfg.deceleration


def check_axis(cfg: AxisConfig, path: tuple[Any, ...], err: ErrorFn) -> None:
    """Refuse inconsistent numbers: non-positive or non-finite scales, NaN, min > max."""
    scales = (("position_scale", cfg.position_scale), ("velocity_scale", cfg.velocity_scale),
              ("torque_scale", cfg.torque_scale))  # fmt: skip
    for key, v in scales:
        if not math.isfinite(v) or v <= 0:
            raise err((*path, key), "must be a positive finite number", v)
        if not SCALE_RANGE[0] <= v <= SCALE_RANGE[1]:
            raise err((*path, key), f"must be within {SCALE_RANGE[0]:g}..{SCALE_RANGE[1]:g} "
                      "(SI units per count: a bigger or smaller one is a typo)", v)  # fmt: skip
    if not math.isfinite(cfg.position_offset):
        raise err((*path, "position_offset"), "must be a finite number", cfg.position_offset)
    lo, hi = cfg.position_limits
    if math.isnan(lo) or math.isnan(hi) or lo > hi:
        raise err((*path, "position_limits"), "must be [min, max] with min <= max", [lo, hi])
    for key, v in (("velocity_limit", cfg.velocity_limit), ("torque_limit", cfg.torque_limit)):
        if math.isnan(v) or v <= 0:
            raise err((*path, key), "must be positive", v)
    w = cfg.following_error_window
    if math.isnan(w) or w < 0 or math.isinf(w):
        raise err((*path, "following_error_window"), "must be a finite number >= 0", w)
    if math.isnan(cfg.deceleration) or cfg.deceleration <= 0:
        raise err((*path, "deceleration"), "must be positive (inf: at once)", cfg.deceleration)
    a = cfg.max_acceleration
    if a is not None and (math.isnan(a) or a <= 0):
        raise err((*path, "max_acceleration"), "must be positive (inf: no limit)", a)
    if cfg.homing is not None:
        homing = homing_values(cfg.homing)
        for key in ("speed_switch", "speed_zero", "acceleration"):
            given = homing[key]
            if given is None:
                continue
            try:
                profile_raw(cfg, key, given)
            except ValueError as exc:
                raise err((*path, "homing", key), str(exc), given) from None
    for key, profile in profile_values(cfg).items():
        if profile is None:
            continue
        if not math.isfinite(profile) or profile <= 0:
            raise err((*path, key), "must be a positive finite number", profile)
        try:
            profile_raw(cfg, key, profile)
        except ValueError as exc:
            raise err((*path, key), str(exc), profile) from None


def resolve_axes(
    dev: EsiDevice,
    layout: ProcessLayout,
    slave: str,
    axes: Sequence[AxisConfig],
    at: tuple[Any, ...],
    err: ErrorFn,
) -> list[AxisSpec]:
    """Check every axis against the ESI and the PDO layout; the error names the axis key,
    the object and why."""
    by_key = {(v.index, v.subindex): v for v in layout.variables}
    specs: list[AxisSpec] = []
    for n, cfg in enumerate(axes):
        path = (*at, "axes", n)
        check_axis(cfg, path, err)
        modes = offered_modes(dev, n)
        if cfg.mode not in modes:
            raise err((*path, "mode"), f"{dev.type_name} axis {n + 1} does not offer this mode "
                      f"(0x{SUPPORTED_MODES + n * AXIS_STRIDE:04X} supported drive modes: "
                      f"{', '.join(modes) or 'none'})", cfg.mode)  # fmt: skip
        profile = profile_values(cfg)
        for key, base in PROFILE_OBJECTS.items():
            idx = base + n * AXIS_STRIDE
            if profile[key] is not None and dev.objects and dev.od_object(idx) is None:
                raise err((*path, key), f"the {dev.type_name} dictionary has no object "
                          f"0x{idx:04X} to write it to", profile[key])  # fmt: skip
        for index in MODE_DICTIONARY.get(cfg.mode, ()):
            idx = index + n * AXIS_STRIDE
            if dev.objects and dev.od_object(idx) is None:
                raise err((*path, "mode"), f"mode {cfg.mode} needs object 0x{idx:04X}, which the "
                          f"{dev.type_name} dictionary lacks", cfg.mode)  # fmt: skip
        variables: dict[str, ProcessVariable] = {}
        for role, (_i, direction, bits) in OBJECTS.items():
            idx = object_index(role, n)
            var = by_key.get((idx, 0))
            if var is None:
                continue
            if var.direction != direction or var.bit_length != bits or var.bit_offset % 8:
                raise err(path, f"object 0x{idx:04X} ({role}) is mapped as {var.direction} of "
                          f"{var.bit_length} bit(s) at bit {var.bit_offset}; the axis needs a "
                          f"byte-aligned {direction} of {bits} bits", None, False)  # fmt: skip
            variables[role] = var
        for role in needed_roles(cfg.mode):
            if role not in variables:
                idx = object_index(role, n)
                kind = "RxPDO" if OBJECTS[role][1] == "output" else "TxPDO"
                where = "the dictionary" if dev.od_object(idx) is None else f"any assigned {kind}"
                raise err(path, f"axis {cfg.name} (mode {cfg.mode}) needs object 0x{idx:04X} "
                          f"({role}), which is not in {where} of {dev.type_name}",
                          None, False)  # fmt: skip
        mode_index = object_index("mode", n)
        if "mode" not in variables and dev.objects and dev.od_object(mode_index) is None:
            raise err(path, f"axis {cfg.name}: object 0x{mode_index:04X} (modes of operation) is "
                      f"neither in the PDOs nor in the {dev.type_name} dictionary: the mode "
                      "cannot be set", None, False)  # fmt: skip
        extras = resolve_extras(dev, layout, cfg, n, path, err)
        methods = supported_homing_methods(dev, n)
        if cfg.homing is not None:
            hpath = (*path, "homing")
            if "hm" not in modes:
                raise err(hpath, f"{dev.type_name} axis {n + 1} does not offer homing (mode hm "
                          "is not in 0x6502)", None, False)  # fmt: skip
            if methods is not None and cfg.homing.method not in methods:
                raise err((*hpath, "method"), f"{dev.type_name} does not offer this homing method "
                          f"(0x60E3 supported homing methods: "
                          f"{', '.join(map(str, methods))})", cfg.homing.method)  # fmt: skip
            homing = homing_values(cfg.homing)
            for key, base in HOMING_OBJECTS.items():
                idx = base + n * AXIS_STRIDE
                given = key == "method" or homing[key] is not None
                if given and dev.objects and dev.od_object(idx) is None:
                    raise err((*hpath, key), f"the {dev.type_name} dictionary has no object "
                              f"0x{idx:04X} to write it to", homing[key])  # fmt: skip
        specs.append(AxisSpec(cfg, slave, n, variables, modes, extras, methods))
    return specs


def resolve_extras(
    dev: EsiDevice,
    layout: ProcessLayout,
    cfg: AxisConfig,
    n: int,
    path: tuple[Any, ...],
    err: ErrorFn,
) -> dict[str, ExtraSpec]:
    """Each extra of the axis as the process variable it is mapped to, with its SI scale; the
    error names the extra and why (no address, not in the dictionary, not mappable, not in any
    PDO, a name given twice)."""
    by_key = {(v.index, v.subindex): v for v in layout.variables}
    factors = {
        "position": (cfg.position_scale, cfg.position_offset),
        "velocity": (cfg.velocity_scale, 0.0),
        "torque": (cfg.torque_scale, 0.0),
    }
    out: dict[str, ExtraSpec] = {}
    for k, extra in enumerate(cfg.extras):
        epath = (*path, "extras", k)
        if extra.name in out:
            raise err((*epath, "name"), "an extra of this axis has this name already", extra.name)
        address = extra_address(extra.object, n)
        if address is None:
            raise err((*epath, "object"), "is not an object address (0x60FD, 0x60FE:01)",
                      extra.object)  # fmt: skip
        shown = protocol.format_address(*address)
        if dev.objects and dev.od_entry(*address) is None:
            raise err((*epath, "object"), f"{shown} is not in the {dev.type_name} dictionary",
                      extra.object)  # fmt: skip
        var = by_key.get(address)
        if var is None:
            why = ("the dictionary does not mark it PDO-mappable"
                   if extra_direction(dev, *address) is None
                   else "no assigned PDO maps it and the PDOs cannot take it")  # fmt: skip
            raise err((*epath, "object"), f"{shown} is not in the process data: {why}",
                      extra.object)  # fmt: skip
        if isinstance(extra.scale, str):
            factor, offset = factors[extra.scale]
        else:
            if not math.isfinite(extra.scale) or extra.scale == 0:
                raise err((*epath, "scale"), "must be a finite number other than 0", extra.scale)
            factor, offset = float(extra.scale), 0.0
        out[extra.name] = ExtraSpec(extra.name, var, factor, offset)
    return out


def supported_homing_methods(dev: EsiDevice, axis: int) -> tuple[int, ...] | None:
    """The homing methods 0x60E3 (supported homing methods) announces in the ESI's defaults, or
    None when the ESI does not say."""
    obj = dev.od_object(SUPPORTED_HOMING_METHODS + axis * AXIS_STRIDE)
    if obj is None:
        return None
    methods = []
    for entry in obj.entries:
        default = entry.default
        if entry.subindex == 0 or not isinstance(default, bytes | bytearray) or not default:
            continue
        methods.append(int.from_bytes(default[:1], "little", signed=True))
    return tuple(methods) or None
