"""One command line: an option name means one thing on every command, every long-running command takes
-q/--quiet, every command's --help shows an example that parses."""

from __future__ import annotations

import re
import shlex

import pytest
from hypothesis import given
from hypothesis import strategies as st

from phonepose.cli import command, options
from phonepose.cli.output import progress_lines


def _is_group(c) -> bool:   # typer from 0.26 on runs its own copy of click: no isinstance with click's classes
    return hasattr(c, "commands")


def _tree(c, path: tuple[str, ...] = ()):
    yield path, c
    for name, sub in getattr(c, "commands", {}).items():
        yield from _tree(sub, (*path, name))


COMMANDS = {" ".join(path): c for path, c in _tree(command())}
LEAVES = {name: c for name, c in COMMANDS.items() if not _is_group(c)}
# the commands that take seconds to hours; each takes -q/--quiet
LONG_RUNNING = ("record sim", "record live", "record rehearse", "playback", "batch", "experiment exp1",
                "experiment exp2", "demo", "recover", "calibrate-camera", "calibrate-gt", "calibrate-hand-eye")


def _options():
    """(command, option) for every option of every command but --help."""
    for name, c in LEAVES.items():
        for p in c.params:
            if p.param_type_name == "option" and "--help" not in p.opts:
                yield name, p


def _kind(p) -> str:
    """What an option takes: a flag, or a value (repeatable or not)."""
    return "flag" if p.is_flag else "values" if p.multiple else "value"


def test_every_option_name_has_one_kind_on_every_command():
    """A name (long or short) is a flag everywhere, or takes one value everywhere, or a list everywhere."""
    kinds: dict[str, set[tuple[str, str]]] = {}
    for name, p in _options():
        for opt in p.opts + p.secondary_opts:
            kinds.setdefault(opt, set()).add((_kind(p), name))
    mixed = {opt: sorted(k) for opt, k in kinds.items() if len({kind for kind, _ in k}) > 1}
    assert mixed == {}


def test_a_short_name_stands_for_one_long_name():
    shorts: dict[str, set[str]] = {}
    for _, p in _options():
        longs = [o for o in p.opts if o.startswith("--")]
        for short in (o for o in p.opts if not o.startswith("--")):
            shorts.setdefault(short, set()).update(longs)
    assert {s: sorted(longs) for s, longs in shorts.items() if len(longs) != 1} == {}
    assert shorts["-t"] == {"--tracker"} and shorts["-j"] == {"--workers"} and shorts["-q"] == {"--quiet"}


def test_an_option_has_one_long_name():
    """No aliases: --x/--no-x pairs aside, an option is spelled one way."""
    aliased = [(name, p.opts) for name, p in _options() if len([o for o in p.opts if o.startswith("--")]) != 1]
    assert aliased == []


@pytest.mark.parametrize("old, new", [("--hand-eye", None), ("--jobs", "--workers"), ("--format", "--gt-format"),
                                      ("--device", "--camera")])
def test_the_renamed_options_are_gone(old, new):
    using = sorted(name for name, p in _options() if old in p.opts)
    assert using == []
    if new is not None:
        assert any(new in p.opts for _, p in _options())


def test_tracker_selects_wherever_it_is_taken():
    """--tracker/-t is the list of trackers that run; the experiments (always T1-T8) take --add-tracker."""
    takers = {name for name, p in _options() if "--tracker" in p.opts}
    assert takers == {"playback", "batch", "record live", "record rehearse"}
    assert {name for name, p in _options() if "--add-tracker" in p.opts} == {"experiment exp1", "experiment exp2"}


@pytest.mark.parametrize("name", LONG_RUNNING)
def test_every_long_running_command_takes_quiet(name):
    quiet = [p for p in LEAVES[name].params if "--quiet" in p.opts]
    assert len(quiet) == 1 and quiet[0].opts == ["--quiet", "-q"] and quiet[0].is_flag
    assert quiet[0].help in (options.QUIET["help"], options.QUIET_ACCEPTED["help"])


