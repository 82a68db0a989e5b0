"""Files and folders that appear whole or not at all.

Everything the project writes (models, reports, configurations, recordings) goes through a
temporary name beside its target and is renamed into place only when it is complete, so a run
that fails or is killed leaves what was there before. A folder is swapped in with one
``renameat2(RENAME_EXCHANGE)`` where the kernel has it (Linux >= 3.15), so readers see the old
folder or the new one, never a mix or nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import secrets
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


def _beside(path: Path, suffix: str) -> Path:
    """A fresh hidden name in ``path``'s folder (random, so two writers never collide)."""
    return path.with_name(f".{path.name}.{secrets.token_hex(6)}{suffix}")


def _fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


@contextlib.contextmanager
def replaced_file(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; when the block ends normally the file written
    there replaces ``path`` at once, otherwise it is removed and ``path`` is untouched.

    For writers that need a file name (MCAP, matplotlib). The parent folder is created.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _beside(path, ".tmp")
    # Not mkstemp: its 0600 would make every output unreadable to other users; 0666 & ~umask.
    os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    try:
        yield tmp
        with tmp.open("rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    finally:
        tmp.unlink(missing_ok=True)


def write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (see ``replaced_file``)."""
    with replaced_file(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (see ``replaced_file``)."""
    write_bytes(path, text.encode())


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (Linux renameat2); False where the system cannot."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p]
    renameat2.argtypes += [ctypes.c_uint]
    rc = renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    return rc == 0


@contextlib.contextmanager
def replaced_dir(path: str | Path) -> Iterator[Path]:
    """Yield an empty staging folder beside ``path``; when the block ends normally the folder
    replaces ``path`` (created or swapped in at once), otherwise it is removed and ``path`` is
    untouched.

    Raises
    ------
    FileExistsError
        If ``path`` exists and is not a folder (a file is never replaced by a folder).
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise FileExistsError(f"{path}: exists and is not a folder")
    path.parent.mkdir(parents=True, exist_ok=True)
    stage = _beside(path, ".tmp")
    stage.mkdir(0o777)  # not mkdtemp's 0700: a model folder must stay readable (umask applies)
    try:
        yield stage
        for child in stage.iterdir():
            with child.open("rb") as f:
                os.fsync(f.fileno())
        _fsync_dir(stage)
        if not path.exists():
            os.rename(stage, path)
        elif not _exchange(stage, path):
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
            os.rename(path, old / path.name)
            os.rename(stage, path)
            shutil.rmtree(old)
        _fsync_dir(path.parent)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
