"""The Python API (phonepose.api, docs/python-api.md): its names, its typed results against the CLI's
documents, its checks, and the documentation page run end to end."""

from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import phonepose
from phonepose.api import results
from phonepose.evaluation.metrics import METRICS, SCOPES, keys
from phonepose.testing.playback_session import write_test_session

DOC = Path(__file__).resolve().parents[1] / "docs" / "python-api.md"


def _dump(doc: dict) -> str:
    """metrics.json's text for a document, as phonepose.playback.outputs.write_metrics writes it."""
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    """A 3 s hand-made session: marker in view for the first half, GT, IMU."""
    path = tmp_path_factory.mktemp("api") / "s.mcap"
    write_test_session(path, duration_s=3.0)
    return path


# ----------------------------------------------------------------------------- the names
def test_every_public_name_resolves_and_is_listed():
    import phonepose.api
    import phonepose.errors

    assert set(phonepose.__all__) == set(phonepose.api.__all__) | {
        n for n in dir(phonepose.errors) if isinstance(getattr(phonepose.errors, n), type)
        and issubclass(getattr(phonepose.errors, n), phonepose.errors.PhoneposeError)}
    assert len(phonepose.__all__) == len(set(phonepose.__all__))
    for name in phonepose.__all__:
        value = getattr(phonepose, name)
        assert value is getattr(phonepose.api if name in phonepose.api.__all__ else phonepose.errors, name)
        assert name in dir(phonepose)
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        phonepose.nope  # noqa: B018


def test_import_phonepose_loads_no_submodule():
    code = ("import sys, phonepose; before = {m for m in sys.modules if m.startswith('phonepose.')}; "
            "phonepose.ConfigError; errors = {m for m in sys.modules if m.startswith('phonepose.')}; "
            "print(sorted(before), sorted(errors), 'numpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")[0]
    assert out == "[] ['phonepose.errors'] False"


@pytest.mark.parametrize("scope", SCOPES)
def test_the_metric_types_have_the_metrics_json_keys(scope):
    cls = results.TotalMetrics if scope == "total" else results.ScopeMetrics
    assert [f.name for f in dataclasses.fields(cls)] == keys(scope)


# ----------------------------------------------------------------------------- playback against the CLI
OPTIONS = [
    ([], {}),
    (["-t", "T1,T4", "--rate", "10"], {"trackers": "T1,T4", "rate": 10.0}),
    (["-t", "T7", "-t", "T8", "--rate", "33.5", "--start", "0.4"], {"trackers": ["T7", "T8"], "rate": 33.5,
                                                                    "start": 0.4}),
    (["-t", "paper", "--correction-math", "se3", "--end", "2.5"], {"trackers": "paper", "correction_math": "se3",
                                                                   "end": 2.5}),
]


@pytest.mark.parametrize(("args", "kwargs"), OPTIONS)
def test_to_json_is_the_cli_metrics_json_byte_for_byte(session, tmp_path, cli, args, kwargs):
    code, _out, err = cli("playback", session, "-q", "--out", tmp_path / "cli", *args)
    assert code == 0, err
    cli_text = (tmp_path / "cli" / "metrics.json").read_text()
    in_memory = phonepose.play(session, **kwargs)
    written = phonepose.play(session, out=tmp_path / "api", **kwargs)
    assert _dump(in_memory.to_json()) == cli_text == _dump(written.to_json())
    assert (tmp_path / "api" / "metrics.json").read_text() == cli_text
    assert sorted(p.name for p in (tmp_path / "api").iterdir()) == sorted(p.name for p in (tmp_path / "cli").iterdir())
    # the typed fields are the document's values
    doc = json.loads(cli_text)
    assert list(in_memory.trackers) == list(doc["trackers"])
    for name, run in in_memory.trackers.items():
        for scope in SCOPES:
            assert dataclasses.asdict(run.scope(scope)) == doc["trackers"][name][scope]


