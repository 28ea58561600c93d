"""The one output rule (phonepose/files.py): checked first, written to a locked temporary, committed whole."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from conftest import DEADLINE_S

from phonepose.cli import flags
from phonepose.errors import ConfigError, InputFileError, OutputError
from phonepose.files import MANIFEST, TMP_SUFFIX, OutputPlan, check_input, write_text_output


def _tree(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (relative path -> bytes): what a test compares before and after."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _write_dir(plan_dir, files: dict[str, str]) -> None:
    for name, text in files.items():
        p = plan_dir.tmp / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)


# ----------------------------------------------------------------------------- inputs
def test_check_input_refuses_a_fifo_at_once(tmp_path):
    fifo = tmp_path / "s.mcap"
    os.mkfifo(fifo)
    with pytest.raises(InputFileError) as e:
        check_input(fifo, "session")   # never opened: opening a FIFO with no writer blocks forever
    assert str(e.value) == f"{fifo}: not a regular file (a FIFO, socket or device): give a session"


@pytest.mark.parametrize("make, message", [
    (lambda p: None, "{p}: no such file"),
    (lambda p: p.mkdir(), "{p}: is a directory, not a session"),
])
def test_check_input_missing_or_directory(tmp_path, make, message):
    p = tmp_path / "x.mcap"
    make(p)
    with pytest.raises(InputFileError) as e:
        check_input(p, "session")
    assert str(e.value) == message.format(p=p)


def test_check_input_refuses_a_device():
    with pytest.raises(InputFileError, match="not a regular file"):
        check_input("/dev/null", "session")


# ----------------------------------------------------------------------------- checks before work
def test_missing_parent_is_one_line_and_creates_nothing(tmp_path):
    plan = OutputPlan()
    plan.file(tmp_path / "no" / "such" / "x.rrd", "--rerun", suffixes=(".rrd",))
    with pytest.raises(OutputError) as e:
        with plan:
            raise AssertionError("the block must not run")
    assert str(e.value) == f"--rerun {tmp_path / 'no' / 'such' / 'x.rrd'}: directory {tmp_path / 'no' / 'such'} does not exist"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("link", ["same", "symlink", "hardlink"])
def test_an_output_that_is_an_input_is_refused_and_the_input_kept(tmp_path, link):
    session = tmp_path / "s.mcap"
    session.write_bytes(b"\x89MCAP0\r\n recording")
    out = {"same": session, "symlink": tmp_path / "l.mcap", "hardlink": tmp_path / "h.mcap"}[link]
    if link == "symlink":
        out.symlink_to(session)
    elif link == "hardlink":
        os.link(session, out)
    plan = OutputPlan(inputs=[session])
    plan.file(out, "--out")
    with pytest.raises(InputFileError, match=r"writing it would destroy the input"):
        with plan:
            raise AssertionError("the block must not run")
    assert session.read_bytes() == b"\x89MCAP0\r\n recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted({"s.mcap", out.name})


def test_an_output_folder_holding_the_input_is_refused(tmp_path):
    d = tmp_path / "d"
    d.mkdir()
    (d / MANIFEST).write_text("{}")
    inp = d / "trackers.mcap"
    inp.write_bytes(b"data")
    plan = OutputPlan(inputs=[inp])
    plan.dir(d, "--out")
    with pytest.raises(InputFileError) as e:
        with plan:
            pass
    assert str(e.value) == f"--out {d}: holds the input {inp} and would be replaced whole; choose another --out"
    assert inp.read_bytes() == b"data"


def test_wrong_extension_is_refused(tmp_path):
    plan = OutputPlan()
    plan.file(tmp_path / "out.txt", "--rerun", suffixes=(".rrd",), what="a Rerun recording")
    with pytest.raises(ConfigError) as e:
        with plan:
            pass
    assert str(e.value) == f"--rerun {tmp_path / 'out.txt'}: writes a Rerun recording; give a name ending in .rrd"


@pytest.mark.parametrize("device", ["/dev/null", "/dev/full"])
def test_a_device_is_never_replaced(device):
    before = os.stat(device)
    plan = OutputPlan()
    plan.file(device, "--out")
    with pytest.raises(OutputError, match="not a regular file"):
        with plan:
            pass
    after = os.stat(device)
    assert (after.st_ino, after.st_rdev) == (before.st_ino, before.st_rdev)


def test_two_outputs_naming_one_file_are_refused(tmp_path):
    plan = OutputPlan()
    plan.file(tmp_path / "a.mcap", "--out")
    plan.file(tmp_path / "a.mcap", "--rerun")
    with pytest.raises(ConfigError, match="--out and --rerun name the same file"):
        with plan:
            pass
    assert list(tmp_path.iterdir()) == []


def test_the_current_directory_is_not_an_output_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    plan = OutputPlan()
    plan.dir(".", "--out")
    with pytest.raises(OutputError, match="is the current directory"):
        with plan:
            pass


# ----------------------------------------------------------------------------- writing and committing
def test_a_folder_is_replaced_whole_and_only_on_success(tmp_path):
    out = tmp_path / "run"
    plan = OutputPlan()
    _write = plan.dir(out, "--out", command="playback")
    with plan:
        _write_dir(_write, {"trajectories/T1.tum": "1", "trajectories/T2.tum": "2", "metrics.json": "{}"})
    first = _tree(out)
    assert set(first) == {"trajectories/T1.tum", "trajectories/T2.tum", "metrics.json", MANIFEST}

    # a failed run leaves the earlier output exactly as it was, and no temporary
    plan = OutputPlan()
    d = plan.dir(out, "--out", command="playback")
    with pytest.raises(RuntimeError):
        with plan:
            _write_dir(d, {"trajectories/T1.tum": "partial"})
            raise RuntimeError("the session is damaged")
    assert _tree(out) == first
    assert [p.name for p in tmp_path.iterdir()] == ["run"]

    # a successful run replaces it whole: T2.tum of the earlier run does not survive
    plan = OutputPlan()
    d = plan.dir(out, "--out", command="playback")
    with plan:
        _write_dir(d, {"trajectories/T1.tum": "new", "metrics.json": "{new}"})
    assert set(_tree(out)) == {"trajectories/T1.tum", "metrics.json", MANIFEST}
    assert (out / "trajectories" / "T1.tum").read_text() == "new"
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_a_folder_of_someone_else_is_refused_and_an_empty_one_is_used(tmp_path):
    mine = tmp_path / "notes"
    mine.mkdir()
    (mine / "thesis.tex").write_text("precious")
    plan = OutputPlan()
    plan.dir(mine, "--out")
    with pytest.raises(OutputError) as e:
        with plan:
            pass
    assert str(e.value) == f"--out {mine}: holds files phonepose did not write; choose a new folder, or empty it"
    assert (mine / "thesis.tex").read_text() == "precious"

    empty = tmp_path / "empty"
    empty.mkdir()
    plan = OutputPlan()
    d = plan.dir(empty, "--out")
    with plan:
        (d.tmp / "metrics.json").write_text("{}")
    assert set(_tree(empty)) == {"metrics.json", MANIFEST}


def _earlier_run(out: Path) -> dict[str, bytes]:
    plan = OutputPlan()
    d = plan.dir(out, "--out", command="playback")
    with plan:
        _write_dir(d, {"trajectories/T1.tum": "1", "metrics.json": "{}"})
    return _tree(out)


@pytest.mark.parametrize("added", ["my_recording.mcap", "trajectories/mine.tum", "notes/a.txt"])
def test_a_file_saved_into_an_earlier_output_folder_stops_its_replacement(tmp_path, added):
    """The manifest lists every file and folder of the run: anything else in the folder (a recording
    saved there after the run, at any depth) is the user's, and the folder is not replaced."""
    out = tmp_path / "run"
    _earlier_run(out)
    (out / added).parent.mkdir(exist_ok=True)
    (out / added).write_bytes(b"\x89MCAP0\r\n precious")
    before = _tree(out)
    plan = OutputPlan()
    d = plan.dir(out, "--out", command="playback")
    with pytest.raises(OutputError) as e:
        with plan:
            raise AssertionError("the block must not run")
    extra = "notes, notes/a.txt" if added == "notes/a.txt" else added
    assert str(e.value) == f"--out {out}: holds {extra}, which phonepose did not write there; " \
                           f"move {'them' if ',' in extra else 'it'} away, or choose a new folder"
    assert _tree(out) == before and sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    # also when it arrives while the command works: checked again before the folder is replaced, and the finished
    # run is kept beside it (it was removed with its temporary: an experiment's hour of work)
    (out / added).unlink()
    if added == "notes/a.txt":
        (out / "notes").rmdir()
    plan = OutputPlan()
    d = plan.dir(out, "--out", command="playback")
    with pytest.raises(OutputError) as e:
        with plan:
            (d.tmp / "metrics.json").write_text("{new}")
            (out / "late.mcap").write_bytes(b"precious")
    assert str(e.value) == (f"--out {out}: holds late.mcap, which phonepose did not write there; move it away, or "
                            f"choose a new folder (this run's output is kept in {out}.new)")
    assert (out / "late.mcap").read_bytes() == b"precious" and (out / "metrics.json").read_text() == "{}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "run.new"]
    assert (tmp_path / "run.new" / "metrics.json").read_text() == "{new}"
    plan = OutputPlan()
    d = plan.dir(tmp_path / "run.new", "--out", command="playback")
    with plan:                                   # an output like any other: the next run replaces it
        (d.tmp / "metrics.json").write_text("{newer}")
    assert (tmp_path / "run.new" / "metrics.json").read_text() == "{newer}"


