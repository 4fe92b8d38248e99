"""STL formulas as immutable trees.

Two small algebras live here, both made of frozen dataclasses:

* ``Expr`` — real-valued expressions over named signals (``x - y``, ``sqrt(dx^2 + dy^2)``),
* ``Formula`` — STL over predicates ``expr <op> expr``: not, and, or, implies, always, eventually and
  until with time intervals ``[a, b]`` in seconds (``b`` may be ``inf``).

Formulas compose in Python (``&``, ``|``, ``~``, ``>>`` for implies, ``.always(a, b)``,
``.eventually(a, b)``, ``.until(other, a, b)``) and ``str(formula)`` prints text that
``parse_formula`` reads back into an equal tree. Semantics live elsewhere (``space``, ``time_rob``,
``online``): the tree only knows its signals and its horizon.

Trees may be deep (``a & b & c ...`` over hundreds of predicates is a left-nested chain, from the
parser as from ``functools.reduce(operator.and_, ...)``): every walk here (``str``, ``repr``, ``==``,
``hash``, ``signal_names``, ``horizon``) is iterative (``fold``), never recursive. ``str`` prints chains
flat (``(a & b & c)``, ``(a -> b -> c)``) so printed text never nests deeper than the tree's other
operators and parses back within the parser's nesting limit. ``all_of`` / ``any_of`` build balanced
``&`` / ``|`` trees (depth ``log2 n``); ``rebalance`` rebuilds every chain so (for recursive consumers
such as the online monitor).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import Any, ClassVar, TypeVar

INF = math.inf
COMPARISONS = (">", ">=", "<", "<=")
FUNCTIONS = {"abs": 1, "sqrt": 1, "exp": 1, "min": 2, "max": 2}  # name -> arity

R = TypeVar("R")
N = TypeVar("N", bound="_Tree")  # the node type of a fold: a formula's nodes are formulas, an expression's expressions


class _Tree:
    """Iterative structural equality, hashing and printing for expression and formula trees."""

    def children(self) -> tuple[_Tree, ...]:
        return ()

    def _label(self) -> tuple[Any, ...]:
        """The node's own (non-child) fields."""
        kids = {id(c) for c in self.children()}
        own = (getattr(self, f.name) for f in fields(self))  # type: ignore[arg-type]
        return (type(self), *(v for v in own if id(v) not in kids and not isinstance(v, tuple)))

    def _text(self, kids: list[str]) -> str:
        raise NotImplementedError

    def _signature(self) -> tuple[Any, ...]:
        """Post-order (label, arity) of every node: equal signatures <=> equal trees."""
        return tuple(node._label() + (len(node.children()),) for node in postorder(self))

    def __eq__(self, other: object) -> bool:
        if self is other:
            return True
        if not isinstance(other, _Tree) or type(self) is not type(other):
            return NotImplemented
        return self._signature() == other._signature()

    def __hash__(self) -> int:
        return hash(self._signature())

    def __str__(self) -> str:
        return fold(self, lambda node, kids: node._text(kids))

    def __repr__(self) -> str:
        def one(node: _Tree, kids: list[str]) -> str:
            own = [repr(v) for v in node._label()[1:]]
            return f"{type(node).__name__}({', '.join(kids + own)})"
        return fold(self, one)


def postorder(root: _Tree) -> list[_Tree]:
    """Every node of the tree, children before parents (each occurrence once), without recursion."""
    out: list[_Tree] = []
    stack: list[tuple[_Tree, bool]] = [(root, False)]
    while stack:
        node, expanded = stack.pop()
        if expanded:
            out.append(node)
            continue
        stack.append((node, True))
        stack.extend((c, False) for c in reversed(node.children()))
    return out


def fold(root: N, combine: Callable[[N, list[R]], R]) -> R:
    """Bottom-up ``combine(node, [results of its children])`` without recursion.

    A child's result is dropped once its parent has used it (big intermediate arrays are freed as in
    a recursive evaluation); a sub-tree object used twice is then evaluated twice.
    """
    done: dict[int, R] = {}
    stack: list[Any] = [root]  # nodes of root's kind (N): a tree's children are of its parent's kind
    while stack:
        node = stack[-1]
        if id(node) in done:
            stack.pop()
            continue
        pending = [c for c in node.children() if id(c) not in done]
        if pending:
            stack.extend(pending)
            continue
        stack.pop()
        kids = node.children()
        done[id(node)] = combine(node, [done[id(c)] for c in kids])
        for c in kids:
            if c is not root:
                done.pop(id(c), None)
    return done[id(root)]


