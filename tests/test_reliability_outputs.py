"""The output rule (phonepose/files.py; docs/reliability.md, "Outputs") in every command that writes.

One table of writing commands (WRITERS) times one table of cases (CASES): each case builds its
situation in a fresh folder, runs the command in-process (``phonepose.cli.main``) and checks the exit
code, the one line on stderr, and that nothing outside the named output changed (every other file's
bytes, the inputs' included). ``python tests/test_reliability_outputs.py`` prints the matrix that
docs/reliability.md shows.

playback is w-structure's and record live w-live's: their rows are added where they apply the rule.
"""

from __future__ import annotations

import contextlib
import os
import signal
import stat
import subprocess
import sys
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from conftest import DEADLINE_S, deadline, wait_until
from test_reliability_data import mounted_tmpfs

from phonepose.files import MANIFEST, TMP_SUFFIX
from phonepose.testing.playback_session import write_test_session

CONFIG = b"[camera]\nrate_hz = 5.0\n"   # a valid override; a 5 Hz camera makes the experiments that run to
#                                          their end ~5x cheaper (what they output does not matter here)


# ----------------------------------------------------------------------------- the writing commands
@dataclass
class Writer:
    id: str
    argv: list[str]                 # "{input}" stands for the command's input file
    option: str                     # the output's option
    name: str                       # a good output name
    kind: str = "file"              # "file" | "dir"
    input: str | None = None        # "config" | "session" | "video" | "motion": what {input} is
    what: str = ""                  # the format the name must end in (files)
    wrong: str = ""                 # a name whose extension does not match
    also: list[str] = field(default_factory=list)   # options naming another output the command writes
    ok: bool = False                # cheap enough to run to success in the default test run
    fails: Callable | None = None   # (monkeypatch, d, argv) -> argv of a run that fails after the checks
    missing_input_code: int = 2
    earlier: Callable[[Path], None] | None = None   # writes an earlier run's output (default: a few bytes)
    title: str = ""                 # the docs matrix's name for it (default: the command's words and the option)


