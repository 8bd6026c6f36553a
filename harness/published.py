"""Where a harness command writes: never over the published reports unless asked to.

The clone's ``reports/`` holds the published reports the README links (``faults.md``, ``bench/*.json``,
``paper/``, ``resco/``), tracked by git. Every command that makes one writes, like ``hils run``, to the folder
``--out`` names, or else to a new ``reports/runs/<time>-<command>/`` under the current folder
(:func:`hils.report.outfiles.fresh_folder`); only ``--publish`` rebuilds the published report, in the clone this
package was loaded from (an installed package has no published reports: ``--publish`` is refused there).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hils.protocol.errors import UserError
from hils.report.outfiles import fresh_folder, given_folder

#: The published reports: ``reports/`` of the clone this package was loaded from.
REPORTS = Path(__file__).resolve().parent.parent / "reports"


def options(parser: argparse.ArgumentParser, command: str, published: str) -> None:
    """``--out DIR`` and ``--publish`` (one or the other) for ``command`` (how its new folders are named), whose
    published report is ``published`` (a folder under reports/, "." for reports/ itself)."""
    shown = "reports/" if published == "." else f"reports/{published}/"
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--out", type=Path, metavar="DIR",
                       help=f"folder of the outputs (default: a new reports/runs/<time>-{command}/ under the current "
                            "folder)")
    where.add_argument("--publish", action="store_true",
                       help=f"rebuild the published report instead: {shown} of the clone hils runs from (tracked by "
                            "git, linked from the README)")
    parser.set_defaults(folder_command=command, folder_published=published)


def folder(args: argparse.Namespace) -> Path:
    """The folder the command writes to, made: ``--out``, the published report's with ``--publish``, or a new one."""
    if args.publish:
        if not REPORTS.is_dir():
            raise UserError(f"--publish rebuilds the published reports of a clone of hils; there is none at {REPORTS} "
                            "(hils is installed as a package): give --out DIR")
        return given_folder(REPORTS / args.folder_published)
    return given_folder(args.out) if args.out is not None else fresh_folder(args.folder_command)
