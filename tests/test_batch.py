"""``phonepose batch``: same rows whatever runs it (1 worker, 2 workers, a Dask cluster), failures in
their rows, resuming, parameter sweeps, and the CLI's exit codes.

The tests of what a batch plans and records (failures, resuming, sweeps) run their units in this
process (:func:`in_process`): a spawned worker costs ~2 s of start-up per batch, and the executors
themselves are covered by the one-worker reference, two workers, Dask, the CLI and the kill tests.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from phonepose.batch import RUNTIME_COLUMNS, run_batch
from phonepose.batch.run import flatten_tracker_metrics
from phonepose.batch.table import to_arrow
from phonepose.cli import flags
from phonepose.errors import ConfigError
from phonepose.pipeline.trackers import PAPER_TRACKERS
from phonepose.playback import run_playback
from phonepose.record.sim import default_config, record_sim

PATHS = ("TRI1", "REC1", "TRI2")
# a cheap camera rate keeps the sessions short to simulate and to play back (~1 s each)
FAST = default_config().replace(camera=dict(rate_hz=5.0))
WINDOW = ["start_s=7", "end_s=12"]    # 5 s around the task's start (7.9 s): sweeps stay fast, metrics not null


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "phonepose", *args], capture_output=True, text=True, cwd=cwd)


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("sessions")
    out = []
    for i, path in enumerate(PATHS):
        p = d / f"{path}_01.mcap"
        record_sim(p, scenario="exp2", path=path, trial=1, seed=i, config=FAST)
        out.append(str(p))
    return out


@pytest.fixture(scope="module")
def one_worker(sessions, tmp_path_factory):
    """The reference: all three sessions x T1-T7 with one local worker process."""
    out = tmp_path_factory.mktemp("ref") / "ref.parquet"
    result = run_batch(sessions, out, trackers="paper", workers=1)
    return out, result


@pytest.fixture
def in_process(monkeypatch):
    """Units run one at a time in a thread of this process instead of spawned worker processes."""
    import contextlib
    from concurrent.futures import ThreadPoolExecutor

    import cv2

    import phonepose.batch.driver as driver

    @contextlib.contextmanager
    def one_thread(workers=None, scheduler=None):
        with ThreadPoolExecutor(max_workers=1) as pool:
            yield pool, "1 thread of the test process"

    threads = cv2.getNumThreads()        # run_unit sets the worker's OpenCV to one thread
    monkeypatch.setattr(driver, "open_executor", one_thread)
    yield
    cv2.setNumThreads(threads)


def table_without_runtime(path) -> pa.Table:
    return pq.read_table(path).drop_columns(list(RUNTIME_COLUMNS))


def test_one_worker_rows_are_the_playbacks_metrics(sessions, one_worker):
    out, result = one_worker
    assert (result.units_run, result.rows_run, result.skipped, result.errors) == (3, 21, 0, 0)
    table = pq.read_table(out)
    rows = table.to_pylist()
    # sorted by session, then tracker; one row per (session, tracker)
    assert [(r["session"], r["tracker"]) for r in rows] == [(s, t) for s in sorted(sessions) for t in PAPER_TRACKERS]
    assert {r["status"] for r in rows} == {"ok"} and {r["error"] for r in rows} == {None}
    assert all(r["p_ate_m_total"] > 0 and r["r_ate_deg_total"] > 0 and r["frames_total"] > 0 for r in rows)
    assert {r["param_rate_hz"] for r in rows} == {20.0} and {r["param_correction_math"] for r in rows} == {"paper"}
    assert {r["param_cm1_reading"] for r in rows} == {"consistent"} and {r["param_start_s"] for r in rows} == {None}
    assert table.schema.field("p_ate_m_total").type == pa.float64()
    assert table.schema.field("frames_inside").type == pa.int64()
    # every value of the metrics document, as the playback itself computes it
    direct = run_playback(sessions[1], trackers="paper", write_outputs=False)
    mine = [r for r in rows if r["session"] == sessions[1]]
    for r in mine:
        m = direct.metrics["trackers"][r["tracker"]]
        for scope in ("inside", "outside", "total"):
            for key, value in m[scope].items():
                assert r[f"{key}_{scope}"] == value, (r["tracker"], scope, key)
        assert r["n_ticks"] == direct.n_ticks and r["frames_decoded"] == direct.frames_decoded
        assert r["session_bytes"] == os.path.getsize(sessions[1])
    # runtime: the shared playback's wall time, the same in every row of one session
    assert len({r["runtime_s"] for r in mine}) == 1 and mine[0]["runtime_s"] > 0


@pytest.mark.slow
def test_two_workers_give_the_same_table(sessions, one_worker, tmp_path):
    out = tmp_path / "two.parquet"
    result = run_batch(list(reversed(sessions)), out, trackers="paper", workers=2)
    assert result.units_run == 3 and result.errors == 0
    assert table_without_runtime(out).equals(table_without_runtime(one_worker[0]))


@pytest.mark.slow
def test_dask_local_cluster_gives_the_same_table(sessions, one_worker, tmp_path):
    import distributed  # in the test extra: a missing one must fail, not skip

    out = tmp_path / "dask.parquet"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        result = run_batch(sessions, out, trackers="paper", scheduler=cluster.scheduler_address)
    assert result.executor.startswith(f"Dask cluster {cluster.scheduler_address}")
    assert result.units_run == 3 and result.errors == 0
    assert table_without_runtime(out).equals(table_without_runtime(one_worker[0]))


def test_failing_sessions_are_rows_and_do_not_stop_the_batch(sessions, in_process, tmp_path):
    not_mcap = tmp_path / "not_mcap.mcap"
    not_mcap.write_bytes(b"this is not an MCAP file")
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(open(sessions[0], "rb").read()[:20_000])
    missing = tmp_path / "missing.mcap"
    out = tmp_path / "r.parquet"
    result = run_batch([str(not_mcap), sessions[0], str(truncated), str(missing)], out, trackers="paper",
                       params=WINDOW, workers=2)
    assert result.units_run == 4 and result.errors == 21
    rows = pq.read_table(out).to_pylist()
    by_session = {}
    for r in rows:
        by_session.setdefault(r["session"], []).append(r)
    assert {r["status"] for r in by_session[sessions[0]]} == {"ok"}
    assert all(r["p_ate_m_total"] > 0 for r in by_session[sessions[0]])
    assert len(by_session[sessions[0]]) == 7
    expected = {str(not_mcap): f"{not_mcap}: not an MCAP file",
                str(missing): f"{missing}: no such file",
                str(truncated): f"{truncated}: damaged MCAP file"}
    for session, message in expected.items():
        rs = by_session[session]
        assert [r["tracker"] for r in rs] == list(PAPER_TRACKERS)
        assert {r["status"] for r in rs} == {"error"}
        assert len({r["error"] for r in rs}) == 1 and rs[0]["error"].startswith(message)
        assert "\n" not in rs[0]["error"]
        assert rs[0]["p_ate_m_total"] is None and rs[0]["n_ticks"] is None
    assert sorted(s for s, _ in result.failures) == sorted(expected)


def test_rerun_skips_done_rows_retries_errors_and_reruns_changed_sessions(sessions, in_process, tmp_path):
    session = tmp_path / "s.mcap"
    shutil.copy(sessions[2], session)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"junk")
    out = tmp_path / "r.parquet"
    first = run_batch([str(session), str(bad)], out, trackers="paper", params=WINDOW, workers=1)
    assert (first.units_run, first.skipped, first.errors) == (2, 0, 7)
    before = pq.read_table(out)

    again = run_batch([str(session), str(bad)], out, trackers="paper", params=WINDOW, workers=1)
    assert (again.units_run, again.rows_run, again.skipped, again.plan.retried) == (1, 7, 7, 7)   # only the bad one
    after = pq.read_table(out)
    good = pa.compute.equal(before["session"], str(session))
    assert after.filter(good).equals(before.filter(good))      # the ok rows were not played again: same runtime_s

    # nothing to do at all: no executor is even started
    bad.unlink()
    none = run_batch([str(session)], out, trackers="paper", params=WINDOW, workers=1)
    assert (none.units_run, none.skipped, none.executor) == (0, 7, "nothing to run")

    # a new tracker subset / parameter value runs only what is missing
    more = run_batch([str(session)], out, trackers="paper", params=WINDOW + ["rate_hz=20,10"], workers=1)
    assert (more.units_run, more.rows_run, more.skipped) == (1, 7, 7)

    # the session file changed (mtime): its rows are stale and run again
    st = os.stat(session)
    os.utime(session, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    changed = run_batch([str(session)], out, trackers="paper", params=WINDOW, workers=1)
    assert (changed.units_run, changed.plan.stale, changed.skipped) == (1, 7, 0)
    assert pq.read_table(out).num_rows == 7 + 7 + 7        # bad, 20 Hz, 10 Hz: replaced, never duplicated


def test_param_sweep_is_the_cross_product(sessions, in_process, tmp_path):
    out = tmp_path / "sweep.parquet"
    result = run_batch([sessions[1]], out, trackers=["T1", "T5"],
                       params=WINDOW + ["rate_hz=20,10", "correction_math=se3,paper", "cm1_reading=paper-literal"],
                       workers=2)
    assert (result.units_run, result.rows_run, result.errors) == (4, 8, 0)
    rows = pq.read_table(out).to_pylist()
    assert [(r["param_rate_hz"], r["param_correction_math"], r["tracker"]) for r in rows] == [
        (rate, math, t) for rate in (10.0, 20.0) for math in ("paper", "se3") for t in ("T1", "T5")]
    assert {(r["param_cm1_reading"], r["param_start_s"], r["param_end_s"]) for r in rows} == {("paper-literal", 7.0, 12.0)}
    assert all(r["p_ate_m_total"] > 0 and r["frames_total"] > 0 for r in rows)
    # one combination checked against the playback itself (cm1_reading goes to the trackers)
    from phonepose.pipeline.trackers import make_trackers

    direct = run_playback(sessions[1], trackers=["T1", "T5"], rate_hz=10, correction_math="se3", start_s=7, end_s=12,
                          write_outputs=False, tracker_factory=lambda n, m: make_trackers(n, m, "paper-literal"))
    for r in rows:
        if (r["param_rate_hz"], r["param_correction_math"]) == (10.0, "se3"):
            for scope, values in direct.metrics["trackers"][r["tracker"]].items():
                for key, value in values.items():
                    assert r[f"{key}_{scope}"] == value, (scope, key)
            assert r["n_ticks"] == direct.n_ticks
    n_ticks = {r["param_rate_hz"]: r["n_ticks"] for r in rows}
    assert n_ticks[20.0] == 2 * n_ticks[10.0] - 1 or n_ticks[20.0] == 2 * n_ticks[10.0]


@pytest.mark.parametrize("params,message", [
    (["speed=1"], "unknown key 'speed'"),
    (["rate_hz=fast"], "'fast' is not a number"),
    (["rate_hz=0"], r"^params rate_hz=0: expected a finite number in \[0\.1, 1000\] Hz$"),
    (["rate_hz=inf"], r"^params rate_hz=inf: expected a finite number in \[0\.1, 1000\] Hz$"),
    (["start_s=nan"], r"^params start_s=nan: expected a finite number in \[0, 1000000\] s$"),
    (["correction_math=quat"], "unknown correction math 'quat'"),
    (["rate_hz=10", "rate_hz=20"], "given twice"),
    (["start_s=5", "end_s=3"], "must be after start_s"),
])
def test_bad_params_are_config_errors(params, message, tmp_path):
    with pytest.raises(ConfigError, match=message):
        run_batch(["x.mcap"], tmp_path / "r.parquet", trackers="paper", params=params)
    assert not (tmp_path / "r.parquet").exists()


def test_a_cross_product_over_the_unit_limit_is_refused_before_it_is_built(tmp_path, cli):
    """2 sessions x 1000 x 1000 x 100 x 2 = 4*10^8 playbacks: one line from the value counts within
    seconds (it used to build the product: 17.9 GB after 120 s, no line), nothing written."""
    import time

    from phonepose.batch.plan import MAX_UNITS

    def values(lo, hi):
        return ",".join(str(v) for v in range(lo, hi))

    t0 = time.monotonic()
    got, _, err = cli("batch", "a.mcap", "b.mcap", "./a.mcap", "-t", "paper", "-o", tmp_path / "big.parquet",
                      "-p", f"rate_hz={values(1, 1001)}", "-p", f"start_s={values(0, 1000)}",
                      "-p", f"end_s={values(1001, 1101)}", "-p", "correction_math=paper,se3,paper", "-q")
    assert time.monotonic() - t0 < 20
    assert got == 5 and err == ("phonepose: error: --param: 2 sessions x 1000 rate_hz x 2 correction_math x "
                                "1000 start_s x 100 end_s = 400,000,000 playbacks, more than a batch's limit of "
                                "100,000; split it into several batches (fewer sessions or --param values each, "
                                "one --out per batch)\n")
    assert MAX_UNITS == 100_000 and not (tmp_path / "big.parquet").exists()
    # the Python API counts the same way: one playback over the limit
    with pytest.raises(ConfigError, match=r"100,001 playbacks, more than a batch's limit of 100,000"):
        run_batch(["x.mcap"], tmp_path / "r.parquet", trackers="paper",
                  params={"start_s": list(range(100_001))})


def test_many_values_of_one_key_are_parsed_in_linear_time():
    import time

    from phonepose.batch.plan import parse_param_options

    t0 = time.monotonic()
    got = parse_param_options(["start_s=" + ",".join(str(v) for v in range(20_000)) + ",1,none,null,0"])
    assert time.monotonic() - t0 < 2     # a list's `in`: 3 s here
    assert got["start_s"] == [float(v) for v in range(20_000)] + [None]


def test_a_repeated_failure_is_printed_three_times_then_counted(in_process, tmp_path, cli):
    """7 playbacks of each of two broken sessions: 3 lines per cause, then one line per cause with the
    rest (a sweep over a short session printed 64,650 identical lines in 120 s); every row is kept."""
    missing, not_mcap = tmp_path / "missing.mcap", tmp_path / "not_mcap.mcap"
    not_mcap.write_bytes(b"this is not an MCAP file")
    out = tmp_path / "r.parquet"
    got, _, err = cli("batch", missing, not_mcap, "-t", "T1", "-p", "start_s=0,1,2,3,4,5,6", "-o", out, "-q")
    assert got == 1
    lines = err.splitlines()
    assert lines[0] == (f"2 sessions x 7 parameter combinations x 1 trackers = 14 rows; 0 already in {out} "
                        "(skipped); 14 playbacks on 1 thread of the test process")
    assert lines[1:] == [f"failed {missing} (start_s={i}): {missing}: no such file" for i in range(3)] + \
        [f"failed {not_mcap} (start_s={i}): {not_mcap}: not an MCAP file" for i in range(3)] + \
        [f"... and 4 more failures like this: {missing}: no such file",
         f"... and 4 more failures like this: {not_mcap}: not an MCAP file",
         f"phonepose: error: 14 of 14 rows failed (status error in {out}; the next run with the same --out "
         "retries them)"]
    rows = pq.read_table(out).to_pylist()
    assert len(rows) == 14 and {r["status"] for r in rows} == {"error"}


def test_a_large_sweeps_summary_shows_its_first_rows_and_a_count():
    from rich.console import Console

    from phonepose.cli.batch import SUMMARY_ROWS_SHOWN, summary_table

    entries = [{"tracker": "T1", "params": f"start_s={i}", "ok": 0, "errors": 1, "p_ate_m_total": (None, None),
                "r_ate_deg_total": (None, None), "p_re_m_total": (None, None)} for i in range(1000)]
    console = Console(width=200, record=True, file=open(os.devnull, "w"))
    console.print(summary_table(entries, "r.parquet"))
    text = console.export_text()
    assert SUMMARY_ROWS_SHOWN == 100
    assert "start_s=99 " in text and "start_s=100 " not in text
    assert "... and 900 more rows (tracker x parameter combinations): read them from r.parquet" in " ".join(text.split())
    console = Console(width=200, record=True, file=open(os.devnull, "w"))
    console.print(summary_table(entries[:100], "r.parquet"))
    assert "more rows" not in console.export_text()


def test_failure_causes_ignore_the_session_and_numbers():
    from phonepose.cli.batch import failure_cause

    def row(session, error):
        return {"session": session, "error": error}

    no_tick = "--start/--end select no tick: the session runs {} s and its first tick is at 0.00 s"
    assert failure_cause(row("a.mcap", no_tick.format("14.48"))) == \
        failure_cause(row("b.mcap", no_tick.format("3.5e+02"))) == \
        "--start/--end select no tick: the session runs # s and its first tick is at # s"
    assert failure_cause(row("a.mcap", "a.mcap: no such file")) == failure_cause(row("b/c.mcap", "b/c.mcap: no such file"))
    assert failure_cause(row("a.mcap", "a.mcap: no such file")) != failure_cause(row("a.mcap", "a.mcap: not an MCAP file"))


def test_row_order_is_cached_per_params_text_and_survives_odd_params():
    from phonepose.batch.table import _params_order, sort_key

    a = {"session": "s", "params": '{"rate_hz":10.0,"start_s":null}', "tracker": "T10"}
    b = {**a, "tracker": "T2"}
    c = {**a, "params": '{"rate_hz":5.0,"start_s":null}'}
    odd = {**a, "params": "[1]"}            # not an object: ordered as if empty, no exception
    hits = _params_order.cache_info().hits
    assert sorted([a, b, c, odd], key=sort_key) == [odd, c, b, a]
    assert sort_key(a)[1] is sort_key(b)[1] and _params_order.cache_info().hits > hits


def test_metrics_are_flattened_generically_and_new_keys_become_columns():
    m = {"inside": {"frames": 3, "p_ate_m": 0.1}, "total": {"frames": 5, "p_ate_m": 0.2, "boundary_jump_max_m": 0.04,
                                                           "boundary_jump_rms_m": None}, "note": "x"}
    assert flatten_tracker_metrics(m) == {"frames_inside": 3, "p_ate_m_inside": 0.1, "frames_total": 5,
                                          "p_ate_m_total": 0.2, "boundary_jump_max_m_total": 0.04,
                                          "boundary_jump_rms_m_total": None, "note": "x"}
    base = {"params": "{}", "status": "ok", "tracker": "T1"}
    table = to_arrow([{**base, "session": "b", "boundary_jump_max_m_total": 0, "frames_total": 4},
                      {**base, "session": "a", "boundary_jump_max_m_total": 0.5},
                      {**base, "session": "c", "status": "error", "error": "x"}])
    assert table.column("session").to_pylist() == ["a", "b", "c"]
    assert table.schema.field("boundary_jump_max_m_total").type == pa.float64()
    assert table.column("boundary_jump_max_m_total").to_pylist() == [0.5, 0.0, None]
    assert table.schema.field("frames_total").type == pa.int64()
    assert table.column("frames_total").to_pylist() == [None, 4, None]


@pytest.mark.parametrize("args,code,message", [
    (["--param", "speed=1,2"], 5, "--param: unknown key 'speed'; valid: rate_hz, correction_math, cm1_reading"),
    (["--out", "{tmp}/no/such/dir/r.parquet"], 6, "does not exist"),
    (["--out", "{tmp}"], 6, "is a directory"),
    (["--out", "{tmp}/not.parquet"], 6, "is not a readable Parquet table"),
    (["--workers", "0"], 5, "--workers 0: expected an integer in [1, 256]"),
    (["--unit-timeout", "nan"], 5, "--unit-timeout nan: expected a finite number in (0, 1000000] s"),
    (["--scheduler", "not a url"], 5, "--scheduler 'not a url': expected a Dask scheduler address such as "
                                      "tcp://host:8786"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], 5, "exclusive"),
    (["-t", "T99"], 5, "T99"),
])
def test_cli_errors_are_one_line_with_exit_code(args, code, message, tmp_path, cli):
    (tmp_path / "not.parquet").write_text("not parquet")
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    if "--out" not in args:
        args += ["--out", str(tmp_path / "r.parquet")]
    if "-t" not in args:
        args += ["-t", "paper"]
    got, _, err = cli("batch", "x.mcap", *args)
    assert got == code, err
    assert err.count("\n") == 1 and err.startswith("phonepose: error: ") and message in err
    assert "Traceback" not in err


@pytest.mark.slow
def test_cli_runs_reports_failures_and_resumes(sessions, tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"junk")
    out = tmp_path / "r.parquet"
    args = ["batch", sessions[0], str(bad), "-t", "paper", "-p", "start_s=7", "-p", "end_s=11", "--out", str(out),
            "--workers", "2"]
    r = run(*args)
    assert r.returncode == 1, r.stderr
    assert f"failed {bad}: {bad}: not an MCAP file" in r.stderr
    assert "2 sessions x 1 parameter combinations x 7 trackers = 14 rows; 0 already in" in " ".join(r.stderr.split())
    assert "phonepose: error: 7 of 14 rows failed" in r.stderr
    assert "2 playbacks (14 rows) run in" in r.stdout and "batch summary" in r.stdout
    assert "│ T7 " in r.stdout
    assert pq.read_table(out).num_rows == 14
    r2 = run(*args[:2], *args[3:])       # the good session only: everything is in the table already
    assert r2.returncode == 0, r2.stderr
    assert "0 playbacks (0 rows) run in" in r2.stdout and "7 rows skipped" in r2.stdout
    assert "nothing to run" in r2.stderr


# The batch in a child that stops after its first unit: progress() runs after the table was written
# (immediately for the first unit), so the kill comes with exactly that unit in the file and two to go,
# however fast or loaded the machine (killing when the file appears raced the remaining ~1 s units).
_HOLD_AFTER_FIRST_UNIT = """
import sys, time
from phonepose.batch import run_batch
def hold(done, total, rows):
    print(done, total, len(rows), flush=True)
    time.sleep(600)
