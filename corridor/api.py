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
    unless ``resume`` (continue the same batch) or ``overwrite`` (replace it) is given.
    """
    from corridor.cli import resolve_scenario
    from corridor.scenario import MAX_SEED, load

    if runs < 1:
        raise CorridorError(f"runs must be >= 1, got {runs}")
    path = resolve_scenario(str(scenario))
    sc, raw = load(path, list(sets))
    first = sc.seed if seed is None else seed
    if first < 0 or first + runs - 1 > MAX_SEED:
        raise CorridorError(f"{path}: seeds {first}..{first + runs - 1} (--seed, --runs) must lie in 0..{MAX_SEED}")
    out_dir = Path(out) if out is not None else Path("results") / sc.name
    bdir = open_batch_dir(out_dir, manifest_for(sc.name, str(path), raw, list(sets)), resume, overwrite)
    try:
        return _run_locked(sc, raw, path, bdir.path, runs, seed, list(variants), executor, workers, address,
                           progress, report, rerun, rerun_run)
    finally:
        bdir.close()


def _run_locked(sc: Scenario, raw: dict[str, Any], path: Path, out: Path, runs: int, seed: int | None,
                variants: list[str], executor: str, workers: int, address: str | None, progress: bool,
                report: bool, rerun: str | Path | None, rerun_run: str | None) -> BatchResult:
    from corridor import batch  # heavy imports only once the input is known to be good
    from corridor.results import ResultStore

    plan = batch.expand(sc, raw, str(path), runs, seed, str(out), variants)
    if rerun:
        target = rerun_run or plan[0].run_id
        plan.record(target, str(Path(rerun).resolve()))
        (out / "parts" / f"{target}.parquet").unlink(missing_ok=True)  # a resumed batch records it again
    store = ResultStore(out)
    batch.run_batch(plan, store, executor, workers, address, progress=progress)
    df = store.compact(plan.rank)
    if report:
        from corridor.reports import write_reports

        write_reports(df, sc, out, path)
    return BatchResult(df, out, sc)
