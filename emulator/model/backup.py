"""The backup timer: how long a controller under system control waits for the next control SET.

Rules of this file
------------------
- The timer is disarmed at power-up and armed (restarted) by every SET of a control object; time is integer
  ticks, as the controller's.
- :meth:`BackupTimer.step` runs once per controller tick, first of the units: it says when the time has passed,
  and the controller then does what the standard asks (backup mode, every control object cleared). The timer is
  then disarmed until the next SET.
- Like every unit it says when it next acts (:meth:`BackupTimer.deadline`), and counts quiet ticks at once
  (:meth:`BackupTimer.skip`).

Theory of operation
-------------------
NTCIP 1202 v02 unitBackupTime (1.3.6.1.4.1.1206.4.2.1.3.3): "When any of the defined system control
parameters is SET, the backup timer is reset. After reset it times the unitBackupTime interval. If the
unitBackupTime interval expires without a SET operation to any of the system control parameters, then the CU
shall revert to Backup Mode. A value of zero (0) for this object shall disable this feature." The parameters the
emulator serves among them: the phase control groups, ringControlGroupMax2, systemPatternControl and
preemptControlState. A SET of unitBackupTime itself moves the threshold at once.
"""

from __future__ import annotations


class BackupTimer:
    """unitBackupTime's timer: ticks since the last control SET (None: disarmed)."""

    def __init__(self, seconds: int) -> None:
        self.seconds = seconds
        self.since: int | None = None

    def reset(self) -> None:
        """Power-up: disarmed until the first control SET."""
        self.since = None

    def restart(self) -> None:
        """A control object was SET."""
        self.since = 0

    def step(self) -> bool:
        """One tick; True when the backup time passed at this tick (the timer then disarms)."""
        if self.since is None or self.seconds == 0:
            return False
        self.since += 1
        if self.since < self.seconds * 10:
            return False
        self.since = None
        return True

    def deadline(self) -> int | None:
        """Ticks until the step at which the time passes (None: never, as things are)."""
        if self.since is None or self.seconds == 0 or self.since >= self.seconds * 10:
            return None
        return self.seconds * 10 - self.since

    def skip(self, n: int) -> None:
        """``n`` quiet ticks (fewer than :meth:`deadline`)."""
        if self.since is not None and self.seconds:
            self.since += n
