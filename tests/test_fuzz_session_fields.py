"""Fuzzing message field values: a valid session with random numeric fields set to NaN, inf, 0,
negative or huge values, replayed end to end. Only a clean run, warnings, or a PhoneposeError
(one line, its exit code) may come out; never another exception.
"""

from __future__ import annotations

import contextlib
import io
import math
import os

import pytest
from google.protobuf.descriptor import FieldDescriptor
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_reliability_cli import rewrite

from phonepose.schemas.topics import TOPIC_TYPES, Topic
from phonepose.testing.playback_session import write_test_session

FUZZ = settings(max_examples=int(os.environ.get("PHONEPOSE_FUZZ_FIELDS", "25")), deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])



@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A folder with the valid session every example mutates (good.mcap), and their outputs."""
    d = tmp_path_factory.mktemp("fieldfuzz")
    write_test_session(d / "good.mcap", duration_s=1.5)
    return d

_NUMERIC = {FieldDescriptor.TYPE_DOUBLE, FieldDescriptor.TYPE_FLOAT, FieldDescriptor.TYPE_INT32,
            FieldDescriptor.TYPE_INT64, FieldDescriptor.TYPE_UINT32, FieldDescriptor.TYPE_FIXED32}


def numeric_fields(descriptor, prefix=()):
    """Dotted paths of every numeric scalar field (repeated fields: element 0), recursively."""
    out = []
    for f in descriptor.fields:
        if f.type == FieldDescriptor.TYPE_MESSAGE:
            if f.message_type.full_name != "google.protobuf.Timestamp" and len(prefix) < 3 \
                    and not f.is_repeated:
                out += numeric_fields(f.message_type, prefix + (f.name,))
        elif f.type in _NUMERIC:
            out.append(prefix + (f.name,))
    return out


PLAYED = [Topic.CAMERA_CALIBRATION, Topic.CAMERA_EXTRINSICS, Topic.CONTROLLER_MARKER, Topic.GT_CALIBRATION,
          Topic.DISPLAY_VIO_POSE, Topic.CONTROLLER_VIO_POSE, Topic.DISPLAY_ANCHOR, Topic.CONTROLLER_ANCHOR,
          Topic.CONTROLLER_IMU, Topic.GT_CONTROLLER_POSE, Topic.CALIBRATION_EVENTS]
TARGETS = [(t, path) for t in PLAYED for path in numeric_fields(TOPIC_TYPES[t].DESCRIPTOR)]
VALUES = st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -1.0, 1e12, -1e-12, 7.0])


def _set(msg, path, value) -> None:
    for name in path[:-1]:
        msg = getattr(msg, name)
    f = msg.DESCRIPTOR.fields_by_name[path[-1]]
    if f.type not in (FieldDescriptor.TYPE_DOUBLE, FieldDescriptor.TYPE_FLOAT):
        if not math.isfinite(value):
            value = -1
        value = int(max(-2**31, min(2**31 - 1, value)))
        if f.type in (FieldDescriptor.TYPE_UINT32, FieldDescriptor.TYPE_FIXED32):
            value = abs(value)
    if f.is_repeated:
        field = getattr(msg, path[-1])
        if len(field):
            field[0] = value
    else:
        setattr(msg, path[-1], value)


@FUZZ
@given(target=st.sampled_from(TARGETS), value=VALUES, every=st.sampled_from([1, 3, 50]))
def test_random_field_values_give_a_result_or_our_error(work, target, value, every):
    from phonepose.cli import main

    topic, path = target
    seen = {"n": 0}

    def mutate(t, msg, log_time):
        if t == topic:
            if seen["n"] % every == 0:
                _set(msg, path, value)
            seen["n"] += 1
        return [(t, msg, log_time)]

    bad = rewrite(work / "good.mcap", work / "bad.mcap", mutate)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            main(["playback", str(bad), "-q", "-t", "T1", "-t", "T4", "-t", "T7", "--out", str(work / "out")])
            code = 0
        except SystemExit as exc:
            code = exc.code or 0
    text = err.getvalue()
    assert "Traceback" not in text
    if code != 0:
        lines = text.strip().splitlines()
        assert code in (3, 4, 5, 6) and lines and lines[-1].startswith("phonepose: error: "), text
