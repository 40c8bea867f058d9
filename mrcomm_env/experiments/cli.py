"""The ``mrcomm`` command: list, evaluate, actions, record, reproduce, bench, train, race, reproduce-learning and docs, each
in its own module (``experiments/commands/``; see ``COMMANDS``).

Errors are one line on stderr and a non-zero exit (2 for bad input, 1 for a failure during the work,
130 for Ctrl-C); ``--debug`` shows the traceback instead. Arguments, ``--param`` values and output paths
are all checked before the work starts, and every result file is written atomically
(:mod:`mrcomm_env.experiments.io`).
"""

from __future__ import annotations

import argparse
import os
import sys

from mrcomm_env.experiments.commands import (
    actions,
    bench,
    docs,
    evaluate,
    listing,
    race,
    record,
    reproduce,
    reproduce_learning,
    train,
)
from mrcomm_env.experiments.sweep import SweepError

EXIT_BAD_INPUT = 2
EXIT_FAILURE = 1
EXIT_INTERRUPTED = 130  # 128 + SIGINT, what a shell reports for a program stopped by Ctrl-C
EXIT_PIPE_CLOSED = 141  # 128 + SIGPIPE, what a shell reports for `ls | head`'s ls

#: each command's ``add_parser(command)``, in the order ``mrcomm --help`` lists them
COMMANDS = (
    listing.add_parser,
    evaluate.add_parser,
    actions.add_parser,
    record.add_parser,
    reproduce.add_parser,
    bench.add_parser,
    train.add_parser,
    race.add_parser,
    reproduce_learning.add_parser,
    docs.add_parser,
)


# ---------------------------------------------------------------------------------------------- parser
class UsageError(ValueError):
    """A command line argparse rejects (unknown flag, bad value); reported as one line like any ValueError."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):
        # argparse would print the usage block and exit; one line, and the caller decides about exiting
        raise UsageError(f"{message} (see '{self.prog} --help')")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="mrcomm", description="Multi-robot communication environments.")
    parser.add_argument("--debug", action="store_true", help="show the full traceback of an error")
    sub = parser.add_subparsers(dest="command", required=True)

    def command(name: str, **kwargs) -> argparse.ArgumentParser:
        p = sub.add_parser(name, **kwargs)
        # accepted after the command name too; SUPPRESS keeps a --debug given before it
        p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
        return p

    for add_parser in COMMANDS:
        add_parser(command)
    return parser


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())  # numpy and others put newlines into messages
    return text or type(exc).__name__


def _error(message: str) -> None:
    print(f"mrcomm: error: {message}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:

    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv  # known before parsing, so that even a parse error can show its traceback
    try:
        args = build_parser().parse_args(argv)
        args.argv = argv  # the command as given, for the records a command writes (e.g. a sweep's)
        debug = args.debug
        status = args.func(args)
        sys.stdout.flush()  # a closed pipe shows here, inside the handlers below, not at the interpreter's exit
        return status
    except KeyboardInterrupt:
        if debug:
            raise
        print("mrcomm: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # the reader stopped (`mrcomm list | head`): nothing is wrong and nothing is printed
        # the interpreter flushes stdout again at exit, into the closed pipe: send that to /dev/null (Python's
        # documented recipe, "Note on SIGPIPE" in the signal module's docs)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_PIPE_CLOSED
    except (ValueError, OverflowError) as exc:  # bad input: argument, --param, seed, path, a value out of range
        if debug:
            raise
        _error(_one_line(exc))
        return EXIT_BAD_INPUT
    except SweepError as exc:  # a task failed twice: its message names it with its arguments
        if debug:
            raise
        _error(f"{_one_line(exc)} (finished tasks are cached: rerun the same command to resume)")
        return EXIT_FAILURE
    except MemoryError as exc:
        if debug:
            raise
        _error(f"out of memory: {_one_line(exc)}; try fewer robots or a smaller --param (see the env's limits)")
        return EXIT_FAILURE
    except Exception as exc:  # anything else is a failure during the work: one line, traceback with --debug
        if debug:
            raise
        _error(f"{type(exc).__name__}: {_one_line(exc)} (run with --debug for the traceback)")
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
