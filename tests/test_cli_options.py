"""What every command shares: checked numbers, choices as enums, --help that reads right, piped tables, SIGTERM."""

from __future__ import annotations

import re
import signal
import subprocess
import sys

import pytest
from conftest import wait_until
from hypothesis import given
from hypothesis import strategies as st

from phonepose.cli import options
from phonepose.errors import ConfigError
from phonepose.numbers import check_number


# ----------------------------------------------------------------------------- numbers
@given(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-2**80, 2**80)))
def test_check_number_accepts_exactly_the_finite_values_in_range(value):
    if 0 < value <= 1000:                      # NaN and inf fail this too
        assert check_number("--rate", value, 0, 1000, lo_open=True) == value
    else:
        with pytest.raises(ConfigError) as e:
            check_number("--rate", value, 0, 1000, lo_open=True, unit="Hz")
        assert re.fullmatch(r"--rate \S+: expected a finite number in \(0, 1000\] Hz", str(e.value)), str(e.value)


@pytest.mark.parametrize("value, message", [
    (-1, "--seed -1: expected an integer in [0, 4294967295]"),
    (2**32, "--seed 4294967296: expected an integer in [0, 4294967295]"),
    (1.5, "--seed 1.5: expected an integer in [0, 4294967295]"),
])
def test_integers(value, message):
    with pytest.raises(ConfigError) as e:
        check_number("--seed", value, 0, 2**32 - 1, integer=True)
    assert str(e.value) == message
    assert check_number("--seed", 7, 0, 2**32 - 1, integer=True) == 7


def test_also_allows_a_sentinel():
    assert check_number("--align-frames", -1, 1, integer=True, also=(-1,)) == -1
    with pytest.raises(ConfigError, match=r"^--align-frames 0: expected an integer >= 1 or -1$"):
        check_number("--align-frames", 0, 1, integer=True, also=(-1,))


# ----------------------------------------------------------------------------- choices
def test_choice_enums_list_what_the_implementations_accept():
    """The light enums of the CLI and the modules that implement the choices agree."""
    from phonepose.calibration.board import PAPER_MM
    from phonepose.evaluation.trajectory import FORMATS
    from phonepose.pipeline.corrections import CorrectionMath
    from phonepose.record.sim.scenarios import PATHS, SCENARIOS

    assert [c.value for c in options.CorrectionMath] == [c.value for c in CorrectionMath]
    assert [c.value for c in options.Scenario] == list(SCENARIOS)
    assert sorted(c.value for c in options.SimPath) == sorted(PATHS)
    assert [c.value for c in options.Paper] == [*PAPER_MM, "fit"]
    assert [c.value for c in options.TrajectoryFormat] == list(FORMATS)


# ----------------------------------------------------------------------------- --help
HELP = [["playback"], ["record", "sim"], ["batch"], ["experiment", "exp2"], ["evaluate"], ["board"],
        ["calibrate-camera"], ["demo"]]


@pytest.mark.parametrize("command", HELP, ids=" ".join)
def test_flags_read_as_flags_in_help(command, cli):
    r = cli(*command, "--help", env={"COLUMNS": "120"})
    assert r.returncode == 0, r.stderr
    assert "<bool>" not in r.stdout
    assert re.search(r"--help\s+Show this message and exit\.", r.stdout), r.stdout


def test_help_paragraphs_wrap_to_the_terminal_not_to_the_source(cli):
    """Each paragraph of a command's help flows as one text: at 80 columns, the batch help's second
    paragraph fills its lines (it broke after "they are", where the docstring's line ended)."""
    from phonepose.cli import command

    def commands(c, path=()):
        yield path, c
        for name, sub in getattr(c, "commands", {}).items():
            yield from commands(sub, (*path, name))

    helps = {" ".join(path): c.help for path, c in commands(command()) if c.help}
    assert len(helps) >= 15
    assert [k for k, h in helps.items() if any("\n" in para for para in h.split("\n\n"))] == []
    r = cli("batch", "--help", env={"COLUMNS": "80"})
    lines = [line.strip() for line in r.stdout.splitlines()]
    assert ("Exit 0 when every row is ok, 1 when some playbacks failed (their rows say why; they are retried by the "
            "next run with the same --out). Ctrl-C or SIGTERM stop the workers and keep every finished row in --out."
            ) in " ".join(lines)
    start = next(i for i, line in enumerate(lines) if line.startswith("Exit 0 when"))
    assert all(len(line) >= 60 for line in lines[start:start + 2]), lines[start:start + 3]


