"""Every command the documentation shows, checked against the program it runs: a command in a
code block of README.md, docs/*.md or tools/README.md, or in the examples of a tool's --help,
that starts one of our programs (cdro-*, build/bin/cdro-*, .venv/bin/cdro-*, scripts/*.sh)
may only use options that program has. Each option must be one the program's --help lists
(and the --help of a sub-command named on the line); a script's options must be ones its
source handles. A cdro-hostd command with nothing left to fill in is also run for real with
--print-config, which parses the whole line and exits. So a wrong option in the docs fails
here instead of on a newcomer's first try."""
from __future__ import annotations

import functools
import os
import pathlib
import re
import shlex
import subprocess
import sys
import tomllib

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
GUARD_S = 60
DOCS = sorted((REPO / "docs").glob("*.md")) + [REPO / "README.md", REPO / "tools" / "README.md"]
PYTHON_TOOLS = set(tomllib.loads((REPO / "tools" / "pyproject.toml").read_text())["project"]["scripts"])
PROGRAM = re.compile(r"^(?:\./)?(?:(?:\.venv|build)/bin/)?(cdro-[a-z0-9-]+)$|^(?:\./)?(scripts/[a-z0-9_-]+\.sh)$")
OPTION = re.compile(r"(?<![\w-])--[a-z0-9][a-z0-9-]*")
PLACEHOLDER = re.compile(r"\.\.\.|[\[\]{}]|\b[A-Z][A-Z_]{2,}\b|…")


def code_blocks(text: str) -> list[str]:
    return re.findall(r"^```[^\n]*\n(.*?)^```", text, re.S | re.M)


PROGRAM_IN_TEXT = re.compile(r"(?<![\w/.-])(?:\./)?(?:(?:\.venv|build)/bin/)?cdro-[a-z0-9-]+\b"
                             r"|(?<![\w/.-])(?:\./)?scripts/[a-z0-9_-]+\.sh\b")


def split_command(line: str) -> list[str]:
    """A command line at ' | ', '&&', ';' and a trailing '&'."""
    return [part.strip() for part in re.split(r"\s\|\s|&&|;|\s&$", line) if part.strip()]


def commands_of(text: str, anywhere: bool = False) -> list[str]:
    """The commands of a code block (anywhere=False: a command starts its line) or of a --help
    text (anywhere=True: from the first program named on a line). Continuation lines are joined.
    In prose (a comment, "# then: cdro-hostd --device ...", or a --help description) a program
    is taken as a command only when an option comes with it."""
    joined = re.sub(r"\\\n\s*", " ", text)
    # A synopsis goes on, indented, on the next line ("cdro-pozyx ... --prf {16,64}\n    --preamble ...").
    joined = re.sub(r"\n[ \t]+(?=--|\[)", " ", joined)
    code_commands, prose_commands = [], []
    for line in joined.splitlines():
        code, _, comment = ("", "", line) if line.lstrip().startswith("#") else line.partition(" #")
        if anywhere:
            first = PROGRAM_IN_TEXT.search(code)
            prose_commands += split_command(code[first.start():]) if first else []
        else:
            code_commands += split_command(code.strip())
        for named in PROGRAM_IN_TEXT.finditer(comment):
            prose_commands += split_command(comment[named.start():])[:1]
    return code_commands + [c for c in prose_commands if OPTION.search(c)]


def program_of(command: str) -> tuple[str, list[str]] | None:
    """(program token, the rest) when the command runs one of ours."""
    words = command.split()
    while words and (re.match(r"^[A-Z_]+=", words[0]) or words[0] in ("sudo", "exec", "time", "$")):
        words = words[1:]
    if words and PROGRAM.match(words[0]):
        return words[0], words[1:]
    return None


def documented_commands() -> list[tuple[str, str]]:
    found = []
    for path in DOCS:
        for block in code_blocks(path.read_text()):
            for command in commands_of(block):
                if program_of(command):
                    found.append((str(path.relative_to(REPO)), command))
    return found


def help_examples() -> list[tuple[str, str]]:
    """The commands in the --help of every Python tool and of cdro-hostd (when built)."""
    found = []
    for name in sorted(PYTHON_TOOLS) + ["cdro-hostd"]:
        if not pathlib.Path(executable(name)).exists():
            continue
        text = run_help((executable(name), "--help"))
        # The description and its examples: the option list below it wraps its lines anywhere.
        text = re.split(r"^(?:options|OPTIONS|positional arguments|POSITIONALS):?\s*$", text, maxsplit=1, flags=re.M)[0]
        for command in commands_of(text, anywhere=True):
            if program_of(command) and OPTION.search(command):
                found.append((f"{name} --help", command))
    return found


def executable(token: str) -> str:
    name = pathlib.PurePath(token).name
    if name in PYTHON_TOOLS:
        return str(pathlib.Path(sys.executable).parent / name)
    build = pathlib.Path(os.environ.get("CDRO_BUILD_DIR", REPO / "build"))
    return str(build / "bin" / name)


@functools.lru_cache(maxsize=None)
def run_help(argv: tuple[str, ...]) -> str:
    result = subprocess.run(argv, capture_output=True, text=True, timeout=GUARD_S, cwd=REPO)
    return result.stdout + result.stderr if result.returncode == 0 else ""


def options_known(token: str, rest: list[str]) -> str:
    """Everything the program (and a sub-command named on the line) says about its options."""
    if token.lstrip("./").startswith("scripts/"):
        return (REPO / token.lstrip("./")).read_text()
    program = executable(token)
    if not pathlib.Path(program).exists():
        pytest.skip(f"{program} is not built")
    text = run_help((program, "--help"))
    assert text, f"{program} --help failed"
    for word in rest:
        if re.fullmatch(r"[a-z][a-z-]*", word) and re.search(rf"\b{word}\b", text):
            text += run_help((program, word, "--help"))   # a sub-command's own options
    return text


CASES = documented_commands()


def test_that_the_docs_show_commands_at_all():
    # Guards the extraction itself: the docs are full of commands; finding none is a broken test.
    assert len(CASES) > 25
    assert any("cdro-hostd" in command for _, command in CASES)


@pytest.mark.parametrize("where, command", CASES + help_examples())
def test_that_every_option_of_a_documented_command_exists(where, command):
    token, rest = program_of(command)
    known = options_known(token, rest)
    script = token.lstrip("./").startswith("scripts/")
    unknown = []
    for option in OPTION.findall(" ".join(rest)):
        # a script handles an option where its source names it whole (`--quick)` in a case); a
        # program lists it in its --help
        whole = (rf"(^|[\s\"'(|]){re.escape(option)}([\s\"')|=]|$)" if script
                 else rf"(?<![\w-]){re.escape(option)}(?![\w-])")
        if not re.search(whole, known, re.M):
            unknown.append(option)
    assert not unknown, f"{where}: `{command}` uses {unknown}, which {token} does not have"


HOSTD_RUNNABLE = [(where, command) for where, command in CASES
                  if pathlib.PurePath(program_of(command)[0]).name == "cdro-hostd" and not PLACEHOLDER.search(command)]


@pytest.mark.parametrize("where, command", HOSTD_RUNNABLE)
def test_that_a_complete_cdro_hostd_command_parses(where, command):
    token, rest = program_of(command)
    program = executable(token)
    if not pathlib.Path(program).exists():
        pytest.skip(f"{program} is not built")
    result = subprocess.run([program, *shlex.split(" ".join(rest)), "--print-config"], capture_output=True, text=True,
                            timeout=GUARD_S, cwd=REPO)
    assert result.returncode == 0, f"{where}: `{command}`: {result.stderr}"
