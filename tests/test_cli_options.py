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

    from phonepose.logs import quiet_libraries

    old = np.geterr()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            quiet_libraries()
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


# ----------------------------------------------------------------------------- the environment
# Standard output closed, full or a pipe whose reader left; a narrow encoding; a narrow terminal; few open files.
# Real processes: what is under test is the process's own descriptors, locale and limits.
def _phonepose(*args, cwd, env=None, encoding="utf-8", **popen) -> subprocess.CompletedProcess:
    import os

    return subprocess.run([sys.executable, "-m", "phonepose", *map(str, args)], cwd=cwd, encoding=encoding, timeout=300,
                          env={**os.environ, **(env or {})}, **{"stdout": subprocess.PIPE, "stderr": subprocess.PIPE,
                                                               **popen})


def test_a_closed_stdout_is_refused_before_any_work(tmp_path):
    """`>&-`: the report would be lost while exit 0 said all is well, and the first file opened would become
    descriptor 1 (strace: the new recording's lock was): one line, exit 6, nothing written."""
    import os

    r = _phonepose("marker", "--out", "m.png", cwd=tmp_path, stdout=None, preexec_fn=lambda: os.close(1))
    assert (r.returncode, r.stderr) == (6, "phonepose: error: standard output is closed (>&-): the report would be "
                                           "lost; send it to a file, or to /dev/null to discard it\n")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("args", [["marker", "--out", "m.png"], ["board", "--out", "b.png"]], ids=" ".join)
def test_a_report_that_cannot_be_written_is_exit_6_and_the_outputs_are_kept(tmp_path, args):
    """stdout on /dev/full (a full disk): the work is done and its output in place, and the exit says the report
    is not (it was `phonepose: error: No space left on device`, exit 1; `demo` lost its whole folder)."""
    import os

    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full here")
    with open("/dev/full", "w") as full:
        r = _phonepose(*args, cwd=tmp_path, stdout=full)
    assert (r.returncode, r.stderr) == (6, "phonepose: error: cannot write the report to standard output: No space "
                                           "left on device (the report is incomplete; the command's own outputs, if "
                                           "any, are written)\n")
    assert [p.name for p in tmp_path.iterdir()] == [args[-1]]


