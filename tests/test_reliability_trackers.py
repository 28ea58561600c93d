"""A user's tracker (``-t package.module:Class``) is hostile input too (docs/reliability.md, "A user's tracker";
docs/writing-a-tracker.md, "Errors"): its name becomes a file name, and its code may raise anything, exit
the process or return garbage. Each case runs the command in-process (the ``cli`` fixture) from a folder two
levels down, beside files a ``../../`` name would hit, and checks the exit code, the one line on stderr, and
that nothing under the test's folder changed: no output, no temporary, no file written outside it."""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import DEADLINE_S

from phonepose.batch.run import UnitTimeout
from phonepose.batch.table import read_rows
from phonepose.errors import ConfigError, TrackerError
from phonepose.pipeline.trackers import UserTracker, make_tracker
from phonepose.testing.playback_session import write_test_session

MODULE = "hostile_trackers"
BAD_NAMES = {   # class -> its name: each refused before any work
    "Escape": "../../evil",
    "Empty": "",
    "Newline": "x\ny",
    "Slash": "a/b",
    "Hidden": ".hidden",
    "Dash": "-rf",
    "Long": "a" * 65,
    "Space": "my tracker",
    "Unicode": "trăcker",
    "Number": 5,
    "NoName": None,
}
CONFIG = "[camera]\nrate_hz = 5.0\n"   # experiments: a 5 Hz camera, ~5x cheaper (what they output does not matter)

SOURCE = '''
import math, os, signal, sys, threading, time

from phonepose.geometry import Pose


class Base:
    name = "Base"
    needs_camera = False
    uses_vio_samples = False

    def reset(self):
        pass

    def step(self, obs):
        return None

''' + "".join(f"class {cls}(Base):\n    name = {name!r}\n\n" for cls, name in BAD_NAMES.items()) + '''
class Good(Base):
    name = "my-trk.v2_1"


class BuiltinInAnotherCase(Base):
    name = "t8"


class Dup1(Base):
    name = "X"


class Dup2(Base):
    name = "X"


class DupCase(Base):
    name = "x"


class ExitInStep(Base):
    name = "E"

    def step(self, obs):
        sys.exit(0)


class Exit3InStep(Base):
    name = "E3"

    def step(self, obs):
        sys.exit(3)


class ExitInReset(Base):
    name = "ER"

    def reset(self):
        sys.exit()


class ExitInInit(Base):
    name = "EI"

    def __init__(self):
        raise SystemExit(1)


class ExitInName(Base):
    @property
    def name(self):
        sys.exit(2)


class GeneratorExitInStep(Base):
    name = "G"

    def step(self, obs):
        raise GeneratorExit


class RaisesInStep(Base):
    name = "R"

    def step(self, obs):
        raise ValueError("boom")


class ReturnsText(Base):
    name = "S"

    def step(self, obs):
        return "pose"


class ReturnsNaN(Base):
    name = "N"

    def step(self, obs):
        return Pose.identity().with_translation([math.nan, 0.0, 0.0])


class CtrlCInStep(Base):
    name = "K"

    def step(self, obs):
        raise KeyboardInterrupt


class WithSetting(Base):
    name = "W"
    weight = 0.3


class Hangs(Base):
    """Its step number HANG_AT (from 0) never returns."""
    name = "H"

    def reset(self):
        self.steps = 0

    def step(self, obs):
        self.steps += 1
        if self.steps > int(os.environ["HANG_AT"]):
            self.hang()
        return None


class Sleeps(Hangs):
    def hang(self):
        time.sleep(1e9)


class Spins(Hangs):
    def hang(self):
        while True:
            pass


class Waits(Hangs):
    def hang(self):
        threading.Event().wait()


class BlocksTheStop(Hangs):
    """Blocks every signal it can (the watchdog's too), then sleeps: only ending the process stops it."""
    def hang(self):
        signal.pthread_sigmask(signal.SIG_BLOCK, set(signal.Signals) - {signal.SIGKILL, signal.SIGSTOP})
        time.sleep(1e9)
'''


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("site")
    (d / f"{MODULE}.py").write_text(SOURCE)
    return d


@pytest.fixture(autouse=True)
def on_path(site, monkeypatch) -> Path:
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in (str(site), os.environ.get("PYTHONPATH")) if p))
    importlib.invalidate_caches()
    yield site
    sys.modules.pop(MODULE, None)


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("session") / "s.mcap"
    write_test_session(p, duration_s=3.0)
    return p


@pytest.fixture
def here(tmp_path, monkeypatch, on_path) -> Path:
    """The test's folder, the command run in its work/sub: a precious evil.tum on every level a
    ``../../evil`` name could reach (from the output folder's trajectories/ or from the output itself)."""
    sub = tmp_path / "work" / "sub"
    sub.mkdir(parents=True)
    for d in (tmp_path, tmp_path / "work", sub):
        (d / "evil.tum").write_text("precious\n")
    (tmp_path / "c.toml").write_text(CONFIG)
    monkeypatch.chdir(sub)
    return tmp_path


