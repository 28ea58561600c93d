"""A session opens in Rerun without phonepose: `rerun mcap convert` maps our Foxglove channels."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import rerun.chunk as rc

from phonepose.schemas.topics import Topic
from phonepose.testing.sample import sample_messages, write_sample


def _rerun_cli() -> str:
    exe = Path(sys.executable).parent / "rerun"
    return str(exe) if exe.exists() else shutil.which("rerun")


def test_rerun_mcap_convert_gives_encoded_image_and_pinhole(tmp_path):
    session = tmp_path / "s.mcap"
    write_sample(session)
    rrd = tmp_path / "s.rrd"
    env = dict(os.environ, RERUN_ANALYTICS="0")
    r = subprocess.run([_rerun_cli(), "mcap", "convert", str(session), "-o", str(rrd), "--application-id", "phonepose"],
                       capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    columns: dict[str, dict] = {}
    for chunk in rc.RrdReader(str(rrd)).stream().to_chunks():
        batch = chunk.to_record_batch()
        columns.setdefault(chunk.entity_path, {}).update({n: batch.column(n) for n in batch.schema.names})
    image = columns[Topic.CAMERA_IMAGE]
    jpeg = [m for t, m, _ in sample_messages() if t == Topic.CAMERA_IMAGE][0].data
    blob = image["EncodedImage:blob"].to_pylist()[0]
    assert bytes(blob[0] if isinstance(blob, list) and not isinstance(blob[0], int) else blob) == jpeg
    assert image["EncodedImage:media_type"].to_pylist()[0] in ("image/jpeg", ["image/jpeg"])
    pinhole = columns[Topic.CAMERA_CALIBRATION]
    k = pinhole["Pinhole:image_from_camera"].to_pylist()[0]
    k = k[0] if isinstance(k[0], list) else k
    # column-major 3x3: fx, 0, 0, 0, fy, 0, cx, cy, 1
    assert [round(v, 3) for v in k] == [500, 0, 0, 0, 500, 0, 319.5, 239.5, 1]
    res = pinhole["Pinhole:resolution"].to_pylist()[0]
    res = res[0] if isinstance(res[0], list) else res
    assert list(res) == [640, 480]
