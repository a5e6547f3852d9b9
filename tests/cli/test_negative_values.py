"""Values that begin with a minus, in the separate-token form (issue 37): ``--extent -1,3,0,1``
and ``--start-time -1e20`` were read as options ("expected one argument"); every option of
every command that takes a value now takes them, and then its own check says what is allowed."""

from __future__ import annotations

import argparse

import pytest

from sonarsim.cli.argtypes import NEGATIVE_VALUE
from sonarsim.cli.main import build_parser, main

# Every form of a number that Python's float reads with a minus, and lists that begin with one.
VALUES = ["-1", "-0.5", "-.5", "-1e20", "-1E-3", "-inf", "-Infinity", "-nan", "-1,3,-0.8,0.8", "-inf,2"]


def run(argv) -> int:
    try:
        return main([str(a) for a in argv])
    except SystemExit as exc:
        return exc.code


def _value_options():
    """(command, option) for every option of every sub-command that takes one value."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, p in sub.choices.items():
        for action in p._actions:
            if action.option_strings and action.nargs is None and action.option_strings[0].startswith("--") \
                    and not isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
                yield name, action.option_strings[0]


@pytest.mark.parametrize("text", VALUES)
def test_the_pattern_takes_negative_numbers_and_lists(text):
    assert NEGATIVE_VALUE.match(text)


@pytest.mark.parametrize("text", ["--extent", "-h", "--inf", "-x", "-information", "-nano"])
def test_the_pattern_leaves_options_alone(text):
    assert not NEGATIVE_VALUE.match(text)


def test_every_value_option_of_every_command_takes_a_leading_minus(capsys):
    options = list(_value_options())
    assert len(options) > 40 and ("reconstruct", "--extent") in options and ("dataset", "--start-time") in options
    for command, option in options:
        for value in ("-1e20", "-1,2"):
            # The option's own type may refuse the value (or a positional be missing); what
            # must not happen is argparse taking the value for an option. (Parsed only: demo
            # --out -1e20 would run the demo.)
            try:
                build_parser().parse_args([command, option, value])
            except SystemExit:
                pass
            err = capsys.readouterr().err
            assert "expected one argument" not in err, (command, option, value, err)


def test_extent_with_a_leading_minus_is_parsed_as_given():
    args = build_parser().parse_args(["reconstruct", "a.npz", "--scene", "s.yaml", "--extent", "-1,3,-0.8,0.8",
                                      "--resolution", "0.1", "--out", "h.npz", "--smoothness", "-1e-3"])
    assert args.extent == (-1.0, 3.0, -0.8, 0.8) and args.smoothness == -1e-3


def test_top_level_budgets_and_display_gains_take_their_values():
    args = build_parser().parse_args(["render", "s.yaml", "--out", "o", "--gain-db", "-3.5e1"])
    assert args.gain_db == -35.0
    # A negative budget is refused by the budget's own check, naming what is allowed.
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--max-memory", "-1e9", "demo"])


def test_a_negative_display_gain_beyond_its_range_is_refused_by_range(capsys):
    assert run(["render", "s.yaml", "--out", "o", "--gain-db", "-1e3"]) == 2
    err = capsys.readouterr().err
    assert "--gain-db" in err and "from -400 to 400" in err


def test_an_absurd_start_time_gets_its_range_refusal(tmp_path, capsys):
    scenario = tmp_path / "s.yaml"
    scenario.write_text("frames: 1\n")
    assert run(["dataset", scenario, "--out", tmp_path / "d", "--rosbag", "mcap", "--start-time", "-1e20"]) == 2
    err = capsys.readouterr().err
    assert "--start-time" in err and "after that instant and before 2038" in err and "Traceback" not in err
    assert not (tmp_path / "d").exists()


def test_frame_numbers_and_counts_refuse_negative_values_by_name(tmp_path, capsys):
    assert run(["compare", "a.npz", "b.npz", "--frame-a", "-1"]) == 2
    assert "frame number >= 0" in capsys.readouterr().err
    assert run(["dataset", "s.yaml", "--out", tmp_path / "d", "--workers", "-4"]) == 2
    assert "--workers" in capsys.readouterr().err


def test_unknown_options_are_still_unknown(capsys):
    assert run(["render", "s.yaml", "--out", "o", "--nope", "-1"]) == 2
    assert "unrecognized arguments: --nope" in capsys.readouterr().err
