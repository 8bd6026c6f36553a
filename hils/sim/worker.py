"""SUMO stepped in a worker process, beside hils' own work: the same simulation on a second core.

Why a process: libsumo holds the GIL for the whole of ``simulationStep``, so a thread of this process gets almost
nothing done while SUMO steps (a pure-Python thread got 2-3 % of its free rate during it). In a process of its own
SUMO steps while this one times the controllers, polls them and writes the records.

What the run sees is what :class:`hils.sim.sumo.SumoSimulation` gives (:class:`hils.run.simulation.Simulation`):
:class:`SumoWorker` has the same ``lights`` (:class:`RemoteLight`, a :class:`hils.sim.sumo.Light` whose libsumo
calls go down the pipe), ``advance``, ``step``, ``summary``, ``finish`` and ``close``.

Why the run is the same run
---------------------------
The worker runs a :class:`~hils.sim.sumo.SumoSimulation` and makes, in the same order, the very libsumo calls it
makes in process: every call goes down one pipe, in order, and the worker carries them out one after another. What
changes what SUMO shows (a light's new state, steps) is sent without waiting for an answer; what reads SUMO (a
traffic state, queues, the summary) waits for its answer, which the worker gives after every call sent before it.
So the same seed gives the same run either way (``tests/hils/sim/test_worker.py`` holds the two equal).

Where SUMO and hils overlap
---------------------------
Between two reads: while the controllers run the steps up to an agent's next decision, SUMO steps the ones already
sent; the read at the decision waits for the rest. The states shown are the controllers' (SUMO's traffic does not
change them), so nothing hils does in between waits for SUMO, except with detector feeds (SUMO's presence SETs the
controllers at every step: every step then waits for its read, and the worker gives no overlap, only its cost).
What cannot overlap is the work from a decision's read to the first step after it: the observations, the agent, the
actions submitted and the controllers' answers to them up to that step's time (the state it shows), which on
RESCO's grid is close to half of the run's own work. The worker gains only where a core is free for it: it is off
by default (``docs/speed.md`` gives the figures).

What differs, and where the worker is not used
----------------------------------------------
- An error of a call sent without an answer (a state string SUMO refuses) is raised by the next read.
- The worker is a fresh interpreter (``python -m hils.sim.worker``): not a fork (a fork of a process that loaded
  libsumo is not a clean SUMO, :mod:`hils.sweep.grid`), nor multiprocessing's spawn (which imports the caller's main
  module again: a script without a ``__main__`` guard would run twice). It lives as long as its
  :class:`SumoProcess`: an environment's episodes run one after another in it, each a fresh SUMO, as they would in
  process. A worker that dies ends the run with a :class:`~hils.sim.sumo.SumoError` naming its exit code.
- At the wall clock a step's cost is measured where SUMO steps: the worker is for virtual time
  (``Testbed(sumo_worker=True)`` refuses a wall-clock run).
"""

from __future__ import annotations

import copyreg
import io
import os
import pickle
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from multiprocessing.connection import Connection
from types import MappingProxyType
from typing import Any

from hils.sim.sumo import PRESENCE_ZONE_M, Light, RunSummary, SumoError, SumoSimulation

__all__ = ["RemoteLight", "SumoProcess", "SumoWorker"]

#: Operations the worker answers (the others are carried out in order and answered with the next that is).
_ANSWERED = frozenset({"start", "step", "read", "light", "call", "usage"})


