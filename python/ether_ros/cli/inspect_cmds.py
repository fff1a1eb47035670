"""Inspection commands, standalone on an interface (like IgH's ``ethercat`` tool):
``pdos``, ``sdos``, ``upload``, ``download``, ``states``, ``reg-read``, ``reg-write``,
``sii-read``, ``xml``, ``graph``, ``master``. Every one takes ``--json``. ``graph`` renders
PNG/SVG with Graphviz's ``dot`` (installed by scripts/bootstrap.sh).

They scan without resetting the bus. Beside a running master they ask that master (through its
claim on the interface, ``ether_ros.claim`` and ``master/service.py``) instead of opening the
interface; without one they open it and hold it while they run.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ether_ros._native.protocol import format_address
from ether_ros.cli.common import add_interface_argument, add_parser, resolve_interface
from ether_ros.master.link import add_link_argument

Handler = Callable[[Any, argparse.Namespace], Any]

_STANDALONE = (
    "\n\nBeside a running master (ether-ros run, a node) it asks that master and never opens "
    "the interface; otherwise it opens the interface itself and scans without resetting the bus."
)
_OBJECT_HELP = (
    "object: index:subindex, both hexadecimal with or without 0x (0x1600:0a is 0x1600:0x0a; "
    "0x1600:10 is subindex 16), or a dictionary name"
)
GRAPH_FORMATS = ("dot", "png", "svg")


def _common(p: argparse.ArgumentParser, slave: str | None) -> None:
    add_interface_argument(p, "network interface (or bus.interface of --config)")
    add_link_argument(p)
    p.add_argument("--config", "-c", help="bus configuration: slave names and ESI files")
    p.add_argument(
        "--esi",
        action="append",
        default=[],
        metavar="PATH",
        help="ESI file or directory for names and types (repeatable)",
    )
    p.add_argument("--json", action="store_true", help="machine-readable output")
    if slave == "required":
        p.add_argument(
            "--position",
            "-p",
            required=True,
            metavar="SLAVE",
            help="slave: bus position, #alias, or configured name",
        )
    elif slave == "optional":
        p.add_argument(
            "--position",
            "-p",
            metavar="SLAVE",
            help="slave: bus position, #alias, or configured name (default: all)",
        )


def register(subparsers: Any) -> None:
    def add(
        name: str,
        help_text: str,
        handler: Handler,
        slave: str | None,
        description: str,
        examples: list[str],
    ) -> Any:
        p = add_parser(
            subparsers,
            name,
            help=help_text,
            description=description + _STANDALONE,
            examples=examples,
        )
        _common(p, slave)
        p.set_defaults(func=lambda args: _run(handler, args))
        return p

    add(
        "pdos",
        "SyncManagers and PDO assignment/mapping of slaves",
        cmd_pdos,
        "optional",
        "Print each slave's SyncManagers and its PDO assignment and mapping, read from the "
        "slave (CoE) or else its SII.",
        ["ether-ros pdos -i eth1", "ether-ros pdos -i eth1 -p 0 --json"],
    )
    add(
        "sdos",
        "object dictionary (SDO information service, else the ESI)",
        cmd_sdos,
        "optional",
        "Print each slave's object dictionary: from the SDO information service, or else from "
        "the ESI file (--esi, or the configuration's).",
        ["ether-ros sdos -i eth1 -p 0", "ether-ros sdos -i eth1 -c config/laelaps.yaml"],
    )
    p = add(
        "upload",
        "read an object by SDO",
        cmd_upload,
        "required",
        "Read one object entry of a slave by SDO upload and print its value.",
        [
            "ether-ros upload -i eth1 -p 0 0x1018:01",
            "ether-ros upload -i eth1 -p 0 0x1008 --type string",
        ],
    )
    p.add_argument("object", help=_OBJECT_HELP)
    p.add_argument("--type", help="data type (uint16, int32, real32, string, ...)")
    p = add(
        "download",
        "write an object by SDO",
        cmd_download,
        "required",
        "Write one object entry of a slave by SDO download; the type comes from the ESI "
        "dictionary unless --type names it.",
        ["ether-ros download -i eth1 -p 0 0x6060:00 8 --type int8"],
    )
    p.add_argument("object", help=_OBJECT_HELP)
    p.add_argument("value", help="the value (decimal, 0x hex, true/false, text)")
    p.add_argument("--type", help="data type (default: from the ESI dictionary)")
    p = add(
        "states",
        "show AL states, or request one (INIT, PREOP, BOOT)",
        cmd_states,
        "optional",
        "Print each slave's AL state and AL status code, or request a state (INIT, PREOP, "
        "BOOT) of one slave or all.",
        ["ether-ros states -i eth1", "ether-ros states -i eth1 -p 2 INIT"],
    )
    p.add_argument("state", nargs="?", help="state to request")
    p = add(
        "reg-read",
        "read ESC registers",
        cmd_reg_read,
        "required",
        "Read ESC registers of a slave (hex bytes, or a value with --type).",
        ["ether-ros reg-read -i eth1 -p 0 0x0130 2", "ether-ros reg-read -i eth1 -p 0 0x0910 "
         "--type uint64"],
    )  # fmt: skip
    p.add_argument("address", help="register address, hexadecimal (0x0130 or 0130)")
    p.add_argument("length", nargs="?", help="bytes to read (default: the type's size, or 1)")
    p.add_argument("--type", help="decode as this type (uint16, int32, ...)")
    p = add(
        "reg-write",
        "write ESC registers",
        cmd_reg_write,
        "required",
        "Write ESC registers of a slave: hex bytes in wire order, or a value with --type.",
        ["ether-ros reg-write -i eth1 -p 0 0x0120 0200", "ether-ros reg-write -i eth1 -p 0 "
         "0x0120 2 --type uint16"],
    )  # fmt: skip
    p.add_argument("address", help="register address, hexadecimal (0x0120 or 0120)")
    p.add_argument("data", help="hex bytes in wire order (0102), or a value with --type")
    p.add_argument("--type", help="encode the data as this type (uint16, ...)")
    p = add(
        "sii-read",
        "the SII EEPROM: decoded, or raw with --raw",
        cmd_sii_read,
        "required",
        "Read a slave's SII EEPROM and print what it says (identity, mailbox, SyncManagers, "
        "PDOs, DC modes), or the raw image with --raw or -o.",
        ["ether-ros sii-read -i eth1 -p 0", "ether-ros sii-read -i eth1 -p 0 -o slave0.bin"],
    )
    p.add_argument("--raw", action="store_true", help="the image itself (hex, or -o file)")
    p.add_argument("-o", "--output", help="write the raw image to this file")
    p = add(
        "xml",
        "an ESI (ETG.2000) description generated from a slave's SII",
        cmd_xml,
        "required",
        "Generate an ESI (ETG.2000) XML description of a slave from its SII EEPROM.",
        ["ether-ros xml -i eth1 -p 0 -o slave0.xml"],
    )
    p.add_argument("-o", "--output", help="write to this file instead of stdout")
    p = add(
        "graph",
        "bus topology as a Graphviz graph (DOT, PNG or SVG)",
        cmd_graph,
        None,
        "Print the bus topology (which port of which slave leads where) as a Graphviz DOT "
        "graph, or render it as PNG or SVG with Graphviz's dot (--format, or the -o file's "
        "suffix).",
        [
            "ether-ros graph -i eth1 -o bus.png",
            "ether-ros graph -i eth1 --format svg > bus.svg",
            "ether-ros graph -i eth1 | dot -Tpdf -o bus.pdf",
        ],
    )
    p.add_argument("-o", "--output", help="write to this file instead of stdout")
    p.add_argument(
        "--format",
        choices=GRAPH_FORMATS,
        help="dot (the graph's text), png or svg (rendered by Graphviz's dot); default: the "
        "-o file's suffix, else dot",
    )
    p = add(
        "master",
        "link statistics and round-trip time",
        cmd_master,
        None,
        "Measure the round-trip time of the link with --probes frames and print it with the "
        "interface's counters and the engine's.",
        ["ether-ros master -i eth1", "ether-ros master -i eth1 --probes 1000 --json"],
    )
    p.add_argument("--probes", type=int, default=100, help="round-trip probes (default 100)")


def _run(handler: Handler, args: argparse.Namespace) -> int:
    from ether_ros.config import load_bus_config
    from ether_ros.tools.bus_inspect import Inspector

    configured = load_bus_config(args.config).bus.interface if args.config else None
    interface = resolve_interface(args, configured, args.command, args.config)
    with Inspector.open(
        interface, config=args.config, esi=args.esi, link_kind=args.link
    ) as inspector:
        result = handler(inspector, args)
    if args.json and result is not None:
        json.dump(result, sys.stdout, indent=2, default=_json_default)
        print()
    return 0


def _json_default(value: Any) -> Any:
    if isinstance(value, bytes | bytearray):
        return value.hex()
    return str(value)


def _write(args: argparse.Namespace, text: str) -> None:
    if getattr(args, "output", None):
        try:
            Path(args.output).write_text(text)
        except OSError as exc:
            from ether_ros.errors import EtherRosError

            raise EtherRosError(f"cannot write {args.output}: {exc.strerror}") from None
    else:
        sys.stdout.write(text)


# ---- handlers: each returns the JSON value and prints text unless --json ------------------


def _print_slave_heading(slave: dict[str, Any]) -> None:
    print(f"=== slave {slave['position']} ({slave['name']}), from the {slave['source']}")


def cmd_pdos(ins: Any, args: argparse.Namespace) -> Any:
    result = [ins.pdos(f.position) for f in ins.selected(args.position)]
    if args.json:
        return result
    for slave in result:
        _print_slave_heading(slave)
        for sm in slave["sync_managers"]:
            print(
                f"SM{sm['index']}: start 0x{sm['start']:04X}, {sm['length']} bytes, control "
                f"0x{sm['control']:02X}, enable {sm['enable']} {sm['role']}"
            )
        for kind, pdos in (("RxPDO", slave["rx_pdos"]), ("TxPDO", slave["tx_pdos"])):
            for pdo in pdos:
                print(f'  {kind} 0x{pdo["index"]:04X} "{pdo["name"]}"')
                for e in pdo["entries"]:
                    print(
                        f"    {format_address(e['index'], e['subindex'])}, {e['bit_length']} bit, "
                        f'{e["type"] or "-"} "{e["name"]}"'
                    )
    return None


def cmd_sdos(ins: Any, args: argparse.Namespace) -> Any:
    result = []
    for f in ins.selected(args.position):
        source, objects = ins.dictionary(f.position)
        result.append(
            {"position": f.position, "name": ins.name_of(f), "source": source, "objects": objects}
        )
    if args.json:
        return result
    for slave in result:
        _print_slave_heading(slave)
        for obj in slave["objects"]:
            print(f'SDO 0x{obj["index"]:04X} {obj["object_code"]} "{obj["name"]}"')
            for e in obj["entries"]:
                print(
                    f"  {format_address(obj['index'], e['subindex'])}, {e['access']}, {e['type']}, "
                    f'{e["bit_length"]} bit, "{e["name"]}"'
                )
    return None


def _object_ref_json(ref: Any) -> dict[str, Any]:
    """The object entry an upload or download addressed, for ``--json`` output."""
    return {
        "index": ref.index,
        "subindex": ref.subindex,
        "name": ref.name,
        "type": ref.dtype.name if ref.dtype else None,
    }


def cmd_upload(ins: Any, args: argparse.Namespace) -> Any:
    ref, data, value = ins.upload(args.position, args.object, args.type)
    entry = {**_object_ref_json(ref), "value": value, "hex": data.hex()}
    if args.json:
        return entry
    shown = value.hex(" ") if isinstance(value, bytes) else value
    if isinstance(value, int) and not isinstance(value, bool):
        shown = f"{value} (0x{value & ((1 << max(8, ref.bit_length or 8)) - 1):X})"
    print(shown)
    return None


def cmd_download(ins: Any, args: argparse.Namespace) -> Any:
    ref, data = ins.download(args.position, args.object, args.value, args.type)
    entry = {**_object_ref_json(ref), "hex": data.hex()}
    if args.json:
        return entry
    name = f" {ref.name}" if ref.name else ""
    print(f"{format_address(ref.index, ref.subindex)}{name} <- {args.value} ({data.hex(' ')})")
    return None


def cmd_states(ins: Any, args: argparse.Namespace) -> Any:
    if args.state:
        result = ins.request_state(args.state, args.position)
    else:
        result = ins.states(args.position)
    if args.json:
        return result
    for e in result:
        error = f"  ERROR 0x{e['al_status_code']:04X} {e['al_status_text']}" if e["error"] else ""
        print(f"{e['position']:>3}  {e['name']:<24} {e['state']}{error}")
    return None


def _register_type(args: argparse.Namespace) -> Any:
    from ether_ros.tools.bus_inspect import data_type

    return data_type(args.type) if args.type else None


def cmd_reg_read(ins: Any, args: argparse.Namespace) -> Any:
    from ether_ros.config import types as dt
    from ether_ros.tools.bus_inspect import InspectError, parse_int, parse_register

    dtype = _register_type(args)
    address = parse_register(args.address)
    if args.length is not None:
        length = parse_int(args.length, "length")
    elif dtype is not None:
        if not dtype.bit_length:
            raise InspectError(f"give a length for a {dtype.name} register")
        length = (dtype.bit_length + 7) // 8
    else:
        length = 1
    data = ins.reg_read(args.position, address, length)
    value = None
    if dtype is not None:
        bits = dtype.bit_length or 8 * len(data)
        value = dt.decode_value(dtype, data[: (bits + 7) // 8], bits)
    if args.json:
        return {"address": address, "length": length, "hex": data.hex(), "value": value}
    if value is not None:
        print(value.hex(" ") if isinstance(value, bytes) else value)
    else:
        print(data.hex(" "))
    return None


def cmd_reg_write(ins: Any, args: argparse.Namespace) -> Any:
    from ether_ros.config import types as dt
    from ether_ros.tools.bus_inspect import (
        InspectError,
        parse_register,
        parse_value,
    )

    dtype = _register_type(args)
    address = parse_register(args.address)
    if dtype is None:
        text = args.data.replace(" ", "").removeprefix("0x")
        try:
            data = bytes.fromhex(text)
        except ValueError:
            raise InspectError(
                f"data {args.data!r} is not hex bytes (e.g. 0102); for a number give --type"
            ) from None
        if not data:
            raise InspectError("no data to write")
    else:
        value = parse_value(args.data, dtype)
        bits = dtype.bit_length or 8 * len(str(value).encode())
        try:
            data = dt.encode_value(dtype, value, bits)
        except ValueError as exc:
            raise InspectError(f"register 0x{address:04X}: {exc}") from None
    ins.reg_write(args.position, address, data)
    if args.json:
        return {"address": address, "hex": data.hex()}
    print(f"0x{address:04X} <- {data.hex(' ')}")
    return None


def cmd_sii_read(ins: Any, args: argparse.Namespace) -> Any:
    from dataclasses import asdict

    image, info = ins.sii(args.position)
    if args.raw or args.output:
        if args.output:
            try:
                Path(args.output).write_bytes(image)
            except OSError as exc:
                from ether_ros.errors import EtherRosError

                raise EtherRosError(f"cannot write {args.output}: {exc.strerror}") from None
            if not args.json:
                print(f"{args.output}: {len(image)} bytes")
            return {"bytes": len(image), "file": args.output} if args.json else None
        if args.json:
            return {"bytes": len(image), "hex": image.hex()}
        for offset in range(0, len(image), 16):
            chunk = image[offset : offset + 16]
            print(f"{offset:04x}: {chunk.hex(' ')}")
        return None
    decoded = asdict(info)
    if args.json:
        return decoded
    print(
        f"vendor 0x{info.vendor_id:08X}  product 0x{info.product_code:08X}  revision "
        f"0x{info.revision:08X}  serial 0x{info.serial:08X}"
    )
    print(
        f'name "{info.name}"  alias {info.alias}  checksum '
        f"{'ok' if info.checksum_ok else 'WRONG'}  EEPROM {info.eeprom_bytes} bytes"
    )
    rx_off, rx_size, tx_off, tx_size = info.mailbox
    print(
        f"mailbox out 0x{rx_off:04X}/{rx_size}  in 0x{tx_off:04X}/{tx_size}  protocols "
        f"0x{info.mailbox_protocols:02X}"
    )
    for i, sm in enumerate(info.sync_managers):
        print(f"SM{i}: 0x{sm.start:04X} {sm.length} bytes control 0x{sm.control:02X} {sm.role}")
    for kind, pdos in (("RxPDO", info.rx_pdos), ("TxPDO", info.tx_pdos)):
        for p in pdos:
            print(
                f'{kind} 0x{p.index:04X} "{p.name}" SM{p.sm}, {len(p.entries)} entries, '
                f"{p.bit_length} bit"
            )
    for mode in info.dc:
        print(f'DC "{mode.name}" AssignActivate 0x{mode.assign_activate:04X}')
    return None


def cmd_xml(ins: Any, args: argparse.Namespace) -> Any:
    from ether_ros.tools.bus_inspect import esi_from_sii

    _image, info = ins.sii(args.position)
    xml = esi_from_sii(info)
    if args.json:
        return {"xml": xml}
    _write(args, xml)
    return None


def cmd_graph(ins: Any, args: argparse.Namespace) -> Any:
    if args.json:
        return ins.topology()
    fmt = graph_format(args.format, args.output)
    dot = ins.graph_dot()
    if fmt == "dot":
        _write(args, dot)
        return None
    image = render_graph(dot, fmt)
    if args.output:
        try:
            Path(args.output).write_bytes(image)
        except OSError as exc:
            from ether_ros.errors import EtherRosError

            raise EtherRosError(f"cannot write {args.output}: {exc.strerror}") from None
    else:
        sys.stdout.flush()
        sys.stdout.buffer.write(image)
    return None


def graph_format(fmt: str | None, output: str | None) -> str:
    """The format ``graph`` writes: ``--format``, else the output file's suffix, else DOT."""
    if fmt:
        return fmt
    suffix = Path(output).suffix.lower().lstrip(".") if output else ""
    return suffix if suffix in GRAPH_FORMATS else "dot"


