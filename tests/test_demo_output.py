"""What the demo shows a newcomer: the table's best values marked and explained, the figure's views, marks and legend."""

from __future__ import annotations

import io

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from phonepose.geometry import Pose

TRACKERS = ["T1", "T2", "T3", "T4", "T5", "T6", "T7", "T7L", "T8"]
# column header -> (metrics key of its first number, scale, digits, scopes, best): written out here, not imported
SPEC = {"p_ATE cm": ("p_ate_m", 100.0, 2, ("inside", "outside", "total"), min),
        "r_ATE deg": ("r_ate_deg", 1.0, 2, ("inside", "outside", "total"), min),
        "p_RE cm": ("p_re_m", 100.0, 2, ("inside", "outside", "total"), min),
        "jump max / RMS cm": ("boundary_jump_max_m", 100.0, 2, ("total",), min),
        "lag ms": ("lag_s", 1000.0, 0, ("total",), lambda vs: min(map(abs, vs))),
        "jitter mm / deg": ("jitter_m", 1000.0, 2, ("total",), min),
        "avail. %": ("availability", 100.0, 1, ("total",), max)}

# a few values per metric, so that ties (the same number printed for several trackers) are common
metric = st.one_of(st.none(), st.sampled_from([0.0012, 0.0087, 0.0087, 0.0154, 0.03]))
lag = st.sampled_from([-0.030, -0.015, 0.015, 0.105, 0.2])
avail = st.sampled_from([0.5, 0.98, 1.0])


@st.composite
def metrics_docs(draw):
    names = draw(st.lists(st.sampled_from(TRACKERS), min_size=1, max_size=9, unique=True))
    trackers = {}
    for name in names:
        scopes = {scope: {"frames": draw(st.integers(0, 200)), "p_ate_m": draw(metric), "r_ate_deg": draw(metric),
                          "p_re_m": draw(metric)} for scope in ("inside", "outside", "total")}
        jumps = draw(st.integers(0, 3))
        scopes["total"].update(boundary_jumps=jumps, boundary_jump_max_m=draw(metric) if jumps else None,
                               boundary_jump_rms_m=draw(metric) if jumps else None, lag_s=draw(lag),
                               jitter_m=draw(metric), jitter_deg=draw(metric), availability=draw(avail))
        trackers[name] = scopes
    return {"session": "s.mcap", "rate_hz": 20.0, "trackers": trackers}


def _printed(metrics: dict, **options) -> str:
    from rich.console import Console

    from phonepose.cli.output import print_table
    from phonepose.cli.playback import metrics_table

    out = io.StringIO()
    print_table(Console(file=out, width=1000, color_system=None), metrics_table(metrics, **options))
    return out.getvalue()


def _cells(text: str) -> dict[tuple[str, str], dict[str, str]]:
    """(tracker, scope) -> {header: cell} of a printed table."""
    lines = [line for line in text.splitlines() if line.startswith(("┃", "│"))]
    headers = [h.strip() for h in lines[0].strip("┃").split("┃")]
    rows, tracker = {}, ""
    for line in lines[1:]:
        cells = dict(zip(headers, (c.strip() for c in line.strip("│").split("│")), strict=True))
        tracker = cells["tracker"] or tracker
        rows[tracker, cells["scope"]] = cells
    return rows


@settings(max_examples=40, deadline=None)
@given(metrics_docs())
def test_the_demo_table_marks_exactly_the_best_value_of_each_column_within_each_scope(metrics):
    marked = _cells(_printed(metrics, mark_best=True))
    plain = _cells(_printed(metrics))
    for header, (key, scale, digits, scopes, best) in SPEC.items():
        for scope in scopes:
            shown = {}
            for name, m in metrics["trackers"].items():
                d = m[scope]
                value = d[key]
                present = {"boundary_jump_max_m": d.get("boundary_jumps"), "jitter_m": value is not None}.get(key, True)
                if present and value is not None:
                    shown[name] = f"{value * scale:.{digits}f}"
            distinct = {float(v) for v in shown.values()}
            winner = best(distinct) if len(distinct) > 1 else None
            for name in metrics["trackers"]:
                cell, unmarked = marked[name, scope][header], plain[name, scope][header]
                value = float(shown[name]) if name in shown else None
                is_best = value is not None and (abs(value) if key == "lag_s" else value) == winner
                assert cell == ("*" + unmarked if is_best else unmarked), (header, scope, name, cell)
    # the marks are the only difference: every number as the unmarked table prints it
    assert _printed(metrics, mark_best=True).replace("*", "").split() == _printed(metrics).split()