def _earlier_table(path: Path) -> None:
    """A phonepose batch table of an earlier run: one row of another session."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table({"session": ["other.mcap"], "params": ["{}"], "tracker": ["T1"], "status": ["ok"]}), path)


def _fail_recording(monkeypatch, d, argv):
    """Disk full after 50 messages (a recorder's OutputError), in the process (main runs in-process)."""
    from phonepose.errors import OutputError
    from phonepose.session.writer import SessionWriter

    real = SessionWriter.write_bytes

    def write_bytes(self, *a, **k):
        if self.message_count >= 50:
            raise OutputError(f"cannot write {self.path}: No space left on device")
        return real(self, *a, **k)
    monkeypatch.setattr(SessionWriter, "write_bytes", write_bytes)
    return argv


def _fail_recover(monkeypatch, d, argv):
    bad = d / "noise.mcap"
    bad.write_bytes(np.random.default_rng(0).bytes(50_000))
    return [str(bad) if a == str(d / "good.mcap") else a for a in argv]


def _fail_batch(monkeypatch, d, argv):
    import phonepose.batch.driver as driver

    def interrupted(futures, timeout=None):
        raise KeyboardInterrupt
        yield   # pragma: no cover
    monkeypatch.setattr(driver, "as_completed", interrupted)
    return argv


def _fail_calibrate_gt(monkeypatch, d, argv):
    import phonepose.calibration.calibrate_gt as calibrate_gt
    from phonepose.errors import SessionContentError

    def refuse(*args, **kwargs):
        raise SessionContentError("the motion does not determine it")
    monkeypatch.setattr(calibrate_gt, "calibrate_gt", refuse)
    return argv


def _fail_rehearsal(monkeypatch, d, argv):
    """The simulated scene half written, then the disk full: before any browser starts."""
    import phonepose.record.rehearse.scene as scene
    from phonepose.errors import OutputError

    def build_scene(folder, **kwargs):
        (folder / "source.mcap").write_bytes(b"half a session")
        raise OutputError(f"cannot write {folder / 'camera.avi'}: No space left on device")
    monkeypatch.setattr(scene, "build_scene", build_scene)
    return argv


WRITERS = [
    # its run to success (1.5 min, a browser) is tests/test_rehearse.py's slow test
    Writer("record-rehearse", ["record", "rehearse", "--config", "{input}"], "--out", "rehearsal", kind="dir",
           input="config", fails=_fail_rehearsal),
    Writer("record-sim", ["record", "sim", "-q", "--config", "{input}", "--force"], "--out", "s.mcap",
           input="config", what="an MCAP session", wrong="s.bag", fails=_fail_recording, missing_input_code=5),
    Writer("record-sim-motion", ["record", "sim", "-q", "--motion", "{input}", "--motion-duration", "2", "--force"],
           "--out", "s.mcap", input="motion", what="an MCAP session", wrong="s.bag", fails=_fail_recording,
           title="record sim --motion FILE --out"),
    Writer("record-sim-rerun", ["record", "sim", "-q", "--config", "{input}", "--out", "{d}/rec.mcap"], "--rerun",
           "s.rrd", input="config", what="a Rerun recording", wrong="s.txt", also=["{d}/rec.mcap"],
           fails=_fail_recording, missing_input_code=5),
    Writer("recover", ["recover", "{input}", "--force"], "--out", "fixed.mcap", input="session",
           what="an MCAP session", wrong="fixed.mcap.partial", ok=True, fails=_fail_recover),
    Writer("board", ["board"], "--out", "board.png", what="a PNG image", wrong="board.pdf", ok=True,
           fails=lambda m, d, argv: argv + ["--board", "squares=12x8"]),
    Writer("marker", ["marker"], "--out", "marker.png", what="a PNG image", wrong="marker.jpg", ok=True,
           fails=lambda m, d, argv: argv + ["--id", "99"]),
    Writer("calibrate-camera", ["calibrate-camera", "-q", "--video", "{input}"], "--out", "cam.yaml", input="video",
           what="an OpenCV FileStorage file (YAML, XML or JSON)", wrong="cam.txt",
           fails=lambda m, d, argv: argv),    # the stand-in video is no video: exit 2 after the checks
    Writer("calibrate-hand-eye", ["calibrate-hand-eye", "{input}"], "--out", "he.yaml", input="session",
           what="a YAML calibration file", wrong="he.mcap",
           fails=lambda m, d, argv: argv),    # the test session turns about one axis only: exit 4
    Writer("calibrate-gt", ["calibrate-gt", "{input}", "--bootstrap", "20"], "--out", "gt.yaml", input="session",
           what="a YAML calibration file", wrong="gt.json", ok=True, fails=_fail_calibrate_gt),
    Writer("batch", ["batch", "{input}", "-t", "T1", "-q", "--workers", "1"], "--out", "r.parquet", input="session",
           what="a Parquet table", wrong="r.csv", ok=True, fails=_fail_batch, earlier=_earlier_table),
    Writer("experiment-exp1", ["experiment", "exp1", "-q", "--config", "{input}"], "--out", "exp1-out", kind="dir",
           input="config", fails=_fail_recording, missing_input_code=5),
    Writer("experiment-exp2", ["experiment", "exp2", "--trials", "1", "--workers", "1", "--config", "{input}"], "--out",
           "exp2-out", kind="dir", input="config", fails=_fail_recording, missing_input_code=5),
    Writer("demo", ["demo"], "--out", "phonepose-demo", kind="dir", fails=_fail_recording),
    # playback's trackers.mcap is written by a SessionWriter too: _fail_recording fills the disk under it
    Writer("playback", ["playback", "{input}", "-q", "-t", "T1,T4"], "--out", "pb", kind="dir", input="session",
           ok=True, fails=_fail_recording),
    Writer("playback-rerun", ["playback", "{input}", "-q", "-t", "T1", "--out", "{d}/pb"], "--rerun", "pb.rrd",
           input="session", what="a Rerun recording", wrong="pb.txt", also=["{d}/pb"], ok=True, fails=_fail_recording),
]
BY_ID = {w.id: w for w in WRITERS}


# ----------------------------------------------------------------------------- running and comparing
def snapshot(root: Path) -> dict[str, tuple]:
    """Every entry under ``root``: kind and content (bytes, link target, device numbers)."""
    out = {}
    for dirpath, dirs, files in os.walk(root):
        for name in dirs + files:
            p = Path(dirpath) / name
            st = os.lstat(p)
            rel = str(p.relative_to(root))
            if stat.S_ISLNK(st.st_mode):
                out[rel] = ("link", os.readlink(p))
            elif stat.S_ISREG(st.st_mode):
                out[rel] = ("file", p.read_bytes(), st.st_ino)
            elif stat.S_ISDIR(st.st_mode):
                out[rel] = ("dir",)
            else:
                out[rel] = ("special", stat.S_IFMT(st.st_mode))
    return out


def outside(snap: dict, named: list[str]) -> dict:
    return {k: v for k, v in snap.items() if not any(k == n or k.startswith(n + "/") for n in named)}


@pytest.fixture(scope="module")
def good_session(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("good") / "good.mcap"
    write_test_session(path, duration_s=2.0)
    return path


def make_input(w: Writer, d: Path, good_session: Path) -> Path | None:
    if w.input == "config":
        (d / "sim.toml").write_bytes(CONFIG)
        return d / "sim.toml"
    if w.input == "session":
        (d / "good.mcap").write_bytes(good_session.read_bytes())
        return d / "good.mcap"
    if w.input == "motion":       # a recorded trajectory (TUM): 3 s of a slow line at 100 Hz
        t = np.arange(0.0, 3.0, 0.01)
        rows = [f"{1000 + s:.2f} {0.05 * s:.4f} 0 0 0 0 0 1" for s in t]
        (d / "motion.txt").write_text("\n".join(rows) + "\n")
        return d / "motion.txt"
    if w.input == "video":
        (d / "board.avi").write_bytes(b"RIFF not really a video")
        return d / "board.avi"
    return None


def argv_for(w: Writer, d: Path, out: Path | str, inp: Path | None) -> list[str]:
    sub = {"{input}": str(inp), "{d}": str(d)}
    args = []
    for a in w.argv:
        for k, v in sub.items():
            a = a.replace(k, v)
        args.append(a)
    return args + [w.option, str(out)]


def one_line(err: str) -> str:
    """The error: one line, the last on stderr (batch prints its plan before it, record rehearse its steps),
    no traceback."""
    lines = err.strip().splitlines()
    errors = [line for line in lines if line.startswith("phonepose: error: ")]
    assert len(errors) == 1 and lines[-1] == errors[0] and "Traceback" not in err, err
    assert len(lines) == 1 or lines[0].startswith(("1 sessions x ", "simulating exp2 ")), err
    return errors[0][len("phonepose: error: "):]


def also_named(w: Writer) -> list[str]:
    """The other outputs the command was given (relative to the case's folder)."""
    return [Path(a).name for a in w.also]


def temporaries(root: Path) -> list[str]:
    return [str(p) for p in root.rglob(f"*{TMP_SUFFIX}*")]


# ----------------------------------------------------------------------------- the cases
def case_missing_parent(w, d, inp, cli, monkeypatch):
    """A missing parent is one line, the same words in every command, and creates nothing."""
    before = snapshot(d)
    out = d / "nodir" / w.name
    code, _, err = cli(*argv_for(w, d, out, inp))
    assert code == 6 and one_line(err) == f"{w.option} {out}: directory {d / 'nodir'} does not exist"
    assert snapshot(d) == before


def case_wrong_extension(w, d, inp, cli, monkeypatch):
    """A name whose extension is not the format written is refused (never a PNG named .jpg)."""
    before = snapshot(d)
    out = d / w.wrong
    code, _, err = cli(*argv_for(w, d, out, inp))
    assert code == 5, err
    line = one_line(err)
    assert line.startswith(f"{w.option} {out}: writes {w.what}") and "; give a name ending in ." in line, line
    assert snapshot(d) == before


def _output_is_input(link: str):
    def case(w, d, inp, cli, monkeypatch):
        if w.kind == "dir":      # the output folder holds the input: it would be replaced whole
            run_dir = d / w.name
            run_dir.mkdir()
            (run_dir / MANIFEST).write_text("{}")
            moved = run_dir / inp.name
            os.rename(inp, moved)
            args = [str(moved) if a == str(inp) else a for a in argv_for(w, d, run_dir, inp)]
            before = snapshot(d)
            code, _, err = cli(*args)
            assert code == 2 and one_line(err) == (f"{w.option} {run_dir}: holds the input {moved} and would be "
                                                   f"replaced whole; choose another {w.option}")
            assert snapshot(d) == before
            return
        out = {"same": inp, "symlink": d / ("l-" + w.name), "hardlink": d / ("h-" + w.name)}[link]
        if link == "symlink":
            out.symlink_to(inp)
        elif link == "hardlink":
            os.link(inp, out)
        before = snapshot(d)
        code, _, err = cli(*argv_for(w, d, out, inp))
        assert code == 2 and one_line(err) == (f"{w.option} {out} is the input {inp}: writing it would destroy the "
                                               "input; choose another name")
        assert snapshot(d) == before       # the input's bytes (and its links) untouched
    case.__doc__ = f"An output that is the input ({link}) is refused before anything is written."
    return case


def case_missing_input(w, d, inp, cli, monkeypatch):
    """A missing input stops the command before any output exists."""
    inp.unlink()
    before = snapshot(d)
    code, _, err = cli(*argv_for(w, d, d / w.name, inp))
    assert code == w.missing_input_code and one_line(err).endswith(f"{inp}: no such file")
    assert snapshot(d) == before


def case_fifo_input(w, d, inp, cli, monkeypatch):
    """A FIFO given as the input is refused at once (opening it would wait forever)."""
    inp.unlink()
    os.mkfifo(inp)
    before = snapshot(d)
    with deadline(60):
        code, _, err = cli(*argv_for(w, d, d / w.name, inp))
    assert code in (2, 5) and "not a regular file (a FIFO, socket or device)" in one_line(err)
    assert snapshot(d) == before


def case_device_output(w, d, inp, cli, monkeypatch):
    """A device is never written nor replaced by a file."""
    before, dev = snapshot(d), os.stat("/dev/full")
    code, _, err = cli(*argv_for(w, d, "/dev/full", inp))
    assert code == 6 and one_line(err) == f"{w.option} /dev/full: not a regular file (a device, FIFO or socket); " \
                                          "give a file name"
    after = os.stat("/dev/full")
    assert (after.st_ino, after.st_rdev) == (dev.st_ino, dev.st_rdev) and snapshot(d) == before


def _earlier_output(w: Writer, d: Path) -> Path:
    out = d / w.name
    if w.kind == "dir":
        out.mkdir()
        (out / MANIFEST).write_text('{"written_by": "phonepose", "files": ["stale.txt"]}\n')
        (out / "stale.txt").write_text("an earlier run's file")
    elif w.earlier is not None:
        w.earlier(out)
    else:
        out.write_bytes(b"an earlier run's output")
    return out


def case_failed_run(w, d, inp, cli, monkeypatch):
    """A run that fails after the checks leaves the earlier output as it was, and no temporary."""
    out = _earlier_output(w, d)
    argv = w.fails(monkeypatch, d, argv_for(w, d, out, inp))
    before = snapshot(d)
    code, _, err = cli(*argv)
    assert code != 0
    one_line(err)
    assert not temporaries(d), temporaries(d)
    after = snapshot(d)
    named = also_named(w)                                      # a new recording beside it may stay (recover it)
    assert outside(after, named) == outside(before, named)    # the earlier output included: untouched
    assert TMP_SUFFIX not in err, err                          # the error names the user's paths


def case_replaced_whole(w, d, inp, cli, monkeypatch):
    """A successful run over an earlier output replaces it whole: nothing of the earlier run survives."""
    out = _earlier_output(w, d)
    before = snapshot(d)
    code, _, err = cli(*argv_for(w, d, out, inp))
    assert code == 0, err
    after = snapshot(d)
    assert outside(after, [w.name, *also_named(w)]) == outside(before, [w.name, *also_named(w)])
    if w.kind == "dir":
        assert not (out / "stale.txt").exists() and (out / MANIFEST).is_file()
    else:
        assert out.read_bytes() != before[w.name][1] and out.stat().st_size > 0
    assert not temporaries(d)


def case_disk_full(w, d, inp, cli, monkeypatch):
    """A full disk is one line (exit 6) and leaves nothing there: no partial output, no temporary."""
    with mounted_tmpfs(d / "full", "size=1m") as mnt:
        with open(mnt / "filler", "wb") as f:     # fill it to the last block
            with contextlib.suppress(OSError):
                while True:
                    f.write(b"\0" * 65536)
                    f.flush()
        before = snapshot(d)
        code, _, err = cli(*argv_for(w, d, mnt / w.name, inp))
        assert code == 6 and "No space left on device" in one_line(err), err
        assert TMP_SUFFIX not in err and "phonepose recover" not in err, err
        assert sorted(p.name for p in mnt.iterdir()) == ["filler"]
        assert snapshot(d) == before


@dataclass
class Case:
    id: str
    fn: Callable
    applies: Callable[[Writer], bool]
    slow: Callable[[Writer], bool] = lambda w: False     # the command runs to its end (or close to it)
    what: str = ""


CASES = [
    Case("missing-parent", case_missing_parent, lambda w: True, what="missing parent folder"),
    Case("wrong-extension", case_wrong_extension, lambda w: w.kind == "file", what="mismatched extension"),
    *[Case(f"output-is-input-{link}", _output_is_input(link), lambda w, link=link: w.input is not None and
           (w.kind == "file" or link == "same"), what=f"output is the input ({link})")
      for link in ("same", "symlink", "hardlink")],
    Case("missing-input", case_missing_input, lambda w: w.input is not None and w.id != "batch",
         what="missing input"),
    Case("fifo-input", case_fifo_input, lambda w: w.input is not None, what="FIFO as the input"),
    Case("device-output", case_device_output, lambda w: w.kind == "file", what="device as the output"),
    Case("failed-run", case_failed_run, lambda w: w.fails is not None,
         slow=lambda w: w.id in ("experiment-exp2",), what="failed run"),
    # calibrate-camera / -hand-eye need a real video / a two-axis session to succeed (tests/test_calibration.py,
    # tests/test_hand_eye.py write theirs); exp2 runs to success in tests/test_experiments.py, record rehearse
    # in tests/test_rehearse.py
    Case("replaced-whole", case_replaced_whole, lambda w: w.id not in ("calibrate-camera", "calibrate-hand-eye",
                                                                       "experiment-exp2", "record-rehearse"),
         slow=lambda w: not w.ok, what="stale output (replaced whole)"),
    # a recording on a full disk: tests/test_reliability_kill.py (it stays, for `phonepose recover`)
    Case("disk-full", case_disk_full, lambda w: w.id in ("recover", "board", "marker", "batch", "playback", "experiment-exp1",
                                                         "experiment-exp2", "demo"), what="disk full"),
]
PAIRS = [pytest.param(w, c, id=f"{w.id}-{c.id}", marks=[pytest.mark.slow] if c.slow(w) else [])
         for c in CASES for w in WRITERS if c.applies(w)]


@pytest.mark.parametrize("w,case", PAIRS)
def test_output_rule(w: Writer, case: Case, good_session, tmp_path, cli, monkeypatch):
    monkeypatch.chdir(tmp_path)
    d = tmp_path / "d"
    d.mkdir()
    inp = make_input(w, d, good_session)
    if w.id == "record-rehearse":   # the output rule is checked whether or not npm could install IWER
        iwer = tmp_path / "iwer.min.js"
        iwer.write_text("// not run: no browser starts in these cases\n")
        monkeypatch.setenv("PHONEPOSE_IWER", str(iwer))
    case.fn(w, d, inp, cli, monkeypatch)


def test_every_writing_command_is_in_the_table():
    """A new command that writes joins WRITERS (record live writes a new recording: tests/test_record_live.py)."""
    from phonepose.cli import command

    writes = set()
    def walk(cmd, path):
        for p in getattr(cmd, "params", []):
            if "--out" in getattr(p, "opts", []) or "--rerun" in getattr(p, "opts", []):
                writes.add(path)
        for name, sub in getattr(cmd, "commands", {}).items():
            walk(sub, f"{path} {name}".strip())
    walk(command(), "")
    covered = {" ".join(w.argv[:2]) if w.argv[0] in ("record", "experiment") else w.argv[0] for w in WRITERS}
    assert writes - covered == {"record live"}


# ----------------------------------------------------------------------------- killed runs
KILLED = [w for w in WRITERS if w.id != "record-rehearse"]   # (it needs a browser: tests/test_rehearse.py)
KILLS_PER_WRITER = 4
FAIL_ON_THEIR_OWN = ("calibrate-camera", "calibrate-hand-eye")   # their stand-in inputs: exit 2 and 4 after the checks


def kill_moments(w: Writer) -> list[tuple[signal.Signals, str, float]]:
    """Generated moments to kill ``w`` at: SIGTERM and SIGKILL in turn, each after its start or once a
    temporary of it exists, and then after a delay drawn from the writer's own generator."""
    rng = np.random.default_rng(zlib.crc32(w.id.encode()))
    return [((signal.SIGTERM, signal.SIGKILL)[i % 2], ("temporary", "start")[int(rng.integers(2))],
             round(float(rng.uniform(0.0, 1.5)), 3)) for i in range(KILLS_PER_WRITER)]


def _complete(path: Path) -> bool:
    """Is ``path`` a whole output: a folder its manifest lists exactly, or a file of its format ending as one does."""
    from phonepose import files

    if path.is_dir():
        listed = files._listed_in_manifest(path / MANIFEST)
        return listed is not None and listed == files._tree_entries(path) - {MANIFEST}
    data = path.read_bytes()
    if path.suffix == ".png":
        return data.endswith(b"IEND\xaeB`\x82")
    if path.suffix == ".rrd":
        from phonepose.viewer.sink import _ends_with_footer
        return _ends_with_footer(path)
    if path.suffix == ".mcap":
        from phonepose.session import SessionReader
        with SessionReader(path) as reader:
            return reader.summary().message_count > 0
    if path.suffix == ".parquet":
        import pyarrow.parquet as pq
        return pq.read_table(path).num_rows > 0
    return len(data) > 0 and data.endswith(b"\n")      # a YAML calibration


def _earlier_outputs(w: Writer, d: Path) -> list[str]:
    """The earlier outputs a run replaces (its own and the folders it also writes), written now: their names."""
    _earlier_output(w, d)
    names = [w.name]
    for other in also_named(w):
        if not Path(other).suffix:                       # a folder (playback's --out beside --rerun)
            (d / other).mkdir()
            (d / other / MANIFEST).write_text('{"written_by": "phonepose", "files": ["stale.txt"]}\n')
            (d / other / "stale.txt").write_text("an earlier run's file")
            names.append(other)
    return names                                         # (a new recording beside them is not an earlier output)


@pytest.mark.parametrize("w,moment", [
    pytest.param(w, m, id=f"{w.id}-{m[0].name}-{m[1]}+{m[2]}s",
                 marks=[] if w.ok and i < 2 else [pytest.mark.slow])
    for w in KILLED for i, m in enumerate(kill_moments(w))])
def test_a_killed_run_leaves_the_earlier_output_as_it_was(w: Writer, moment, good_session, tmp_path, cli):
    """SIGTERM or SIGKILL at a generated moment: the earlier outputs stay byte for byte as they were, unless the
    run put its new ones in place (exit 0; after SIGKILL: whole new outputs), never a mix of the two nor a part.
    SIGTERM leaves no temporary; what SIGKILL leaves, the next command writing in that folder removes."""
    sig, after, extra_s = moment
    d = tmp_path / "d"
    d.mkdir()
    inp = make_input(w, d, good_session)
    names = _earlier_outputs(w, d)
    before = snapshot(d)
    child = subprocess.Popen([sys.executable, "-m", "phonepose", *argv_for(w, d, d / w.name, inp)], cwd=tmp_path,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        if after == "temporary":
            wait_until(lambda: child.poll() is not None or temporaries(d), what=f"a temporary of {w.id}")
        time.sleep(extra_s)                        # the generated moment itself, not a wait for a condition
        child.send_signal(sig)
        _, err = child.communicate(timeout=DEADLINE_S)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    now = snapshot(d)
    for name in names:
        old = {k: v[:2] for k, v in before.items() if k == name or k.startswith(name + "/")}
        new = {k: v[:2] for k, v in now.items() if k == name or k.startswith(name + "/")}
        if child.returncode == 0 or (sig == signal.SIGKILL and new != old):
            assert new != old and _complete(d / name), (name, child.returncode, err)   # the run's own, whole
            assert "phonepose: error:" not in err, err
        elif w.id == "batch" and sig == signal.SIGTERM and new != old:
            # a stopped batch writes the rows it finished first (docs/reliability.md, "Stopping a batch"): the
            # table is then a whole one, never a part
            assert _complete(d / name) and child.returncode == 143, (name, child.returncode, err)
            from phonepose.batch.table import read_rows
            (tmp_path / "earlier.parquet").write_bytes(old[name][1])
            assert set(read_rows(tmp_path / "earlier.parquet")) <= set(read_rows(d / name))   # the earlier rows kept
        else:
            assert new == old, (name, child.returncode, err)            # byte for byte the earlier one
    if sig == signal.SIGTERM and child.returncode not in (0, -signal.SIGTERM):   # (-15: before the command began)
        if w.id in FAIL_ON_THEIR_OWN and child.returncode != 143:
            one_line(err)                          # its own error line, the signal after it
        else:
            assert child.returncode == 143 and err.strip().splitlines()[-1].startswith(
                "phonepose: error: terminated (SIGTERM)"), err
    if sig == signal.SIGTERM:
        assert not temporaries(d), temporaries(d)
    code, _, err = cli("marker", "--out", d / "next.png")   # another command writing in the folder
    assert code == 0, err
    assert not temporaries(d), temporaries(d)


# ----------------------------------------------------------------------------- the docs' matrix
def label(w: Writer) -> str:
    if w.title:
        return w.title
    words = []
    for a in w.argv:
        if a.startswith(("-", "{")):
            break
        words.append(a)
    return f"{' '.join(words)} {w.option}"


def markdown_matrix() -> str:
    """Which case runs for which command (slow: only with the slow tests, `pytest -m slow`)."""
    rows = ["| command | " + " | ".join(c.what for c in CASES) + " |", "|---|" + "---|" * len(CASES)]
    for w in WRITERS:
        cells = [("slow" if c.slow(w) else "✓") if c.applies(w) else "–" for c in CASES]
        rows.append(f"| `{label(w)}` | " + " | ".join(cells) + " |")
    return "\n".join(rows)


if __name__ == "__main__":
    print(markdown_matrix())
