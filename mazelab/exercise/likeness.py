"""Copied code, found in the grader (never in the student's process): each part of a submission
compared with the lab's reference functions by their normalised tokens, as MOSS and JPlag do.

A function's text is parsed, its docstrings dropped and its layout made canonical (ast.unparse); its
tokens are then read with every name that is not an attribute replaced by one placeholder, so that
renaming variables, reordering keyword arguments' spelling or reformatting changes nothing. Its
fingerprint is the set of runs of K consecutive tokens. A part's text is its method and the
submission's functions it calls by name; its likeness to a reference function is the share of the
reference's fingerprint found in it (containment). A part is flagged "not own work" when some
reference function of at least MIN_TOKENS tokens is contained at LIKENESS_LIMIT or more.

The limit is measured on the honest solutions (tests/exercise_answers.py: the reference answers,
every resampling scheme, the planted bugs and the slightly wrong parts): `uv run python
benchmarks/copy_likeness.py` prints the largest likeness of any of them (0.225) and the smallest of
the lab's functions copied with their names changed (1.0); docs/exercise.md quotes both.
"""

from __future__ import annotations

import ast
import contextlib
import inspect
import io
import keyword
import textwrap
import tokenize
from dataclasses import dataclass
from functools import cache

from mazelab.exercise.kit import source_file

K = 8  # tokens per fingerprint run
MIN_TOKENS = 24  # a reference shorter than this is an idiom anyone writes (np.average), not a copy
LIKENESS_LIMIT = 0.6  # measured: honest solutions reach at most 0.225, renamed copies 1.0 (module docstring)
PARTS = ("predict", "weigh", "resample", "estimate")
REFERENCE_SOURCES = (  # where the lab's implementations of the four parts live
    "mazelab.model",
    "mazelab.resampling",
    "mazelab.weights",
    "mazelab.filters",
    "mazelab.regularisation",
)


@dataclass(frozen=True)
class Likeness:
    """A part's nearest reference function: its name and the share of its fingerprint in the part."""

    part: str
    reference: str
    share: float

    @property
    def copied(self) -> bool:
        return self.share >= LIKENESS_LIMIT

    def text(self) -> str:
        return f"{self.share:.0%} of the lab's {self.reference} is in it (its code with the names changed)"


def _strip_docstrings(tree: ast.AST) -> ast.AST:
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr):
            value = body[0].value
            if isinstance(value, ast.Constant) and isinstance(value.value, str):
                node.body = body[1:] or [ast.Pass()]
    return tree


def tokens(node: ast.AST) -> list[str]:
    """The normalised tokens of a parsed function: names (not attributes) as one placeholder, strings
    as another, comments and layout gone."""
    text = ast.unparse(_strip_docstrings(ast.parse(ast.unparse(node))))
    out, previous = [], ""
    with contextlib.suppress(tokenize.TokenError, IndentationError):
        for token in tokenize.generate_tokens(io.StringIO(text).readline):
            if token.type == tokenize.NAME and not keyword.iskeyword(token.string) and previous != ".":
                out.append("N")
            elif token.type == tokenize.STRING:
                out.append("S")
            elif token.type in (tokenize.NAME, tokenize.OP, tokenize.NUMBER, tokenize.INDENT, tokenize.DEDENT):
                out.append(token.string if token.type != tokenize.INDENT else "{")
            previous = token.string
    return out


def fingerprint(token_list: list[str]) -> set[tuple[str, ...]]:
    return {tuple(token_list[i : i + K]) for i in range(len(token_list) - K + 1)}


@cache
def reference_prints() -> dict[str, set[tuple[str, ...]]]:
    """The fingerprint of every reference function (and method) of at least MIN_TOKENS tokens."""
    prints = {}
    for module in REFERENCE_SOURCES:
        tree = ast.parse(source_file(module).read_text())
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                found = tokens(node)
                if len(found) >= MIN_TOKENS:
                    prints[f"{module}.{node.name}"] = fingerprint(found)
    return prints


def _functions(tree: ast.AST) -> dict[str, list[ast.FunctionDef]]:
    found: dict[str, list[ast.FunctionDef]] = {}
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            found.setdefault(node.name, []).append(node)
    return found


def part_texts(source: str) -> dict[str, list[ast.AST]]:
    """Each part's functions in a submission's source: its methods of that name and the functions
    they call by name (or as self.NAME), followed to any depth."""
    tree = ast.parse(source)
    functions = _functions(tree)
    texts = {}
    for part in PARTS:
        seen, todo = [], list(functions.get(part, []))
        while todo:
            node = todo.pop()
            if any(node is s for s in seen):
                continue
            seen.append(node)
            for called in ast.walk(node):
                name = called.id if isinstance(called, ast.Name) else getattr(called, "attr", None)
                todo += [f for f in functions.get(name or "", []) if f.name not in PARTS]
        if seen:
            texts[part] = seen
    return texts


def likeness(source: str) -> dict[str, Likeness]:
    """Each part's nearest reference function in `source` (a submission's text), by containment."""
    try:
        texts = part_texts(source)
    except (SyntaxError, ValueError, RecursionError):
        return {}
    found = {}
    for part, nodes in texts.items():
        mine: set[tuple[str, ...]] = set()
        for node in nodes:
            mine |= fingerprint(tokens(node))
        references = reference_prints()
        shares = {name: len(prints & mine) / len(prints) for name, prints in references.items() if prints}
        nearest = max(shares, key=lambda name: (round(shares[name], 2), len(references[name])))  # the largest of ties
        found[part] = Likeness(part, nearest, shares[nearest])
    return found


def copied_parts(source: str) -> dict[str, str]:
    """The parts of `source` that are the lab's code, each with the line saying whose."""
    return {part: one.text() for part, one in likeness(source).items() if one.copied}


def class_source(filter_class: type) -> str:
    """The source of a class's four parts as the class has them (a self-check's: a notebook cell's
    class too), the parts it inherits from StudentFilter left out."""
    texts = []
    for part in PARTS:
        method = getattr(filter_class, "estimate_part" if part == "estimate" else part, None)
        with contextlib.suppress(OSError, TypeError):
            texts.append(textwrap.dedent(inspect.getsource(method)))
    return "\n".join(texts)


__all__ = ["LIKENESS_LIMIT", "Likeness", "class_source", "copied_parts", "likeness"]
