"""The library speaks Python: an error or warning outside phonepose/cli/ names a parameter as the API
names it (``rate``), and the command line alone shows its option (``--rate``) through cli/flags.py."""

from __future__ import annotations

import ast
import pickle
import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

import phonepose
from phonepose.cli import flags
from phonepose.errors import NO_VALUE, ConfigError, OutputError, PhoneposeError, TrackerError, keyword
from phonepose.files import OutputPlan

PACKAGE = Path(phonepose.__file__).parent
FLAG = re.compile(r"(?<![\w-])--[A-Za-z]")

# Text that is not phonepose's message to its caller: arguments for other programs, and lines quoting a whole
# shell command to run. Each entry: module, a literal's start ("SWITCH": a literal that is one switch alone).
SWITCH = re.compile(r"--[a-z][a-z_-]*(=\S*)?")
NOT_A_MESSAGE = {
    ("record/rehearse/browser.py", "SWITCH"),                   # Chromium's own command-line switches
    ("record/rehearse/browser.py", "IWER (the npm package iwer)"),  # `npm ci --prefix ...`, npm's option
    ("schemas/regenerate.py", "SWITCH"),                        # protoc's arguments
    ("viewer/sink.py", "--bind"),                               # the Rerun viewer's argument
    ("session/index.py", " --out FIXED.mcap`"),                 # `phonepose recover FILE --out FIXED.mcap`, quoted whole
    ("record/rehearse/__init__.py", "record live --camera"),    # the command a rehearsal stands for, quoted whole
    ("record/rehearse/score.py", "playback --tracker all"),     # the same, for the playbacks it runs
    ("experiments/exp2.py", "Ground truth"),                    # the report's notes on how its table was made
    ("experiments/exp2.py", "Exact ground truth"),
}


def _docstrings(tree: ast.AST) -> set[int]:
    """ids of the string constants that are docstrings or bare string statements (comments)."""
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str):
            found.add(id(node.value))
    return found


