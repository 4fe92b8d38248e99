"""Files a scenario names (``ScenarioFile`` fields), relative to the scenario file's folder.

``scenario_dir(folder)`` sets the folder for the validation inside it and collects the files
resolved; ``file_stamps`` records their sizes and times for a batch folder (``--resume`` after one
changed is refused).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Annotated

from pydantic import AfterValidator

from corridor.errors import clip

# The folder of the scenario file being validated (set by ``load`` and by a run, see ``scenario_dir``):
# relative paths of ``ScenarioFile`` fields are taken from it.  Unset (a report re-reading a
# scenario), a relative path is kept as written and not checked.
_SCENARIO_DIR: ContextVar[Path | None] = ContextVar("corridor_scenario_dir", default=None)
_NAMED_FILES: ContextVar[set[str] | None] = ContextVar("corridor_named_files", default=None)


@contextmanager
def scenario_dir(folder: str | Path | None) -> Iterator[set[str]]:
    """Validate inside this block with relative ``ScenarioFile`` paths taken from ``folder``.

    Yields:
        The set of the files resolved in it (absolute paths).
    """
    named: set[str] = set()
    token = _SCENARIO_DIR.set(Path(folder).resolve() if folder is not None else None)
    files_token = _NAMED_FILES.set(named)
    try:
        yield named
    finally:
        _NAMED_FILES.reset(files_token)
        _SCENARIO_DIR.reset(token)


def file_stamps(files: set[str]) -> dict[str, list[int]]:
    """Size [B] and modification time [ns] of each file a scenario names: path -> [size, mtime].

    A batch folder records them: ``--resume`` after one changed is refused.
    """
    out: dict[str, list[int]] = {}
    for f in sorted(files):
        try:
            st = os.stat(f)
        except OSError:
            continue
        out[f] = [st.st_size, st.st_mtime_ns]
    return out


def resolving_files() -> bool:
    """True inside ``scenario_dir``: files a scenario names are resolved and must exist.

    A validator that reads them checks them only then.
    """
    return _SCENARIO_DIR.get() is not None


def _scenario_file(text: str) -> str:
    """The absolute path of a file named by a scenario, relative to the scenario file's folder.

    It must be an existing file (refused at load, one line).
    """
    base = _SCENARIO_DIR.get()
    path = Path(text).expanduser()
    if not text or "\0" in text:
        raise ValueError(f"{clip(text)} is not a file path")
    if base is None:
        return str(path)
    full = path if path.is_absolute() else base / path
    try:
        found = full.is_file()
    except OSError:  # a name too long for the file system, ...
        found = False
    if not found:
        where = "" if path.is_absolute() else f" (relative to the scenario's folder {clip(str(base), 80)[1:-1]})"
        what = "not a regular file" if os.path.lexists(full) else "no such file"
        raise ValueError(f"{what}: {clip(text, 80)}{where}")
    resolved = str(full.resolve())
    named = _NAMED_FILES.get()
    if named is not None:
        named.add(resolved)
    return resolved


ScenarioFile = Annotated[str, AfterValidator(_scenario_file)]  # a component's params field naming a file
