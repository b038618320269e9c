"""Gradescope's autograder bundle: `mazelab exercise autograder OUT.zip`.

Gradescope unpacks the zip into /autograder/source, runs `setup.sh` once to build its image, then
`run_autograder` for each submission, with the student's files in /autograder/submission, and reads
/autograder/results/results.json. The bundle holds:

- `lab/`: this lab's source as it is now (the package, the shipped mazes, pyproject.toml and uv.lock),
  so that the image grades with exactly the version that made the bundle;
- `setup.sh`: bubblewrap (each submission's sandbox), uv, and `uv sync --frozen --no-dev` in lab/
  (the lab and its locked dependencies, with the Python version the lab needs);
- `run_autograder`: `mazelab exercise check /autograder/submission/my_filter.py --gradescope
  /autograder/results` (with the instructor's seed and language if given), and a results.json of
  score 0 saying why if the check wrote none.

`MAZELAB_AUTOGRADER_ROOT` (default /autograder) and `MAZELAB_COMMAND` (default the lab's own
`.venv/bin/mazelab`) let `run_autograder` run in a simulated tree against any installed lab: the
tests run it so, on this checkout.
"""

from __future__ import annotations

import hashlib
import io
import shlex
import stat
import zipfile
from pathlib import Path

from mazelab import __version__
from mazelab.exercise.kit import PACKAGE_DIR
from mazelab.exercise.runner import DEFAULT_TIMEOUT

ROOT = PACKAGE_DIR.parent
LAB_FILES = ("pyproject.toml", "uv.lock", "README.md", "MANIFEST.in", "main.py", "draw.py", "particle_filter.py")
LAB_FOLDERS = {"mazelab": ("*.py", "*.po"), "mazes": ("*.txt",), "model_parameters": ("*.json",)}
SETUP = """#!/usr/bin/env bash
# Gradescope's image: bubblewrap (the sandbox each submission is graded in), uv, and mazelab {version}
# (source sha256 {digest}) with its locked dependencies, from the lab/ folder of this bundle.
set -euo pipefail
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq bubblewrap python3 python3-pip python3-venv ca-certificates >/dev/null
python3 -m pip install --quiet --break-system-packages uv 2>/dev/null || python3 -m pip install --quiet uv
cd /autograder/source/lab
python3 -m uv sync --frozen --no-dev
.venv/bin/mazelab exercise --help >/dev/null
"""
RUN = """#!/usr/bin/env bash
# Gradescope runs this for each submission: the check of my_filter.py, its results.json where Gradescope
# reads it (a 0 with the reason when the file cannot be checked). Made by mazelab {version}.
set -uo pipefail
root="${{MAZELAB_AUTOGRADER_ROOT:-/autograder}}"
read -r -a mazelab <<< "${{MAZELAB_COMMAND:-$root/source/lab/.venv/bin/mazelab}}"
mkdir -p "$root/results"
rm -f "$root/results/results.json"
"${{mazelab[@]}}" exercise check "$root/submission/my_filter.py" --gradescope "$root/results" --force \\
    --timeout {timeout} {options}
code=$?
if [ ! -s "$root/results/results.json" ]; then
    printf '{{"score": 0.0, "output": "the autograder could not check my_filter.py (exit code %s)", "tests": []}}\\n' \\
        "$code" > "$root/results/results.json"
fi
exit 0
"""


class BundleError(ValueError):
    """The bundle cannot be made here: one line saying why."""


def lab_files() -> list[Path]:
    """The lab's files the bundle carries (relative to the repository), sorted."""
    missing = [name for name in LAB_FILES[:2] if not (ROOT / name).is_file()]
    if missing:
        raise BundleError(f"the bundle is made from a checkout of the lab: {', '.join(missing)} missing in {ROOT}")
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


def run_script(seed: int | None = None, lang: str | None = None, timeout: float = DEFAULT_TIMEOUT) -> str:
    """run_autograder's text (the instructor's seed and language baked in)."""
    options = [*(["--seed", str(seed)] if seed is not None else []), *(["--lang", lang] if lang else [])]
    return RUN.format(version=__version__, timeout=f"{timeout:g}", options=shlex.join(options)).replace(" \n", "\n")


def bundle_bytes(seed: int | None = None, lang: str | None = None, timeout: float = DEFAULT_TIMEOUT) -> bytes:
    """The zip: setup.sh and run_autograder (executable) at its top, the lab's source under lab/."""
    files = lab_files()
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as bundle:
        scripts = {
            "setup.sh": SETUP.format(version=__version__, digest=source_digest(files)),
            "run_autograder": run_script(seed, lang, timeout),
        }
        for name, text in scripts.items():
            info = zipfile.ZipInfo(name, date_time=(2020, 1, 1, 0, 0, 0))
            info.external_attr = (stat.S_IFREG | 0o755) << 16
            bundle.writestr(info, text)
        for name in files:
            info = zipfile.ZipInfo(f"lab/{name.as_posix()}", date_time=(2020, 1, 1, 0, 0, 0))
            info.external_attr = (stat.S_IFREG | 0o644) << 16
            bundle.writestr(info, (ROOT / name).read_bytes())
    return buffer.getvalue()


__all__ = ["BundleError", "bundle_bytes", "lab_files", "run_script", "source_digest"]
