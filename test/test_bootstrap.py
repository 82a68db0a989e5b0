"""``scripts/bootstrap.sh`` sourced in a shell: the shell keeps its own options."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BOOTSTRAP = ROOT / "scripts" / "bootstrap.sh"


def _bash(script: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["bash", "--norc", "--noprofile", "-c", script],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_sourcing_leaves_the_callers_shell_options_alone() -> None:
    """A user's shell (no errexit, nounset, pipefail) survives a failing command afterwards."""
    done = _bash(
        f". {BOOTSTRAP}; echo status=$?; false; echo survived; echo options=$-; "
        "shopt -qo pipefail && echo pipefail; echo unset=$NO_SUCH_VARIABLE; "
        "command -v thruster-fdd >/dev/null && echo cli"
    )
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    assert "status=0" in lines
    assert "survived" in lines, done.stdout
    (options,) = [line for line in lines if line.startswith("options=")]
    assert not {"e", "u"} & set(options.removeprefix("options=")), options
    assert "pipefail" not in lines
    assert "unset=" in lines
    assert "cli" in lines, "the environment is set up in the caller's shell"


@pytest.mark.parametrize("options", ["-euo pipefail", "-e"])
def test_scripts_that_set_errexit_keep_it(options: str) -> None:
    """scripts/test and scripts/up set -euo pipefail before sourcing: still fail fast."""
    done = _bash(f"set {options}; . {BOOTSTRAP}; echo options=$-; false; echo not-reached")
    assert done.returncode == 1, done.stdout
    (line,) = [x for x in done.stdout.splitlines() if x.startswith("options=")]
    assert "e" in line.removeprefix("options=")
    assert ("u" in line.removeprefix("options=")) == ("u" in options)
    assert "not-reached" not in done.stdout
