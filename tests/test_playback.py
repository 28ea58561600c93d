"""``phonepose playback`` end to end: outputs, determinism, CLI names and errors, Rerun read-back."""

from __future__ import annotations

import json
import os
import re

import numpy as np
import pytest

from phonepose.errors import ConfigError, OutputError
from phonepose.pipeline.trackers import tracker_names
from phonepose.playback import rerun_log as paths
from phonepose.playback.engine import run_playback
from phonepose.schemas.topics import Topic, tracker_pose_topic
from phonepose.session import SessionReader, codec
from phonepose.testing.playback_session import write_test_session
from phonepose.viewer import entities as E


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    p = tmp_path_factory.mktemp("pb") / "s.mcap"
    write_test_session(p, duration_s=2.5)
    return p


def test_outputs_and_metrics_layout(session, tmp_path):
    out = tmp_path / "out"
    r = run_playback(session, trackers=["all"], out_dir=out)
    names = tracker_names()
    assert sorted(os.listdir(out / "trajectories")) == sorted(f"{n}.tum" for n in names)
    doc = json.loads((out / "metrics.json").read_text())
    assert list(doc) == ["session", "rate_hz", "trackers"]
    assert r.metrics == doc
    assert doc["session"] == "s.mcap" and doc["rate_hz"] == 20
    assert list(doc["trackers"]) == names
    for m in doc["trackers"].values():
        assert list(m) == ["inside", "outside", "total"]
        for scope in ("inside", "outside"):
            assert list(m[scope]) == ["frames", "p_ate_m", "r_ate_deg", "p_re_m"]
        assert list(m["total"]) == ["frames", "p_ate_m", "r_ate_deg", "p_re_m",
                                    "boundary_jumps", "boundary_jump_max_m", "boundary_jump_rms_m",
                                    "lag_s", "lag_resolution_s", "jitter_m", "jitter_deg", "still_ticks",
                                    "availability"]
        assert 0 < m["total"]["availability"] <= 1 and m["total"]["lag_resolution_s"] == 0.005
        assert -0.5 <= m["total"]["lag_s"] <= 0.5
        assert m["total"]["boundary_jumps"] >= 1 and m["total"]["boundary_jump_max_m"] >= m["total"]["boundary_jump_rms_m"] > 0
        assert m["inside"]["frames"] > 5 and m["outside"]["frames"] > 5
        assert m["inside"]["frames"] + m["outside"]["frames"] == m["total"]["frames"]
        assert all(m["total"][k] is not None and m["total"][k] >= 0 for k in ("p_ate_m", "r_ate_deg", "p_re_m"))
    # T1 carries the test session's anchor error (3.7 cm, 2 deg) outside; T4 uses the marker inside
    t1, t4 = doc["trackers"]["T1"], doc["trackers"]["T4"]
    assert t1["outside"]["r_ate_deg"] == pytest.approx(2.0, abs=0.05)
    assert t4["inside"]["p_ate_m"] < t1["inside"]["p_ate_m"]
    # TUM: one line per task-window tick with a pose, display_vio, ns stamps
    rows = np.loadtxt(out / "trajectories" / "T1.tum")
    assert rows.shape == (r.trajectories["T1"].stamps_ns.size, 8)
    header, tag, first = (out / "trajectories" / "T1.tum").read_text().splitlines()[:3]
    assert header == "# timestamp tx ty tz qx qy qz qw" and re.fullmatch(r"# session: s\.mcap [0-9a-f]{16}", tag)
    assert first.split()[0] == "1700000000.300000000"
    gt = np.loadtxt(out / "groundtruth.tum")
    assert gt.shape[0] == r.gt_stamps_ns.size == r.n_task_ticks
    # trackers.mcap: markers per new frame, one pose topic per tracker
    with SessionReader(out / "trackers.mcap") as rd:
        s = rd.summary()
        counts = {c.topic: c.count for c in s.channels}
    assert counts[Topic.PIPELINE_MARKERS] > 0
    for n in names:
        assert counts[tracker_pose_topic(n)] >= r.trajectories[n].stamps_ns.size
    # the poses in trackers.mcap are the trajectory's, stamped with the tick time
    traj = r.trajectories["T7"]
    with SessionReader(out / "trackers.mcap") as rd:
        msgs = {m.log_time_ns: m.msg for m in rd.messages([tracker_pose_topic("T7")])}
    for i in (0, traj.stamps_ns.size // 2, traj.stamps_ns.size - 1):
        m = msgs[int(traj.stamps_ns[i])]
        assert m.frame_id == "display_vio" and m.timestamp.ToNanoseconds() == traj.stamps_ns[i]
        assert codec.pose_of(m.pose).allclose(traj.poses[i], atol=1e-12)


def test_determinism_byte_identical(session, tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    run_playback(session, trackers=["T1", "T4", "T7"], out_dir=a, correction_math="se3")
    run_playback(session, trackers=["T1", "T4", "T7"], out_dir=b, correction_math="se3")
    for rel in ["metrics.json", "groundtruth.tum", *(f"trajectories/T{i}.tum" for i in (1, 4, 7))]:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel


@pytest.mark.parametrize("name", tracker_names())
def test_every_tracker_from_the_cli(session, tmp_path, cli, name):
    code, out, err = cli("playback", "--quiet", session, "--tracker", name, "--out", tmp_path / "o")
    assert code == 0, err
    assert name in out
    assert (tmp_path / "o" / "trajectories" / f"{name}.tum").exists()
    assert list(json.loads((tmp_path / "o" / "metrics.json").read_text())["trackers"]) == [name]


def test_all_and_repeated_trackers_from_the_cli(session, tmp_path, cli):
    code, out, err = cli("playback", "--quiet", session, "--tracker", "all", "--out", tmp_path / "all")
    assert code == 0, err
    assert sorted(os.listdir(tmp_path / "all" / "trajectories")) == sorted(f"{n}.tum" for n in tracker_names())
    code, out, err = cli("playback", "--quiet", session, "-t", "T1", "-t", "T7", "--out", tmp_path / "two", "--rate", "10",
                         "--start", "0.5", "--end", "2")
    assert code == 0, err
    doc = json.loads((tmp_path / "two" / "metrics.json").read_text())
    assert list(doc["trackers"]) == ["T1", "T7"] and doc["rate_hz"] == 10


def test_unknown_tracker_is_one_line_listing_valid_names(session, tmp_path, cli):
    code, out, err = cli("playback", "--quiet", session, "--tracker", "T99", "--out", tmp_path / "x")
    assert code == ConfigError.exit_code
    line = err.strip()
    assert "\n" not in line and "T99" in line
    assert all(n in line for n in tracker_names()) and "all" in line
    assert not (tmp_path / "x").exists()


def test_output_not_writable_is_output_error(session, tmp_path, cli):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, out, err = cli("playback", "--quiet", session, "--tracker", "T1", "--out", blocker / "sub")
    assert code == OutputError.exit_code
    assert err.strip() == f"phonepose: error: --out {blocker / 'sub'}: {blocker} is not a directory"


def test_missing_session_and_bad_options(tmp_path, cli, session):
    code, _, err = cli("playback", "--quiet", tmp_path / "nope.mcap", "--out", tmp_path / "o")
    assert code == 2 and "no such file" in err
    code, _, err = cli("playback", "--quiet", session, "--rate", "0", "--out", tmp_path / "o")
    assert code == ConfigError.exit_code
    code, _, err = cli("playback", "--quiet", session, "--correction-math", "bogus", "--out", tmp_path / "o")
    assert code == ConfigError.exit_code


@pytest.mark.parametrize("kind", ["no_gt", "no_imu", "no_marker"])
def test_sessions_missing_a_stream_play_back(tmp_path, kind):
    p = tmp_path / f"{kind}.mcap"
    write_test_session(p, duration_s=1.5, gt=kind != "no_gt", imu=kind != "no_imu", marker=kind != "no_marker")
    r = run_playback(p, trackers=["all"], out_dir=tmp_path / "out")
    doc = json.loads((tmp_path / "out" / "metrics.json").read_text())
    for name in tracker_names():
        assert r.trajectories[name].stamps_ns.size > 0
        m = doc["trackers"][name]
        if kind == "no_gt":
            for scope in m.values():
                assert scope["p_ate_m"] is None and scope["r_ate_deg"] is None and scope["p_re_m"] is None
        elif kind == "no_marker":
            assert m["inside"]["frames"] == 0 and m["inside"]["p_ate_m"] is None
            assert m["outside"]["p_ate_m"] is not None and m["outside"]["p_ate_m"] > 0
        else:
            assert m["total"]["p_ate_m"] is not None
    assert (tmp_path / "out" / "groundtruth.tum").exists() == (kind != "no_gt")
    assert not r.has_gt if kind == "no_gt" else r.has_gt


def test_no_gt_cli_says_unavailable(tmp_path, cli):
    p = tmp_path / "nogt.mcap"
    write_test_session(p, duration_s=1.0, gt=False)
    code, out, err = cli("playback", "--quiet", p, "-t", "T1", "--out", tmp_path / "o")
    assert code == 0, err
    assert "n/a" in out and "unavailable" in out


def _rrd_columns(path):
    import rerun.chunk as rc

    found: dict[str, dict] = {}
    for chunk in rc.RrdReader(str(path)).stream().to_chunks():
        entry = found.setdefault(chunk.entity_path, {"columns": set(), "timelines": set(), "rows": 0, "batches": []})
        batch = chunk.to_record_batch()
        entry["columns"].update(batch.schema.names)
        entry["timelines"].update(chunk.timeline_names)
        entry["rows"] += chunk.num_rows
        entry["batches"].append(batch)
    return found


def test_rrd_read_back(session, tmp_path, monkeypatch):
    monkeypatch.setattr(paths, "SEGMENT_TICKS", 40)   # 50 ticks: one closed trajectory part + the open one
    rrd = tmp_path / "s.rrd"
    r = run_playback(session, trackers=["T1", "T7"], out_dir=tmp_path / "o", rerun_path=rrd)
    assert rrd.exists() and r.rerun_path == str(rrd)
    found = _rrd_columns(rrd)
    image = found[E.IMAGE]
    assert "EncodedImage:blob" in image["columns"] and "tick" in image["timelines"] and "time" in image["timelines"]
    assert "Pinhole:image_from_camera" in image["columns"]
    # the recorded JPEG bytes, untouched
    with SessionReader(session) as rd:
        first_jpeg = next(iter(rd.messages([Topic.CAMERA_IMAGE]))).msg.data
    blobs = [b for batch in image["batches"] if "EncodedImage:blob" in batch.schema.names
             for b in batch.column("EncodedImage:blob").to_pylist() if b is not None]
    flat = [bytes(b[0] if isinstance(b, list) and b and not isinstance(b[0], int) else b) for b in blobs]
    assert first_jpeg in flat
    markers = found[E.MARKER]
    assert "LineStrips2D:strips" in markers["columns"] and "tick" in markers["timelines"]
    assert "LineStrips2D:labels" in markers["columns"]
    assert "Clear:is_recursive" in markers["columns"]            # cleared when the marker left the view
    for p in (E.GT_CONTROLLER, E.tracker_pose("T1"), E.tracker_pose("T7")):
        assert "Transform3D:translation" in found[p]["columns"] and "tick" in found[p]["timelines"], p
    for p in (E.GT_TRAJECTORY, E.tracker_trajectory("T7")):
        closed, open_ = found[p + "/0000"], found[p + "/open"]
        assert "LineStrips3D:strips" in closed["columns"] and "LineStrips3D:strips" in open_["columns"], p
        assert "Clear:is_recursive" in open_["columns"]      # emptied when its points were closed
        first = [x for b in closed["batches"] for x in b.column("LineStrips3D:strips").to_pylist() if x]
        assert len(first) == 1 and len(first[0][0]) >= 30      # about 40 ticks of points, one strip
    assert "Scalars:scalars" in found[E.position_error("T7")]["columns"]
    assert "Scalars:scalars" in found[E.rotation_error("T1")]["columns"]
    import rerun.chunk as rc

    reader = rc.RrdReader(str(rrd))
    assert len(reader.blueprints()) == 1
    # the default blueprint: 3D view of /world, the camera view, one error plot per quantity
    values = []
    for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch = chunk.to_record_batch()
        for n in batch.schema.names:
            if n in ("ViewBlueprint:space_origin", "ViewContents:query"):
                values += [str(v) for v in batch.column(n).to_pylist()]
    text = " ".join(values)
    assert "'/world'" in text and f"'{E.IMAGE}'" in text
    assert E.POSITION_ERRORS in text and E.ROTATION_ERRORS in text


@pytest.mark.slow
def test_simulator_session_plays_back(tmp_path):
    """Integration with the simulator: a real exp2 session through every tracker."""
    import subprocess
    import sys

    sim = tmp_path / "sim.mcap"
    r = subprocess.run([sys.executable, "-m", "phonepose", "record", "sim", "--scenario", "exp2", "--path", "TRI2",
                        "--trial", "1", "--seed", "0", "--out", str(sim)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    res = run_playback(sim, trackers=["all"], out_dir=tmp_path / "out")
    doc = res.metrics
    assert res.has_gt and res.n_task_ticks > 50
    for name in tracker_names():
        m = doc["trackers"][name]
        assert m["inside"]["frames"] > 0 and m["outside"]["frames"] > 0
        assert m["total"]["frames"] == m["inside"]["frames"] + m["outside"]["frames"]
    # the marker is far better than anchor-mapped VIO while it is in view (paper Table 4)
    assert doc["trackers"]["T4"]["inside"]["p_ate_m"] < 0.5 * doc["trackers"]["T1"]["inside"]["p_ate_m"]
    assert doc["trackers"]["T7"]["inside"]["p_ate_m"] == doc["trackers"]["T4"]["inside"]["p_ate_m"]


def test_realtime_paces_ticks_and_otherwise_no_wall_clock(session, tmp_path):
    import time

    t0 = time.monotonic()
    r = run_playback(session, trackers=["T1"], write_outputs=False, realtime=True, start_s=0.5, end_s=1.1)
    took = time.monotonic() - t0
    assert r.n_ticks == 13 and r.out_dir is None and r.files == {}
    assert took >= 0.55                      # 12 periods of 50 ms, paced
    fast = run_playback(session, trackers=["T1"], write_outputs=False, start_s=0.5, end_s=1.1)
    np.testing.assert_array_equal(fast.trajectories["T1"].stamps_ns, r.trajectories["T1"].stamps_ns)
    assert fast.metrics == r.metrics


def test_progress_callback_counts_every_tick(session):
    seen = []
    r = run_playback(session, trackers=["T4"], write_outputs=False, progress=lambda done, total: seen.append((done, total)))
    assert [d for d, _ in seen] == list(range(1, r.n_ticks + 1))
    assert all(total == r.n_ticks for _, total in seen)


def test_cli_rerun_option_and_spawn_conflict(session, tmp_path, cli):
    rrd = tmp_path / "s.rrd"
    code, out, err = cli("playback", "--quiet", session, "-t", "T7", "--out", tmp_path / "o", "--rerun", rrd)
    assert code == 0, err
    assert rrd.exists() and rrd.stat().st_size > 10_000 and "rerun:" in out
    code, out, err = cli("playback", "--quiet", session, "-t", "T7", "--out", tmp_path / "o", "--rerun", rrd, "--spawn")
    assert code == ConfigError.exit_code and "exclusive" in err
