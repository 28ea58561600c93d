"""What a person sees: the playback recording's id, name, colours, units, blueprint and the
detection's diagnostics; the raw session's frame tree as Rerun's MCAP importer reads it."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
import rerun.chunk as rc
from hypothesis import given, settings
from hypothesis import strategies as st

from phonepose.playback.engine import run_playback
from phonepose.playback.rerun_log import METRIC_COLUMNS, axis_colors, metrics_markdown, recording_id
from phonepose.schemas.topics import Frame, Topic
from phonepose.session import SessionReader
from phonepose.testing.playback_session import write_test_session
from phonepose.viewer import entities as E
from phonepose.viewer.scene import WORKING_DEPTH_M
from phonepose.viewer.style import GT_COLOR, TASK_COLOR, TRACKER_COLORS, color_name, tracker_color

DOCS = Path(__file__).resolve().parents[1] / "docs"
TRACKERS = ["T1", "T7", "T8"]


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    p = tmp_path_factory.mktemp("viewer") / "s.mcap"
    write_test_session(p, duration_s=2.5)
    return p


@pytest.fixture(scope="module")
def played(session, tmp_path_factory):
    out = tmp_path_factory.mktemp("viewer-pb")
    rrd = out / "s.rrd"
    result = run_playback(session, trackers=TRACKERS, out_dir=out / "o", rerun_path=rrd)
    return result, rrd, _entities(rrd)


def _entities(rrd) -> dict[str, list]:
    """entity path -> its record batches."""
    found: dict[str, list] = {}
    for chunk in rc.RrdReader(str(rrd)).stream().to_chunks():
        found.setdefault(chunk.entity_path, []).append((chunk, chunk.to_record_batch()))
    return found


def _values(entity: list, column: str) -> list:
    """Every instance of ``column`` in the entity's rows, flattened (a row holds a list of instances)."""
    out = []
    for _, batch in entity:
        if column in batch.schema.names:
            for v in batch.column(column).to_pylist():
                if v is not None:
                    out += v if isinstance(v, list) else [v]
    return out


