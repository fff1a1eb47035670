"""Joint limits from a robot's URDF (``urdf:`` in the bus configuration).

A URDF ``<joint name=… type=…>`` with a ``<limit lower upper velocity effort>`` gives the CiA 402
axis of the same name its ``position_limits`` (lower/upper, none for a ``continuous`` joint),
``velocity_limit`` and ``torque_limit`` (effort), and — where the ``<limit>`` carries the
``acceleration`` attribute some toolchains add (the URDF standard has none; it is
``joint_limits.yaml``'s ``max_acceleration``) — its ``max_acceleration``. What the bus
configuration sets on the axis itself wins; the URDF fills in what it leaves out
(:func:`apply_urdf_limits`).

Hostile input is bounded as for ESI files (:mod:`ether_ros.config.esi`): a regular file of at most
:data:`MAX_URDF_BYTES`, read by :func:`ether_ros.config.files.read_regular`, and no document type
declaration — without one no entity can be declared, so nothing expands. Every failure is one
:class:`ConfigError` naming the file, the joint and the attribute.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from ether_ros.config.files import read_regular
from ether_ros.errors import ConfigError

if TYPE_CHECKING:
    from ether_ros.config.bus import AxisConfig

#: Largest URDF read (a full humanoid with inline meshes' names is well under 1 MiB).
MAX_URDF_BYTES = 8 << 20

#: URDF joint types that can be a drive's axis, and those that cannot.
MOVABLE_TYPES = ("revolute", "prismatic", "continuous")
_OTHER_TYPES = ("fixed", "floating", "planar")


@dataclass(frozen=True)
class UrdfJoint:
    """One movable joint's limits, in SI (rad or m; per second; N·m or N). None: not given."""

    name: str
    type: str
    lower: float | None
    upper: float | None
    velocity: float | None
    effort: float | None
    acceleration: float | None = None


def load_urdf_joints(path: Path) -> dict[str, UrdfJoint]:
    """The joints of the URDF ``path`` by name; ``fixed``/``floating``/``planar`` joints are
    listed with no limits so that an axis named after one can be refused."""
    data = read_regular(path, MAX_URDF_BYTES, "URDF file")
    if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
        raise ConfigError(
            f"{path}: <!DOCTYPE>: document type declarations (DTD, entities) are not supported"
            " in a URDF",
            file=path,
        )
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise ConfigError(f"{path}: not well-formed XML: {exc}", file=path) from None
    if root.tag != "robot":
        raise ConfigError(f"{path}: a URDF's root element is <robot>, not <{root.tag}>", file=path)
    joints: dict[str, UrdfJoint] = {}
    for el in root.iter("joint"):
        name = el.get("name")
        kind = el.get("type")
        if name is None or kind is None:
            # <joint> inside <transmission> names a joint without a type: not a declaration.
            continue
        if kind not in MOVABLE_TYPES + _OTHER_TYPES:
            raise _error(path, f"joint[{name}].type", f"unknown joint type {kind!r}", kind)
        if name in joints:
            raise _error(path, f"joint[{name}].name", "duplicate joint name", name)
        joints[name] = _joint(path, name, kind, el.find("limit"))
    return joints


def _joint(path: Path, name: str, kind: str, limit: ET.Element | None) -> UrdfJoint:
    values: dict[str, float | None] = {}
    for attr in ("lower", "upper", "velocity", "effort", "acceleration"):
        text = None if limit is None else limit.get(attr)
        values[attr] = None if text is None else _number(path, f"joint[{name}].limit.{attr}", text)
    if kind == "continuous":  # a continuous joint has no position limits, whatever it says
        values["lower"] = values["upper"] = None
    lo, hi = values["lower"], values["upper"]
    if lo is not None and hi is not None and lo > hi:
        raise _error(path, f"joint[{name}].limit", "lower must be <= upper", [lo, hi])
    for attr in ("velocity", "effort", "acceleration"):
        v = values[attr]
        if v is not None and v <= 0:
            raise _error(path, f"joint[{name}].limit.{attr}", "must be positive", v)
    return UrdfJoint(
        name, kind, lo, hi, values["velocity"], values["effort"], values["acceleration"]
    )


def _number(path: Path, field: str, text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise _error(path, field, "not a number", text) from None
    if not math.isfinite(v):
        raise _error(path, field, "must be a finite number (not nan or inf)", text)
    return v


def _error(path: Path, field: str, msg: str, value: object) -> ConfigError:
    return ConfigError(
        f"{path}: {field}: {msg} (got {value!r})", file=path, field=field, value=value
    )


def apply_urdf_limits(path: Path, joints: dict[str, UrdfJoint], axes: Iterable[AxisConfig]) -> int:
    """Give each axis named like a movable URDF joint the joint's limits, where the axis does
    not set them itself. The number of axes that matched a joint; an axis named like a
    fixed/floating/planar joint is refused (it cannot be driven)."""
    matched = 0
    for axis in axes:
        joint = joints.get(axis.name)
        if joint is None:
            continue
        if joint.type not in MOVABLE_TYPES:
            raise _error(
                path,
                f"joint[{joint.name}].type",
                f"axis {axis.name} is a {joint.type} joint in the URDF; an axis must be one of"
                f" {', '.join(MOVABLE_TYPES)}",
                joint.type,
            )
        matched += 1
        given = axis.model_fields_set
        if "position_limits" not in given:
            lo = -math.inf if joint.lower is None else joint.lower
            hi = math.inf if joint.upper is None else joint.upper
            axis.position_limits = (lo, hi)
        if "velocity_limit" not in given and joint.velocity is not None:
            axis.velocity_limit = joint.velocity
        if "torque_limit" not in given and joint.effort is not None:
            axis.torque_limit = joint.effort
        if "max_acceleration" not in given and joint.acceleration is not None:
            axis.max_acceleration = joint.acceleration
    return matched
