"""corridor's own import-linter contract type (``contract_types`` in pyproject.toml).

``forbidden_except``: a ``forbidden`` contract whose source modules are a rule, not a list: module
expressions with wildcards (``corridor.controllers.**``) minus ``except_modules``, patterns matched
segment by segment with shell wildcards (``corridor.controllers.*.*components`` matches
``corridor.controllers.ramp_metering.metanet_components``).  A new module under a source package
is checked without anyone adding it; only the exceptions are named.
"""

from __future__ import annotations

from fnmatch import fnmatchcase
from typing import Any

from importlinter import fields
from importlinter.contracts.forbidden import ForbiddenContract
from importlinter.domain.helpers import module_expressions_to_modules
from importlinter.domain.imports import ModuleExpression


def matches(name: str, pattern: str) -> bool:
    """Dotted ``name`` against ``pattern``: same number of segments, each matched by fnmatch."""
    a, b = name.split("."), pattern.split(".")
    return len(a) == len(b) and all(fnmatchcase(x, y) for x, y in zip(a, b, strict=True))


class ForbiddenExceptContract(ForbiddenContract):
    """Forbidden contract over ``source_modules`` (wildcards) minus ``except_modules`` (patterns)."""

    type_name = "forbidden_except"
    except_modules = fields.ListField(subfield=fields.StringField(), required=False)

    def check(self, graph: Any, verbose: bool) -> Any:
        patterns = list(self.except_modules or [])  # type: ignore[arg-type]
        sources = module_expressions_to_modules(graph, self.source_modules)  # type: ignore[arg-type]
        kept = sorted(m.name for m in sources if not any(matches(m.name, p) for p in patterns))
        unused = [p for p in patterns if not any(matches(m.name, p) for m in sources)]
        if unused:  # a stale exception (module renamed or gone) is an error, not silence
            raise ValueError(f"except_modules matches no source module: {', '.join(unused)}")
        self.source_modules = {ModuleExpression(n) for n in kept}  # type: ignore[assignment]
        self.as_packages = False  # each source is one module (a package's __init__ is not its descendants)
        return super().check(graph, verbose)
