"""``phonepose info`` from the command line."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from phonepose.testing.sample import sample_messages, write_sample


def test_version():
    """In a real process: the console script's entry point (``python -m phonepose``) itself."""
    from phonepose import __version__

    r = subprocess.run([sys.executable, "-m", "phonepose", "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip() == f"phonepose {__version__}"


def test_info_json(tmp_path, cli):
    path = tmp_path / "s.mcap"
    write_sample(path)
    r = cli("info", str(path), "--json")
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert data["messages"] == len(sample_messages())
    topics = {c["topic"]: c for c in data["channels"]}
    assert topics["/display/camera/image"]["schema"] == "foxglove.CompressedImage"
    assert topics["/controller/imu"]["schema"] == "phonepose.Imu"
    assert data["duration_s"] == pytest.approx((len(sample_messages()) - 1) * 1e-6)


@pytest.mark.parametrize("content,message", [(None, "no such file"), (b"", "empty file"),
                                             (b"not mcap at all", "not an MCAP file")])
def test_info_bad_file_is_one_line_and_nonzero(tmp_path, content, message, cli):
    path = tmp_path / "bad.mcap"
    if content is not None:
        path.write_bytes(content)
    r = cli("info", str(path))
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0
    assert message in r.stderr and "Traceback" not in r.stderr


def test_info_truncated_file_points_to_recover(tmp_path, cli):
    path = tmp_path / "s.mcap"
    write_sample(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    r = cli("info", str(path))
    assert r.returncode == 3
    assert "recover" in r.stderr and "Traceback" not in r.stderr


def test_info_shows_the_task_window(tmp_path, cli):
    """What playback scores, and what --start/--end must overlap (seconds after the session start)."""
    from phonepose.testing.playback_session import write_test_session

    path = tmp_path / "s.mcap"
    write_test_session(path, duration_s=2.0, camera=False)
    r = cli("info", str(path))
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[1] == "task window 0.30-1.80 s (seconds after the start)"
    assert json.loads(cli("info", str(path), "--json").stdout)["task_window_s"] == [0.3, 1.8]


EVIL = "\x1b]0;PWNED\x07\x1b[2J\x1b[31mRED\nfake line\r\b\u202e [bold]x"


def _evil_session(path):
    """What anyone can write: topic, schema and encoding names with escape sequences, a newline, U+202E
    and rich markup."""
    from mcap.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        schema = w.register_schema(EVIL, EVIL, b"{}")
        channel = w.register_channel(EVIL, EVIL, schema)
        for k in range(5):
            w.add_message(channel, log_time=k * 10**8, publish_time=k * 10**8, data=b"{}")
        w.finish()
    return path


@pytest.mark.parametrize("command", ["info", "recover"])
def test_a_sessions_own_text_is_shown_not_obeyed(tmp_path, cli, command):
    """No escape sequence reaches the terminal, every row stays one line, markup is shown as written."""
    from phonepose.text import printable

    evil = _evil_session(tmp_path / "evil.mcap")
    args = ["info", str(evil)] if command == "info" else ["recover", str(evil), "-o", str(tmp_path / "r.mcap")]
    code, out, err = cli(*args)
    assert code == 0, err
    assert "\x1b" not in out and "\x07" not in out and "\u202e" not in out and "\r" not in out
    shown = printable(EVIL)
    assert shown == "\\x1b]0;PWNED\\x07\\x1b[2J\\x1b[31mRED\\nfake line\\r\\x08\\u202e [bold]x"
    rows = [line for line in out.splitlines() if "PWNED" in line]
    assert len(rows) == 1 and rows[0].count(shown) == (3 if command == "info" else 1), out


def test_an_error_quoting_a_sessions_text_stays_one_safe_line(tmp_path, cli):
    """playback's error names the schema the file gives /controller/vio/pose: anyone's text, shown escaped."""
    from mcap.writer import Writer

    from phonepose.text import printable

    path = tmp_path / "s.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        channel = w.register_channel("/controller/vio/pose", "protobuf", w.register_schema(EVIL, "protobuf", b""))
        for k in range(5):
            w.add_message(channel, log_time=k * 10**8, publish_time=k * 10**8, data=b"")
        w.finish()
    code, _, err = cli("playback", str(path), "-q", "-t", "T1", "-o", str(tmp_path / "o"))
    assert code == 4 and err.count("\n") == 1 and "\x1b" not in err and "\r" not in err, err
    assert f"has schema '{printable(EVIL)}'" in err