def snapshot(root: Path) -> dict[str, bytes | None]:
    """Every entry under ``root``, hidden ones included: a file's bytes, None for a folder."""
    out: dict[str, bytes | None] = {}
    for dirpath, dirs, files in os.walk(root):
        for name in dirs:
            out[os.path.relpath(os.path.join(dirpath, name), root)] = None
        for name in files:
            out[os.path.relpath(os.path.join(dirpath, name), root)] = Path(dirpath, name).read_bytes()
    return out


def ref(cls: str) -> str:
    return f"{MODULE}:{cls}"


def one_line(err: str) -> str:
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("phonepose: error: "), err
    assert "Traceback" not in err and "unexpected" not in err and "a bug in phonepose" not in err
    return lines[0]


def commands(session: Path, tracker: str) -> dict[str, list]:
    return {
        "playback": ["playback", "-q", session, "-o", "pt", "-t", "T1", "-t", tracker],
        "batch": ["batch", "-q", session, "--out", "r.parquet", "--workers", "1", "-t", "T1", "-t", tracker],
        "experiment": ["experiment", "exp2", "--trials", "1", "--config", "../../c.toml", "--out", "et",
                       "--add-tracker", tracker],
    }


# ----------------------------------------------------------------------------- names
@pytest.mark.parametrize("command", ["playback", "batch", "experiment"])
def test_a_name_that_leaves_the_folder_is_refused_before_any_work(session, here, cli, command):
    """The hostile-input pass: `name = "../../evil"` overwrote ../../evil.tum (exit 0), outside the output."""
    before = snapshot(here)
    code, _, err = cli(*commands(session, ref("Escape"))[command])
    assert code == 5
    assert one_line(err) == (
        "phonepose: error: tracker 'hostile_trackers:Escape' (hostile_trackers.Escape) is named '../../evil': a "
        "tracker's name is 1-64 ASCII letters, digits, '_', '-' or '.', not starting with '.' or '-' (it names "
        "trajectories/NAME.tum); see docs/writing-a-tracker.md")
    assert snapshot(here) == before


@pytest.mark.parametrize("cls", list(BAD_NAMES))
def test_every_unsafe_name_is_one_line_naming_the_class(session, here, cli, cls):
    before = snapshot(here)
    code, _, err = cli(*commands(session, ref(cls))["playback"])
    assert code == 5
    line = one_line(err)
    assert line.startswith(f"phonepose: error: tracker '{ref(cls)}' ({MODULE}.{cls}) is named ")
    assert "a tracker's name is 1-64 ASCII letters" in line
    assert snapshot(here) == before


def test_a_name_that_is_not_a_string_says_its_type():
    with pytest.raises(ConfigError, match=r"is named 5 \(an int, not a string\): "):
        make_tracker(ref("Number"))
    with pytest.raises(ConfigError, match=r"is named None \(a NoneType, not a string\): "):
        make_tracker(ref("NoName"))


def test_a_builtin_name_in_another_case_is_refused(session, here, cli):
    before = snapshot(here)
    code, _, err = cli(*commands(session, ref("BuiltinInAnotherCase"))["playback"])
    assert code == 5
    assert one_line(err) == ("phonepose: error: tracker 'hostile_trackers:BuiltinInAnotherCase' "
                             "(hostile_trackers.BuiltinInAnotherCase) is named 't8', in another case the name (T8) "
                             "of a built-in tracker; rename it")
    assert snapshot(here) == before


@pytest.mark.parametrize("command", ["playback", "batch", "experiment"])
@pytest.mark.parametrize(("second", "words"), [
    ("Dup2", "trackers hostile_trackers:Dup1 and hostile_trackers:Dup2 are named 'X': the trackers of a run need "
             "distinct names; rename one"),
    ("DupCase", "trackers hostile_trackers:Dup1 and hostile_trackers:DupCase are named 'X' and 'x', one file name "
                "on a case-insensitive disk: the trackers of a run need distinct names; rename one"),
])
def test_two_trackers_of_one_name_are_refused_before_any_work(session, here, cli, command, second, words):
    before = snapshot(here)
    argv = commands(session, ref("Dup1"))[command]
    argv += [argv[-2], ref(second)]     # the command's own tracker option (-t, or the experiments' --add-tracker)
    code, _, err = cli(*argv)
    assert code == 5
    assert one_line(err) == f"phonepose: error: {words}"
    assert snapshot(here) == before


