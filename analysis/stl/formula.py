"""STL formulas as immutable trees.

Two small algebras live here, both made of frozen dataclasses:

* ``Expr`` — real-valued expressions over named signals (``x - y``, ``sqrt(dx^2 + dy^2)``),
* ``Formula`` — STL over predicates ``expr <op> expr``: not, and, or, implies, always, eventually and
  until with time intervals ``[a, b]`` in seconds (``b`` may be ``inf``).

Formulas compose in Python (``&``, ``|``, ``~``, ``>>`` for implies, ``.always(a, b)``,
``.eventually(a, b)``, ``.until(other, a, b)``) and ``str(formula)`` prints text that
``parse_formula`` reads back into an equal tree. Semantics live elsewhere (``space``, ``time_rob``,
``online``): the tree only knows its signals and its horizon.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

INF = math.inf
COMPARISONS = (">", ">=", "<", "<=")
FUNCTIONS = {"abs": 1, "sqrt": 1, "exp": 1, "min": 2, "max": 2}  # name -> arity


# ----------------------------------------------------------------------------------------------------
# Expressions
# ----------------------------------------------------------------------------------------------------
class Expr:
    """Base of real-valued expressions; Python operators build bigger expressions or predicates."""

    def signal_names(self) -> frozenset[str]:
        raise NotImplementedError

    def __add__(self, other: ExprLike) -> Expr:
        return BinOp("+", self, as_expr(other))

    def __radd__(self, other: ExprLike) -> Expr:
        return BinOp("+", as_expr(other), self)

    def __sub__(self, other: ExprLike) -> Expr:
        return BinOp("-", self, as_expr(other))

    def __rsub__(self, other: ExprLike) -> Expr:
        return BinOp("-", as_expr(other), self)

    def __mul__(self, other: ExprLike) -> Expr:
        return BinOp("*", self, as_expr(other))

    def __rmul__(self, other: ExprLike) -> Expr:
        return BinOp("*", as_expr(other), self)

    def __truediv__(self, other: ExprLike) -> Expr:
        return BinOp("/", self, as_expr(other))

    def __rtruediv__(self, other: ExprLike) -> Expr:
        return BinOp("/", as_expr(other), self)

    def __pow__(self, other: ExprLike) -> Expr:
        return BinOp("^", self, as_expr(other))

    def __neg__(self) -> Expr:
        return Neg(self)

    def __gt__(self, other: ExprLike) -> Predicate:  # type: ignore[override]
        return Predicate(self, ">", as_expr(other))

    def __ge__(self, other: ExprLike) -> Predicate:  # type: ignore[override]
        return Predicate(self, ">=", as_expr(other))

    def __lt__(self, other: ExprLike) -> Predicate:  # type: ignore[override]
        return Predicate(self, "<", as_expr(other))

    def __le__(self, other: ExprLike) -> Predicate:  # type: ignore[override]
        return Predicate(self, "<=", as_expr(other))


ExprLike = Expr | float | int


def as_expr(value: ExprLike) -> Expr:
    """Wrap numbers as ``Const``; pass expressions through."""
    if isinstance(value, Expr):
        return value
    return Const(float(value))


@dataclass(frozen=True, eq=True)
class Var(Expr):
    """A named signal."""

    name: str

    def signal_names(self) -> frozenset[str]:
        return frozenset({self.name})

    def __str__(self) -> str:
        return self.name


@dataclass(frozen=True, eq=True)
class Const(Expr):
    """A real constant."""

    value: float

    def signal_names(self) -> frozenset[str]:
        return frozenset()

    def __str__(self) -> str:
        return "inf" if self.value == INF else repr(float(self.value))


@dataclass(frozen=True, eq=True)
class Neg(Expr):
    """Unary minus."""

    arg: Expr

    def signal_names(self) -> frozenset[str]:
        return self.arg.signal_names()

    def __str__(self) -> str:
        return f"-({self.arg})"


@dataclass(frozen=True, eq=True)
class BinOp(Expr):
    """Binary arithmetic: ``+ - * /`` and ``^`` (power)."""

    op: str
    left: Expr
    right: Expr

    def signal_names(self) -> frozenset[str]:
        return self.left.signal_names() | self.right.signal_names()

    def __str__(self) -> str:
        return f"({self.left} {self.op} {self.right})"


@dataclass(frozen=True, eq=True)
class Call(Expr):
    """A function of expressions: ``abs``, ``sqrt``, ``exp`` (one argument), ``min``, ``max`` (two)."""

    func: str
    args: tuple[Expr, ...]

    def __post_init__(self) -> None:
        if FUNCTIONS.get(self.func) != len(self.args):
            raise ValueError(f"{self.func}() takes {FUNCTIONS.get(self.func)} argument(s)")

    def signal_names(self) -> frozenset[str]:
        return frozenset().union(*(a.signal_names() for a in self.args))

    def __str__(self) -> str:
        return f"{self.func}({', '.join(str(a) for a in self.args)})"


def var(name: str) -> Var:
    """Shorthand for ``Var(name)``: ``var("gap_lead") > 5``."""
    return Var(name)


# ----------------------------------------------------------------------------------------------------
# Formulas
# ----------------------------------------------------------------------------------------------------
class Formula:
    """Base of STL formulas: composition operators, signal names and horizon."""

    def children(self) -> tuple[Formula, ...]:
        return ()

    def signal_names(self) -> frozenset[str]:
        """All signal names the formula reads."""
        return frozenset().union(*(c.signal_names() for c in self.children()))

    def horizon(self) -> float:
        """Seconds of future signal needed to decide the formula at a time point (may be inf)."""
        return max((c.horizon() for c in self.children()), default=0.0)

    def __and__(self, other: Formula) -> Formula:
        return And(self, other)

    def __or__(self, other: Formula) -> Formula:
        return Or(self, other)

    def __invert__(self) -> Formula:
        return Not(self)

    def __rshift__(self, other: Formula) -> Formula:
        return Implies(self, other)

    def always(self, a: float = 0.0, b: float = INF) -> Formula:
        return Always(self, float(a), float(b))

    def eventually(self, a: float = 0.0, b: float = INF) -> Formula:
        return Eventually(self, float(a), float(b))

    def until(self, other: Formula, a: float = 0.0, b: float = INF) -> Formula:
        return Until(self, other, float(a), float(b))


def _check_interval(a: float, b: float) -> None:
    if not (0.0 <= a <= b) or math.isnan(b) or a == INF:
        raise ValueError(f"bad interval [{a}, {b}]: need 0 <= a <= b, a finite")


def _interval_str(a: float, b: float) -> str:
    end = "inf" if b == INF else repr(b)
    return f"[{a!r}, {end}]"


@dataclass(frozen=True, eq=True)
class Predicate(Formula):
    """``lhs <op> rhs`` with op in ``> >= < <=``; robustness ``lhs - rhs`` (or ``rhs - lhs``)."""

    lhs: Expr
    op: str
    rhs: Expr

    def __post_init__(self) -> None:
        if self.op not in COMPARISONS:
            raise ValueError(f"unknown comparison {self.op!r}")

    def signal_names(self) -> frozenset[str]:
        return self.lhs.signal_names() | self.rhs.signal_names()

    def __str__(self) -> str:
        return f"({self.lhs} {self.op} {self.rhs})"


@dataclass(frozen=True, eq=True)
class Not(Formula):
    arg: Formula

    def children(self) -> tuple[Formula, ...]:
        return (self.arg,)

    def __str__(self) -> str:
        return f"!{self.arg}"


@dataclass(frozen=True, eq=True)
class And(Formula):
    left: Formula
    right: Formula

    def children(self) -> tuple[Formula, ...]:
        return (self.left, self.right)

    def __str__(self) -> str:
        return f"({self.left} & {self.right})"


@dataclass(frozen=True, eq=True)
class Or(Formula):
    left: Formula
    right: Formula

    def children(self) -> tuple[Formula, ...]:
        return (self.left, self.right)

    def __str__(self) -> str:
        return f"({self.left} | {self.right})"


@dataclass(frozen=True, eq=True)
class Implies(Formula):
    left: Formula
    right: Formula

    def children(self) -> tuple[Formula, ...]:
        return (self.left, self.right)

    def __str__(self) -> str:
        return f"({self.left} -> {self.right})"


@dataclass(frozen=True, eq=True)
class _Temporal(Formula):
    """A unary temporal operator over ``t + [a, b]`` (G and F differ only in their semantics)."""

    arg: Formula
    a: float = 0.0
    b: float = INF
    symbol: ClassVar[str] = ""

    def __post_init__(self) -> None:
        _check_interval(self.a, self.b)

    def children(self) -> tuple[Formula, ...]:
        return (self.arg,)

    def horizon(self) -> float:
        return self.b + self.arg.horizon()

    def __str__(self) -> str:
        return f"{self.symbol}{_interval_str(self.a, self.b)}{self.arg}"


@dataclass(frozen=True, eq=True)
class Always(_Temporal):
    """``G[a,b] arg``: arg holds at every time in ``t + [a, b]``."""

    symbol: ClassVar[str] = "G"


@dataclass(frozen=True, eq=True)
class Eventually(_Temporal):
    """``F[a,b] arg``: arg holds at some time in ``t + [a, b]``."""

    symbol: ClassVar[str] = "F"


@dataclass(frozen=True, eq=True)
class Until(Formula):
    """``left U[a,b] right``: right holds at some t' in ``t + [a, b]`` and left holds on ``[t, t')``."""

    left: Formula
    right: Formula
    a: float = 0.0
    b: float = INF

    def __post_init__(self) -> None:
        _check_interval(self.a, self.b)

    def children(self) -> tuple[Formula, ...]:
        return (self.left, self.right)

    def horizon(self) -> float:
        return self.b + max(self.left.horizon(), self.right.horizon())

    def __str__(self) -> str:
        return f"({self.left} U{_interval_str(self.a, self.b)} {self.right})"
