"""``run_scenario``: run a scenario file once or as a Monte Carlo batch."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from corridor.errors import CorridorError

EXAMPLES = """\
examples:
  run_scenario scenarios/merging.yaml                      one run per variant, default seed
  run_scenario scenarios/merging.yaml --runs 20 --out results/merging
                                                           20 seeds x every variant, report in results/merging
  run_scenario merging --set road.demand.scale=1.2         a packaged scenario by name, 20 % more demand
  run_scenario scenarios/merging.yaml --variant sumo_default --runs 4 --seed 7
  run_scenario scenarios/merging.yaml --runs 8 --resume    finish a batch that was interrupted
  run_scenario scenarios/merging.yaml --rerun out.rrd      also record the first run for the Rerun viewer
  run_scenario scenarios/merging.yaml --executor ray --address auto

--set takes any field path of the scenario (see the YAML file): a.b.c=VALUE, VALUE in YAML syntax
(3, 0.5, true, [1, 2], {a: 1}).  Errors in the scenario or the options print one line and exit 2;
a batch in which some runs failed exits 1 (the failed runs are rows with status=error).
"""


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="run_scenario", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EXAMPLES,
        description="Run a corridor scenario (YAML) as a batch: seeds x sweep variants x randomized "
                    "draws. Writes DIR/runs.parquet (one row per run) and DIR/report.html, and prints "
                    "a summary table per variant.")
    p.add_argument("scenario", nargs="?", default="merging",
                   help="scenario file, or the name of a packaged scenario (default: merging)")
    p.add_argument("--runs", type=int, default=1, metavar="N", help="seeds per variant (default 1)")
    p.add_argument("--seed", type=int, default=None, metavar="S",
                   help="first seed; runs use S, S+1, ... (default: the scenario's seed)")
    p.add_argument("--set", action="append", default=[], metavar="A.B=C", dest="sets",
                   help="override any scenario field (repeatable)")
    p.add_argument("--variant", action="append", default=[], metavar="NAME",
                   help="run only these sweep variants (repeatable; default: all)")
    p.add_argument("--out", default=None, metavar="DIR", help="output folder (default: results/<name>)")
    p.add_argument("--workers", type=int, default=max(1, os.cpu_count() or 1), metavar="N",
                   help="parallel run processes for --executor local (default: CPU count)")
    p.add_argument("--executor", choices=["local", "ray"], default="local",
                   help="local process pool (default) or a Ray cluster (pip install 'corridor[ray]')")
    p.add_argument("--address", default=None, help="Ray cluster address, e.g. auto")
    p.add_argument("--resume", action="store_true", help="keep finished runs in DIR and run the rest")
    p.add_argument("--rerun", default=None, metavar="FILE.rrd", help="record one run for the Rerun viewer")
    p.add_argument("--rerun-run", default=None, metavar="RUN_ID",
                   help="which run to record (default: the first), e.g. sumo_default-s0")
    p.add_argument("--no-report", action="store_true", help="skip report.html")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no summary table")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    args = p.parse_args(argv)
    if args.runs < 1:
        p.error("--runs must be >= 1")
    if args.workers < 1:
        p.error("--workers must be >= 1")
    return args


def resolve_scenario(name: str) -> Path:
    path = Path(name)
    try:
        exists = path.exists()
    except OSError:  # e.g. a name too long for the file system
        exists = False
    if exists or path.suffix in (".yaml", ".yml"):
        return path
    dirs = [Path(__file__).resolve().parent.parent / "scenarios"]
    try:
        import corridor.scenarios as pkg  # installed wheel: scenarios ship as package data

        dirs += [Path(p) for p in pkg.__path__]
    except ImportError:
        pass
    if len(name) <= 64 and name.replace("_", "").replace("-", "").isalnum():  # a bare name, not a path
        for d in dirs:
            if (d / f"{name}.yaml").is_file():
                return d / f"{name}.yaml"
    from corridor.errors import ScenarioError, clip

    names = sorted({p.stem for d in dirs if d.is_dir() for p in d.glob("*.yaml")})
    raise ScenarioError(f"{clip(name)}: no such file, and no packaged scenario of that name "
                        f"(packaged: {', '.join(names)})")


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        return _main(args)
    except CorridorError as exc:
        if args.debug:
            raise
        print(f"run_scenario: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("run_scenario: interrupted; finished runs are kept, continue with --resume", file=sys.stderr)
        return 130


def _main(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from corridor import batch
    from corridor.results import ResultStore
    from corridor.scenario import load
    from corridor.summary import summary_table

    path = resolve_scenario(args.scenario)
    sc, raw = load(path, args.sets)
    out = Path(args.out or f"results/{sc.name}")
    specs = batch.expand(sc, raw, str(path), args.runs, args.seed, str(out), args.variant)
    if args.rerun:
        target = args.rerun_run or specs[0].run_id
        idx = next((i for i, s in enumerate(specs) if s.run_id == target), None)
        if idx is None:
            raise CorridorError(f"--rerun-run {target!r}: no such run; runs are {', '.join(s.run_id for s in specs[:6])}, ...")
        specs[idx] = replace(specs[idx], rerun_path=str(Path(args.rerun).resolve()))
    store = ResultStore(out, resume=args.resume)
    if args.rerun and args.resume:
        (out / "parts" / f"{specs[idx].run_id}.parquet").unlink(missing_ok=True)  # record it again
    batch.run_batch(specs, store, args.executor, args.workers, args.address, progress=not args.quiet)
    df = store.compact([s.run_id for s in specs])
    if not args.no_report:
        from corridor.analysis.report import write_report
        from corridor.analysis.report_series import report_sections

        write_report(df, sc, out / "report.html", extra_sections=report_sections(out, df, sc, path))
    if not args.quiet:
        print(summary_table(df, sc.metrics))
        print(f"\nresults: {out / 'runs.parquet'}" + ("" if args.no_report else f"\nreport:  {out / 'report.html'}"))
        if args.rerun:
            print(f"rerun:   {args.rerun}  (open with: rerun {args.rerun})")
    errors = df[df["status"] != "ok"]
    for _, r in errors.head(5).iterrows():
        print(f"run {r['run_id']} failed: {r['error']}", file=sys.stderr)
    return 1 if len(errors) else 0


if __name__ == "__main__":
    sys.exit(main())
