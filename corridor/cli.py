"""``run_scenario``: run a scenario file once or as a Monte Carlo batch."""

from __future__ import annotations

import argparse
import os
import sys

from corridor.errors import CorridorError

EXAMPLES = """\
examples:
  run_scenario scenarios/merging.yaml                      one run per variant, default seed -> results/merging
  run_scenario scenarios/merging.yaml --runs 20 --out results/merging20
                                                           20 seeds x every variant, report in results/merging20
  run_scenario merging --set road.demand.scale=1.2 --out results/m12
                                                           a packaged scenario by name, 20 % more demand
  run_scenario scenarios/merging.yaml --variant sumo_default --runs 4 --seed 7 --out results/sumo7
  run_scenario merging --set sweep.v2x_cps.controllers.merge.params.policy=fifo --out results/p
                                                           a parameter of one sweep variant
  run_scenario scenarios/merging.yaml --runs 8 --resume    finish (or extend) the batch in results/merging
  run_scenario scenarios/merging.yaml --overwrite          replace the batch in results/merging
  run_scenario scenarios/merging.yaml --rerun out.rrd --out results/rec
                                                           also record the first run for the Rerun viewer
  run_scenario scenarios/merging.yaml --executor ray --out results/ray      a private local Ray
  run_scenario uav_encounter --estimate 'nmac > 0' --level sep_min_h_m --method ce --budget 1000
                                                           P(NMAC) by importance sampling (see "Safety statistics")
  run_scenario uav_encounter --learn avoid_enter.dist_m --objective -path_ratio_mean --constraint 'nmac == 0' \\
      --method blrl --budget 48 --variant potential_field    learn a mode boundary (see "Modes and boundaries")
  run_scenario overtaking --falsify safety_space --budget 200
                                                           search for a violation; writes DIR/counterexample.yaml

Output folders: a batch writes only inside DIR (--out, default results/<name>) and the --rerun file
you name: batch.json (what defines the batch), parts/ (one file per finished run), runs.parquet,
report.html, signals/.  A folder that holds a batch is never deleted implicitly: a second batch there is refused unless you --resume
it (same scenario and --set only) or --overwrite it.  Two batches cannot write one folder at once.
Ctrl-C stops the batch at once and keeps every finished run (exit 130; continue with --resume).

--set takes any field path of the scenario (see the YAML file): a.b.c=VALUE, VALUE in YAML syntax
(3, 0.5, true, [1, 2], {a: 1}).  Randomized fields draw from their own stream per seed, so fixing one
with --set leaves the draws of the others unchanged.  A --set wins over a sweep variant that sets the
same field (--set sweep.VARIANT.a.b=VALUE changes one variant only).  Errors in the scenario or the
options print one line and exit 2; a batch in which some runs failed exits 1 (the failed runs are rows
with status=error).

Python: corridor.api.run(...) takes the same options and returns the rows and signals.
"""


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="run_scenario", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EXAMPLES,
        description="Run a corridor scenario (YAML) as a batch: seeds x sweep variants x randomized "
                    "draws. Writes DIR/runs.parquet (one row per run) and DIR/report.html, and prints "
                    "a summary table per variant.")
    p.add_argument("scenario", nargs="?", default="merging",
                   help="scenario file, or the name of a packaged scenario (default: merging)")
    p.add_argument("--runs", type=int, default=1, metavar="N",
                   help="seeds per variant (default 1); runs are created lazily, one at a time")
    p.add_argument("--seed", type=int, default=None, metavar="S",
                   help="first seed; runs use S, S+1, ... (default: the scenario's seed)")
    p.add_argument("--set", action="append", default=[], metavar="A.B=C", dest="sets",
                   help="override any scenario field (repeatable)")
    p.add_argument("--variant", action="append", default=[], metavar="NAME",
                   help="run only these sweep variants (repeatable; default: all)")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="batch folder (default: results/<name>). A folder that already holds a batch is "
                        "never deleted implicitly: use --resume or --overwrite, or another folder")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the batch already in DIR (deletes its runs, report and signals)")
    p.add_argument("--workers", type=int, default=max(1, os.cpu_count() or 1), metavar="N",
                   help="parallel run processes for --executor local (default: CPU count)")
    p.add_argument("--executor", choices=["local", "ray"], default="local",
                   help="local processes (default) or a Ray cluster (pip install -e '.[ray]' in the clone)")
    p.add_argument("--address", default=None,
                   help="Ray cluster address (default: start a private local Ray); 'auto' attaches to any "
                        "Ray cluster already running on this host")
    p.add_argument("--resume", action="store_true",
                   help="continue the batch in DIR: keep its finished runs, run the rest (refused if the "
                        "scenario or --set differ from the stored batch)")
    p.add_argument("--rerun", default=None, metavar="FILE.rrd", help="record one run for the Rerun viewer")
    p.add_argument("--rerun-run", default=None, metavar="RUN_ID",
                   help="which run to record (default: the first), e.g. sumo_default-s0")
    p.add_argument("--no-report", action="store_true", help="skip report.html")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no summary table")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    r = p.add_argument_group("safety statistics (a batch of adaptive stages instead of --runs)")
    r.add_argument("--estimate", default=None, metavar="EVENT",
                   help="estimate P(EVENT): an expression over the columns of a run's row ('collisions > 0', "
                        "'nmac > 0 or sep_min_h_m < 10'; an unknown column is an error), or spec:NAME "
                        "(robustness < 0); default DIR results/<name>-<method>")
    r.add_argument("--method", default=None, metavar="METHOD",
                   help="naive: plain Monte Carlo (Clopper-Pearson); ce: cross-entropy importance sampling "
                        "(default); splitting: subset simulation; splitting_is: subset simulation, then importance "
                        "sampling with a Gaussian mixture (several failure modes); or an installed "
                        "corridor.estimators plug-in.  Least --budget: ce and splitting 100, splitting_is 200")
    r.add_argument("--budget", type=int, default=None, metavar="N", help="runs the estimate or search may use")
    r.add_argument("--level", default=None, metavar="COLUMN",
                   help="level function of ce/splitting: a row column, smaller = closer to failure ('-COL': "
                        "larger is); default: the spec's robustness, or a - b of a single comparison 'a < b'")
    r.add_argument("--falsify", default=None, metavar="SPEC",
                   help="minimise SPEC's robustness over the randomized inputs (CMA-ES); writes "
                        "DIR/counterexample.yaml on a violation; default DIR results/<name>-falsify")
    learn = p.add_argument_group("learning mode boundaries (stages of runs instead of --runs)")
    learn.add_argument("--learn", default=None, metavar="KEYS",
                       help="boundary parameters to learn, comma-separated (avoid_enter.dist_m,avoid_enter.ttc_s); "
                            "with --objective, --budget and --method blrl|cma|ppo")
    learn.add_argument("--objective", default=None, metavar="EXPR",
                       help="maximised over the row, e.g. '-path_ratio_mean'")
    learn.add_argument("--constraint", action="append", default=None, metavar="EXPR",
                       help="a safety constraint on the row (repeatable; default 'collisions == 0')")
    learn.add_argument("--penalty", default="count", choices=("count", "hinge"),
                       help="per broken --constraint: 1 (count, default), or 1 + how far the row is past "
                            "its bound (hinge: 'hard_brakes <= 3' at 8 costs 6)")
    learn.add_argument("--holdout", type=int, default=20, metavar="N",
                       help="held-out seeds on which the hand-tuned and learned boundaries are compared")
    args = p.parse_args(_glue_expressions(sys.argv[1:] if argv is None else list(argv)))
    if args.learn is not None:
        _check_learn(p, args)
    elif args.objective is not None or args.constraint is not None or args.penalty != "count":
        p.error("--objective, --constraint and --penalty go with --learn KEYS")
    if args.runs < 1:
        p.error("--runs must be >= 1")
    if args.workers < 1:
        p.error("--workers must be >= 1")
    if args.method is not None and args.estimate is None and args.learn is None:
        p.error("--method goes with --estimate EVENT (--falsify has its own search)")
    if args.level is not None and args.estimate is None:
        p.error("--level goes with --estimate EVENT")
    if args.estimate is not None and args.falsify is not None:
        p.error("--estimate and --falsify exclude each other")
    if (args.estimate is not None or args.falsify is not None or args.learn is not None) != (args.budget is not None):
        p.error("--budget N goes with --estimate, --falsify or --learn (and they need it)")
    if (args.estimate is not None or args.falsify is not None) and (args.runs != 1 or args.rerun):
        p.error("--runs and --rerun do not apply to --estimate/--falsify (the method chooses the runs)")
    if args.budget is not None and args.budget < 1:
        p.error("--budget must be >= 1")
    return args


