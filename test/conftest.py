"""Shared pytest fixtures: a real rclpy context on this machine's own DDS domain, and the
repository's scripts as modules."""

from __future__ import annotations

import importlib.util
import os
import signal
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType

import pytest

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def pytest_configure(config: pytest.Config) -> None:
    # DDS must never leave this machine, whoever runs pytest.
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))
    # A shell that runs pytest in the background (`cmd &`) starts it with Ctrl-C ignored, and
    # every process a test starts would inherit that: nodes that ignore SIGINT, a launch that
    # never ends (seen: six failures in a full suite run so). A handler is reset to the
    # default in a child, an ignored signal is not.
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def ros_context() -> Iterator[object]:
    """An initialised rclpy context, shut down after the test."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


@pytest.fixture(scope="session")
def quiet_t100() -> object:
    """The t100 preset without sensor outliers: in a link or bridge test an odd value is then
    the link's or the bridge's doing."""
    from dataclasses import replace

    from thruster_fdd_shore.core.sim.config import load_config

    config = load_config("t100")
    return replace(config, measurement=replace(config.measurement, outlier_prob=0.0))


@pytest.fixture(scope="session")
def firmware_images(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    """The bridge firmware built from scratch for this run, ``{variant: FirmwareImage}``."""
    from thruster_fdd_shore.core.bridge.firmware_build import build_firmware

    out = tmp_path_factory.mktemp("firmware")
    return {image.variant: image for image in build_firmware(out)}


@pytest.fixture
def load_script() -> Callable[[str], ModuleType]:
    """Import ``scripts/<name>.py`` as module ``name`` (registered in ``sys.modules``, so the
    script's own imports of its siblings find it)."""

    def load(name: str) -> ModuleType:
        spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        return module

    return load