def _rgb(packed: int) -> tuple[int, int, int]:
    return (packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255


def _recording_id_of(rrd) -> str:
    recs = rc.RrdReader(str(rrd)).recordings()
    assert len(recs) == 1
    return recs[0].recording_id


def test_recording_id_is_the_same_for_the_same_inputs_and_differs_otherwise(session, tmp_path):
    params = {"rate_hz": 20.0, "correction_math": "paper", "start_s": None, "end_s": None, "hand_eye": None,
              "trackers": TRACKERS}
    same = recording_id(session, params)
    assert same == recording_id(session, dict(params))
    assert same.startswith("playback-s-") and re.fullmatch(r"playback-s-[0-9a-f]{16}", same)
    others = {recording_id(session, {**params, "rate_hz": 10.0}),
              recording_id(session, {**params, "trackers": ["T1"]}),
              recording_id(session, {**params, "correction_math": "se3"}),
              recording_id(session, {**params, "start_s": 0.5})}
    other_session = tmp_path / "s.mcap"          # the same name, another content
    write_test_session(other_session, duration_s=2.0)
    others.add(recording_id(other_session, params))
    copy = tmp_path / "copy" / "s.mcap"          # the same content elsewhere: the same recording
    copy.parent.mkdir()
    shutil.copyfile(session, copy)
    assert recording_id(copy, params) == same
    assert same not in others and len(others) == 5


def test_two_playbacks_are_two_recordings_and_a_rerun_is_the_same_one(session, played, tmp_path):
    _, rrd, _ = played
    again = tmp_path / "again.rrd"
    run_playback(session, trackers=TRACKERS, out_dir=tmp_path / "o1", rerun_path=again)
    other = tmp_path / "other.rrd"
    run_playback(session, trackers=TRACKERS, out_dir=tmp_path / "o2", rerun_path=other, rate_hz=10)
    assert _recording_id_of(again) == _recording_id_of(rrd)
    assert _recording_id_of(other) != _recording_id_of(rrd)


def test_recording_name_and_no_wall_clock_timeline(played):
    _, rrd, found = played
    names = _values(found.get(rr.RECORDING_PROPERTIES_PATH, []), "RecordingInfo:name")
    assert names == ["s.mcap · T1 T7 T8 · 20 Hz"]
    timelines = {t for entity in found.values() for chunk, _ in entity for t in chunk.timeline_names}
    assert timelines == {"tick", "time", "session_time"}   # no log_time: the recording lasts as long as the session


def test_each_tracker_has_one_colour_on_every_entity(played):
    _, _, found = played
    seen = {}
    for name in TRACKERS:
        dots = {_rgb(c) for c in _values(found[E.tracker_pose(name)], "Points3D:colors")}
        labels = set(_values(found[E.tracker_pose(name)], "Points3D:labels"))
        # the axes in the tracker's colour (x as is, y lighter, z darker), never the plain RGB of every pose
        axes = [_rgb(c) for c in _values(found[E.tracker_pose(name)], "Arrows3D:colors")]
        assert axes and len(axes) % 3 == 0
        assert {tuple(axes[i:i + 3]) for i in range(0, len(axes), 3)} == {tuple(map(tuple, axis_colors(tracker_color(name))))}
        assert axis_colors(tracker_color(name))[0].tolist() == list(tracker_color(name))
        # the name is data on the dot, not drawn: nine labels at one place would cover the scene
        assert set(_values(found[E.tracker_pose(name)], "Points3D:show_labels")) == {False}
        lines = {_rgb(c) for path in found if path.startswith(E.tracker_trajectory(name) + "/")
                 for c in _values(found[path], "LineStrips3D:colors")}
        series = {_rgb(c) for path in (E.position_error(name), E.rotation_error(name))
                  for c in _values(found[path], "SeriesLines:colors")}
        assert dots == lines == series == {tracker_color(name)}, name
        assert labels == {name}
        seen[name] = tracker_color(name)
    assert len(set(seen.values())) == len(TRACKERS)
    gt = {_rgb(c) for path in found if path.startswith(E.GT_TRAJECTORY + "/")
          for c in _values(found[path], "LineStrips3D:colors")}
    assert gt == {GT_COLOR} and GT_COLOR not in TRACKER_COLORS.values() and TASK_COLOR not in TRACKER_COLORS.values()


def test_errors_are_cm_and_degrees_over_the_task_window(played):
    result, _, found = played
    gt = dict(zip(result.gt_stamps_ns.tolist(), result.gt.translation, strict=True))
    for name in TRACKERS:
        traj = result.trajectories[name]
        est = dict(zip(traj.stamps_ns.tolist(), traj.poses.translation, strict=True))
        rows = [(t, v) for chunk, batch in found[E.position_error(name)] if "Scalars:scalars" in batch.schema.names
                for t, v in zip(batch.column("time").cast("int64").to_pylist(), batch.column("Scalars:scalars").to_pylist(),
                                strict=True)
                if v is not None]
        assert rows and all(t in gt and t in est for t, _ in rows)   # task-window ticks with GT only
        for t, v in rows:
            assert v[0] == pytest.approx(100.0 * np.linalg.norm(gt[t] - est[t]), abs=1e-6)
        p_ate_cm = 100.0 * result.metrics["trackers"][name]["total"]["p_ate_m"]
        assert np.sqrt(np.mean([v[0] ** 2 for _, v in rows])) == pytest.approx(p_ate_cm, rel=1e-6)


def test_detection_diagnostics_are_data_on_the_detection(played):
    result, _, found = played
    marker = found[E.MARKER]
    errors = _values(marker, "reprojection_error_px")
    ratios = _values(marker, "ambiguity_ratio")
    with SessionReader(result.out_dir / "trackers.mcap") as r:
        dets = [m.msg.detections[0] for m in r.messages([Topic.PIPELINE_MARKERS]) if m.msg.detections]
    assert len(errors) == len(dets) > 0
    assert errors == pytest.approx([d.reprojection_error_px for d in dets])
    assert ratios == pytest.approx([d.ambiguity_ratio for d in dets])


def test_status_lanes_mark_the_task_window_and_the_marker_in_view(played):
    _, _, found = played
    assert _values(found[E.STATUS_TASK], "StateChange:state") == ["calibration", "task", "after"]
    states = _values(found[E.STATUS_MARKER], "StateChange:state")
    assert {"in_view", "out_of_view"} <= set(states)
    assert all(a != b for a, b in zip(states, states[1:], strict=False))     # logged on change only


def _blueprint_rows(rrd) -> dict[str, list]:
    reader = rc.RrdReader(str(rrd))
    (store,) = reader.blueprints()
    rows: dict[str, list] = {}
    for chunk in reader.stream(store=store).to_chunks():
        batch = chunk.to_record_batch()
        for n in batch.schema.names:
            if ":" in n:
                for v in batch.column(n).to_pylist():
                    if v is not None:
                        rows.setdefault(n, []).extend(v if isinstance(v, list) else [v])
    return rows


def test_the_3d_view_draws_the_frustum_at_the_working_depth_and_the_image_only_in_2d(played, tmp_path):
    _, rrd, found = played
    assert _values(found[E.IMAGE], "Pinhole:image_plane_distance") == [pytest.approx(WORKING_DEPTH_M)]
    assert _values(found[E.IMAGE], "EncodedImage:blob")                   # the images are there, for the 2D view
    reader = rc.RrdReader(str(rrd))
    (store,) = reader.blueprints()
    overrides: dict[str, list] = {}
    for chunk in reader.stream(store=store).to_chunks():
        batch = chunk.to_record_batch()
        if "/ViewContents/overrides/" in chunk.entity_path and "VisualizerInstruction:visualizer_type" in batch.schema.names:
            entity = "/" + chunk.entity_path.split("/ViewContents/overrides/", 1)[1].rsplit("/visualizers", 1)[0]
            overrides.setdefault(entity, []).extend(_values([(chunk, batch)], "VisualizerInstruction:visualizer_type"))
    # in the 3D view the camera entity has its Pinhole's visualizer only: no image plane over the scene
    assert overrides == {E.IMAGE: ["Cameras"]}


def test_session_time_counts_from_the_sessions_first_message(played, session):
    result, rrd, found = played
    with SessionReader(session) as r:
        first = min(m.log_time_ns for m in r.messages())
    for path in (E.tracker_pose("T8"), E.position_error("T8"), E.DISPLAY):
        for _, batch in found[path]:
            if "session_time" in batch.schema.names:
                since = batch.column("session_time").cast("int64").to_numpy()
                t = batch.column("time").cast("int64").to_numpy()
                assert np.array_equal(since, t - first), path
    rows = _blueprint_rows(rrd)
    assert [str(v) for v in rows["TimePanelBlueprint:timeline"]] == ["session_time"]
    (selection,) = rows["TimePanelBlueprint:time_selection"]
    info = result.metrics   # the task window, in seconds since the first message
    assert info is not None
    gt = result.gt_stamps_ns
    assert selection["min"] <= gt[0] - first and gt[-1] - first <= selection["max"]


def _table(markdown: str) -> dict[str, list[str]]:
    """tracker -> its cells after the colour, from the metrics panel's markdown table."""
    rows = [line.strip("|").split("|") for line in markdown.splitlines() if line.startswith("| T")]
    return {cells[0].strip(): [c.strip() for c in cells[1:]] for cells in rows}


def test_the_metrics_panel_holds_the_metrics_and_the_colour_legend(played):
    result, _, found = played
    (chunk, batch), *_ = found[E.METRICS]
    assert chunk.is_static
    (text,) = _values(found[E.METRICS], "TextDocument:text")
    assert _values(found[E.METRICS], "TextDocument:media_type") == ["text/markdown"]
    assert text == metrics_markdown(result.metrics)
    table = _table(text)
    assert list(table) == TRACKERS
    for name in TRACKERS:
        assert table[name][0] == color_name(name)
        for (_, key, scope, factor), cell in zip(METRIC_COLUMNS, table[name][1:], strict=True):
            v = result.metrics["trackers"][name][scope][key]
            assert cell.strip("*") == ("–" if v is None else f"{v * factor:.2f}")


@settings(max_examples=40, deadline=None)
@given(st.lists(st.lists(st.one_of(st.none(), st.floats(0, 10, allow_nan=False)), min_size=9, max_size=9),
                min_size=1, max_size=9))
def test_the_best_of_each_metrics_column_is_bold(values):
    names = [f"T{i + 1}" for i in range(len(values))]
    doc = {"session": "s.mcap", "rate_hz": 20, "trackers": {
        n: {scope: {key: None for _, key, *_ in METRIC_COLUMNS} for scope in ("inside", "outside", "total")}
        for n in names}}
    for n, row in zip(names, values, strict=True):
        for (_, key, scope, _f), v in zip(METRIC_COLUMNS, row, strict=True):
            doc["trackers"][n][scope][key] = v
    table = _table(metrics_markdown(doc))
    for j in range(len(METRIC_COLUMNS)):
        column = [row[j] for row in values]
        best = min((v for v in column if v is not None), default=None)
        for n, v in zip(names, column, strict=True):
            cell = table[n][1 + j]
            assert cell.startswith("**") == (v is not None and v == best)
            assert (cell == "–") == (v is None)


def test_trackers_mcap_has_every_estimate_as_a_frame_transform(played):
    result, _, _ = played
    from phonepose.topics import tracker_frame, tracker_pose_topic

    with SessionReader(result.out_dir / "trackers.mcap") as r:
        tf = [(m.log_time_ns, m.msg) for m in r.messages([Topic.TF_TRACKERS])]
        poses = {name: [(m.log_time_ns, m.msg) for m in r.messages([tracker_pose_topic(name)])] for name in TRACKERS}
    assert {m.parent_frame_id for _, m in tf} == {Frame.DISPLAY_VIO}
    assert {m.child_frame_id for _, m in tf} == {tracker_frame(n) for n in TRACKERS}
    for name in TRACKERS:
        mine = [(t, m) for t, m in tf if m.child_frame_id == tracker_frame(name)]
        assert len(mine) == len(poses[name]) > 0
        for (t, m), (tp, p) in zip(mine, poses[name], strict=True):
            assert t == tp
            assert [m.translation.x, m.translation.y, m.translation.z] == [p.pose.position.x, p.pose.position.y,
                                                                            p.pose.position.z]
            assert [m.rotation.x, m.rotation.y, m.rotation.z, m.rotation.w] == [
                p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z, p.pose.orientation.w]


def test_errors_csv_holds_the_errors_the_metrics_are_the_rms_of(played):
    import csv

    from phonepose.evaluation.stats import rmse

    result, _, _ = played
    with open(result.out_dir / "errors.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["timestamp", "tracker", "position_error_m", "rotation_error_deg", "in_view"]
    assert [r["tracker"] for r in rows] == sorted((r["tracker"] for r in rows), key=TRACKERS.index)
    gt_t = set(result.gt_stamps_ns.tolist())
    for name in TRACKERS:
        mine = [r for r in rows if r["tracker"] == name]
        stamps = [int(r["timestamp"].replace(".", "")) for r in mine]
        assert stamps == sorted(set(stamps) & gt_t & set(result.trajectories[name].stamps_ns.tolist()))
        p = np.array([float(r["position_error_m"]) for r in mine])
        rot = np.array([float(r["rotation_error_deg"]) for r in mine])
        inside = np.array([r["in_view"] == "1" for r in mine])
        for scope, mask in (("inside", inside), ("outside", ~inside), ("total", np.ones(len(mine), bool))):
            m = result.metrics["trackers"][name][scope]
            assert m["frames"] == (int(mask.sum()) or None) or (m["frames"] in (0, None) and not mask.any())
            if mask.any():
                # the metrics' own RMS of the column gives the metric exactly; numpy's mean to a few ulps
                assert (rmse(p[mask]), rmse(rot[mask])) == (m["p_ate_m"], m["r_ate_deg"])
                assert np.sqrt(np.mean(p[mask] ** 2)) == pytest.approx(m["p_ate_m"], rel=8 * np.finfo(float).eps, abs=0)
                assert np.sqrt(np.mean(rot[mask] ** 2)) == pytest.approx(m["r_ate_deg"], rel=8 * np.finfo(float).eps,
                                                                         abs=0)


def test_blueprint_holds_the_documented_views_and_an_eye_on_the_task(played):
    _, rrd, found = played
    rows = _blueprint_rows(rrd)
    views = dict(zip([str(v) for v in rows["ViewBlueprint:space_origin"]], rows["ViewBlueprint:class_identifier"],
                     strict=True))
    expected = {E.WORLD: "3D", E.IMAGE: "2D", E.STATUS: "StateTimeline", E.POSITION_ERRORS: "TimeSeries",
                E.ROTATION_ERRORS: "TimeSeries", E.METRICS: "TextDocument"}
    assert {o: str(views.get(o, "")) for o in expected} == expected
    doc = (DOCS / "playback.md").read_text()
    for origin in expected:
        assert f"`{origin}`" in doc, origin
    # every entity the documented tree names for playback exists in the recording
    for path in (E.DISPLAY, E.CAMERA, E.IMAGE, E.MARKER, E.GT_CONTROLLER, E.tracker_pose("T8"), E.TASK_PATH,
                 E.position_error("T8"), E.rotation_error("T8"), E.STATUS_TASK, E.STATUS_MARKER):
        assert f"`{path.replace('T8', '<name>')}" in doc, path
    present = set(found)
    for path in (E.DISPLAY, E.CAMERA, E.IMAGE, E.MARKER, E.GT_CONTROLLER, E.tracker_pose("T8"),
                 E.position_error("T8"), E.rotation_error("T8"), E.STATUS_TASK, E.STATUS_MARKER):
        assert path in present, path


def test_the_eye_looks_between_the_camera_and_the_task_from_behind_the_camera():
    from types import SimpleNamespace

    from phonepose.pipeline.types import TaskPath
    from phonepose.playback.rerun_log import _eye

    path = TaskPath(frame_id="display_vio", name="TRI1", trial=1, waypoints=((-0.1, 1.0, 0.0), (0.1, 1.2, 0.2)),
                    closed=True)
    task_center, camera = np.array([0.0, 1.1, 0.1]), np.array([0.0, 0.0, 0.1])
    eye = _eye(SimpleNamespace(path=path, targets=None), camera)
    target = np.array(eye.look_target.as_arrow_array().to_pylist()[0])
    position = np.array(eye.position.as_arrow_array().to_pylist()[0])
    # the target lies on the segment task centre -> camera; the eye is behind the camera, above it
    along = np.dot(target - task_center, camera - task_center) / np.dot(camera - task_center, camera - task_center)
    assert 0 < along < 1 and np.allclose(np.cross(target - task_center, camera - task_center), 0, atol=1e-6)
    assert position[1] < camera[1] and position[2] > camera[2]
    assert _eye(SimpleNamespace(path=None, targets=None), camera) is None    # no task: the viewer's own framing


# ------------------------------------------------------------------ the raw session in Rerun
def _rerun_cli() -> str:
    exe = Path(sys.executable).parent / "rerun"
    return str(exe) if exe.exists() else shutil.which("rerun")


def _recorded_session(tmp_path) -> Path:
    from phonepose.record.sim import default_config, record_sim

    out = tmp_path / "raw.mcap"
    record_sim(out, scenario="exp2", path="TRI1", seed=0, config=default_config().replace(camera=dict(rate_hz=2.0)))
    return out


@pytest.mark.slow
def test_rerun_mcap_convert_connects_camera_controller_and_marker_to_the_root(tmp_path):
    session = _recorded_session(tmp_path)
    rrd = tmp_path / "raw.rrd"
    r = subprocess.run([_rerun_cli(), "mcap", "convert", str(session), "-o", str(rrd), "--application-id", "phonepose"],
                       capture_output=True, text=True, env=dict(os.environ, RERUN_ANALYTICS="0"))
    assert r.returncode == 0, r.stderr
    parent: dict[str, str] = {}
    for chunk in rc.RrdReader(str(rrd)).stream().to_chunks():
        batch = chunk.to_record_batch()
        for kind in ("Transform3D", "Pinhole"):
            if f"{kind}:child_frame" in batch.schema.names:
                for p, c in zip(batch.column(f"{kind}:parent_frame").to_pylist(),
                                batch.column(f"{kind}:child_frame").to_pylist(), strict=True):
                    p, c = (p[0] if isinstance(p, list) else p), (c[0] if isinstance(c, list) else c)
                    assert parent.setdefault(c, p) == p, f"{c} has two parents"

    def root(frame: str) -> list[str]:
        chain = [frame]
        while chain[-1] in parent:
            chain.append(parent[chain[-1]])
            assert len(chain) < 10
        return chain

    image_plane = f"{Frame.DISPLAY_CAMERA}_image_plane"   # the importer's frame of the camera image
    assert root(image_plane) == [image_plane, Frame.DISPLAY_CAMERA, Frame.DISPLAY, Frame.DISPLAY_VIO, Frame.WORLD]
    assert root(Frame.MARKER) == [Frame.MARKER, Frame.CONTROLLER, Frame.CONTROLLER_VIO, Frame.DISPLAY_VIO, Frame.WORLD]
    drawn = {chunk.entity_path for chunk in rc.RrdReader(str(rrd)).stream().to_chunks()
             if "Points3D:positions" in chunk.to_record_batch().schema.names}
    assert {Topic.CONTROLLER_MARKER_OUTLINE, Topic.CAMERA_FRUSTUM} <= drawn   # something drawn in each body's frame


@pytest.mark.slow
def test_the_recorders_rerun_output_uses_the_playback_tree(tmp_path):
    from phonepose.record.sim import default_config, record_sim

    rrd = tmp_path / "rec.rrd"
    record_sim(tmp_path / "s.mcap", scenario="exp2", path="TRI1", seed=0,
               config=default_config().replace(camera=dict(rate_hz=2.0)), rerun_path=rrd)
    found = _entities(rrd)
    for path in (E.WORLD, E.DISPLAY, E.CAMERA, E.IMAGE, E.CONTROLLER_VIO, E.GT_CONTROLLER, E.GT_DISPLAY, E.TASK_PATH,
                 E.IMU_GYRO, E.IMU_ACCEL):
        assert path in found, path
    assert not any(p.startswith("/world/display_vio") or p.startswith("/controller_vio") for p in found)
    (rec,) = rc.RrdReader(str(rrd)).recordings()
    assert rec.recording_id.startswith("record-s-") and rec.application_id == "phonepose_record"


def test_a_rrd_that_cannot_be_written_whole_is_one_line_and_never_put_in_place(tmp_path, cli, monkeypatch):
    """rerun's file writer stops on a write error (a full disk, `ulimit -f`), logs it (in colour, naming the
    temporary) and the process goes on: `record sim --rerun` exited 0 with a cut .rrd in place; playback said
    "unexpected RuntimeError: File-writer thread shut down prematurely (a bug in phonepose ...)"."""
    import resource

    from phonepose.files import TMP_SUFFIX
    from phonepose.testing.playback_session import write_test_session

    write_test_session(tmp_path / "s.mcap", duration_s=2.0)     # its .rrd: ~185 kB, its other outputs < 40 kB
    limit = 150_000
    r = subprocess.run([sys.executable, "-m", "phonepose", "playback", "s.mcap", "-q", "-t", "t1", "-o", "pb",
                        "--rerun", "p.rrd"], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                       preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit)))
    assert (r.returncode, r.stderr) == (6, f"phonepose: error: cannot write p.rrd: File too large (the limit of "
                                           f"`ulimit -f`, {limit} bytes)\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.mcap"]

    def writer_stopped(self, *args, **kwargs):
        raise RuntimeError("File-writer thread shut down prematurely")
    monkeypatch.setattr(rr.RecordingStream, "flush", writer_stopped)
    monkeypatch.chdir(tmp_path)
    r = cli("record", "sim", "-q", "--scenario", "exp2", "--path", "tri2", "--seed", "0", "-o", "r.mcap",
            "--rerun", "r.rrd")
    assert (r.returncode, r.stderr) == (6, "phonepose: error: cannot write r.rrd: File-writer thread shut down "
                                           "prematurely\n")
    assert not (tmp_path / "r.rrd").exists() and not list(tmp_path.glob(f".*{TMP_SUFFIX}"))


