"""Objective and constraint expressions over a run's row (``-extra_path_m``, ``nmac == 0``).

An expression is Python syntax restricted to numbers, row columns (dotted names such as
``spec.safety.space`` are columns too), ``+ - * /``, unary minus, ``abs``/``min``/``max``, comparisons
and ``and``/``or``/``not``; it is parsed once (a bad one is a ``CorridorError`` naming it) and
evaluated on rows.  Used by ``run_scenario --learn`` and the Gymnasium environments' reward.
"""

from __future__ import annotations

import ast
import math
import operator
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from corridor.errors import CorridorError
from corridor.rare_event import column_name

_BIN = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv}
_CMP = {ast.Eq: operator.eq, ast.NotEq: operator.ne, ast.Lt: operator.lt, ast.LtE: operator.le,
        ast.Gt: operator.gt, ast.GtE: operator.ge}
_FUN: dict[str, Callable[..., float]] = {"abs": abs, "min": min, "max": max}


class Expression:
    """A parsed row expression; ``names`` are the columns it reads."""

    def __init__(self, text: str, what: str = "expression") -> None:
        self.text = text
        try:
            self._tree = ast.parse(text.strip(), mode="eval").body
        except SyntaxError as exc:
            raise CorridorError(f"{what} {text!r}: not an expression ({exc.msg})") from None
        self.names: set[str] = set()
        self._check(self._tree, what)

    def _check(self, node: ast.AST, what: str) -> None:
        name = column_name(node)
        if name is not None:
            self.names.add(name)
            return
        ok = (isinstance(node, ast.Constant) and isinstance(node.value, int | float) and not isinstance(node.value, bool)
              or isinstance(node, ast.BinOp) and type(node.op) in _BIN
              or isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub | ast.UAdd | ast.Not)
              or isinstance(node, ast.Compare) and all(type(o) in _CMP for o in node.ops)
              or isinstance(node, ast.BoolOp)
              or isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in _FUN
              and not node.keywords)
        if not ok:
            raise CorridorError(f"{what} {self.text!r}: {ast.unparse(node)!r} is not allowed "
                                "(numbers, columns, + - * /, abs/min/max, comparisons, and/or/not)")
        for child in (node.args if isinstance(node, ast.Call) else ast.iter_child_nodes(node)):
            if not isinstance(child, ast.operator | ast.cmpop | ast.unaryop | ast.boolop | ast.expr_context):
                self._check(child, what)

    def check_columns(self, columns: Iterable[str], what: str = "expression") -> None:
        """Refuse a column the rows will not have (one line naming the closest ones)."""
        known = set(columns)
        missing = sorted(self.names - known)
        if missing:
            import difflib

            hint = difflib.get_close_matches(missing[0], sorted(known), n=3)
            near = f" (did you mean {', '.join(hint)}?)" if hint else ""
            raise CorridorError(f"{what} {self.text!r}: unknown column {missing[0]!r}{near}")

    def __call__(self, row: Mapping[str, Any]) -> Any:
        return self._eval(self._tree, row)

    def _eval(self, node: ast.AST, row: Mapping[str, Any]) -> Any:
        name = column_name(node)
        if name is not None:
            v = row.get(name, math.nan)
            return math.nan if v is None else float(v)
        if isinstance(node, ast.Constant) and isinstance(node.value, int | float):
            return float(node.value)
        if isinstance(node, ast.BinOp):
            a, b = self._eval(node.left, row), self._eval(node.right, row)
            return a / b if isinstance(node.op, ast.Div) and b != 0 else (
                math.nan if isinstance(node.op, ast.Div) else _BIN[type(node.op)](a, b))
        if isinstance(node, ast.UnaryOp):
            v = self._eval(node.operand, row)
            return (not v) if isinstance(node.op, ast.Not) else (-v if isinstance(node.op, ast.USub) else v)
        if isinstance(node, ast.Compare):
            left, ok = self._eval(node.left, row), True
            for op, comp in zip(node.ops, node.comparators, strict=True):
                right = self._eval(comp, row)
                ok, left = ok and _CMP[type(op)](left, right), right
            return ok
        if isinstance(node, ast.BoolOp):
            vals = [bool(self._eval(v, row)) for v in node.values]
            return all(vals) if isinstance(node.op, ast.And) else any(vals)
        assert isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
        return _FUN[node.func.id](*(self._eval(a, row) for a in node.args))


def value(expr: Expression, row: Mapping[str, Any]) -> float:
    """The objective's value on a row (NaN when a column is missing or a run failed)."""
    v = expr(row)
    return float(v) if not isinstance(v, bool) else float(v)


def excess(constraint: Expression, row: Mapping[str, Any]) -> float:
    """How far the row is past a broken single comparison ``a OP b`` (``hard_brakes <= 3`` at 8: 5.0;
    ``a == b``: |a - b|); 0 when it holds, or for a constraint of another form; NaN as NaN."""
    tree = constraint._tree
    if bool(constraint(row)) or not (isinstance(tree, ast.Compare) and len(tree.ops) == 1):
        return 0.0
    a, b = constraint._eval(tree.left, row), constraint._eval(tree.comparators[0], row)
    op = type(tree.ops[0])
    d = a - b if op in (ast.Lt, ast.LtE) else b - a if op in (ast.Gt, ast.GtE) else abs(a - b) if op is ast.Eq else 0.0
    return max(float(d), 0.0) if not math.isnan(d) else math.nan


def hinge_violations(constraints: Iterable[Expression], row: Mapping[str, Any]) -> float:
    """Sum over the broken constraints of 1 + its ``excess``: grows with how far a row is past a bound
    (a missing column or NaN counts as 1, like ``violations``)."""
    total = 0.0
    for c in constraints:
        if not bool(c(row)):
            e = excess(c, row)
            total += 1.0 + (e if math.isfinite(e) else 0.0)
    return total


def violations(constraints: Iterable[Expression], row: Mapping[str, Any]) -> int:
    """How many constraints the row breaks (a constraint on a missing column counts as broken)."""
    return sum(1 for c in constraints if not bool(c(row)))
