"""The files the exercise writes from `templates/`: `exercise new DIR` writes the student's filter
(four parts to write) and a README, in English or a language of mazelab.exercise.language (each
docstring, error text and paragraph looked up whole, the code the same; my_filter.py keeps its
`LANGUAGE`, so that its checks answer in it); `exercise autograder OUT.zip` writes Gradescope's bundle
(docs/exercise.md, "On Gradescope"): `lab/` (this lab's source, and uv.lock or a pinned requirements.txt),
`grading.key` (read by run_autograder only), `setup.sh` and `run_autograder`, which
`MAZELAB_AUTOGRADER_ROOT` (default /autograder) and `MAZELAB_COMMAND` (default the lab's own
`.venv/bin/mazelab`) let run in a simulated tree, as the tests do."""

from __future__ import annotations

import ast
import hashlib
import io
import os
import re
import shlex
import stat
import zipfile
from importlib import metadata
from pathlib import Path

from mazelab import __version__
from mazelab.atomic import NameTakenError, NotRegularFileError, output_target, write_text_atomically
from mazelab.exercise.kit import PACKAGE_DIR
from mazelab.exercise.language import catalogue_for
from mazelab.exercise.sandbox import DEFAULT_BUDGET

FILTER_FILE = "my_filter.py"
README_FILE = "README.md"

TEMPLATES = Path(__file__).resolve().parent / "templates"  # the texts as files (and the bundle's scripts)
FILTER_TEMPLATE = (TEMPLATES / f"{FILTER_FILE}.txt").read_text()
README_TEMPLATE = (TEMPLATES / f"{README_FILE}.txt").read_text()
ROOT = PACKAGE_DIR.parent
LAB_FILES = ("pyproject.toml", "uv.lock", "README.md", "MANIFEST.in", "main.py", "draw.py", "particle_filter.py")
DISTRIBUTION = "maze-particle-filter-lab"
LAB_FOLDERS = {"mazelab": ("*.py", "*.po", "*.txt"), "mazes": ("*.txt",), "model_parameters": ("*.json",)}
SETUP = (TEMPLATES / "setup.sh.txt").read_text()  # str.format fields: version, digest
RUN = (TEMPLATES / "run_autograder.txt").read_text()  # version, timeout, options


def exercise_texts(language: str = "en") -> tuple[str, str]:
    """my_filter.py and README.md in `language`: each string literal of the filter (its docstrings and
    error texts) and each paragraph of the README translated whole; ValueError for an unknown language."""
    words = catalogue_for(language)
    text = FILTER_TEMPLATE.replace('LANGUAGE = "en"', f'LANGUAGE = "{words.language}"')
    for node in ast.walk(ast.parse(FILTER_TEMPLATE)):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in words.entries:
            text = text.replace(node.value, words.entries[node.value])
    readme = "\n\n".join(words.gettext(paragraph) for paragraph in README_TEMPLATE.split("\n\n"))
    return text, readme


def write_exercise(folder: Path, force: bool = False, language: str = "en") -> list[Path]:
    """Write my_filter.py and README.md into `folder` (made if missing) through mazelab.atomic: each
    file is the old one or the new whole one, a folder, pipe, device or symlink loop at either name is
    refused, and without `force` so is any name that exists (a symlink too, dangling or not). Both
    names are checked before either file is written (a ValueError of one line); a write that fails
    (a full disk) is a WriteError naming the file, with the old file left whole. Returns the paths."""
    paths, texts = [folder / FILTER_FILE, folder / README_FILE], exercise_texts(language)
    if os.path.lexists(folder) and not folder.is_dir():
        raise ValueError(f"{folder} is not a folder (give a folder to write the exercise into)")
    if folder.is_dir() and not os.access(folder, os.W_OK):
        raise ValueError(f"{folder} is not writable: cannot write the exercise there")
    for path in paths:  # each name refused in one line where mazelab.atomic would not write it
        try:
            output_target(path, force)
        except (NameTakenError, NotRegularFileError) as error:  # "X: it exists; use --force to replace it"
            raise ValueError(str(error).removeprefix("cannot write ")) from None
        except OSError as error:  # e.g. a part of the folder's path is a file
            raise ValueError(f"cannot write {path}: {error.strerror or error}") from None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ValueError(f"cannot make the folder {folder}: {error.strerror or error}") from None
    # The README first: should a write fail, the student's my_filter.py is the one left as it was.
    for path, text in reversed(list(zip(paths, texts, strict=True))):
        write_text_atomically(path, text, replace=force)
    return paths


class BundleError(ValueError):
    """The bundle cannot be made here: one line saying why."""


def lab_files() -> list[Path]:
    """The lab's files the bundle carries (relative to the repository), sorted."""
    if not (ROOT / "pyproject.toml").is_file():
        raise BundleError(
            f"the bundle is made from the lab's source: pyproject.toml missing in {ROOT} (an install from a clone, "
            "`pip install -e CLONE` or `uv sync`, makes it from there)"
        )
    found = [Path(name) for name in LAB_FILES if (ROOT / name).is_file()]
    for folder, patterns in LAB_FOLDERS.items():
        for pattern in patterns:
            found += [p.relative_to(ROOT) for p in (ROOT / folder).rglob(pattern) if "__pycache__" not in p.parts]
    return sorted(set(found))


def source_digest(files: list[Path]) -> str:
    """sha256 of the lab's files (names and contents): which source a bundle holds."""
    digest = hashlib.sha256()
    for name in files:
        digest.update(f"{name.as_posix()}\0".encode() + (ROOT / name).read_bytes() + b"\0")
    return digest.hexdigest()


def pinned_requirements() -> str:
    """The lab's dependencies at the versions installed here (requirements.txt, where there is no uv.lock)."""
    lines = []
    for requirement in metadata.requires(DISTRIBUTION) or []:
        if "extra ==" not in requirement:
            name = re.match(r"[A-Za-z0-9_.-]+", requirement).group(0)
            lines.append(f"{name}=={metadata.version(name)}")
    return "\n".join(sorted(lines)) + "\n"


def bundle_bytes(key: bytes, lang: str | None = None, timeout: float = DEFAULT_BUDGET) -> bytes:
    """The zip: setup.sh and run_autograder (executable, the instructor's language and time budget baked
    in) and the key at its top, the lab's source under lab/."""
    files, options = lab_files(), shlex.join(["--lang", lang] if lang else [])
    texts = {
        "setup.sh": SETUP.format(version=__version__, digest=source_digest(files)),
        "run_autograder": RUN.format(version=__version__, timeout=f"{timeout:g}", options=options).replace(" \n", "\n"),
        "grading.key": key.hex() + "\n",
    }
    texts |= {f"lab/{n.as_posix()}": (ROOT / n).read_bytes() for n in files}
    if not (ROOT / "uv.lock").is_file():
        texts["lab/requirements.txt"] = pinned_requirements()
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as bundle:
        for name, text in texts.items():
            info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
            mode = 0o755 if name in ("setup.sh", "run_autograder") else 0o600 if name == "grading.key" else 0o644
            info.external_attr = (stat.S_IFREG | mode) << 16
            bundle.writestr(info, text)
    return buffer.getvalue()