def test_help_shows_defaults_choices_and_paper(cli):
    r = cli("playback", "--help", env={"COLUMNS": "160"})
    assert "[default: (./playback-<session>)]" in r.stdout          # rich markup no longer eats it
    assert "<paper|se3>" in r.stdout                                 # --correction-math is a choice
    assert "'paper' (T1-T7)" in r.stdout                             # --tracker lists paper
    r = cli("evaluate", "--help", env={"COLUMNS": "160"})
    for choice in ("<rpg|ape|rpe|paper>", "<posyaw|se3|sim3|none>", "<tum|euroc|kitti>"):
        assert choice in r.stdout, r.stdout


# ----------------------------------------------------------------------------- piped output
def test_info_does_not_cut_topic_names_when_piped(tmp_path, cli):
    from phonepose.testing.playback_session import write_test_session

    write_test_session(tmp_path / "s.mcap", duration_s=1.0)
    r = cli("info", str(tmp_path / "s.mcap"), env={"COLUMNS": "40"})   # not a terminal, 40 columns
    assert r.returncode == 0, r.stderr
    for topic in ("/controller/vio/pose", "/display/camera/calibration", "foxglove.CameraCalibration"):
        assert topic in r.stdout, r.stdout
    assert "…" not in r.stdout


# ----------------------------------------------------------------------------- SIGTERM
def test_sigterm_stops_a_command_like_ctrl_c_and_removes_its_temporaries(tmp_path):
    """One handler in main: SIGTERM is a KeyboardInterrupt where the command runs, so the output's
    temporary is removed on the way out and the line says why (exit 143)."""
    from phonepose.files import TMP_SUFFIX

    out = tmp_path / "demo"
    p = subprocess.Popen([sys.executable, "-m", "phonepose", "demo", "--out", str(out)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    def recording() -> bool:
        assert p.poll() is None, p.communicate()
        return bool(list(tmp_path.glob(f".demo.*{TMP_SUFFIX}/TRI2_01.mcap")))
    wait_until(recording, what="the demo to start recording into its temporary folder")
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 143, err
    assert err.strip().splitlines()[-1] == "phonepose: error: terminated (SIGTERM)"
    assert list(tmp_path.iterdir()) == []          # no temporary, no partial output


# ----------------------------------------------------------------------------- library noise
def test_library_warnings_stay_off_the_terminal():
    """An absurd but finite input (a gyro of 1e200) overflows in numpy; the user sees phonepose's own lines
    about it, not numpy's RuntimeWarnings (main and every worker call this)."""
    import warnings

    import numpy as np

    from phonepose.errors import quiet_library_warnings

    old = np.geterr()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            quiet_library_warnings()
            big = np.array([1e200, 1e200])
            assert np.isinf(big * big).all()                        # ufunc overflow: no warning
            np.linalg.norm(np.full((3, 3), 1e300))                  # numpy's own RuntimeWarning: filtered
            warnings.warn("a phonepose warning stays", UserWarning, stacklevel=1)
        assert [str(w.message) for w in caught] == ["a phonepose warning stays"]
    finally:
        np.seterr(**old)


def test_an_unexpected_exception_is_one_line_and_the_traceback_on_request(tmp_path, monkeypatch, capsys):
    """The last net in main: a bug (here a library's RuntimeError) is one line and exit 1, never a traceback."""
    import phonepose.cli.info as info
    from phonepose.cli import main

    def broken(path):
        raise RuntimeError("Failed to encode LogMsg:\n  disk gone")
    monkeypatch.setattr(info, "SessionReader", broken)
    with pytest.raises(SystemExit) as e:
        main(["info", str(tmp_path / "s.mcap")])
    assert e.value.code == 1
    assert capsys.readouterr().err == (
        "phonepose: error: unexpected RuntimeError: Failed to encode LogMsg: disk gone (a bug in phonepose: please "
        "report it with the command; PHONEPOSE_TRACEBACK=1 shows where it happened)\n")
    monkeypatch.setenv("PHONEPOSE_TRACEBACK", "1")
    with pytest.raises(RuntimeError, match="disk gone"):
        main(["info", str(tmp_path / "s.mcap")])
