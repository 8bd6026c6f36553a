"""The `hils` command line.

The core commands live here; the emulator and harness packages add theirs
through the ``hils.cli.run`` entry points (see pyproject.toml), so that this
package never imports them and runs against real hardware without them.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, entry_points, version

from hils.dashboard import cli as view
from hils.protocol.errors import UserError

log = logging.getLogger("hils")

DESCRIPTION = """\
hils: hardware-in-the-loop testbed for real-time traffic-signal phase control.

A control agent commands a signal controller phase by phase through a middleware
that speaks NTCIP 1202 (SNMP). The controller is the built-in emulator in
virtual time (default) or, with --target snmp://HOST:PORT, a real controller or
`hils emulator serve` at wall-clock time.
"""


def _version() -> str:
    try:
        return version("hils")
    except PackageNotFoundError:
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hils", description=DESCRIPTION,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-v", "--verbose", action="store_true", help="debug log output, tracebacks of errors")
    parser.add_argument("--version", action="version", version=f"hils {_version()}")
    parser.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors in the log")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    view.register(sub)
    for ep in sorted(entry_points(group="hils.commands"), key=lambda e: e.name):
        try:
            register = ep.load()
        except ImportError as exc:
            log.debug("command group %s unavailable: %s", ep.name, exc)
            continue
        register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING if args.quiet else logging.DEBUG if args.verbose else logging.INFO
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)-7s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except UserError as exc:
        print(f"hils: {exc}", file=sys.stderr)
        if args.verbose:
            log.debug("traceback", exc_info=exc)
        return 2
    except KeyboardInterrupt:
        print("hils: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
