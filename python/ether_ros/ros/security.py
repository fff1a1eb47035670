"""What protects the node, found at start and reported (log and diagnostics): the control lease,
how far discovery reaches (``ROS_AUTOMATIC_DISCOVERY_RANGE``, ``ROS_STATIC_PEERS``), the Fast DDS
XML profile in use and the interfaces it allows, and whether DDS security (SROS2) is asked for
and possible with the loaded DDS. docs/security.md says what each of them does and does not
protect.

Only what the node can see is reported: the environment it was started with, the profile file
that environment names, and the Fast DDS library loaded into this process (the PyPI build has no
security plugins: it carries none of their names).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

#: The environment variable each Fast DDS generation reads its XML profile from: 2.x (the
#: library libfastrtps, ROS 2 Jazzy) reads only FASTRTPS_DEFAULT_PROFILES_FILE, 3.x (libfastdds)
#: FASTDDS_DEFAULT_PROFILES_FILE.
PROFILE_VARIABLES = {"libfastrtps": "FASTRTPS_DEFAULT_PROFILES_FILE",
                     "libfastdds": "FASTDDS_DEFAULT_PROFILES_FILE"}  # fmt: skip
#: A profile larger than this is not read (it is reported as unreadable).
MAX_PROFILE_BYTES = 1 << 20
#: What a Fast DDS build with the security plugins carries (the PKI-DH authentication
#: plugin's name); the PyPI build does not.
_SECURITY_MARK = b"PKI-DH"


@dataclass(frozen=True)
class SecurityReport:
    lease: bool
    #: ROS_AUTOMATIC_DISCOVERY_RANGE as rmw reads it (SUBNET when unset).
    discovery_range: str
    static_peers: str
    rmw: str
    #: The XML profile file named by the environment ("" for none) and what it restricts.
    profile: str = ""
    profile_interfaces: tuple[str, ...] = ()
    profile_builtin_transports: bool = True
    profile_error: str = ""
    #: ROS_SECURITY_ENABLE, ROS_SECURITY_STRATEGY, ROS_SECURITY_KEYSTORE.
    security_requested: bool = False
    security_strategy: str = "Permissive"
    keystore: str = ""
    #: Whether the loaded Fast DDS has the security plugins (None: not found in this process).
    security_plugins: bool | None = None
    warnings: tuple[str, ...] = field(default=())

    @property
    def discovery_limited(self) -> bool:
        """Discovery does not reach the whole subnet (localhost or off, or only an interface
        allow-list without the built-in transports)."""
        if self.discovery_range in ("LOCALHOST", "OFF"):
            return True
        return bool(self.profile_interfaces) and not self.profile_builtin_transports

    @property
    def transport_limited(self) -> bool:
        """The traffic stays on the profile's interfaces (a profile with an allow-list and no
        built-in transports, which rmw leaves alone unless the discovery range is LOCALHOST)."""
        return (
            bool(self.profile_interfaces)
            and not self.profile_builtin_transports
            and self.discovery_range != "LOCALHOST"
        )

    @property
    def authenticated(self) -> bool:
        return self.security_requested and bool(self.security_plugins)


def _local(tag: object) -> str:
    return str(tag).rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def read_profile(path: str) -> tuple[tuple[str, ...], bool, str]:
    """(interfaces or addresses a transport is restricted to, whether the built-in transports
    stay on, error) of a Fast DDS XML profile."""
    from lxml import etree

    p = Path(path)
    try:
        if not p.is_file():
            return (), True, f"{path}: not a regular file"
        if p.stat().st_size > MAX_PROFILE_BYTES:
            return (), True, f"{path}: larger than {MAX_PROFILE_BYTES} bytes"
        parser = etree.XMLParser(resolve_entities=False, no_network=True, huge_tree=False)
        root = etree.fromstring(p.read_bytes(), parser)
    except (OSError, etree.XMLSyntaxError) as exc:
        return (), True, f"{path}: {exc}"
    allowed: list[str] = []
    builtin = True
    for el in root.iter():
        name = _local(el.tag)
        parent = el.getparent()
        within = _local(parent.tag) if parent is not None else ""
        if name == "useBuiltinTransports" and (el.text or "").strip().lower() == "false":
            builtin = False
        elif name == "address" and within == "interfaceWhiteList":
            allowed.append((el.text or "").strip())
        elif name == "interface" and within == "allowlist":
            allowed.append(str(el.get("name", "")).strip())
    return tuple(a for a in dict.fromkeys(allowed) if a), builtin, ""


def loaded_fastdds(maps: str = "/proc/self/maps") -> Path | None:
    """The Fast DDS library loaded into this process (None: none found)."""
    try:
        lines = Path(maps).read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        path = line.split(maxsplit=5)[-1] if line.count(" ") >= 5 else ""
        if Path(path).name.startswith(("libfastrtps.so", "libfastdds.so")):
            return Path(path)
    return None


def security_plugins(library: Path | None) -> bool | None:
    """Whether that Fast DDS was built with the security plugins (None: unknown)."""
    if library is None:
        return None
    try:
        return _SECURITY_MARK in library.read_bytes()
    except OSError:
        return None


def detect(lease: bool, env: Mapping[str, str] | None = None) -> SecurityReport:
    """What protects a node started in ``env`` (default: this process's environment)."""
    env = os.environ if env is None else env
    discovery = env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip().upper() or "SUBNET"
    if env.get("ROS_LOCALHOST_ONLY", "").strip() == "1" and discovery == "SUBNET":
        discovery = "LOCALHOST"  # the deprecated switch, still honoured by Jazzy
    library = loaded_fastdds()
    kind = library.name.split(".so")[0] if library is not None else "libfastrtps"
    variable = PROFILE_VARIABLES.get(kind, PROFILE_VARIABLES["libfastrtps"])
    profile = env.get(variable, "")
    interfaces: tuple[str, ...] = ()
    builtin, profile_error = True, ""
    if profile:
        interfaces, builtin, profile_error = read_profile(profile)
    requested = env.get("ROS_SECURITY_ENABLE", "").strip().lower() == "true"
    plugins = security_plugins(library)
    warnings = []
    for other in PROFILE_VARIABLES.values():
        if other != variable and env.get(other) and not profile:
            warnings.append(
                f"{other} is set, but the loaded Fast DDS ({kind}) reads {variable}: "
                "the profile is not used"
            )
    if profile_error:
        warnings.append(f"the DDS profile cannot be read: {profile_error}")
    if interfaces and not builtin and discovery == "LOCALHOST":
        warnings.append(
            f"ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST with the profile {profile}: rmw_fastrtps "
            "then adds a UDP transport of its own beside the profile's, on every interface; "
            "use ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT with a profile"
        )
    if requested and plugins is False:
        warnings.append(
            "ROS_SECURITY_ENABLE=true, but the loaded Fast DDS has no security plugins: "
            "nothing is authenticated or encrypted (docs/security.md)"
        )
    return SecurityReport(
        lease=lease,
        discovery_range=discovery,
        static_peers=env.get("ROS_STATIC_PEERS", ""),
        rmw=env.get("RMW_IMPLEMENTATION", "") or "rmw_fastrtps_cpp",
        profile=profile,
        profile_interfaces=interfaces,
        profile_builtin_transports=builtin,
        profile_error=profile_error,
        security_requested=requested,
        security_strategy=env.get("ROS_SECURITY_STRATEGY", "") or "Permissive",
        keystore=env.get("ROS_SECURITY_KEYSTORE", ""),
        security_plugins=plugins,
        warnings=tuple(warnings),
    )


def describe(r: SecurityReport) -> list[str]:
    """One line per protection, as the node logs it at start."""
    if r.profile:
        where = ", ".join(r.profile_interfaces) or "no interface restriction"
        if r.profile_interfaces and r.profile_builtin_transports:
            where += " (built-in transports still on)"
        profile = f"DDS profile {r.profile}: {where}"
    else:
        profile = "no DDS profile: Fast DDS's defaults (every interface)"
    plugins = {True: "present", False: "absent", None: "unknown"}[r.security_plugins]
    return [
        f"control lease {'on' if r.lease else 'off (anyone on the domain may command)'}",
        f"discovery range {r.discovery_range}"
        + (f", static peers {r.static_peers}" if r.static_peers else ""),
        profile,
        f"DDS security {'requested' if r.security_requested else 'not requested'}"
        f" (plugins {plugins}): {'authenticated' if r.authenticated else 'no authentication'}",
    ]


def status(node_name: str, r: SecurityReport, lease: Mapping[str, object]) -> DiagnosticStatus:
    """``<node>: security``: which protections are active, the lease holder; ERROR when DDS
    security was asked for but cannot be had, else OK (what is off is reported, not alarmed:
    it is the operator's choice, docs/security.md)."""
    st = DiagnosticStatus()
    st.name = f"{node_name}: security"
    st.hardware_id = node_name
    values = [
        ("lease", "on" if r.lease else "off"),
        ("lease_holder", str(lease.get("holder", ""))),
        ("lease_remaining_s", f"{float(lease.get('remaining_s', 0.0)):.2f}"),  # type: ignore[arg-type]
        ("lease_refused", str(lease.get("refused", 0))),
        ("lease_lapsed", str(lease.get("lapsed", 0))),
        ("lease_taken_over", str(lease.get("taken_over", 0))),
        ("discovery_range", r.discovery_range),
        ("static_peers", r.static_peers),
        ("discovery_limited", str(r.discovery_limited).lower()),
        ("transport_limited", str(r.transport_limited).lower()),
        ("dds_profile", r.profile),
        ("dds_profile_interfaces", " ".join(r.profile_interfaces)),
        ("dds_builtin_transports", str(r.profile_builtin_transports).lower()),
        ("dds_security_requested", str(r.security_requested).lower()),
        ("dds_security_strategy", r.security_strategy),
        (
            "dds_security_plugins",
            {True: "present", False: "absent", None: "unknown"}[r.security_plugins],
        ),
        ("authenticated", str(r.authenticated).lower()),
        ("rmw", r.rmw),
    ]
    st.values = [KeyValue(key=k, value=v) for k, v in values]
    if r.warnings:
        st.level, st.message = DiagnosticStatus.ERROR, "; ".join(r.warnings)
    else:
        st.level = DiagnosticStatus.OK
        parts = [
            f"lease {'on' if r.lease else 'off'}",
            f"discovery {'limited' if r.discovery_limited else r.discovery_range.lower()}",
            "authenticated" if r.authenticated else "no DDS authentication",
        ]
        st.message = ", ".join(parts)
    return st