@pytest.mark.parametrize("manifest", ["{}", '{"written_by": "phonepose"}', "not json", '{"files": "x"}'])
def test_an_output_folder_whose_manifest_lists_no_files_is_not_replaced(tmp_path, manifest):
    """An older phonepose wrote no list: files of the user's cannot be told apart, so nothing is replaced."""
    out = tmp_path / "run"
    out.mkdir()
    (out / MANIFEST).write_text(manifest)
    (out / "metrics.json").write_text("{}")
    plan = OutputPlan()
    plan.dir(out, "--out")
    with pytest.raises(OutputError) as e:
        with plan:
            pass
    assert str(e.value) == (f"--out {out}: its {MANIFEST} does not list what phonepose wrote (an older phonepose, "
                            f"or edited), so files of yours in it cannot be told apart; choose a new folder, or "
                            f"empty it")
    assert (out / "metrics.json").read_text() == "{}"


def test_a_symlinked_output_name_is_checked_by_the_file_it_replaces(tmp_path):
    """Written through a link, the file replaced is the link's target: its name must end as the format
    written (``ln -s keep.mcap b.png; phonepose board -o b.png`` would have turned a recording into a PNG)."""
    keep = tmp_path / "notes.txt"
    keep.write_text("precious")
    link = tmp_path / "b.png"
    link.symlink_to(keep.name)
    plan = OutputPlan()
    plan.file(link, "--out", suffixes=(".png",), what="a PNG image")
    with pytest.raises(ConfigError) as e:
        with plan:
            raise AssertionError("the block must not run")
    assert str(e.value) == f"--out {link}: a symlink to {keep}, which does not end in .png; give the file's own name"
    assert keep.read_text() == "precious" and link.is_symlink()
    # a link to a file of the right name is written through, as before: the link stays
    target = tmp_path / "real.png"
    target.write_bytes(b"old")
    link.unlink()
    link.symlink_to(target.name)
    plan = OutputPlan()
    out = plan.file(link, "--out", suffixes=(".png",))
    with plan:
        assert out.tmp is not None
        out.tmp.write_bytes(b"new")
    assert target.read_bytes() == b"new" and link.is_symlink()


