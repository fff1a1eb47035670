"""The process-data layout as the ROS side sees it: which variables each slave has, their types
and ranges, in the order their values are published.

These are plain dataclasses with no ROS import, so the console's command parser (a pure function)
and its tests use them without a ROS context. :mod:`ether_ros.ros.convert` turns them into the
``ether_ros_msgs`` messages and back.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ether_ros._native import protocol
from ether_ros.errors import EtherRosError


class LayoutError(EtherRosError):
    """A slave or variable reference that names nothing on this bus."""


@dataclass(frozen=True)
class VariableSpec:
    """One mapped process variable."""

    name: str
    type: str  # ESI data type name: BOOL, SINT, INT, DINT, USINT, UINT, UDINT, REAL, ...
    index: int
    subindex: int
    bit_length: int
    minimum: float
    maximum: float

    @property
    def address(self) -> str:
        return protocol.format_address(self.index, self.subindex)


@dataclass(frozen=True)
class SlaveSpec:
    name: str
    position: int
    device: str
    inputs: tuple[VariableSpec, ...] = ()
    outputs: tuple[VariableSpec, ...] = ()
    # The slave group and its cycle (0: unknown, e.g. a layout from an older node).
    group: str = "default"
    group_cycle_us: int = 0

    def output(self, ref: str) -> VariableSpec:
        """The output variable named ``ref`` or addressed by ``ref`` ("0x7030:03", "7030:3")."""
        return _find(self.outputs, ref, self.name, "output")

    def input(self, ref: str) -> VariableSpec:
        return _find(self.inputs, ref, self.name, "input")

    def has_output(self, ref: str) -> bool:
        try:
            self.output(ref)
        except LayoutError:
            return False
        return True


@dataclass(frozen=True)
class BusSpec:
    bus: str
    cycle_us: int
    slaves: tuple[SlaveSpec, ...] = field(default_factory=tuple)

    def slave(self, ref: str | int) -> SlaveSpec:
        """A slave by name, or by position (an int or a decimal string)."""
        if isinstance(ref, int) or (isinstance(ref, str) and ref.isascii() and ref.isdigit()):
            position = int(ref)
            for s in self.slaves:
                if s.position == position:
                    return s
            raise LayoutError(
                f"no slave at position {position} (positions: "
                f"{', '.join(str(s.position) for s in self.slaves) or 'none'})"
            )
        for s in self.slaves:
            if s.name == ref:
                return s
        raise LayoutError(
            f"no slave named '{ref}' (slaves: {', '.join(s.name for s in self.slaves) or 'none'})"
        )


def parse_address(ref: str) -> tuple[int, int] | None:
    """``"0x7030:03"`` / ``"7030:3"`` -> (0x7030, 3); a name -> None (the one grammar of
    object addresses: ``ether_ros._native.protocol.parse_address``, both parts hexadecimal).
    Raises :class:`LayoutError` for text of that shape that is out of range (``28720:10``)."""
    try:
        return protocol.parse_address(ref)
    except ValueError as exc:
        raise LayoutError(str(exc)) from None


def _find(variables: tuple[VariableSpec, ...], ref: str, slave: str, kind: str) -> VariableSpec:
    address = parse_address(ref)
    if address is not None:
        for v in variables:
            if (v.index, v.subindex) == address:
                return v
        raise LayoutError(
            f"slave '{slave}' maps no {kind} variable at {protocol.format_address(*address)}"
        )
    for v in variables:
        if v.name == ref:
            return v
    # Names in ESI files are not consistent in case (FlatnessParam100 next to a_ellipse100):
    # accept a case-insensitive match when it is unambiguous.
    folded = [v for v in variables if v.name.lower() == ref.lower()]
    if len(folded) == 1:
        return folded[0]
    raise LayoutError(f"slave '{slave}' has no {kind} variable '{ref}'")
