"""Signal temporal logic: formulas, parser, space and time robustness, online monitoring.

>>> from corridor.stl import evaluate_spec
>>> result = evaluate_spec("G[0,30](gap_lead > 5)", {"gap_lead": gaps}, dt=0.1)  # doctest: +SKIP
"""

from __future__ import annotations

from corridor.stl.formula import (
    Always,
    And,
    BinOp,
    Call,
    Const,
    Eventually,
    Expr,
    Formula,
    Implies,
    Neg,
    Not,
    Or,
    Predicate,
    Until,
    Var,
    all_of,
    any_of,
    var,
)
from corridor.stl.online import OnlineMonitor
from corridor.stl.parser import STLSyntaxError, as_formula, parse_formula
from corridor.stl.space import STLSignalError, space_robustness
from corridor.stl.spec import SpecResult, evaluate_spec
from corridor.stl.time_rob import TimeRobustness, time_robustness

__all__ = [
    "Always", "And", "BinOp", "Call", "Const", "Eventually", "Expr", "Formula", "Implies", "Neg", "Not",
    "OnlineMonitor", "Or", "Predicate", "STLSignalError", "STLSyntaxError", "SpecResult", "TimeRobustness",
    "Until", "Var", "all_of", "any_of", "as_formula", "evaluate_spec", "parse_formula", "space_robustness", "time_robustness",
    "var",
]
