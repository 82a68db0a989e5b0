#!/usr/bin/env python3
"""Damage a recording at random many times and read each copy with every MCAP reader.

The recording is the adversarial tests' (``test/core/test_adversarial_files.py``: 400 telemetry
samples in 27 zstd chunks, rpm = sample index, so a wrong sample shows). Each case flips 1-6
bytes, cuts the file, does both, or splices 50 bytes from elsewhere, then reads the copy with
``read_trace_mcap``, ``load_bag`` and ``read_recovered``. A reader may read (whole or in part)
or refuse with BadInputError; any sample that differs from what was written, or any other
exception, is a bug: the script prints it, keeps the file and exits 1. Then ``--payloads``
random CDR payloads go through the EscTelemetry, Residual and Diagnosis decoders of
``read_mcap``; each must decode or raise one of ``mcap_io.DECODE_ERRORS``. It prints the
counts.

    python scripts/fuzz_readers.py --seed 1 --cases 3000 --payloads 20000   # about 3 min
"""

from __future__ import annotations

import argparse
import importlib.util
import random
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from mcap.records import Schema

from thruster_fdd.core.errors import BadInputError
from thruster_fdd.core.traces.mcap_io import DECODE_ERRORS, message_definition, read_trace_mcap
from thruster_fdd.core.traces.mcap_read import McapChannel, ros2_decoder
from thruster_fdd.core.traces.recording import read_recovered
from thruster_fdd_shore.core.traces.replay_check import load_bag

TESTS = Path(__file__).resolve().parents[1] / "test" / "core" / "test_adversarial_files.py"


def _fixture_writer() -> object:
    spec = importlib.util.spec_from_file_location("test_adversarial_files", TESTS)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module._write_recording


def _damage(good: bytes, rng: random.Random) -> tuple[str, bytes]:
    data = bytearray(good)
    mode = rng.choice(["flip", "cut", "both", "splice"])
    if mode in ("flip", "both"):
        for _ in range(rng.randint(1, 6)):
            data[rng.randrange(len(data))] ^= rng.randint(1, 255)
    if mode in ("cut", "both"):
        data = data[: rng.randrange(len(data))]
    if mode == "splice":
        a, b = rng.randrange(len(data)), rng.randrange(len(data))
        data[a : a + 50] = good[b : b + 50]
    return mode, bytes(data)


def _check_traces(traces: list) -> None:
    for trace in traces:
        index = np.rint((trace.t - 1.0) / 0.1).astype(int)
        if not (np.array_equal(trace.rpm, index.astype(float)) and np.all(trace.voltage == 15.0)):
            raise AssertionError("a sample differs from what was written")


def _fuzz_payloads(rng: random.Random, n: int) -> bool:
    """Random CDR payloads through each message type's decoder; False on an escaped error."""
    for i, name in enumerate(("EscTelemetry", "Residual", "Diagnosis")):
        type_name = f"thruster_fdd_msgs/msg/{name}"
        schema = Schema(i + 1, type_name, "ros2msg", message_definition(type_name).encode())
        decode = ros2_decoder(McapChannel("/fuzz", "cdr", schema))
        slowest = 0.0
        for _ in range(n):
            payload = bytes([0, 1, 0, 0]) + rng.randbytes(rng.randint(0, 120))
            start = time.perf_counter()
            try:
                decode(payload)
            except DECODE_ERRORS:
                pass
            except Exception as exc:  # the point of the script: anything else is a bug
                print(f"BUG decoding {name}: {type(exc).__name__}: {exc}; payload {payload.hex()}")
                return False
            slowest = max(slowest, time.perf_counter() - start)
        print(f"{n} random {name} payloads: every error caught, slowest {1e3 * slowest:.1f} ms")
    return True


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--cases", type=int, default=3000, help="damaged recordings")
    parser.add_argument("--payloads", type=int, default=0, help="random CDR payloads per type")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    work = Path(tempfile.mkdtemp(prefix="fuzz_readers_"))
    _fixture_writer()(work / "good.mcap")
    good = (work / "good.mcap").read_bytes()
    rng = random.Random(args.seed)
    readers = {
        "read_trace_mcap": lambda p: _check_traces(read_trace_mcap(p)),
        "load_bag": lambda p: load_bag(p, 0.1),
        "read_recovered": read_recovered,
    }
    counts = {f"{name} {kind}": 0 for name in readers for kind in ("read", "refused")}
    for case in range(args.cases):
        mode, data = _damage(good, rng)
        path = work / "case.mcap"
        path.write_bytes(data)
        for name, read in readers.items():
            try:
                read(path)
                counts[f"{name} read"] += 1
            except BadInputError:
                counts[f"{name} refused"] += 1
            except Exception as exc:  # the point of the script: anything else is a bug
                kept = work / f"bug_{case}.mcap"
                path.rename(kept)
                print(f"BUG in {name} ({mode}): {type(exc).__name__}: {exc}; file {kept}")
                return 1
    print(f"seed {args.seed}, {args.cases} damaged recordings: {counts}")
    return 0 if _fuzz_payloads(rng, args.payloads) else 1


if __name__ == "__main__":
    sys.exit(main())
