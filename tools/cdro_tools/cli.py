"""What every command-line entry point of cdro-tools shares.

`entry_point` wraps a `main(argv) -> int`: when the reader of stdout goes away (`cdro-eval |
head`), the tool ends quietly with the status of a program ended by SIGPIPE (128 + 13), as C
tools do, instead of a BrokenPipeError traceback. SIGPIPE itself stays ignored (Python's
default): the tools also write to sockets and pseudo-terminals, where a vanished peer is an
error to handle, not a reason to die.

It also answers `--version` for every tool, in the words cdro-hostd uses: the package version,
the serial protocol version and the layout hashes of the frames and checkpoints this build
speaks, so that a bug report or a mismatch with the firmware can be told from the output alone.
"""
from __future__ import annotations

import argparse
import contextlib
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


def version_text(program: str) -> str:
    """`<program> <version> (protocol <n>, frame layout 0x<hash>, checkpoint layout 0x<hash>)`."""
    from importlib import metadata

    from .codec.layout import CONSTANTS
    try:
        version = metadata.version("cdro-tools")
    except metadata.PackageNotFoundError:   # run from a source tree that was never installed
        version = "unknown"
    return (f"{program} {version} (protocol {CONSTANTS['CDRO_PROTOCOL_VERSION']}, "
            f"frame layout 0x{CONSTANTS['CDRO_LAYOUT_HASH']:04X}, "
            f"checkpoint layout 0x{CONSTANTS['CDRO_SOG_LAYOUT_HASH']:04X})")


def _asks_for_version(argv: list[str]) -> bool:
    # Only before a "--": after it, "--version" would be an operand (a file of that name).
    return "--version" in (argv[:argv.index("--")] if "--" in argv else argv)


@contextlib.contextmanager
def _version_in_help(text: str):
    """While main runs, every parser it parses with lists --version in its --help (argparse's
    own "version" action), so that the option is documented where the tool's others are."""
    original = argparse.ArgumentParser.parse_known_args

    def parse_known_args(self, args=None, namespace=None):
        if "--version" not in self._option_string_actions:
            self.add_argument("--version", action="version", version=text,
                              help="print the version, protocol version and layout hashes, and exit")
        return original(self, args, namespace)

    argparse.ArgumentParser.parse_known_args = parse_known_args
    try:
        yield
    finally:
        argparse.ArgumentParser.parse_known_args = original


def entry_point(main: Callable[..., int]) -> Callable[..., int]:
    @functools.wraps(main)
    def run(argv: list[str] | None = None) -> int:
        args = sys.argv[1:] if argv is None else argv
        text = version_text(_program_name(main))
        if _asks_for_version(args):
            # Before main: a tool with a required argument or a sub-command answers it too.
            print(text)
            return 0
        try:
            with _version_in_help(text):
                status = main(argv)
            sys.stdout.flush()     # what is still buffered fails here, not at exit
            return status
        except BrokenPipeError:
            _silence_stdout()
            return SIGPIPE_EXIT_STATUS
    return run


def _program_name(main: Callable[..., int]) -> str:
    # cdro_tools.eval_motion -> cdro-eval-motion; cdro_tools.export.cli -> cdro-export
    parts = main.__module__.split(".")
    name = parts[-2] if parts[-1] == "cli" and len(parts) > 2 else parts[-1]
    return {"foxglove_bridge": "cdro-foxglove"}.get(name, "cdro-" + name.replace("_", "-"))
