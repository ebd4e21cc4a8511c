"""The ``scaletwin`` command line. Each subcommand lives in its own module of this package, which defines
``register(subparsers)``; modules are discovered, so adding a command means adding a module.

``register`` only declares arguments: a command module imports nothing heavier than the standard library at module
level (numpy, torch, MuJoCo, pandas, rich... are imported inside its ``run``), so ``scaletwin --help`` and argument
errors answer at once; tests/test_cli_behaviour.py checks it.

Output piped into a reader that stops early (``scaletwin predict ... | head -3``) ends the command quietly with exit
code :data:`BROKEN_PIPE_EXIT`, as the Python documentation recommends (`signal` module, "Note on SIGPIPE").
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
from collections.abc import Sequence

HELPER_MODULES = {"common"}  # modules of this package that are not commands
#: Exit code when stdout's reader went away before the command finished writing (the Python docs' choice).
BROKEN_PIPE_EXIT = 1


class CommandError(Exception):
    """A user-facing error: printed as one line, exit code 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="scaletwin", description="Scale calibrated digital twins across sizes.")
    parser.add_argument("--version", action="version", version="scaletwin 0.1.0")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
        if info.name not in HELPER_MODULES and not info.name.startswith("_"):
            importlib.import_module(f"{__name__}.{info.name}").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    try:
        return _main(argv)
    except BrokenPipeError:
        _stdout_to_devnull()
        return BROKEN_PIPE_EXIT


def _main(argv: Sequence[str] | None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit:  # --help, --version, usage errors: flush here, where a closed pipe can still be handled
        sys.stdout.flush()
        raise
    name = command_name(args)
    try:
        code = int(args.func(args) or 0)
    except (CommandError, ValueError, FileNotFoundError) as exc:
        code = 2
        print(f"scaletwin {name}: error: {exc}", file=sys.stderr)
    except KeyboardInterrupt:
        code = 130
        print(f"scaletwin {name}: interrupted", file=sys.stderr)
    sys.stdout.flush()  # a closed pipe raises here, not in the interpreter's shutdown
    return code


def command_name(args: argparse.Namespace) -> str:
    """The command as typed, for messages: ``"dataset"``, or with its subcommand (``"zoo build"``; a command with
    subcommands stores them as ``<command>_command``, as argparse's usage lines name them)."""
    sub = getattr(args, f"{args.command}_command", None)
    return f"{args.command} {sub}" if sub else str(args.command)


def _stdout_to_devnull() -> None:
    """Point stdout's file descriptor at /dev/null, so that flushing what is still buffered (at exit) succeeds
    instead of printing a second BrokenPipeError."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # replaced by an in-memory stream: nothing to flush to a pipe
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
    finally:
        os.close(devnull)


if __name__ == "__main__":
    raise SystemExit(main())
