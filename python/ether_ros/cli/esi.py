"""``ether-ros esi FILE``: what an ESI file describes, as the master and the simulator read it —
every device with its SyncManagers, PDOs (default assignment marked), CiA 402 modes and
profiles, DC modes, init commands and modules, and whatever the parser skipped and why.

Nothing is sent anywhere; the file is only read (regular files, bounded in size).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any

from ether_ros.cli.common import add_parser
from ether_ros.config import types as dt
from ether_ros.config.cia402 import PROFILE_NUMBER, offered_modes
from ether_ros.config.esi import EsiDevice, EsiFile, Pdo, load_esi_file


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "esi",
        help="list the devices of an ESI file: PDOs, modes, profiles, what was skipped",
        description="Read an ESI (EtherCATInfo XML) file and print its devices as ether_ros"
        " reads them, and every element the parser disabled, one line each (FILE:LINE:"
        " <element>: why).",
        examples=[
            "ether-ros esi devices/laelaps_ii_leg.xml           # every device in full",
            'ether-ros esi "Beckhoff EL2xxx.xml" --device EL2008  # one device of a vendor file',
            "ether-ros esi vendor.xml --brief                   # one line per device",
            "ether-ros esi vendor.xml --json | jq '.[0].name'   # for scripts",
        ],
    )
    p.add_argument("file", type=Path, help="the ESI file")
    p.add_argument("--device", help="only devices of this <Type> name")
    p.add_argument("--brief", action="store_true", help="one line per device")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # The warnings are part of the listing: not logged a second time on stderr.
    logging.getLogger("ether_ros.config.esi").setLevel(logging.ERROR)
    esi = load_esi_file(args.file)
    devices = [d for d in esi.devices if args.device is None or d.type_name == args.device]
    if args.device is not None and not devices:
        known = ", ".join(sorted({d.type_name for d in esi.devices}))
        print(f"ether-ros esi: error: {args.file}: no device {args.device!r} (it has: {known})",
              file=sys.stderr)  # fmt: skip
        return 2
    if args.json:
        json.dump(_file_json(esi, devices), sys.stdout, indent=1)
        print()
        return 0
    out = sys.stdout
    passive = sum(1 for d in devices if d.passive)
    print(f"{esi.path}: {len(devices)} device(s)"
          + (f", {passive} passive" if passive else "")
          + f", {len(esi.warnings)} warning(s)", file=out)  # fmt: skip
    for d in devices:
        if args.brief:
            print(_brief(d), file=out)
        else:
            _print_device(d)
    if esi.skipped_devices:
        print("skipped devices:", file=out)
        for w in esi.skipped_devices:
            print(f"  {w}", file=out)
    rest = [w for w in esi.warnings if w not in esi.skipped_devices
            and not any(w in d.warnings for d in esi.devices)]  # fmt: skip
    if rest:
        print("file warnings:", file=out)
        for w in rest:
            print(f"  {w}", file=out)
    return 0


def _brief(d: EsiDevice) -> str:
    if d.passive:
        return f"{d.type_name}: passive terminal (no EtherCAT slave controller)"
    rx = sum(p.bit_length for p in d.default_rx())
    tx = sum(p.bit_length for p in d.default_tx())
    mbx = "CoE" if d.mailbox is not None and d.mailbox.coe else ("mailbox" if d.mailbox else "-")
    return (
        f"{d.type_name} rev {d.revision:#010x} product {d.product_code:#010x}: "
        f"{(rx + 7) // 8} B out, {(tx + 7) // 8} B in, {mbx}"
        + (", DC" if d.dc_supported else "")
        + (f", profile {'/'.join(map(str, sorted(set(d.profile_numbers))))}"
           if d.profile_numbers else "")
        + (f", {len(d.warnings)} skipped" if d.warnings else "")
    )  # fmt: skip


def _modes(d: EsiDevice) -> list[tuple[int, tuple[str, ...]]]:
    axes = max(1, d.profile_numbers.count(PROFILE_NUMBER))
    return (
        [(n, offered_modes(d, n)) for n in range(axes)]
        if PROFILE_NUMBER in (d.profile_numbers)
        else []
    )


def _print_device(d: EsiDevice) -> None:
    print()
    print(f"{d.type_name}  rev {d.revision:#010x}  (line {d.line})")
    print(f"  {d.name}")
    if d.passive:
        print("  passive terminal: no EtherCAT slave controller, not on the bus")
        return
    print(f"  vendor {d.vendor_id:#010x} {d.vendor_name}, product {d.product_code:#010x},"
          f" group {d.group_type or '-'}, physics {d.physics or '-'}")  # fmt: skip
    mb = d.mailbox
    if mb is not None:
        protocols = [
            n
            for n, on in (
                ("CoE", mb.coe),
                ("EoE", mb.eoe),
                ("FoE", mb.foe),
                ("SoE", mb.soe),
                ("AoE", mb.aoe),
                ("VoE", mb.voe),
            )
            if on
        ]
        coe = [
            n
            for n, on in (
                ("SdoInfo", mb.sdo_info),
                ("PdoAssign", mb.pdo_assign),
                ("PdoConfig", mb.pdo_config),
                ("CompleteAccess", mb.complete_access),
            )
            if on
        ]
        print(f"  mailbox: {', '.join(protocols) or '-'}"
              + (f" ({', '.join(coe)})" if coe else ""))  # fmt: skip
    if d.profile_numbers:
        print(f"  profiles: {', '.join(str(p) for p in d.profile_numbers)}")
    for axis, modes in _modes(d):
        print(f"  axis {axis + 1} modes: {', '.join(modes) or 'none'}")
    for m in d.dc_opmodes:
        print(f"  DC mode {m.name!r}: AssignActivate {m.assign_activate:#06x}"
              + (f" ({m.description})" if m.description else ""))  # fmt: skip
    for sm in d.sync_managers:
        flags = [
            f
            for f, on in (
                ("virtual", sm.virtual),
                ("OpOnly", sm.op_only),
                ("disabled", not sm.enable and not sm.virtual),
            )
            if on
        ]
        label = f" ({sm.label})" if sm.label != sm.role else ""
        size = f", {sm.default_size} B" if sm.default_size else ""
        print(f"  SM{sm.number} {sm.role or 'unused'}{label} at {sm.start:#06x}"
              f", control {sm.control:#04x}{size}"
              + (f" [{', '.join(flags)}]" if flags else ""))  # fmt: skip
    for p in (*d.rx_pdos, *d.tx_pdos):
        _print_pdo(p)
    for c in d.init_cmds:
        print(f"  init command {'/'.join(c.transitions)} {c.index:#06x}:{c.subindex:02x}"
              f" = {c.data.hex()}" + (f" ({c.comment})" if c.comment else ""))  # fmt: skip
    for k, slot in enumerate(d.slots):
        names = [m.type_name for m in d.modules if m.ident in slot.module_idents]
        default = next((m.type_name for m in d.modules if m.ident == slot.default_ident), "-")
        print(f"  slot {k + 1} {slot.name!r}: default {default}; takes {', '.join(names)}")
    if d.objects:
        print(f"  dictionary: {len(d.objects)} objects")
    for w in d.warnings:
        print(f"  warning: {w}")
    for n in d.notes:
        print(f"  note: {n}")


def _print_pdo(p: Pdo) -> None:
    kind = "RxPDO" if p.direction == "rx" else "TxPDO"
    flags = [
        f
        for f, on in (
            ("default", p.sm is not None),
            ("fixed", p.fixed),
            ("mandatory", p.mandatory),
            ("virtual", p.virtual),
        )
        if on
    ]
    where = f" SM{p.sm}" if p.sm is not None else ""
    print(
        f"  {kind} {p.index:#06x} {p.name!r}{where}, {p.bit_length} bits"
        + (f" [{', '.join(flags)}]" if flags else "")
        + (f" excludes {', '.join(f'{x:#06x}' for x in p.excludes)}" if p.excludes else "")
    )
    for e in p.entries:
        if e.is_padding:
            print(f"      (gap of {e.bit_length} bits)")
            continue
        t = dt.BY_CODE.get(e.data_type)
        print(f"      {e.index:#06x}:{e.subindex:02x} {e.name} "
              f"{t.name if t else e.type_name or '?'} {e.bit_length}")  # fmt: skip


def _file_json(esi: EsiFile, devices: list[EsiDevice]) -> dict[str, Any]:
    return {
        "file": esi.path,
        "warnings": [str(w) for w in esi.warnings],
        "skipped_devices": [str(w) for w in esi.skipped_devices],
        "devices": [
            {
                "type": d.type_name,
                "name": d.name,
                "vendor_id": d.vendor_id,
                "product_code": d.product_code,
                "revision": d.revision,
                "passive": d.passive,
                "profiles": list(d.profile_numbers),
                "modes": {str(n + 1): list(m) for n, m in _modes(d)},
                "sync_managers": [
                    {"number": s.number, "role": s.role, "label": s.label, "start": s.start,
                     "control": s.control, "virtual": s.virtual, "op_only": s.op_only}
                    for s in d.sync_managers
                ],
                "pdos": [
                    {"index": p.index, "direction": p.direction, "name": p.name, "sm": p.sm,
                     "fixed": p.fixed, "virtual": p.virtual, "bits": p.bit_length,
                     "entries": [[e.index, e.subindex, e.bit_length, e.name]
                                 for e in p.entries]}
                    for p in (*d.rx_pdos, *d.tx_pdos)
                ],
                "init_cmds": [
                    {"transitions": list(c.transitions), "index": c.index,
                     "subindex": c.subindex, "data": c.data.hex()}
                    for c in d.init_cmds
                ],
                "skipped": [str(w) for w in d.warnings],
                "notes": [str(n) for n in d.notes],
            }
            for d in devices
        ],
    }  # fmt: skip
