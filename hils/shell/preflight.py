"""Start-up checks of the controller: what must hold before a run may begin, said in one line each.

The middleware reads the controller once before the run (:meth:`hils.shell.middleware.Middleware.start`):
its signal state, ``unitBackupTime``, ``systemPatternControl``, ``unitFlashStatus`` and the six
control objects. :func:`judge` turns what was read into refusals (the run does not start) and
warnings (it starts, and the console says what to look at). A controller that does not answer, or a
community that may read but not write, is refused by the middleware itself with the same kind of
message (:class:`ControllerCheckFailed`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from hils.protocol.errors import UserError
from hils.protocol.ntcip import SYSTEM_PATTERN_CONTROL, ControlColumn, UnitFlashStatus, oid_str

FREE = 254  # systemPatternControl: the system calls free mode
STANDBY = 0  # systemPatternControl: no system call; the controller runs its own local plan


class ControllerCheckFailed(UserError):
    """The controller is not fit for a run; the message says why and what to do."""


@dataclass(frozen=True, slots=True)
class ControllerReading:
    """What the start-up read found."""

    backup_time: int
    pattern: int
    flash_status: int
    control: Mapping[ControlColumn, frozenset[int]]  # the control objects' phases as found


@dataclass(frozen=True, slots=True)
class Verdict:
    refusals: tuple[str, ...]
    warnings: tuple[str, ...]


def judge(reading: ControllerReading, *, where: str, community: str | None, keepalive_period: float) -> Verdict:
    """Refusals and warnings for a controller as read at start-up."""
    refusals, warnings = [], []
    # Standby is accepted: the controller then runs its local plan (the emulator's: free unless its config runs a
    # coordination plan, as for `--agent coordinated`). The middleware reads no coordPatternStatus yet to tell a
    # local plan that coordinates from one that runs free.
    if reading.pattern not in (FREE, STANDBY):
        set_free = (f"snmpset -v1 -c {community} {where} {oid_str(SYSTEM_PATTERN_CONTROL.instance())} i {FREE}"
                    if community else f"SET {oid_str(SYSTEM_PATTERN_CONTROL.instance())} to {FREE}")
        refusals.append(f"the controller at {where} is not in free mode (systemPatternControl = {reading.pattern}, "
                        f"needs {FREE}, or {STANDBY} with a free local plan): set free mode in its coordination menu "
                        f"or with `{set_free}`")
    if reading.flash_status != UnitFlashStatus.NOT_FLASH:
        try:
            why = UnitFlashStatus(reading.flash_status).name.lower()
        except ValueError:
            why = str(reading.flash_status)
        refusals.append(f"the controller at {where} is in flash (unitFlashStatus = {why}): clear the flash "
                        "at the cabinet before a run")
    if reading.backup_time == 0:
        warnings.append(f"the controller at {where} has no backup time (unitBackupTime = 0): if the middleware "
                        "dies, the calls it placed stay; set e.g. 30 s")
    elif keepalive_period and reading.backup_time < 3:
        warnings.append(f"the controller at {where} has a backup time of {reading.backup_time} s: the keepalive "
                        f"must refresh the call every {reading.backup_time / 3:.1f} s; 30 s is usual")
    foreign = {c: p for c, p in reading.control.items() if p}
    if foreign:
        warnings.append(f"the controller at {where} had control objects set by someone else, cleared now: "
                        + ", ".join(f"{c.name} {sorted(p)}" for c, p in foreign.items()))
    return Verdict(tuple(refusals), tuple(warnings))
