"""``rt check``: is this host ready for a 2.5 kHz+ EtherCAT cycle?

Each check reads a few files under the host root and gives pass / warn / fail / skip with what
was found and the fix. The list follows the thesis's chapter 5.3 and Appendix A (PREEMPT_RT,
isolation, power management, interrupt placement, RT throttling), plus what a user-space master
needs of its own process (capabilities, locked memory, timer slack).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

from ether_ros.tools.host import (
    POLICY_NAMES,
    Ethtool,
    Host,
    HostError,
    format_cpu_list,
    parse_cpu_list,
    parse_cpu_mask,
)

PASS, WARN, FAIL, SKIP = "pass", "warn", "fail", "skip"

CAP_NET_RAW, CAP_IPC_LOCK, CAP_SYS_NICE = 13, 14, 23

# A C-state whose exit latency exceeds this may land on top of a cycle's wake-up.
MAX_CSTATE_LATENCY_US = 10
# NIC IRQ threads run this much above the RT thread: they deliver the frame it waits for.
IRQ_PRIORITY_MARGIN = 5
# Locked memory the master needs without CAP_IPC_LOCK: the RT stack, rings and buffers.
MIN_MEMLOCK_BYTES = 64 * 1024 * 1024


@dataclass
class Check:
    name: str
    status: str
    found: str
    fix: str = ""


@dataclass
class CheckOptions:
    interface: str | None = None
    cpu: int | None = None
    priority: int = 80  # the engine's RT thread priority (bus config realtime.priority)
    policy: str = "fifo"


@dataclass
class Report:
    checks: list[Check] = field(default_factory=list)

    @property
    def worst(self) -> str:
        statuses = {c.status for c in self.checks}
        for status in (FAIL, WARN, PASS):
            if status in statuses:
                return status
        return SKIP

    def as_dict(self) -> dict[str, object]:
        return {"result": self.worst, "checks": [asdict(c) for c in self.checks]}


def run_checks(host: Host, options: CheckOptions) -> Report:
    online = host.online_cpus()
    if options.cpu is not None and online and options.cpu not in online:
        raise HostError(f"CPU {options.cpu} is not online (online: {format_cpu_list(online)})")
    if options.interface is not None and not host.exists(f"/sys/class/net/{options.interface}"):
        raise HostError(
            f"network interface {options.interface!r} not found under {host.path('/sys/class/net')}"
        )
    checks: list[Callable[[Host, CheckOptions], Check]] = [
        check_preemption,
        check_isolation,
        check_nohz_full,
        check_rcu_nocbs,
        check_governor,
        check_cstates,
        check_irqbalance,
        check_nic_irq_affinity,
        check_irq_threads,
        check_rps_xps,
        check_coalescing,
        check_rt_throttling,
        check_memlock,
        check_capabilities,
        check_timer_slack,
    ]
    return Report([check(host, options) for check in checks])


def _target_cpus(host: Host, options: CheckOptions) -> set[int]:
    if options.cpu is not None:
        return {options.cpu}
    return host.online_cpus()


# ---- kernel -------------------------------------------------------------------------------


def check_preemption(host: Host, options: CheckOptions) -> Check:
    name = "preemption model"
    fix = "boot a PREEMPT_RT kernel (e.g. linux-image-rt; mainline >= 6.12 with CONFIG_PREEMPT_RT)"
    if host.read_strip("/sys/kernel/realtime") == "1":
        return Check(name, PASS, "PREEMPT_RT (/sys/kernel/realtime = 1)")
    version = host.read_strip("/proc/version") or ""
    if "PREEMPT_RT" in version:
        return Check(name, PASS, "PREEMPT_RT (/proc/version)")
    dynamic = host.read_strip("/sys/kernel/debug/sched/preempt")
    if dynamic:
        # "none voluntary (full) lazy": the active model is in parentheses.
        m = re.search(r"\((\w+)\)", dynamic)
        active = m.group(1) if m else dynamic
        if active == "full":
            return Check(name, WARN, "PREEMPT_DYNAMIC, full preemption (not PREEMPT_RT)", fix)
        return Check(
            name,
            FAIL,
            f"PREEMPT_DYNAMIC, {active} preemption",
            "boot with preempt=full at least; better: " + fix,
        )
    if "PREEMPT_DYNAMIC" in version:
        return Check(
            name,
            WARN,
            "PREEMPT_DYNAMIC (active model unknown: debugfs not mounted)",
            "mount debugfs to see it, boot with preempt=full; better: " + fix,
        )
    if re.search(r"\bPREEMPT\b", version):
        return Check(name, WARN, "low-latency desktop preemption (PREEMPT), not PREEMPT_RT", fix)
    return Check(
        name,
        FAIL,
        "no kernel preemption (server kernel)"
        if version
        else "unknown: /proc/version not readable",
        fix,
    )


def _isolated_partition_cpus(host: Host) -> set[int]:
    """CPUs in cgroup v2 cpuset partitions of type "isolated" (what `rt setup` creates)."""
    cpus: set[int] = set()
    for path in host.glob("sys/fs/cgroup/*/cpuset.cpus.partition"):
        if (host.read_strip(path) or "").startswith("isolated"):
            base = path.rsplit("/", 1)[0]
            effective = host.read_strip(f"{base}/cpuset.cpus.effective")
            if effective is None:
                effective = host.read_strip(f"{base}/cpuset.cpus") or ""
            cpus |= parse_cpu_list(effective)
    return cpus


def check_isolation(host: Host, options: CheckOptions) -> Check:
    name = "CPU isolation"
    cmdline = host.cmdline()
    boot = set()
    if "isolcpus" in cmdline:
        # isolcpus=[flags,]list, flags like "nohz,domain,managed_irq"
        parts = [p for p in cmdline["isolcpus"].split(",") if p and (p[0].isdigit())]
        boot = parse_cpu_list(",".join(parts))
    sysfs = parse_cpu_list(host.read_strip("/sys/devices/system/cpu/isolated") or "")
    partition = _isolated_partition_cpus(host)
    isolated = boot | sysfs | partition
    online = host.online_cpus()
    cpu = options.cpu
    target = "the RT CPU" if cpu is None else f"CPU {cpu}"
    fix = (
        f"boot with isolcpus={cpu if cpu is not None else 'N'} (or run `ether-ros rt setup "
        f"--cpu {cpu if cpu is not None else 'N'} --apply` for a cgroup v2 isolated partition)"
    )
    if online and isolated >= online:
        return Check(
            name,
            FAIL,
            f"every CPU is isolated ({format_cpu_list(isolated)}): no housekeeping CPU left",
            "leave at least one CPU out of isolcpus",
        )
    sources = []
    if boot or sysfs:
        sources.append(f"isolcpus {format_cpu_list(boot | sysfs)}")
    if partition:
        sources.append(f"cgroup partition {format_cpu_list(partition)}")
    if cpu is None:
        if isolated:
            return Check(name, PASS, "; ".join(sources))
        return Check(name, WARN, "no CPU isolated", fix)
    if cpu in isolated:
        return Check(name, PASS, f"CPU {cpu} isolated ({'; '.join(sources)})")
    found = f"{target} not isolated" + (f" ({'; '.join(sources)})" if sources else "")
    return Check(name, WARN, found, fix)


def _cmdline_cpus_cover(host: Host, param: str, options: CheckOptions) -> tuple[set[int], bool]:
    cpus = parse_cpu_list(host.cmdline().get(param, ""))
    if param == "nohz_full":
        cpus |= parse_cpu_list(host.read_strip("/sys/devices/system/cpu/nohz_full") or "")
    wanted = _target_cpus(host, options) if options.cpu is not None else set()
    covered = bool(cpus) and (not wanted or wanted <= cpus)
    return cpus, covered


def check_nohz_full(host: Host, options: CheckOptions) -> Check:
    cpus, covered = _cmdline_cpus_cover(host, "nohz_full", options)
    n = options.cpu if options.cpu is not None else "N"
    if covered:
        return Check("full dynamic ticks", PASS, f"nohz_full={format_cpu_list(cpus)}")
    found = f"nohz_full={format_cpu_list(cpus)}" if cpus else "scheduler tick on every CPU"
    return Check(
        "full dynamic ticks",
        WARN,
        found,
        f"boot with nohz_full={n} (the RT thread is alone on its CPU)",
    )


def check_rcu_nocbs(host: Host, options: CheckOptions) -> Check:
    cpus, covered = _cmdline_cpus_cover(host, "rcu_nocbs", options)
    n = options.cpu if options.cpu is not None else "N"
    if covered:
        return Check("RCU callbacks offloaded", PASS, f"rcu_nocbs={format_cpu_list(cpus)}")
    found = f"rcu_nocbs={format_cpu_list(cpus)}" if cpus else "RCU callbacks run on every CPU"
    return Check("RCU callbacks offloaded", WARN, found, f"boot with rcu_nocbs={n}")


# ---- power management ---------------------------------------------------------------------


def check_governor(host: Host, options: CheckOptions) -> Check:
    name = "CPU frequency governor"
    governors: dict[int, str] = {}
    for cpu in sorted(_target_cpus(host, options)):
        value = host.read_strip(f"/sys/devices/system/cpu/cpu{cpu}/cpufreq/scaling_governor")
        if value is not None:
            governors[cpu] = value
    if not governors:
        return Check(name, PASS, "no cpufreq: the CPU runs at a fixed frequency")
    slow = {cpu: g for cpu, g in governors.items() if g != "performance"}
    listed = ", ".join(f"cpu{c}={g}" for c, g in governors.items())
    if not slow:
        return Check(name, PASS, listed)
    cpus = format_cpu_list(slow)
    return Check(
        name,
        WARN,
        listed,
        f"`ether-ros rt setup --apply` or: echo performance > "
        f"/sys/devices/system/cpu/cpu{{{cpus}}}/cpufreq/scaling_governor",
    )


def check_cstates(host: Host, options: CheckOptions) -> Check:
    name = "CPU idle states"
    cmdline = host.cmdline()
    if cmdline.get("idle") == "poll":
        return Check(name, PASS, "idle=poll: the CPU never sleeps")
    deep: list[str] = []
    for cpu in sorted(_target_cpus(host, options)):
        for state in host.glob(f"sys/devices/system/cpu/cpu{cpu}/cpuidle/state[0-9]*"):
            latency = host.read_strip(f"{state}/latency")
            if host.read_strip(f"{state}/disable") == "1" or latency is None:
                continue
            if int(latency) > MAX_CSTATE_LATENCY_US:
                label = host.read_strip(f"{state}/name") or state.rsplit("/", 1)[1]
                deep.append(f"cpu{cpu} {label} ({latency} µs)")
    limits = [
        f"{k}={cmdline[k]}"
        for k in ("intel_idle.max_cstate", "processor.max_cstate")
        if k in cmdline
    ]
    if not deep:
        found = f"no enabled idle state with exit latency > {MAX_CSTATE_LATENCY_US} µs"
        return Check(name, PASS, found + (f" ({', '.join(limits)})" if limits else ""))
    shown = ", ".join(deep[:4]) + (f" and {len(deep) - 4} more" if len(deep) > 4 else "")
    holders = host.holders("/dev/cpu_dma_latency")
    if holders:
        # A process holding /dev/cpu_dma_latency open keeps the CPUs out of states slower than
        # the latency it wrote (tuned, the master itself, cyclictest do this).
        pids = ", ".join(map(str, holders[:3]))
        return Check(
            name,
            PASS,
            f"deep idle states enabled ({shown}) but /dev/cpu_dma_latency "
            f"is held open (pid {pids})",
        )
    return Check(
        name,
        WARN,
        f"deep idle states enabled: {shown}",
        "`ether-ros rt setup --apply` disables them on the RT CPU; or boot with "
        "intel_idle.max_cstate=1 processor.max_cstate=1; or hold /dev/cpu_dma_latency "
        "open with 0",
    )


# ---- interrupts and the network path ------------------------------------------------------


def check_irqbalance(host: Host, options: CheckOptions) -> Check:
    running = [t.pid for t in host.threads() if t.comm == "irqbalance"]
    if running:
        return Check(
            "irqbalance",
            WARN,
            f"running (pid {running[0]}): it moves IRQs back",
            "systemctl disable --now irqbalance (or IRQBALANCE_BANNED_CPULIST=<RT CPU>)",
        )
    return Check("irqbalance", PASS, "not running")


def check_nic_irq_affinity(host: Host, options: CheckOptions) -> Check:
    name = "NIC IRQ affinity"
    if options.interface is None:
        return Check(name, SKIP, "no --interface given")
    irqs = host.interface_irqs(options.interface)
    if not irqs:
        return Check(name, PASS, f"{options.interface} raises no hardware IRQ (virtual interface)")
    found: list[str] = []
    wrong: list[int] = []
    for irq in sorted(irqs):
        text = host.read_strip(f"/proc/irq/{irq}/smp_affinity_list")
        cpus = parse_cpu_list(text) if text is not None else set()
        found.append(f"{irq}:{format_cpu_list(cpus) or '?'}")
        if options.cpu is not None and cpus != {options.cpu}:
            wrong.append(irq)
    listed = f"{options.interface} IRQ:CPUs {' '.join(found)}"
    if options.cpu is None:
        return Check(name, SKIP, listed + " (no --cpu to compare with)")
    if not wrong:
        return Check(name, PASS, listed)
    return Check(
        name,
        WARN,
        listed,
        f"`ether-ros rt setup --apply`, or echo {options.cpu} > "
        f"/proc/irq/{wrong[0]}/smp_affinity_list (for each of "
        f"{', '.join(map(str, wrong))})",
    )


def check_irq_threads(host: Host, options: CheckOptions) -> Check:
    name = "NIC IRQ thread priority"
    if options.interface is None:
        return Check(name, SKIP, "no --interface given")
    irqs = host.interface_irqs(options.interface)
    if not irqs:
        return Check(name, PASS, f"{options.interface} raises no hardware IRQ (virtual interface)")
    threads = [
        t
        for t in host.threads()
        if (m := re.match(r"irq/(\d+)-", t.comm)) and int(m.group(1)) in irqs
    ]
    if not threads:
        return Check(
            name,
            WARN,
            "IRQs are not threaded: the handler runs in hard-IRQ context "
            "and its softirq wherever it lands",
            "boot a PREEMPT_RT kernel or add threadirqs to the kernel command line",
        )
    low = [t for t in threads if t.policy not in (1, 2) or t.rt_priority <= options.priority]
    listed = " ".join(
        f"{t.comm}={POLICY_NAMES.get(t.policy, t.policy)}/{t.rt_priority}" for t in threads
    )
    if not low:
        return Check(name, PASS, listed)
    # The NIC's IRQ thread delivers the frame the RT thread waits for: it must not be starved by
    # the RT thread it serves.
    return Check(
        name,
        WARN,
        listed + f" (RT thread priority {options.priority})",
        f"`ether-ros rt setup --apply`, or chrt -f -p "
        f"{min(options.priority + IRQ_PRIORITY_MARGIN, 99)} {low[0].pid} (for each NIC IRQ "
        "thread; again after reloading the driver)",
    )


def check_rps_xps(host: Host, options: CheckOptions) -> Check:
    name = "RPS/XPS"
    if options.interface is None:
        return Check(name, SKIP, "no --interface given")
    base = f"sys/class/net/{options.interface}/queues"
    entries: list[str] = []
    bad: list[str] = []
    for path in host.glob(f"{base}/rx-*/rps_cpus") + host.glob(f"{base}/tx-*/xps_cpus"):
        text = host.read_strip(path)
        if text is None:
            continue
        cpus = parse_cpu_mask(text)
        queue = "/".join(path.rsplit("/", 2)[1:])
        entries.append(f"{queue}={format_cpu_list(cpus) or 'off'}")
        # Empty (off) keeps the packet on the CPU that took the IRQ; anything else must be the
        # RT CPU, as in the thesis's Appendix A.
        if cpus and options.cpu is not None and cpus != {options.cpu}:
            bad.append(queue)
    if not entries:
        return Check(name, PASS, "no steering files (single-queue or virtual interface)")
    listed = ", ".join(entries)
    if not bad:
        return Check(name, PASS, listed)
    return Check(
        name,
        WARN,
        listed,
        f"`ether-ros rt setup --apply`, or write {1 << (options.cpu or 0):x} to "
        f"/sys/class/net/{options.interface}/queues/{bad[0]}",
    )


def check_coalescing(host: Host, options: CheckOptions) -> Check:
    name = "interrupt coalescing"
    if options.interface is None:
        return Check(name, SKIP, "no --interface given")
    settings = Ethtool(host).get(options.interface)
    if settings is None:
        where = "no ethtool fixture file" if not host.is_live else "ethtool not available"
        return Check(name, SKIP, where)
    if not settings.supported:
        return Check(name, PASS, f"{options.interface} has no coalescing (not supported)")
    v = settings.values
    delays = [k for k in ("rx-usecs", "tx-usecs") if v.get(k, "0") not in ("0", "n/a")]
    batches = [k for k in ("rx-frames", "tx-frames") if v.get(k, "0") not in ("0", "1", "n/a")]
    adaptive = [k for k in ("adaptive-rx", "adaptive-tx") if v.get(k) == "on"]
    listed = ", ".join(f"{k} {v[k]}" for k in v)
    if not (delays or batches or adaptive):
        return Check(name, PASS, listed)
    return Check(
        name,
        WARN,
        listed,
        f"`ether-ros rt setup --apply`, or ethtool -C {options.interface} adaptive-rx "
        "off rx-usecs 0 rx-frames 1 (e1000e: InterruptThrottleRate=0)",
    )


# ---- scheduler and the master process -----------------------------------------------------


def check_rt_throttling(host: Host, options: CheckOptions) -> Check:
    name = "RT throttling"
    runtime = host.read_strip("/proc/sys/kernel/sched_rt_runtime_us")
    period = host.read_strip("/proc/sys/kernel/sched_rt_period_us") or "1000000"
    if runtime is None:
        return Check(name, SKIP, "/proc/sys/kernel/sched_rt_runtime_us not readable")
    if runtime == "-1":
        return Check(name, PASS, "off (sched_rt_runtime_us = -1)")
    return Check(
        name,
        WARN,
        f"RT tasks limited to {runtime} of every {period} µs",
        "`ether-ros rt setup --apply`, or echo -1 > /proc/sys/kernel/sched_rt_runtime_us",
    )


def _capabilities(host: Host) -> int | None:
    for line in (host.read("/proc/self/status") or "").splitlines():
        if line.startswith("CapEff:"):
            return int(line.split()[1], 16)
    return None


def _memlock_limit(host: Host) -> int | None:
    """The soft RLIMIT_MEMLOCK in bytes (-1: unlimited), from /proc/self/limits."""
    for line in (host.read("/proc/self/limits") or "").splitlines():
        if line.startswith("Max locked memory"):
            soft = line[len("Max locked memory") :].split()[0]
            return -1 if soft == "unlimited" else int(soft)
    return None


def check_memlock(host: Host, options: CheckOptions) -> Check:
    name = "locked memory limit"
    limit = _memlock_limit(host)
    caps = _capabilities(host)
    if limit is None:
        return Check(name, SKIP, "/proc/self/limits not readable")
    shown = "unlimited" if limit < 0 else f"{limit // 1024} KiB"
    if limit < 0 or limit >= MIN_MEMLOCK_BYTES:
        return Check(name, PASS, shown)
    if caps is not None and caps >> CAP_IPC_LOCK & 1:
        return Check(name, PASS, f"{shown}, but CAP_IPC_LOCK lifts it")
    return Check(
        name,
        FAIL,
        f"{shown}: mlockall of the master will fail",
        "ulimit -l unlimited, or @realtime - memlock unlimited in "
        "/etc/security/limits.conf, or LimitMEMLOCK=infinity in the systemd unit",
    )


def check_capabilities(host: Host, options: CheckOptions) -> Check:
    name = "capabilities"
    caps = _capabilities(host)
    if caps is None:
        return Check(name, SKIP, "/proc/self/status not readable")
    wanted = {
        "CAP_NET_RAW": CAP_NET_RAW,
        "CAP_SYS_NICE": CAP_SYS_NICE,
        "CAP_IPC_LOCK": CAP_IPC_LOCK,
    }
    missing = [n for n, bit in wanted.items() if not caps >> bit & 1]
    if not missing:
        return Check(name, PASS, "CAP_NET_RAW, CAP_SYS_NICE, CAP_IPC_LOCK")
    # Without NET_RAW no raw socket; without SYS_NICE no SCHED_FIFO. IPC_LOCK is covered by a
    # large enough memlock limit.
    status = FAIL if {"CAP_NET_RAW", "CAP_SYS_NICE"} & set(missing) else WARN
    return Check(
        name,
        status,
        "missing " + ", ".join(missing),
        "run as root, or: setcap cap_net_raw,cap_sys_nice,cap_ipc_lock+ep "
        "$(readlink -f $(which python3))",
    )


def check_timer_slack(host: Host, options: CheckOptions) -> Check:
    name = "timer slack"
    text = host.read_strip("/proc/self/timerslack_ns")
    if text is None:
        return Check(name, SKIP, "/proc/self/timerslack_ns not readable")
    slack = int(text)
    if slack == 0:
        return Check(name, PASS, "0 ns")
    if options.policy in ("fifo", "deadline", "rr"):
        return Check(
            name, PASS, f"{slack} ns (the kernel ignores it for SCHED_FIFO/DEADLINE threads)"
        )
    return Check(
        name,
        WARN,
        f"{slack} ns: each cycle's sleep may end this much late",
        "use realtime.policy fifo, or prctl(PR_SET_TIMERSLACK, 1)",
    )


def format_table(report: Report) -> str:
    rows = [(c.status.upper(), c.name, c.found, c.fix) for c in report.checks]
    w_status = max(len(r[0]) for r in rows)
    w_name = max(len(r[1]) for r in rows)
    lines = []
    for status, name, found, fix in rows:
        lines.append(f"{status:<{w_status}}  {name:<{w_name}}  {found}")
        if fix:
            lines.append(f"{'':<{w_status}}  {'':<{w_name}}  fix: {fix}")
    lines.append(f"result: {report.worst}")
    return "\n".join(lines)
