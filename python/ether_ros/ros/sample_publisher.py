"""The thread that turns the engine's per-cycle samples into ROS messages.

It runs off the real-time path: the engine's RT thread pushes one sample (record + process image)
per cycle into a lock-free ring; this Python thread drains the ring through ``Bus.samples()``
and publishes

- ``pdo_raw`` every ``raw_decimation`` cycles (the whole image, inputs and outputs),
- ``pdo_in`` / ``pdo_out`` (decoded values per slave) and ``joint_states`` (the ``joints:``
  mappings and every CiA 402 axis, SI units) every ``decoded_decimation`` cycles,
- ``joint_extras`` (the axes' ``extras:``, SI units) at the same rate, when some axis has extras.

Freshness: each sample says which cyclic frames' inputs are stale (``stale_mask``: no reply came
back whole within two of the frame's periods). ``pdo_in`` carries it per slave (``stale``, the
values being the last ones received), and ``joint_states`` leaves out the joints whose slave's
inputs are stale — no message at all while every joint is — so a consumer never takes old
positions for new ones (ROS consumers already treat a joint that stops coming as unknown).

When ROS falls behind (a batch holds more than ``max_backlog`` samples) the oldest samples are
skipped and counted in ``dropped``; the engine counts the samples it could not even queue
(ring full) itself. A second small thread feeds the engine's command watchdog every 10 ms while
the node's commands are fresh (see ``EtherRosNode``); the publisher keeps the numbers the
diagnostics report.
"""

from __future__ import annotations

import array
import contextlib
import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from ether_ros_msgs.msg import JointExtras, PdoRaw, SlaveValues
from sensor_msgs.msg import JointState

from ether_ros.config.bus import JointSpec
from ether_ros.ros import bridge
from ether_ros.ros.joints import AxisState
from ether_ros.ros.layout import BusSpec

log = logging.getLogger(__name__)


@dataclass
class PublisherCounters:
    samples: int = 0
    published_raw: int = 0
    published_decoded: int = 0
    dropped: int = 0
    lost: int = 0
    watchdog_cycles: int = 0
    panic_cycles: int = 0
    last_cycle: int = 0
    last_flags: int = 0
    dc_error_max_ns: int = 0  # largest |DC difference| since the diagnostics last read it
    wkc: int = 0
    # Decoded samples in which some slave's inputs were stale.
    stale_samples: int = 0
    extra: dict[str, float] = field(default_factory=dict)


@dataclass
class Rates:
    raw_decimation: int = 1
    decoded_decimation: int = 10