@pytest.mark.parametrize("linked", [False, True])
def test_only_a_recording_replaces_a_recording(tmp_path, linked):
    """An existing file that is an MCAP recording is replaced by no other output, whatever its name."""
    rec = tmp_path / "x.yaml"
    rec.write_bytes(b"\x89MCAP0\r\n a recording named like a calibration")
    out_path = tmp_path / "he.yaml" if linked else rec
    if linked:
        out_path.symlink_to(rec.name)
    plan = OutputPlan()
    plan.file(out_path, "--out", suffixes=(".yaml",))
    with pytest.raises(OutputError) as e:
        with plan:
            raise AssertionError("the block must not run")
    what = f"points to {rec}, " if linked else "is "
    assert str(e.value) == f"--out {out_path}: {what}a recording (MCAP), which only a recording replaces; " \
                           f"choose another name"
    assert rec.read_bytes().startswith(b"\x89MCAP0\r\n")


@pytest.mark.parametrize("kind", ["file", "dir"])
def test_a_dangling_symlink_as_output_names_its_target(tmp_path, kind):
    link = tmp_path / ("x.yaml" if kind == "file" else "run")
    link.symlink_to(tmp_path / "nowhere" / "x")
    plan = OutputPlan()
    plan.file(link, "--out") if kind == "file" else plan.dir(link, "--out")
    with pytest.raises(OutputError) as e:
        with plan:
            raise AssertionError("the block must not run")
    assert str(e.value) == f"--out {link}: a symlink to {tmp_path / 'nowhere' / 'x'}, whose directory does not exist"
    assert sorted(p.name for p in tmp_path.iterdir()) == [link.name]


