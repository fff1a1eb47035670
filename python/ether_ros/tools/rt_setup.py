"""``rt setup``: apply the runtime part of the host tuning, and take it back.

What it changes (all at runtime, all undoable; boot parameters such as isolcpus are only reported
by ``rt check``):

- a cgroup v2 cpuset partition of type ``isolated`` holding the RT CPU (the thesis used a cgroup
  v1 cpuset with load balancing off; an isolated v2 partition is the same thing in one file);
- IRQ affinity: the EtherCAT NIC's IRQs onto the RT CPU, every other IRQ off it, and the default
  affinity for new IRQs to the housekeeping CPUs (Appendix A);
- RPS/XPS of the EtherCAT interface's queues onto the RT CPU (Appendix A);
- RT throttling off (``sched_rt_runtime_us = -1``, Appendix A);
- the ``performance`` governor and no deep idle states on the RT CPU (chapter 5.3.3);
- interrupt coalescing off on the NIC (the thesis reloaded e1000e with InterruptThrottleRate=0).

Without ``--apply`` it only prints what it would write. With it, each change's previous value goes
into an undo file (JSON), saved after every step so an interrupted run can still be undone; a
value it cannot read first is left alone, because it could not be put back.
"""

from __future__ import annotations

import json
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ether_ros.tools.host import (
    Ethtool,
    Host,
    HostError,
    format_cpu_list,
    format_cpu_mask,
    parse_cpu_list,
    parse_cpu_mask,
)
from ether_ros.tools.rt_check import IRQ_PRIORITY_MARGIN, MAX_CSTATE_LATENCY_US

SCHED_FIFO = 1

CGROUP = "/sys/fs/cgroup"
PARTITION = f"{CGROUP}/ether_ros_rt"
UNDO_FORMAT = "ether_ros rt setup undo"


@dataclass
class Step:
    """One change: ``kind`` is write (a file), mkdir (a cgroup), controller (enable a cgroup
    controller in the root), ethtool (coalescing settings) or sched (a thread's policy and
    priority; ``target`` is the pid, ``value`` and ``current`` are [policy, priority])."""

    kind: str
    target: str
    value: Any
    why: str
    current: Any = None  # what is there now (None: nothing / not readable)

    def describe(self) -> str:
        if self.kind == "write":
            now = "absent" if self.current is None else self.current
            return f"write {self.value} > {self.target} (now {now}): {self.why}"
        if self.kind == "mkdir":
            return f"mkdir {self.target}: {self.why}"
        if self.kind == "controller":
            return f"write +{self.value} > {self.target}: {self.why}"
        if self.kind == "sched":
            return (
                f"chrt -f -p {self.value[1]} {self.target} (now policy {self.current[0]}, "
                f"priority {self.current[1]}): {self.why}"
            )
        settings = " ".join(f"{k} {v}" for k, v in self.value.items())
        return f"ethtool -C {self.target} {settings}: {self.why}"


@dataclass
class Plan:
    cpu: int
    interface: str
    housekeeping: set[int]
    steps: list[Step] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def make_plan(host: Host, cpu: int, interface: str, priority: int = 80) -> Plan:
    online = host.online_cpus()
    if cpu not in online:
        raise HostError(f"CPU {cpu} is not online (online: {format_cpu_list(online) or 'none'})")
    if not host.exists(f"/sys/class/net/{interface}"):
        raise HostError(
            f"network interface {interface!r} not found under {host.path('/sys/class/net')}"
        )
    already = parse_cpu_list(host.read_strip("/sys/devices/system/cpu/isolated") or "")
    housekeeping = online - {cpu} - already
    if not housekeeping:
        raise HostError(
            f"isolating CPU {cpu} would leave no housekeeping CPU "
            f"(online {format_cpu_list(online)}, already isolated "
            f"{format_cpu_list(already) or 'none'})"
        )
    plan = Plan(cpu, interface, housekeeping)
    _plan_partition(host, plan)
    _plan_irqs(host, plan)
    _plan_irq_threads(host, plan, priority)
    _plan_steering(host, plan)
    _plan_write(
        host,
        plan,
        "/proc/sys/kernel/sched_rt_runtime_us",
        "-1",
        "RT throttling off (the RT thread owns its CPU)",
    )
    _plan_power(host, plan)
    _plan_coalescing(host, plan)
    return plan


def _plan_write(host: Host, plan: Plan, path: str, value: str, why: str) -> None:
    current = host.read_strip(path)
    if current is None:
        if host.exists(path):
            plan.notes.append(f"{path} is not readable: left alone (could not be undone)")
        return
    if current != value:
        plan.steps.append(Step("write", path, value, why, current))


