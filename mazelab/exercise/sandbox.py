"""Where a submission's code runs: a bubblewrap sandbox of its own (Linux), or, where none can be made,
a plain process (macOS, Windows, no `bwrap`) whose verdict a hostile submission can forge.

The sandbox (`bwrap`, the one Flatpak uses) is a new user, PID, network, IPC, UTS and mount
namespace: an unprivileged uid (65534), no network, a private /tmp, a new /proc and /dev, and
read-only views of only the interpreter, the system's libraries, numpy, the student kit
(mazelab.exercise.kit) and the submission's own copy. The lab's source, the other submissions, the
grader's output folders and the user's home are not there. Every process the submission starts is
in the sandbox's PID namespace and dies with it (`--die-with-parent`; the namespace ends when its
first process does). The time and memory limits are set by the grader on the sandbox's first
process before it runs (setrlimit), outside the student's reach, and inherited by everything inside.

`bwrap` is the Debian and Ubuntu package `bubblewrap`; where it is missing or cannot make namespaces
(a container that forbids them), `sandbox()` says why in one line, and grading runs unsandboxed
unless the caller requires the sandbox.
"""

from __future__ import annotations

import functools
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mazelab.exercise.kit import PACKAGE_DIR

SANDBOX_UID = 65534  # "nobody"
TMP_LIMIT = 256 << 20  # bytes the sandbox's private /tmp (in memory) may hold, where bwrap can bound it (0.7+)
KIT_ROOT, SITE_ROOT, SUBMISSION_ROOT = "/kit", "/site", "/submission"
UNSANDBOXED = (
    "not sandboxed ({why}): the student's code ran with the grader's rights, so a hostile submission's "
    "verdict cannot be trusted here"
)
CHILD_ENVIRONMENT = {  # the child's whole environment: one thread each, a fixed str hash
    # (python -P -S -s -B -u: no folder of the grader's on sys.path, no site, no bytecode, prints unbuffered)
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "PYTHONHASHSEED": "0",
    "HOME": "/tmp",
    "LANG": "C.UTF-8",
}
ENTRY = "import sys; sys.path[:0] = [{kit!r}, {site!r}]; from mazelab.exercise.child import main; main({fd})"


class SandboxRequiredError(RuntimeError):
    """--require-sandbox, and no sandbox can be made here: one line saying why."""


@dataclass(frozen=True)
class Sandbox:
    """How children are started here: in bwrap (`bwrap` its path) or plain (`why` none can be made)."""

    bwrap: str | None
    why: str = ""
    bounded_tmp: bool = True  # bwrap bounds the private /tmp (--size, bubblewrap 0.7 and later)

    @property
    def sandboxed(self) -> bool:
        return self.bwrap is not None

    @property
    def note(self) -> str:
        """'' in a sandbox; else the one line the report, the CSV and results.json carry."""
        return "" if self.sandboxed else UNSANDBOXED.format(why=self.why)

    def command(self, kit: Path, run: Path, answers: int) -> list[str]:
        """The command that runs mazelab.exercise.child on the kit with `run/submission/` as the only
        student files (`run/site/` holds links to numpy where there is no sandbox), answering on the
        descriptor `answers`."""
        python = os.path.realpath(sys.executable)
        if not self.sandboxed:
            entry = ENTRY.format(kit=str(kit), site=str(run / "site"), fd=answers)
            return [python, "-P", "-S", "-s", "-B", "-u", "-c", entry]
        entry = ENTRY.format(kit=KIT_ROOT, site=SITE_ROOT, fd=answers)
        return [
            self.bwrap,
            *bwrap_arguments(kit, run / "submission"),
            "--",
            python,
            "-P",
            "-S",
            "-s",
            "-B",
            "-u",
            "-c",
            entry,
        ]

    def inside(self, run: Path, name: str) -> str:
        """The submission's path as the child sees it."""
        return f"{SUBMISSION_ROOT}/{name}" if self.sandboxed else str(run / "submission" / name)


def numpy_folders() -> list[Path]:
    """numpy's package folder and, for a wheel, its bundled libraries (numpy.libs) beside it."""
    package = Path(np.__file__).resolve().parent
    return [p for p in (package, package.parent / "numpy.libs") if p.is_dir()]


