"""Where and how a submission's code runs: a bubblewrap sandbox of its own, or a plain process where
none can be made, with the limits set before any of its code runs; and one run of the student's
process, read without trusting it. docs/exercise.md ("The sandbox") says what each holds, which limits
hold on which host, and how a run may end (`ChildRun`); a run that never said "hello" never ran the
student's code: the sandbox failed, the grader's error (SandboxError), never the student's grade.
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import functools
import math
import os
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from mazelab.exercise.child import Message, WireError, encode, messages
from mazelab.exercise.kit import PACKAGE_DIR, build_kit

DEFAULT_BUDGET = 40.0  # wall seconds of a submission's processes in all: 3 x a correct one's (1-3 s) + 30
MAX_TIMEOUT = 86_400.0  # a day: the largest --timeout (a processor-time limit must be a finite number)
MEMORY_LIMIT = 4 << 30  # bytes of address space per process, and of memory per sandbox (cgroup)
FILE_LIMIT = 64 << 20  # the largest file the child may write
PROCESS_LIMIT = 64  # processes and threads per sandbox
TMP_LIMIT = 256 << 20  # bytes the sandbox's private /tmp (in memory) may hold, where bwrap can bound it (0.7+)
STARTUP = 30.0  # wall seconds a sandbox may take to start the child, the grader's, not the submission's
STARTUP_CPU = 3  # processor seconds the child's start takes at most (the interpreter, numpy, the kit, the guard)
OUTPUT_KEPT = 2000  # characters of the child's prints kept (its first and its last)
SANDBOX_UID = 65534  # "nobody"
COMPANIONS_KEPT = 50  # at most this many Python files beside a submission are copied with it
KIT_ROOT, SITE_ROOT, SUBMISSION_ROOT = "/kit", "/site", "/submission"
UNSANDBOXED = (
    "not sandboxed ({why}): the student's code ran with the grader's rights, so a hostile submission's "
    "verdict cannot be trusted here"
)
CHILD_ENVIRONMENT = {  # the child's whole environment, and bwrap's: one thread each, a fixed str hash
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",  # the compiled backend's kernels too
    "PYTHONHASHSEED": "0",
    "HOME": "/tmp",
    "LANG": "C.UTF-8",
    "PATH": "/usr/bin:/bin",
}
BWRAP_OPTIONS = (  # the namespaces, the uid, a session and no capabilities, its own /proc and /dev
    "--unshare-all --unshare-user",
    f"--uid {SANDBOX_UID} --gid {SANDBOX_UID}",
    "--die-with-parent --new-session",
    "--cap-drop ALL",
    "--hostname sandbox",
    "--proc /proc --dev /dev",
)
# python -P -S -s -B -u: no folder of the grader's on sys.path, no site, no bytecode, prints unbuffered
PYTHON = ("-P", "-S", "-s", "-B", "-u")
ENTRY = "import sys; sys.path[:0] = [{kit!r}, {site!r}]; from mazelab.exercise.child import main; main({fd})"
_LIBC = ctypes.CDLL(None, use_errno=True) if sys.platform == "linux" else None  # loaded before any fork


class SandboxError(RuntimeError):
    """The sandbox failed before the student's code ran: the grader's error, one line."""


@dataclass(frozen=True)
class Sandbox:
    """How children are started here: in bwrap (`bwrap` its path) or plain (`why` none can be made)."""

    bwrap: str | None
    why: str = ""
    bounded_tmp: bool = True  # this bwrap bounds the private /tmp (--size, bubblewrap 0.7 and later)

    @property
    def sandboxed(self) -> bool:
        return self.bwrap is not None

    @property
    def note(self) -> str:
        """'' in a sandbox; else the one line the report, the CSV and results.json carry."""
        return "" if self.sandboxed else UNSANDBOXED.format(why=self.why)

    def command(self, kit: Path, run: Path, answers: int | None, staged: dict[str, str] | None = None) -> list[str]:
        """The command that runs mazelab.exercise.child on the kit with `run/submission/` as the only
        student files (`run/site/` holds links to numpy where there is no sandbox), answering on the
        descriptor `answers` (None: nothing runs, the probe). bwrap's options: the namespaces, the uid, a
        private /tmp (of at most TMP_LIMIT bytes where `bounded_tmp`), the read-only binds (from
        `staged[source]` where given: the root's drop to nobody), the lab hidden where an interpreter
        folder holds it (a lab installed into the system's Python), a minimal environment."""
        python = [os.path.realpath(sys.executable), *PYTHON, "-c"]
        roots = (KIT_ROOT, SITE_ROOT) if self.sandboxed else (str(kit), str(run / "site"))
        code = "" if answers is None else ENTRY.format(kit=roots[0], site=roots[1], fd=answers)
        if not self.sandboxed:
            return [*python, code]
        size = ["--size", str(TMP_LIMIT)] if self.bounded_tmp else []
        arguments = [word for option in BWRAP_OPTIONS for word in option.split()] + [*size, "--tmpfs", "/tmp"]
        for top in ("/usr/lib", "/usr/lib64", "/lib", "/lib64", "/lib32", "/usr/lib32"):  # as the host lays them out
            if Path(top).is_symlink():
                arguments += ["--symlink", os.readlink(top), top]
            elif Path(top).is_dir():
                arguments += ["--ro-bind", top, top]
        for source, target in read_only_binds(kit, run):
            arguments += ["--ro-bind", (staged or {}).get(source, source), target]
            if target != KIT_ROOT and PACKAGE_DIR.is_relative_to(source):
                arguments += ["--tmpfs", str(PACKAGE_DIR)]
        arguments += ["--chdir", "/tmp", "--clearenv"]
        for name, value in CHILD_ENVIRONMENT.items():
            arguments += ["--setenv", name, value]
        return [self.bwrap, *arguments, "--", *python, code]

    def inside(self, run: Path, name: str) -> str:
        """The submission's path as the child sees it."""
        return f"{SUBMISSION_ROOT}/{name}" if self.sandboxed else str(run / "submission" / name)


def read_only_binds(kit: Path, run: Path) -> list[tuple[str, str]]:
    """(source, target) of each folder a sandbox binds read-only: the interpreter's (its installation, the
    standard library, and its binary's folder, unless one holds the other), numpy's (under SITE_ROOT), the
    kit and the submission's copy (`run/submission/`)."""
    folders = {os.path.realpath(sys.base_prefix), os.path.dirname(os.path.realpath(sys.executable))}
    python = sorted(f for f in folders if not any(f != g and f.startswith(g + os.sep) for g in folders))
    binds = [(f, f) for f in python] + [(str(f), f"{SITE_ROOT}/{f.name}") for f in numpy_folders()]
    return [*binds, (str(kit), KIT_ROOT), (str(run / "submission"), SUBMISSION_ROOT)]


def numpy_folders() -> list[Path]:
    """numpy's package folder and, for a wheel, its bundled libraries (numpy.libs) beside it."""
    package = Path(np.__file__).resolve().parent
    return [p for p in (package, package.parent / "numpy.libs") if p.is_dir()]


@functools.cache
def sandbox() -> Sandbox:
    """The sandbox of this machine: bwrap if it is installed and makes a sandbox here (its command tried
    once with --size and once without), else plain, saying why."""
    if sys.platform != "linux":
        return Sandbox(None, f"no bubblewrap sandbox on {sys.platform}")
    found = os.environ.get("MAZELAB_BWRAP") or shutil.which("bwrap")
    if not found:
        return Sandbox(None, "bwrap is not installed; on Debian or Ubuntu: apt-get install bubblewrap")
    why = "no reason given"
    with tempfile.TemporaryDirectory(prefix="mazelab-probe-") as run:
        (Path(run) / "submission").mkdir()
        for made in (Sandbox(found), Sandbox(found, bounded_tmp=False)):  # before 0.7, /tmp cannot be bounded
            try:  # the command a child runs, on an empty submission, running nothing
                probe = made.command(Path(run), Path(run), None)
                done = subprocess.run(probe, capture_output=True, timeout=30, check=False, env=CHILD_ENVIRONMENT)
            except (OSError, subprocess.TimeoutExpired) as error:
                return Sandbox(None, f"bwrap cannot run here ({error})")
            if done.returncode == 0:
                return made
            why = (done.stderr.decode(errors="replace").strip().splitlines() or [why])[-1]
    return Sandbox(None, f"bwrap cannot make a sandbox here ({why[:120]})")


# -- the limits of one sandbox ---------------------------------------------------------------------------
@functools.cache
def cgroup_parents() -> list[Path] | None:
    """The folders under which this grader may make a cgroup with a process and a memory limit: cgroup
    v2's (its own cgroup or the nearest above it with both controllers for its children that it may
    write: a delegated one, or the root's as root), else v1's pids and memory folders (as root); None."""
    if sys.platform != "linux" or os.environ.get("MAZELAB_CGROUPS") == "off":
        return None
    own = dict(line.split(":", 2)[1:] for line in Path("/proc/self/cgroup").read_text().splitlines())
    found: dict[str, Path] = {}
    for _, point, kind, options, *_ in (line.split() for line in Path("/proc/self/mounts").read_text().splitlines()):
        if kind == "cgroup2":
            mine = Path(point + own.get("", "/"))  # its own cgroup, then those above it (a delegated one)
            for parent in [p for p in (mine, *mine.parents) if p.is_relative_to(point)]:
                controls = (parent / "cgroup.subtree_control").read_text().split() if parent.is_dir() else []
                if {"pids", "memory"} <= set(controls) and os.access(parent, os.W_OK):
                    return [parent]
        elif kind == "cgroup":
            for controller in {"pids", "memory"} & set(options.split(",")):
                if os.access(Path(point + own.get(controller, "/")), os.W_OK):
                    found[controller] = Path(point + own.get(controller, "/"))
    return sorted(found.values()) if len(found) == 2 else None


class Cgroup:
    """A cgroup of its own for one child (made with its LIMITS, the child moved in before it starts,
    emptied and removed at the end); `folders` is empty where none can be made."""

    # each written where the controller has the file (v2: the first three, memory.swap.max only with swap
    # accounting; v1: pids.max in the pids hierarchy, memory.limit_in_bytes in the memory one)
    LIMITS: ClassVar[dict[str, int]] = {
        "pids.max": PROCESS_LIMIT,
        "memory.max": MEMORY_LIMIT,
        "memory.swap.max": 0,
        "memory.limit_in_bytes": MEMORY_LIMIT,
    }

    def __init__(self) -> None:
        self.folders: list[Path] = []
        name = f"mazelab-{os.getpid()}-{threading.get_ident()}-{time.monotonic_ns()}"
        written = set()
        try:
            for parent in cgroup_parents() or []:
                (parent / name).mkdir()
                self.folders.append(parent / name)
                for limit, value in self.LIMITS.items():
                    if (parent / name / limit).exists():
                        (parent / name / limit).write_text(str(value))
                        written.add(limit)
        except OSError:
            written = set()
        if self.folders and ("pids.max" not in written or not written & {"memory.max", "memory.limit_in_bytes"}):
            self.close()  # no process or no memory limit: the fallback's RLIMIT_NPROC holds instead
        self._procs = [os.fsencode(f / "cgroup.procs") for f in self.folders]

    def enter(self) -> None:
        """Move this process in (run in the child before exec: everything it starts stays in)."""
        for path in self._procs:
            fd = os.open(path, os.O_WRONLY)
            os.write(fd, b"0")
            os.close(fd)

    def close(self) -> None:
        """End every process left in it (an escaped one of a plain child too), then remove it."""
        for folder in self.folders:
            for _ in range(50):
                with contextlib.suppress(OSError, ValueError):
                    for pid in (folder / "cgroup.procs").read_text().split():
                        os.kill(int(pid), signal.SIGKILL)
                with contextlib.suppress(OSError):
                    folder.rmdir()
                if not folder.exists():
                    break
                time.sleep(0.02)
        self.folders = []


def _reachable_by_nobody(path: str) -> bool:
    """Whether every folder on the way to `path` may be searched by others (uid 65534)."""
    parts = Path(path).parts
    return all(os.stat(Path(*parts[:i])).st_mode & stat.S_IXOTH for i in range(1, len(parts) + 1))


def _dropped(bound: list[str], stage: Path) -> Any:
    """As root without a cgroup: the preexec step that drops the sandbox to uid 65534 (RLIMIT_NPROC then
    counts), binding each source nobody cannot reach onto a folder under `stage` first (in a mount
    namespace of the child's own); and the staged places. Elsewhere (None, {})."""
    if os.geteuid() != 0 or _LIBC is None:
        return None, {}
    staged = {s: str(stage / str(i)) for i, s in enumerate(bound) if not _reachable_by_nobody(s)}
    for place in staged.values():
        Path(place).mkdir(parents=True, exist_ok=True)
    stage.chmod(0o755)

    def drop() -> None:
        if staged:  # CLONE_NEWNS, then / private, then each bind (MS_BIND | MS_REC)
            if _LIBC.unshare(0x00020000) or _LIBC.mount(None, b"/", None, (1 << 14) | (1 << 18), None):
                raise OSError(ctypes.get_errno(), "cannot make a mount namespace to stage the sandbox's binds")
            for source, place in staged.items():
                if _LIBC.mount(os.fsencode(source), os.fsencode(place), None, 4096 | (1 << 14), None):
                    raise OSError(ctypes.get_errno(), f"cannot stage {source}")
        os.setgroups([])
        os.setresgid(SANDBOX_UID, SANDBOX_UID, SANDBOX_UID)
        os.setresuid(SANDBOX_UID, SANDBOX_UID, SANDBOX_UID)

    return drop, staged


def _preexec(seconds: float, cgroup: Cgroup, drop: Any) -> Any:
    """What runs in the child before exec: its cgroup, its processor time (SIGXCPU at the limit,
    SIGKILL two seconds later), memory, no core file, a bounded file size (each never above the
    grader's own hard limit), the drop to nobody."""
    try:
        import resource
    except ImportError:  # Windows: the grader's clock is all there is
        return None
    cpu = math.ceil(min(seconds, MAX_TIMEOUT))
    wanted = {
        resource.RLIMIT_CPU: (cpu, cpu + 2),
        resource.RLIMIT_AS: (MEMORY_LIMIT, MEMORY_LIMIT),
        resource.RLIMIT_CORE: (0, 0),
        resource.RLIMIT_FSIZE: (FILE_LIMIT, FILE_LIMIT),
    }
    hard = {which: resource.getrlimit(which)[1] for which in wanted}
    settings = [
        (which, values if hard[which] == resource.RLIM_INFINITY else tuple(min(v, hard[which]) for v in values))
        for which, values in wanted.items()
    ]

    def apply() -> None:
        signal.pthread_sigmask(signal.SIG_SETMASK, [])  # a grading thread blocks the stop signals
        cgroup.enter()
        for which, values in settings:
            resource.setrlimit(which, values)
        if drop is not None:
            drop()

    return apply


# -- the kit and the submission's copy --------------------------------------------------------------------
_kit_lock = threading.Lock()
_kit: list[Path] = []  # the one built (grading threads share it)


def kit() -> Path:
    """The student kit of this process: built once, in a temporary folder removed at exit."""
    with _kit_lock:
        if not _kit:
            folder = Path(tempfile.mkdtemp(prefix="mazelab-kit-"))
            folder.chmod(0o755)  # the sandbox may run as nobody (as root without a cgroup)
            atexit.register(_remove, folder)
            build_kit(folder / "kit")
            _kit.append(folder / "kit")
        return _kit[0]


def _remove(folder: Path) -> None:
    """Remove a folder of read-only files and folders."""
    for path in [folder, *folder.rglob("*")]:
        with contextlib.suppress(OSError):
            path.chmod(0o755 if path.is_dir() else 0o644)
    shutil.rmtree(folder, ignore_errors=True)


def companions_of(path: Path) -> list[Path]:
    """The Python files beside a submission (its helper modules), regular files only, by name."""
    beside = [p for p in path.parent.glob("*.py") if p.name != path.name and p.is_file() and not p.is_symlink()]
    return sorted(beside)[:COMPANIONS_KEPT]


@contextlib.contextmanager
def submission_copy(files: dict[str, bytes]) -> Any:
    """A folder holding only read-only copies of the submission's files ({name: bytes} as the grader
    read them, in `submission/`), and for a plain child `site/` with links to numpy; removed
    afterwards. Yields the folder."""
    run = Path(tempfile.mkdtemp(prefix="mazelab-run-"))
    try:
        (run / "submission").mkdir()
        for name, data in files.items():
            (run / "submission" / name).write_bytes(data)
            (run / "submission" / name).chmod(0o444)
        (run / "site").mkdir()
        (run / "stage").mkdir()  # where a root grader without a cgroup stages the binds nobody cannot reach
        for folder in numpy_folders():
            (run / "site" / folder.name).symlink_to(folder)
        for folder in (run / "submission", run / "site", run):
            folder.chmod(0o555)
        yield run
    finally:
        _remove(run)


# -- one run -------------------------------------------------------------------------------------------
_running: set[subprocess.Popen] = set()  # the children alive now (what `stop_children` ends)
_running_lock = threading.Lock()
_stopped = threading.Event()


def stop_children() -> None:
    """End every running child (and its sandbox) and start no new one until `allow_children`."""
    _stopped.set()
    with _running_lock:
        running = list(_running)
    for process in running:
        _end_session(process)


def allow_children() -> None:
    _stopped.clear()


@dataclass
class ChildRun:
    """What one run gave: when it said hello, what it said of the class it loaded, each stage's answer,
    the stages answered twice, the stages (and the whole filter's scenario) it started, how it ended
    (None: it said "done"), its prints, and how long it took (from its hello: the student's time)."""

    hello: float | None = None
    loaded: dict[str, Any] | None = None
    results: dict[str, Message] = field(default_factory=dict)
    twice: set[str] = field(default_factory=set)
    started: list[str] = field(default_factory=list)
    scenario: int | None = None
    ended: str | None = None
    output: str = ""
    seconds: float = 0.0
    done: bool = False  # its last message was "done"
    unreadable: str | None = None  # what made its answers unreadable

    @property
    def stage(self) -> str:
        """Where it was: the last stage it started ("import" before any)."""
        return self.started[-1] if self.started else "import"

    def where(self) -> str:
        """'while importing the file', 'in predict', 'in the whole filter (scenario 3)'."""
        if self.loaded is None or not self.started:
            return "while importing the file"
        if self.stage == "whole":
            return "in the whole filter" + ("" if self.scenario is None else f" (scenario {self.scenario + 1})")
        return f"in {self.stage}"

    def take(self, message: Message) -> bool:
        """Record one message (False: it ends the conversation as unreadable). A second "loaded" (two
        processes answering: "loaded" in `twice`) voids every answer; a stage answered twice voids that stage."""
        meta, kind = message.meta, message.meta.get("kind")
        stage, self.done = meta.get("stage"), kind == "done"
        if kind == "hello" and self.hello is None:
            self.hello = time.perf_counter()
        elif kind == "loaded":
            self.twice |= set() if self.loaded is None else {"loaded"}
            self.loaded = meta
        elif kind == "stage" and isinstance(stage, str):
            self.started += [] if stage in self.started else [stage]
            scenario = meta.get("scenario")
            self.scenario = scenario if isinstance(scenario, int) and not isinstance(scenario, bool) else self.scenario
        elif kind == "result" and isinstance(stage, str):
            if stage in self.results:
                self.twice.add(stage)
            self.results[stage] = message
        elif kind != "done":
            return False
        return True


def _read(stream: Any, run: ChildRun) -> None:
    """Read the child's messages as they come into `run` (in a daemon thread: a pipe kept open by an
    escaped grandchild cannot hold the grader), until the end of the pipe or the first unreadable
    message (`run.unreadable` says what was wrong)."""
    try:
        for message in messages(stream):
            if not run.take(message):
                raise WireError("an unexpected message")
    except (WireError, OSError, ValueError) as error:
        run.unreadable = f"sent output the grader cannot read ({error})"


class _Output(threading.Thread):
    """Collects what the child prints, keeping its first and last OUTPUT_KEPT characters."""

    def __init__(self, fd: int):
        super().__init__(daemon=True)
        self.fd, self.head, self.tail, self.total = fd, b"", b"", 0

    def run(self) -> None:
        with contextlib.suppress(OSError):
            while chunk := os.read(self.fd, 1 << 16):
                self.total += len(chunk)
                if len(self.head) < OUTPUT_KEPT:
                    taken = OUTPUT_KEPT - len(self.head)
                    self.head, chunk = self.head + chunk[:taken], chunk[taken:]
                self.tail = (self.tail + chunk)[-OUTPUT_KEPT:]

    def text(self) -> str:
        skipped = self.total - len(self.head) - len(self.tail)
        middle = f"\n[... {skipped} bytes not kept ...]\n".encode() if skipped > 0 else b""
        return (self.head + middle + self.tail).decode(errors="replace")


def run_child(
    request: tuple[dict, dict], run_folder: Path, seconds: float, made: Sandbox, reserve: float = 0.0
) -> ChildRun:
    """Start a child on `request` (meta, arrays) in its sandbox (the submission's copy in `run_folder`)
    with `seconds` of the budget left, less `reserve` for each stage after the one it is in (the time
    budget of docs/exercise.md); return what it gave, or SandboxError when it never ran the student's code."""
    if _stopped.is_set():  # an interrupt, which no handler of the grader's own errors takes
        raise KeyboardInterrupt("the grading was stopped")
    stages, cgroup = request[0]["stages"], Cgroup()
    cpu = max(1, math.floor(seconds - reserve * (len(stages) - 1)) - 1)
    meta = {**request[0], "processes": None if cgroup.folders or not made.sandboxed else PROCESS_LIMIT}
    run, started = ChildRun(), time.perf_counter()
    process, reader, printed = _start(made, run, run_folder, cgroup, cpu + STARTUP_CPU, encode(meta, request[1]))

    def limit() -> float:  # the wait allowed so far: the budget less the reserve of the stages after this one
        at = max([stages.index(s) for s in run.started if s in stages], default=0)
        return seconds - reserve * (len(stages) - 1 - at)

    def waiting() -> bool:  # within its time: the student's from hello on (a start is the grader's, up to STARTUP)
        now = time.perf_counter()
        return now - run.hello < limit() if run.hello else now - started < STARTUP

    try:
        while process.poll() is None and waiting():
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.wait(0.1)
        timed_out = process.poll() is None
    finally:
        _end_session(process)
        with contextlib.suppress(subprocess.TimeoutExpired):
            process.wait(5)
        cgroup.close()
        with _running_lock:
            _running.discard(process)
    if _stopped.is_set():
        raise KeyboardInterrupt("the grading was stopped")
    run.seconds = time.perf_counter() - (run.hello or started)
    reader.join(5)
    printed.join(2)
    run.output = printed.text()
    if not run.hello:
        last = (run.output.strip().splitlines() or ["no message"])[-1][:200]
        code = f"did not start within {STARTUP:g} s" if timed_out else f"exit code {process.returncode}"
        raise SandboxError(f"the sandbox did not start the student's process ({code}: {last})")
    run.ended = _how_it_ended(run, reader, process.returncode, made, limit() if timed_out else None, cpu)
    return run


def _start(made: Sandbox, run: ChildRun, run_folder: Path, cgroup: Cgroup, cpu: int, request: bytes) -> tuple:
    """The child's process (the request on its standard input, from a file of its own; its prints merged
    on one pipe, the answer pipe kept open, its limits, a session of its own), its answers' reader and
    its prints' collector, both started; SandboxError when it cannot be started (bwrap gone since the
    probe, no memory to fork)."""
    drop, staged = None, {}
    if made.sandboxed and not cgroup.folders:
        drop, staged = _dropped([source for source, _ in read_only_binds(kit(), run_folder)], run_folder / "stage")
    answers_in, answers_out = os.pipe()
    try:
        with _running_lock, tempfile.TemporaryFile() as sent:
            sent.write(request)
            sent.seek(0)
            process = subprocess.Popen(
                made.command(kit(), run_folder, answers_out, staged),
                stdin=sent,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                pass_fds=(answers_out,),
                preexec_fn=_preexec(cpu, cgroup, drop),
                start_new_session=True,
                env=CHILD_ENVIRONMENT,
                cwd=run_folder,
            )
            _running.add(process)
    except (OSError, subprocess.SubprocessError) as error:
        cgroup.close()
        os.close(answers_in)
        raise SandboxError(f"the student's process could not be started ({error})") from None
    finally:
        os.close(answers_out)
    reader = threading.Thread(target=_read, args=(os.fdopen(answers_in, "rb"), run), daemon=True)
    printed = _Output(process.stdout.fileno())
    reader.start()
    printed.start()
    return process, reader, printed


def _end_session(process: subprocess.Popen) -> None:
    """Kill the child's session (bwrap and so its whole sandbox; a plain child and what it started)."""
    for kill in (lambda: os.killpg(process.pid, signal.SIGKILL), process.kill):
        with contextlib.suppress(OSError):
            kill()


def _how_it_ended(
    run: ChildRun, reader: threading.Thread, code: int | None, made: Sandbox, waited: float | None, seconds: float
) -> str | None:
    """None when it said "done" and exited 0; else one phrase naming how it ended and where."""
    # the signal: a negative return code, or bwrap's 128 + the signal of its child
    number = -code if code is not None and code < 0 else None
    if made.sandboxed and code is not None and 128 < code < 128 + 65:
        number = code - 128
    where = run.where()
    if waited is not None:
        return f"ran past its time ({waited:.0f} s of the budget) {where} and was stopped"
    if number == getattr(signal, "SIGXCPU", 0):
        return f"ran past the time limit ({math.ceil(seconds)} s of processor time) {where} and was stopped"
    if run.unreadable:
        return f"{run.unreadable} {where}"
    if reader.is_alive():
        return f"kept its answer pipe open after it ended {where}"
    if run.done and code == 0:
        return None
    if number is not None:
        name = signal.Signals(number).name if number in signal.Signals._value2member_map_ else "unknown"
        return f"was killed by signal {number} ({name}) {where}"
    return f"exited with code {code} {where}, before answering"