def test_the_title_names_the_papers_trackers_and_ours():
    doc = {"session": "s.mcap", "rate_hz": 20.0,
           "trackers": {name: {scope: {"frames": 1, "p_ate_m": None, "r_ate_deg": None, "p_re_m": None}
                               for scope in ("inside", "outside", "total")} for name in TRACKERS}}
    assert "s.mcap @ 20.0 Hz: the paper's T1-T7 and ours (T7L, T8)" in _printed(doc, title_ours=True)
    doc["trackers"] = {k: doc["trackers"][k] for k in ("T2", "T8")}
    assert "s.mcap @ 20.0 Hz: the paper's T2 and ours (T8)" in _printed(doc, title_ours=True)


def test_the_legend_explains_every_column_beyond_the_papers_three():
    from phonepose.cli.playback import TABLE_LEGEND

    starts = [line.split(":")[0] for line in TABLE_LEGEND]
    assert starts[1:] == ["p_ATE, r_ATE", "jump", "lag", "jitter", "avail.", "definitions"]
    assert "positive: late, negative: ahead" in TABLE_LEGEND[3]


# ----------------------------------------------------------------------------- the figure
@settings(deadline=None)   # the first example imports matplotlib
@given(st.lists(st.booleans(), min_size=0, max_size=60))
def test_outside_runs_are_the_stretches_of_false(inside):
    from phonepose.experiments.plots import outside_runs

    runs = outside_runs(np.array(inside, bool))
    rebuilt = np.ones(len(inside), bool)
    for start, stop in runs:
        assert start < stop
        rebuilt[start:stop] = False
    assert rebuilt.tolist() == list(inside)
    # stretches are maximal: each one is bounded by an inside sample or an end of the path
    for start, stop in runs:
        assert start == 0 or inside[start - 1]
        assert stop == len(inside) or inside[stop]


@settings(max_examples=10, deadline=None)
@given(st.lists(st.booleans(), min_size=8, max_size=40))
def test_the_figure_titles_its_views_marks_leaving_and_coming_back_and_has_one_legend(tmp_path_factory, inside):
    import matplotlib.pyplot as plt

    from phonepose.experiments import plots

    n = len(inside)
    t = np.linspace(0.0, 1.0, n)
    gt = Pose.from_xyzw(np.column_stack([0.3 * t, 0.1 * np.sin(6 * t), 0.3 + 0.05 * t]), np.tile([0, 0, 0, 1.0], (n, 1)))
    est = {name: Pose.from_xyzw(gt.translation + 0.01, gt.quat_xyzw) for name in ("T4", "T8")}
    figures = []
    close = plt.close
    try:
        plt.close = figures.append   # keep the figure to look at it
        plots.plot_fig11(tmp_path_factory.mktemp("fig") / "f.png", "title", Pose.identity(), gt, est, np.array(inside))
    finally:
        plt.close = close
    fig = figures[0]
    front, side = fig.axes
    assert front.get_title() == "front view: x-y, seen along z from the camera"
    assert (front.get_xlabel(), front.get_ylabel()) == ("x (cm, right)", "y (cm, up)")
    assert side.get_title() == "side view: z-y, seen along x"
    assert (side.get_xlabel(), side.get_ylabel()) == ("z (cm, forward)", "y (cm, up)")
    assert front.get_legend() is None and side.get_legend() is None and len(fig.legends) == 1
    runs = plots.outside_runs(np.array(inside))
    labels = [text.get_text() for text in fig.legends[0].get_texts()]
    assert labels[:3] == ["ground truth", "T4", "T8 (ours)"]
    assert labels[3:] == (["marker outside the camera's view"] if runs else []) \
        + (["marker leaves the view"] if any(a > 0 for a, _ in runs) else []) \
        + (["marker back in view"] if any(b < n for _, b in runs) else [])
    # the leave / back points sit on the ground truth where the stretches start and end (display axes, cm)
    xyz = plots.to_display_view(Pose.identity(), gt) * 100.0
    for ax, (h, v) in ((front, (0, 1)), (side, (2, 1))):
        leaves = [line.get_xydata()[0].tolist() for line in ax.lines if line.get_marker() == "o"
                  and line.get_markerfacecolor() == "white"]
        backs = [line.get_xydata()[0].tolist() for line in ax.lines if line.get_marker() == "o"
                 and line.get_markerfacecolor() == "black"]
        assert np.allclose(leaves, [[xyz[a, h], xyz[a, v]] for a, _ in runs if a > 0]) if leaves else \
            not any(a > 0 for a, _ in runs)
        assert np.allclose(backs, [[xyz[b, h], xyz[b, v]] for _, b in runs if b < n]) if backs else \
            not any(b < n for _, b in runs)
    close(fig)
