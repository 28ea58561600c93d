"""The boundary jump and the paper's metrics from files: playback's in_view.txt + `evaluate --metric paper`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from phonepose.evaluation.trajectory import load_in_view, read_session_tag, write_in_view
from phonepose.playback.engine import run_playback
from phonepose.testing.playback_session import write_test_session


@pytest.fixture(scope="module")
def played(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("jump")
    session = tmp / "s.mcap"
    write_test_session(session)
    out = tmp / "out"
    result = run_playback(session, trackers="T4,T7,T8", out_dir=out)
    return out, result


def test_in_view_file_matches_the_ticks_and_round_trips(played, tmp_path):
    out, result = played
    stamps, flags = load_in_view(out / "in_view.txt")
    np.testing.assert_allclose(stamps, result.gt_stamps_ns / 1e9, rtol=0, atol=1e-6)   # float s near 1.7e9: ~0.2 us
    t4 = result.trajectories["T4"]
    assert flags.sum() == t4.inside.sum() and 0 < flags.sum() < flags.size
    tag = read_session_tag(out / "in_view.txt")
    assert tag is not None and tag.startswith("s.mcap ")
    write_in_view(tmp_path / "again.txt", result.gt_stamps_ns, flags, session=tag)
    assert (tmp_path / "again.txt").read_bytes() == (out / "in_view.txt").read_bytes()


@pytest.mark.parametrize("tracker", ["T4", "T8"])
def test_evaluate_paper_from_files_gives_playbacks_metrics(played, tracker, cli):
    out, result = played
    r = cli("evaluate", "--metric", "paper", "--gt", str(out / "groundtruth.tum"),
                  "--est", str(out / "trajectories" / f"{tracker}.tum"), "--in-view", str(out / "in_view.txt"), "--json")
    assert r.returncode == 0, r.stderr
    from_files = json.loads(r.stdout)
    in_memory = result.metrics["trackers"][tracker]
    for scope in ("inside", "outside", "total"):
        assert from_files[scope]["frames"] == in_memory[scope]["frames"]
        for key, value in in_memory[scope].items():
            if isinstance(value, float):   # the files carry 9 decimals
                assert from_files[scope][key] == pytest.approx(value, rel=1e-6, abs=1e-9), (scope, key)
    assert in_memory["total"]["boundary_jumps"] >= 1


def test_t4_jumps_where_t8_does_not(played):
    _, result = played
    total = {n: result.metrics["trackers"][n]["total"] for n in ("T4", "T8")}
    # the test session's anchor error (3.7 cm) is T4's step between marker and VIO
    assert total["T4"]["boundary_jump_max_m"] > 0.02
    assert total["T8"]["boundary_jump_max_m"] < 0.5 * total["T4"]["boundary_jump_max_m"]


def test_evaluate_paper_needs_in_view_and_reads_it_strictly(played, tmp_path, cli):
    out, _ = played
    args = ["evaluate", "--metric", "paper", "--gt", str(out / "groundtruth.tum"),
            "--est", str(out / "trajectories" / "T8.tum")]
    r = cli(*args)
    assert r.returncode == 5 and "--in-view" in r.stderr and "Traceback" not in r.stderr
    bad = tmp_path / "bad.txt"
    bad.write_text("# timestamp in_view\n1.0 yes\n")
    r = cli(*args, "--in-view", str(bad))
    assert r.returncode == 2 and "bad.txt:2" in r.stderr and "Traceback" not in r.stderr