def test_the_table_has_a_row_per_tracker_and_scope(session):
    import pyarrow as pa

    run = phonepose.play(session, "T1,T4,T8")
    table = run.to_table()
    assert table.num_rows == 9
    assert table.column_names == ["session", "tracker", "scope"] + [m.key for m in METRICS]
    for m in METRICS:
        assert table.schema.field(m.key).type == (pa.int64() if m.kind is int else pa.float64())
    rows = table.to_pylist()
    for i, (name, scope) in enumerate((n, s) for n in ("T1", "T4", "T8") for s in SCOPES):
        row = rows[i]
        assert (row["session"], row["tracker"], row["scope"]) == ("s.mcap", name, scope)
        want = run.to_json()["trackers"][name][scope]
        assert {k: row[k] for k in want} == want
        assert all(row[k] is None for k in row if k not in want and k not in ("session", "tracker", "scope"))


def test_trajectories_are_the_written_tum_files(session, tmp_path):
    from phonepose.evaluation.trajectory import load_tum

    run = phonepose.play(session, "T4,T8", out=tmp_path / "out")
    for tracker in run:
        tum = load_tum(tmp_path / "out" / "trajectories" / f"{tracker.name}.tum")
        assert np.allclose(tum.stamps, tracker.trajectory.stamps, rtol=0, atol=1e-6)   # a float64's ulp at 1.7e9 s
        assert np.allclose(tum.poses.translation, tracker.trajectory.poses.translation, rtol=0, atol=1e-9)
        assert int(tracker.in_view.sum()) == tracker.inside.frames
    gt = load_tum(tmp_path / "out" / "groundtruth.tum")
    assert np.allclose(gt.stamps, run.ground_truth.stamps, rtol=0, atol=1e-6)
    assert run.out == tmp_path / "out" and Path(run.files["metrics.json"]).is_file()


class _Marker:
    name = "MarkerOnly"
    needs_camera = True
    uses_vio_samples = False

    def reset(self) -> None:
        pass

    def step(self, obs):
        return obs.marker.T_dvio_controller if obs.marker is not None else None


def test_a_tracker_object_scores_like_a_built_in(session):
    """The marker alone is T4 inside the view: the same poses there (p_RE differs: its pairs span the scopes);
    a class works as well as an object."""
    for given_ in (_Marker(), _Marker):
        run = phonepose.play(session, ["T4", given_])
        assert list(run.trackers) == ["T4", "MarkerOnly"]
        mine, t4 = run["MarkerOnly"].inside, run["T4"].inside
        assert (mine.frames, mine.p_ate_m, mine.r_ate_deg) == (t4.frames, t4.p_ate_m, t4.r_ate_deg)
        assert run["MarkerOnly"].outside.frames == 0 < run["T4"].outside.frames


class _Broken(_Marker):
    name = "Broken"

    def step(self, obs):
        raise ValueError("boom")


class _Nameless:
    needs_camera = True
    uses_vio_samples = False


@pytest.mark.parametrize(("trackers", "error", "message"), [
    ([_Broken()], phonepose.TrackerError, r"\(Broken\) failed in step\(\): ValueError: boom"),
    ([_Nameless()], phonepose.ConfigError, "is not a phonepose tracker: it has no name, reset, step"),
    ([_Marker(), _Marker()], phonepose.ConfigError, "tracker given twice"),
    (["T4", "t4"], phonepose.ConfigError, "trackers T4 and t4 are named 'T4'"),
    ("T99", phonepose.ConfigError, "unknown tracker 'T99'"),
])
def test_bad_trackers_raise_the_cli_errors(session, tmp_path, trackers, error, message):
    with pytest.raises(error, match=message):
        phonepose.play(session, trackers, out=tmp_path / "out")
    assert not (tmp_path / "out").exists()


@settings(max_examples=25, deadline=None)
@given(option=st.sampled_from(["rate", "start", "end"]),
       value=st.one_of(st.just(float("nan")), st.just(float("inf")), st.floats(max_value=-1e-9),
                       st.floats(min_value=1e7, allow_infinity=False)))
def test_a_bad_number_is_a_config_error_naming_it(session, option, value):
    with pytest.raises(phonepose.ConfigError, match=rf"^{option} "):
        phonepose.play(session, "T1", **{option: value})


def test_a_missing_session_is_an_input_file_error(tmp_path):
    with pytest.raises(phonepose.InputFileError, match="no such file"):
        phonepose.play(tmp_path / "missing.mcap")
    with pytest.raises(phonepose.InputFileError, match="no such file"):
        phonepose.open_session(tmp_path / "missing.mcap")


