"""Text to STL formula: a hand-written recursive-descent parser with column tracking.

Grammar (lowest precedence first; ``->`` is right-associative, ``&``/``|`` left-associative)::

    formula  := disj [ ("->" | "implies") formula ]
    disj     := conj { ("|" | "or") conj }
    conj     := until { ("&" | "and") until }
    until    := unary [ ("U" | "until") [interval] until ]
    unary    := ("!" | "not") unary
              | ("G" | "always" | "F" | "eventually") [interval] unary
              | "(" formula ")" | predicate
    interval := "[" number "," (number | "inf") "]"           (seconds; no interval means [0, inf])
    predicate:= expr (">" | ">=" | "<" | "<=") expr
    expr     := term { ("+" | "-") term };  term := factor { ("*" | "/") factor }
    factor   := "-" factor | atom [ ("^" | "**") factor ]
    atom     := number | name | func "(" expr {"," expr} ")" | "(" expr ")"

``G F U always eventually until not and or implies inf`` and the function names are keywords, not
signal names. A parenthesis may open a formula or an arithmetic expression; the parser tries the
predicate reading first and falls back to the formula reading. Errors raise ``STLSyntaxError`` with
a one-line message ``col N: expected ...`` (columns are 1-based).

Long flat specs are fine: chains of ``&`` / ``|`` / ``->`` / ``U`` (hundreds of predicates) and runs
of prefix operators (``! G F``) are read in loops, so none of them costs Python recursion (the trees
they make are deep, and every walk over a tree is iterative, see ``formula``). What does recurse is nesting: parentheses, function calls, unary minus and
``^``; more than ``MAX_NESTING`` (100) levels of those is an ``STLSyntaxError`` ``formula nests deeper
than 100 levels``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from corridor.stl.formula import (
    COMPARISONS,
    FUNCTIONS,
    INF,
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
)

T = TypeVar("T")
MAX_NESTING = 100  # parentheses / calls / unary minus / powers inside one another


class STLSyntaxError(ValueError):
    """A formula text that does not parse; ``column`` is 1-based."""

    def __init__(self, column: int, message: str) -> None:
        super().__init__(f"col {column}: {message}")
        self.column = column


@dataclass(frozen=True)
class Token:
    kind: str  # "num", "name", "op", "end"
    text: str
    col: int  # 1-based


_TOKEN_RE = re.compile(
    r"(?P<num>\d+\.?\d*(?:[eE][+-]?\d+)?|\.\d+(?:[eE][+-]?\d+)?)"
    r"|(?P<name>[A-Za-z_][A-Za-z_0-9]*)"
    r"|(?P<op>->|>=|<=|\*\*|[-+*/^()\[\],<>!&|])"
)
_KEYWORDS = {"G", "F", "U", "always", "eventually", "until", "not", "and", "or", "implies", "inf"}
_ALIASES = {"not": "!", "and": "&", "or": "|", "implies": "->", "always": "G", "eventually": "F",
            "until": "U", "**": "^"}


def tokenize(text: str) -> list[Token]:
    """Split ``text`` into tokens; keyword aliases are normalised (``and`` -> ``&``)."""
    tokens: list[Token] = []
    pos = 0
    while True:
        while pos < len(text) and text[pos].isspace():
            pos += 1
        if pos == len(text):
            break
        match = _TOKEN_RE.match(text, pos)
        if match is None or match.lastgroup is None:
            raise STLSyntaxError(pos + 1, f"unexpected character {text[pos]!r}")
        kind, word = match.lastgroup, match.group()
        if kind == "name" and word in _KEYWORDS:
            kind = "num" if word == "inf" else "op"
        tokens.append(Token(kind, _ALIASES.get(word, word), pos + 1))
        pos = match.end()
    tokens.append(Token("end", "end of input", len(text) + 1))
    return tokens


def parse_formula(text: str) -> Formula:
    """Parse STL text such as ``G[0,30](gap_lead > 5) & F[0,20](ahead_of_lead > 0)``."""
    parser = _Parser(tokenize(text))
    formula = parser.formula()
    parser.expect_end()
    return formula


def as_formula(spec: str | Formula) -> Formula:
    """Accept either a formula tree or its text."""
    return parse_formula(spec) if isinstance(spec, str) else spec


class _Parser:
    """Recursive descent over a token list; ``pos`` indexes the next token."""

    def __init__(self, tokens: list[Token]) -> None:
        self.tokens = tokens
        self.pos = 0
        self.depth = 0  # current nesting (see MAX_NESTING)

    def nested(self, parse: Callable[[], T]) -> T:
        """Run ``parse()`` one nesting level deeper; refuse beyond ``MAX_NESTING``."""
        if self.depth >= MAX_NESTING:
            raise STLSyntaxError(self.tok.col, f"formula nests deeper than {MAX_NESTING} levels")
        self.depth += 1
        try:
            return parse()
        finally:
            self.depth -= 1

    # ---- token helpers ---------------------------------------------------------------------------
    @property
    def tok(self) -> Token:
        return self.tokens[self.pos]

    def accept(self, *texts: str) -> Token | None:
        if self.tok.kind == "op" and self.tok.text in texts:
            self.pos += 1
            return self.tokens[self.pos - 1]
        return None

    def expect(self, text: str, context: str) -> Token:
        token = self.accept(text)
        if token is None:
            raise STLSyntaxError(self.tok.col, f"expected '{text}' {context}, found '{self.tok.text}'")
        return token

    def expect_end(self) -> None:
        if self.tok.kind != "end":
            raise STLSyntaxError(self.tok.col, f"expected end of formula, found '{self.tok.text}'")

    # ---- formulas --------------------------------------------------------------------------------
    def formula(self) -> Formula:
        items = [self.disjunction()]
        while self.accept("->"):
            items.append(self.disjunction())
        out = items[-1]
        for left in reversed(items[:-1]):  # right-associative
            out = Implies(left, out)
        return out

    def disjunction(self) -> Formula:
        left = self.conjunction()
        while self.accept("|"):
            left = Or(left, self.conjunction())
        return left

    def conjunction(self) -> Formula:
        left = self.until()
        while self.accept("&"):
            left = And(left, self.until())
        return left

    def until(self) -> Formula:
        items, intervals = [self.unary()], []
        while self.accept("U"):
            intervals.append(self.interval())
            items.append(self.unary())
        out = items[-1]
        for left, (a, b) in zip(reversed(items[:-1]), reversed(intervals), strict=True):  # right-assoc.
            out = Until(left, out, a, b)
        return out

    def unary(self) -> Formula:
        prefixes: list[tuple[str, float, float]] = []
        while True:
            if self.accept("!"):
                prefixes.append(("!", 0.0, INF))
                continue
            token = self.accept("G", "F")
            if token is None:
                break
            prefixes.append((token.text, *self.interval()))
        if self.tok.kind == "op" and self.tok.text == "(":
            out = self.parenthesised()
        else:
            out = self.predicate()
        for op, a, b in reversed(prefixes):
            out = Not(out) if op == "!" else Always(out, a, b) if op == "G" else Eventually(out, a, b)
        return out

    def parenthesised(self) -> Formula:
        """``(`` opens either a predicate like ``(x - y) > 2`` or a formula; try the predicate first."""
        start = self.pos
        try:
            return self.predicate()
        except STLSyntaxError as as_predicate:
            self.pos = start
            try:
                self.expect("(", "")
                inner = self.nested(self.formula)
                self.expect(")", "to close '('")
                return inner
            except STLSyntaxError as as_formula:  # report whichever reading got further
                raise as_formula if as_formula.column >= as_predicate.column else as_predicate from None

    def interval(self) -> tuple[float, float]:
        if not self.accept("["):
            return 0.0, INF
        a = self.number("interval start")
        self.expect(",", "in interval")
        b_token = self.tok
        b = self.number("interval end")
        self.expect("]", "to close interval")
        if math.isinf(a) or b < a:
            raise STLSyntaxError(b_token.col, f"bad interval [{a}, {b}]: need 0 <= a <= b, a finite")
        return a, b

    def number(self, what: str) -> float:
        token = self.tok
        if token.kind != "num":
            raise STLSyntaxError(token.col, f"expected a number for {what}, found '{token.text}'")
        self.pos += 1
        return INF if token.text == "inf" else float(token.text)

    def predicate(self) -> Predicate:
        lhs = self.expr()
        token = self.tok
        if token.kind != "op" or token.text not in COMPARISONS:
            raise STLSyntaxError(token.col, f"expected a comparison (> >= < <=), found '{token.text}'")
        self.pos += 1
        return Predicate(lhs, token.text, self.expr())

    # ---- arithmetic ------------------------------------------------------------------------------
    def expr(self) -> Expr:
        left = self.term()
        while (token := self.accept("+", "-")) is not None:
            left = BinOp(token.text, left, self.term())
        return left

    def term(self) -> Expr:
        left = self.factor()
        while (token := self.accept("*", "/")) is not None:
            left = BinOp(token.text, left, self.factor())
        return left

    def factor(self) -> Expr:
        if self.accept("-"):
            follower = self.tokens[min(self.pos + 1, len(self.tokens) - 1)]
            if self.tok.kind == "num" and not (follower.kind == "op" and follower.text == "^"):
                return Const(-self.number("a number"))  # a negative literal, not Neg(Const)
            return Neg(self.nested(self.factor))
        base = self.atom()
        if self.accept("^"):
            return BinOp("^", base, self.nested(self.factor))
        return base

    def atom(self) -> Expr:
        token = self.tok
        if token.kind == "num":
            return Const(self.number("a number"))
        if token.kind == "name":
            self.pos += 1
            if token.text in FUNCTIONS:
                return self.call(token)
            return Var(token.text)
        if self.accept("("):
            inner = self.nested(self.expr)
            self.expect(")", "to close '('")
            return inner
        raise STLSyntaxError(token.col, f"expected a signal, number or '(', found '{token.text}'")

    def call(self, name: Token) -> Expr:
        self.expect("(", f"after {name.text}")
        args = [self.nested(self.expr)]
        while self.accept(","):
            args.append(self.nested(self.expr))
        close = self.expect(")", f"to close {name.text}(")
        if len(args) != FUNCTIONS[name.text]:
            raise STLSyntaxError(close.col, f"{name.text}() takes {FUNCTIONS[name.text]} argument(s)")
        return Call(name.text, tuple(args))