# ----------------------------------------------------------------------------------------------------
# Expressions
# ----------------------------------------------------------------------------------------------------
class Expr(_Tree):
    """Base of real-valued expressions; Python operators build bigger expressions or predicates."""

    __hash__ = _Tree.__hash__

    def signal_names(self) -> frozenset[str]:
        return frozenset(n.name for n in postorder(self) if isinstance(n, Var))

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

    def __gt__(self, other: ExprLike) -> Predicate:
        return Predicate(self, ">", as_expr(other))

    def __ge__(self, other: ExprLike) -> Predicate:
        return Predicate(self, ">=", as_expr(other))

    def __lt__(self, other: ExprLike) -> Predicate:
        return Predicate(self, "<", as_expr(other))

    def __le__(self, other: ExprLike) -> Predicate:
        return Predicate(self, "<=", as_expr(other))


ExprLike = Expr | float | int


def as_expr(value: ExprLike) -> Expr:
    """Wrap numbers as ``Const``; pass expressions through."""
    if isinstance(value, Expr):
        return value
    return Const(float(value))


@dataclass(frozen=True, eq=False, repr=False)
class Var(Expr):
    """A named signal."""

    name: str

    def _text(self, kids: list[str]) -> str:
        return self.name


@dataclass(frozen=True, eq=False, repr=False)
class Const(Expr):
    """A real constant."""

    value: float

    def _text(self, kids: list[str]) -> str:
        return "inf" if self.value == INF else repr(float(self.value))


@dataclass(frozen=True, eq=False, repr=False)
class Neg(Expr):
    """Unary minus."""

    arg: Expr

    def children(self) -> tuple[Expr, ...]:
        return (self.arg,)

    def _text(self, kids: list[str]) -> str:
        return f"-({kids[0]})"


@dataclass(frozen=True, eq=False, repr=False)
class BinOp(Expr):
    """Binary arithmetic: ``+ - * /`` and ``^`` (power)."""

    op: str
    left: Expr
    right: Expr

    def children(self) -> tuple[Expr, ...]:
        return (self.left, self.right)

    def _text(self, kids: list[str]) -> str:
        return f"({kids[0]} {self.op} {kids[1]})"


@dataclass(frozen=True, eq=False, repr=False)
class Call(Expr):
    """A function of expressions: ``abs``, ``sqrt``, ``exp`` (one argument), ``min``, ``max`` (two)."""

    func: str
    args: tuple[Expr, ...]

    def __post_init__(self) -> None:
        if FUNCTIONS.get(self.func) != len(self.args):
            raise ValueError(f"{self.func}() takes {FUNCTIONS.get(self.func)} argument(s)")

    def children(self) -> tuple[Expr, ...]:
        return self.args

    def _text(self, kids: list[str]) -> str:
        return f"{self.func}({', '.join(kids)})"


def var(name: str) -> Var:
    """Shorthand for ``Var(name)``: ``var("gap_lead") > 5``."""
    return Var(name)


# ----------------------------------------------------------------------------------------------------
# Formulas
# ----------------------------------------------------------------------------------------------------
class Formula(_Tree):
    """Base of STL formulas: composition operators, signal names and horizon."""

    __hash__ = _Tree.__hash__

    def children(self) -> tuple[Formula, ...]:
        return ()

    def signal_names(self) -> frozenset[str]:
        """All signal names the formula reads."""
        preds = (n for n in postorder(self) if isinstance(n, Predicate))
        return frozenset().union(*(p.lhs.signal_names() | p.rhs.signal_names() for p in preds))

    def horizon(self) -> float:
        """Seconds of future signal needed to decide the formula at a time point (may be inf)."""
        def one(node: Formula, kids: list[float]) -> float:
            return node._horizon(kids)

        return fold(self, one)

    def _horizon(self, kids: list[float]) -> float:
        return max(kids, default=0.0)

    def depth(self) -> int:
        """Operator nesting depth (a predicate has depth 1)."""
        return fold(self, lambda node, kids: 1 + max(kids, default=0))

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


@dataclass(frozen=True, eq=False, repr=False)
class Predicate(Formula):
    """``lhs <op> rhs`` with op in ``> >= < <=``; robustness ``lhs - rhs`` (or ``rhs - lhs``)."""

    lhs: Expr
    op: str
    rhs: Expr

    def __post_init__(self) -> None:
        if self.op not in COMPARISONS:
            raise ValueError(f"unknown comparison {self.op!r}")

    def _text(self, kids: list[str]) -> str:
        return f"({self.lhs} {self.op} {self.rhs})"


