"""Evaluation internals: exact alignment recovery, zero error on identical trajectories, the vectorised
association and pair searches against plain-loop references, loaders/writer, paper_metrics, CLI."""

from __future__ import annotations

import json
import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from phonepose.errors import ConfigError, InputFileError
from phonepose.evaluation import (
    Trajectory,
    align,
    associate_evo,
    associate_rpg,
    evaluate_rpg,
    load_euroc,
    load_kitti,
    load_tum,
    paper_metrics,
    write_tum,
)
from phonepose.evaluation.evo_metrics import Unit, _first_crossings, evo_align, id_pairs_from_delta
from phonepose.evaluation.relative import find_pairs, relative_errors
from phonepose.geometry import Pose

DATA = Path(__file__).parent / "data"


def random_traj(n: int, seed: int) -> Pose:
    rng = np.random.default_rng(seed)
    p = np.cumsum(rng.normal(0, 0.1, (n, 3)), axis=0)
    r = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.05, (n, 3)), axis=0))
    return Pose(r, p)


# ----------------------------------------------------------------------------- alignment
@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), scale=st.floats(0.2, 5.0))
def test_umeyama_recovers_known_sim3_and_se3(seed, scale):
    rng = np.random.default_rng(seed)
    gt = random_traj(50, seed)
    r = Rotation.random(random_state=seed)
    t = rng.normal(0, 3, 3)
    # est = T^-1 gt with a scale: gt = s R est + t
    est = Pose(r.inv() * gt.rotation, r.inv().apply(gt.translation - t) / scale)
    a = align(gt, est, "sim3")
    assert a.scale == pytest.approx(scale, rel=1e-9)
    np.testing.assert_allclose(a.rotation, r.as_matrix(), atol=1e-9)
    np.testing.assert_allclose(a.translation, t, atol=1e-8)
    assert a.apply(est).allclose(gt, atol=1e-8)
    est1 = Pose(r.inv() * gt.rotation, r.inv().apply(gt.translation - t))
    for method, n in (("se3", -1), ("se3", 10), ("se3", 1)):
        b = align(gt, est1, method, n)
        assert b.scale == 1.0
        np.testing.assert_allclose(b.rotation, r.as_matrix(), atol=1e-9)
        np.testing.assert_allclose(b.translation, t, atol=1e-8)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), yaw=st.floats(-3.1, 3.1))
def test_posyaw_recovers_known_yaw(seed, yaw):
    gt = random_traj(40, seed)
    r = Rotation.from_euler("z", yaw)
    t = np.array([1.0, -2.0, 0.5])
    est = Pose(r.inv() * gt.rotation, r.inv().apply(gt.translation - t))
    for n in (-1, 1, 5):
        a = align(gt, est, "posyaw", n)
        np.testing.assert_allclose(a.rotation, r.as_matrix(), atol=1e-9)
        np.testing.assert_allclose(a.translation, t, atol=1e-8)


def test_alignment_options_are_checked():
    gt = random_traj(10, 1)
    with pytest.raises(ConfigError):
        align(gt, gt, "sim3", 1)
    with pytest.raises(ConfigError):
        align(gt, gt, "se3", 11)
    with pytest.raises(ConfigError):
        align(gt, gt, "yaw", -1)