run_batch(sys.argv[2:], sys.argv[1], trackers="paper", workers=1, progress=hold)
"""


@pytest.mark.slow
def test_killed_batch_keeps_finished_units_and_the_rerun_completes(sessions, one_worker, tmp_path):
    import signal

    out = tmp_path / "r.parquet"
    proc = subprocess.Popen([sys.executable, "-c", _HOLD_AFTER_FIRST_UNIT, str(out), *sessions],
                            stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        assert proc.stdout.readline().split() == ["1", "3", "7"]   # waits for the first unit, however long
    finally:
        os.killpg(proc.pid, signal.SIGKILL)      # the batch and its worker (busy with unit 2), at once
        proc.wait()
    kept = pq.read_table(out).to_pylist()       # a complete table: written to a temporary file, then renamed
    assert len(kept) == 7 and {r["status"] for r in kept} == {"ok"}
    rerun = run_batch(sessions, out, trackers="paper", workers=1)
    assert rerun.skipped == 7 and rerun.rows_run == 14 and rerun.errors == 0
    assert table_without_runtime(out).equals(table_without_runtime(one_worker[0]))   # the same as in one go


@pytest.mark.parametrize("where", ["main thread (SIGALRM)", "worker thread (tick check)"])
def test_a_unit_past_its_time_budget_becomes_error_rows(sessions, where):
    """A session that would play forever (or a Dask worker's thread) cannot hold a batch: --unit-timeout."""
    import threading

    from phonepose.batch.plan import Unit
    from phonepose.batch.run import run_unit

    unit = Unit("s.mcap", sessions[0], (("rate_hz", 20.0),), ("T1", "T4"))
    rows = []
    if where.startswith("main"):
        rows = run_unit(unit, budget_s=0.01)
    else:
        t = threading.Thread(target=lambda: rows.extend(run_unit(unit, budget_s=0.01)))
        t.start()
        t.join(timeout=300)
    assert [r["tracker"] for r in rows] == ["T1", "T4"]
    assert {r["status"] for r in rows} == {"error"}
    assert {r["error"] for r in rows} == {"stopped after its time budget of 0.01 s (unit_timeout_s)"}
    assert run_unit(unit, budget_s=600)[0]["status"] == "ok"


def test_a_flipped_bit_in_the_table_is_found_on_resume(one_worker, tmp_path):
    """Page CRCs and the rows' SHA-256 in the metadata: a flip anywhere is one line, or changes nothing."""
    from phonepose.batch.table import CHECKSUM_KEY, read_rows
    from phonepose.errors import OutputError

    ref, _ = one_worker
    assert CHECKSUM_KEY in pq.read_metadata(ref).metadata
    clean = read_rows(ref)
    data = ref.read_bytes()
    p = tmp_path / "t.parquet"
    refused = 0
    positions = range(4, len(data) - 4, max(1, len(data) // 400))     # ~400 spread over pages, footer, metadata
    for i in positions:
        b = bytearray(data)
        b[i] ^= 1 << (i % 8)
        p.write_bytes(bytes(b))
        try:
            rows = read_rows(p)
        except OutputError as exc:
            assert "\n" not in str(exc) and str(exc).startswith(f"out {p} ")
            assert str(exc).endswith("; move it away or choose another out")
            refused += 1
        else:
            assert rows == clean, f"flipping a bit of byte {i} changed the rows"
    assert refused > len(positions) // 2
    # a flip in a value that still decodes: the hash finds it
    table = pq.read_table(ref)
    meta = table.schema.metadata
    t = table.set_column(table.column_names.index("n_ticks"), "n_ticks",
                         pa.array([v + 1 for v in table.column("n_ticks").to_pylist()], pa.int64()))
    pq.write_table(t.replace_schema_metadata(meta), p)
    with pytest.raises(OutputError) as err:
        read_rows(p)
    assert str(err.value) == (f"out {p} does not match its checksum: it changed on the disk after phonepose wrote it; "
                              "move it away or choose another out")


def test_the_columns_hash_survives_parquet_and_sees_each_value(tmp_path):
    """NaN, -0.0, inf, nulls, booleans, empty and NUL-holding strings: the same hash after a round trip,
    another hash after any one value changes (a null for a zero, an empty string for a null included)."""
    from phonepose.batch.table import columns_hash

    columns = {"f": [float("nan"), -0.0, float("inf"), None, 1.0], "s": ["x", None, "", "é", "a\x00b"],
               "b": [True, None, False, True, True], "i": [1, None, 3, 4, 0]}
    table = pa.table(columns)
    pq.write_table(table, tmp_path / "t.parquet")
    assert columns_hash(pq.read_table(tmp_path / "t.parquet")) == columns_hash(table)
    changes = {"f": [(1, 0.0), (3, 0.0)], "s": [(1, ""), (2, None), (4, "a")], "b": [(1, False), (2, True)],
               "i": [(1, 0), (4, None)]}
    hashes = {columns_hash(table)}
    for name, edits in changes.items():
        for row, value in edits:
            values = list(columns[name])
            values[row] = value
            hashes.add(columns_hash(table.set_column(table.column_names.index(name), name,
                                                     pa.array(values, table.schema.field(name).type))))
    assert len(hashes) == 1 + sum(map(len, changes.values()))


def test_a_table_checksummed_by_an_older_phonepose_is_still_checked(one_worker, tmp_path):
    """Tables written before the columns' hash carry a hash of their rows as JSON: still read, still checked."""
    from phonepose.batch.table import CHECKSUM_KEY, ROWS_CHECKSUM_KEY, columns_hash, read_rows, rows_hash
    from phonepose.errors import OutputError

    ref, _ = one_worker
    table = pq.read_table(ref)
    assert table.schema.metadata[CHECKSUM_KEY].decode() == columns_hash(table)   # as written == as read back
    old = tmp_path / "old.parquet"
    pq.write_table(table.replace_schema_metadata({ROWS_CHECKSUM_KEY: rows_hash(table.to_pylist()).encode()}), old)
    assert read_rows(old) == read_rows(ref)
    changed = table.set_column(table.column_names.index("n_ticks"), "n_ticks",
                               pa.array([v + 1 for v in table.column("n_ticks").to_pylist()], pa.int64()))
    pq.write_table(changed.replace_schema_metadata({ROWS_CHECKSUM_KEY: rows_hash(table.to_pylist()).encode()}), old)
    with pytest.raises(OutputError, match="does not match its checksum"):
        read_rows(old)
    # a value moved from one row to the next keeps every column's multiset: the hash still sees it
    trackers = table.column("tracker").to_pylist()
    assert len(set(trackers)) > 1
    rotated = table.set_column(table.column_names.index("tracker"), "tracker",
                               pa.array(trackers[1:] + trackers[:1], pa.string()))
    pq.write_table(rotated.replace_schema_metadata(table.schema.metadata), old)
    with pytest.raises(OutputError, match="does not match its checksum"):
        read_rows(old)


def test_resuming_a_table_with_wrong_column_types_is_one_line(sessions, tmp_path, cli):
    out = tmp_path / "r.parquet"
    pq.write_table(pa.table({"session": pa.array([1, 2]), "params": ["{}", "{}"], "tracker": ["T1", "T2"],
                             "status": ["ok", "ok"]}), out)
    before = out.read_bytes()
    code, _, err = cli("batch", sessions[0], "-t", "T1", "--out", out)
    assert code == 6
    assert err == (f"phonepose: error: --out {out} is not a phonepose batch table (column session is "
                   "int64, not string); move it away or choose another --out\n")
    assert out.read_bytes() == before


LEFT_WITHOUT_WORKERS = [(int(w), int(a)) for w, a in zip(np.random.default_rng(5).integers(1, 3, 3),
                                                        np.random.default_rng(6).integers(0, 4, 3), strict=True)]


@pytest.mark.slow
@pytest.mark.parametrize("keep_waiting", [False, True], ids=["stops", "keeps-waiting"])
@pytest.mark.parametrize(("workers", "after"), LEFT_WITHOUT_WORKERS)
def test_a_dask_cluster_left_without_workers_is_said_and_waited_for_a_bound(sessions, tmp_path, workers, after,
                                                                           keep_waiting):
    """Every worker of the cluster gone after a generated number of finished units: the batch hears the count
    drop to 0 (it waited silently for ever); it stops after the bound with one line naming what is left and the
    finished rows it wrote, or, asked to keep waiting, goes on when a worker comes back."""
    import re

    import distributed

    from phonepose.batch.driver import execute_batch, prepare_batch
    from phonepose.errors import PhoneposeError

    out = tmp_path / "r.parquet"
    with distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        batch = prepare_batch(sessions, out, trackers=["T1"], params=["rate_hz=10,20"] + WINDOW,
                              scheduler=cluster.scheduler_address)
        assert len(batch.plan.units) == 6      # more than the finished units and the ones in flight together
        counts: list[int] = []

        def leave() -> None:
            cluster.scale(0)

        def on_workers(n: int) -> None:
            counts.append(n)
            if n == 0 and keep_waiting:
                cluster.scale(workers)          # one comes back: the batch goes on

        def progress(done, total, rows):
            if done == after:
                leave()

        on_start = (lambda plan, executor: leave()) if after == 0 else None
        if keep_waiting:
            result = execute_batch(batch, progress, on_start, on_workers=on_workers, no_worker_timeout_s=None)
            assert result.units_run == 6 and result.errors == 0 and pq.read_table(out).num_rows == 6
            assert 0 in counts                          # said, then waited for (the return may not be seen before
            return                                      # the last unit ends)
        with pytest.raises(PhoneposeError) as e:
            execute_batch(batch, progress, on_start, on_workers=on_workers, no_worker_timeout_s=1.0)
    rows = pq.read_table(out).num_rows
    assert rows >= after and counts[-1] == 0       # (2 workers may be seen leaving one at a time)
    left = re.fullmatch(rf"--scheduler {re.escape(cluster.scheduler_address)}: the cluster has had no worker for 1 s, "
                        rf"so (\d+) playbacks cannot run; {rows} finished rows? (are|is) in {re.escape(str(out))} "
                        rf"\(start a `dask worker {re.escape(cluster.scheduler_address)}` and run the same command "
                        rf"again, or add --keep-waiting\)", flags.message(e.value))
    assert left is not None, str(e.value)
    assert int(left[1]) == 6 - rows
