"""The batch folder: what defines a batch, who may write to it, and what may be deleted.

A batch folder (``--out``) holds ``batch.json`` (the manifest: scenario name and source, the resolved
scenario data with every ``--set`` applied, its SHA-256, the corridor version), ``parts/`` (one Parquet
file per finished run), ``runs.parquet``, ``report.html`` and ``signals/``.  Rules:

- a batch never deletes earlier results unless told to (``--overwrite``); a folder that already holds
  a batch is refused with a one-line hint, a non-empty folder that holds no batch is never touched;
- ``--resume`` continues only the same batch: a different scenario content (``--set`` included) or
  corridor version is refused, naming the first differences;
- one batch at a time: an exclusive lock (``flock``, released by the kernel when the process dies)
  on ``.corridor.lock``; a second batch on the same folder is refused.

This module imports nothing heavy, so these checks run before any simulation library is loaded.
"""

from __future__ import annotations

import datetime as _dt
import errno
import fcntl
import hashlib
import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from corridor import __version__
from corridor.errors import CorridorError, clip_path

MANIFEST = "batch.json"
LOCK = ".corridor.lock"
# What a batch writes, and so what --overwrite may delete (nothing else in the folder is touched).
OWNED = ("parts", "signals", "runs.parquet", "report.html", MANIFEST, ".runs.parquet.tmp",
         "stages", "estimate.json", "falsify.json", "counterexample.yaml",  # these four: --estimate/--falsify
         ".tmp")  # the runs' scratch folders (corridor.run.SCRATCH)