def test_an_alignment_the_positions_do_not_determine_is_refused(cli, tmp_path):
    """A trajectory that never moves, or two poses (on one line): the rotation of a se3/sim3 Umeyama (and posyaw's
    yaw, for one point) is then arbitrary. rpg's code has no check: ours returned an SVD's arbitrary rotation and
    ATE rotation / RE from it; evo refuses ("degenerate covariance rank"), and so do we, on both paths."""
    gt = random_traj(50, 4)
    still = Pose(gt.rotation, np.tile(gt.translation[0], (50, 1)))
    line = Pose(gt.rotation, np.outer(np.arange(50) * 0.01, [1.0, 2.0, 0.5]))
    for est, methods in ((still, ("posyaw", "se3", "sim3")), (line, ("se3", "sim3")), (gt[:2], ("se3", "sim3"))):
        ref = gt[:len(est)]
        for method in methods:
            with pytest.raises(ConfigError, match="at one point or on one line"):
                align(ref, est, method)
            if method != "posyaw":
                with pytest.raises(ConfigError, match="at one point or on one line"):
                    evo_align(ref, est, method)
        assert align(ref, est, "se3", 1).method == "se3"          # the first-pose closed form needs no spread
    # a line determines the yaw (its direction in x-y): posyaw keeps working
    yaw = Rotation.from_euler("z", 0.3)
    a = align(Pose(yaw * line.rotation, yaw.apply(line.translation)), line, "posyaw")
    np.testing.assert_allclose(a.rotation, yaw.as_matrix(), atol=1e-12)
    stamps = np.arange(50) * 0.05
    write_tum(tmp_path / "gt.tum", stamps, gt)
    write_tum(tmp_path / "still.tum", stamps, still)
    write_tum(tmp_path / "one.tum", stamps[:1], gt[:1])
    for args, text in ((["--est", "still.tum"], "lie at one point or on one line"),
                       (["--est", "one.tum", "--metric", "ape", "--align", "se3"],
                        "--align se3 needs at least 2 matched poses, there is 1: use --align none")):
        code, _, err = cli("evaluate", "--gt", str(tmp_path / "gt.tum"), *[str(tmp_path / a) if a.endswith(".tum")
                                                                           else a for a in args])
        *warnings, last = err.strip().splitlines()   # one error line, the last; warnings about the inputs before it
        assert code == 5 and text in last and all(w.startswith("phonepose: warning: ") for w in warnings), err


def test_an_estimate_in_millimetres_is_flagged(cli, tmp_path, caplog):
    """Neither file says its unit: an estimate in mm against a GT in m gave an ATE of hundreds of metres and no word.
    One warning line with both spreads (RMS distance from their centroid over the matched poses); none with sim3."""
    gt = random_traj(200, 5)
    stamps = np.arange(200) * 0.05
    write_tum(tmp_path / "gt.tum", stamps, gt)
    write_tum(tmp_path / "mm.tum", stamps, Pose(gt.rotation, gt.translation * 1000))
    p = gt.translation
    spread = float(np.sqrt(np.mean(np.sum((p - p.mean(0)) ** 2, axis=1))))
    with caplog.at_level(logging.WARNING, logger="phonepose"):
        code, out, _ = cli("evaluate", "--gt", str(tmp_path / "gt.tum"), "--est", str(tmp_path / "mm.tum"), "--json")
    assert code == 0 and json.loads(out)["n_matched"] == 200
    assert caplog.messages == [
        f"{tmp_path / 'mm.tum'}'s positions spread {1000 * spread:.3g} m, {tmp_path / 'gt.tum'}'s "
        f"{spread:.3g} m (1e+03x): are both in metres? (--align sim3 estimates a scale)"]
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="phonepose"):
        code, out, _ = cli("evaluate", "--gt", str(tmp_path / "gt.tum"), "--est", str(tmp_path / "mm.tum"), "--json",
                           "--align", "sim3")
    assert code == 0 and caplog.messages == [] and json.loads(out)["align"]["scale"] == pytest.approx(1e-3, rel=1e-9)
    # an estimate 10x too large (a diverging tracker) or in cm: only the unit is flagged
    for factor, flagged in ((10.0, False), (100.0, True), (0.01, True), (3.0, False)):
        write_tum(tmp_path / "x.tum", stamps, Pose(gt.rotation, gt.translation * factor))
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="phonepose"):
            cli("evaluate", "--gt", str(tmp_path / "gt.tum"), "--est", str(tmp_path / "x.tum"), "--json")
        assert bool(caplog.messages) == flagged, factor