def _system_binds() -> list[str]:
    """The system's libraries, read-only, as the host lays them out (/lib a link to /usr/lib or not)."""
    arguments: list[str] = []
    for top in ("/usr/lib", "/usr/lib64", "/lib", "/lib64", "/lib32", "/usr/lib32"):
        path = Path(top)
        if path.is_symlink():
            arguments += ["--symlink", os.readlink(path), top]
        elif path.is_dir():
            arguments += ["--ro-bind", top, top]
    return arguments


def interpreter_folders() -> list[str]:
    """The folders the interpreter needs: its installation (the standard library) and its binary's."""
    folders = {os.path.realpath(sys.base_prefix), os.path.dirname(os.path.realpath(sys.executable))}
    return sorted(f for f in folders if not any(f != g and f.startswith(g + os.sep) for g in folders))


def bwrap_arguments(kit: Path, submission: Path, bounded_tmp: bool = True) -> list[str]:
    """bwrap's options: the namespaces, the uid, a private /tmp (of at most TMP_LIMIT bytes where
    `bounded_tmp`), the read-only binds, and the lab hidden where an interpreter folder holds it (a
    lab installed into the system's Python)."""
    size = ["--size", str(TMP_LIMIT)] if bounded_tmp else []
    arguments = [
        "--unshare-all", "--unshare-user", "--uid", str(SANDBOX_UID), "--gid", str(SANDBOX_UID),
        "--die-with-parent", "--new-session", "--cap-drop", "ALL", "--hostname", "sandbox",
        "--proc", "/proc", "--dev", "/dev", *size, "--tmpfs", "/tmp", *_system_binds(),
    ]  # fmt: skip
    for folder in interpreter_folders():
        arguments += ["--ro-bind", folder, folder]
        hidden = Path(folder)
        if PACKAGE_DIR.is_relative_to(hidden):
            arguments += ["--tmpfs", str(PACKAGE_DIR)]
    for folder in numpy_folders():
        arguments += ["--ro-bind", str(folder), f"{SITE_ROOT}/{folder.name}"]
    arguments += ["--ro-bind", str(kit), KIT_ROOT, "--ro-bind", str(submission), SUBMISSION_ROOT]
    arguments += ["--chdir", "/tmp", "--clearenv"]
    for name, value in CHILD_ENVIRONMENT.items():
        arguments += ["--setenv", name, value]
    return arguments


@functools.cache
def sandbox() -> Sandbox:
    """The sandbox of this machine: bwrap if it is installed and makes a sandbox here (tried once),
    else plain, saying why."""
    if sys.platform != "linux":
        return Sandbox(None, f"no bubblewrap sandbox on {sys.platform}")
    found = os.environ.get("MAZELAB_BWRAP") or shutil.which("bwrap")
    if not found:
        return Sandbox(None, "bwrap is not installed; on Debian or Ubuntu: apt-get install bubblewrap")
    empty = Path(os.path.realpath(sys.base_prefix))
    why = "no reason given"
    for bounded in (True, False):  # an older bwrap (before 0.7) cannot bound /tmp: a sandbox all the same
        probe = [found, *bwrap_arguments(empty, empty, bounded), "--", os.path.realpath(sys.executable), "-S", "-c", ""]
        try:
            done = subprocess.run(probe, capture_output=True, timeout=30, check=False)
        except (OSError, subprocess.TimeoutExpired) as error:
            return Sandbox(None, f"bwrap cannot run here ({error})")
        if done.returncode == 0:
            return Sandbox(found, bounded_tmp=bounded)
        why = (done.stderr.decode(errors="replace").strip().splitlines() or [why])[-1]
    return Sandbox(None, f"bwrap cannot make a sandbox here ({why[:120]})")


def require_sandbox() -> Sandbox:
    """The sandbox, or SandboxRequiredError naming why there is none."""
    made = sandbox()
    if not made.sandboxed:
        raise SandboxRequiredError(f"--require-sandbox: {made.why}")
    return made


__all__ = [
    "CHILD_ENVIRONMENT",
    "UNSANDBOXED",
    "Sandbox",
    "SandboxRequiredError",
    "bwrap_arguments",
    "numpy_folders",
    "require_sandbox",
    "sandbox",
]
