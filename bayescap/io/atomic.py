"""Atomic text output: a file is either written whole or left as it was."""

from __future__ import annotations

import os
import secrets
from pathlib import Path

__all__ = [
    "atomic_write_text",
    "write_files_atomically",
]


def _create_temp(target: Path) -> tuple[int, str]:
    """A new, exclusively created temporary file next to ``target`` (ordinary permissions)."""
    while True:
        tmp = str(target.with_name(f".{target.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"))
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), tmp
        except FileExistsError:
            continue


def write_files_atomically(files: dict[Path, str]) -> None:
    """Write every file to a temporary file in its directory, then os.replace them all.

    Nothing is replaced until every temporary file is written and synced, so an error while
    writing leaves all targets as they were; temporary files are removed. The files get the
    ordinary permissions of a new file (the umask applies). Raises :class:`OSError`.
    """
    temps: list[tuple[str, Path]] = []
    try:
        for target, text in files.items():
            target = Path(target)
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = _create_temp(target)
            temps.append((tmp, target))
            with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
                fh.write(text)
                fh.flush()
                os.fsync(fh.fileno())
        for tmp, target in temps:
            os.replace(tmp, target)
    finally:
        for tmp, _ in temps:
            if os.path.exists(tmp):
                os.unlink(tmp)


def atomic_write_text(path: os.PathLike | str, text: str) -> None:
    """Write ``text`` to ``path`` atomically: a temp file in the same folder, then rename."""
    write_files_atomically({Path(path): text})