# ----------------------------------------------------------------------------- zero errors
@pytest.mark.parametrize("method", ["posyaw", "se3", "sim3", "none"])
def test_trajectory_against_itself_is_zero(method):
    poses = random_traj(300, 7)
    tr = Trajectory(np.arange(300) * 0.05, poses)
    r = evaluate_rpg(tr, tr, method, lengths=[1.0, 2.0])
    assert r["n_matched"] == 300
    assert r["ate"]["trans_m"]["max"] == pytest.approx(0, abs=1e-9)
    assert r["ate"]["rot_deg"]["max"] == pytest.approx(0, abs=1e-6)
    for v in r["re"].values():
        assert v["trans_m"]["num_samples"] > 10
        assert v["trans_m"]["max"] == pytest.approx(0, abs=1e-9)
        assert v["rot_deg"]["max"] == pytest.approx(0, abs=1e-5)  # arccos near 1: ~1e-6 deg resolution


# ----------------------------------------------------------------------------- plain-loop references
def rpg_associate_loop(te, tr, max_diff):
    cands = sorted((abs(a - (b + 0.0)), i, j) for i, a in enumerate(te) for j, b in enumerate(tr)
                   if abs(a - (b + 0.0)) < max_diff)
    ui, uj, out = set(), set(), []
    for _, i, j in cands:
        if i not in ui and j not in uj:
            ui.add(i), uj.add(j), out.append((i, j))
    return sorted(out)


stamp_lists = st.lists(st.integers(0, 400), min_size=1, max_size=60).map(lambda v: np.sort(np.array(v)) * 0.005)


@settings(max_examples=80, deadline=None)
@given(te=stamp_lists, tr=stamp_lists)
def test_rpg_association_equals_greedy_loop(te, tr):
    i, j = associate_rpg(te, tr, 0.02)
    assert list(zip(i.tolist(), j.tolist(), strict=True)) == rpg_associate_loop(te, tr, 0.02)


@settings(max_examples=80, deadline=None)
@given(te=stamp_lists, tr=stamp_lists)
def test_evo_association_equals_evo_sync(te, tr):
    """Against evo 1.38.1's own matching_time_indices (shorter trajectory as query; duplicates included)."""
    from evo.core import sync  # evo 1.38.1 is in the test extra

    i_est, i_ref = associate_evo(te, tr, 0.01)
    if te.size > tr.size:
        q_idx, s_idx = sync.matching_time_indices(tr, te, 0.01)
        assert (i_ref.tolist(), i_est.tolist()) == (q_idx, s_idx)
    else:
        q_idx, s_idx = sync.matching_time_indices(te, tr, 0.01)
        assert (i_est.tolist(), i_ref.tolist()) == (q_idx, s_idx)


def rpg_pairs_loop(d, dist, max_dist_diff):
    out = []
    for idx, x in enumerate(d):
        best, err = -1, max_dist_diff
        for i in range(idx, len(d)):
            if abs(d[i] - (x + dist)) < err:
                best, err = i, abs(d[i] - (x + dist))
        if best != -1:
            out.append((idx, best))
    return out


steps = st.lists(st.sampled_from([0.0, 0.0, 0.1, 0.25, 0.3, 1.0, 1.7]), min_size=1, max_size=80)


@settings(max_examples=100, deadline=None)
@given(s=steps, length=st.sampled_from([0.3, 0.5, 1.0, 2.0]))
def test_rpg_pair_search_equals_loop(s, length):
    d = np.concatenate(([0.0], np.cumsum(s)))
    a, b = find_pairs(d, length)
    assert list(zip(a.tolist(), b.tolist(), strict=True)) == rpg_pairs_loop(d.tolist(), length, 0.2 * length)


