"""Atomic file output: every writer in :mod:`planar_vo.io` goes through here.

A file is written under a temporary name in the destination directory and renamed
onto its final name (``os.replace``, atomic on POSIX) only once it is complete, so a
crash or an exception never leaves a half-written file under the real name.
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator

from planar_vo.core.errors import InputError


def _temp_path(path: Path) -> Path:
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise InputError(f"{path}: output folder {directory} does not exist; create it first")
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    os.close(fd)
    return Path(name)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` on success.

    On an exception inside the ``with`` block the temporary file is removed and the
    exception propagates; an existing file at ``path`` is left untouched.
    """
    final = Path(path)
    tmp = _temp_path(final)
    try:
        yield tmp
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _commit(tmp, final)


def _commit(tmp: Path, final: Path) -> None:
    # mkstemp creates 0600 files; give the result the permissions a plain open() would.
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    os.replace(tmp, final)


class AtomicFile:
    """A binary file object written atomically: ``commit()`` renames, ``discard()`` removes.

    For writers whose lifetime spans several calls (e.g. :class:`RGBDLogWriter`), where a
    ``with`` block around all the writing is not available.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.tmp_path = _temp_path(self.path)
        self.file = open(self.tmp_path, "wb")  # noqa: SIM115 - closed in commit/discard

    def commit(self) -> None:
        self.file.close()
        _commit(self.tmp_path, self.path)

    def discard(self) -> None:
        self.file.close()
        self.tmp_path.unlink(missing_ok=True)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


class AtomicTree:
    """A file or folder written by a library that opens the path itself (e.g. rosbags).

    ``tmp_path`` lies in a fresh hidden folder beside ``path`` and has the same name, so
    names the library derives from it (a rosbag2 folder names its storage file after
    itself) are right once ``commit()`` moves it onto ``path``; ``discard()`` removes it.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        directory = self.path.parent if str(self.path.parent) else Path(".")
        if not directory.is_dir():
            raise InputError(f"{self.path}: output folder {directory} does not exist; create it first")
        self._dir = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=directory))
        self.tmp_path = self._dir / self.path.name

    def commit(self) -> None:
        import shutil
        if self.path.is_dir() and not self.path.is_symlink():
            shutil.rmtree(self.path)  # os.replace cannot replace a non-empty folder
        os.replace(self.tmp_path, self.path)
        self._dir.rmdir()

    def discard(self) -> None:
        import shutil
        shutil.rmtree(self._dir, ignore_errors=True)
