"""The one place where the library's parameter names become command-line options.

A library error names the keyword at fault (:class:`phonepose.errors.PhoneposeError`'s ``parameter``,
``rate``); the CLI prints the same line with its option (``--rate``): ``align_frames`` is
``--align-frames``, :data:`FLAGS` lists the options whose name is not the keyword's, and
:data:`COMMAND_FLAGS` those that differ in one command.
"""

from __future__ import annotations

from phonepose.errors import PhoneposeError

#: keyword -> option, where the option is not ``--`` + the keyword with ``-`` for ``_``
FLAGS: dict[str, str] = {
    "params": "--param",
    "unit_timeout_s": "--unit-timeout",
    "no_worker_timeout_s": "--keep-waiting",   # execute_batch(no_worker_timeout_s=None): wait for ever
    "replace": "--force",        # recover(path, out, replace=True)
    "fmt": "--gt-format",              # evaluate(fmt=...)
    "trackers": "--tracker",
    "device": "--camera",                # calibrate_camera(device=N)
    "marker_size_m": "--marker-size",
    "duration_s": "--duration",
    "lead_in_s": "--lead-in",
}


#: command (its words after ``phonepose``) -> keyword -> option, where that command names it otherwise
COMMAND_FLAGS: dict[str, dict[str, str]] = {
    "experiment": {"trackers": "--add-tracker"},   # the experiments always run T1-T8: a tracker is added
}

_command: list[str] = []   # the running command's words (set_command)


def set_command(argv: list[str]) -> None:
    """The command the next lines are for: its leading words (``experiment exp1``), options excluded."""
    words = []
    for arg in argv:
        if arg.startswith("-"):
            break
        words.append(arg)
    _command[:] = words[:2]


def flag(parameter: str) -> str:
    """The command-line option of a library keyword (in the running command, see set_command)."""
    for n in range(len(_command), 0, -1):
        found = COMMAND_FLAGS.get(" ".join(_command[:n]), {}).get(parameter)
        if found:
            return found
    return FLAGS.get(parameter) or "--" + parameter.replace("_", "-")


def option(parameter: str, _as_python: str = "") -> str:
    """A placeholder of an error's message as the command line shows it (see PhoneposeError.render)."""
    return flag(parameter)


def message(exc: BaseException) -> str:
    """An error's line as the command line says it: each keyword it names shown as its option."""
    if isinstance(exc, PhoneposeError):
        return exc.render(option)
    return str(exc)
