"""Shared pytest fixtures: where the golden vectors and the native build live."""
import os
import pathlib

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def repo_root() -> pathlib.Path:
    return REPO


@pytest.fixture(scope="session")
def golden_dir() -> pathlib.Path:
    return REPO / "tests" / "golden"


@pytest.fixture(scope="session")
def build_dir() -> pathlib.Path:
    """The native CMake build (scripts/test.sh sets CDRO_BUILD_DIR; default ./build)."""
    return pathlib.Path(os.environ.get("CDRO_BUILD_DIR", REPO / "build"))


@pytest.fixture(scope="session")
def hostd(build_dir) -> pathlib.Path:
    """The cdro-hostd of the native build."""
    binary = build_dir / "bin" / "cdro-hostd"
    assert binary.is_file(), f"{binary} not found: build first (scripts/test.sh), or set CDRO_BUILD_DIR"
    return binary