def _plan_partition(host: Host, plan: Plan) -> None:
    controllers = host.read_strip(f"{CGROUP}/cgroup.controllers")
    if controllers is None or "cpuset" not in controllers.split():
        plan.notes.append(
            f"cgroup v2 with the cpuset controller is not mounted at {CGROUP}: no "
            f"isolated partition (boot with isolcpus={plan.cpu} instead)"
        )
        return
    if host.exists(PARTITION):
        plan.notes.append(f"{PARTITION} exists already: partition left as it is")
        return
    enabled = (host.read_strip(f"{CGROUP}/cgroup.subtree_control") or "").split()
    if "cpuset" not in enabled:
        plan.steps.append(
            Step(
                "controller",
                f"{CGROUP}/cgroup.subtree_control",
                "cpuset",
                "let child cgroups own CPUs",
            )
        )
    plan.steps.append(Step("mkdir", PARTITION, None, "the real-time partition"))
    plan.steps.append(
        Step("write", f"{PARTITION}/cpuset.cpus", str(plan.cpu), "the RT CPU alone in it")
    )
    plan.steps.append(
        Step(
            "write",
            f"{PARTITION}/cpuset.cpus.partition",
            "isolated",
            "no load balancing, no other task on the RT CPU",
        )
    )


def _plan_irqs(host: Host, plan: Plan) -> None:
    nic = host.interface_irqs(plan.interface)
    hk_list = format_cpu_list(plan.housekeeping)
    default = host.read_strip("/proc/irq/default_smp_affinity")
    if default is not None and parse_cpu_mask(default) != plan.housekeeping:
        plan.steps.append(
            Step(
                "write",
                "/proc/irq/default_smp_affinity",
                format_cpu_mask(plan.housekeeping),
                "new IRQs on the housekeeping CPUs",
                default,
            )
        )
    for irq in host.all_irqs():
        path = f"/proc/irq/{irq}/smp_affinity_list"
        current = host.read_strip(path)
        if current is None:
            continue
        cpus = parse_cpu_list(current)
        if irq in nic:
            if cpus != {plan.cpu}:
                plan.steps.append(
                    Step(
                        "write",
                        path,
                        str(plan.cpu),
                        f"{nic[irq]} (EtherCAT NIC) onto the RT CPU",
                        current,
                    )
                )
        elif plan.cpu in cpus:
            plan.steps.append(Step("write", path, hk_list, "off the RT CPU", current))
    if not nic:
        plan.notes.append(f"{plan.interface} raises no hardware IRQ (virtual interface)")


def _plan_irq_threads(host: Host, plan: Plan, priority: int) -> None:
    """The NIC's IRQ threads (PREEMPT_RT or threadirqs) above the RT thread's priority."""
    irqs = host.interface_irqs(plan.interface)
    if not irqs:
        return
    target = min(priority + IRQ_PRIORITY_MARGIN, 99)
    for t in host.threads():
        m = re.match(r"irq/(\d+)-", t.comm)
        if not m or int(m.group(1)) not in irqs:
            continue
        if t.policy == SCHED_FIFO and t.rt_priority >= target:
            continue
        plan.steps.append(
            Step(
                "sched",
                str(t.pid),
                [SCHED_FIFO, target],
                f"{t.comm} above the RT thread ({priority})",
                [t.policy, t.rt_priority],
            )
        )


def _plan_steering(host: Host, plan: Plan) -> None:
    mask = format_cpu_mask({plan.cpu})
    base = f"sys/class/net/{plan.interface}/queues"
    for path in host.glob(f"{base}/rx-*/rps_cpus") + host.glob(f"{base}/tx-*/xps_cpus"):
        current = host.read_strip(path)
        if current is not None and parse_cpu_mask(current) != {plan.cpu}:
            kind = "RPS" if path.endswith("rps_cpus") else "XPS"
            plan.steps.append(Step("write", path, mask, f"{kind} onto the RT CPU", current))


def _plan_power(host: Host, plan: Plan) -> None:
    cpu_dir = f"/sys/devices/system/cpu/cpu{plan.cpu}"
    available = host.read_strip(f"{cpu_dir}/cpufreq/scaling_available_governors") or ""
    if "performance" in available.split():
        _plan_write(
            host,
            plan,
            f"{cpu_dir}/cpufreq/scaling_governor",
            "performance",
            "no frequency changes on the RT CPU",
        )
    for state in host.glob(f"{cpu_dir.lstrip('/')}/cpuidle/state[0-9]*"):
        latency = host.read_strip(f"{state}/latency")
        if latency is not None and int(latency) > MAX_CSTATE_LATENCY_US:
            name = host.read_strip(f"{state}/name") or state
            _plan_write(
                host, plan, f"{state}/disable", "1", f"no {name} ({latency} µs exit) on the RT CPU"
            )


def _plan_coalescing(host: Host, plan: Plan) -> None:
    settings = Ethtool(host).get(plan.interface)
    if settings is None:
        plan.notes.append(
            "coalescing: ethtool not available"
            if host.is_live
            else "coalescing: no ethtool fixture file"
        )
        return
    if not settings.supported:
        return
    wanted: dict[str, str] = {}
    for key, value in settings.values.items():
        if key.startswith("adaptive") and value == "on":
            wanted[key] = "off"
        elif key.endswith("usecs") and value.isdigit() and value != "0":
            wanted[key] = "0"
        elif key.endswith("frames") and value.isdigit() and int(value) > 1:
            wanted[key] = "1"
    if wanted:
        previous = {k: settings.values[k] for k in wanted}
        plan.steps.append(
            Step(
                "ethtool",
                plan.interface,
                wanted,
                "every frame raises its interrupt at once",
                previous,
            )
        )


