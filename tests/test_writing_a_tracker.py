"""The example tracker of docs/writing-a-tracker.md, taken from the page itself, run beside T1-T8:
loaded by ``module:Class`` in playback and in a batch, and found as an installed package's entry point."""

from __future__ import annotations

import importlib
import math
import re
import sys
from pathlib import Path

import pytest

from phonepose.batch.driver import run_batch
from phonepose.batch.table import read_rows
from phonepose.errors import ConfigError
from phonepose.pipeline.trackers import make_tracker
from phonepose.playback.engine import run_playback
from phonepose.testing.playback_session import write_test_session

DOC = Path(__file__).resolve().parents[1] / "docs" / "writing-a-tracker.md"
REF = "my_tracker:LastSightingTracker"


def example_source() -> str:
    text = DOC.read_text()
    block = re.search(r"<!-- example-tracker[^>]*-->\n```python\n(.*?)```", text, re.S)
    assert block is not None, "docs/writing-a-tracker.md lost its example block"
    return block.group(1)


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """A folder with the example module and an installed distribution's metadata declaring its entry point
    (what `pip install` of the page's pyproject.toml leaves in site-packages)."""
    d = tmp_path_factory.mktemp("site")
    (d / "my_tracker.py").write_text(example_source())
    info = d / "my_tracker-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: my-tracker\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[phonepose.trackers]\nlast-sighting = {REF}\n")
    return d


@pytest.fixture
def on_path(site, monkeypatch) -> Path:
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setenv("PYTHONPATH", str(site))   # batch workers are separate processes
    importlib.invalidate_caches()
    yield site
    sys.modules.pop("my_tracker", None)


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("session") / "s.mcap"
    write_test_session(p, duration_s=3.0)
    return p


def test_the_example_is_about_40_lines():
    code = [line for line in example_source().splitlines() if line.strip()]
    assert 25 <= len(code) <= 45


def test_example_in_playback_beside_t1_t8_is_scored(session, on_path, tmp_path):
    out = tmp_path / "o"
    r = run_playback(session, trackers=["all", REF], out_dir=out)
    assert list(r.trajectories) == ["T1", "T2", "T3", "T4", "T5", "T6", "T7", "T7L", "T8", "LastSighting"]
    m = r.metrics["trackers"]
    # inside the view it reports the marker, exactly as T4-T7 do (p_RE spans the view's edges: not compared)
    for key in ("frames", "p_ate_m", "r_ate_deg"):
        assert m["LastSighting"]["inside"][key] == m["T4"]["inside"][key]
    assert m["LastSighting"]["inside"]["frames"] > 0
    outside = m["LastSighting"]["outside"]
    assert outside["frames"] == m["T7"]["outside"]["frames"] > 0
    assert math.isfinite(outside["p_ate_m"]) and outside["p_ate_m"] < 0.05   # the test session's VIO: cm-level
    lines = (out / "trajectories" / "LastSighting.tum").read_text().count("\n")
    assert lines == len(r.trajectories["LastSighting"].stamps_ns) + 2      # the header and the session tag


def test_example_in_a_batch_beside_the_paper_trackers(session, on_path, tmp_path):
    direct = run_playback(session, trackers=["T1", REF], write_outputs=False)
    out = tmp_path / "runs.parquet"
    run_batch([session], out, trackers=["paper", REF], workers=1)
    rows = {k[2]: row for k, row in read_rows(out).items()}
    assert set(rows) == {"T1", "T2", "T3", "T4", "T5", "T6", "T7", "LastSighting"}
    assert all(row["status"] == "ok" for row in rows.values())
    want = direct.metrics["trackers"]["LastSighting"]["total"]["p_ate_m"]
    assert rows["LastSighting"]["p_ate_m_total"] == pytest.approx(want, rel=0, abs=0)


def test_example_as_an_installed_entry_point(session, on_path, tmp_path, cli):
    out = tmp_path / "o"
    assert cli("playback", session, "-q", "-t", "T4", "-t", "last-sighting", "--out", out).returncode == 0
    assert sorted(p.name for p in (out / "trajectories").iterdir()) == ["LastSighting.tum", "T4.tum"]
    with pytest.raises(ConfigError, match=r"unknown tracker 'nope'; valid: .*, last-sighting, all, paper"):
        make_tracker("nope")


def test_a_wrong_reference_is_one_line_before_any_work(on_path):
    with pytest.raises(ConfigError, match=r"cannot import no_such_module"):
        make_tracker("no_such_module:X")
    with pytest.raises(ConfigError, match=r"my_tracker has no Nope"):
        make_tracker("my_tracker:Nope")
    with pytest.raises(ConfigError, match=r"could not be created: TypeError: "):
        make_tracker("my_tracker:Observation")
    with pytest.raises(ConfigError, match=r"'collections:OrderedDict' is not a phonepose tracker: it has no name, "
                                          r"needs_camera, uses_vio_samples, reset, step \(docs/writing-a-tracker.md\)$"):
        make_tracker("collections:OrderedDict")


def test_experiments_refuse_a_builtin_as_an_extra_tracker_before_any_work(tmp_path):
    from phonepose.cli import flags
    from phonepose.experiments.exp1 import run_exp1

    with pytest.raises(ConfigError, match=r"^trackers T4: the experiments always run T1-T8; trackers adds your own") as e:
        run_exp1(tmp_path / "e1", trackers=["T4"])
    assert not (tmp_path / "e1").exists()
    flags.set_command(["experiment", "exp1"])
    try:                          # the command line's line names its option
        assert flags.message(e.value).startswith("--add-tracker T4: the experiments always run T1-T8; --add-tracker ")
    finally:
        flags.set_command([])


@pytest.mark.slow
def test_example_in_experiment_1_beside_t1_t8(on_path, tmp_path, short_exp1):
    """`experiment exp1 --add-tracker my_tracker:LastSightingTracker`: its rows join Tables 2 and 3 (no paper values); on
    4 of exp1's targets, inside and outside the view."""
    from phonepose.experiments.exp1 import run_exp1

    result = run_exp1(tmp_path / "e1", trackers=[REF])
    s = result.summary
    assert list(s)[-3:] == ["T7L", "T8", "LastSighting"]
    assert s["LastSighting"]["inside"] == s["T4"]["inside"]          # the marker inside the view, as T4
    assert s["LastSighting"]["outside"]["targets"] == s["T7"]["outside"]["targets"] > 0
    tables = (tmp_path / "e1" / "exp1_tables.md").read_text()
    assert re.search(r"^\| LastSighting \| outside \| [0-9.]+ \| — \| [0-9.]+ \| — \| \d+/\d+ \|$", tables, re.M)
    assert (tmp_path / "e1" / "playback" / "exp1" / "trajectories" / "LastSighting.tum").is_file()
