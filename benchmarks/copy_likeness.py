"""How like the lab's reference functions honest solutions are, and how like them a renamed copy is:
the measurement behind mazelab.exercise.kit.LIKENESS_LIMIT.

    uv run python benchmarks/copy_likeness.py

Honest: every class of tests/exercise_answers.py (the reference answers, each resampling scheme, the
planted bugs, the slightly wrong parts). Copies: each reference function of at least MIN_TOKENS tokens,
its names changed (every local name and argument renamed), as a helper its part calls. The limit must
lie between the honest solutions' largest likeness and the copies' smallest.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import exercise_answers

from mazelab.exercise.kit import (
    LIKENESS_LIMIT,
    MIN_TOKENS,
    REFERENCE_SOURCES,
    class_source,
    likeness,
    source_file,
    tokens,
)
from mazelab.exercise.kit import qualified_functions as qualified


class _Renamer(ast.NodeTransformer):
    """Every name and argument to a new one (attributes and calls of modules kept: np.cumsum)."""

    def __init__(self) -> None:
        self.names: dict[str, str] = {"np": "np", "math": "math", "len": "len", "range": "range"}

    def _new(self, name: str) -> str:
        return self.names.setdefault(name, f"v{len(self.names)}")

    def visit_Name(self, node: ast.Name) -> ast.Name:
        node.id = self._new(node.id)
        return node

    def visit_arg(self, node: ast.arg) -> ast.arg:
        node.arg = self._new(node.arg)
        return node


def renamed_copies() -> dict[str, str]:
    """Each long enough reference function, renamed, as a part's helper (called from its method)."""
    copies = {}
    for module in REFERENCE_SOURCES:
        for name, node in qualified(ast.parse(source_file(module).read_text()), module):
            if isinstance(node, ast.FunctionDef) and len(tokens(node)) >= MIN_TOKENS:
                node.name = "helper"
                text = ast.unparse(_Renamer().visit(node)).replace("\n", "\n    ")
                method = "    def estimate(self, positions, weights):\n        return self.helper()\n"
                copies[name] = f"class Copy:\n{method}\n    {text}\n"
    return copies


def main() -> None:
    honest = {
        c.__name__: max((one.share for one in likeness({"c.py": class_source(c)}).values()), default=0.0)
        for c in vars(exercise_answers).values()
        if isinstance(c, type) and c.__module__ == exercise_answers.__name__
    }
    worst = max(honest, key=honest.__getitem__)
    copies = {name: likeness({"copy.py": text})["estimate"].share for name, text in renamed_copies().items()}
    least = min(copies, key=copies.__getitem__)
    print(f"honest solutions: {len(honest)}; the largest likeness {honest[worst]:.3f} ({worst})")
    print(f"renamed copies: {len(copies)}; the smallest likeness {copies[least]:.3f}")
    between = honest[worst] < LIKENESS_LIMIT <= copies[least]
    print(f"limit {LIKENESS_LIMIT}: {'between them' if between else 'NOT between them'}")


if __name__ == "__main__":
    main()