def _glue_expressions(argv: list[str]) -> list[str]:
    """``--objective -path_ratio_mean``: an expression may start with a minus (argparse would take it
    for an option), so the value after ``--objective``/``--constraint`` is glued to it."""
    out: list[str] = []
    it = iter(argv)
    for a in it:
        if a in ("--objective", "--constraint"):
            nxt = next(it, None)
            out.append(a if nxt is None else f"{a}={nxt}")
        else:
            out.append(a)
    return out


def _check_learn(p: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    if args.estimate is not None or args.falsify is not None:
        p.error("--learn excludes --estimate and --falsify")
    if args.objective is None or args.method is None:
        p.error("--learn KEYS needs --objective EXPR and --method blrl|cma|ppo")
    if args.runs != 1 or args.rerun:
        p.error("--runs and --rerun do not apply to --learn (the method chooses the runs)")


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
        print("run_scenario: interrupted; finished runs are kept: continue with the same command and --resume",
              file=sys.stderr)
        return 130


def _main(args: argparse.Namespace) -> int:
    if args.learn is not None:
        return _learn(args)
    if args.estimate is not None or args.falsify is not None:
        return _rare(args)
    from corridor.api import run

    res = run(args.scenario, runs=args.runs, seed=args.seed, sets=args.sets, variants=args.variant,
              out=args.out, resume=args.resume, overwrite=args.overwrite, executor=args.executor,
              workers=args.workers, address=args.address, progress=not args.quiet,
              report=not args.no_report, rerun=args.rerun, rerun_run=args.rerun_run)
    df, out = res.rows, res.out
    if not args.quiet:
        from corridor.summary import print_summary
        from corridor.variants import collisions_apply

        print_summary(df, res.scenario.metrics, collisions=collisions_apply(df, res.scenario))
        print(f"\nresults: {out / 'runs.parquet'}" + ("" if args.no_report else f"\nreport:  {out / 'report.html'}"))
        if args.rerun:
            print(f"rerun:   {args.rerun}  (open with: rerun {args.rerun})")
    errors = df[df["status"] != "ok"]
    for _, r in errors.head(5).iterrows():
        print(f"run {r['run_id']} failed: {r['error']}", file=sys.stderr)
    return 1 if len(errors) else 0



def _learn(args: argparse.Namespace) -> int:
    from corridor import learn

    if len(args.variant) > 1:
        raise CorridorError("--learn tunes one sweep variant: give at most one --variant")
    data = learn.learn(args.scenario, args.learn, args.objective, budget=args.budget, method=args.method,
                       constraints=args.constraint or ("collisions == 0",),
                       variant=args.variant[0] if args.variant else None, holdout_runs=args.holdout, seed=args.seed,
                       sets=args.sets, out=args.out, resume=args.resume, overwrite=args.overwrite,
                       executor=args.executor, workers=args.workers, address=args.address, progress=not args.quiet,
                       penalty=args.penalty)
    if not args.quiet:
        print("\n".join(learn.learn_lines(data)))
    return 0


def _rare(args: argparse.Namespace) -> int:
    from corridor import rare_api
    from corridor.estimate import EstimateRunError

    variant = args.variant[0] if args.variant else None
    if len(args.variant) > 1:
        raise CorridorError("--estimate/--falsify run one sweep variant: give at most one --variant")
    common = dict(seed=args.seed, sets=args.sets, variant=variant, out=args.out, resume=args.resume,
                  overwrite=args.overwrite, executor=args.executor, workers=args.workers, address=args.address,
                  progress=not args.quiet, report=not args.no_report)
    try:
        if args.falsify is not None:
            data = rare_api.falsify(args.scenario, args.falsify, budget=args.budget, **common)
        else:
            data = rare_api.estimate(args.scenario, args.estimate, method=args.method or "ce", budget=args.budget,
                                     level=args.level, **common)
    except EstimateRunError as exc:
        print(f"run_scenario: {exc}", file=sys.stderr)
        return 1
    if not args.quiet:
        from corridor.estimate import print_rare

        print_rare(data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
