"""Gradescope's autograder bundle, `mazelab exercise autograder OUT.zip` (docs/exercise.md, "On
Gradescope"): `lab/` (this lab's source, and uv.lock or the pinned `requirements.txt`), `grading.key`
(read only by run_autograder, never by the sandbox), `setup.sh` and `run_autograder` (templates/).
`MAZELAB_AUTOGRADER_ROOT` (default /autograder) and `MAZELAB_COMMAND` (default the lab's own
`.venv/bin/mazelab`) let `run_autograder` run in a simulated tree: the tests run it so, on this checkout.
"""

from __future__ import annotations

import hashlib
import io
import re
import shlex
import stat
import zipfile
from importlib import metadata
from pathlib import Path

from mazelab import __version__
from mazelab.exercise.kit import PACKAGE_DIR
from mazelab.exercise.sandbox import DEFAULT_BUDGET
from mazelab.exercise.template import TEMPLATES

ROOT = PACKAGE_DIR.parent
LAB_FILES = ("pyproject.toml", "uv.lock", "README.md", "MANIFEST.in", "main.py", "draw.py", "particle_filter.py")
DISTRIBUTION = "maze-particle-filter-lab"
LAB_FOLDERS = {"mazelab": ("*.py", "*.po", "*.txt"), "mazes": ("*.txt",), "model_parameters": ("*.json",)}
SETUP = (TEMPLATES / "setup.sh.txt").read_text()  # str.format fields: version, digest
RUN = (TEMPLATES / "run_autograder.txt").read_text()  # version, timeout, options


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