class SumoProcess:
    """The worker process and its pipe: one SUMO at a time, runs after runs.

    Calls are queued with :meth:`send` and go down the pipe with :meth:`flush`; :meth:`ask` sends what is queued and
    one call more, and returns its answer (raising what the worker raised on any call since the last answer)."""

    def __init__(self) -> None:
        ours, theirs = socket.socketpair()
        # A fresh interpreter running this module, not multiprocessing's spawn: that imports the caller's main module
        # again, which a script without a ``__main__`` guard does not survive. It sees what this process imports.
        path = os.pathsep.join(filter(None, sys.path))
        self._process = subprocess.Popen([sys.executable, "-m", __name__, str(theirs.fileno())],
                                         pass_fds=(theirs.fileno(),), env={**os.environ, "PYTHONPATH": path})
        theirs.close()
        self._conn = Connection(ours.detach())
        self._queued: list[tuple[Any, ...]] = []

    def send(self, *call: Any) -> None:
        self._queued.append(call)

    def flush(self) -> None:
        if self._queued:
            queued, self._queued = self._queued, []
            self._io(lambda: _send(self._conn, queued))

    def ask(self, *call: Any) -> Any:
        self._queued.append(call)
        self.flush()
        failure, answer = self._io(lambda: pickle.loads(self._conn.recv_bytes()))
        if failure is not None:
            raise failure
        return answer

    @property
    def alive(self) -> bool:
        return self._process.poll() is None

    def usage(self) -> tuple[float, float]:
        """The worker's CPU seconds so far and, of its wall time, the seconds libsumo spent stepping."""
        return self.ask("usage")

    def close(self) -> None:
        """End the worker (idempotent): it ends its SUMO, if one runs, and exits."""
        if self._conn.closed:
            return
        self._conn.close()
        try:
            self._process.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()

    def _io(self, io: Callable[[], Any]) -> Any:
        try:
            return io()
        except (EOFError, OSError):
            try:
                code = self._process.wait(timeout=1.0)
            except subprocess.TimeoutExpired:
                code = None
            raise SumoError(f"SUMO's worker process ended (exit code {code}); the run cannot go on") from None


class RemoteLight(Light):
    """A :class:`~hils.sim.sumo.Light` of the worker's SUMO: what it shows and reads goes down the pipe."""

    def __init__(self, process: SumoProcess, state: Mapping[str, Any], readings: _RemoteReadings) -> None:
        # the worker's light as it was built (phase map, lanes, what it shows), less what reads SUMO
        vars(self).update(state)
        self._process = process
        self._readings = readings

    def show(self, text: str) -> None:
        self._process.send("show", self.tls_id, text)
        self._applied = text

    def indications(self) -> str:
        return self._ask("indications")

    def present(self, zone: float = PRESENCE_ZONE_M) -> frozenset[str]:
        return self._ask("present", zone)

    def preempt_calls(self) -> frozenset[int]:
        return self._ask("preempt_calls") if self._preempt_zones else frozenset()

    def queues(self) -> dict[int, int]:
        return self._ask("queues")

    def _ask(self, method: str, *args: Any) -> Any:
        return self._process.ask("light", self.tls_id, method, *args)


class _RemoteReadings:
    """The traffic state's figures (:class:`hils.sim.sumo._Readings`), every light's lanes read in one call per
    simulated time: after a step, the first light observed reads them all."""

    def __init__(self, process: SumoProcess) -> None:
        self._process = process
        self._read: tuple[float, dict[str, Any], int, int] | None = None

    def stale(self) -> None:
        self._read = None

    def read(self, names: Sequence[str]) -> tuple[float, dict[str, Any], int, int]:
        if self._read is None:
            self._read = self._process.ask("read")
        return self._read


