"""Sparsity of the ramp MPC's KKT matrix on the METANET beltway: what couples what, and the fill-in.

For each beltway size it builds the MPC's NLP (``RampMeteringMPC.nlp``), takes CasADi's structural
Jacobian of the constraints J and Hessian of the Lagrangian H, and prints

* per constraint family (rho, v, w dynamics rows, queue rows): row degree in J and the largest
  ring distance [km] and time span [model steps] between the variables one row touches;
* per variable family (rho, v, w states, rates R, splits S, slacks): degree in H and in J, and the
  largest distance H couples;
* the fill of a symbolic Cholesky factorization of the KKT pattern [[H + I, J'], [J, -I]] under
  SuperLU's orderings (multiple minimum degree on A'+A, COLAMD) and reverse Cuthill-McKee (a band
  along the ring: linear in the ring's length, but wide): nnz(L) and the factorization's flop count
  sum(colcount^2), with the growth per size step.

    python benchmarks/mpc_kkt_structure.py [--sizes 4 8 16 32] [--horizons 5] [--orderings mmd colamd rcm] [--quiet]
"""

from __future__ import annotations

import argparse

from corridor.controllers.ramp_metering.mpc import MPCConfig, RampMeteringMPC
from corridor.controllers.ramp_metering.mpc_structure import (
    beltway_geometry,
    family_table,
    kkt_matrix,
    kkt_patterns,
    ordering_fill,
)
from corridor.traffic.macro.metanet_networks import BeltwayLayout, beltway


def analyse(n: int, horizon: int, orderings: tuple[str, ...]) -> dict[str, object]:
    """Structure and fill figures of the n-interchange beltway MPC with the given horizon."""
    layout = BeltwayLayout(n_interchanges=n, lanes=2, trip_exponent=2.0)
    mpc = RampMeteringMPC(beltway(layout), MPCConfig(horizon_ctrl_steps=horizon))
    jac, hess = kkt_patterns(mpc)
    var, con = beltway_geometry(mpc, layout)
    kkt = kkt_matrix(jac, hess)
    fills = {o: ordering_fill(kkt, o) for o in orderings}
    return {"n": n, "horizon": horizon, "nz": jac.shape[1], "ng": jac.shape[0], "nnz_j": jac.nnz,
            "nnz_h": hess.nnz, "kkt": kkt.shape[0], "rows": family_table(jac, con, var),
            "hess": family_table(hess, var, var), "jcols": family_table(jac.T.tocsr(), var, con),
            "fill": fills, "steps": mpc.n}


def _print_case(r: dict[str, object]) -> None:
    print(f"\n== {r['n']} interchanges, horizon {r['horizon']} control steps ({r['steps']} model steps): "
          f"{r['nz']} variables, {r['ng']} constraints, nnz J {r['nnz_j']}, nnz H {r['nnz_h']}, KKT {r['kkt']}")
    for title, key in (("constraint rows in J", "rows"), ("variables in H", "hess"), ("variables in J", "jcols")):
        print(f"  {title}: family  mean deg / max deg / max ring distance [km] / max time span [steps]")
        for fam, (mean, mx, dist, span) in r[key].items():  # type: ignore[attr-defined]
            print(f"    {fam:>8}: {mean:6.2f} {mx:5d} {dist:7.1f} {span:5.0f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[4, 8, 16, 32])
    ap.add_argument("--horizons", type=int, nargs="+", default=[5])
    ap.add_argument("--orderings", nargs="+", default=["mmd", "colamd", "rcm"], choices=["mmd", "colamd", "rcm"])
    ap.add_argument("--quiet", action="store_true", help="only the fill table")
    args = ap.parse_args()
    orderings = tuple(args.orderings)
    results = [analyse(n, h, orderings) for h in args.horizons for n in args.sizes]
    for r in results if not args.quiet else []:
        _print_case(r)
    print("\nfill of the KKT pattern's Cholesky factor: nnz(L) [k] / flops [M] per ordering, and growth")
    print(f"{'interch.':>9}{'horizon':>8}{'KKT':>8}" + "".join(f"{o + ' nnzL':>12}{o + ' Mflop':>13}" for o in orderings))
    prev: dict[str, object] | None = None
    for r in results:
        fill = r["fill"]  # type: ignore[index]
        line = f"{r['n']:>9}{r['horizon']:>8}{r['kkt']:>8}"
        for o in orderings:
            nnz, fl = fill[o]  # type: ignore[index]
            grow = ""
            if prev is not None and prev["horizon"] == r["horizon"]:
                grow = f"x{fl / prev['fill'][o][1]:.1f}"  # type: ignore[index]
            line += f"{nnz / 1e3:>12.0f}{fl / 1e6:>8.1f}{grow:>5}"
        print(line)
        prev = r


if __name__ == "__main__":
    main()
