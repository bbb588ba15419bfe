"""The one error convention of every `vid2sim` command.

A user error (a bad option or argument, a missing or unreadable input, a config value out of
range, any error type the project defines, a `ValueError`) ends the command with exit status 2
and one line on stderr, `error: INPUT: REASON`; with `--json` a JSON object also goes to stdout:
`{"error": {"type", "input", "reason", "message"}, "exit_code": 2}`. Anything else is a bug and
keeps its traceback. `VID2SIM_TRACEBACK=1` re-raises user errors too (for debugging).

`ConventionGroup` is the click group class of the top-level app: it wraps the whole invocation,
so sub-apps and commands only raise.
"""

from __future__ import annotations

import gc
import json
import os
import sys
from dataclasses import asdict, dataclass
from typing import Any, Optional, Sequence

import typer
from typer._click import exceptions as click  # the click typer vendors: its usage errors
from typer.core import TyperGroup

USER_EXIT = 2
PATH_ERRORS = (FileNotFoundError, NotADirectoryError, IsADirectoryError, FileExistsError, PermissionError)


class InputError(ValueError):
    """A command refuses one of its inputs: `input` names it (an option, argument or path)."""

    def __init__(self, input: str, reason: str) -> None:
        self.input, self.reason = input, reason
        super().__init__(f"{input}: {reason}")


@dataclass(frozen=True)
class ErrorReport:
    """What the user sees of one error."""

    type: str
    input: Optional[str]
    reason: str

    @property
    def message(self) -> str:
        return f"{self.input}: {self.reason}" if self.input else self.reason

    def to_json(self) -> dict:
        return {"error": {**asdict(self), "message": self.message}, "exit_code": USER_EXIT}


def one_line(text: Any) -> str:
    """Whitespace (newlines included) collapsed: a message fits one line."""
    return " ".join(str(text).split())


def is_user_error(exc: BaseException) -> bool:
    """An error of the input, not of the code: click usage errors, project-defined errors, ValueError,
    a missing or unwritable path."""
    if isinstance(exc, (click.ClickException, ValueError) + PATH_ERRORS):
        return True
    return any(k.__module__.startswith("vid2sim.") for k in type(exc).__mro__ if issubclass(k, Exception))


def _param_hint(exc: click.ClickException) -> Optional[str]:
    param = getattr(exc, "param", None)
    if param is not None:
        opts = [o for o in param.opts if o.startswith("--")] or param.opts
        return opts[0] if param.param_type_name == "option" and opts else (param.name or "").upper()
    hint = getattr(exc, "param_hint", None) or getattr(exc, "option_name", None)
    return one_line(hint if isinstance(hint, str) else " / ".join(hint)) if hint else None


def _click_reason(exc: click.ClickException) -> str:
    if isinstance(exc, click.MissingParameter):
        return "missing (required)"
    if isinstance(exc, click.NoSuchOption):
        close = f"; did you mean {', '.join(exc.possibilities)}?" if exc.possibilities else ""
        return f"no such option{close}"
    if isinstance(exc, click.BadParameter):
        return one_line(exc.message) or "invalid value"
    return one_line(exc.format_message())


def report_of(exc: BaseException) -> ErrorReport:
    """The input and reason a user error names."""
    name = type(exc).__name__
    if isinstance(exc, click.ClickException):
        return ErrorReport(name, _param_hint(exc), _click_reason(exc))
    if isinstance(exc, InputError):
        return ErrorReport(name, exc.input, one_line(exc.reason))
    reason = getattr(exc, "reason", None)
    path = getattr(exc, "path", None) or getattr(exc, "filename", None)
    if isinstance(reason, str) and path:
        return ErrorReport(name, str(path), one_line(reason))
    if isinstance(exc, PATH_ERRORS) and exc.filename:
        return ErrorReport(name, str(exc.filename), one_line(exc.strerror or exc))
    text = one_line(exc) or name
    if isinstance(exc, KeyError) and len(exc.args) == 1:
        text = one_line(exc.args[0])
    return ErrorReport(name, None, text)


def wants_json(argv: Sequence[str]) -> bool:
    """`--json` among the options (before any `--`)."""
    args = list(argv)
    return "--json" in (args[:args.index("--")] if "--" in args else args)


def emit(rep: ErrorReport, as_json: bool) -> int:
    """Print the report (stderr line, and the JSON object on stdout with --json); the exit status."""
    typer.secho(f"error: {rep.message}", fg="red", err=True)
    if as_json:
        typer.echo(json.dumps(rep.to_json()))
    return USER_EXIT


class ConventionGroup(TyperGroup):
    """The top-level group: runs the command line and reports every user error by the convention."""

    def main(self, args: Optional[Sequence[str]] = None, prog_name: Optional[str] = None,
             complete_var: Optional[str] = None, standalone_mode: bool = True, **extra: Any) -> Any:
        argv = list(sys.argv[1:] if args is None else args)
        code = self._run(argv, prog_name, complete_var, **extra)
        if standalone_mode:
            sys.exit(code)
        return code

    def _run(self, argv: list[str], prog_name: Optional[str], complete_var: Optional[str], **extra: Any) -> int:
        rep = None
        try:
            rv = super().main(argv, prog_name, complete_var, standalone_mode=False, **extra)
            return rv if isinstance(rv, int) else 0
        except click.NoArgsIsHelpError as e:
            e.show()
            return e.exit_code
        except typer.Abort:
            typer.echo("Aborted!", err=True)
            return 1
        except Exception as e:
            if not is_user_error(e) or os.environ.get("VID2SIM_TRACEBACK") == "1":
                raise
            rep, parsing = report_of(e), isinstance(e, click.ClickException)
        if not parsing:  # the command ran: free the frames of its traceback now (Delta/Arrow objects
            gc.collect()  # left to interpreter teardown can abort the process from their native threads)
        return emit(rep, wants_json(argv))
