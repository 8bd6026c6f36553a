"""Action conversion and conflict detection on the shipped paper intersection."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hils.control.actions import (
    ActionConverter,
    ActionError,
    ActionType,
    ActionTypeError,
    Command,
    ConflictError,
    ConflictMatrix,
    DurationRangeError,
    NotInActionSetError,
    UnknownPhaseError,
)
from hils.protocol.config import IntersectionConfig

# The matrix printed in the paper: 1 marks the eight compatible pairs (its text calls them conflicts).
PAPER_MATRIX = [
    [0, 0, 0, 0, 1, 1, 0, 0],
    [0, 0, 0, 0, 1, 1, 0, 0],
    [0, 0, 0, 0, 0, 0, 1, 1],
    [0, 0, 0, 0, 0, 0, 1, 1],
    [1, 1, 0, 0, 0, 0, 0, 0],
    [1, 1, 0, 0, 0, 0, 0, 0],
    [0, 0, 1, 1, 0, 0, 0, 0],
    [0, 0, 1, 1, 0, 0, 0, 0],
]


class Positioned:
    """A converter at a position of the cyclic sequence, moved as the manager moves it."""

    def __init__(self, config: IntersectionConfig, action_type: ActionType, greens: frozenset[int] | None) -> None:
        self.conv = ActionConverter(config, action_type)
        self.sequence = config.sequence
        self.position = next((i for i, pair in enumerate(self.sequence) if greens and set(pair) <= greens), -1)

    def convert(self, value: object) -> Command:
        return self.conv.convert(value, self.position)

    def commit(self, command: Command) -> None:
        self.position = self.sequence.index(command.phases)

    @property
    def current_pair(self) -> tuple[int, int] | None:
        return self.conv.pair_at(self.position)

    def green_range(self, pair: tuple[int, int]) -> tuple[float, float]:
        return self.conv.green_range(pair)


def converter(config: IntersectionConfig, action_type: ActionType, greens: frozenset[int] | None = None):
    return Positioned(config, action_type, greens)


# --- conflict matrix -------------------------------------------------------------------------


def test_derived_conflict_matrix_is_the_papers_matrix_inverted(paper_config: IntersectionConfig) -> None:
    matrix = ConflictMatrix(paper_config)
    expected = [[int(i != j and not PAPER_MATRIX[i][j]) for j in range(8)] for i in range(8)]
    assert matrix.phases == (1, 2, 3, 4, 5, 6, 7, 8)
    assert matrix.as_rows() == expected
    compatible = {(a, b) for a in range(1, 9) for b in range(a + 1, 9) if not matrix.conflict(a, b)}
    assert compatible == {(1, 5), (1, 6), (2, 5), (2, 6), (3, 7), (3, 8), (4, 7), (4, 8)}


# --- phase selection -------------------------------------------------------------------------


@pytest.mark.parametrize(("value", "pair"), [
    ((1, 5), (1, 5)), ([2, 6], (2, 6)), ((7, 3), (3, 7)), ([8, 4], (4, 8)),
    (np.array([5, 1]), (1, 5)), ((np.int64(2), np.int32(6)), (2, 6)),
    # What RL libraries hand over: float arrays with integral values, numpy scalars of either kind.
    (np.array([2.0, 6.0], dtype=np.float32), (2, 6)), ([1.0, 5.0], (1, 5)), ((np.float64(4), np.int8(8)), (4, 8)),
])
def test_selection_is_normalised_to_ring1_ring2(paper_config, value, pair) -> None:
    cmd = converter(paper_config, ActionType.SELECTION).convert(value)
    assert cmd == Command(pair)
    assert all(type(p) is int for p in cmd.phases)


@pytest.mark.parametrize(("value", "error", "words"), [
    ([1, 2], ConflictError, ["1 and 2 conflict", "allowed", "1, 5"]),
    ([2, 3], ConflictError, ["2 and 3 conflict", "allowed"]),
    ([1, 7], ConflictError, ["1 and 7 conflict", "allowed"]),
    ([5, 5], ConflictError, ["5 and 5 conflict"]),
    ([1, 9], UnknownPhaseError, ["unknown phase 9", "allowed phases", "1, 2, 3, 4, 5, 6, 7, 8"]),
    ([0, 5], UnknownPhaseError, ["unknown phase 0", "allowed phases"]),
    ([1, 6], NotInActionSetError, ["[1, 6]", "not in the configured set", "allowed", "4, 8"]),
    ([5, 2], NotInActionSetError, ["[2, 5]", "not in the configured set"]),
    ((1, 5, 2), ActionTypeError, ["pair of phase numbers", "(1, 5, 2)", "allowed"]),
    ("15", ActionTypeError, ["pair of phase numbers", "'15'"]),
    ([1.5, 5.0], ActionTypeError, ["pair of phase numbers"]),
    ({1, 5}, ActionTypeError, ["pair of phase numbers", "{1, 5}"]),
    ({1: 5, 2: 6}, ActionTypeError, ["pair of phase numbers"]),
    (np.array([[1, 5]]), ActionTypeError, ["pair of phase numbers"]),
    ([float("inf"), 5], ActionTypeError, ["pair of phase numbers"]),
    ([2**70, 5], UnknownPhaseError, ["unknown phase 1180591620717411303424"]),
    ([True, 5], ActionTypeError, ["pair of phase numbers"]),
    (None, ActionTypeError, ["pair of phase numbers", "None"]),
    (3, ActionTypeError, ["pair of phase numbers", "got 3"]),
])
def test_selection_refusals_are_typed_and_explain(paper_config, value, error, words) -> None:
    with pytest.raises(error) as info:
        converter(paper_config, ActionType.SELECTION).convert(value)
    assert isinstance(info.value, ActionError)
    for word in words:
        assert word in str(info.value)


def test_refusal_reasons_are_distinct(paper_config) -> None:
    reasons = {cls.reason for cls in (ActionTypeError, UnknownPhaseError, ConflictError, NotInActionSetError,
                                      DurationRangeError)}
    assert len(reasons) == 5
    assert issubclass(ActionTypeError, TypeError)


# --- phase switch ------------------------------------------------------------------------------


def test_switch_advances_through_the_sequence_and_wraps(paper_config) -> None:
    conv = converter(paper_config, ActionType.SWITCH, frozenset({2, 6}))
    assert conv.current_pair == (2, 6)
    seen = []
    for _ in range(5):
        cmd = conv.convert(1)
        assert not cmd.keep and cmd.green is None
        conv.commit(cmd)
        seen.append(cmd.phases)
    assert seen == [(3, 7), (4, 8), (1, 5), (2, 6), (3, 7)]


def test_switch_keep_stays_on_the_current_pair(paper_config) -> None:
    conv = converter(paper_config, ActionType.SWITCH, frozenset({4, 8}))
    assert conv.convert(0) == Command((4, 8), keep=True)
    assert conv.convert(np.int64(0)) == Command((4, 8), keep=True)
    assert conv.convert(np.int64(1)) == Command((1, 5))
    assert conv.position == paper_config.sequence.index((4, 8)), "converting alone must not move the position"


@pytest.mark.parametrize("value", [np.float32(1.0), 1.0, np.array(1), np.array([1]), np.array([1.0], dtype=np.float32),
                                   np.uint8(1)])
def test_switch_accepts_what_rl_libraries_hand_over(paper_config, value) -> None:
    assert converter(paper_config, ActionType.SWITCH, frozenset({2, 6})).convert(value) == Command((3, 7))


@pytest.mark.parametrize(("value", "green"), [(np.array([0.5], dtype=np.float32), 11.5), (np.array(0.0), 3.0),
                                              (np.array([1.0]), 20.0)])
def test_duration_accepts_box_actions(paper_config, value, green) -> None:
    assert converter(paper_config, ActionType.DURATION, frozenset({2, 6})).convert(value).green == green


@pytest.mark.parametrize(("value", "error"), [(10**400, DurationRangeError), (np.array([0.5, 0.5]), ActionTypeError),
                                              ("0.5", ActionTypeError)])
def test_duration_refuses_overflow_and_wrong_shapes(paper_config, value, error) -> None:
    with pytest.raises(error):
        converter(paper_config, ActionType.DURATION, frozenset({2, 6})).convert(value)


def test_switch_keep_before_any_pair_is_known_commands_the_first(paper_config) -> None:
    # Nothing of the sequence is green (all red at start-up): "keep" cannot keep anything.
    assert converter(paper_config, ActionType.SWITCH, frozenset()).convert(0) == Command((1, 5))


@pytest.mark.parametrize("value", [2, -1, True, False, np.bool_(True), 0.5, "1", None, [1], 2**80,
                                   np.array([1, 0]), float("nan")])
def test_switch_refuses_anything_but_0_or_1(paper_config, value) -> None:
    with pytest.raises(ActionTypeError) as info:
        converter(paper_config, ActionType.SWITCH, frozenset({2, 6})).convert(value)
    assert "0 (keep) or 1 (advance)" in str(info.value)
    assert repr(value) in str(info.value)


# --- phase duration ------------------------------------------------------------------------------


@pytest.mark.parametrize(("x", "green"), [
    (0, 3.0), (0.0, 3.0), (1, 20.0), (1.0, 20.0), (0.5, 11.5), (0.25, 7.25),
    (np.float32(0.5), 11.5), (np.float64(1.0), 20.0), (np.int64(0), 3.0),
])
def test_duration_maps_x_to_green_of_the_next_pair(paper_config, x, green) -> None:
    conv = converter(paper_config, ActionType.DURATION, frozenset({2, 6}))
    cmd = conv.convert(x)
    assert cmd.phases == (3, 7)
    assert not cmd.keep
    assert math.isclose(cmd.green, green, abs_tol=1e-9)
    assert type(cmd.green) is float
    assert conv.green_range((3, 7)) == (3.0, 20.0)


def test_duration_follows_the_sequence_as_commands_are_committed(paper_config) -> None:
    conv = converter(paper_config, ActionType.DURATION, frozenset({4, 8}))
    pairs = []
    for _ in range(4):
        cmd = conv.convert(0.5)
        conv.commit(cmd)
        pairs.append(cmd.phases)
    assert pairs == [(1, 5), (2, 6), (3, 7), (4, 8)]


@pytest.mark.parametrize(("x", "error", "words"), [
    (float("nan"), DurationRangeError, ["nan", "outside [0, 1]", "0 <= x <= 1"]),
    (float("inf"), DurationRangeError, ["inf", "outside [0, 1]"]),
    (float("-inf"), DurationRangeError, ["outside [0, 1]"]),
    (-0.1, DurationRangeError, ["-0.1", "outside [0, 1]", "0 = minimum green"]),
    (1.1, DurationRangeError, ["1.1", "outside [0, 1]"]),
    (np.float32("nan"), DurationRangeError, ["outside [0, 1]"]),
    ("1", ActionTypeError, ["number x in [0, 1]", "'1'"]),
    (True, ActionTypeError, ["number x in [0, 1]", "True"]),
    (None, ActionTypeError, ["number x in [0, 1]", "None"]),
    ([0.5], ActionTypeError, ["number x in [0, 1]"]),
])
def test_duration_refusals_are_typed_and_explain(paper_config, x, error, words) -> None:
    with pytest.raises(error) as info:
        converter(paper_config, ActionType.DURATION, frozenset({2, 6})).convert(x)
    for word in words:
        assert word in str(info.value)


def test_green_range_takes_the_tighter_bounds_of_a_pair(paper_toml) -> None:
    from hils.protocol.config import parse

    text = paper_toml.replace('1 = { approach = "west", turn = "left" }',
                              '1 = { approach = "west", turn = "left", min_green = 5, max_green = 15 }')
    conv = ActionConverter(parse(text), ActionType.DURATION)
    assert conv.green_range((1, 5)) == (5.0, 15.0)
    assert conv.green_range((2, 6)) == (3.0, 20.0)
    assert conv.convert(1.0).phases == (1, 5)
    assert conv.convert(1.0).green == 15.0


def test_action_type_is_validated(paper_config) -> None:
    assert ActionConverter(paper_config, "switch").action_type is ActionType.SWITCH
    with pytest.raises(ValueError, match="sideways"):
        ActionConverter(paper_config, "sideways")