def test_a_safe_unusual_name_names_its_outputs(session, here, cli):
    code, _, err = cli(*commands(session, ref("Good"))["playback"])
    assert code == 0, err
    out = here / "work" / "sub" / "pt"
    assert sorted(p.name for p in (out / "trajectories").iterdir()) == ["T1.tum", "my-trk.v2_1.tum"]
    assert '"my-trk.v2_1"' in (out / "metrics.json").read_text()


# ----------------------------------------------------------------------------- its code
FAILURES = [   # class, what the line says after "tracker 'hostile_trackers:CLASS' "
    ("ExitInStep", "(E) failed in step(): it called sys.exit(0): a tracker must not end the process; raise an "
                   "exception instead"),
    ("Exit3InStep", "(E3) failed in step(): it called sys.exit(3): a tracker must not end the process; raise an "
                    "exception instead"),
    ("ExitInReset", "(ER) failed in reset(): it called sys.exit(): a tracker must not end the process; raise an "
                    "exception instead"),
    ("GeneratorExitInStep", "(G) failed in step(): GeneratorExit"),
    ("RaisesInStep", "(R) failed in step(): ValueError: boom"),
    ("ReturnsText", "(S) failed in step(): it returned a str; step returns one phonepose.geometry.Pose, or None"),
    ("ReturnsNaN", "(N) failed in step(): it returned a pose with NaN/inf values; return None when there is no pose"),
    ("ExitInInit", "(hostile_trackers.ExitInInit): could not be created: it called sys.exit(1): a tracker must "
                   "not end the process; raise an exception instead"),
    ("ExitInName", "(hostile_trackers.ExitInName): reading its name failed: it called sys.exit(2): a tracker must "
                   "not end the process; raise an exception instead"),
]


@pytest.mark.parametrize(("cls", "words"), FAILURES, ids=[c for c, _ in FAILURES])
def test_a_tracker_that_exits_or_fails_is_one_line_and_leaves_the_earlier_output(session, here, cli, cls, words):
    """sys.exit() in a tracker ended playback silently with its code (0: "success", no output)."""
    assert cli("playback", "-q", session, "-o", "pt", "-t", "T1").returncode == 0   # an earlier output
    before = snapshot(here)
    code, _, err = cli(*commands(session, ref(cls))["playback"])
    assert code == 5
    assert one_line(err) == f"phonepose: error: tracker '{ref(cls)}' {words}"
    assert snapshot(here) == before


HANGS = ["Sleeps", "Spins", "Waits", "BlocksTheStop"]


@pytest.mark.parametrize(("cls", "at"), [(c, int(t)) for c, t in zip(
    HANGS, np.random.default_rng(4).integers(0, 40, len(HANGS)), strict=True)])
def test_a_step_that_never_returns_is_stopped_by_the_tick_timeout(session, here, cls, at):
    """A step that sleeps, spins, waits or blocks every signal for ever (from a generated tick on): one line naming
    the tracker and the tick, exit 5 as for any failing tracker, the earlier output kept, no temporary. A real
    process: the last one is ended by the watchdog itself."""
    assert subprocess.run([sys.executable, "-m", "phonepose", "playback", "-q", session, "-o", "pt", "-t", "T1",
                           "--rerun", "pt.rrd"], capture_output=True, timeout=DEADLINE_S).returncode == 0
    before = snapshot(here)
    r = subprocess.run([sys.executable, "-m", "phonepose", *map(str, commands(session, ref(cls))["playback"]),
                        "--rerun", "pt.rrd", "--tick-timeout", "0.5"], capture_output=True, text=True,
                       timeout=DEADLINE_S, env={**os.environ, "HANG_AT": str(at)})
    assert r.returncode == 5, r.stderr
    assert one_line(r.stderr) == (f"phonepose: error: tracker '{ref(cls)}' (H) did not return from step() at tick "
                                  f"{at} within --tick-timeout 0.5 s: stopped")
    assert snapshot(here) == before


def test_ctrl_c_inside_a_tracker_is_still_an_interrupt(session, here, cli):
    before = snapshot(here)
    code, _, err = cli(*commands(session, ref("CtrlCInStep"))["playback"])
    assert (code, one_line(err)) == (130, "phonepose: error: interrupted")
    assert snapshot(here) == before