def test_closing_waits_for_the_sink_a_bounded_time(tmp_path):
    """rerun's flush waits forever by default; once, its file writer had stopped and a command hung there. The
    close asks for FLUSH_TIMEOUT_S, and rerun's error when it passes is one line naming the .rrd."""
    from phonepose.errors import OutputError
    from phonepose.viewer.sink import FLUSH_TIMEOUT_S, close_recording

    asked = []

    class StuckSink:
        def flush(self, *, timeout_sec=1e38):
            asked.append(timeout_sec)
            raise RuntimeError("Flush timed out")

        def disconnect(self):
            raise AssertionError("not reached")

    with pytest.raises(OutputError) as err:
        close_recording(StuckSink(), tmp_path / "p.rrd")
    assert asked == [FLUSH_TIMEOUT_S] and 10 <= FLUSH_TIMEOUT_S <= 600
    assert str(err.value) == f"cannot write {tmp_path / 'p.rrd'}: Flush timed out"


def test_a_rrd_removed_while_it_is_written_is_one_line(tmp_path):
    """Its folder removed under a playback (`rm -rf` of the output's parent): "it ends without its footer" was
    the line; what happened is that the file is gone."""
    from phonepose.errors import OutputError
    from phonepose.viewer.sink import close_recording, open_recording

    path = tmp_path / "p.rrd"
    rec = open_recording("phonepose-test", "removed", name="removed", rrd_path=path)
    rec.log("x", rr.Points3D([[0.0, 0.0, 0.0]]))
    path.unlink()
    with pytest.raises(OutputError) as e:
        close_recording(rec, path)
    assert str(e.value) == f"cannot write {path}: No such file or directory (removed while it was written)"


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("asked, listens", [(None, "127.0.0.1"), ("127.0.0.1", "127.0.0.1"), ("0.0.0.0", "0.0.0.0")])
def test_a_spawned_viewer_listens_on_localhost_unless_asked_otherwise(monkeypatch, capfd, asked, listens):
    """``--spawn``'s viewer (a real one, headless) listens on loopback only; $PHONEPOSE_VIEWER_BIND opens it to
    other interfaces (rr.spawn's viewer listens on 0.0.0.0). Where it listens is the viewer's own log line: a
    headless viewer without a GPU render context exits right after binding, before it could be asked."""
    import psutil
    from conftest import wait_until

    from phonepose.viewer import sink

    port = _free_port()
    pids: list[int] = []
    real_spawn = sink.spawn_viewer

    def headless_spawn(*, port: int, bind: str, headless: bool = False):
        pid = real_spawn(port=port, bind=bind, headless=True)
        assert pid is not None      # a new viewer, not one already on the port
        pids.append(pid)
        return pid

    monkeypatch.setenv("PATH", os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", ""))
    monkeypatch.delenv("_RERUN_TEST_FORCE_SAVE", raising=False)
    monkeypatch.setenv("RUST_LOG", "info")   # the line read below; a command run in this process set it off
    if asked is None:
        monkeypatch.delenv(sink.VIEWER_BIND_ENV, raising=False)
    else:
        monkeypatch.setenv(sink.VIEWER_BIND_ENV, asked)
    monkeypatch.setattr(sink, "VIEWER_PORT", port)
    monkeypatch.setattr(sink, "spawn_viewer", headless_spawn)
    err: list[str] = []
    rec = sink.open_recording("phonepose-test", f"bind-{listens}", name="bind", spawn=True)
    try:
        line = wait_until(lambda: err.append(capfd.readouterr().err) or re.search(
            r"Listening for gRPC connections on (\S+):(\d+)\.", "".join(err)), what="the viewer's listening line")
        assert (line.group(1), int(line.group(2))) == (listens, port)
    finally:
        rec.disconnect()
        for pid in pids:
            viewer = psutil.Process(pid)
            viewer.kill()
            viewer.wait(timeout=60)    # our child: reaped, not left a zombie


@pytest.mark.parametrize("asked", ["everywhere", "localhost", "300.1.1.1", "0.0.0.0:80"])
def test_a_viewer_bind_that_is_not_an_ip_address_is_one_line_before_spawning(monkeypatch, asked):
    from phonepose.errors import ConfigError
    from phonepose.viewer import sink

    monkeypatch.setenv(sink.VIEWER_BIND_ENV, asked)
    monkeypatch.setattr(sink, "spawn_viewer", lambda **kw: pytest.fail("spawned"))
    with pytest.raises(ConfigError, match=rf"^PHONEPOSE_VIEWER_BIND='{re.escape(asked)}': expected an IP address"):
        sink.open_recording("phonepose-test", "bad-bind", name="bad", spawn=True)