def render_graph(dot: str, fmt: str) -> bytes:
    """``dot`` rendered as ``fmt`` (png, svg) by Graphviz's ``dot`` program (an argument list,
    no shell)."""
    from ether_ros.errors import EtherRosError

    program = shutil.which("dot")
    if program is None:
        raise EtherRosError(
            f"rendering {fmt.upper()} needs Graphviz's dot program (apt-get install graphviz; "
            f"scripts/bootstrap.sh installs it); without it, write the DOT text: "
            f"'ether-ros graph -i IFACE -o bus.dot'"
        )
    done = subprocess.run(
        [program, f"-T{fmt}"], input=dot.encode(), capture_output=True, check=False
    )
    if done.returncode != 0:
        raise EtherRosError(f"dot -T{fmt} failed: {done.stderr.decode(errors='replace').strip()}")
    return done.stdout


def cmd_master(ins: Any, args: argparse.Namespace) -> Any:
    from ether_ros.tools.bus_inspect import InspectError

    if not 1 <= args.probes <= 100_000:
        raise InspectError(f"--probes must be 1..100000, got {args.probes}")
    stats = ins.link_statistics(args.probes)
    if args.json:
        return stats
    rtt = stats["round_trip_us"]
    print(f"interface {stats['interface']}, {stats['slaves']} slaves")
    print(
        f"round trip ({rtt['probes']} frames): min {rtt['min']:.1f} µs, median "
        f"{rtt['median']:.1f} µs, max {rtt['max']:.1f} µs"
    )
    iface = stats["interface_stats"]
    for key in (
        "operstate",
        "mtu",
        "speed",
        "rx_packets",
        "tx_packets",
        "rx_errors",
        "tx_errors",
        "rx_dropped",
        "tx_dropped",
    ):
        if key in iface:
            print(f"  {key}: {iface[key]}")
    for key, value in sorted(stats["engine"].items()):
        print(f"  engine {key}: {value}")
    return None
