"""The bridge firmware builds from scratch (the session fixture), fits an ATmega328P with margin,
and its main loop stays short under load in the co-simulation."""

from __future__ import annotations

from dataclasses import replace

import pytest

from thruster_fdd_shore.core.bridge.firmware_build import (
    FLASH_BYTES,
    RAM_BYTES,
    VARIANTS,
    FirmwareImage,
    ensure_built,
)
from thruster_fdd_shore.core.bridge.firmware_cosim import measure_loop_time


def test_both_variants_build_and_fit_half_the_chip(firmware_images: dict) -> None:
    assert set(firmware_images) == set(VARIANTS)
    for image in firmware_images.values():
        print(
            f"{image.variant}: flash {image.flash_bytes} B ({image.flash_bytes / FLASH_BYTES:.1%})"
            f", static RAM {image.ram_bytes} B ({image.ram_bytes / RAM_BYTES:.1%})"
        )
        assert image.hex_path.stat().st_size > 0
        assert 0 < image.flash_bytes <= FLASH_BYTES // 2
        assert 0 < image.ram_bytes <= RAM_BYTES // 2
        assert image.limit_problems() == ()
        assert image.loop_address > 0


def test_an_image_over_the_limit_is_named(firmware_images: dict) -> None:
    image: FirmwareImage = replace(firmware_images["hott"], flash_bytes=20_000, ram_bytes=1500)
    assert image.limit_problems() == (
        "hott: flash 20000 B > 50% of 32768",
        "hott: RAM 1500 B > 50% of 2048",
    )


def test_ensure_built_reuses_a_build_of_the_same_sources(firmware_images: dict) -> None:
    out = firmware_images["hott"].hex_path.parent
    first = ensure_built("hott", out)
    built_at = first.hex_path.stat().st_mtime_ns
    assert ensure_built("hott", out) == first
    assert first.hex_path.stat().st_mtime_ns == built_at
    with pytest.raises(ValueError, match="ESC telemetry must be one of"):
        ensure_built("dshot", out)


@pytest.mark.parametrize("variant", VARIANTS)
def test_the_main_loop_stays_short_and_the_stack_small_under_load(
    firmware_images: dict, variant: str
) -> None:
    image = firmware_images[variant]
    stats = measure_loop_time(image, seconds=2.0)
    print(
        f"{variant}: worst loop pass {stats.loop_max_us:.0f} µs over {stats.loops} passes, "
        f"deepest stack {stats.stack_bytes} B; unpaced {stats.speed:.2f}x real time"
    )
    assert stats.virtual_s == pytest.approx(2.0, abs=0.01)
    assert stats.loops > 2000, "the loop should pass at least once per 1 ms wake tick"
    # Far inside the 60 ms AVR watchdog and the 10 ms telemetry period at 100 Hz.
    assert 0 < stats.loop_max_us < 2000
    assert stats.stack_bytes > 0
    assert image.ram_bytes + stats.stack_bytes <= RAM_BYTES // 2
