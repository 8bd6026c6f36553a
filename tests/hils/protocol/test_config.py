"""Config loading and validation: the shipped paper intersection and every rejection."""

from __future__ import annotations

from pathlib import Path

import pytest

from hils.protocol.config import ConfigError, IntersectionConfig, MiddlewareParams, load, parse
from hils.protocol.ntcip import PhaseStartup

SOURCE = "site/test.toml"
ALL_PHASES = range(1, 9)
PAPER_COMPATIBLE = {(1, 5), (1, 6), (2, 5), (2, 6), (3, 7), (3, 8), (4, 7), (4, 8)}


def toml(*, timing: str = "min_green = 3\nmax_green = 20\nyellow = 3.0\nred_clear = 2.0",
         phases: dict[int, str] | None = None,
         rings: str = "[[1, 2, 3, 4], [5, 6, 7, 8]]",
         barriers: str = "[[1, 2, 5, 6], [3, 4, 7, 8]]",
         sequence: str = "[[1, 5], [2, 6], [3, 7], [4, 8]]",
         pairs: str = "[[1, 5], [2, 6], [3, 7], [4, 8]]",
         structure_extra: str = "", top_extra: str = "", middleware: str = "") -> str:
    """A valid dual-ring eight-phase config, with the given parts replaced."""
    phases = {p: "{}" for p in ALL_PHASES} | (phases or {})
    phase_lines = "\n".join(f"{p} = {body}" for p, body in sorted(phases.items()))
    return (f'name = "test"\n{top_extra}\n[timing]\n{timing}\n[phases]\n{phase_lines}\n'
            f"[structure]\nrings = {rings}\nbarriers = {barriers}\nsequence = {sequence}\npairs = {pairs}\n"
            f"{structure_extra}\n[middleware]\n{middleware}\n")


def rejected(text: str) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        parse(text, SOURCE)
    err = info.value
    # Every rejection names the file first, then the field.
    assert str(err).startswith(f"{SOURCE}: {err.field}: ")
    return err


def matrix(marked: set[tuple[int, int]]) -> str:
    """An 8x8 TOML matrix with 1 at the given pairs (both ways round)."""
    rows = [[1 if (i, j) in marked or (j, i) in marked else 0 for j in ALL_PHASES] for i in ALL_PHASES]
    return "[" + ", ".join(str(r) for r in rows) + "]"


# --- the shipped default ---------------------------------------------------------------


