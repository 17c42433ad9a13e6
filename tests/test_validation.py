"""``riskplan._validation`` is the one home of argument checks (issue #21): its integer check,
and a scan of ``src`` that fails on an integer-argument message written by hand elsewhere."""

from __future__ import annotations

import re

import numpy as np
import pytest

import riskplan
from riskplan._validation import (
    as_cells,
    check_count,
    check_count_list,
    check_counts,
    integer_words,
    seed_sequence,
)
from riskplan.errors import DataFormatError, InvalidInputError, RobotDescriptionError

SRC = riskplan.__file__.rsplit("/", 1)[0]

# Phrases of a message that checks one integer argument: "expected a positive integer",
# "expected an integer >= 2", "must be an integer in [0, 64]", "widths must be integers",
# "is not an integer in". The check's own module writes them once, as `integer_words`.
HAND_WRITTEN = re.compile(
    r"""["'][^"'\n]*(?:expected|must be|is not)\s+(?:an?\s+)?"""
    r"""(?:positive\s+|non-negative\s+|finite\s+)?integers?\b(?!\s+(?:node|cell))"""
)
# Where "integer" in a message speaks of something other than an integer argument:
# an array's element type (voxel cells, label maps) and the text parser of the command line
# (`parsing.parse_numbers` reads "64.0" and says it is not an integer; a string, not a number).
NOT_AN_ARGUMENT_CHECK = {
    "collision/voxels.py": "the element type of a (K, 3) array of cell indices",
    "collision/segmentation.py": "the element type of a label map",
    "parsing.py": "the text parser of command-line lists",
}


def _hand_written() -> dict[str, list[str]]:
    from pathlib import Path

    found: dict[str, list[str]] = {}
    for p in sorted(Path(SRC).rglob("*.py")):
        rel = str(p.relative_to(SRC))
        if rel == "_validation.py" or rel in NOT_AN_ARGUMENT_CHECK:
            continue
        for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), start=1):
            if HAND_WRITTEN.search(line):
                found.setdefault(rel, []).append(f"{n}: {line.strip()}")
    return found


def test_no_hand_written_integer_messages_outside_validation():
    # a ratchet at 0: integer arguments are checked by `check_count` (one wording, one
    # error type per call site through `error=`)
    assert _hand_written() == {}


def test_the_scan_finds_hand_written_messages():
    # the counter-example: the pattern catches the messages it replaced
    for text in (
        'raise InvalidInputError(f"n: expected a positive integer, got {n!r}")',
        'raise InvalidInputError(f"seed: expected an integer >= 0, got {seed!r}")',
        'f"{where}: {key} must be an integer in [{low}, {high}], got {v!r}"',
        'f"{key!r} = {v!r} is not an integer in [{lo}, {hi}]"',
        'f"{where}: {key} widths must be integers in [1, {MAX_WIDTH}], got {h!r}"',
        'f"components: expected positive integers, got {spec!r}"',
    ):
        assert HAND_WRITTEN.search(text), text
    assert not HAND_WRITTEN.search('raise InvalidInputError("tets: expected integer node indices")')


def test_the_exempt_modules_still_exist():
    from pathlib import Path

    for rel in NOT_AN_ARGUMENT_CHECK:
        assert (Path(SRC) / rel).is_file(), f"strike {rel} from NOT_AN_ARGUMENT_CHECK"


@pytest.mark.parametrize(
    ("minimum", "maximum", "words"),
    [
        (0, None, "a non-negative integer"),
        (1, None, "a positive integer"),
        (2, None, "an integer >= 2"),
        (0, 64, "an integer in [0, 64]"),
        (None, None, "an integer"),
    ],
)
def test_integer_words(minimum, maximum, words):
    assert integer_words(minimum, maximum) == words


@pytest.mark.parametrize("bad", [True, 2.5, "3", None, -1, float("nan"), [1]])
def test_check_count_rejects_with_the_name(bad):
    with pytest.raises(InvalidInputError, match=r"^n_points: expected a non-negative integer, got"):
        check_count(bad, "n_points", 0, integral=True)


def test_check_count_accepts_and_converts():
    assert check_count(np.int32(4), "n", 1) == 4 and type(check_count(np.int32(4), "n", 1)) is int
    assert check_count(640.0, "width", 1, integral=True) == 640
    with pytest.raises(InvalidInputError, match="width: expected a positive integer pixel count"):
        check_count(640.0, "width", 1, noun="pixel count")  # integral floats only when asked
    assert check_count(None, "n", 1, none=True) is None
    assert check_count(-7, "id", None) == -7
    with pytest.raises(InvalidInputError, match=r"expected an integer in \[8, 5000\], got 5001"):
        check_count(5001, "n_elements", 8, maximum=5000)


def test_check_count_message_lists_the_alternatives():
    with pytest.raises(
        InvalidInputError,
        match=r"seed: expected a non-negative integer, a torch.Generator or None, got -1",
    ):
        check_count(-1, "seed", 0, none=True, alternatives="a torch.Generator")


def test_check_count_error_type_is_the_callers():
    with pytest.raises(DataFormatError, match="model 'm': n_inputs: expected"):
        check_count(0, "model 'm': n_inputs", 1, maximum=8, error=DataFormatError)
    with pytest.raises(RobotDescriptionError) as info:
        check_count(
            1.5, "'disks.count'", 0, error=lambda m: RobotDescriptionError(m, key="disks.count")
        )
    assert info.value.key == "disks.count"


def test_check_counts_and_lists():
    assert check_counts({"a": 1, "b": np.int64(2)}, 1) == {"a": 1, "b": 2}
    with pytest.raises(InvalidInputError, match=r"^b: expected a positive integer"):
        check_counts({"a": 1, "b": 0}, 1)
    assert check_count_list([3, 1.0], "components") == (3, 1)
    for bad in ([], "12", 5, [1, 0], [1, 2.5]):
        with pytest.raises(
            InvalidInputError, match="components: expected a non-empty list of positive integers"
        ):
            check_count_list(bad, "components")


def test_seed_sequence():
    assert seed_sequence(5).entropy == np.random.SeedSequence(5).entropy
    for bad in (-1, 1.5, "zero"):
        with pytest.raises(InvalidInputError, match="seed: expected None or a non-negative"):
            seed_sequence(bad)


def test_as_cells():
    cells = as_cells([[0, 1, 2.0]], "triangles", 3, 3, "triangle")
    assert cells.dtype == np.int64 and cells.tolist() == [[0, 1, 2]]
    for bad, what in (
        ([[0, 1, 2.5]], "integer node indices"),
        ([[0, 1]], r"shape \(T>0, 3\)"),
        ([[0, 1, 3]], r"lie in \[0, 2\]"),
        ([[0, 1, 1]], "belong to no triangle"),
    ):
        with pytest.raises(InvalidInputError, match=what):
            as_cells(bad, "triangles", 3, 3, "triangle")


def test_check_instance_and_choice():
    from riskplan._validation import check_choice, check_instance

    assert check_instance(3, int, "n") == 3
    with pytest.raises(InvalidInputError, match=r"^mesh: expected a int, got str$"):
        check_instance("x", int, "mesh")
    assert check_choice("a", {"a": 1, "b": 2}, "law") == "a"
    with pytest.raises(InvalidInputError, match=r"^law: expected one of \('a', 'b'\), got 'c'$"):
        check_choice("c", {"a": 1, "b": 2}, "law")