class SamplePublisher:
    def __init__(
        self,
        bus: Any,
        spec: BusSpec,
        publishers: dict[str, Any],
        joints: list[JointSpec],
        rates: Rates,
        feed_watchdog: Callable[[], bool],
        max_backlog: int = 5000,
        poll_s: float = 0.002,
        axis_joints: Callable[[bytes], list[tuple[str, float, float, float]]] | None = None,
        axis_slaves: dict[str, str] | None = None,
        feeder_priority: int = 0,
        axis_extras: Callable[[], list[tuple[str, str, float]]] | None = None,
        axis_states: Callable[[], list[AxisState]] | None = None,
    ) -> None:
        self._bus = bus
        self._spec = spec
        self._pub = publishers
        self._joints = joints
        # CiA 402 axes: (joint, position, velocity, effort) in SI, read from the sample's own
        # process image (joints.AxisImageJoints), so they are the values of the cycle the
        # message's stamp names.
        self._axis_joints = axis_joints
        # (joint, extra, value in SI) of every axis extra, read like the axes' joint_states
        # part; None when no axis has extras (no joint_extras then).
        self._axis_extras = axis_extras
        # Each axis's state for joint_extras (``AxisState``); None when the bus has no axes.
        self._axis_states = axis_states
        # Frames carrying each slave's data (a bit mask), and each axis joint's slave: what
        # the sample's stale_mask is checked against.
        self._frame_masks = bridge.frame_masks(bus)
        self._axis_slaves = dict(axis_slaves or {})
        self.rates = rates
        self._feed_watchdog = feed_watchdog
        # SCHED_FIFO priority of the watchdog feeder (0: normal scheduling).
        self._feeder_priority = feeder_priority
        self._max_backlog = max_backlog
        self._poll_s = poll_s
        self._slices = bridge.image_slices(bus)
        self._output_bytes = bridge.output_bytes(bus)
        self._expected_wkc = bridge.expected_wkc(bus)
        self._decoders = {
            s.name: (bridge.area_decoder(s.layout.inputs), bridge.area_decoder(s.layout.outputs))
            for s in bus.slaves
            if s.layout is not None
        }
        self._input_names = {
            s.name: {v.name: i for i, v in enumerate(s.inputs)} for s in spec.slaves
        }
        self._positions = {s.name: s.position for s in spec.slaves}
        self.counters = PublisherCounters()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        # CLOCK_MONOTONIC (the engine's time base) -> wall clock for message stamps.
        self._mono_to_wall_ns = time.time_ns() - time.clock_gettime_ns(time.CLOCK_MONOTONIC)

    def start(self) -> None:
        self._stop.clear()
        self._threads = [
            threading.Thread(target=self._run, name="ether_ros-samples", daemon=True),
            threading.Thread(target=self._feed, name="ether_ros-watchdog", daemon=True),
        ]
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=5)
        self._threads = []

    def take_dc_error(self) -> int:
        with self._lock:
            value = self.counters.dc_error_max_ns
            self.counters.dc_error_max_ns = 0
            return value

    def _feed(self) -> None:
        """Feed the engine's command watchdog every 10 ms, in its own thread so a long batch of
        messages never starves it: only a stalled process (or stale commands, see the node's
        ``command_timeout_ms``) lets the watchdog expire. At ``feeder_priority`` (SCHED_FIFO,
        the native command thread's) a loaded machine's normal processes cannot hold it off
        either: a watchdog stop keeps CiA 402 axes out until an explicit enable, so it must
        mean a stalled node, not a busy machine. Without CAP_SYS_NICE it keeps normal
        scheduling."""
        if self._feeder_priority:
            with contextlib.suppress(OSError, AttributeError):
                os.sched_setscheduler(
                    threading.get_native_id(),
                    os.SCHED_FIFO,
                    os.sched_param(self._feeder_priority),
                )
        while not self._stop.wait(0.01):
            try:
                self._feed_watchdog()
            except Exception:
                log.exception("feeding the command watchdog failed")

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                batch = self._bus.samples()
                published = self._publish_batch(batch)
            except Exception:  # keep publishing: one bad batch must not end the thread
                log.exception("publishing samples failed")
                published = 0
            if not published:
                self._stop.wait(self._poll_s)

    def _publish_batch(self, batch: Any) -> int:
        records, images = bridge.sample_arrays(batch)
        if records is None or len(records) == 0:
            return 0
        n = len(records)
        excess = n - self._max_backlog
        if excess > 0:
            records, images = records[excess:], images[excess:]
        flags = records["flags"]
        c = self.counters
        with self._lock:
            c.dropped += max(excess, 0)
            c.samples += n
            c.last_cycle = int(records["cycle"][-1])
            c.last_flags = int(flags[-1])
            c.wkc = int(records["wkc"][-1])
            c.lost += int(np.count_nonzero(flags & bridge.FLAG_LOST))
            c.watchdog_cycles += int(np.count_nonzero(flags & bridge.FLAG_WATCHDOG))
            c.panic_cycles += int(np.count_nonzero(flags & bridge.FLAG_PANIC))
            dc = int(np.max(np.abs(records["dc_diff_ns"].astype(np.int64))))
            c.dc_error_max_ns = max(c.dc_error_max_ns, dc)
        cycles = records["cycle"]
        raw_every = max(self.rates.raw_decimation, 1)
        decoded_every = max(self.rates.decoded_decimation, 1)
        for i in np.flatnonzero((cycles % raw_every == 0) | (cycles % decoded_every == 0)):
            record = records[i]
            cycle = int(record["cycle"])
            image = images[i].tobytes()
            stamp = self._stamp(int(record["t_wake_ns"]))
            if cycle % raw_every == 0:
                self._publish_raw(stamp, cycle, int(record["wkc"]), image)
            if cycle % decoded_every == 0:
                self._publish_decoded(stamp, cycle, image, int(record["stale_mask"]))
        return n

    def _stale(self, slave: str, stale_mask: int) -> bool:
        return bool(self._frame_masks.get(slave, 0) & stale_mask)

    def _stamp(self, t_mono_ns: int) -> Time:
        wall = t_mono_ns + self._mono_to_wall_ns if t_mono_ns else time.time_ns()
        return Time(sec=wall // 1_000_000_000, nanosec=wall % 1_000_000_000)

    def _publish_raw(self, stamp: Time, cycle: int, wkc: int, image: bytes) -> None:
        msg = PdoRaw()
        msg.header.stamp = stamp
        msg.header.frame_id = self._spec.bus
        msg.cycle = cycle
        msg.working_counter = wkc & 0xFFFF
        msg.expected_working_counter = self._expected_wkc & 0xFFFF
        msg.pdo_out = array.array("B", image[: self._output_bytes])
        msg.pdo_in = array.array("B", image[self._output_bytes :])
        self._pub["pdo_raw"].publish(msg)
        self.counters.published_raw += 1

    def _publish_decoded(self, stamp: Time, cycle: int, image: bytes, stale_mask: int = 0) -> None:
        inputs_by_slave: dict[str, list[float]] = {}
        stale_slaves = {sl.slave for sl in self._slices if self._stale(sl.slave, stale_mask)}
        if stale_slaves:
            self.counters.stale_samples += 1
        for sl in self._slices:
            decoders = self._decoders.get(sl.slave)
            if decoders is None:
                continue
            inputs = decoders[0].decode(image[sl.input_offset : sl.input_offset + sl.input_bytes])
            outputs = decoders[1].decode(
                image[sl.output_offset : sl.output_offset + sl.output_bytes]
            )
            inputs_by_slave[sl.slave] = inputs
            for topic, values in (("pdo_in", inputs), ("pdo_out", outputs)):
                if not values:
                    continue
                msg = SlaveValues()
                msg.header.stamp = stamp
                msg.header.frame_id = sl.slave
                msg.slave = sl.slave
                msg.position = self._positions.get(sl.slave, 0)
                msg.cycle = cycle
                msg.values = values
                msg.stale = topic == "pdo_in" and sl.slave in stale_slaves
                self._pub[topic].publish(msg)
        if self._joints or self._axis_joints is not None:
            joint_state = self._joint_state(stamp, image, inputs_by_slave, stale_slaves)
            if joint_state.name:  # every joint stale: no message at all
                self._pub["joint_states"].publish(joint_state)
        if self._axis_extras is not None or self._axis_states is not None:
            extras = self._joint_extras(stamp, stale_slaves)
            if extras.joints or extras.axes:  # nothing to report: no message at all
                self._pub["joint_extras"].publish(extras)
        self.counters.published_decoded += 1

    def _joint_extras(self, stamp: Time, stale: set[str]) -> JointExtras:
        """The extras of the axes whose slave's inputs are fresh (as ``joint_states``)."""
        msg = JointExtras()
        msg.header.stamp = stamp
        msg.header.frame_id = self._spec.bus
        entries = [
            entry
            for entry in (self._axis_extras() if self._axis_extras is not None else [])
            if self._axis_slaves.get(entry[0]) not in stale
        ]
        msg.joints = [joint for joint, _, _ in entries]
        msg.names = [name for _, name, _ in entries]
        msg.values = [value for _, _, value in entries]
        # Every axis's state, also of an axis whose inputs are stale: the engine's own view
        # (a stale axis is stopped by its group's watchdog, which its state then says).
        states = self._axis_states() if self._axis_states is not None else []
        msg.axes = [s.joint for s in states]
        msg.states = [s.state for s in states]
        msg.enable_wanted = [s.enable_wanted for s in states]
        msg.mode_reached = [s.mode_reached for s in states]
        msg.restart_blocked = [s.restart_blocked for s in states]
        msg.limit_active = [s.limit_active for s in states]
        msg.outside_limits = [s.outside_limits for s in states]
        msg.stopped_by = [s.stopped_by for s in states]
        msg.blocked = [s.blocked for s in states]
        return msg

    def _joint_state(
        self,
        stamp: Time,
        image: bytes,
        inputs: dict[str, list[float]],
        stale: set[str] | None = None,
    ) -> JointState:
        """The joints whose slave's inputs are fresh (all of them when ``stale`` is empty)."""
        stale = stale or set()
        msg = JointState()
        msg.header.stamp = stamp
        names, pos, vel, eff = [], [], [], []
        with_velocity = all(j.velocity for j in self._joints)
        with_effort = all(j.effort for j in self._joints)

        def raw(slave: str, variable: str | None) -> float:
            index = self._input_names.get(slave, {}).get(variable or "")
            values = inputs.get(slave)
            return values[index] if values is not None and index is not None else 0.0

        for j in self._joints:
            if j.slave in stale:
                continue
            names.append(j.name)
            pos.append(raw(j.slave, j.position) * j.position_scale + j.position_offset)
            if with_velocity:
                vel.append(raw(j.slave, j.velocity) * j.velocity_scale)
            if with_effort:
                eff.append(raw(j.slave, j.effort) * j.effort_scale)
        if self._axis_joints is not None:
            for name, p, v, e in self._axis_joints(image):
                if self._axis_slaves.get(name) in stale:
                    continue
                names.append(name)
                pos.append(p)
                if with_velocity:
                    vel.append(v)
                if with_effort:
                    eff.append(e)
        msg.name = names
        msg.position = pos
        msg.velocity = vel
        msg.effort = eff
        return msg
