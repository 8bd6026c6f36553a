"""A hi-res log's inputs run into the emulator's controller model in process, in virtual time.

The bench of `hils replay` by default (Signal-Replay at the wall clock is the other, ``--bench signal-replay``): the
log's vehicle detector (81/82), push-button (89/90) and preempt input (102/104) events are the cabinet's inputs,
and the model (:class:`emulator.model.controller.Controller`, with its data logger) runs them with the config the
replay is given, as `hils emulator serve` would, without a wire or a clock to wait for.

Times
-----
The model's clock is the log's: it powers up at the log's first tenth of a second (``Controller(start=...)``), so
a logged event's time and the model's are the same clock and nothing has to be shifted afterwards. A config whose
``[emulator] start`` is earlier on the log's first day powers up there and runs without inputs until the log begins
(:func:`power_up`): the inference writes so for a log that begins in the middle of a green whose minimum has run.
An input logged at tick ``t`` was read by the field controller at that tick, as the data logger logs a detector
change on the tick that reads it: the model is advanced to tick ``t - 1`` (quiet stretches skipped at once,
:meth:`Controller.advance`), given the input, and stepped once. So every input lands on the tick it was logged
at, whatever the log's length, and the run is the same every time (the model is deterministic; nothing here
draws a random number). After the last input the model runs to the log's last event, so the bench's log spans the
field's and the match has no cutoff.

A detector whose first event in the log is an off was on when the log began (a vehicle on the loop across the
log's start): it starts actuated.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from itertools import groupby
from typing import Protocol

from emulator.model.controller import Controller
from emulator.model.datalogger import DataLogger
from hils.protocol.config import IntersectionConfig
from hils.protocol.hires import Event, EventCode

E = EventCode
TICK = timedelta(milliseconds=100)
#: input event -> (which input, on?)
INPUTS = {E.DETECTOR_ON: ("vehicle", True), E.DETECTOR_OFF: ("vehicle", False),
          E.PED_DETECTOR_ON: ("pedestrian", True), E.PED_DETECTOR_OFF: ("pedestrian", False),
          E.PREEMPT_CALL_INPUT_ON: ("preempt", True), E.PREEMPT_CALL_INPUT_OFF: ("preempt", False)}


class _Logged(Protocol):
    """A logged event (a file's row or the model's event)."""

    time: datetime
    code: int
    parameter: int


@dataclass(frozen=True, slots=True)
class Run:
    """The bench's events, the log's span it covered and how many inputs it replayed."""

    events: list[Event]
    start: datetime
    end: datetime
    inputs: int


def floor_tick(t: datetime) -> datetime:
    return t.replace(microsecond=t.microsecond // 100_000 * 100_000)


def run(rows: Sequence[_Logged], config: IntersectionConfig) -> Run:
    """The model under ``config`` given the inputs of ``rows`` (time order) at their ticks (see the header)."""
    if not rows:
        raise ValueError("an empty log has no inputs to replay")
    start, end = floor_tick(rows[0].time), floor_tick(rows[-1].time)
    powered = power_up(config, start)
    controller = Controller(config, start=powered)
    clock = controller.coordinator  # its clock counts ticks since midnight of the power-up's day
    zero = clock.clock + _ticks(start - powered)
    on = _on_at_start(r for r in rows if r.code in INPUTS)
    if powered < start:  # running with no input until the log begins, then the inputs on at its start
        logger = DataLogger(controller)
        controller.advance(zero - clock.clock)
        _apply(controller, on)
    else:
        _apply(controller, on)
        logger = DataLogger(controller)  # after: it logs the inputs on at the start with the power-up
    replayed = 0
    for tick, same in groupby((r for r in rows if r.code in INPUTS), key=lambda r: _ticks(r.time - start)):
        controller.advance(zero + tick - 1 - clock.clock)
        for r in same:
            kind, is_on = INPUTS[E(r.code)]
            (on[kind].add if is_on else on[kind].discard)(r.parameter)
            replayed += 1
        _apply(controller, on)
        controller.step()
    controller.advance(zero + _ticks(end - start) - clock.clock)
    return Run(logger.events(), start, end, replayed)


def power_up(config: IntersectionConfig, start: datetime) -> datetime:
    """When the model powers up for a log beginning at ``start``: the config's ``[emulator] start`` when it falls
    earlier on the log's first day (a config written from a log that began in the middle of a green: the controller
    was running before the log), else the log's first tenth."""
    at = config.emulator.start
    return at if at.date() == start.date() and at < start else start


def _ticks(span: timedelta) -> int:
    return span // TICK


def _on_at_start(inputs: Iterable[_Logged]) -> dict[str, set[int]]:
    """The inputs on when the log began: those whose first event is an off."""
    first: dict[tuple[str, int], bool] = {}
    for r in inputs:
        kind, is_on = INPUTS[E(r.code)]
        first.setdefault((kind, r.parameter), is_on)
    on: dict[str, set[int]] = {"vehicle": set(), "pedestrian": set(), "preempt": set()}
    for (kind, n), is_on in first.items():
        if not is_on:
            on[kind].add(n)
    return on


def _apply(controller: Controller, on: dict[str, set[int]]) -> None:
    if frozenset(on["vehicle"]) != controller.actuations:
        controller.set_actuations(on["vehicle"])
    if frozenset(on["pedestrian"]) != controller.ped_actuations:
        controller.set_ped_actuations(on["pedestrian"])
    if frozenset(on["preempt"]) != controller.preemptor.control:
        controller.set_preempt_control(on["preempt"])