def flag_literals(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every string literal, f-string parts included, that names a --flag."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = _docstrings(tree)
    return [(node.lineno, node.value) for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip
            and FLAG.search(node.value)]


LIBRARY = sorted(p for p in PACKAGE.rglob("*.py") if p.relative_to(PACKAGE).parts[0] != "cli")


def test_the_scan_sees_flags_in_f_string_parts_and_skips_docstrings():
    tree_text = 'def f(rate):\n    """--rate in a docstring"""\n    raise ValueError(f"--rate {rate} bad")\n'
    src = PACKAGE.parent / "build-scan-probe.py"
    try:
        src.write_text(tree_text)
        assert flag_literals(src) == [(3, "--rate ")]
    finally:
        src.unlink()


@pytest.mark.parametrize("path", LIBRARY, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_no_library_module_names_a_command_line_flag(path):
    module = path.relative_to(PACKAGE).as_posix()
    found = [(line, text) for line, text in flag_literals(path)
             if not any(module == m and (SWITCH.fullmatch(text) if start == "SWITCH" else text.startswith(start))
                        for m, start in NOT_A_MESSAGE)]
    assert found == []


def _one_line(exc: PhoneposeError) -> str:
    text = str(exc)
    assert "--" not in text and "\n" not in text
    return text


def test_play_names_rate(tmp_path):
    with pytest.raises(ConfigError) as e:
        phonepose.play(tmp_path / "s.mcap", rate=0)
    assert (_one_line(e.value), e.value.parameter, e.value.value) == (
        "rate 0: expected a finite number in [0.1, 1000] Hz", "rate", 0)
    assert flags.message(e.value) == "--rate 0: expected a finite number in [0.1, 1000] Hz"


@pytest.mark.parametrize(("kwargs", "parameter", "cli_start"), [
    (dict(align="nope"), "align", "--align 'nope': expected one of"),
    (dict(align_frames=0), "align_frames", "--align-frames 0: expected"),
    (dict(fmt="xyz"), "fmt", "--gt-format 'xyz': expected one of"),
    (dict(delta_unit="q"), "delta_unit", "--delta-unit 'q': expected one of"),
    (dict(delta=-1.0), "delta", "--delta -1: expected"),
])
def test_evaluate_names_its_keyword(tmp_path, kwargs, parameter, cli_start):
    with pytest.raises(ConfigError) as e:
        phonepose.evaluate(tmp_path / "gt.tum", tmp_path / "est.tum", **kwargs)
    text = _one_line(e.value)
    assert e.value.parameter == parameter and text.startswith(parameter + " ")
    assert flags.message(e.value).startswith(cli_start)


def test_an_output_in_a_missing_folder_names_out(tmp_path):
    plan = OutputPlan()
    plan.dir(tmp_path / "no" / "such", "out")
    with pytest.raises(OutputError) as e:
        plan.check()
    assert _one_line(e.value) == f"out {tmp_path / 'no' / 'such'}: directory {tmp_path / 'no'} does not exist"
    assert (e.value.parameter, e.value.value) == ("out", tmp_path / "no" / "such")
    assert flags.message(e.value) == f"--out {tmp_path / 'no' / 'such'}: directory {tmp_path / 'no'} does not exist"


def test_record_sim_names_trial(tmp_path):
    with pytest.raises(ConfigError) as e:
        phonepose.record_sim(tmp_path / "s.mcap", trial=7)
    assert _one_line(e.value) == "trial must be 1, 2 or 3, got 7" and e.value.expected == "1, 2 or 3"
    assert flags.message(e.value) == "--trial must be 1, 2 or 3, got 7"


def test_a_session_is_kept_unless_force_true(tmp_path):
    s = tmp_path / "s.mcap"
    s.write_bytes(b"old")
    with pytest.raises(OutputError) as e:
        phonepose.record_sim(s)
    assert _one_line(e.value) == f"{s} already exists: choose another out, or add force=True to replace it"
    assert flags.message(e.value) == f"{s} already exists: choose another --out, or add --force to replace it"


keywords = st.from_regex(r"[a-z][a-z0-9]{0,6}(_[a-z0-9]{1,6}){0,2}", fullmatch=True)


@given(keywords, st.text(max_size=20), st.sampled_from([ConfigError, OutputError, PhoneposeError]))
def test_a_placeholder_becomes_the_keyword_or_the_option(name, value, cls):
    """Rendering replaces exactly the declared keywords; the value's own text (braces too) stays; the fields
    survive pickling (a worker process sends errors back)."""
    exc = cls(f"{{{name}}} {value}: bad {{{name}=True}}", parameter=name, value=value, expected="good")
    assert str(exc) == f"{name} {value}: bad {name}=True"
    option = "--" + name.replace("_", "-") if name not in flags.FLAGS else flags.FLAGS[name]
    assert flags.message(exc) == f"{option} {value}: bad {option}"
    back = pickle.loads(pickle.dumps(exc))
    assert (type(back), str(back), back.parameter, back.value, back.expected, back.also) == \
        (cls, str(exc), name, value, "good", ())


def test_undeclared_braces_and_plain_errors_stay_as_written():
    assert str(ConfigError("{rate} and {x}", parameter="rate")) == "rate and {x}"
    assert str(ConfigError("{rate} as written")) == "{rate} as written"
    plain = PhoneposeError("no parameter")
    assert (plain.parameter, plain.value, plain.expected, flags.message(plain)) == (None, NO_VALUE, None,
                                                                                   "no parameter")
    t = pickle.loads(pickle.dumps(TrackerError("{tick_timeout} 1 s", "T9", parameter="tick_timeout")))
    assert (str(t), t.tracker, flags.message(t)) == ("tick_timeout 1 s", "T9", "--tick-timeout 1 s")


def test_a_warning_names_the_keyword_outside_the_cli(cli, tmp_path):
    assert keyword("marker_size_m") == "marker_size_m"
    assert cli("playback", tmp_path / "missing.mcap", "--rate", "0").stderr.startswith("phonepose: error: --rate 0")
    assert keyword("marker_size_m") == "marker_size_m"


def _keywords_named() -> set[str]:
    """Every keyword a library message names: parameter=/also= constants, check_number's and keyword()'s
    first word, and the outputs' parameter names."""
    found: set[str] = set()
    for path in LIBRARY:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.Call):
                continue
            for k in node.keywords:
                if k.arg in ("parameter", "force_parameter") and isinstance(k.value, ast.Constant) and k.value.value:
                    found.add(k.value.value)
                if k.arg == "also" and isinstance(k.value, (ast.List, ast.Tuple)):
                    found |= {e.value for e in k.value.elts if isinstance(e, ast.Constant)}
            name = node.func.id if isinstance(node.func, ast.Name) else getattr(node.func, "attr", "")
            args = [a.value for a in node.args if isinstance(a, ast.Constant) and isinstance(a.value, str)]
            if name in ("keyword", "check_number") and args and args[0].split()[0].isidentifier():
                found.add(args[0].split()[0])
            if name in ("file", "dir", "check_output", "write_text_output") and len(node.args) >= 2 \
                    and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str):
                found.add(node.args[1].value)
    return found


def _options() -> set[str]:
    """Every long option some command defines (click's own list, from the app)."""
    import click
    import typer

    from phonepose.cli import app

    def walk(cmd: click.Command) -> set[str]:
        opts = {o for p in cmd.params for o in p.opts if o.startswith("--")}
        for sub in getattr(cmd, "commands", {}).values():
            opts |= walk(sub)
        return opts
    return walk(typer.main.get_command(app))


def test_every_keyword_a_library_message_names_is_an_option_of_the_command_line():
    options = _options()
    named = _keywords_named()
    assert {"rate", "out", "align_frames", "params", "trackers"} <= named   # the scan finds them
    assert {k: flags.flag(k) for k in named if flags.flag(k) not in options} == {}
    for command, table in flags.COMMAND_FLAGS.items():
        assert set(table.values()) <= options, command
