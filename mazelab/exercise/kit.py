"""The student kit: the only lab code a submission's sandbox holds (docs/exercise.md, "The kit"):
StudentFilter and what it imports, and the child's side of the grading; never an implementation of a
graded part, the shipped filters, the grid filter or the grader.

`KIT` is the one list to extend when StudentFilter imports a new module: an entry is a module copied
whole (`WHOLE`), only its constants (`CONSTANTS`: their values, written as literals), or only the
named top-level functions and classes (with the private helpers they use). tests/test_grading_sandbox.py
checks that every module StudentFilter imports, directly or not, is here, and that no reference
implementation is.
"""

from __future__ import annotations

import ast
import hashlib
import importlib
from pathlib import Path

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


class KitError(RuntimeError):
    """The kit cannot be built: a module's constant is not a plain value (the list needs a look)."""


def source_file(module: str) -> Path:
    """The lab's source file of `module` (a package's __init__.py)."""
    relative = Path(*module.split("."))
    package = PACKAGE_DIR.parent / relative / "__init__.py"
    return package if package.is_file() else PACKAGE_DIR.parent / relative.with_suffix(".py")


def kit_file(module: str) -> Path:
    """Where `module` lies inside the kit folder (relative): where it lies beside the package."""
    return source_file(module).relative_to(PACKAGE_DIR.parent)


def constants_text(module: str) -> str:
    """A module of `module`'s upper-case constants as literals (their values now: one source of truth)."""
    loaded = importlib.import_module(module)
    lines = [f'"""The constants of {module}, as the student kit carries them."""', ""]
    for name, value in vars(loaded).items():
        upper = name.isupper() and not name.startswith("_") and name != "TYPE_CHECKING"
        literal = isinstance(value, PLAIN) or (isinstance(value, tuple) and all(isinstance(v, PLAIN) for v in value))
        if (name == "__version__" or upper) and literal:  # a repr that reads back as the same value
            lines.append(f"{name} = {value!r}")
    return "\n".join(lines) + "\n"


def selected_text(module: str, names: tuple[str, ...]) -> str:
    """`module`'s source with only its imports, its constants and the named functions and classes
    (and the private top-level helpers they use), in their order."""
    source = source_file(module).read_text()
    tree = ast.parse(source)
    defined = {n.name: n for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
    missing = [name for name in names if name not in defined]
    if missing:
        raise KitError(f"{module} has no {', '.join(missing)} (mazelab.exercise.kit.KIT)")
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
    """The text the kit holds for `module`."""
    how = KIT[module]
    if how == WHOLE:
        return source_file(module).read_text()
    if how == CONSTANTS:
        return constants_text(module)
    return selected_text(module, tuple(how))


def build_kit(folder: Path) -> str:
    """Write the kit into `folder` (which must be empty or new) and return its sha256 (of every file's
    name and text, in order): the grader builds it once and binds it read-only into each sandbox."""
    digest = hashlib.sha256()
    for module in KIT:
        target = folder / kit_file(module)
        target.parent.mkdir(parents=True, exist_ok=True)
        text = module_text(module)
        target.write_text(text)
        target.chmod(0o444)
        digest.update(f"{kit_file(module)}\0{text}\0".encode())
    for directory in sorted({p for p in folder.rglob("*") if p.is_dir()} | {folder}):
        directory.chmod(0o555)
    return digest.hexdigest()