@pytest.fixture
def held(tmp_path):
    """A recording in progress: a file another writer holds with the output rule's lock (flock, as a
    recorder does for its whole run; another open file description conflicts as another process would)."""
    import fcntl

    path = tmp_path / "live.mcap"
    path.write_bytes(b"\x89MCAP0\r\n being recorded")
    fd = os.open(path, os.O_RDWR)
    fcntl.flock(fd, fcntl.LOCK_EX)
    yield path
    os.close(fd)


def test_a_recording_in_progress_is_not_replaced_even_with_force(held):
    """A `recover --force` or a second `record live --force` onto the file a recorder is writing replaced it
    under the recorder, which then reported a valid file that was not its own."""
    plan = OutputPlan()
    plan.file(held, "--out", session=True, force=True)
    with pytest.raises(OutputError) as e:
        with plan:
            raise AssertionError("the block must not run")
    assert str(e.value) == f"--out {held}: another phonepose is writing it (a recording in progress); wait for it " \
                           f"to finish or choose another --out"
    assert held.read_bytes() == b"\x89MCAP0\r\n being recorded"


def test_a_recording_that_begins_while_the_command_works_is_not_replaced(tmp_path):
    import fcntl

    target = tmp_path / "s.mcap"
    target.write_bytes(b"old")
    plan = OutputPlan()
    out = plan.file(target, "--out", session=True, force=True)
    fd = None
    with pytest.raises(OutputError) as e:
        with plan:
            assert out.tmp is not None
            out.tmp.write_bytes(b"new")
            fd = os.open(target, os.O_RDWR)          # a recorder starts on it meanwhile
            fcntl.flock(fd, fcntl.LOCK_EX)
    assert fd is not None
    os.close(fd)
    assert str(e.value) == f"--out {target}: another phonepose began writing it (a recording in progress); not replaced"
    assert target.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["s.mcap"]


def test_reading_a_recording_in_progress_says_so_not_damaged(held):
    """Its footer and index come last: while the recorder holds it, it is not done, not damaged."""
    from phonepose.session import SessionReader

    with pytest.raises(InputFileError) as e:
        SessionReader(held)
    assert str(e.value) == f"{held}: a recording in progress (another phonepose is writing it; its footer and " \
                           f"index come last): wait for it to finish"


