"""The command line: bad input gives one line naming the option, exit code 2, nothing written."""

import pytest

from bench.cli import main


def call(argv):
    try:
        return main(argv)
    except SystemExit as exc:  # argparse's own errors (unparseable values)
        return exc.code


@pytest.mark.parametrize(
    "arg, option",
    [
        ("--sizes=0", "--sizes"),
        ("--sizes=-3,13.2", "--sizes"),
        ("--sizes=big", "--sizes"),
        ("--alphas=96", "--alphas"),
        ("--alphas=-1", "--alphas"),
        ("--phis=90", "--phis"),
        ("--phis=-5", "--phis"),
        ("--dictionary=9x9_50", "--dictionary"),
        ("--lighting=moon", "--lighting"),
        ("--lighting=sun,fog", "--lighting"),
        ("--images=0", "--images"),
        ("--images=many", "--images"),
        ("--distance=0", "--distance"),
        ("--workers=0", "--workers"),
        ("--variant=cpu", "--variant"),
    ],
)
def test_bad_options(tmp_path, capsys, arg, option):
    out = tmp_path / "run"
    assert call(["detectability", arg, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and option in err[0], err
    assert not out.exists()


def test_error_names_the_allowed_range(tmp_path, capsys):
    call(["detectability", "--phis=95", "--out", str(tmp_path / "x")])
    assert "0..89" in capsys.readouterr().err


def test_unwritable_out(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert call(["detectability", "--quick", "--out", str(blocker / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0]
    assert blocker.read_text() == "not a folder"