@settings(max_examples=100, deadline=None)
@given(s=steps, delta=st.sampled_from([0.3, 0.5, 1.0, 2.0]))
def test_evo_path_pairs_equal_loops(s, delta):
    d = np.concatenate(([0.0], np.cumsum(s)))
    p = np.zeros((d.size, 3))
    p[:, 0] = d
    poses = Pose(Rotation.identity(d.size), p)
    # consecutive: accumulate with reset
    ids, cur = [0], 0.0
    for i in range(1, d.size):
        cur += float(np.linalg.norm(p[i] - p[i - 1]))
        if cur >= delta:
            ids.append(i)
            cur = 0.0
    assert _first_crossings(np.diff(d), delta) == ids
    # all pairs: argmin over j > i, accepted if <= tol
    expected = []
    for i in range(d.size - 1):
        dfh = d[i + 1:] - d[i]
        k = int(np.argmin(np.abs(dfh - delta)))
        if abs(dfh[k] - delta) <= 0.1 * delta:
            expected.append((i, k + i + 1))
    try:
        got = id_pairs_from_delta(poses, delta, Unit.meters, 0.1, all_pairs=True)
    except ConfigError:
        assert expected == []
        return
    assert [tuple(x) for x in got.tolist()] == expected


# ----------------------------------------------------------------------------- files
def test_loaders_read_the_fixture_formats():
    tum = load_tum(DATA / "evo/V102.txt")
    csv = load_euroc(DATA / "evo/V102_groundtruth.csv")
    assert len(tum) == 807 and len(csv) == 16702
    first = next(x for x in (DATA / "evo/V102_groundtruth.csv").read_text().splitlines() if not x.startswith("#"))
    assert csv.stamps[0] == float(first.split(",")[0]) / 1e9  # as evo: ns / 1e9
    assert np.all(np.abs(np.linalg.norm(csv.poses.rotation.as_quat(), axis=1) - 1) < 1e-12)


@pytest.mark.parametrize("text,where", [
    ("# header\n0 1 2 3 0 0 0 1\n1 1 2 x 0 0 0 1\n", ":3: not a number"),
    ("0 1 2 3 0 0 0 1\n1 1 2 3 0 0 1\n", ":2: 7 values, expected 8"),
    ("0 1 2 3 0 0 0 1 5\n", "9 columns, expected 8"),
    ("# only a comment\n", "no poses"),
    ("0 1 2 3 0 0 0 0\n", "zero quaternion"),
    ("0 1 2 nan 0 0 0 1\n", ":1: non-finite"),
    ("0 1 2 3 0 0 0 1\n1 1 2 3 0 0 0 1 9\n", ":2: 9 values, the lines before have 8"),
    # commas: refused, not guessed (an 8-column EuRoC row, t[ns] and w first, would read as TUM without an error)
    ("t,x,y,z,qx,qy,qz,qw\n0,1,2,3,0,0,0,1\n", ":2: values separated by commas in '0,1,2,3,0,0,0,1': TUM 't tx ty tz "
                                             "qx qy qz qw' is separated by spaces (an EuRoC csv is fmt euroc)"),
    ("timestamp tx ty tz qx qy qz qw\n0 1 2 3 0 0 0 1\ntimestamp tx ty tz qx qy qz qw\n", ":3: not a number"),
])
def test_malformed_tum_is_one_clear_line(tmp_path, text, where):
    p = tmp_path / "bad.txt"
    p.write_text(text)
    with pytest.raises(InputFileError) as e:
        load_tum(p)
    msg = str(e.value)
    assert str(p) in msg and where in msg and "\n" not in msg


def test_missing_and_binary_files(tmp_path):
    with pytest.raises(InputFileError, match="no such file"):
        load_tum(tmp_path / "nope.txt")
    (tmp_path / "b.txt").write_bytes(b"\x89PNG\x00\xff\xfe")
    with pytest.raises(InputFileError, match=r"not a trajectory file \(binary data: a NUL byte at byte 4\)"):
        load_tum(tmp_path / "b.txt")
    (tmp_path / "k.txt").write_text("1 0 0 0 0 1 0 0 0 0 1\n")
    with pytest.raises(InputFileError, match="11 values, expected 12"):
        load_kitti(tmp_path / "k.txt")


