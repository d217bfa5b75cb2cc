"""Atomic output: a file, or a directory of files, is either written whole or left as it was;
and the checks, made before any work, that an output is not an input and can be written."""

from __future__ import annotations

import errno
import os
import secrets
import shutil
import stat
import tempfile
import time
from pathlib import Path
from typing import Callable, Iterable

__all__ = [
    "atomic_write_text",
    "atomic_write_bytes",
    "write_files_atomically",
    "write_dir_atomically",
    "output_problem",
    "clean_stale_twins",
]


def _same(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return Path(os.path.abspath(a)).resolve() == Path(os.path.abspath(b)).resolve()


def _inside(path: Path, directory: Path) -> bool:
    d, p = directory.resolve(), Path(os.path.abspath(path)).resolve()
    return d == p or d in p.parents


def output_problem(
    out, inputs: Iterable = (), *, directory: bool = False, option: str = "--out", names: Iterable[str] | None = None
) -> str | None:
    """Why ``out`` cannot be written, in one line, or None; checked before any work.

    Refused: an output that is one of ``inputs`` (compared with :func:`os.path.samefile`, else by
    resolved path), for a ``directory`` output (replaced as a whole) one that holds an input; a
    file output that is an existing directory, a directory output that is an existing file; a
    place whose nearest existing folder is not a writable directory; with ``names`` (the files a
    directory output is made of), an existing directory that holds anything else.
    """
    out = Path(out)
    for inp in inputs:
        inp = Path(inp)
        if _same(out, inp):
            return f"{option} {out} would overwrite an input ({inp}): choose another output"
        if directory and _inside(inp, out):
            return f"{option} {out} holds the input {inp} and is replaced as a whole: choose another directory"
    if directory and out.exists() and not out.is_dir():
        return f"{option} {out} is a file, not a directory"
    if not directory and out.is_dir():
        return f"{option} {out} is a directory, not a file"
    if directory and names is not None and out.is_dir():
        other = sorted(set(os.listdir(out)) - set(names))
        if other:
            return (
                f"{option} {out} holds other files ({', '.join(other[:3])}{', ...' if len(other) > 3 else ''}) "
                "and the output set replaces the directory as a whole: choose a new or empty directory"
            )
    # the folder the output (and, for a directory, its temporary twin) is created in
    parent = Path(os.path.abspath(out)).parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        return f"{option} {out}: {parent} is not a directory"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"{option} {out}: {parent} is not writable"
    if out.exists() and not os.access(out, os.W_OK | (os.X_OK if directory else 0)):
        return f"{option} {out} is not writable"
    return None


def _create_temp(target: Path) -> tuple[int, str]:
    """A new, exclusively created temporary file next to ``target`` (ordinary permissions)."""
    while True:
        tmp = str(target.with_name(f".{target.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp"))
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), tmp
        except FileExistsError:
            continue


def write_files_atomically(files: dict[Path, str | bytes]) -> None:
    """Write every file (text as UTF-8, or bytes as they are) to a temporary file in its
    directory, then os.replace them all.

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
            binary = isinstance(text, (bytes, bytearray))
            with os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
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


def atomic_write_bytes(path: os.PathLike | str, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically: a temp file in the same folder, then rename."""
    write_files_atomically({Path(path): data})


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _twin_prefix(name: str) -> str:
    """The start of a temporary or set-aside twin's name: ``.<name>.`` with ``name`` cut to 120
    bytes of UTF-8, so that the twin's name stays within the 255 bytes a folder name may have."""
    b = name.encode("utf-8", "surrogateescape")[:120]
    return f".{b.decode('utf-8', 'ignore')}."


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def clean_stale_twins(target: os.PathLike | str) -> list[Path]:
    """Remove the temporary (``.<name>.<pid>.<x>.tmp``) and set-aside (``.<name>.<pid>.<x>.old``)
    twins of ``target`` that a process, since dead (``kill -9``, a power cut), left beside it;
    a set-aside twin whose target is missing is the last complete set and is renamed back instead.
    Twins of living processes are left alone. Returns what was removed or restored."""
    target = Path(target)
    parent = Path(os.path.abspath(target)).parent
    prefix = _twin_prefix(target.name)
    done = []
    try:
        entries = os.listdir(parent)
    except OSError:
        return done
    for e in sorted(entries):
        if not e.startswith(prefix) or not e.endswith((".tmp", ".old")):
            continue
        pid = e[len(prefix) :].split(".", 1)[0]
        if not pid.isdigit() or _alive(int(pid)):
            continue
        path = parent / e
        if e.endswith(".old") and not target.exists():
            try:
                os.rename(path, target)
                done.append(path)
                continue
            except OSError:
                pass
        shutil.rmtree(path, ignore_errors=True)
        done.append(path)
    return done


def write_dir_atomically(target: os.PathLike | str, fill: Callable[[Path], object]) -> None:
    """Make the directory ``target`` as a whole: ``fill(tmp)`` writes every file into a fresh
    temporary directory beside ``target``, which is then renamed into place (an existing
    ``target`` is renamed aside first and removed after), so a reader finds the previous set or
    the new one, never a mix of two runs. On any error the temporary directory is removed and
    ``target`` is left as it was (or holds another run's complete set that came in between).
    Twins a dead process left beside ``target`` are cleaned first (:func:`clean_stale_twins`).
    Raises :class:`OSError`; ``fill``'s own errors pass through.
    """
    target = Path(target)
    parent = Path(os.path.abspath(target)).parent
    parent.mkdir(parents=True, exist_ok=True)
    clean_stale_twins(target)
    prefix = f"{_twin_prefix(target.name)}{os.getpid()}."
    tmp = Path(tempfile.mkdtemp(prefix=prefix, suffix=".tmp", dir=parent))
    try:
        fill(tmp)
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp's 0o700 -> the ordinary mode of a new folder
        for attempt in range(200):  # another run can put its set in between: try again, backing off
            if attempt >= 3:
                time.sleep(secrets.randbelow(2000) * 1e-6)  # up to 2 ms: lets a busy neighbour finish its swap
            if not target.exists():
                try:
                    os.rename(tmp, target)
                    return
                except OSError as e:
                    if e.errno not in (errno.EEXIST, errno.ENOTEMPTY):
                        raise
                    continue
            try:
                st = os.lstat(target)  # one look: another run may move it between two
            except FileNotFoundError:
                continue
            if not stat.S_ISDIR(st.st_mode):  # a file, or a link
                raise FileExistsError(errno.EEXIST, "exists and is not a directory", str(target))
            old = parent / f"{prefix}{secrets.token_hex(4)}.old"
            try:
                os.rename(target, old)
            except FileNotFoundError:
                continue
            try:
                os.rename(tmp, target)
            except OSError as e:
                try:
                    os.rename(old, target)
                except OSError:
                    # another run's complete set is in place: the set aside is not needed
                    shutil.rmtree(old, ignore_errors=True)
                if e.errno in (errno.EEXIST, errno.ENOTEMPTY):
                    continue
                raise
            shutil.rmtree(old, ignore_errors=True)
            return
        raise FileExistsError(errno.EEXIST, "kept being replaced by another run", str(target))
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
