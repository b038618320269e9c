"""Output that survives failures: files whole or not at all, write errors as one line, the umask,
leftovers, RERUN=off, concurrent default-named recordings, and the web server ending with its run.

Failures are real: a file size limit (RLIMIT_FSIZE) in a child process, a full or read-only tmpfs
mounted in a user namespace (skipped where the machine does not allow one), real signals to real
processes.
"""

from __future__ import annotations

import os
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import ROOT

try:
    import resource
except ImportError:  # not on Windows
    resource = None
from rerun.chunk import RrdReader

from mazelab.atomic import WriteError, write_atomically
from mazelab.cli.app import main
from mazelab.experiments.tables import pyplot, save_figure

RUN = [sys.executable, str(ROOT / "main.py"), "run", "--maze", "paper_5x5", "--steps", "4", "--particles", "100"]
NO_DISPLAY = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "RERUN")}


def recorded_steps(path: Path) -> list[int]:
    """The steps at which the robot is drawn in an .rrd file (read back with Rerun's reader)."""
    reader = RrdReader(path)
    (store,) = reader.recordings()
    steps = set()
    for chunk in reader.stream(store=store):
        if chunk.entity_path == "/map/robot" and not chunk.is_static:
            steps.update(chunk.to_record_batch().column("step").to_pylist())
    return sorted(steps)


def leftovers(folder: Path) -> list[str]:
    """Hidden files (temporaries) in `folder`."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


# -- the write layer -------------------------------------------------------------------------------
@pytest.mark.skipif(os.name == "nt", reason="POSIX file modes")
def test_new_files_follow_the_umask_and_replaced_files_keep_their_mode(tmp_path, umask_022):
    scenario, csv, png, rrd = (tmp_path / name for name in ("s.json", "e.csv", "f.png", "r.rrd"))
    assert main([*RUN[2:], "--quiet", "--seed", "1", "--save-scenario", str(scenario), "--rrd", str(rrd)]) == 0
    write_atomically(csv, "step,error\n")
    plt = pyplot()
    save_figure(plt.figure(), png)
    for path in (scenario, csv, png, rrd):
        assert stat.S_IMODE(path.stat().st_mode) == 0o644, path.name
    os.chmod(scenario, 0o640)
    assert main([*RUN[2:], "--quiet", "--save-scenario", str(scenario), "--force", "--no-viz"]) == 0
    assert stat.S_IMODE(scenario.stat().st_mode) == 0o640
    assert recorded_steps(rrd) == [1, 2, 3, 4] and leftovers(tmp_path) == []


def test_force_onto_a_symlink_writes_through_to_its_target(tmp_path):
    (tmp_path / "real").mkdir()
    target = tmp_path / "real" / "s.json"
    target.write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to(target)
    assert main([*RUN[2:], "--quiet", "--no-viz", "--save-scenario", str(link), "--force"]) == 0
    assert link.is_symlink() and '"init_robot_pos"' in target.read_text()
    assert leftovers(tmp_path) == [] and leftovers(tmp_path / "real") == []


SLOW_WRITER = """
import os, sys, time
from mazelab import atomic
atomic.write_all = lambda handle, data: (os.write(handle, data[:1000]), print("writing", flush=True), time.sleep(60))
atomic.write_atomically(sys.argv[1], b"x" * 100_000)
"""


def test_a_save_killed_midway_leaves_a_temporary_that_the_next_write_removes(tmp_path):
    """kill -9 during a save: the old file is intact, and the next write to the folder removes the
    temporary (its writer is gone; here not even reaped yet, a zombie)."""
    target = tmp_path / "s.json"
    target.write_text("old and whole")
    writer = subprocess.Popen([sys.executable, "-c", SLOW_WRITER, str(target)], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})  # fmt: skip
    try:
        _wait_for_line(writer, "writing")
        (stale,) = [p for p in tmp_path.iterdir() if p.name.startswith(".s.json.")]
        os.kill(writer.pid, signal.SIGKILL)
        deadline = time.monotonic() + 10
        while _running(writer.pid) and time.monotonic() < deadline:
            time.sleep(0.01)
        alive = tmp_path / f".s.json.{os.getpid()}-0123abcd.tmp"  # a writer still at work: kept
        foreign = tmp_path / ".notes.tmp"  # not ours: kept
        for path in (alive, foreign):
            path.write_bytes(b"x")
        write_atomically(tmp_path / "other.json", "{}")
        assert not stale.exists() and alive.exists() and foreign.exists()
        assert target.read_text() == "old and whole"
    finally:
        writer.kill()
        writer.wait()


def test_a_name_near_the_limit_gets_a_temporary_name_that_fits(tmp_path):
    for length in (242, 250, 255):
        path = tmp_path / ("n" * (length - 5) + ".json")
        write_atomically(path, "{}")
        assert path.read_text() == "{}"
    assert leftovers(tmp_path) == []
    with pytest.raises(WriteError, match=r"^cannot write .*n\.json: File name too long$"):
        write_atomically(tmp_path / ("n" * 300 + ".json"), "{}")


def test_a_claimed_name_is_never_replaced(tmp_path):
    path = tmp_path / "r.rrd"
    write_atomically(path, b"first", replace=False)
    with pytest.raises(FileExistsError):
        write_atomically(path, b"second", replace=False)
    assert path.read_bytes() == b"first" and leftovers(tmp_path) == []


# -- write errors: one line, exit 1, results first -------------------------------------------------
def _file_size_limit(limit: int):
    return lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))


@pytest.mark.skipif(not hasattr(resource, "RLIMIT_FSIZE"), reason="no file size limit (RLIMIT_FSIZE) here")
def test_a_recording_over_the_file_size_limit_is_not_announced_and_leaves_nothing(tmp_path):
    """`ulimit -f`: the write fails with EFBIG; the summary is printed, then one line, exit 1."""
    done = subprocess.run([*RUN, "--quiet", "--seed", "2", "--rrd", "r.rrd"], cwd=tmp_path, env=NO_DISPLAY,
                          capture_output=True, text=True, timeout=120, preexec_fn=_file_size_limit(20_000))  # fmt: skip
    assert done.returncode == 1
    assert "last-20% error" in done.stdout and "Recording saved" not in done.stdout
    assert done.stderr.strip() == "error: cannot write r.rrd: File too large"
    assert list(tmp_path.iterdir()) == []


UNSHARE = shutil.which("unshare")


def _in_a_small_tmpfs(tmp_path: Path, options: str, code: str) -> subprocess.CompletedProcess:
    """Run python `code` with a tmpfs (mount `options`) at tmp_path/mnt, in a user and mount namespace."""
    mount = tmp_path / "mnt"
    mount.mkdir()
    script = f'mount -t tmpfs -o {options} none {mount} && cd {mount} && exec {sys.executable} -c "$0"'
    command = [UNSHARE, "--user", "--map-root-user", "--mount", "sh", "-c", script, code]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(command, capture_output=True, text=True, timeout=60, env=env)


FULL_DISK = """
from pathlib import Path
from mazelab.atomic import write_atomically, WriteError
Path("old.json").write_bytes(b"old and whole")
for name in ("old.json", "new.rrd"):
    try:
        write_atomically(name, b"x" * 200_000)
    except WriteError as error:
        print(error)
