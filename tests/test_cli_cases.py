"""Every bad or unusual command line of ``tests/cli_cases.py`` (issue 24), run in-process
as ``transcalib`` would run it: the exit status, one line on stderr naming what was wrong,
no traceback, no output folder; with ``--json`` also one JSON document on stdout holding
the same exit status and message."""

import json

import pytest

from cli_cases import CASES, make_workspace
from transcalib.cli.main import main


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    import contextlib
    import io

    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return make_workspace(tmp_path_factory.mktemp("cases"))


def test_enough_cases_across_every_subcommand():
    from transcalib.cli.main import COMMANDS

    assert len(CASES) >= 60
    firsts = {c.line.split()[0] for c in CASES if c.line}
    assert set(COMMANDS) <= firsts


@pytest.mark.parametrize("case", CASES, ids=[f"{k:02d}-{c.line.split()[0] if c.line else 'none'}"
                                              for k, c in enumerate(CASES)])
def test_case(case, workspace, capsys):
    argv = case.argv(workspace)
    code = main(argv)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == case.code, (code, err)
    assert "Traceback" not in err
    assert lines[-1].startswith("transcalib: error: "), err
    assert [line for line in lines if "error" in line] == lines[-1:], err
    for word in case.words:
        assert word in lines[-1], (word, lines[-1])
    assert not (workspace / "o").exists() and not list(workspace.glob(".o.*"))
    if "--json" not in argv:  # the same with --json: one JSON document on stdout
        code = main(argv + ["--json"] if argv else ["--json"])
        out, err = capsys.readouterr()
        doc = json.loads(out)
        assert code == case.code and doc == {"status": "error", "exit_code": case.code,
                                             "error": err.strip().splitlines()[-1][len("transcalib: error: "):]}


def test_help_is_grouped_and_explains_every_option(capsys):
    """Every subcommand's options sit in the groups of ``GROUPS`` (inputs, model, robust,
    outputs, performance), in that order, each with a help text; -h exits 0."""
    import argparse

    from transcalib.cli.common import GROUPS
    from transcalib.cli.main import COMMANDS, build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    titles = [title for title, _ in GROUPS.values()]
    for name in COMMANDS:
        parser = sub.choices[name]
        groups = [g for g in parser._action_groups if g._group_actions and g.title in titles]
        assert [g.title for g in groups] == [t for t in titles if t in {g.title for g in groups}], name
        bag = [g for g in parser._action_groups if g.title == "ROS bag input (with --bag)"]  # extract.py's
        grouped = {a for g in groups + bag for a in g._group_actions}
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action in grouped, (name, action.option_strings or action.dest)
            assert action.help and action.help != argparse.SUPPRESS and len(action.help) > 15, (name, action.dest)
        assert main([name, "-h"]) == 0
        text = capsys.readouterr().out
        assert all(f"\n{g.title}:" in text for g in groups), name


def test_sizes_are_spelt_one_way_everywhere(tmp_path, capsys):
    """WxH and W,H are both taken wherever an image size is (calibrate, plan)."""
    from transcalib.cli.common import image_size

    assert image_size("640x480") == image_size("640,480") == image_size(" 640 X 480 ") == (640, 480)
    base = ["plan", "--focal-px", "800", "--distance", "1000", "--evaluate"]
    poses = tmp_path / "poses.csv"
    poses.write_text("view,x,y,z\n0,0,0,0\n1,100,0,0\n2,0,100,0\n3,0,0,100\n")
    for size in ("640x480", "640,480"):
        assert main([*base, str(poses), "--image-size", size, "--json"]) == 0
        doc = json.loads(capsys.readouterr().out)
        assert doc["status"] in ("ok", "warnings")


def test_the_python_boundary_of_the_same_cases():
    """``calibrate(fix={"k1": 0.1})`` was a TypeError deep in the bundle adjuster and
    ``plan(box=zeros)`` a ValueError: both are now named at the public boundary."""
    import numpy as np

    import transcalib
    from transcalib import simulate
    from transcalib.errors import DegenerateError, InputError

    scene = simulate.paper_scene(noise_px=0.3, rng=0)
    with pytest.raises(InputError, match="k1 is a distortion coefficient.*distortion='radial1'"):
        transcalib.calibrate(scene.uv, scene.T, fix={"k1": 0.1})
    with pytest.raises(InputError, match="k2 is not a coefficient of distortion='radial1'"):
        transcalib.calibrate(scene.uv, scene.T, fix={"k2": 0.1}, distortion="radial1")
    lin = transcalib.estimate_linear(scene.uv, scene.T)
    with pytest.raises(InputError, match="k1"):
        transcalib.refine(scene.uv, scene.T, lin, options=transcalib.RefineOptions(fix={"k1": 0.1}))
    cal = transcalib.calibrate(scene.uv, scene.T, fix={"k1": 0.05}, distortion="radial2")
    assert cal.dist[0] == 0.05 and np.isfinite(cal.dist[1])
    with pytest.raises(DegenerateError, match="no extent along x, y, z"):
        transcalib.plan(np.zeros(6), 6, image_size=(640, 480), focal_px=800, distance=1000)