class SumoWorker:
    """A :class:`~hils.sim.sumo.SumoSimulation` run in ``process`` (its arguments are SumoSimulation's)."""

    def __init__(self, process: SumoProcess, **options: Any) -> None:
        self._process = process
        self._options = options
        self.seed: int = options.get("seed", 0)
        self.lights: dict[str, RemoteLight] = {}
        self._readings = _RemoteReadings(process)
        self._running = False
        self.begin = 0.0
        self.step_length = 0.0
        self.measure = options.get("measure", True)

    def start(self) -> None:
        """Start SUMO in the worker and take its traffic lights over (see :meth:`SumoSimulation.start`)."""
        lights, self.begin, self.step_length = self._process.ask("start", {**self._options, "seed": self.seed})
        self._running = True
        self._readings.stale()
        configs = self._options["lights"]
        self.lights = {tls: RemoteLight(self._process, {**state, "config": configs[tls]}, self._readings)
                       for tls, state in lights.items()}

    @property
    def running(self) -> bool:
        return self._running

    @property
    def time(self) -> float:
        return self._process.ask("call", "time")

    def step(self) -> float:
        """One SUMO step; returns the wall seconds the worker took for it."""
        self._readings.stale()
        return self._process.ask("step")

    def advance(self, steps: int) -> None:
        """``steps`` steps, sent without waiting: the worker steps them while this process goes on."""
        self._readings.stale()
        self._process.send("advance", steps)
        self._process.flush()

    def summary(self) -> RunSummary:
        return self._process.ask("call", "summary")

    def finish(self) -> RunSummary:
        summary = self._process.ask("call", "finish")
        self._running = False
        return summary

    def run_fixed_time(self) -> None:
        self._process.ask("call", "run_fixed_time")
        for light in self.lights.values():
            light.release()

    def close(self) -> None:
        """End the simulation in the worker (idempotent; nothing to end once the worker has); the worker stays for
        the next."""
        if self._running and self._process.alive:
            self._running = False
            self._process.ask("call", "close")

    def __enter__(self) -> SumoWorker:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: How what crosses the pipe is pickled: as pickle does, and a read-only mapping (a config's tables) as what it shows.
_REDUCE = {**copyreg.dispatch_table, MappingProxyType: lambda m: (_read_only, (dict(m),))}


def _read_only(mapping: dict[Any, Any]) -> MappingProxyType:
    return MappingProxyType(mapping)


def _dumps(obj: Any) -> bytes:
    out = io.BytesIO()
    pickler = pickle.Pickler(out, pickle.HIGHEST_PROTOCOL)
    pickler.dispatch_table = _REDUCE
    pickler.dump(obj)
    return out.getvalue()


def _send(conn: Connection, obj: Any) -> None:
    conn.send_bytes(_dumps(obj))


# --- the worker's side ---------------------------------------------------------------------------------------------

class _Served:
    """What the worker holds: the simulation of the run going on, and the seconds its steps took."""

    def __init__(self) -> None:
        self.sim: SumoSimulation | None = None
        self.lanes: tuple[str, ...] = ()
        self.stepping = 0.0

    def start(self, options: dict[str, Any]) -> tuple[dict[str, dict[str, Any]], float, float]:
        if self.sim is not None:
            self.sim.close()
        sim = self.sim = SumoSimulation(**options)
        sim.start()
        self.lanes = tuple(dict.fromkeys(lane for light in sim.lights.values() for lane in light.lanes))
        # the main process has the configs already, and its own readings
        return ({tls: {k: v for k, v in vars(light).items() if k not in ("_readings", "config")}
                 for tls, light in sim.lights.items()},
                sim.begin, sim.step_length)

    def show(self, tls: str, text: str) -> None:
        self.sim.lights[tls].show(text)

    def advance(self, steps: int) -> None:
        t0 = time.perf_counter()
        self.sim.advance(steps)
        self.stepping += time.perf_counter() - t0

    def step(self) -> float:
        took = self.sim.step()
        self.stepping += took
        return took

    def read(self) -> tuple[float, dict[str, Any], int, int]:
        return self.sim.read_lanes(self.lanes)

    def light(self, tls: str, method: str, *args: Any) -> Any:
        return getattr(self.sim.lights[tls], method)(*args)

    def call(self, name: str) -> Any:
        value = getattr(self.sim, name)
        return value() if callable(value) else value

    def usage(self) -> tuple[float, float]:
        return time.process_time(), self.stepping


def _serve(conn: Connection) -> None:
    """The worker's loop: carry out every call in order; answer those that are asked, with the first failure since
    the last answer. Ends when the pipe does."""
    served = _Served()
    failure: BaseException | None = None
    try:
        while True:
            try:
                calls = pickle.loads(conn.recv_bytes())
            except EOFError:
                return
            for name, *args in calls:
                answer = None
                if failure is None:
                    try:
                        answer = getattr(served, name)(*args)
                    except Exception as exc:  # raised in the main process by the next answer
                        failure = exc if _picklable(exc) else SumoError(f"{type(exc).__name__}: {exc}")
                if name in _ANSWERED:
                    _send(conn, (failure, answer))
                    failure = None
    finally:
        if served.sim is not None:
            served.sim.close()


def _picklable(exc: BaseException) -> bool:
    try:
        pickle.loads(_dumps(exc))
    except Exception:  # anything that does not survive the pipe is sent as text
        return False
    return True


if __name__ == "__main__":
    # Ctrl-C reaches the whole process group: the run that was interrupted still ends with SUMO's summary, so the
    # worker leaves it to the main process and ends when its pipe does.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _serve(Connection(int(sys.argv[1])))