def test_write_tum_round_trip_and_fixed_format(tmp_path):
    poses = random_traj(20, 3)
    stamps = 1700000000.0 + np.arange(20) * 0.05
    write_tum(tmp_path / "a.tum", stamps, poses)
    back = load_tum(tmp_path / "a.tum")
    np.testing.assert_allclose(back.stamps, stamps, atol=1e-9, rtol=0)
    assert back.poses.allclose(poses, atol=1e-8)
    lines = (tmp_path / "a.tum").read_text().splitlines()
    assert lines[0] == "# timestamp tx ty tz qx qy qz qw" and len(lines) == 21
    assert all(len(x.split(".")[-1]) == 9 for x in lines[1].split())
    assert all(float(x.split()[-1]) >= 0 for x in lines[1:])  # qw >= 0
    # integer nanoseconds are written exactly
    write_tum(tmp_path / "b.tum", np.array([1_700_000_000_123_456_789], np.int64), poses[:1])
    assert (tmp_path / "b.tum").read_text().splitlines()[1].startswith("1700000000.123456789 ")
    write_tum(tmp_path / "c.tum", np.zeros(0), None)
    assert (tmp_path / "c.tum").read_text() == "# timestamp tx ty tz qx qy qz qw\n"


def test_kitti_loader(tmp_path):
    poses = random_traj(5, 2)
    m = poses.as_matrix()[:, :3, :].reshape(5, 12)
    np.savetxt(tmp_path / "k.txt", m)
    k = load_kitti(tmp_path / "k.txt")
    assert k.stamps is None and k.poses.allclose(poses, atol=1e-12)


# ----------------------------------------------------------------------------- paper metrics
def test_paper_metrics_no_alignment_and_splits():
    n = 400
    gt = random_traj(n, 11)
    offset = np.array([0.03, 0.0, -0.04])  # 5 cm constant offset, no rotation error
    est = Pose(gt.rotation, gt.translation + offset)
    inside = np.zeros(n, bool)
    inside[:250] = True
    m = paper_metrics(np.arange(n) * 0.1, gt, est, inside)
    assert m["inside"]["frames"] == 250 and m["outside"]["frames"] == 150 and m["total"]["frames"] == 400
    for s in ("inside", "outside", "total"):
        assert m[s]["p_ate_m"] == pytest.approx(0.05, abs=1e-12)  # not aligned away
        assert m[s]["r_ate_deg"] == pytest.approx(0.0, abs=1e-6)
    # a world-frame offset does not change the relative error of a translation-only offset... in the
    # body frame it does: RE translation = |R_i^T offset - R_i^T offset| = 0 only for equal offsets
    assert m["total"]["p_re_m"] == pytest.approx(0.0, abs=1e-9)


def test_paper_metrics_re_pairs_go_to_the_split_of_their_start():
    n = 300
    gt = random_traj(n, 5)
    rng = np.random.default_rng(0)
    est = Pose(gt.rotation, gt.translation + np.cumsum(rng.normal(0, 0.002, (n, 3)), axis=0))
    inside = np.arange(n) < 120
    m = paper_metrics(np.arange(n) * 0.1, gt, est, inside)
    from phonepose.evaluation.paper import relative_translation_pairs

    starts, err = relative_translation_pairs(gt, est)
    assert m["inside"]["p_re_m"] == pytest.approx(np.sqrt(np.mean(err[starts < 120] ** 2)), rel=1e-12)
    assert m["outside"]["p_re_m"] == pytest.approx(np.sqrt(np.mean(err[starts >= 120] ** 2)), rel=1e-12)
    assert m["total"]["p_re_m"] == pytest.approx(np.sqrt(np.mean(err ** 2)), rel=1e-12)
    # pooled over the 5 default lengths, each pair exactly as rpg's RE (s = 1)
    from phonepose.evaluation.relative import default_lengths

    rel = relative_errors(gt, est, default_lengths(gt.translation))
    assert sum(len(r) for r in rel.values()) == starts.size


