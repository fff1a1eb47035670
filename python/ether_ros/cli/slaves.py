"""``ether-ros slaves``: list the slaves on a link, one line each (like IgH's ``ethercat
slaves``): position, station address, AL state, vendor, product, name.

The listing does not change AL states or reset the bus; it (re)assigns the station addresses
0x1001+position, which a running ether_ros master uses too. Beside a running master it asks
that master (``ether_ros.claim``) and does not touch the interface.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from ether_ros.cli.common import add_interface_argument, add_parser, resolve_interface
from ether_ros.master.link import add_link_argument


def register(subparsers: Any) -> None:
    p = add_parser(
        subparsers,
        "slaves",
        help="list the slaves on a network interface",
        description="Scan the bus on INTERFACE and print one line per slave: position, station "
        "address, AL state, vendor, product, name. It does not change AL states.",
        examples=[
            "ether-ros slaves -i eth1",
            "ether-ros slaves -i eth1 -c config/laelaps.yaml -v",
            "ether-ros slaves -i eth1 --json",
        ],
    )
    add_interface_argument(p, "network interface (e.g. eth1)", required=True)
    add_link_argument(p)
    p.add_argument("--config", "-c", help="bus configuration: check identities, show names")
    p.add_argument("-v", "--verbose", action="store_true", help="details of every slave")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run)


def describe(
    found: Any, status: Any, configured: str | None, group: str | None = None
) -> dict[str, Any]:
    """One slave's listing entry (also the JSON object); ``group``: its slave group in the
    configuration, if one was given."""
    h = found.header
    rx_off, rx_size, tx_off, tx_size = h.mailbox
    return {
        "position": found.position,
        "station": found.station,
        "alias": found.alias,
        "state": status.name,
        "error": bool(status.error),
        "al_status_code": status.code,
        "vendor_id": h.vendor_id,
        "product_code": h.product_code,
        "revision": h.revision,
        "serial": h.serial,
        "name": h.name,
        "configured_name": configured,
        "esc_type": found.esc_type,
        "dc": found.dc_supported,
        "lrw": found.lrw_supported,
        "group": group,
        "mailbox": {
            "rx": [rx_off, rx_size],
            "tx": [tx_off, tx_size],
            "protocols": h.mailbox_protocols,
        },
        "rx_pdos": [f"0x{p.index:04X}" for p in h.rx_pdos],
        "tx_pdos": [f"0x{p.index:04X}" for p in h.tx_pdos],
    }


def line(entry: dict[str, Any]) -> str:
    state = entry["state"] + ("+E" if entry["error"] else "")
    name = entry["name"] or "?"
    if entry["configured_name"]:
        name += f" ({entry['configured_name']})"
    if entry.get("group"):
        name += f" [group {entry['group']}]"
    return (
        f"{entry['position']:>3}  0x{entry['station']:04X}  {state:<8}  "
        f"0x{entry['vendor_id']:08X}  0x{entry['product_code']:08X}  {name}"
    )


def details(entry: dict[str, Any]) -> list[str]:
    from ether_ros.master.al import al_code_text

    mb = entry["mailbox"]
    out = [
        f"     alias {entry['alias']}  revision 0x{entry['revision']:08X}  "
        f"serial 0x{entry['serial']:08X}  ESC type 0x{entry['esc_type']:02X}  "
        f"DC {'yes' if entry['dc'] else 'no'}  LRW {'yes' if entry['lrw'] else 'no (LRD + LWR)'}",
        f"     mailbox out 0x{mb['rx'][0]:04X}/{mb['rx'][1]}  in 0x{mb['tx'][0]:04X}/{mb['tx'][1]}"
        f"  protocols 0x{mb['protocols']:02X}",
        f"     RxPDOs {' '.join(entry['rx_pdos']) or '-'}  "
        f"TxPDOs {' '.join(entry['tx_pdos']) or '-'}",
    ]
    if entry["error"]:
        code = entry["al_status_code"]
        out.append(f"     AL status code 0x{code:04X}: {al_code_text(code)}")
    return out


def run(args: argparse.Namespace) -> int:
    from types import SimpleNamespace

    from ether_ros.tools.bus_inspect import Inspector

    groups: dict[str, str] = {}
    if args.config:
        from ether_ros.config import load_bus_config

        cfg = load_bus_config(args.config)
        groups = {s.name: g.name for g in cfg.groups for s in cfg.slaves if s.name in g.slaves}
    interface = resolve_interface(args, None, "slaves")
    # Beside a running master the listing comes from that master (it never opens the
    # interface a second time); otherwise it scans the interface itself.
    with Inspector.open(interface, config=args.config, link_kind=args.link) as ins:
        found = ins.found
        names = {f.position: ins.names[f.position] for f in found if f.position in ins.names}
        statuses = [
            SimpleNamespace(name=e["state"], error=e["error"], code=e["al_status_code"])
            for e in ins.states()
        ]
    entries = [
        describe(f, st, names.get(f.position), groups.get(names.get(f.position, "")))
        for f, st in zip(found, statuses, strict=True)
    ]
    if args.json:
        json.dump(entries, sys.stdout, indent=2)
        print()
        return 0
    if not entries:
        print(f"no slaves on {args.interface}")
        return 0
    for e in entries:
        print(line(e))
        if args.verbose:
            for text in details(e):
                print(text)
    return 0
