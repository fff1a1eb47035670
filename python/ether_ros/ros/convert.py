"""Between the plain layout dataclasses and the ``ether_ros_msgs`` messages."""

from __future__ import annotations

from ether_ros_msgs.msg import BusLayout, SlaveLayout, VariableInfo

from ether_ros.ros.layout import BusSpec, SlaveSpec, VariableSpec


def variable_msg(v: VariableSpec) -> VariableInfo:
    return VariableInfo(
        name=v.name,
        type=v.type,
        index=v.index,
        subindex=v.subindex,
        bit_length=v.bit_length,
        minimum=float(v.minimum),
        maximum=float(v.maximum),
    )


def layout_msg(spec: BusSpec) -> BusLayout:
    msg = BusLayout()
    msg.bus = spec.bus
    msg.cycle_us = spec.cycle_us
    msg.slaves = [
        SlaveLayout(
            slave=s.name,
            position=s.position,
            device=s.device,
            group=s.group,
            group_cycle_us=s.group_cycle_us,
            inputs=[variable_msg(v) for v in s.inputs],
            outputs=[variable_msg(v) for v in s.outputs],
        )
        for s in spec.slaves
    ]
    return msg


def variable_from_msg(m: VariableInfo) -> VariableSpec:
    return VariableSpec(
        name=m.name,
        type=m.type,
        index=int(m.index),
        subindex=int(m.subindex),
        bit_length=int(m.bit_length),
        minimum=float(m.minimum),
        maximum=float(m.maximum),
    )


def spec_from_msg(msg: BusLayout) -> BusSpec:
    return BusSpec(
        bus=msg.bus,
        cycle_us=int(msg.cycle_us),
        slaves=tuple(
            SlaveSpec(
                name=s.slave,
                position=int(s.position),
                device=s.device,
                inputs=tuple(variable_from_msg(v) for v in s.inputs),
                outputs=tuple(variable_from_msg(v) for v in s.outputs),
                group=s.group or "default",
                group_cycle_us=int(s.group_cycle_us),
            )
            for s in msg.slaves
        ),
    )
