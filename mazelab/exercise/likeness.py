"""Copied code, found in the grader (never in the student's process): what each part of a submission
runs compared with the lab's reference functions by their normalised tokens, as MOSS and JPlag do
(docs/exercise.md, "Copied code": what a part resolves to, the fingerprints of K tokens, containment,
and the limit measured on the honest solutions by `benchmarks/copy_likeness.py`). Code that is not in
the files cannot run in the student's process (mazelab.exercise.child.guard).
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
from mazelab.exercise.student import PARTS

K = 8  # tokens per fingerprint run
MIN_TOKENS = 24  # a reference shorter than this is an idiom anyone writes (np.average), not a copy
LIKENESS_LIMIT = 0.6  # measured: honest solutions reach at most 0.31, renamed copies 1.0 (docs/exercise.md)
REFERENCE_SOURCES = (  # where the lab's implementations of the four parts live
    "mazelab.model",
    "mazelab.resampling",
    "mazelab.weights",
    "mazelab.filters",
    "mazelab.regularisation",
)
FUNCTIONS = (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)


@dataclass(frozen=True)
class Likeness:
    """A part's nearest reference function: its qualified name and the share of its fingerprint in the part."""

    part: str
    reference: str
    share: float

    @property
    def copied(self) -> bool:
        return self.share >= LIKENESS_LIMIT

    def text(self) -> str:
        return f"{self.share:.0%} of the lab's {self.reference} is in it (its code with the names changed)"


def _plain(tree: ast.AST) -> ast.AST:
    """`tree` without docstrings and annotations (a copy's annotations are not its code)."""
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            node.returns = None
        elif isinstance(node, ast.arg):
            node.annotation = None
        body = getattr(node, "body", None)
        if isinstance(body, list):
            if body and isinstance(body[0], ast.Expr) and isinstance(getattr(body[0], "value", None), ast.Constant):
                body = body[1:] if isinstance(body[0].value.value, str) else body
            plain = [s for s in body if not (isinstance(s, ast.AnnAssign) and s.value is None)]
            body = [ast.Assign([s.target], s.value, lineno=0) if isinstance(s, ast.AnnAssign) else s for s in plain]
            node.body = body or [ast.Pass()]
    return tree


def tokens(node: ast.AST) -> list[str]:
    """The normalised tokens of a parsed function: names (not attributes) as one placeholder, strings
    as another, comments, docstrings, annotations and layout gone."""
    text = ast.unparse(_plain(ast.parse(ast.unparse(node))))
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


def qualified_functions(tree: ast.AST, prefix: str) -> list[tuple[str, ast.AST]]:
    """Every function of `tree` with its qualified name (prefix.Class.method, prefix.outer.inner)."""
    found = []
    for node in getattr(tree, "body", []):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            if not isinstance(node, ast.ClassDef):
                found.append((f"{prefix}.{node.name}", node))
            found += qualified_functions(node, f"{prefix}.{node.name}")
    return found


@cache
def reference_prints() -> dict[str, set[tuple[str, ...]]]:
    """The fingerprint of every reference function (and method) of at least MIN_TOKENS tokens, by qualified name."""
    prints = {}
    for module in REFERENCE_SOURCES:
        for name, node in qualified_functions(ast.parse(source_file(module).read_text()), module):
            found = tokens(node)
            if len(found) >= MIN_TOKENS:
                prints[name] = fingerprint(found)
    return prints


def _named(trees: list[ast.AST]) -> dict[str, list[ast.AST]]:
    """What each name of the files may stand for: the functions of that name, the values bound to it
    (`predict = _p`, a lambda, a staticmethod), and the names imported as it (`from h import f as g`)."""
    table: dict[str, list[ast.AST]] = {}
    for tree in trees:
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                table.setdefault(node.name, []).append(node)
            elif isinstance(node, (ast.Assign, ast.AnnAssign)) and node.value is not None:
                for target in node.targets if isinstance(node, ast.Assign) else [node.target]:
                    for name in (n.id for n in ast.walk(target) if isinstance(n, ast.Name)):
                        table.setdefault(name, []).append(node.value)
            elif isinstance(node, ast.ImportFrom):
                for alias in node.names:
                    table.setdefault(alias.asname or alias.name, []).append(ast.Name(alias.name))
    return table


def part_functions(sources: dict[str, str]) -> tuple[dict[str, list[ast.AST]], list[ast.AST]]:
    """Each part's code in a submission's files ({file name: text}): what its name stands for, and all
    that this calls or names, to any depth (never another part); and every function of the files."""
    trees = []
    for text in sources.values():
        with contextlib.suppress(SyntaxError, ValueError, RecursionError):
            trees.append(ast.parse(text))
    table, found = _named(trees), {}
    for part in PARTS:
        seen, todo = [], list(table.get(part, []))
        while todo:
            node = todo.pop()
            if any(node is s for s in seen):
                continue
            seen.append(node)
            for used in ast.walk(node):
                name = used.id if isinstance(used, ast.Name) else getattr(used, "attr", None)
                todo += table.get(name, []) if name not in PARTS else []
        if seen:
            found[part] = seen
    return found, [n for tree in trees for n in ast.walk(tree) if isinstance(n, FUNCTIONS)]


def _nearest(nodes: list[ast.AST], part: str) -> Likeness:
    """The reference function most contained in `nodes`."""
    mine: set[tuple[str, ...]] = set()
    for node in nodes:
        mine |= fingerprint(tokens(node))
    references = reference_prints()
    shares = {name: len(prints & mine) / len(prints) for name, prints in references.items() if prints}
    nearest = max(shares, key=lambda name: (round(shares[name], 2), len(references[name])))  # the largest of ties
    return Likeness(part, nearest, shares[nearest])


def likeness(sources: dict[str, str]) -> dict[str, Likeness]:
    """Each part's nearest reference function in a submission's files, by containment; "whole" for the
    nearest of the functions no part reaches."""
    try:
        parts, every = part_functions(sources)
    except RecursionError:
        return {}
    found = {part: _nearest(nodes, part) for part, nodes in parts.items()}
    reached = {id(n) for nodes in parts.values() for top in nodes for n in ast.walk(top)}
    alone = [_nearest([node], "whole") for node in every if id(node) not in reached]
    if alone:
        found["whole"] = max(alone, key=lambda one: one.share)
    return found


def copied_parts(sources: dict[str, str]) -> dict[str, str]:
    """The parts (and "whole") of a submission's files that are the lab's code, each with the line saying whose."""
    return {part: one.text() for part, one in likeness(sources).items() if one.copied}


def class_source(filter_class: type) -> str:
    """The source of a class's four parts as the class has them (a self-check's: a notebook cell's
    class too), each bound to its part's name; the parts it inherits from StudentFilter left out."""
    texts = []
    for part in PARTS:
        method = getattr(filter_class, "estimate_part" if part == "estimate" else part, None)
        with contextlib.suppress(OSError, TypeError):
            source = textwrap.dedent(inspect.getsource(method))
            texts.append(f"{part} = {method.__name__}\n{source}" if method.__name__ != part else source)
    return "\n".join(texts)