def test_a_batch_whose_tracker_exits_writes_its_error_row_and_the_others_rows(session, here, cli):
    """A worker's sys.exit came back through the pool as a SystemExit of the batch: no table, exit 0. Then the
    failing tracker's error became every tracker's row of the unit; now the unit runs again without it."""
    code, _, err = cli(*commands(session, ref("ExitInStep"))["batch"])
    assert code == 1
    assert err.splitlines()[-1] == ("phonepose: error: 1 of 2 rows failed (status error in r.parquet; the next run "
                                    "with the same --out retries them)")
    rows = {k[2]: r for k, r in read_rows(here / "work" / "sub" / "r.parquet").items()}
    assert (rows["E"]["status"], rows["E"]["error"]) == ("error", (
        "tracker 'hostile_trackers:ExitInStep' (E) failed in step(): it called sys.exit(0): a tracker must not end "
        "the process; raise an exception instead"))
    assert cli("batch", "-q", session, "--out", "alone.parquet", "--workers", "1", "-t", "T1").returncode == 0
    alone = next(iter(read_rows(here / "work" / "sub" / "alone.parquet").values()))
    assert rows["T1"]["status"] == "ok"
    assert {k: v for k, v in rows["T1"].items() if k != "runtime_s"} == \
        {k: v for k, v in alone.items() if k != "runtime_s"}      # the same row as a batch without the failing one
    assert sorted(p.name for p in (here / "work" / "sub").iterdir()) == ["alone.parquet", "evil.tum", "r.parquet"]


def test_a_unit_whose_trackers_all_fail_gives_each_its_own_error(session):
    from phonepose.batch.plan import Unit
    from phonepose.batch.run import run_unit

    unit = Unit("s.mcap", str(session), (), ("R", "S"), refs=(("R", ref("RaisesInStep")), ("S", ref("ReturnsText"))))
    rows = run_unit(unit)
    assert [(r["tracker"], r["status"], r["error"]) for r in rows] == [
        ("R", "error", f"tracker '{ref('RaisesInStep')}' (R) failed in step(): ValueError: boom"),
        ("S", "error", f"tracker '{ref('ReturnsText')}' (S) failed in step(): it returned a str; step returns one "
                       "phonepose.geometry.Pose, or None")]


def test_an_experiment_whose_tracker_exits_is_one_line_and_no_folder(session, here, cli):
    """`experiment exp2 --trials 1` with it ended with exit 0 and no folder; its sequences run in 2 worker processes."""
    before = snapshot(here)
    code, _, err = cli(*commands(session, ref("ExitInStep"))["experiment"], "--workers", "2")
    assert code == 5
    assert one_line(err) == ("phonepose: error: tracker 'hostile_trackers:ExitInStep' (E) failed in step(): it called "
                             "sys.exit(0): a tracker must not end the process; raise an exception instead")
    assert snapshot(here) == before


# ----------------------------------------------------------------------------- the guard itself
def test_the_guard_lets_phonepose_stops_and_ctrl_c_through():
    """A batch's time budget (UnitTimeout, from SIGALRM) may land inside a tracker's step: it stays a timeout."""
    tracker = make_tracker(ref("Base"))
    assert isinstance(tracker, UserTracker)
    for exc in (UnitTimeout(1.0), KeyboardInterrupt()):
        tracker.tracker.step = lambda obs, exc=exc: (_ for _ in ()).throw(exc)
        with pytest.raises(type(exc)):
            tracker.step(None)
    tracker.tracker.step = lambda obs: sys.exit(4)
    with pytest.raises(TrackerError, match=re.escape("(Base) failed in step(): it called sys.exit(4)")):
        tracker.step(None)


def test_the_users_object_stays_reachable():
    tracker = make_tracker(ref("WithSetting"))
    assert (tracker.name, tracker.weight, type(tracker.tracker).__name__) == ("W", 0.3, "WithSetting")


def test_a_unit_ending_in_system_exit_is_error_rows(session, monkeypatch):
    """The net behind the guard: whatever ends a unit but Ctrl-C is its rows, in the worker (a SystemExit sent
    back through the pool was raised in the batch itself: a silent exit)."""
    import phonepose.playback.engine
    from phonepose.batch.plan import Unit
    from phonepose.batch.run import run_unit

    def exits(*args, **kwargs):
        sys.exit(0)

    monkeypatch.setattr(phonepose.playback.engine, "run_playback", exits)
    rows = run_unit(Unit("s.mcap", str(session), (), ("T1", "T4")))
    assert [(r["tracker"], r["status"], r["error"]) for r in rows] == [("T1", "error", "SystemExit: 0"),
                                                                        ("T4", "error", "SystemExit: 0")]


def test_the_engine_refuses_an_unsafe_name_from_a_tracker_factory(session, tmp_path):
    """Trackers from PlaybackOptions.tracker_factory (the Python API) skip make_trackers: the engine checks
    the names itself before the output folder exists."""
    from phonepose.playback.engine import run_playback

    escape = make_tracker(ref("Base")).tracker   # the user's object, unwrapped
    escape.name = "../../evil"
    with pytest.raises(ConfigError, match=r"^tracker Base is named '../../evil': a tracker's name is 1-64 ASCII"):
        run_playback(session, out_dir=tmp_path / "o", tracker_factory=lambda names, math: [escape])
    assert list(tmp_path.iterdir()) == []