def scenario_hash(raw: dict[str, Any]) -> str:
    """SHA-256 of the resolved scenario data (``extends`` merged, ``--set`` applied), canonical JSON."""
    text = json.dumps(raw, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def manifest_for(name: str, source: str, raw: dict[str, Any], sets: list[str],
                 files: dict[str, list[int]] | None = None) -> dict[str, Any]:
    """What defines a batch; ``files``: path -> [size, mtime ns] of the files the scenario names (a
    user's own SUMO network, say), recorded only when there are some."""
    out = {"corridor_batch": 1, "scenario": name, "source": source, "scenario_sha256": scenario_hash(raw),
           "sets": list(sets), "version": __version__,
           "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
           "raw": json.loads(json.dumps(raw, default=str))}
    if files:
        out["files"] = files
    return out


def _flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(data, dict):
        out: dict[str, Any] = {}
        for k, v in data.items():
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        return out or {prefix: {}}
    return {prefix: data}


def _short(v: Any) -> str:
    text = json.dumps(v, default=str) if v is not _MISSING else "(absent)"
    return text if len(text) <= 30 else text[:29] + "…"


_MISSING = object()


def differences(old: dict[str, Any], new: dict[str, Any], limit: int = 3) -> str:
    """The first differing field paths of two scenario data trees, as ``path: old -> new``."""
    a, b = _flatten(old), _flatten(new)
    keys = sorted(k for k in a.keys() | b.keys() if a.get(k, _MISSING) != b.get(k, _MISSING))
    parts = [f"{k}: {_short(a.get(k, _MISSING))} -> {_short(b.get(k, _MISSING))}" for k in keys[:limit]]
    more = f" (+{len(keys) - limit} more)" if len(keys) > limit else ""
    return "; ".join(parts) + more


@dataclass
class BatchDir:
    """An opened, locked batch folder.  Keep it alive for the whole batch (the lock is its file)."""

    path: Path
    manifest: dict[str, Any]
    resumed: bool = False
    _lock_fd: int | None = field(default=None, repr=False)

    def discard(self) -> None:
        """Undo a fresh batch whose input was refused after the folder was opened (a column only a row
        could show missing): delete what this batch wrote and the lock, and the folder if then empty, so
        that the corrected command starts afresh.  Never for a resumed batch (its runs are kept)."""
        if self.resumed:
            return
        for name in OWNED:
            p = self.path / name
            if p.is_dir():
                shutil.rmtree(p)
            else:
                p.unlink(missing_ok=True)
        (self.path / LOCK).unlink(missing_ok=True)
        self.close()
        try:
            self.path.rmdir()
        except OSError:  # not empty: something else is there, keep it
            pass

    def close(self) -> None:
        if self._lock_fd is not None:
            try:
                (self.path / ".tmp").rmdir()  # the runs' scratch root, once empty
            except OSError:
                pass
            os.close(self._lock_fd)  # releases the flock
            self._lock_fd = None


def _lock(out: Path) -> int:
    fd = os.open(out / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
        os.close(fd)
        if exc.errno in (errno.EAGAIN, errno.EACCES):
            raise CorridorError(f"{out}: another batch (pid {holder}) is writing to this folder; "
                                "wait for it or choose another --out") from None
        raise
    os.ftruncate(fd, 0)
    os.pwrite(fd, str(os.getpid()).encode(), 0)
    return fd


def _holds_batch(out: Path) -> bool:
    return any((out / n).exists() for n in (MANIFEST, "parts", "runs.parquet"))


def _count_runs(out: Path) -> int:
    return len(list((out / "parts").glob("*.parquet"))) if (out / "parts").is_dir() else 0


def _make_dir(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise CorridorError(f"--out {out}: exists and is not a folder; choose a folder path")
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise CorridorError(f"--out {out}: cannot write there ({exc.strerror or exc}); "
                            "choose a writable folder") from None


def open_batch_dir(out: Path, manifest: dict[str, Any], resume: bool = False,
                   overwrite: bool = False) -> BatchDir:
    """Create or reopen ``out`` for a batch, enforcing the rules in the module docstring."""
    if resume and overwrite:
        raise CorridorError("--resume and --overwrite exclude each other: resume keeps runs, overwrite deletes them")
    _make_dir(out)
    fd = _lock(out)
    try:
        resumed = _check(out, manifest, resume, overwrite)
        shutil.rmtree(out / ".tmp", ignore_errors=True)  # scratch of runs killed mid-way (we hold the lock)
        if not resumed:
            tmp = out / f".{MANIFEST}.tmp"
            tmp.write_text(json.dumps(manifest, indent=1))
            os.replace(tmp, out / MANIFEST)
    except BaseException:
        os.close(fd)
        raise
    return BatchDir(out, manifest, resumed, fd)


def _check(out: Path, manifest: dict[str, Any], resume: bool, overwrite: bool) -> bool:
    """Returns True when an existing batch is resumed."""
    if not _holds_batch(out):
        others = [p.name for p in out.iterdir() if p.name != LOCK and not p.name.startswith(".write-test-")]
        if others:
            raise CorridorError(f"--out {out}: the folder is not empty and holds no corridor batch "
                                f"(e.g. {others[0]!r}); choose a new or empty folder")
        return False
    if overwrite:
        for name in OWNED:
            p = out / name
            if p.is_dir():
                shutil.rmtree(p)
            else:
                p.unlink(missing_ok=True)
        return False
    if not resume:
        raise CorridorError(f"{out} already holds a batch ({_count_runs(out)} runs); --resume completes it, "
                            "--overwrite replaces it, or choose another --out")
    old_path = out / MANIFEST
    if not old_path.exists():
        raise CorridorError(f"{out}: this batch has no {MANIFEST} (written by an older corridor), so its "
                            "settings cannot be checked; use --overwrite or another --out")
    try:
        old = json.loads(old_path.read_text())
    except (OSError, ValueError):
        raise CorridorError(f"{old_path}: unreadable; use --overwrite or another --out") from None
    if old.get("version") != manifest["version"]:
        raise CorridorError(f"--resume {out}: the batch was made by corridor {old.get('version')}, this is "
                            f"{manifest['version']}; rows would mix versions: use --overwrite or another --out")
    if old.get("scenario_sha256") != manifest["scenario_sha256"]:
        diff = differences(old.get("raw", {}), manifest["raw"]) or "scenario content"
        raise CorridorError(f"--resume {out}: settings differ from the stored batch ({diff}); "
                            "resume with the same scenario and --set, or use --overwrite or another --out")
    old_files, new_files = old.get("files", {}), manifest.get("files", {})
    if old_files != new_files:
        changed = sorted(f for f in old_files.keys() | new_files.keys() if old_files.get(f) != new_files.get(f))
        raise CorridorError(f"--resume {out}: {clip_path(changed[0], 80)} changed since the batch started "
                            "(size or modification time); rows would mix versions: use --overwrite or another --out")
    return True