def test_default_loads_from_any_working_directory_with_the_papers_parameters(tmp_path: Path,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    cfg = load()
    assert cfg.phase_numbers == tuple(ALL_PHASES)
    assert cfg.rings == ((1, 2, 3, 4), (5, 6, 7, 8))
    assert cfg.barriers == (frozenset({1, 2, 5, 6}), frozenset({3, 4, 7, 8}))
    assert cfg.pairs == ((1, 5), (2, 6), (3, 7), (4, 8))
    assert cfg.sequence == ((1, 5), (2, 6), (3, 7), (4, 8))
    assert cfg.groups == 1
    for p, ph in cfg.phases.items():
        assert (ph.number, ph.min_green, ph.max_green, ph.yellow, ph.red_clear) == (p, 3, 20, 3, 2)
        assert ph.clearance == 5
        assert ph.ring == (1 if p <= 4 else 2)
    assert {p for p, ph in cfg.phases.items() if ph.startup is PhaseStartup.GREEN_NO_WALK} == {2, 6}
    mw = cfg.middleware
    assert (mw.poll_hz, mw.tau_udp, mw.tau_trans, mw.n_timeout, mw.n_drift) == (10, 1, 10, 5, 5)
    assert (mw.sumo_step, mw.control_interval) == (0.25, 10)
    assert mw.poll_period == pytest.approx(0.1)
    assert mw.keepalive_period < mw.backup_time


def test_derived_compatibility_is_exactly_the_papers_eight_pairs(paper_config: IntersectionConfig) -> None:
    assert paper_config.compatibility == {frozenset(p) for p in PAPER_COMPATIBLE}
    for a in ALL_PHASES:
        for b in ALL_PHASES:
            expected = (min(a, b), max(a, b)) in PAPER_COMPATIBLE
            assert paper_config.compatible(a, b) is expected, (a, b)


def test_ring_and_barrier_lookups(paper_config: IntersectionConfig) -> None:
    assert [paper_config.ring_of(p) for p in ALL_PHASES] == [1, 1, 1, 1, 2, 2, 2, 2]
    assert [paper_config.barrier_of(p) for p in ALL_PHASES] == [0, 0, 1, 1, 0, 0, 1, 1]


def test_load_by_path_matches_the_default(tmp_path: Path, paper_toml: str,
                                          paper_config: IntersectionConfig) -> None:
    path = tmp_path / "copy.toml"
    path.write_text(paper_toml, encoding="utf-8")
    cfg = load(path)
    assert cfg.source == str(path)
    assert (cfg.phases, cfg.rings, cfg.pairs, cfg.compatibility, cfg.middleware) == (
        paper_config.phases, paper_config.rings, paper_config.pairs, paper_config.compatibility,
        paper_config.middleware)


def test_missing_file_names_the_file(tmp_path: Path) -> None:
    missing = tmp_path / "nope.toml"
    with pytest.raises(ConfigError) as info:
        load(missing)
    assert info.value.source == str(missing)
    assert str(missing) in str(info.value)
    assert "cannot be read" in info.value.message


def test_a_binary_file_is_refused_naming_it(tmp_path: Path) -> None:
    binary = tmp_path / "config.toml"
    binary.write_bytes(bytes(range(256)))
    with pytest.raises(ConfigError) as info:
        load(binary)
    assert str(binary) in str(info.value) and "not UTF-8 text; allowed: a TOML file" in info.value.message


def test_the_builder_makes_a_valid_config() -> None:
    cfg = parse(toml(), SOURCE)
    assert cfg.compatibility == {frozenset(p) for p in PAPER_COMPATIBLE}
    assert cfg.source == SOURCE


def test_per_phase_values_override_the_shared_timing() -> None:
    cfg = parse(toml(phases={4: "{ min_green = 5, max_green = 40, yellow = 4.5, red_clear = 1.5 }"}), SOURCE)
    ph = cfg.phases[4]
    assert (ph.min_green, ph.max_green, ph.yellow, ph.red_clear) == (5, 40, 4.5, 1.5)
    assert cfg.phases[3].max_green == 20


# --- explicit matrices --------------------------------------------------------------------


def test_an_explicit_compatibility_matrix_is_honoured() -> None:
    allowed = PAPER_COMPATIBLE - {(2, 5)}
    cfg = parse(toml(structure_extra=f"compatibility = {matrix(allowed)}"), SOURCE)
    assert cfg.compatibility == {frozenset(p) for p in allowed}
    assert not cfg.compatible(2, 5)
    assert cfg.compatible(5, 1)


def test_an_explicit_conflict_matrix_marks_conflicts() -> None:
    conflicts = {(a, b) for a in ALL_PHASES for b in ALL_PHASES if a < b} - PAPER_COMPATIBLE | {(1, 6)}
    cfg = parse(toml(structure_extra=f"conflict = {matrix(conflicts)}"), SOURCE)
    assert cfg.compatibility == {frozenset(p) for p in PAPER_COMPATIBLE - {(1, 6)}}


def test_an_explicit_matrix_allowing_nothing_is_not_replaced_by_the_derived_one() -> None:
    err = rejected(toml(structure_extra=f"compatibility = {matrix(set())}"))
    assert err.field == "structure.pairs[0]"
    assert "phases 1 and 5 conflict" in err.message


def test_a_pair_the_explicit_matrix_forbids_is_rejected() -> None:
    err = rejected(toml(structure_extra=f"compatibility = {matrix(PAPER_COMPATIBLE - {(3, 7)})}"))
    assert err.field == "structure.pairs[2]"
    assert "phases 3 and 7 conflict" in err.message


def test_start_up_phases_the_explicit_matrix_forbids_are_rejected() -> None:
    err = rejected(toml(phases={2: '{ startup = "green" }', 6: '{ startup = "green" }'},
                        sequence="[[1, 5], [3, 7], [4, 8]]", pairs="[[1, 5], [3, 7], [4, 8]]",
                        structure_extra=f"compatibility = {matrix(PAPER_COMPATIBLE - {(2, 6)})}"))
    assert err.field == "phases.6.startup"
    assert "allowed" in err.message


@pytest.mark.parametrize("key", ["compatibility", "conflict"])
def test_an_asymmetric_matrix_is_rejected(key: str) -> None:
    rows = [[0] * 8 for _ in ALL_PHASES]
    rows[0][4] = 1  # [1][5] set, [5][1] not
    err = rejected(toml(structure_extra=f"{key} = {rows}"))
    assert err.field == f"structure.{key}"
    assert "not symmetric" in err.message
    assert "[1][5] = 1" in err.message and "[5][1] = 0" in err.message
    assert "allowed: symmetric" in err.message


@pytest.mark.parametrize("value", ["[[0, 1], [1, 0]]", "[[0, 0, 0, 0, 0, 0, 0, 2]] ", "true"])
def test_a_malformed_matrix_is_rejected(value: str) -> None:
    err = rejected(toml(structure_extra=f"compatibility = {value}"))
    assert err.field == "structure.compatibility"
    assert "8x8 matrix of 0 and 1" in err.message


def test_both_matrices_at_once_are_rejected() -> None:
    err = rejected(toml(structure_extra=f"compatibility = {matrix(PAPER_COMPATIBLE)}\n"
                                        f"conflict = {matrix(set())}"))
    assert "either compatibility or conflict" in err.message


# --- structural rejections ---------------------------------------------------------------


def test_a_phase_in_two_rings_is_rejected() -> None:
    err = rejected(toml(rings="[[1, 2, 3, 4], [5, 6, 7, 8, 2]]"))
    assert err.field == "structure.rings[1]"
    assert "phase 2 is in rings 1 and 2" in err.message
    assert "allowed: one ring per phase" in err.message


def test_a_phase_in_no_ring_is_rejected() -> None:
    err = rejected(toml(rings="[[1, 2, 3, 4], [5, 6, 7]]"))
    assert err.field == "phases.8"
    assert "no ring" in err.message


@pytest.mark.parametrize("key", ["pairs", "sequence"])
def test_a_conflicting_pair_is_rejected(key: str) -> None:
    err = rejected(toml(**{key: "[[1, 5], [2, 7]]"}))
    assert err.field == f"structure.{key}[1]"
    assert "phases 2 and 7 conflict" in err.message
    assert "allowed: compatible pairs" in err.message


@pytest.mark.parametrize("key", ["pairs", "sequence"])
def test_a_pair_in_the_wrong_ring_order_is_rejected(key: str) -> None:
    err = rejected(toml(**{key: "[[5, 1]]"}))
    assert err.field == f"structure.{key}[0]"
    assert "a ring 1 phase first, then a ring 2 phase" in err.message


@pytest.mark.parametrize("key", ["pairs", "sequence"])
def test_a_pair_of_three_phases_is_rejected(key: str) -> None:
    err = rejected(toml(**{key: "[[1, 5, 6]]"}))
    assert err.field == f"structure.{key}[0]"
    assert "exactly two phases" in err.message


@pytest.mark.parametrize("key", ["pairs", "sequence"])
def test_an_empty_pair_list_is_rejected(key: str) -> None:
    assert rejected(toml(**{key: "[]"})).field == f"structure.{key}"


@pytest.mark.parametrize(("part", "value", "field"), [
    ("rings", "[[1, 2, 3, 4, 9], [5, 6, 7, 8]]", "structure.rings[0]"),
    ("barriers", "[[1, 2, 5, 6], [3, 4, 7, 8, 9]]", "structure.barriers[1]"),
    ("pairs", "[[1, 5], [2, 9]]", "structure.pairs[1]"),
    ("sequence", "[[1, 5], [2, 6], [3, 7], [4, 0]]", "structure.sequence[3]"),
])
def test_an_unknown_phase_number_is_rejected(part: str, value: str, field: str) -> None:
    err = rejected(toml(**{part: value}))
    assert err.field == field
    assert "unknown phase" in err.message
    assert "allowed: [1, 2, 3, 4, 5, 6, 7, 8]" in err.message


@pytest.mark.parametrize("key", ["300", "0", "01", "x"])
def test_a_phase_key_that_is_not_a_phase_number_is_rejected(key: str) -> None:
    text = toml().replace("[structure]", f"{key} = {{}}\n[structure]")
    err = rejected(text)
    assert err.field == f"phases.{key}"
    assert "allowed: 1..255" in err.message


def test_a_phase_min_green_above_the_shared_max_green_names_the_phase() -> None:
    err = rejected(toml(phases={6: "{ min_green = 25 }"}))
    assert err.field == "phases.6.max_green"
    assert "is 20 s, below min_green 25 s" in err.message


def test_a_phase_in_two_barrier_groups_is_rejected() -> None:
    err = rejected(toml(barriers="[[1, 2, 5, 6], [3, 4, 7, 8, 1]]"))
    assert err.field == "structure.barriers[1]"
    assert "phase 1 is in barrier groups 0 and 1" in err.message


def test_a_phase_in_no_barrier_group_is_rejected() -> None:
    err = rejected(toml(barriers="[[1, 2, 5, 6], [3, 4, 7]]"))
    assert err.field == "structure.barriers"
    assert "phase 8 is in no barrier group" in err.message


def test_a_ring_out_of_barrier_order_is_rejected() -> None:
    err = rejected(toml(rings="[[3, 1, 2, 4], [5, 6, 7, 8]]"))
    assert err.field == "structure.rings[0]"
    assert "barrier order" in err.message


def test_three_rings_are_rejected() -> None:
    assert rejected(toml(rings="[[1, 2], [3, 4], [5, 6, 7, 8]]")).field == "structure.rings"


def test_start_up_phases_in_one_ring_are_rejected() -> None:
    err = rejected(toml(phases={1: '{ startup = "green" }', 2: '{ startup = "green" }'}))
    assert err.field == "phases.2.startup"
    assert "cannot start together with phase 1" in err.message


def test_start_up_phases_across_a_barrier_are_rejected() -> None:
    err = rejected(toml(phases={2: '{ startup = "green" }', 7: '{ startup = "green" }'}))
    assert err.field == "phases.7.startup"


# --- timing rejections -----------------------------------------------------------------


def test_max_green_below_min_green_is_rejected() -> None:
    err = rejected(toml(phases={3: "{ min_green = 10, max_green = 8 }"}))
    assert err.field == "phases.3.max_green"
    assert "below min_green 10 s" in err.message
    assert "allowed: max_green >= min_green" in err.message


def test_a_shared_max_green_below_min_green_names_the_timing_table() -> None:
    err = rejected(toml(timing="min_green = 5\nmax_green = 4\nyellow = 3.0\nred_clear = 2.0"))
    assert err.field == "timing.max_green"
    assert "allowed: max_green >= min_green" in err.message


@pytest.mark.parametrize("value", ["0", "0.0", "-1.0"])
def test_non_positive_red_clearance_is_rejected(value: str) -> None:
    err = rejected(toml(phases={5: f"{{ red_clear = {value} }}"}))
    assert err.field == "phases.5.red_clear"
    assert "allowed: > 0" in err.message


def test_non_positive_shared_red_clearance_names_the_timing_table() -> None:
    err = rejected(toml(timing="min_green = 3\nmax_green = 20\nyellow = 3.0\nred_clear = -2.0"))
    assert err.field == "timing.red_clear"
    assert "allowed: > 0" in err.message


@pytest.mark.parametrize("key", ["yellow", "red_clear"])
@pytest.mark.parametrize("value", ["3.05", "4.01", "3.25"])
def test_clearance_not_in_tenths_is_rejected(key: str, value: str) -> None:
    err = rejected(toml(phases={1: f"{{ {key} = {value} }}"}))
    assert err.field == f"phases.1.{key}"
    assert "allowed: multiples of 0.1 s" in err.message


@pytest.mark.parametrize("value", ["3.0", "4.7", "25.5"])
def test_clearance_in_tenths_is_accepted(value: str) -> None:
    assert parse(toml(phases={1: f"{{ yellow = {value} }}"}), SOURCE).phases[1].yellow == float(value)


def test_clearance_above_the_ntcip_range_is_rejected() -> None:
    err = rejected(toml(phases={1: "{ red_clear = 25.6 }"}))
    assert "<= 25.5" in err.message


# NTCIP 1202 v03 phaseTable (1202v0328.MIB): phaseYellowChange "in tenth seconds (NEMA TS 2 range: 3-25.5 sec)";
# the other times fit their objects' SYNTAX INTEGER (0..255) in seconds or tenths.
@pytest.mark.parametrize(("key", "value", "field", "allowed"), [
    ("yellow", "0.1", "phases.1.yellow", "allowed: >= 3.0 and <= 25.5 s (NTCIP 1202 phaseYellowChange: 30-255 tenths "
                                         "of a second)"),
    ("yellow", "2.9", "phases.1.yellow", "allowed: >= 3.0 and <= 25.5 s (NTCIP 1202 phaseYellowChange"),
    ("yellow", "25.6", "phases.1.yellow", "allowed: >= 3.0 and <= 25.5 s (NTCIP 1202 phaseYellowChange"),
    ("red_revert", "25.6", "phases.1.red_revert", "allowed: >= 0.0 and <= 25.5 s (NTCIP 1202 phaseRedRevert: 0-255 "
                                                  "tenths of a second)"),
    ("passage", "25.6", "phases.1.passage", "<= 25.5 s (NTCIP 1202 phasePassage: 0-255 tenths of a second)"),
    ("walk", "256", "phases.1.walk", "<= 255 s (NTCIP 1202 phaseWalk: 0-255 seconds)"),
    ("max_green", "256", "phases.1.max_green", "allowed: >= 1 and <= 255 s (NTCIP 1202 phaseMaximum1: 0-255 "
                                               "seconds)"),
])
def test_a_time_its_ntcip_object_cannot_carry_is_refused_naming_the_range(key: str, value: str, field: str,
                                                                          allowed: str) -> None:
    err = rejected(toml(phases={1: f"{{ {key} = {value} }}"}))
    assert err.field == field
    assert allowed in err.message
    assert str(err).startswith(f"{SOURCE}: {field}: is {value}; ")


def test_a_shared_yellow_the_standard_cannot_carry_names_the_timing_table() -> None:
    err = rejected(toml(timing="min_green = 3\nmax_green = 20\nyellow = 0.1\nred_clear = 2.0"))
    assert err.field == "timing.yellow"
    assert "allowed: >= 3.0 and <= 25.5 s (NTCIP 1202 phaseYellowChange" in err.message


@pytest.mark.parametrize("value", ["0", "-3"])
def test_non_positive_min_green_is_rejected(value: str) -> None:
    err = rejected(toml(phases={1: f"{{ min_green = {value} }}"}))
    assert err.field == "phases.1.min_green"
    assert "allowed: >= 1" in err.message


def test_a_missing_timing_is_rejected() -> None:
    err = rejected(toml(timing="min_green = 3\nmax_green = 20\nyellow = 3.0"))
    assert err.field == "phases.1.red_clear"
    assert "is required" in err.message


# --- unknown keys and wrong types ---------------------------------------------------------


@pytest.mark.parametrize(("text", "field"), [
    (toml(top_extra="colour = 1"), "colour"),
    (toml(timing="min_green = 3\nmax_green = 20\nyellow = 3.0\nred_clear = 2.0\nall_red = 1"), "timing.all_red"),
    (toml(phases={2: "{ gap_time = 2 }"}), "phases.2.gap_time"),
    (toml(structure_extra="offset = 3"), "structure.offset"),
    (toml(middleware="poll = 10"), "middleware.poll"),
])
def test_an_unknown_key_is_rejected_with_the_allowed_keys(text: str, field: str) -> None:
    err = rejected(text)
    assert err.field == field
    assert err.message.startswith("unknown field; allowed: ")


@pytest.mark.parametrize(("text", "field", "expected"), [
    (toml(phases={1: '{ min_green = "3" }'}), "phases.1.min_green", "must be an integer"),
    (toml(phases={1: "{ min_green = 3.5 }"}), "phases.1.min_green", "must be an integer"),
    (toml(phases={1: "{ max_green = true }"}), "phases.1.max_green", "must be an integer"),
    (toml(phases={1: '{ yellow = "3" }'}), "phases.1.yellow", "must be a finite number"),
    (toml(phases={1: "{ red_clear = nan }"}), "phases.1.red_clear", "must be a finite number"),
    (toml(phases={1: "{ red_clear = inf }"}), "phases.1.red_clear", "must be a finite number"),
    (toml(phases={1: "3"}), "phases.1", "must be a table"),
    (toml(phases={1: '{ startup = "amber" }'}), "phases.1.startup", "allowed: off, green, yellow, red_clear"),
    (toml(phases={1: '{ approach = "up" }'}), "phases.1.approach", "allowed: north, south, east, west"),
    (toml(phases={1: '{ turn = "u" }'}), "phases.1.turn", "allowed: left, through"),
    (toml(rings='[[1, 2, "3", 4], [5, 6, 7, 8]]'), "structure.rings[0]", "must be a list of phase numbers"),
    (toml(pairs='"1,5"'), "structure.pairs", "non-empty list"),
    (toml(middleware="n_timeout = 2.5"), "middleware.n_timeout", "must be an integer"),
    (toml(middleware='poll_hz = "fast"'), "middleware.poll_hz", "must be a finite number"),
    (toml(middleware="tau_udp = 0"), "middleware.tau_udp", "allowed: > 0"),
    (toml(middleware="backup_time = 70000"), "middleware.backup_time", "<= 65535"),
    (toml(top_extra="name = 3").replace('name = "test"\n', ""), "name", "must be a string"),
    ('name = "x"\n[phases]\n1 = {}\n', "structure", "is required"),
])
def test_a_wrong_type_or_value_is_rejected(text: str, field: str, expected: str) -> None:
    err = rejected(text)
    assert err.field == field
    assert expected in err.message


def test_invalid_toml_is_rejected() -> None:
    err = rejected(toml() + "\n[phases\n")
    assert err.field == "<file>"
    assert "is not valid TOML" in err.message


def test_a_config_error_is_a_value_error() -> None:
    assert issubclass(ConfigError, ValueError)


# --- with_middleware ------------------------------------------------------------------------


def test_with_middleware_replaces_and_keeps_the_rest(paper_config: IntersectionConfig) -> None:
    cfg = paper_config.with_middleware(poll_hz=20, backup_time=0)
    assert (cfg.middleware.poll_hz, cfg.middleware.backup_time) == (20, 0)
    assert cfg.middleware.tau_trans == paper_config.middleware.tau_trans
    assert (cfg.phases, cfg.pairs, cfg.compatibility, cfg.source) == (
        paper_config.phases, paper_config.pairs, paper_config.compatibility, paper_config.source)
    assert paper_config.middleware == MiddlewareParams()


@pytest.mark.parametrize(("changes", "field"), [
    ({"poll_hz": 0}, "middleware.poll_hz"),
    ({"n_drift": 0}, "middleware.n_drift"),
    ({"tau_trans": "10"}, "middleware.tau_trans"),
    ({"backup_time": -1}, "middleware.backup_time"),
    ({"keepalive": 3}, "middleware.keepalive"),
])
def test_with_middleware_validates(paper_config: IntersectionConfig, changes: dict[str, object],
                                   field: str) -> None:
    with pytest.raises(ConfigError) as info:
        paper_config.with_middleware(**changes)
    assert info.value.field == field
    assert info.value.source == paper_config.source


def test_the_shipped_config_keeps_its_name() -> None:
    assert load().name == "paper four-leg intersection"


# --- phase options (issue 9) -------------------------------------------------------------------


def test_phase_options_are_read_per_phase_and_from_timing() -> None:
    from hils.protocol.config import Recall

    cfg = parse(toml(timing="min_green = 3\nmax_green = 20\nyellow = 3.0\nred_clear = 2.0\npassage = 1.5\n"
                            "startup_flash = 6",
                     phases={4: '{ walk = 5, ped_clear = 8, recall = "ped", dual_entry = true, max2 = 35 }',
                             8: '{ recall = "soft", backup_prevent = true, red_revert = 4.5, passage = 0, '
                                'simultaneous_gap_disable = false }'}),
                SOURCE)
    four, eight, one = cfg.phases[4], cfg.phases[8], cfg.phases[1]
    assert (four.walk, four.ped_clear, four.recall, four.dual_entry, four.maximum2) == (5, 8, Recall.PED, True, 35)
    assert (eight.recall, eight.backup_prevent, eight.red_revert, eight.passage) == (Recall.SOFT, True, 4.5, 0)
    assert (one.passage, one.maximum2, one.recall, one.dual_entry, one.walk) == (1.5, 20, Recall.NONE, False, 0)
    assert not eight.simultaneous_gap_disable and four.simultaneous_gap_disable and one.simultaneous_gap_disable
    assert cfg.startup_flash == 6


def test_the_paper_config_keeps_the_paper_behaviour(paper_config) -> None:
    from hils.protocol.config import Recall

    for ph in paper_config.phases.values():
        got = (ph.passage, ph.recall, ph.walk, ph.ped_clear, ph.dual_entry, ph.backup_prevent, ph.conditional_service,
               ph.red_revert, ph.simultaneous_gap_disable, ph.ped_recycle)
        assert got == (0, Recall.NONE, 0, 0, False, True, False, 0, True, False)
    assert paper_config.startup_flash == 0
    assert paper_config.next_phase_lock == "green_end"


@pytest.mark.parametrize(("phases", "timing_extra", "field", "allowed"), [
    ({4: "{ walk = 12, ped_clear = 9 }"}, "", "phases.4.walk", "walk + ped_clear <= max_green"),
    ({4: "{ walk = 5 }"}, "", "phases.4.walk", "both 0"),
    ({4: "{ passage = 21.0 }"}, "", "phases.4.passage", "passage <= max_green"),
    ({4: "{ passage = 0.05 }"}, "", "phases.4.passage", "multiples of 0.1"),
    ({4: "{ passage = 2.0, min_gap = 2.5 }"}, "", "phases.4.min_gap", "min_gap <= passage"),
    ({4: "{ passage = 2.0, min_gap = 0.5, time_to_reduce = 256 }"}, "", "phases.4.time_to_reduce",
     "<= 255 s (NTCIP 1202 phaseTimeToReduce"),
    ({4: '{ recall = "always" }'}, "", "phases.4.recall", "none, min, max, ped, soft"),
    ({4: '{ recall = "ped" }'}, "", "phases.4.recall", "walk > 0"),
    ({4: "{ max2 = 2 }"}, "", "phases.4.max2", ">= 3"),
    ({4: '{ dual_entry = "yes" }'}, "", "phases.4.dual_entry", "true, false"),
    ({}, "\nbackup_prevent = 1", "timing.backup_prevent", "true, false"),
    ({4: '{ simultaneous_gap_disable = "off" }'}, "", "phases.4.simultaneous_gap_disable", "true, false"),
    ({}, "\nstartup_flash = 300", "timing.startup_flash", "<= 255"),
    ({}, '\nnext_phase_lock = "yellow_end"', "timing.next_phase_lock", "green_end, red_end"),
    ({}, "\nwalk = 30\nped_clear = 5", "timing.walk", "walk + ped_clear <= max_green"),
])
def test_contradicting_phase_options_are_rejected(phases: dict[int, str], timing_extra: str, field: str,
                                                  allowed: str) -> None:
    err = rejected(toml(timing="min_green = 3\nmax_green = 20\nyellow = 3.0\nred_clear = 2.0" + timing_extra,
                        phases=phases))
    assert err.field == field
    assert allowed in err.message


def test_dual_entry_on_a_phase_without_a_concurrent_partner_is_rejected() -> None:
    allowed = {(1, 5), (2, 6), (3, 7), (3, 8), (4, 7), (4, 8), (1, 6), (2, 5)}
    text = toml(phases={6: "{ dual_entry = true }"},
                structure_extra=f"compatibility = {matrix(allowed - {(1, 6), (2, 6)})}",
                pairs="[[1, 5], [3, 7], [4, 8]]", sequence="[[1, 5], [3, 7], [4, 8]]")
    err = rejected(text)
    assert err.field == "phases.6.dual_entry" and "concurrent" in err.message


# --- [coordination] (issue 24) -------------------------------------------------------------------

PLAN = ('[coordination]\npattern = 1\n[[coordination.patterns]]\nnumber = 1\ncycle = 80\noffset = 10\n'
        'coord_phases = [2, 6]\nsplits = { 1 = 15, 2 = 25, 3 = 15, 4 = 25, 5 = 15, 6 = 25, 7 = 15, 8 = 25 }\n')


def with_plan(text: str = PLAN) -> str:
    return toml() + "\n" + text


def test_a_coordination_plan_is_read() -> None:
    from hils.protocol.config import Correction, ForceOff, OffsetReference

    cfg = parse(with_plan(PLAN + '[[coordination.schedule]]\nfrom = "06:30"\npattern = 1\n'
                          '[[coordination.schedule]]\nfrom = "22:00:30"\npattern = "free"\n'), SOURCE)
    c = cfg.coordination
    assert (c.pattern, c.force_off, c.offset_reference, c.correction) == (
        1, ForceOff.FIXED, OffsetReference.LEAD_GREEN, Correction.SHORTWAY)
    assert c.patterns[1].cycle == 80 and c.patterns[1].offset == 10 and c.patterns[1].coord_phases == (2, 6)
    assert c.patterns[1].splits[4] == 25
    assert [(e.start, e.pattern) for e in c.schedule] == [(6 * 3600 + 1800, 1), (22 * 3600 + 30, 254)]


def test_without_coordination_the_controller_runs_free(paper_config) -> None:
    assert parse(toml(), SOURCE).coordination.pattern == 254
    assert paper_config.coordination.pattern == 254 and paper_config.coordination.patterns  # a plan, not running
    assert paper_config.planned().coordination.pattern == 1


@pytest.mark.parametrize(("old", "new", "field", "allowed"), [
    ("pattern = 1\n", "pattern = 3\n", "coordination.pattern", "a pattern of [[coordination.patterns]] (1)"),
    ("pattern = 1\n", 'force_off = "hard"\n', "coordination.force_off", "floating, fixed"),
    ("pattern = 1\n", 'correction = "jump"\n', "coordination.correction", "shortway, dwell, add"),
    ("pattern = 1\n", 'offset_reference = "red"\n', "coordination.offset_reference", "lead_green, yellow"),
    ("cycle = 80", "cycle = 20", "coordination.patterns[0].cycle", ">= 30"),
    ("offset = 10", "offset = 80", "coordination.patterns[0].offset", "<= 79"),
    ("number = 1", "number = 254", "coordination.patterns[0].number", "<= 253"),
    ("coord_phases = [2, 6]", "coord_phases = [2, 4]", "coordination.patterns[0].coord_phases", "one configured "
     "phase per ring"),
    ("coord_phases = [2, 6]", "coord_phases = [2, 7]", "coordination.patterns[0].coord_phases", "not concurrent"),
    ("4 = 25, 5", "4 = 30, 5", "coordination.patterns[0].splits", "ring 1 (1, 2, 3, 4) adds up to 85 s, not the "
     "cycle of 80 s"),
    ("1 = 15, 2 = 25", "1 = 5, 2 = 35", "coordination.patterns[0].splits.1", "shorter than phase 1's minimum green"),
    ("2 = 25, 3 = 15", "2 = 30, 3 = 10", "coordination.patterns[0].splits", "reach barrier 1 at different times"),
    (", 8 = 25 }", " }", "coordination.patterns[0].splits", "no split for phase(s) [8]"),
    ("offset = 10\n", "offset = 10\nsplit = 3\n", "coordination.patterns[0].split", "unknown field"),
])
def test_a_plan_that_cannot_run_is_refused(old: str, new: str, field: str, allowed: str) -> None:
    assert old in PLAN
    err = rejected(with_plan(PLAN.replace(old, new, 1)))
    assert err.field == field and allowed in err.message, err


WALKING = {4: '{ walk = 12, ped_clear = 8, recall = "ped" }', 8: "{ walk = 12, ped_clear = 8 }"}


def test_a_recalled_walk_times_beside_the_minimum_green_within_its_split() -> None:
    """Walk 12 s and clearance 8 s, beside a minimum green of 3 s, with 5 s of yellow and red fill a 25 s split (NTCIP
    1202 splitTime; the Econolite of ECON_10.204.9.227 ran so), on phase recall or the pattern's split mode."""
    from hils.protocol.ntcip import SplitMode

    cfg = parse(toml(phases=WALKING) + "\n" + PLAN + 'modes = { 8 = "max_and_ped_recall", 3 = "min_recall" }\n',
                SOURCE)
    assert cfg.coordination.patterns[1].modes == {8: SplitMode.MAX_AND_PED_RECALL, 3: SplitMode.MIN_RECALL}
    longer = {4: '{ walk = 13, ped_clear = 8, max_green = 25, recall = "ped" }'}
    err = rejected(toml(phases=WALKING | longer) + "\n" + PLAN)
    assert err.field == "coordination.patterns[0].splits.4" and "allowed: >= 26 s" in err.message, err
    err = rejected(toml(phases=WALKING) + "\n" + PLAN.replace("1 = 15, 2 = 25", "1 = 16, 2 = 24")
                   .replace("8 = 25", "8 = 24").replace("5 = 15", "5 = 16") + 'modes = { 8 = "ped_recall" }\n')
    assert err.field == "coordination.patterns[0].splits.8" and "walk and pedestrian clearance" in err.message, err


@pytest.mark.parametrize(("modes", "field", "allowed"), [
    ('{ 4 = "walk" }', "coordination.patterns[0].modes.4", "allowed: none, min_recall, max_recall, ped_recall, "
     "max_and_ped_recall, omitted"),
    ('{ 9 = "min_recall" }', "coordination.patterns[0].modes.9", "unknown phase"),
    ('{ 3 = "ped_recall" }', "coordination.patterns[0].modes.3", "a walk > 0"),
    ('{ 2 = "omitted" }', "coordination.patterns[0].modes.2", "omits a coordinated phase"),
    ('"ped_recall"', "coordination.patterns[0].modes", "a table of split modes by phase"),
])
def test_a_bad_split_mode_is_refused(modes: str, field: str, allowed: str) -> None:
    err = rejected(toml(phases=WALKING) + "\n" + PLAN + f"modes = {modes}\n")
    assert err.field == field and allowed in err.message, err


@pytest.mark.parametrize(("entry", "field", "allowed"), [
    ('from = "25:00"\npattern = 1', "coordination.schedule[0].from", '"HH:MM" or "HH:MM:SS"'),
    ('from = "7:00"\npattern = 1', "coordination.schedule[0].from", '"HH:MM"'),
    ('from = "07:00"\npattern = 4', "coordination.schedule[0].pattern", '"free" (or 0) or a pattern'),
    ('from = "07:00"', "coordination.schedule[0].pattern", "is required"),
])
def test_a_bad_schedule_entry_is_refused(entry: str, field: str, allowed: str) -> None:
    err = rejected(with_plan(PLAN + f"[[coordination.schedule]]\n{entry}\n"))
    assert err.field == field and allowed in err.message, err


def test_two_patterns_of_one_number_are_refused() -> None:
    second = PLAN.split("[[coordination.patterns]]")[1]
    err = rejected(with_plan(PLAN + "[[coordination.patterns]]" + second))
    assert err.field == "coordination.patterns[1].number" and "given twice" in err.message
