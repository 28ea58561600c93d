"""run_playback checks everything before its first side effect, and the tracker capabilities it reads."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from phonepose.errors import SessionContentError
from phonepose.playback.engine import PlaybackOptions, run_playback
from phonepose.testing.playback_session import write_test_session


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("options")
    write_test_session(d / "s.mcap", duration_s=1.0)
    write_test_session(d / "nocam.mcap", duration_s=1.0, camera=False)
    return d / "s.mcap", d / "nocam.mcap"


def test_a_tracker_given_twice_is_refused_before_any_file(sessions, tmp_path, cli):
    out = tmp_path / "o"
    code, _, err = cli("playback", str(sessions[0]), "-q", "-t", "T1", "-t", "T1", "--out", str(out))
    assert code == 5 and err.strip() == "phonepose: error: tracker given twice: T1, T1"
    assert not out.exists()   # formerly a 40-byte trackers.mcap that `info` reported as damaged


def test_a_missing_session_leaves_nothing_behind(tmp_path, cli):
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        code, _, err = cli("playback", "missing.mcap", "-q")
    finally:
        os.chdir(cwd)
    assert code == 2 and err.startswith("phonepose: error: ") and "missing.mcap" in err
    assert list(tmp_path.iterdir()) == []   # formerly ./playback-missing/trajectories/


def test_t8_is_refused_on_a_camera_less_session_like_t7(sessions, tmp_path):
    for name in ("T7", "T7L", "T8"):
        with pytest.raises(SessionContentError, match=rf"no camera images .*: {name} need the camera; "
                                                      r"run the VIO-only trackers with -t T1 -t T2$"):
            run_playback(sessions[1], trackers=["T1", name, "T2"], out_dir=tmp_path / name)
        assert not (tmp_path / name).exists()
    r = run_playback(sessions[1], PlaybackOptions(trackers=["T1", "T2"], write_outputs=False))
    assert set(r.trajectories) == {"T1", "T2"} and r.n_ticks > 0


def test_options_whole_or_as_keywords_give_the_same_result(sessions):
    a = run_playback(sessions[0], PlaybackOptions(trackers="T4,T8", write_outputs=False, rate_hz=10))
    b = run_playback(sessions[0], trackers="T4,T8", write_outputs=False, rate_hz=10)
    assert a.metrics == b.metrics
    assert a.n_ticks == b.n_ticks == 11   # 1 s at 10 Hz, both ends