def test_a_reader_that_leaves_is_exit_141_in_silence_and_the_outputs_are_kept(tmp_path):
    """`phonepose ... | head -1`: the pipe's reader is gone before the report is written. Silence (the reader
    chose to stop) and 141, as a shell shows for a command stopped by SIGPIPE, never 0; the output is in place.
    (It was exit 1 from typer, 0 from main, or a lost `demo` folder, depending on where the write failed.)"""
    p = subprocess.Popen([sys.executable, "-m", "phonepose", "marker", "--out", "m.png"], cwd=tmp_path,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    p.stdout.close()          # before the child has imported anything: its first write finds no reader
    err = p.stderr.read()
    assert (p.wait(timeout=300), err) == (141, "")
    assert [f.name for f in tmp_path.iterdir()] == ["m.png"]


@pytest.mark.parametrize("encoding", ["ascii", "latin-1"])
def test_a_narrow_encoding_gets_plain_text_never_an_encode_error(tmp_path, encoding):
    """PYTHONIOENCODING=ascii or latin-1 (a C locale, an old log collector): `evaluate --metric rpe` crashed on its
    Δ (an "unexpected UnicodeEncodeError", exit 1), `info →.mcap` on the name; now plain ASCII or escapes."""
    from phonepose.testing.playback_session import write_test_session

    write_test_session(tmp_path / "→.mcap", duration_s=1.0)
    (tmp_path / "t.tum").write_text("".join(f"{i / 10} {i / 100} 0 0 0 0 0 1\n" for i in range(20)))
    (tmp_path / "far.tum").write_text("0 2e7 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n")
    env = {"PYTHONIOENCODING": encoding, "LC_ALL": "C.UTF-8"}
    info = _phonepose("info", "→.mcap", cwd=tmp_path, env=env, encoding=encoding)
    assert (info.returncode, info.stderr) == (0, "")
    assert info.stdout.startswith("\\u2192.mcap: "), info.stdout
    rpe = _phonepose("evaluate", "--gt", "t.tum", "--est", "t.tum", "--metric", "rpe", cwd=tmp_path, env=env,
                     encoding=encoding)
    assert (rpe.returncode, rpe.stderr) == (0, "")
    assert "delta 1 frames" in rpe.stdout and "+--" in rpe.stdout, rpe.stdout   # ASCII table borders (rich)
    far = _phonepose("evaluate", "--gt", "far.tum", "--est", "t.tum", cwd=tmp_path, env=env, encoding=encoding)
    plus_minus = "+/-" if encoding == "ascii" else "±"
    assert (far.returncode, far.stderr) == (2, f"phonepose: error: far.tum:1: position 2e+07 m is not one on Earth "
                                               f"(beyond {plus_minus}1e7 m): check the file's columns and units\n")


def test_a_utf8_name_in_an_ascii_locale_is_one_line_naming_the_locale(tmp_path):
    """LC_ALL=C PYTHONUTF8=0: Python reads the argument's UTF-8 bytes as ASCII; it was refused as "not UTF-8
    text: rename the file", which it is. The line names the locale and how to run in a UTF-8 one (the name shown
    as its escape: the terminal is ASCII)."""
    r = _phonepose("info", "→.mcap", cwd=tmp_path, env={"LC_ALL": "C", "PYTHONUTF8": "0"})
    assert (r.returncode, r.stderr) == (5, "phonepose: error: the argument '\\u2192.mcap' cannot be read in this locale "
                                           "(arguments and file names are read as ascii): run phonepose in a UTF-8 "
                                           "locale (LC_ALL=C.UTF-8) or with PYTHONUTF8=1\n")


@pytest.mark.parametrize("width", [1, 20, 40, 60, 80, 200])
def test_result_tables_never_cut_a_number_in_a_narrow_terminal(width):
    """rich fit playback's table into 60 columns as "7.…" and "14…" (COLUMNS=20 dropped a column); every
    cell is whole now, its lines wrapped by the terminal when even whole words do not fit."""
    import io

    from rich.console import Console

    from phonepose.cli.output import print_table
    from phonepose.cli.playback import metrics_table

    scope = {"frames": 12345, "p_ate_m": 1.234567, "r_ate_deg": 123.456, "p_re_m": 0.0123}
    total = {**scope, "boundary_jumps": 2, "boundary_jump_max_m": 0.0055, "boundary_jump_rms_m": 0.0053,
             "lag_s": 0.105, "jitter_m": 0.00204, "jitter_deg": 0.57, "availability": 1.0}
    metrics = {"session": "s.mcap", "rate_hz": 20.0, "trackers": {"T7L": {"inside": scope, "outside": scope,
                                                                          "total": total}}}
    out = io.StringIO()
    print_table(Console(file=out, width=width, force_terminal=True, color_system=None), metrics_table(metrics))
    text = out.getvalue()
    for cell in ("12345", "123.46", "123.46", "1.23", "0.55", "0.53", "105", "2.04", "0.57", "100.0", "T7L",
                 "inside", "outside", "p_ATE", "r_ATE", "p_RE", "avail."):
        assert cell in text, text
    assert "…" not in text


def test_a_table_that_fits_without_its_padding_loses_the_padding_not_a_digit():
    """Playback's table at 80 columns needed 84 with rich's side padding: the terminal wrapped every line. Without
    the padding it fits in 80, every number whole; where even that is too wide, the padding stays."""
    import io

    from rich.console import Console

    from phonepose.cli.output import print_table
    from phonepose.cli.playback import metrics_table

    scope = {"frames": 84, "p_ate_m": 0.0776, "r_ate_deg": 14.26, "p_re_m": 0.0331}
    total = {**scope, "boundary_jumps": 2, "boundary_jump_max_m": 0.0055, "boundary_jump_rms_m": 0.0053,
             "lag_s": 0.105, "jitter_m": 0.00204, "jitter_deg": 0.57, "availability": 1.0}
    metrics = {"session": "s.mcap", "rate_hz": 20.0,
               "trackers": {t: {"inside": scope, "outside": scope, "total": total} for t in ("T1", "T7L", "T8")}}

    def printed(width: int) -> list[str]:
        out = io.StringIO()
        print_table(Console(file=out, width=width, force_terminal=True, color_system=None), metrics_table(metrics))
        return out.getvalue().splitlines()

    wide = printed(200)
    assert "│ T1 " in "\n".join(wide)                               # padded where there is room
    narrow = printed(80)
    assert max(map(len, narrow)) == 80 and "│T1 " in "\n".join(narrow)
    for cell in ("7.76", "14.26", "3.31", "0.55 /", "0.53", "105", "2.04 /", "0.57", "100.0", "T7L", "outside"):
        assert cell in "\n".join(narrow), narrow
    too_narrow = printed(40)
    assert "│ T1 " in "\n".join(too_narrow) and max(map(len, too_narrow)) > 40   # wrapped by the terminal, padded


def test_too_few_open_files_is_one_line_before_any_work(tmp_path):
    """`ulimit -n 16`: rerun's runtime panicked (a page of Rust backtrace, exit 134) and experiment failed
    half-way with "Too many open files". A low soft limit is raised to what the hard one allows; below the
    least phonepose needs, one line before any work."""
    import resource

    def limit(soft, hard):
        return lambda: resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))

    r = _phonepose("marker", "--out", "m.png", cwd=tmp_path, preexec_fn=limit(16, 16))
    assert (r.returncode, r.stderr) == (1, "phonepose: error: the limit on open files is 16 (`ulimit -n`); "
                                           "phonepose needs at least 64: raise it (`ulimit -n 1024`)\n")
    assert list(tmp_path.iterdir()) == []
    _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and hard < 64:
        pytest.skip(f"the hard limit here is {hard}")
    r = _phonepose("marker", "--out", "m.png", cwd=tmp_path, preexec_fn=limit(16, hard))   # `ulimit -Sn 16`
    assert (r.returncode, r.stderr) == (0, "")