def test_the_long_running_list_is_every_command_with_progress():
    """A command that has -q is in LONG_RUNNING (the list the help and the docs promise)."""
    assert sorted(name for name, c in LEAVES.items() if any("--quiet" in p.opts for p in c.params)) \
        == sorted(LONG_RUNNING)


def _examples(help_text: str) -> list[list[str]]:
    """The command lines of a help's "Example:" paragraph (``a && b``: two)."""
    para = next(p for p in help_text.split("\n\n") if p.startswith("Example:"))
    shown = re.search(r"\[bold\](.*?)\[/bold\]", para)
    assert shown is not None, para
    return [shlex.split(line) for line in shown.group(1).split("&&")]


@pytest.mark.parametrize("name", sorted(COMMANDS), ids=lambda n: n or "phonepose")
def test_every_help_has_an_example_that_parses(name):
    """Each example names existing options with valid values: click parses it as the command would."""
    c = COMMANDS[name]
    examples = _examples(c.help or "")
    assert examples
    for argv in examples:
        assert argv[0] == "phonepose", argv
        words = argv[1:]
        target, path = command(), []
        while _is_group(target) and words and words[0] in target.commands:
            path.append(words[0])
            target = target.commands[words.pop(0)]
        assert argv is examples[-1] or path, argv
        if argv is examples[0]:
            assert " ".join(path).startswith(name), (name, argv)    # a command's example runs that command
        if _is_group(target):
            assert words == [], argv
            continue
        ctx = target.make_context(" ".join(path), words)           # exits 2 on an unknown option or a bad value
        ctx.close()


LINES = st.text(st.characters(blacklist_categories=("Cs", "Cc")), max_size=40)


@given(st.lists(st.tuples(st.booleans(), LINES), max_size=8), st.booleans(), st.booleans())
def test_quiet_keeps_the_warnings_among_the_progress_lines(lines, quiet, stamp):
    import contextlib
    import io

    lines = [(warn, ("  record live: warning: " if warn else "step ") + text.replace("warning: ", ""))
             for warn, text in lines]
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        echo = progress_lines(quiet, stamp=stamp)
        for _, line in lines:
            echo(line)
    printed = err.getvalue().split("\n")[:-1]
    expected = [line for warn, line in lines if warn or not quiet]
    if stamp:
        assert all(re.match(r"\[\d\d:\d\d:\d\d\] ", p) for p in printed)
        printed = [p[11:] for p in printed]
    assert printed == expected


def _documented_command_lines() -> list[tuple[str, str]]:
    """(file, line) for each concrete ``phonepose ...`` command in the code blocks of README.md and docs/*.md
    (a synopsis with [optional] or <placeholder> parts, or shell variables, left out)."""
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    found = []
    for f in [root / "README.md", *sorted((root / "docs").glob("*.md"))]:
        for block in re.findall(r"```(?:bash|sh|console)?\n(.*?)```", f.read_text(encoding="utf-8"), re.S):
            for line in block.replace("\\\n", " ").splitlines():
                line = line.split("  #")[0].split(" # ")[0].strip()
                for part in (p.strip() for p in re.split(r"&&|;|\|", line)):
                    if part.startswith("phonepose ") and not any(c in part for c in "[<$") and "..." not in part:
                        found.append((f.name, part))
    return found


DOCUMENTED = _documented_command_lines()


def test_the_docs_show_commands():
    assert len(DOCUMENTED) >= 40


@pytest.mark.parametrize("doc, line", DOCUMENTED, ids=[f"{d}: {line}" for d, line in DOCUMENTED])
def test_every_documented_command_parses(doc, line):
    """The docs name only options that exist, with values they take."""
    words = shlex.split(line)[1:]
    target, path = command(), []
    while _is_group(target) and words and words[0] in target.commands:
        path.append(words[0])
        target = target.commands[words.pop(0)]
    if _is_group(target) or "--help" in words or "--version" in words:
        return
    target.make_context(" ".join(path), words).close()