def test_paper_re_ignores_orientation_error_and_world_offsets():
    """The paper's p_RE (Table 5: T1 = T2 = T3) depends on positions only, after posyaw alignment."""
    from scipy.spatial.transform import Rotation

    from phonepose.evaluation.paper import relative_translation_pairs
    from phonepose.evaluation.relative import relative_errors

    n = 300
    gt = random_traj(n, 7)
    tilt = Rotation.from_rotvec([0.0, np.radians(11.0), 0.0])  # a hand-eye-like orientation offset
    yaw = Rotation.from_rotvec([0.0, 0.0, 0.3])
    est = Pose(gt.rotation * tilt, yaw.apply(gt.translation) + [0.04, -0.02, 0.01])
    _, err = relative_translation_pairs(gt, est)
    assert err.size > 0 and np.max(err) < 1e-9
    # rpg's RE translation does see the orientation offset (the displacement is taken in the start pose frame)
    rpg = relative_errors(gt, est, [1.0])
    assert max(np.max(r.trans) for r in rpg.values()) > 0.05
    # a known displacement error, exactly: one jump of 3 cm along z halfway, no rotation error
    jump = np.zeros((n, 3))
    jump[n // 2:, 2] = 0.03
    est2 = Pose(gt.rotation, gt.translation + jump)
    starts, err2 = relative_translation_pairs(gt, est2)
    from phonepose.evaluation.alignment import align

    a = align(gt, est2, "posyaw")
    p = a.apply(est2).translation
    from phonepose.evaluation.relative import accumulated_distances, default_lengths, find_pairs

    d = accumulated_distances(gt.translation)
    expected = []
    for L in default_lengths(gt.translation):
        s_, e_ = find_pairs(d, L)
        if e_.size >= 2:
            expected.append(np.linalg.norm((p[e_] - p[s_]) - (gt.translation[e_] - gt.translation[s_]), axis=1))
    assert np.allclose(err2, np.concatenate(expected), atol=1e-12)


def test_paper_metrics_empty_and_none():
    gt = random_traj(30, 1)
    m = paper_metrics(np.arange(30) * 0.1, gt, gt, np.ones(30, bool))
    assert m["outside"] == {"frames": 0, "p_ate_m": None, "r_ate_deg": None, "p_re_m": None}
    assert paper_metrics(np.zeros(0), None, None, np.zeros(0, bool))["total"]["frames"] == 0
    one = paper_metrics(np.zeros(1), gt[:1], gt[:1], np.ones(1, bool))
    assert one["total"]["frames"] == 1 and one["total"]["p_re_m"] is None


# ----------------------------------------------------------------------------- CLI
def test_cli_json_layout(cli):
    code, out, err = cli("evaluate", "--gt", str(DATA / "rpg/MH_04_stamped_groundtruth.txt"),
                             "--est", str(DATA / "rpg/MH_04_stamped_ba_estimate0.txt"), "--json")
    assert code == 0, err
    d = json.loads(out)
    assert d["n_matched"] == 187 and d["align"]["method"] == "posyaw"
    assert set(d["ate"]["trans_m"]) >= {"rmse", "mean", "median", "std", "min", "max"}
    assert list(d["re"]) == ["9.17", "18.34", "27.52", "36.69", "45.87"]
    assert set(d["re"]["9.17"]) >= {"trans_m", "trans_perc", "rot_deg", "yaw_deg", "gravity_deg"}
    assert d["ate"]["trans_m"]["rmse"] == pytest.approx(0.105614372, abs=5e-10)
    code, out, err = cli("evaluate", "--gt", str(DATA / "evo/V102_groundtruth.csv"), "--est",
                             str(DATA / "evo/V102.txt"), "--gt-format", "euroc", "--metric", "rpe", "--delta", "1",
                             "--delta-unit", "m", "--json")
    d = json.loads(out)
    assert d["rpe"]["num_samples"] == 72 and d["rpe"]["rmse"] == pytest.approx(0.060284, abs=5e-7)


def test_cli_rpg_quirks(cli):
    args = ["--gt", str(DATA / "evo/fr2_desk_groundtruth.txt"), "--est", str(DATA / "evo/fr2_desk_ORB.txt"),
            "--align", "se3", "--lengths", "2.03", "--json"]
    _, out, _ = cli("evaluate", *args)
    assert json.loads(out)["re"]["2.03"]["trans_m"]["rmse"] == pytest.approx(0.015502644, abs=5e-10)
    _, out, _ = cli("evaluate", *args, "--rpg-quirks")
    assert json.loads(out)["re"]["2.03"]["trans_m"]["rmse"] == pytest.approx(0.016630469, abs=5e-10)


def test_cli_table(cli):
    code, out, _ = cli("evaluate", "--gt", str(DATA / "evo/fr2_desk_groundtruth.txt"), "--est",
                           str(DATA / "evo/fr2_desk_ORB.txt"), "--metric", "ape", "--align", "se3")
    assert code == 0 and "2174 matched poses" in out and "0.00811898" in out
    # a .csv estimate with --gt-format euroc is read as EuRoC too: GT against itself
    code, out, _ = cli("evaluate", "--gt", str(DATA / "evo/V102_groundtruth.csv"), "--est",
                           str(DATA / "evo/V102_groundtruth.csv"), "--gt-format", "euroc", "--metric", "ape", "--json")
    assert code == 0 and json.loads(out)["ape"]["max"] == 0.0


@pytest.mark.parametrize("args,code,text", [
    (["--gt", "{evo}/V102.txt", "--est", "{evo}/V102.txt", "--align", "yaw"], 5, "--align"),
    (["--gt", "{evo}/V102.txt", "--est", "{evo}/V102.txt", "--metric", "ate"], 5, "--metric"),
    (["--gt", "{evo}/V102.txt", "--est", "{evo}/V102.txt", "--lengths", "1,x"], 5, "--lengths"),
    (["--gt", "{evo}/V102.txt", "--est", "{evo}/V102.txt", "--align", "sim3", "--align-frames", "1"], 5, "sim3"),
    (["--gt", "{evo}/V102_groundtruth.csv", "--est", "{evo}/V102.txt"], 2, "V102_groundtruth.csv:2"),
])
def test_cli_errors_are_one_line(cli, args, code, text):
    got, _, err = cli("evaluate", *[a.format(evo=DATA / "evo") for a in args])
    assert got == code
    *warnings, last = err.strip().splitlines()   # one error line, the last; warnings about the inputs before it
    assert text in last and last.startswith("phonepose: error: ")
    assert all(w.startswith("phonepose: warning: ") for w in warnings) and "Traceback" not in err


def test_cli_error_in_a_real_process():
    r = subprocess.run([sys.executable, "-m", "phonepose", "evaluate", "--gt", "missing.txt", "--est", "x.txt"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.strip() == "phonepose: error: missing.txt: no such file"


@pytest.mark.parametrize("max_rounds", [64, 1, 2])
def test_rpg_association_dense_irregular_stamps(monkeypatch, max_rounds):
    """Dense irregular stamps (many blocking candidates), also with the in-order fallback forced early."""
    import phonepose.evaluation.association as assoc

    monkeypatch.setattr(assoc, "_MAX_ROUNDS", max_rounds)
    rng = np.random.default_rng(3)
    te = np.sort(rng.uniform(0, 2, 300))
    tr = np.sort(te + rng.normal(0, 0.004, 300))
    i, j = associate_rpg(te, tr, 0.02)
    assert list(zip(i.tolist(), j.tolist(), strict=True)) == rpg_associate_loop(te, tr, 0.02)


def test_errors_in_blocks_are_the_whole_arrays_bits(monkeypatch):
    """Long inputs are computed BLOCK_ROWS rows at a time (bounded temporaries): the same bits as one pass."""
    from phonepose.evaluation import ate, relative, stats
    from phonepose.evaluation.paper import relative_translation_pairs

    n = 2 * stats.BLOCK_ROWS + 123
    gt = random_traj(n, 11)
    rng = np.random.default_rng(3)
    est = Pose(gt.rotation * Rotation.from_rotvec(rng.normal(0, 0.01, (n, 3))), gt.translation + rng.normal(0, 0.01, (n, 3)))
    inside = rng.random(n) < 0.5
    stamps = np.arange(n) * 0.05
    blocked = (ate.absolute_errors(gt, est), relative_translation_pairs(gt, est),
               find_pairs(relative.accumulated_distances(gt.translation), 1.0), paper_metrics(stamps, gt, est, inside))
    for module in (stats, ate, relative):
        monkeypatch.setattr(module, "BLOCK_ROWS", 10 * n, raising=False)
    whole = (ate.absolute_errors(gt, est), relative_translation_pairs(gt, est),
             find_pairs(relative.accumulated_distances(gt.translation), 1.0), paper_metrics(stamps, gt, est, inside))
    for b, w in zip(blocked[:3], whole[:3], strict=True):
        for x, y in zip(b, w, strict=True):
            assert x.dtype.kind == y.dtype.kind and np.array_equal(x, y)
    assert blocked[3] == whole[3]


@settings(deadline=None, max_examples=40)
@given(seed=st.integers(0, 2**32 - 1), block=st.integers(1, 400), bad_at=st.one_of(st.none(), st.integers(0, 59)))
def test_a_trajectory_parsed_in_blocks_is_the_whole_files_numbers(tmp_path_factory, seed, block, bad_at):
    """Blocks of any size (cut after a newline) give the same array, line numbers and first error as one block:
    the blocks keep the parse's memory to the text and the array."""
    from phonepose.evaluation import trajectory

    rng = np.random.default_rng(seed)
    lines = ["# timestamp tx ty tz qx qy qz qw"] if rng.random() < 0.5 else []
    for k in range(60):
        q = rng.normal(size=4)
        row = f"{k / 10:.1f} {rng.normal():.6f} {rng.normal():.6f} {rng.normal():.6f} " + " ".join(f"{v:.6f}" for v in q)
        if k == bad_at:
            row = row.replace(" ", " x", 1) if rng.random() < 0.5 else row + " 7"
        lines.append(row)
        if rng.random() < 0.2:
            lines.append(rng.choice(["", "# a comment", "   "]))
    text = (rng.choice(["\n", "\r\n", "\r"])).join(lines) + "\n"
    p = tmp_path_factory.mktemp("blocks") / "t.tum"
    p.write_text(text, newline="")

    def load():
        try:
            traj = load_tum(p)
            return traj.stamps.tolist(), traj.poses.translation.tolist(), traj.poses.rotation.as_quat().tolist()
        except InputFileError as exc:
            return str(exc)

    whole = load()
    saved = trajectory.PARSE_BLOCK_CHARS
    trajectory.PARSE_BLOCK_CHARS = block
    try:
        assert load() == whole
    finally:
        trajectory.PARSE_BLOCK_CHARS = saved
    if bad_at is None:
        assert len(whole[0]) == 60


def test_relative_errors_in_blocks_are_the_whole_arrays_bits():
    """RE pairs are computed BLOCK_ROWS at a time; each value equals the one computed over all pairs at once."""
    from phonepose.evaluation.relative import accumulated_distances, euler_zyx, find_pairs, pair_errors, relative_errors_at
    from phonepose.evaluation.stats import BLOCK_ROWS

    gt, est = random_traj(3 * BLOCK_ROWS + 77, 5), random_traj(3 * BLOCK_ROWS + 77, 6)
    d = accumulated_distances(gt.translation)
    L = float(d[-1] / 7)
    starts, ends = find_pairs(d, L)
    assert ends.size > 2 * BLOCK_ROWS
    r_w, t_w, r_e = pair_errors(gt, est, starts, ends, 1.03)
    got = relative_errors_at(gt, est, L, 1.03)
    assert np.array_equal(got.trans, np.sqrt(np.sum(t_w * t_w, axis=1)))
    rot = np.degrees(np.arccos(np.clip((np.trace(r_e, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)))
    assert np.array_equal(got.rot_deg, rot)
    yaw, pitch, roll = euler_zyx(r_w)
    assert np.array_equal(got.yaw_deg, np.abs(yaw) * 180.0 / np.pi)
    assert np.array_equal(got.gravity_deg, np.sqrt(pitch ** 2 + roll ** 2) * 180.0 / np.pi)