# ---- apply and undo ------------------------------------------------------------------------


def apply_plan(host: Host, plan: Plan, undo_file: Path) -> list[str]:
    """Make the changes, recording each one's previous value in ``undo_file`` as it goes.

    Returns the problems met (a step that failed is reported and the rest still run: an IRQ the
    kernel refuses to move must not stop the others).
    """
    if undo_file.exists():
        raise HostError(
            f"undo file {undo_file} exists: undo it first (--undo {undo_file}) or "
            "choose another with --undo-file"
        )
    record: dict[str, Any] = {
        "format": UNDO_FORMAT,
        "version": 1,
        "root": str(host.root.resolve()),
        "cpu": plan.cpu,
        "interface": plan.interface,
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "changes": [],
    }
    problems: list[str] = []
    created_dirs: set[str] = set()
    _save(undo_file, record)
    for step in plan.steps:
        try:
            change = _apply_step(host, step, created_dirs)
        except HostError as exc:
            problems.append(str(exc))
            continue
        if change is not None:
            record["changes"].append(change)
            _save(undo_file, record)
    return problems


def _apply_step(host: Host, step: Step, created_dirs: set[str]) -> dict[str, Any] | None:
    if step.kind == "mkdir":
        host.mkdir(step.target)
        created_dirs.add(step.target)
        return {"kind": "mkdir", "path": step.target}
    if step.kind == "controller":
        enable_controller(host, step.target, step.value, enable=True)
        return {"kind": "controller", "path": step.target, "controller": step.value}
    if step.kind == "ethtool":
        Ethtool(host).set(step.target, step.value)
        return {"kind": "ethtool", "interface": step.target, "previous": step.current}
    if step.kind == "sched":
        host.set_sched(int(step.target), step.value[0], step.value[1])
        return {"kind": "sched", "pid": int(step.target), "previous": list(step.current)}
    inside_new = any(step.target.startswith(d + "/") for d in created_dirs)
    if inside_new:
        # Control files of a cgroup we made go away with it; nothing to restore.
        host.write(step.target, step.value)
        return None
    # Read again right before writing: the value to restore is the one there now.
    previous = host.read_strip(step.target)
    if previous is None:
        raise HostError(f"{step.target} is not readable: left alone")
    host.write(step.target, step.value)
    return {"kind": "write", "path": step.target, "previous": previous}


def enable_controller(host: Host, path: str, controller: str, enable: bool) -> None:
    if host.is_live:
        host.write(path, ("+" if enable else "-") + controller)
        return
    # A fixture file holds the list itself; edit it the way the kernel would.
    names = (host.read_strip(path) or "").split()
    names = [n for n in names if n != controller] + ([controller] if enable else [])
    host.write(path, " ".join(names) + "\n")


def _save(undo_file: Path, record: dict[str, Any]) -> None:
    tmp = undo_file.with_name(undo_file.name + ".tmp")
    try:
        tmp.write_text(json.dumps(record, indent=2) + "\n")
        tmp.replace(undo_file)
    except OSError as exc:
        raise HostError(f"cannot write undo file {undo_file}: {exc.strerror}") from exc


def load_undo(undo_file: Path) -> dict[str, Any]:
    try:
        record = json.loads(undo_file.read_text())
    except FileNotFoundError as exc:
        raise HostError(f"undo file {undo_file} does not exist") from exc
    except (OSError, ValueError) as exc:
        raise HostError(f"undo file {undo_file} is not readable JSON: {exc}") from exc
    if not isinstance(record, dict) or record.get("format") != UNDO_FORMAT:
        raise HostError(f"{undo_file} is not an ether-ros rt setup undo file")
    if not isinstance(record.get("changes"), list):
        raise HostError(f"undo file {undo_file} has no list of changes")
    return record


def undo(host: Host, undo_file: Path) -> list[str]:
    """Restore every recorded change, newest first. Returns the problems met."""
    record = load_undo(undo_file)
    if record.get("root") != str(host.root.resolve()):
        raise HostError(
            f"undo file {undo_file} was recorded for root {record.get('root')!r}, "
            f"not {str(host.root.resolve())!r}"
        )
    problems: list[str] = []
    for change in reversed(record["changes"]):
        try:
            kind = change["kind"]
            if kind == "write":
                host.write(change["path"], str(change["previous"]))
            elif kind == "mkdir":
                host.rmdir(change["path"])
            elif kind == "controller":
                enable_controller(host, change["path"], change["controller"], enable=False)
            elif kind == "ethtool":
                Ethtool(host).set(change["interface"], dict(change["previous"]))
            elif kind == "sched":
                policy, prio = change["previous"]
                host.set_sched(int(change["pid"]), int(policy), int(prio))
            else:
                problems.append(f"unknown change kind {kind!r} in {undo_file}")
        except HostError as exc:
            problems.append(str(exc))
        except (KeyError, TypeError) as exc:
            problems.append(f"malformed change {change!r} in {undo_file}: {exc}")
    if not problems:
        undo_file.unlink()
    return problems
