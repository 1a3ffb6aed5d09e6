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
