"""Fixtures of the service's end-to-end tests."""
import pytest


@pytest.fixture
def harness_bin(build_dir):
    """The build folder, once it holds cdro-service-harness."""
    binary = build_dir / "bin" / "cdro-service-harness"
    if not binary.exists():
        pytest.fail(f"{binary} missing: build the native tree first (cmake --build build)")
    return build_dir