def test_a_session_is_not_replaced_without_force(tmp_path):
    s = tmp_path / "s.mcap"
    s.write_bytes(b"old recording")
    plan = OutputPlan()
    plan.file(s, "out", session=True)
    with pytest.raises(OutputError) as e:
        with plan:
            pass
    assert str(e.value) == f"{s} already exists: choose another out, or add force=True to replace it"
    assert flags.message(e.value) == f"{s} already exists: choose another --out, or add --force to replace it"
    assert s.read_bytes() == b"old recording"
    plan = OutputPlan()
    f = plan.file(s, "out", session=True, force=True)
    with plan:
        f.tmp.write_bytes(b"new recording")
    assert s.read_bytes() == b"new recording"


def test_a_file_written_through_a_symlink_keeps_the_link(tmp_path):
    real = tmp_path / "real.yaml"
    real.write_text("old")
    link = tmp_path / "link.yaml"
    link.symlink_to(real)
    write_text_output(link, "new", "--out")
    assert link.is_symlink() and real.read_text() == "new"


_HOLD = textwrap.dedent("""
    import sys, time
    from phonepose.files import OutputPlan
    plan = OutputPlan()
    d = plan.dir(sys.argv[1], "--out")
    with plan:
        (d.tmp / "metrics.json").write_text("partial")
        print("writing", flush=True)
        time.sleep(600)
""")


def _start_holder(out: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", _HOLD, str(out)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "writing"   # waits for the condition, however loaded the machine
    return proc


def test_a_second_writer_stops_and_a_killed_writers_temporary_is_cleared(tmp_path):
    out = tmp_path / "run"
    proc = _start_holder(out)
    try:
        plan = OutputPlan()
        plan.dir(out, "--out")
        with pytest.raises(OutputError) as e:
            with plan:
                pass
        assert str(e.value) == (f"--out {out}: another phonepose (pid {proc.pid}) is writing it; wait for it to "
                                f"finish or choose another --out")
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=DEADLINE_S)
    stale = [p for p in tmp_path.iterdir() if p.name.endswith(TMP_SUFFIX)]
    assert len(stale) == 1 and not out.exists()     # the killed writer left its temporary, not a partial "run"
    plan = OutputPlan()
    d = plan.dir(out, "--out")
    with plan:
        (d.tmp / "metrics.json").write_text("complete")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    assert (out / "metrics.json").read_text() == "complete"


def test_a_writer_of_a_longer_name_is_not_mistaken_for_one_of_this_output(tmp_path):
    """Two runs side by side, --out run and --out run.v2: the temporaries of "run.v2" also matched the pattern
    of "run" (.run.*.phonepose-tmp), so the second run stopped ("another phonepose is writing it") or, had the
    first been killed, cleared what was not its own."""
    proc = _start_holder(tmp_path / "run.v2")
    try:
        plan = OutputPlan()
        d = plan.dir(tmp_path / "run", "--out")
        with plan:
            (d.tmp / "metrics.json").write_text("complete")
        assert (tmp_path / "run" / "metrics.json").read_text() == "complete"
        assert len([p for p in tmp_path.iterdir() if p.name.startswith(".run.v2.")]) == 1   # untouched
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=DEADLINE_S)


