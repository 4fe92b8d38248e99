"""The failure event and the level function of a rare-event estimate (``--estimate``, ``--level``).

``EVENT`` is either ``spec:NAME`` (failure: the spec's robustness ``spec.NAME.space`` is below 0) or a
boolean expression over the columns of a run's row: comparisons of columns and numbers joined with
``and``, ``or``, ``not`` and parentheses, e.g. ``collisions > 0``, ``nmac > 0 or min_sep_h_m < 10``.
Dotted column names are allowed (``spec.safety.space < -0.5``).  The expression is parsed into a
small tree of these node kinds only (Python's ``ast`` as the parser, never ``eval``).

The level function (``--level COL``: smaller is closer to failure, ``--level=-COL``: larger is) guides
the adaptive methods; by default it is the spec's robustness, or ``a - b`` of a single comparison.
"""

from __future__ import annotations

import ast
import math
import operator
from dataclasses import dataclass
from typing import Any

from corridor.errors import CorridorError, clip

_CMP = {ast.Lt: operator.lt, ast.LtE: operator.le, ast.Gt: operator.gt, ast.GtE: operator.ge,
        ast.Eq: operator.eq, ast.NotEq: operator.ne}


def column_name(node: ast.AST) -> str | None:
    """The dotted column a name or attribute node reads (``a.b.c``), None for any other node."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        head = column_name(node.value)
        return None if head is None else f"{head}.{node.attr}"
    return None


def _number(node: ast.AST) -> float | None:
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        inner = _number(node.operand)
        return None if inner is None else -inner
    if isinstance(node, ast.Constant) and isinstance(node.value, int | float) and not isinstance(node.value, bool):
        try:
            value = float(node.value)
        except OverflowError:  # an integer beyond the float range (a 400-digit literal)
            value = math.inf
        if not math.isfinite(value):  # 1e400 parses as inf
            raise CorridorError(f"--estimate: the number {clip(str(node.value), 20)} is beyond the float range "
                                "(|x| < 1.8e308)")
        return value
    return None


@dataclass(frozen=True)
class Event:
    """A parsed failure event; ``fails(row)`` says whether a run's row is a failure."""

    text: str
    tree: ast.Expression
    columns: tuple[str, ...]
    spec: str | None = None

    def fails(self, row: dict[str, Any]) -> bool:
        if self.spec is not None:  # robustness below 0 (NaN: never judged satisfied, so a failure)
            value = self._value(ast.Name(self.columns[0]), row)
            return not value >= 0
        return bool(self._eval(self.tree.body, row))

    def _eval(self, node: ast.AST, row: dict[str, Any]) -> Any:
        if isinstance(node, ast.BoolOp):
            vals = [self._eval(v, row) for v in node.values]
            return all(vals) if isinstance(node.op, ast.And) else any(vals)
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
            return not self._eval(node.operand, row)
        if isinstance(node, ast.Compare):
            left = self._value(node.left, row)
            for op, right_node in zip(node.ops, node.comparators, strict=True):
                right = self._value(right_node, row)
                if not _CMP[type(op)](left, right):
                    return False
                left = right
            return True
        return bool(self._value(node, row))

    def _value(self, node: ast.AST, row: dict[str, Any]) -> float:
        num = _number(node)
        if num is not None:
            return num
        col = column_name(node)
        value = row.get(col, math.nan) if col is not None else math.nan
        try:
            return float(value)
        except (TypeError, ValueError):
            return math.nan

    def default_level(self) -> Level | None:
        """``spec.NAME.space`` for a spec; ``a - b`` for a single comparison ``a < b`` (``b - a`` for ``>``)."""
        if self.spec is not None:
            return Level(f"spec.{self.spec}.space", 1.0)
        body = self.tree.body
        if isinstance(body, ast.Compare) and len(body.ops) == 1 and type(body.ops[0]) in (ast.Lt, ast.LtE, ast.Gt, ast.GtE):
            col, num = column_name(body.left), _number(body.comparators[0])
            if col is not None and num is not None:
                sign = 1.0 if isinstance(body.ops[0], ast.Lt | ast.LtE) else -1.0
                return Level(col, sign, num)
        return None


@dataclass(frozen=True)
class Level:
    """``sign * (row[column] - offset)``: smaller is closer to failure."""

    column: str
    sign: float = 1.0
    offset: float = 0.0

    def of(self, row: dict[str, Any]) -> float:
        try:
            return self.sign * (float(row.get(self.column, math.nan)) - self.offset)
        except (TypeError, ValueError):
            return math.nan

    def __str__(self) -> str:
        name = self.column if self.sign > 0 else f"-{self.column}"
        return name if not self.offset else f"{name} {'-' if self.sign > 0 else '+'} {self.offset:g}"


