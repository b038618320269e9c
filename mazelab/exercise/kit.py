"""The student kit: the only lab code a submission's sandbox holds (docs/exercise.md, "The kit"):
StudentFilter and what it imports, and the child's side of the grading; never an implementation of a
graded part, the shipped filters, the grid filter or the grader.

`KIT` is the one list to extend when StudentFilter imports a new module: an entry is a module copied
whole (`WHOLE`), only its constants (`CONSTANTS`: their values, written as literals), or only the
named top-level functions and classes (with the private helpers they use). tests/test_grading_sandbox.py
checks that every module StudentFilter imports, directly or not, is here, and that no reference
implementation is.

Copied code is found here too, in the grader: what each part of a submission runs compared with the
lab's reference functions (`REFERENCE_SOURCES`) by their normalised tokens, as MOSS and JPlag do
(docs/exercise.md, "Copied code", which says how, and the limit's measurement).
"""

from __future__ import annotations

import ast
import contextlib
import importlib
import inspect
import io
import keyword
import textwrap
import tokenize
from functools import cache
from pathlib import Path

from mazelab.exercise.student import PARTS

WHOLE = "whole"
CONSTANTS = "constants"
PLAIN = (bool, int, float, str)  # the values a constant may hold (a tuple of them too)
PACKAGE_DIR = Path(__file__).resolve().parents[1]  # mazelab/
KIT: dict[str, str | tuple[str, ...]] = {
    "mazelab": CONSTANTS,  # the package's __init__: its version only (the real one reaches the studies)
    "mazelab.checks": WHOLE,
    "mazelab.declaration": WHOLE,
    "mazelab.contract": WHOLE,
    "mazelab.lookup": WHOLE,
    "mazelab.maze": WHOLE,
    "mazelab.seeding": WHOLE,
    "mazelab.constants": WHOLE,  # L, the outside penalty, the green circle: numbers only
    "mazelab.model": CONSTANTS,  # the same constants as the model re-exports them: never the transition or likelihood
    "mazelab.smc": WHOLE,  # the step: it calls the model object and the scheme it is given (the student's parts)
    "mazelab.stops": ("describe_exit",),  # what the student's code did when it exits (the child's words)
    # the weights' value and normalisation, not weighted_mean (the estimate is a graded part)
    "mazelab.weights": ("Weights", "read_only", "log_sum_exp", "effective_sample_size", "mass_within"),
    "mazelab.exercise": WHOLE,
    "mazelab.exercise.student": WHOLE,
    "mazelab.exercise.child": WHOLE,
}


def source_file(module: str) -> Path:
    """The lab's source file of `module` (a package's __init__.py)."""
    relative = Path(*module.split("."))
    package = PACKAGE_DIR.parent / relative / "__init__.py"
    return package if package.is_file() else PACKAGE_DIR.parent / relative.with_suffix(".py")


def kit_file(module: str) -> Path:
    """Where `module` lies inside the kit folder (relative): where it lies beside the package."""
    return source_file(module).relative_to(PACKAGE_DIR.parent)


def selected_text(module: str, names: tuple[str, ...]) -> str:
    """`module`'s source with only its imports, its constants and the named functions and classes
    (and the private top-level helpers they use), in their order."""
    source = source_file(module).read_text()
    tree = ast.parse(source)
    defined = {n.name: n for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
    missing = [name for name in names if name not in defined]
    if missing:
        raise LookupError(f"{module} has no {', '.join(missing)} (mazelab.exercise.kit.KIT)")
    keep, todo = set(), list(names)
    while todo:
        name = todo.pop()
        if name in keep:
            continue
        keep.add(name)
        used = {n.id for n in ast.walk(defined[name]) if isinstance(n, ast.Name)}
        todo += [u for u in used if u in defined and u.startswith("_")]
    body = [
        n
        for n in tree.body
        if not isinstance(n, (ast.FunctionDef, ast.ClassDef)) or n.name in keep
        if not (isinstance(n, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in n.targets))
    ]
    kept = ast.Module(body=body, type_ignores=[])
    return ast.unparse(kept) + f"\n__all__ = {sorted(names)!r}\n"


def module_text(module: str) -> str:
    """The text the kit holds for `module`: its source (WHOLE), its selected functions and classes, or
    (CONSTANTS) a module of its upper-case constants as literals (their values now: one source of truth)."""
    how = KIT[module]
    if how == WHOLE:
        return source_file(module).read_text()
    if how != CONSTANTS:
        return selected_text(module, tuple(how))
    lines = [f'"""The constants of {module}, as the student kit carries them."""', ""]
    for name, value in vars(importlib.import_module(module)).items():
        upper = name.isupper() and not name.startswith("_") and name != "TYPE_CHECKING"
        literal = isinstance(value, PLAIN) or (isinstance(value, tuple) and all(isinstance(v, PLAIN) for v in value))
        if (name == "__version__" or upper) and literal:  # a repr that reads back as the same value
            lines.append(f"{name} = {value!r}")
    return "\n".join(lines) + "\n"


def build_kit(folder: Path) -> None:
    """Write the kit into `folder` (which must be empty or new), read-only: the grader builds it once
    and binds it into each sandbox."""
    for module in KIT:
        target = folder / kit_file(module)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(module_text(module))
        target.chmod(0o444)
    for directory in sorted({p for p in folder.rglob("*") if p.is_dir()} | {folder}):
        directory.chmod(0o555)


# -- copied code -------------------------------------------------------------------------------------
K = 8  # tokens per fingerprint run
MIN_TOKENS = 24  # a reference shorter than this is an idiom anyone writes (np.average), not a copy
LIKENESS_LIMIT = 0.6  # measured: honest solutions reach at most 0.25, renamed copies 1.0 (docs/exercise.md)
REFERENCE_SOURCES = (  # where the lab's implementations of the four parts live
    "mazelab.model",
    "mazelab.resampling",
    "mazelab.weights",
    "mazelab.filters",
    "mazelab.regularisation",
)
FUNCTIONS = (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)


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


def _nearest(nodes: list[ast.AST]) -> tuple[float, str]:
    """(the share of its fingerprint in `nodes`, the qualified name) of the reference function most
    contained in `nodes`."""
    mine: set[tuple[str, ...]] = set()
    for node in nodes:
        mine |= fingerprint(tokens(node))
    references = reference_prints()
    shares = {name: len(prints & mine) / len(prints) for name, prints in references.items() if prints}
    nearest = max(shares, key=lambda name: (round(shares[name], 2), len(references[name])))  # the largest of ties
    return shares[nearest], nearest


def likeness(sources: dict[str, str]) -> dict[str, tuple[float, str]]:
    """Each part's nearest reference function in a submission's files, by containment; "whole" for the
    nearest of the functions no part reaches."""
    try:
        parts, every = part_functions(sources)
    except RecursionError:
        return {}
    found = {part: _nearest(nodes) for part, nodes in parts.items()}
    reached = {id(n) for nodes in parts.values() for top in nodes for n in ast.walk(top)}
    alone = [_nearest([node]) for node in every if id(node) not in reached]
    if alone:
        found["whole"] = max(alone, key=lambda one: one[0])
    return found


def copied_parts(sources: dict[str, str]) -> dict[str, str]:
    """The parts (and "whole") of a submission's files that are the lab's code, each with the line saying whose."""
    return {
        part: f"{share:.0%} of the lab's {reference} is in it (its code with the names changed)"
        for part, (share, reference) in likeness(sources).items()
        if share >= LIKENESS_LIMIT
    }


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