@dataclass(frozen=True, eq=False, repr=False)
class Not(Formula):
    arg: Formula

    def children(self) -> tuple[Formula, ...]:
        return (self.arg,)

    def _text(self, kids: list[str]) -> str:
        return f"!{kids[0]}"


@dataclass(frozen=True, eq=False, repr=False)
class And(Formula):
    left: Formula
    right: Formula

    def children(self) -> tuple[Formula, ...]:
        return (self.left, self.right)

    def _text(self, kids: list[str]) -> str:
        left = kids[0][1:-1] if isinstance(self.left, And) else kids[0]  # left-nested chain: flat
        return f"({left} & {kids[1]})"


@dataclass(frozen=True, eq=False, repr=False)
class Or(Formula):
    left: Formula
    right: Formula

    def children(self) -> tuple[Formula, ...]:
        return (self.left, self.right)

    def _text(self, kids: list[str]) -> str:
        left = kids[0][1:-1] if isinstance(self.left, Or) else kids[0]
        return f"({left} | {kids[1]})"


@dataclass(frozen=True, eq=False, repr=False)
class Implies(Formula):
    left: Formula
    right: Formula

    def children(self) -> tuple[Formula, ...]:
        return (self.left, self.right)

    def _text(self, kids: list[str]) -> str:
        right = kids[1][1:-1] if isinstance(self.right, Implies) else kids[1]  # right-associative
        return f"({kids[0]} -> {right})"


@dataclass(frozen=True, eq=False, repr=False)
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

    def _horizon(self, kids: list[float]) -> float:
        return self.b + kids[0]

    def _text(self, kids: list[str]) -> str:
        return f"{self.symbol}{_interval_str(self.a, self.b)}{kids[0]}"


@dataclass(frozen=True, eq=False, repr=False)
class Always(_Temporal):
    """``G[a,b] arg``: arg holds at every time in ``t + [a, b]``."""

    symbol: ClassVar[str] = "G"


@dataclass(frozen=True, eq=False, repr=False)
class Eventually(_Temporal):
    """``F[a,b] arg``: arg holds at some time in ``t + [a, b]``."""

    symbol: ClassVar[str] = "F"


@dataclass(frozen=True, eq=False, repr=False)
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

    def _horizon(self, kids: list[float]) -> float:
        return self.b + max(kids)

    def _text(self, kids: list[str]) -> str:
        right = kids[1][1:-1] if isinstance(self.right, Until) else kids[1]  # right-associative
        return f"({kids[0]} U{_interval_str(self.a, self.b)} {right})"


# ----------------------------------------------------------------------------------------------------
# Balanced n-ary conjunction / disjunction
# ----------------------------------------------------------------------------------------------------
def _balanced(op: type[And] | type[Or], items: Sequence[Formula]) -> Formula:
    """``op`` over ``items`` as a balanced binary tree; three items give the left-nested ``(a op b) op c``."""
    if not items:
        raise ValueError(f"{op.__name__} of no formulas")
    level = list(items)
    while len(level) > 1:
        pairs = [op(level[i], level[i + 1]) for i in range(0, len(level) - 1, 2)]
        level = pairs + ([level[-1]] if len(level) % 2 else [])
    return level[0]


def all_of(items: Sequence[Formula]) -> Formula:
    """Conjunction of ``items`` with depth ``ceil(log2 n)`` (min is associative: same semantics)."""
    return _balanced(And, items)


def any_of(items: Sequence[Formula]) -> Formula:
    """Disjunction of ``items`` with depth ``ceil(log2 n)``."""
    return _balanced(Or, items)


def rebalance(formula: Formula) -> Formula:
    """The same formula with every chain of ``&`` (or of ``|``) rebuilt balanced (iteratively)."""
    def combine(node: Formula, kids: list[Formula]) -> Formula:
        if isinstance(node, And | Or):
            op = type(node)
            flat: list[Formula] = []
            for k in kids:
                flat.extend(_chain(k, op))
            return _balanced(op, flat)
        if not kids:
            return node
        return type(node)(*kids, *node._label()[1:])

    return fold(formula, combine)


def _chain(formula: Formula, op: type) -> list[Formula]:
    """Operands of a (balanced) ``op`` chain, in order."""
    out: list[Formula] = []
    stack = [formula]
    while stack:
        node = stack.pop()
        if type(node) is op:
            stack.extend((node.right, node.left))  # type: ignore[attr-defined]
        else:
            out.append(node)
    return out
