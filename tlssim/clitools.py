"""Shared console-script plumbing: run a sub-command, turn user errors into one-line messages.

Every package raises one exception type for user mistakes (all subclass
``ValueError``); the console scripts print its message and exit with status 2
instead of showing a traceback; warnings are printed as one line each. An interrupted command exits with status 130;
one whose reader closed the pipe (``tlssim diff A B | head``) stops quietly with status 141, as the shell reports it.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings


def run_main(parser: argparse.ArgumentParser, argv: list[str]) -> int:
    """Parse ``argv``, run the selected command's ``func(args)`` and return the exit status.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser; each sub-command sets ``func`` in its defaults.
    argv : list of str
        Command-line arguments, without the program name.

    Returns
    -------
    int
        Exit status: the command's status, 2 after a one-line error message, 130 if interrupted, 141 if the
        reader of standard output went away.
    """
    args = parser.parse_args(argv)

    def one_line_warning(message, category, filename, lineno, file=None, line=None):
        print(f"{parser.prog}: warning: {message}", file=sys.stderr)

    warnings.showwarning = one_line_warning
    try:
        status = args.func(args)
    except KeyboardInterrupt:
        print(f"{parser.prog}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # Python flushes stdout again at exit; point it at /dev/null so that flush cannot raise a second time.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except (ValueError, FileNotFoundError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    return int(status or 0)
