"""Fixtures of the firmware-in-the-loop tests: where the AVR build lives (scripts/test.sh sets
CDRO_AVR_BUILD_DIR; default ./build-avr), next to the native build of tests/conftest.py."""
import os
import pathlib

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def avr_build_dir() -> pathlib.Path:
    return pathlib.Path(os.environ.get("CDRO_AVR_BUILD_DIR", REPO / "build-avr"))
