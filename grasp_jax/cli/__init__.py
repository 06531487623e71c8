"""The ``grasp-jax`` command line: :func:`main` builds one parser from :data:`COMMANDS` and runs
the command named.

A command is one module of this package with ``add_parser(subparsers)`` (adds and returns its
parser) and ``run(args)`` (returns the exit status); adding a command is adding its module to
:data:`COMMANDS`. Shared options are in ``_options``, shared run-time steps in ``_common``,
figures and result files in ``_output``. The pipeline and the pictures (matplotlib, plotly) are
imported inside ``run``, after the command line has been read and the CPU device count chosen.

Exit status: 0 on success, 2 for a user mistake (one ``grasp-jax: error: ...`` line on stderr),
130 after ``Ctrl-C`` (and 143 after ``SIGTERM``), with no partial output file in either case.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from .. import __version__
from . import dataset, demo, hand, optimize, sample, score, show, simulate
from ._options import DEFAULT_MU, DESCRIPTION, PROG, Formatter, Parser, UsageError, epilog
from ._output import plot_best, plot_robust

#: The commands, in the order ``grasp-jax --help`` lists them.
COMMANDS = (sample, score, show, optimize, hand, simulate, dataset, demo)

__all__ = ["COMMANDS", "DEFAULT_MU", "PROG", "build_parser", "main", "plot_best", "plot_robust"]


def build_parser() -> argparse.ArgumentParser:
    """The ``grasp-jax`` parser: one subcommand per module of :data:`COMMANDS`."""
    parser = Parser(prog=PROG, description=DESCRIPTION, epilog=epilog(), formatter_class=Formatter)
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for command in COMMANDS:
        command.add_parser(subparsers).set_defaults(func=command.run)
    return parser


def main(argv=None) -> int:
    """Run the ``grasp-jax`` command line; returns the exit status."""
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    if not argv or (argv[0].startswith("-") and argv[0] not in ("-h", "--help", "--version")):
        argv = ["demo", *argv]  # "grasp-jax" and "grasp-jax --num 5000" run the demo
    try:
        if hasattr(signal, "SIGTERM") and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, _on_sigterm)
        try:
            args = build_parser().parse_args(argv)
        except UsageError as e:
            print(f"{PROG}: error: {e}", file=sys.stderr)
            return 2
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except _Terminated:
        print(f"{PROG}: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except UsageError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except (ValueError, FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError) as e:
        print(f"{PROG}: error: {_one_line(e)}", file=sys.stderr)
        return 2
    except OSError as e:  # disk full and the like: not a mistake, but still one line
        print(f"{PROG}: error: {_one_line(e)}", file=sys.stderr)
        return 1


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    if isinstance(exc, (FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError)) and exc.filename:
        text = f"{exc.strerror or text}: {exc.filename!s}"
    return " ".join(text.split())


class _Terminated(BaseException):
    """SIGTERM, raised in the main thread so that partial output is removed on the way out."""


def _on_sigterm(signum, frame):  # pragma: no cover - exercised through a subprocess
    raise _Terminated()