def test_out_of_memory_is_one_line_naming_the_limit(tmp_path, monkeypatch, capsys):
    """`ulimit -v`: a MemoryError, or a library that cannot map its code ("failed to map segment"), was
    "unexpected ...: a bug in phonepose"; it is the machine's memory or its limit, and the line says so."""
    import phonepose.cli.info as info
    from phonepose.cli import main

    for exc in (MemoryError(), ImportError("libopenblas.so: failed to map segment from shared object")):
        def broken(path, exc=exc):
            raise exc
        monkeypatch.setattr(info, "SessionReader", broken)
        with pytest.raises(SystemExit) as e:
            main(["info", str(tmp_path / "s.mcap")])
        err = capsys.readouterr().err
        assert e.value.code == 1
        assert re.fullmatch(rf"phonepose: error: out of memory \({type(exc).__name__}: [^\n]*\): the command needs "
                            r"(free memory or a larger swap|a larger limit than the \S+ GiB of `ulimit -v`)\n", err), err


@pytest.mark.parametrize("encoding", ["utf-8", "ascii", "latin-1"])
def test_a_qr_code_is_drawn_with_what_the_terminal_takes(encoding):
    """`record live` prints its pages' QR codes in half blocks (▀▄█); an ASCII or latin-1 terminal got them as
    \\u2580 escapes, no code at all. There, coloured spaces (segno's non-compact output) draw it."""
    import io

    from phonepose.cli.live import print_qr
    from phonepose.cli.output import ReportStream

    raw = io.BytesIO()
    stream = ReportStream(io.TextIOWrapper(raw, encoding=encoding))
    old, sys.stdout = sys.stdout, stream
    try:
        print_qr("https://192.168.1.2:8443/")
        stream.flush()
    finally:
        sys.stdout = old
    text = raw.getvalue().decode(encoding)
    assert stream.failure is None and "\\u" not in text
    assert ("▀" in text or "▄" in text) == (encoding == "utf-8")


def test_the_library_logs_plain_messages_and_the_cli_prefixes_them(capsys):
    """A library user's log shows the plain message; the command line's handler prints it as one
    ``phonepose: warning:`` line, its escapes shown (a message may quote a file's text)."""
    import logging

    from phonepose import logs

    logger = logging.getLogger("phonepose")
    handlers, propagate = list(logger.handlers), logger.propagate
    records: list[logging.LogRecord] = []

    class Keep(logging.Handler):
        def emit(self, record):
            records.append(record)

    keep = Keep()
    logger.handlers[:] = [keep]   # as in a library user's process, whatever ran in this one before
    try:
        logger.warning("%s: %d sample(s) skipped", "/imu\x1b[2J", 3)
        assert [r.getMessage() for r in records] == ["/imu\x1b[2J: 3 sample(s) skipped"]
        assert capsys.readouterr().err == ""            # no handler of its own before to_terminal
        logs.to_terminal()
        logs.to_terminal()                               # once a process
        logger.warning("%s: %d sample(s) skipped", "/imu\x1b[2J", 3)
        assert capsys.readouterr().err == "phonepose: warning: /imu\\x1b[2J: 3 sample(s) skipped\n"
    finally:
        logger.handlers[:], logger.propagate = handlers, propagate


def test_no_library_module_writes_the_command_line_s_prefix():
    """The library's messages are plain; only the command line (cli/, and the handler in logs.py it installs)
    prints ``phonepose: warning:``. The tick watchdog writes its line itself, just before it ends a process
    whose tracker step cannot be stopped."""
    import ast
    from pathlib import Path

    import phonepose

    root = Path(phonepose.__file__).parent
    found = []
    for path in root.rglob("*.py"):
        rel = path.relative_to(root).as_posix()
        if rel.startswith("cli/") or rel in ("logs.py", "playback/watchdog.py") or rel.endswith("_pb2.py"):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and \
                    ("phonepose: warning:" in node.value or "phonepose: error:" in node.value):
                found.append(f"{rel}:{node.lineno}")
    assert found == []
