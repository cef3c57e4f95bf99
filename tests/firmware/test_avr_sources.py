"""What the AVR build compiles is what the Uno runs: the firmware (firmware/core, firmware/arduino)
and common/src (cdro_common), never the host's sources (common/host, sim/, host/, tools/). Read
from the AVR build's compile_commands.json and from the members of its libcdro_common.a, so a
host-only file added to the AVR library fails here, not only as a bigger image."""
import json
import pathlib
import shutil
import subprocess

import pytest

# Folders of the repository whose sources the AVR image may compile; everything else of ours is
# host-only. Paths relative to the repository.
UNO_SOURCE_DIRS = ("firmware/core/src", "firmware/arduino", "common/src")
HOST_ONLY_COMMON_DIR = "common/host/src"


def source_dir_of_build(build: pathlib.Path) -> pathlib.Path:
    """The source tree a CMake build was configured from (CMakeCache.txt's CMAKE_HOME_DIRECTORY)."""
    cache = build / "CMakeCache.txt"
    for line in cache.read_text().splitlines():
        if line.startswith("CMAKE_HOME_DIRECTORY:"):
            return pathlib.Path(line.split("=", 1)[1])
    raise AssertionError(f"{cache}: no CMAKE_HOME_DIRECTORY")


def sources_outside_the_uno(compiled: list[pathlib.Path], source_dir: pathlib.Path) -> list[str]:
    """The files of `source_dir` among `compiled` that are not in UNO_SOURCE_DIRS (relative paths).
    Files outside `source_dir` (the system's Arduino core) are not ours to judge."""
    outside = []
    for path in compiled:
        try:
            relative = path.resolve().relative_to(source_dir.resolve())
        except ValueError:
            continue
        if not any(relative.parent.as_posix() == d or relative.parent.as_posix().startswith(d + "/")
                   for d in UNO_SOURCE_DIRS):
            outside.append(relative.as_posix())
    return sorted(outside)


@pytest.fixture(scope="module")
def avr_build(avr_build_dir) -> pathlib.Path:
    commands = avr_build_dir / "compile_commands.json"
    assert commands.is_file(), (f"{commands} not found: configure and build the AVR image "
                                "(cmake -S . -B build-avr --toolchain cmake/avr-gcc.cmake, docs/firmware.md)")
    return avr_build_dir


def test_that_the_check_names_a_host_source_it_is_given(tmp_path):
    # The check itself: a host-only source and a simulator source are named, the Uno's are not.
    compiled = [tmp_path / "common/src/frames.c", tmp_path / "firmware/core/src/link.c",
                tmp_path / "common/host/src/capture.c", tmp_path / "sim/pozyx_sim/src/pozyx_sim.c",
                pathlib.Path("/usr/share/arduino/hardware/arduino/avr/cores/arduino/wiring.c")]
    assert sources_outside_the_uno(compiled, tmp_path) == ["common/host/src/capture.c",
                                                           "sim/pozyx_sim/src/pozyx_sim.c"]


def test_that_the_avr_build_compiles_only_what_the_uno_runs(avr_build):
    source_dir = source_dir_of_build(avr_build)
    entries = json.loads((avr_build / "compile_commands.json").read_text())
    compiled = [pathlib.Path(e["directory"], e["file"]) for e in entries]
    ours = [p for p in compiled if p.resolve().is_relative_to(source_dir.resolve())]
    assert ours, f"{avr_build}/compile_commands.json compiles none of {source_dir}'s sources"
    assert sources_outside_the_uno(compiled, source_dir) == [], \
        f"host-only sources in the AVR build {avr_build}: move them out of cdro_common/cdro_fw_core"
    # Every host-only source of common/ exists, so the check above had something to keep out.
    assert sorted((source_dir / HOST_ONLY_COMMON_DIR).glob("*.c")), f"no sources in {HOST_ONLY_COMMON_DIR}"


def test_that_the_avr_common_library_holds_only_common_src(avr_build):
    library = avr_build / "lib" / "libcdro_common.a"
    assert library.is_file(), f"{library} not found: build the AVR image (cmake --build build-avr)"
    archiver = shutil.which("avr-gcc-ar") or shutil.which("avr-ar")
    assert archiver, "avr-gcc-ar not found (scripts/setup.sh installs gcc-avr)"
    members = subprocess.run([archiver, "t", str(library)], check=True, capture_output=True,
                             text=True).stdout.split()
    # CMake names each object after its source: frames.c -> frames.c.obj.
    member_sources = sorted(m.removesuffix(".obj").removesuffix(".o") for m in members)
    source_dir = source_dir_of_build(avr_build)
    uno = sorted(p.name for p in (source_dir / "common/src").glob("*.c"))
    host_only = {p.name for p in (source_dir / HOST_ONLY_COMMON_DIR).glob("*.c")}
    assert not host_only & set(member_sources), f"{library} holds host-only objects: {members}"
    assert member_sources == uno, f"{library} holds {members}, common/src has {uno}"
