"""The per-run SecOC key (``bus.secoc``): made by ``hil run`` / ``hil up``, read by the nodes
and the panel. The file is created readable and writable by its owner only (mode 0600, with
``O_EXCL``: never an existing file); a key file others may read is refused. The key never goes
on the bus nor into a record, an event or a log line; only the file's path does."""

from __future__ import annotations

import os
import secrets
import stat
from pathlib import Path

from bus.secoc import KEY_BYTES
from hil.errors import UsageError

KEY_FILE = "secoc.key"


def new_key_file(out: Path) -> Path:
    """A fresh random key in ``out/secoc.key`` (replacing one of an earlier run)."""
    path = Path(out) / KEY_FILE
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    try:
        os.write(fd, secrets.token_bytes(KEY_BYTES).hex().encode() + b"\n")
    finally:
        os.close(fd)
    return path


def read_key(path: str | Path) -> bytes:
    """The key in ``path``; UsageError (one line) when it is missing, readable by others or
    not a key."""
    p = Path(path)
    try:
        st = p.stat()
        text = p.read_text().strip()
    except OSError as exc:
        raise UsageError(f"{p}: expected a SecOC key file, got {exc.strerror or exc}") from None
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise UsageError(f"{p}: expected mode 0600 (owner only), got "
                         f"{stat.S_IMODE(st.st_mode):04o}")
    try:
        key = bytes.fromhex(text)
    except ValueError:
        key = b""
    if len(key) != KEY_BYTES:
        raise UsageError(f"{p}: expected {KEY_BYTES} bytes in hex, got something else")
    return key
