"""The Python entry point: run a scenario batch from Python and get the rows and the signals.

``run_scenario`` (the CLI) is a thin shell around :func:`run`, so the rows are the CLI's, variants,
seeds and randomized draws included::

    from corridor.api import run

    res = run("scenarios/merging.yaml", runs=4, sets=["duration=120"], out="results/m4")
    res.rows                       # pandas DataFrame, one row per run (as runs.parquet)
    res.signals("sumo_default-s0") # {signal name: array}, e.g. "min_ttc" -> times and values

Errors a user can fix raise :class:`corridor.errors.CorridorError` (one-line message).  The scenario
is loaded and validated, and the output folder checked and locked, before any simulation library is
imported, so a typo fails in a fraction of a second.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from corridor.batchdir import manifest_for, open_batch_dir
from corridor.errors import CorridorError

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np
    import pandas as pd

    from corridor.scenario import Scenario


@dataclass(frozen=True)
class BatchResult:
    """A finished batch: its rows, its folder and the scenario it ran."""

    rows: pd.DataFrame  # one row per run of the batch (the content of runs.parquet)
    out: Path  # the batch folder
    scenario: Scenario  # the validated base scenario (--set applied; variants and draws are per run)

    def signals(self, run_id: str) -> dict[str, np.ndarray]:
        """The recorded time series of one run: ``name`` -> values and ``name.t`` -> times [s]."""
        import numpy as np

        path = self.out / "signals" / f"{run_id}.npz"
        if not path.exists():
            raise CorridorError(f"{path}: no signals for run {run_id!r} (outputs.signals off, or no such run)")
        with np.load(path) as data:
            return {k: data[k] for k in data.files}

    @property
    def failed(self) -> pd.DataFrame:
        """The rows whose run did not end ``ok`` (``status`` error), with their ``error`` message."""
        return self.rows[self.rows["status"] != "ok"]


def run(scenario: str | Path = "merging", *, runs: int = 1, seed: int | None = None,
        sets: Sequence[str] = (), variants: Sequence[str] = (), out: str | Path | None = None,
        resume: bool = False, overwrite: bool = False, executor: str = "local", workers: int = 2,
        address: str | None = None, progress: bool = False, report: bool = True,
        rerun: str | Path | None = None, rerun_run: str | None = None) -> BatchResult:
    """Run a scenario (a file, or a packaged scenario's name) as a batch; see ``run_scenario --help``.

    ``out`` defaults to ``results/<scenario name>``.  A folder that already holds a batch is refused
    unless ``resume`` (continue the same batch) or ``overwrite`` (replace it) is given.  Every input is
    checked (one-line ``CorridorError``) before the folder is created or touched.
    """
    from corridor import batch
    from corridor.scenario import MAX_SEED, file_stamps, load_with_files, resolve_scenario, set_overrides

    check_options(runs=runs, seed=seed, sets=sets, variants=variants, executor=executor, workers=workers)
    path = resolve_scenario(str(scenario))
    sc, raw, named = load_with_files(path, list(sets))
    first = sc.seed if seed is None else seed
    if first < 0 or first + runs - 1 > MAX_SEED:
        raise CorridorError(f"{path}: seeds {first}..{first + runs - 1} (--seed, --runs) must lie in 0..{MAX_SEED}")
    out_dir = Path(out) if out is not None else Path("results") / sc.name
    plan = batch.expand(sc, raw, str(path), runs, seed, str(out_dir), list(variants), set_overrides(sets))
    if rerun:
        plan.record(rerun_run or plan[0].run_id, str(Path(rerun).resolve()))
    elif rerun_run is not None:
        raise CorridorError("--rerun-run names the run to record: give --rerun FILE.rrd too")
    bdir = open_batch_dir(out_dir, manifest_for(sc.name, str(path), raw, list(sets), file_stamps(named)), resume,
                          overwrite)
    try:
        return _run_locked(sc, path, bdir.path, plan, executor, workers, address, progress, report, rerun)
    finally:
        bdir.close()


def _int(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise CorridorError(f"{name} must be a whole number, got {type(value).__name__} {value!r:.40}")
    return value


def check_options(*, runs: int | None = None, seed: int | None = None, sets: Sequence[str] = (),
                  variants: Sequence[str] = (), executor: str = "local", workers: int = 2) -> None:
    """Check the options of a batch as the command line checks them.

    ``run_scenario`` parses them into these types; a wrong type or value is a one-line
    ``CorridorError``.
    """
    from corridor.scenario import MAX_SEED

    if runs is not None and _int("runs", runs) < 1:
        raise CorridorError(f"runs must be >= 1, got {runs}")
    if seed is not None and not 0 <= _int("seed", seed) <= MAX_SEED:
        raise CorridorError(f"seed must lie in 0..{MAX_SEED}, got {seed}")
    for name, seq in (("sets", sets), ("variants", variants)):
        if isinstance(seq, str | bytes) or not isinstance(seq, Sequence):
            example = "sets=['duration=60']" if name == "sets" else "variants=['default']"
            raise CorridorError(f"{name} must be a list of strings (e.g. {example}), got {type(seq).__name__} "
                                f"{seq!r:.40}")
        bad = [v for v in seq if not isinstance(v, str)]
        if bad:
            raise CorridorError(f"{name} must be a list of strings, got the item {bad[0]!r:.40}")
    if executor not in EXECUTORS:
        raise CorridorError(f"executor {executor!r:.40}: must be one of {', '.join(EXECUTORS)}")
    if executor == "ray" and importlib.util.find_spec("ray") is None:  # before the folder, not in run_batch
        raise CorridorError("--executor ray needs Ray: pip install -e '.[ray]' in the corridor clone")
    if _int("workers", workers) < 1:
        raise CorridorError(f"workers must be >= 1, got {workers}")


EXECUTORS = ("local", "ray")


def _run_locked(sc: Scenario, path: Path, out: Path, plan: Any, executor: str, workers: int,
                address: str | None, progress: bool, report: bool, rerun: str | Path | None) -> BatchResult:
    from corridor import batch  # heavy imports only once the input is known to be good
    from corridor.results import ResultStore

    for target in plan.recorded():
        (out / "parts" / f"{target}.parquet").unlink(missing_ok=True)  # a resumed batch records it again
    store = ResultStore(out)
    batch.run_batch(plan, store, executor, workers, address, progress=progress)
    df = store.compact(plan.rank)
    if report:
        from corridor.reports import write_reports

        write_reports(df, sc, out, path)
    return BatchResult(df, out, sc)