@pytest.mark.parametrize("length", [200, 222, 223, 250, 255])
def test_a_name_the_file_system_takes_is_written_whatever_its_length(tmp_path, length):
    """NAME_MAX is 255 bytes; the temporary adds 32 to the name (".NAME.PID-RANDOM.phonepose-tmp"), so names
    of 224 to 255 bytes were refused as "File name too long" (and a recording of such a name could be made
    but never replaced with --force). Its temporary now carries the name's start and a hash."""
    name = "é" * ((length - 4) // 2) + "x" * ((length - 4) % 2) + ".png"     # two bytes a letter: cut inside none
    assert len(os.fsencode(name)) == length
    out = tmp_path / name
    for content in (b"first", b"second"):            # a new output, then one that replaces it
        write_text_output(out, content, "--out")
        assert [p.name for p in tmp_path.iterdir()] == [name]
        assert out.read_bytes() == content
    plan = OutputPlan()
    d = plan.dir(tmp_path / name[:-4], "--out")      # a folder, twice: the earlier one set aside under a name too
    for _ in range(2):
        with plan:
            (d.tmp / "metrics.json").write_text("complete")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([name, name[:-4]])


def test_a_name_too_long_for_the_file_system_is_one_line(tmp_path):
    out = tmp_path / ("m" * 252 + ".png")
    with pytest.raises(OutputError) as e:
        write_text_output(out, b"png", "--out")
    assert str(e.value) == f"cannot write {out}: File name too long"
    assert list(tmp_path.iterdir()) == []


def test_a_replaced_output_keeps_its_permissions(tmp_path):
    """`chmod 600 he.yaml` then the same command again: the new file was 644 (umask), readable by everyone.
    A replaced file or folder keeps its mode; a new one gets the umask's."""
    f, folder = tmp_path / "he.yaml", tmp_path / "run"
    write_text_output(f, "old", "--out")
    assert f.stat().st_mode & 0o777 == 0o666 & ~_umask()
    plan = OutputPlan()
    d = plan.dir(folder, "--out")
    with plan:
        (d.tmp / "metrics.json").write_text("old")
    os.chmod(f, 0o600)
    os.chmod(folder, 0o750)
    write_text_output(f, "new", "--out")
    with plan:
        (d.tmp / "metrics.json").write_text("new")
    assert (f.stat().st_mode & 0o777, folder.stat().st_mode & 0o777) == (0o600, 0o750)
    assert (f.read_text(), (folder / "metrics.json").read_text()) == ("new", "new")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_an_input_named_like_a_temporary_is_never_cleared(tmp_path):
    out = tmp_path / "p.mcap"
    leftover = tmp_path / f".p.mcap.123-abcd{TMP_SUFFIX}"   # what a killed command leaves: the user recovers it
    leftover.write_bytes(b"the only copy")
    plan = OutputPlan(inputs=[leftover])
    f = plan.file(out, "--out", session=True)
    with plan:
        f.tmp.write_bytes(b"recovered")
    assert leftover.read_bytes() == b"the only copy"
    assert out.read_bytes() == b"recovered"


def test_interrupted_file_write_leaves_the_old_file(tmp_path):
    p = tmp_path / "he.yaml"
    p.write_text("old calibration")
    plan = OutputPlan()
    f = plan.file(p, "--out")
    with pytest.raises(KeyboardInterrupt):
        with plan:
            f.tmp.write_text("half")
            raise KeyboardInterrupt
    assert p.read_text() == "old calibration"
    assert [x.name for x in tmp_path.iterdir()] == ["he.yaml"]


def test_a_new_recording_is_written_under_its_own_name_and_kept_when_interrupted(tmp_path):
    s = tmp_path / "live.mcap"
    plan = OutputPlan()
    f = plan.file(s, "--out", in_place=True)
    with pytest.raises(KeyboardInterrupt):
        with plan:
            assert f.tmp == s.absolute()      # what a killed recorder leaves is here, for `phonepose recover`
            s.write_bytes(b"\x89MCAP0\r\n first second")
            raise KeyboardInterrupt
    assert s.read_bytes() == b"\x89MCAP0\r\n first second"
    # over an existing recording only with --force, and then through a temporary
    plan = OutputPlan()
    plan.file(s, "--out", in_place=True)
    with pytest.raises(OutputError, match="already exists"):
        with plan:
            pass
    plan = OutputPlan()
    f = plan.file(s, "--out", in_place=True, force=True)
    with pytest.raises(RuntimeError):
        with plan:
            assert f.tmp != s.absolute()
            f.tmp.write_bytes(b"half of the new one")
            raise RuntimeError("camera unplugged")
    assert s.read_bytes() == b"\x89MCAP0\r\n first second"
    assert [p.name for p in tmp_path.iterdir()] == ["live.mcap"]


# ----------------------------------------------------------------------------- rewritten outputs (a batch's table)
def test_a_rewritten_output_goes_in_whole_at_each_checkpoint_and_stays_locked(tmp_path):
    table = tmp_path / "r.parquet"
    plan = OutputPlan()
    f = plan.file(table, "--out", suffixes=(".parquet",), rewritten=True)
    with pytest.raises(KeyboardInterrupt):
        with plan:
            f.tmp.write_bytes(b"version 1")
            first_tmp = f.tmp
            f.checkpoint()
            assert table.read_bytes() == b"version 1" and f.tmp != first_tmp and not first_tmp.exists()
            other = OutputPlan()                    # a second command on the same output stops
            other.file(table, "--out")
            with pytest.raises(OutputError, match=r"another phonepose \(pid \d+\) is writing it"):
                with other:
                    pass
            f.tmp.write_bytes(b"version 2, half")  # interrupted before its checkpoint
            raise KeyboardInterrupt
    assert table.read_bytes() == b"version 1"      # the unfinished version never goes in
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.parquet"]


def test_check_output_fails_before_the_work(tmp_path):
    from phonepose.files import check_output

    with pytest.raises(OutputError) as e:
        check_output(tmp_path / "no" / "cam.yaml", "--out")
    assert str(e.value) == f"--out {tmp_path / 'no' / 'cam.yaml'}: directory {tmp_path / 'no'} does not exist"
    check_output(tmp_path / "cam.yaml", "--out", suffixes=(".yaml",))
    assert list(tmp_path.iterdir()) == []


def test_an_error_from_inside_names_the_users_paths(tmp_path):
    """A disk-full line from a writer inside a temporary folder names the user's folder, and drops
    "run `phonepose recover`": the temporary is removed."""
    from phonepose.errors import RECOVER_HINT

    plan = OutputPlan()
    d = plan.dir(tmp_path / "exp", "--out")
    with pytest.raises(OutputError) as e:
        with plan:
            raise OutputError(f"cannot write {d.tmp / 'sessions' / 's.mcap'}: No space left on device{RECOVER_HINT}")
    assert str(e.value) == f"cannot write {tmp_path / 'exp' / 'sessions' / 's.mcap'}: No space left on device"
    # a new recording stays under its own name: there the hint is true
    plan = OutputPlan()
    f = plan.file(tmp_path / "s.mcap", "--out", in_place=True)
    with pytest.raises(OutputError) as e:
        with plan:
            f.tmp.write_bytes(b"\x89MCAP0\r\n")
            raise OutputError(f"cannot write {f.tmp}: No space left on device{RECOVER_HINT}")
    assert str(e.value) == f"cannot write {(tmp_path / 's.mcap').absolute()}: No space left on device{RECOVER_HINT}"


@pytest.mark.parametrize("what, expected", [("session", "a session"), ("image", "an image"),
                                            ("MCAP file", "an MCAP file"), ("TOML file", "a TOML file")])
def test_messages_read_as_english(tmp_path, what, expected):
    fifo = tmp_path / "x"
    os.mkfifo(fifo)
    with pytest.raises(InputFileError, match=f"give {expected}$"):
        check_input(fifo, what)


def test_checks_come_in_the_order_that_helps(tmp_path):
    """An output that is the input is said first (whatever its extension), then a directory or device
    in the way, then the extension, then the folder."""
    session = tmp_path / "s.mcap"
    session.write_bytes(b"recording")
    plan = OutputPlan(inputs=[session])
    plan.file(session, "--out", suffixes=(".yaml",))
    with pytest.raises(InputFileError, match="writing it would destroy the input"):
        plan.check()
    plan = OutputPlan()
    plan.file(tmp_path, "--out", suffixes=(".parquet",))
    with pytest.raises(OutputError, match="is a directory; --out takes a file name"):
        plan.check()
