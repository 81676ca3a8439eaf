"""Finding a fleet's logs, naming their result folders, hashing their content.

A log is what :func:`planar_vo.io.open_log` reads: an MCAP file or a TUM RGB-D folder
(a folder holding ``rgb.txt``). Given folders are searched recursively; a file given by
name is taken whatever it is (a corrupt one then fails in its own task, with its reason).
"""
from __future__ import annotations

import hashlib
import os
import re
from pathlib import Path

from planar_vo.core.errors import InputError

#: Bytes read at a time while hashing (large reads let hashlib release the GIL).
HASH_CHUNK = 1 << 20


def is_tum_folder(path: Path) -> bool:
    return path.is_dir() and (path / "rgb.txt").is_file()


def find_logs(inputs: list[str | Path], exclude: Path | None = None) -> list[Path]:
    """Absolute paths of the logs in ``inputs`` (files, TUM folders, folders searched
    recursively for ``*.mcap`` and TUM folders), in a stable order, without duplicates;
    nothing under ``exclude`` (the results folder, whose ``poses.mcap`` are not logs)."""
    found: dict[Path, None] = {}
    skip = exclude.resolve() if exclude is not None else None
    for item in inputs:
        p = Path(item)
        if not p.exists():
            raise InputError(f"{p}: no such file or folder; give MCAP logs, TUM folders or folders holding them")
        p = p.resolve()
        if p.is_file() or is_tum_folder(p):
            found[p] = None
            continue
        for log in sorted(_walk(p, skip)):
            found[log] = None
    return list(found)


def _walk(folder: Path, skip: Path | None):
    """``*.mcap`` files and TUM folders below ``folder`` (hidden entries and ``skip`` left out)."""
    for root, dirs, files in os.walk(folder):
        here = Path(root)
        if skip is not None and (here == skip or skip in here.parents):
            dirs[:] = []
            continue
        keep = []
        for d in sorted(dirs):
            if d.startswith("."):
                continue
            if is_tum_folder(here / d):
                yield here / d
            else:
                keep.append(d)
        dirs[:] = keep
        for f in files:
            if f.endswith(".mcap") and not f.startswith("."):
                yield here / f


def _clean(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "log"


def result_names(logs: list[Path]) -> dict[Path, str]:
    """One result-folder name per log: the log's name without ``.mcap``; logs sharing a
    name get their parent folder's name in front, and a short hash of the path if that
    still collides. Depends only on each log's own path and the set of logs."""
    base = {p: _clean(p.name[:-5] if p.name.endswith(".mcap") else p.name) for p in logs}
    names = dict(base)
    for attempt in ("parent", "hash"):
        counts: dict[str, int] = {}
        for n in names.values():
            counts[n] = counts.get(n, 0) + 1
        for p in logs:
            if counts[names[p]] > 1:
                if attempt == "parent":
                    names[p] = _clean(f"{p.parent.name}_{base[p]}")
                else:
                    names[p] = f"{names[p]}-{hashlib.sha1(str(p).encode()).hexdigest()[:8]}"
    return names


def _hash_file(h, path: Path) -> None:
    with open(path, "rb") as fh:
        while chunk := fh.read(HASH_CHUNK):
            h.update(chunk)


def content_hash(log: Path) -> str:
    """SHA-256 of what a run of ``log`` reads: the MCAP file and the ``LOG.gt.tum`` beside it
    (if any), or every file of a TUM folder with its relative path. Renaming or moving a
    log keeps its hash; changing a byte changes it."""
    h = hashlib.sha256()
    if log.is_dir():
        for f in sorted(q for q in log.rglob("*") if q.is_file()):
            h.update(f"\0{f.relative_to(log).as_posix()}\0".encode())
            _hash_file(h, f)
        return h.hexdigest()
    try:
        _hash_file(h, log)
    except OSError as exc:
        raise InputError(f"{log}: cannot be read ({exc.strerror})") from None
    beside = log.with_suffix(".gt.tum")
    if beside.is_file():
        h.update(b"\0ground truth\0")
        _hash_file(h, beside)
    return h.hexdigest()
