"""A pseudo-terminal published under a stable symlink: a serial port for the ESC driver.

The slave side is put in raw mode (no echo, no line editing, no CR/LF translation of binary
frames) and the link is replaced atomically, so the driver opens the link exactly as it opens a
USB serial adapter and sees it vanish when the pty closes.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import tty
from dataclasses import dataclass
from pathlib import Path

from thruster_fdd.core.errors import BadInputError


@dataclass(frozen=True)
class PtyLink:
    """An open pty and the link pointing at its slave.

    Attributes
    ----------
    link : Path
        The symlink: the port name the driver opens.
    master, slave : int
        File descriptors; the master is non-blocking.
    device : str
        The slave device path (``/dev/pts/N``).
    """

    link: Path
    master: int
    slave: int
    device: str

    @classmethod
    def open(cls, link: str | Path) -> PtyLink:
        """Create the pty and point ``link`` at it (its folder is created, an old symlink
        replaced).

        Raises
        ------
        BadInputError
            If something other than a symlink exists at the link path: a file is never replaced.
        """
        link = Path(link)
        if link.exists() and not link.is_symlink():
            raise BadInputError(f"{link}: exists and is not a symlink; only a symlink is replaced")
        master, slave = os.openpty()
        # Raw mode: no echo, no line editing, no CR/LF translation of the binary frames.
        tty.setraw(slave)
        os.set_blocking(master, False)
        device = os.ttyname(slave)
        link.parent.mkdir(parents=True, exist_ok=True)
        tmp = link.with_name(f".{link.name}.{secrets.token_hex(6)}")
        tmp.symlink_to(device)
        tmp.replace(link)
        return cls(link, master, slave, device)

    def close(self) -> None:
        """Remove the link while it still points at this pty, and close both ends (the driver
        sees the port vanish)."""
        with contextlib.suppress(OSError):
            if os.readlink(self.link) == self.device:
                self.link.unlink()
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)
