"""What every command-line entry point of cdro-tools shares.

`entry_point` wraps a `main(argv) -> int`: when the reader of stdout goes away (`cdro-eval |
head`), the tool ends quietly with the status of a program ended by SIGPIPE (128 + 13), as C
tools do, instead of a BrokenPipeError traceback. SIGPIPE itself stays ignored (Python's
default): the tools also write to sockets and pseudo-terminals, where a vanished peer is an
error to handle, not a reason to die.
"""
from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable

SIGPIPE_EXIT_STATUS = 128 + 13


def _silence_stdout() -> None:
    # The interpreter flushes stdout once more at exit; pointed at /dev/null, that flush cannot
    # fail and print "Exception ignored ... BrokenPipeError".
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass


def entry_point(main: Callable[..., int]) -> Callable[..., int]:
    @functools.wraps(main)
    def run(argv: list[str] | None = None) -> int:
        try:
            status = main(argv)
            sys.stdout.flush()     # what is still buffered fails here, not at exit
            return status
        except BrokenPipeError:
            _silence_stdout()
            return SIGPIPE_EXIT_STATUS
    return run