# ----------------------------------------------------------------------------- session
def test_open_session_reads_what_the_reader_reads(session):
    from phonepose.schemas.topics import Topic
    from phonepose.session import SessionReader

    with SessionReader(session) as reader:
        summary = reader.summary()
        gt = [(m.log_time_ns, m.msg.pose.position.x) for m in reader.messages([Topic.GT_CONTROLLER_POSE])]
        n_imu = sum(1 for _ in reader.messages([Topic.CONTROLLER_IMU]))
    with phonepose.open_session(session) as s:
        assert s.span == (summary.start_ns, summary.end_ns)
        assert s.topics == sorted({c.topic for c in summary.channels if c.count})
        series = s.poses(Topic.GT_CONTROLLER_POSE)
        assert series.t_ns.tolist() == [t for t, _ in gt]
        assert series.poses.translation[:, 0].tolist() == [x for _, x in gt]
        assert len(s.imu()) == n_imu
        assert s.camera.width == 320 and s.marker.id == 7
        assert s.log_times(Topic.GT_CONTROLLER_POSE).tolist() == [t for t, _ in gt]
        with pytest.raises(phonepose.ConfigError, match="not a pose topic"):
            s.poses(Topic.CONTROLLER_IMU)
        with pytest.raises(phonepose.SessionContentError, match="no /nope"):
            s.poses("/nope")


# ----------------------------------------------------------------------------- evaluation against the CLI
@pytest.mark.parametrize(("args", "kwargs"), [
    (["--metric", "rpg", "--lengths", "0.05,0.1"], {"metric": "rpg", "lengths": [0.05, 0.1]}),
    (["--metric", "ape", "--align", "se3"], {"metric": "ape", "align": "se3"}),
    (["--metric", "rpe", "--delta", "3", "--pose-relation", "angle"], {"metric": "rpe", "delta": 3.0,
                                                                        "pose_relation": "angle"}),
    (["--metric", "paper", "--in-view", "IN_VIEW"], {"metric": "paper", "in_view": "IN_VIEW"}),
])
def test_evaluate_is_the_cli_json(session, tmp_path, cli, args, kwargs):
    out = tmp_path / "out"
    phonepose.play(session, "T4", out=out)
    gt, est, in_view = out / "groundtruth.tum", out / "trajectories" / "T4.tum", out / "in_view.txt"
    args = [str(in_view) if a == "IN_VIEW" else a for a in args]
    kwargs = {k: in_view if v == "IN_VIEW" else v for k, v in kwargs.items()}
    code, text, err = cli("evaluate", "--gt", gt, "--est", est, "--json", *args)
    assert code == 0, err
    result = phonepose.evaluate(gt, est, **kwargs)
    assert json.dumps(result.to_json(), indent=2, allow_nan=False) + "\n" == text
    if isinstance(result, phonepose.Evaluation):
        stats = result.to_table().to_pylist()
        assert [r["error"] for r in stats] == list(result.stats)
        assert all(r["rmse"] == result[r["error"]].rmse for r in stats)
    else:
        assert result.name == "T4"


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"metric": "nope"}, "metric 'nope': expected one of rpg, ape, rpe, paper"),
    ({"align": "affine"}, "align 'affine': expected one of"),
    ({"lengths": [1.0, -2.0]}, "lengths -2"),
    ({"max_diff": 0.0}, "max_diff 0"),
    ({"align_frames": 0}, "align_frames 0"),
])
def test_evaluate_refuses_bad_options(session, tmp_path, kwargs, message):
    run = phonepose.play(session, "T4")
    with pytest.raises(phonepose.ConfigError, match=re.escape(message)):
        phonepose.evaluate(run.ground_truth, run["T4"].trajectory, **kwargs)


# ----------------------------------------------------------------------------- the page
def _python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, re.S | re.M)


@pytest.mark.long
def test_the_python_api_page_runs_end_to_end(monkeypatch, tmp_path):
    """docs/python-api.md's python blocks in order, in one namespace, as a notebook runs them."""
    import tempfile

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))   # the page's mkdtemp: inside tmp_path
    blocks = _python_blocks(DOC.read_text())
    assert len(blocks) >= 8
    namespace: dict = {"__name__": "__notebook__"}
    for i, block in enumerate(blocks):
        exec(compile(block, f"{DOC.name} block {i + 1}", "exec"), namespace)   # noqa: S102 - the page's own code
    assert namespace["text"] == (namespace["cli_out"] / "metrics.json").read_text()
