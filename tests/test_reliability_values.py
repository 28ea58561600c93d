"""Values a user's files and options may hold: text inputs read within a bound, finite but absurd numbers
refused where they are read, never printed or written as metrics (docs/reliability.md, "Bad inputs tried").

The one-line errors themselves are cases of tests/test_reliability_cli.py (they generate the docs table);
these tests check what those cases cannot: what is still accepted, and how the checks read.
"""

from __future__ import annotations

import json
import math

import pytest

from phonepose.errors import InputFileError
from phonepose.files import read_text_input

BOM = b"\xef\xbb\xbf"
TUM = b"".join(b"%.1f %.3f %.3f 0 0 0 0 1\n" % (k / 10, k / 50, (k % 7) / 40) for k in range(40))


def test_read_text_input_stops_at_the_limit_and_at_the_first_nul(tmp_path):
    p = tmp_path / "t.txt"
    p.write_bytes(b"a" * 101)
    with pytest.raises(InputFileError, match=r"t\.txt: larger than 100 bytes, the most phonepose reads as a "
                                             r"trajectory file \(why\): check that it is the right file$"):
        read_text_input(p, "trajectory file", limit=100, note="why")
    assert read_text_input(p, "trajectory file", limit=101) == "a" * 101
    # a NUL far into the file (past the first chunk) is found where it is
    p.write_bytes(b"1 2 3\n" * 400_000 + b"\0" + b"x" * 10)
    with pytest.raises(InputFileError, match=r"not a trajectory file \(binary data: a NUL byte at byte 2400000\)$"):
        read_text_input(p, "trajectory file")
    p.write_bytes(BOM + "é\n".encode())
    assert read_text_input(p) == "é\n"


def test_a_byte_order_mark_is_accepted_in_tum_euroc_and_toml(tmp_path, cli):
    from phonepose.record.sim.config import load_config

    (tmp_path / "gt.txt").write_bytes(BOM + TUM)
    code, out, err = cli("evaluate", "--gt", tmp_path / "gt.txt", "--est", tmp_path / "gt.txt", "--json")
    assert code == 0 and err == "", err
    assert json.loads(out)["n_matched"] == 40
    csv = b"#timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z\n" + b"".join(
        b"%d,%.3f,0,0,1,0,0,0\n" % (k * 10**8, k / 50) for k in range(40))
    (tmp_path / "gt.csv").write_bytes(BOM + csv)
    code, out, err = cli("evaluate", "--gt", tmp_path / "gt.csv", "--est", tmp_path / "gt.csv", "--format", "euroc",
                         "--metric", "ape", "--json")
    assert code == 0 and err == "", err
    (tmp_path / "c.toml").write_bytes(BOM + b"[camera]\nrate_hz = 24\n")
    assert load_config(tmp_path / "c.toml").camera.rate_hz == 24


def test_a_non_finite_metric_is_never_printed_nor_written(tmp_path, cli, monkeypatch):
    """Whatever still overflows is one line, never a NaN in the table or a failing --json."""
    from phonepose.evaluation import evo_metrics

    real = evo_metrics.evaluate_ape

    def overflowing(*args, **kwargs):
        result = real(*args, **kwargs)
        result["ape"]["rmse"] = math.inf
        return result

    monkeypatch.setattr(evo_metrics, "evaluate_ape", overflowing)
    (tmp_path / "gt.txt").write_bytes(TUM)
    for extra in ((), ("--json",)):
        code, out, err = cli("evaluate", "--gt", tmp_path / "gt.txt", "--est", tmp_path / "gt.txt", "--metric", "ape",
                             *extra)
        assert code == 4 and out == "", out
        assert err.strip().endswith("gt.txt are not finite numbers (ape.rmse): check the trajectories' values and "
                                    "units"), err
        assert len(err.strip().splitlines()) == 1


def test_georeferenced_trajectories_still_load(tmp_path, cli):
    """UTM-like coordinates (northing 5.4e6 m) are within the bound, and evaluate as well as near the origin."""
    rows = b"".join(b"%.1f %.3f %.3f 310.5 0 0 0 1\n" % (k / 10, 500000 + k / 50, 5400000 + (k % 7) / 40)
                    for k in range(40))
    (tmp_path / "utm.txt").write_bytes(rows)
    code, out, err = cli("evaluate", "--gt", tmp_path / "utm.txt", "--est", tmp_path / "utm.txt", "--json")
    assert code == 0 and err == "", err
    assert json.loads(out)["ate"]["trans_m"]["rmse"] < 1e-6


@pytest.mark.parametrize("body, message", [
    (b"- 1\n- 2\n", r"not an OpenCV YAML/XML calibration file \(its top level is a list"),
    (b"camera_matrix: [[1,0,0],[0,1,0],[0,0,1]]\n", r"camera_matrix is not a matrix \(found a list"),
    (b"camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [1,0,0,0,1,0,0,0,1]\n"
     b"distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [0,0,0,0,0]\n"
     b"image_width: wide\nimage_height: 480\n", r"image_width is not a number \(found text\)$"),
    (b"camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [1,0,0,0,1,0,0,0,1]\n"
     b"distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [0,0,0,0,0]\n"
     b"image_width: 1e300\nimage_height: 480\n", r"image_width 1e\+300, image_height 480: expected whole pixels"),
])
def test_a_camera_calibration_file_is_read_node_by_node(tmp_path, body, message):
    from phonepose.calibration import load_calibration

    (tmp_path / "c.yaml").write_bytes(b"%YAML:1.0\n---\n" + body)
    with pytest.raises(InputFileError, match=message):
        load_calibration(tmp_path / "c.yaml")