def parse_level(text: str) -> Level:
    col = text.strip().removeprefix("-")
    if not col or not all(p.isidentifier() for p in col.split(".")):
        raise CorridorError(f"--level {clip(text)}: expected a column name (e.g. min_ttc_s, spec.safety.space), "
                            "'-' in front when larger is closer to failure")
    return Level(col, -1.0 if text.strip().startswith("-") else 1.0)


def _check(node: ast.AST, text: str, cols: set[str]) -> None:
    """Refuse every node kind but the allowed ones; collect the column names."""
    if isinstance(node, ast.BoolOp):
        for v in node.values:
            _check(v, text, cols)
    elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
        _check(node.operand, text, cols)
    elif isinstance(node, ast.Compare):
        for op in node.ops:
            if type(op) not in _CMP:
                raise CorridorError(f"--estimate {clip(text)}: only <, <=, >, >=, ==, != compare")
        for side in (node.left, *node.comparators):
            if _number(side) is None and column_name(side) is None:
                raise CorridorError(f"--estimate {clip(text)}: compare column names and numbers only")
            if (col := column_name(side)) is not None:
                cols.add(col)
    elif (col := column_name(node)) is not None:
        cols.add(col)
    else:
        raise CorridorError(f"--estimate {clip(text)}: expected comparisons such as 'collisions > 0' "
                            "joined by and/or/not, or spec:NAME")


def parse_event(text: str, spec_names: list[str] | None = None) -> Event:
    """Parse ``EVENT``; a one-line ``CorridorError`` when it is not of the allowed form."""
    text = text.strip()
    if text.startswith("spec:"):
        name = text[5:].strip()
        if spec_names is not None and name not in spec_names:
            known = ", ".join(spec_names) or "none declared"
            raise CorridorError(f"--estimate {clip(text)}: no spec {clip(name)} in the scenario (specs: {known})")
        return Event(text, ast.Expression(ast.Constant(False)), (f"spec.{name}.space",), name)
    if not text or len(text) > 500:
        raise CorridorError("--estimate: expected an expression such as 'collisions > 0', or spec:NAME")
    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError:
        raise CorridorError(f"--estimate {clip(text)}: not an expression such as 'collisions > 0'") from None
    cols: set[str] = set()
    _check(tree.body, text, cols)
    # the canonical spelling ('nmac>0' and 'nmac > 0' are one event: --resume compares this text)
    return Event(ast.unparse(tree), tree, tuple(sorted(cols)))


# the columns of every run's row, whatever the scenario (corridor.run.execute, corridor.run.simulate)
ROW_COLUMNS = frozenset({"run_id", "scenario", "variant", "seed", "status", "error", "wall_s", "sim_s",
                         "events_mode", "events_fallback"})


class ColumnError(CorridorError):
    """EVENT or ``--level`` names a column that the scenario's rows do not have (exit 2)."""


def known_columns(sc: Any) -> set[str]:
    """Columns known before any run: the row's own, the draws, the specs' and the scenario's key
    ``metrics`` (components write more, known only from a row)."""
    cols = set(ROW_COLUMNS) | {f"draw.{p}" for p in sc.randomize} | set(sc.metrics)
    for s in sc.specs:
        cols |= {f"spec.{s.name}.{k}" for k in ("satisfied", "space", "time")}
    return cols


def needed_columns(event: Event | None, level: Level | None) -> list[tuple[str, str]]:
    """(option text, column) of every column EVENT and the level read."""
    out = [(f"--estimate {clip(event.text)}", c) for c in event.columns] if event is not None else []
    if level is not None:
        out.append((f"--level {clip(level.column)}", level.column))
    return out


def check_columns(needed: list[tuple[str, str]], known: set[str], from_rows: bool) -> None:
    """A column not in ``known`` is a ``ColumnError`` naming the closest known metric columns;
    before any run (``from_rows`` False) only the draw and spec columns can be judged."""
    import difflib

    for what, col in needed:
        if col in known or not (from_rows or col.startswith(("draw.", "spec."))):
            continue
        metrics = sorted(c for c in known if c not in ROW_COLUMNS and not c.startswith(("draw.", "estimate.")))
        close = difflib.get_close_matches(col, metrics, n=1, cutoff=0.5)
        hint = f" (did you mean {close[0]}?)" if close else ""
        listed = ", ".join(metrics)
        listed = listed if len(listed) <= 200 else listed[:listed.rfind(", ", 0, 198)] + ", …"
        raise ColumnError(f"{what}: no column {clip(col)} in the scenario's rows{hint}; "
                          f"metric columns: {listed or 'none'}")