print(sorted(p.name for p in Path(".").iterdir()), Path("old.json").read_bytes().decode())
"""


@pytest.mark.skipif(UNSHARE is None or sys.platform != "linux", reason="needs unshare (util-linux) on Linux")
def test_a_full_disk_and_a_read_only_folder_are_one_line_and_leave_the_old_file(tmp_path):
    done = _in_a_small_tmpfs(tmp_path, "size=64k", FULL_DISK)
    if "mount" in done.stderr or "unshare" in done.stderr:
        pytest.skip(f"no tmpfs in a user namespace here: {done.stderr.strip()}")
    assert done.stdout.splitlines() == [
        "cannot write old.json: No space left on device",
        "cannot write new.rrd: No space left on device",
        "['old.json'] old and whole",
    ], done.stderr
    shutil.rmtree(tmp_path / "mnt")
    read_only = "from mazelab.cli.app import main; print(main(['run', '--quiet']), main(['run', '--rrd', 'r.rrd']))"
    done = _in_a_small_tmpfs(tmp_path, "ro", read_only)
    assert done.stdout.splitlines()[-1] == "1 2"  # nothing computed yet: refused before the run
    assert done.stderr.splitlines() == [
        "error: cannot write recordings: Read-only file system",
        "error: . is not writable: cannot write r.rrd there",
    ]


# -- RERUN=off and default names -------------------------------------------------------------------
def test_rerun_off_records_nothing_says_so_and_keeps_the_summary_and_scenario(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("RERUN", "off")
    monkeypatch.chdir(tmp_path)
    assert main([*RUN[2:], "--save-scenario", "s.json"]) == 0
    out = capsys.readouterr().out
    assert "Rerun is switched off (RERUN=off" in out and "last-20% error" in out and "scenario saved to s.json" in out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json"]  # no recordings/, no temporaries


def test_two_runs_started_together_give_two_whole_recordings(tmp_path):
    """Default names (recordings/<filter>-<date>-<time>.rrd) of runs started in the same second."""
    runs = [subprocess.Popen([*RUN, "--quiet", "--seed", str(seed)], cwd=tmp_path, env=NO_DISPLAY,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for seed in (1, 2)]  # fmt: skip
    outputs = [run.communicate(timeout=120) for run in runs]
    assert [run.returncode for run in runs] == [0, 0], outputs
    saved = [line.split(";")[0].removeprefix("Recording saved to ") for out, _ in outputs
             for line in out.splitlines() if line.startswith("Recording saved to")]  # fmt: skip
    assert len(set(saved)) == 2
    for path in saved:
        assert recorded_steps(tmp_path / path) == [1, 2, 3, 4]
    assert sorted(p.name for p in (tmp_path / "recordings").iterdir()) == sorted(Path(p).name for p in saved)


# -- the web viewer's server ends with its run -----------------------------------------------------
def _children(pid: int) -> list[int]:
    return [int(p) for p in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


def _wait_for_line(process: subprocess.Popen, text: str) -> None:
    for line in process.stdout:
        if text in line:
            return
    raise AssertionError(f"{text!r} never printed")


WEB_SERVER = """
from mazelab.viz.processes import WebServer
server = WebServer.start()
print("serving", flush=True)
server.serve_until_interrupted()
"""


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="reads child processes from /proc (Linux)")
@pytest.mark.parametrize("how", ["SIGTERM to a --web run", "SIGHUP to a web server"])
def test_sigterm_and_sighup_leave_no_child_process_running(tmp_path, how):
    if how.startswith("SIGTERM"):
        command, ready, sent = [*RUN, "--quiet", "--web"], "press Ctrl-C to stop serving", signal.SIGTERM
    else:
        command, ready, sent = [sys.executable, "-c", WEB_SERVER], "serving", signal.SIGHUP
    process = subprocess.Popen(command, cwd=tmp_path, env={**NO_DISPLAY, "PYTHONPATH": str(ROOT)},
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        _wait_for_line(process, ready)
        children = _children(process.pid)
        descendants = children + [g for c in children for g in _children(c)]
        assert children, "the server was not started"
        process.send_signal(sent)
        assert process.wait(timeout=30) == 128 + sent
        deadline = time.monotonic() + 10
        while any(map(_running, descendants)) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not any(map(_running, descendants))
    finally:
        if process.poll() is None:
            process.kill()
        process.communicate()


def test_the_signal_handlers_are_ours_only_while_a_child_runs():
    """Once the server has stopped, SIGTERM and SIGHUP do what they did before (a notebook kernel keeps its own)."""
    from mazelab.stops import STOP_SIGNALS
    from mazelab.viz import processes

    numbers = [number for number in STOP_SIGNALS if number != signal.SIGINT]
    before = {number: signal.getsignal(number) for number in numbers if signal.getsignal(number) != signal.SIG_IGN}
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    processes.hold_stop_signals(child)
    assert all(signal.getsignal(number) is not before[number] for number in before)
    processes.stop_process(child)
    assert child.poll() is not None
    assert {number: signal.getsignal(number) for number in before} == before


@pytest.mark.skipif(os.name == "nt", reason="POSIX signals")
def test_sigterm_during_a_recorded_run_saves_the_steps_done_as_ctrl_c_does(tmp_path):
    command = [*RUN[:-4], "--steps", "100000", "--particles", "100", "--rrd", "r.rrd"]
    process = subprocess.Popen(command, cwd=tmp_path, env=NO_DISPLAY, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        _wait_for_line(process, "step   40/")
        process.send_signal(signal.SIGTERM)
        out, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 128 + signal.SIGTERM, err
    assert "Recording saved to r.rrd" in out and "Traceback" not in err
    steps = recorded_steps(tmp_path / "r.rrd")
    assert steps == list(range(1, len(steps) + 1)) and len(steps) >= 40
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.rrd"]
