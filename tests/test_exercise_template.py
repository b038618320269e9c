"""`exercise new DIR` writes through the program's one output mechanism (mazelab.atomic): a symlink,
pipe, device or symlink loop at my_filter.py or README.md is refused up front in one line (exit 2),
and a write that fails (a file size limit, a full disk) leaves the student's my_filter.py whole.
Real processes (`python main.py exercise new`), real links, pipes and file size limits."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT, needs_unwritable_folders

from mazelab.exercise.template import FILTER_TEMPLATE, README_TEMPLATE

try:
    import resource
except ImportError:  # not on Windows
    resource = None

NEW = [sys.executable, str(ROOT / "main.py"), "exercise", "new"]
STUDENTS_WORK = "# my own filter, hours of work\n" + "x = 1\n" * 800  # larger than the template


def exercise_new(folder: Path, *flags: str, preexec_fn=None) -> subprocess.CompletedProcess:
    return subprocess.run([*NEW, str(folder), *flags], capture_output=True, text=True, timeout=60,
                          preexec_fn=preexec_fn)  # fmt: skip


def one_error_line(done: subprocess.CompletedProcess) -> str:
    (line,) = done.stderr.splitlines()
    assert line.startswith("error: ") and "Traceback" not in done.stderr
    return line


def test_a_fresh_folder_gets_both_files_whole(tmp_path):
    done = exercise_new(tmp_path / "ex")
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "ex" / "my_filter.py").read_text() == FILTER_TEMPLATE
    assert (tmp_path / "ex" / "README.md").read_text() == README_TEMPLATE
    assert sorted(p.name for p in (tmp_path / "ex").iterdir()) == ["README.md", "my_filter.py"]  # no temporaries


def test_a_dangling_symlink_is_not_written_through_without_force(tmp_path):
    (tmp_path / "my_filter.py").symlink_to(tmp_path / "elsewhere.py")
    done = exercise_new(tmp_path)
    assert done.returncode == 2
    assert "my_filter.py: it is a symlink to a missing file; use --force" in one_error_line(done)
    assert not (tmp_path / "elsewhere.py").exists() and not (tmp_path / "README.md").exists()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
def test_a_pipe_at_either_name_is_refused_with_force_and_nothing_is_written(tmp_path):
    for name in ("my_filter.py", "README.md"):
        folder = tmp_path / name.split(".")[0]
        folder.mkdir()
        os.mkfifo(folder / name)
        done = exercise_new(folder, "--force")  # would hang on the pipe if it opened it
        assert done.returncode == 2
        assert f"{name}: it is a pipe, not a regular file" in one_error_line(done)
        assert [p.name for p in folder.iterdir()] == [name]  # neither file written


def test_a_link_to_a_device_and_a_symlink_loop_are_refused(tmp_path):
    (tmp_path / "README.md").symlink_to("/dev/null")
    done = exercise_new(tmp_path, "--force")
    assert done.returncode == 2 and "README.md: it is a device" in one_error_line(done)
    (tmp_path / "README.md").unlink()
    (tmp_path / "my_filter.py").symlink_to(tmp_path / "my_filter.py")
    done = exercise_new(tmp_path, "--force")
    assert done.returncode == 2 and "my_filter.py: it is a symlink loop" in one_error_line(done)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["my_filter.py"]


def test_an_existing_file_is_replaced_only_with_force(tmp_path):
    (tmp_path / "my_filter.py").write_text(STUDENTS_WORK)
    done = exercise_new(tmp_path)
    assert done.returncode == 2 and "my_filter.py: it exists; use --force" in one_error_line(done)
    assert (tmp_path / "my_filter.py").read_text() == STUDENTS_WORK and not (tmp_path / "README.md").exists()
    assert exercise_new(tmp_path, "--force").returncode == 0
    assert (tmp_path / "my_filter.py").read_text() == FILTER_TEMPLATE


@pytest.mark.skipif(resource is None or not hasattr(resource, "RLIMIT_FSIZE"), reason="no file size limit here")
def test_a_file_size_limit_leaves_the_students_filter_whole(tmp_path):
    """`ulimit -f` between the README's size and the filter's: the README is written, the filter's
    write fails with one line and exit 1, and the student's my_filter.py is left as it was."""
    limit = (len(README_TEMPLATE.encode()) + len(FILTER_TEMPLATE.encode())) // 2  # README fits, filter not
    assert len(README_TEMPLATE.encode()) < limit < len(FILTER_TEMPLATE.encode())
    (tmp_path / "my_filter.py").write_text(STUDENTS_WORK)

    def limited() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))

    done = exercise_new(tmp_path, "--force", preexec_fn=limited)
    assert done.returncode == 1
    assert one_error_line(done) == f"error: cannot write {tmp_path / 'my_filter.py'}: File too large"
    assert (tmp_path / "my_filter.py").read_text() == STUDENTS_WORK
    assert sorted(p.name for p in tmp_path.iterdir()) == ["README.md", "my_filter.py"]  # no temporary left


UNSHARE = shutil.which("unshare")
FULL_DISK = f"""
import os, sys
from pathlib import Path
Path("my_filter.py").write_text({STUDENTS_WORK!r})
Path("fill").write_bytes(b"x" * (4096 * 64))
while True:  # fill the disk to its last byte
    try:
        with open("fill", "ab") as f:
            f.write(b"x" * 512)
    except OSError:
        break
sys.argv = ["main.py", "exercise", "new", ".", "--force"]
from mazelab.cli.app import main
code = main(sys.argv[1:])
print(code, Path("my_filter.py").read_text() == {STUDENTS_WORK!r}, sorted(os.listdir(".")))
"""


@pytest.mark.skipif(UNSHARE is None or sys.platform != "linux", reason="needs unshare (util-linux) on Linux")
def test_a_full_disk_leaves_the_students_filter_whole(tmp_path):
    mount = tmp_path / "mnt"
    mount.mkdir()
    script = f'mount -t tmpfs -o size=512k none {mount} && cd {mount} && exec {sys.executable} -c "$0"'
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    command = [UNSHARE, "--user", "--map-root-user", "--mount", "sh", "-c", script, FULL_DISK]
    done = subprocess.run(command, capture_output=True, text=True, timeout=60, env=env)
    if "mount" in done.stderr or "unshare" in done.stderr:
        pytest.skip(f"no tmpfs in a user namespace here: {done.stderr.strip()}")
    assert done.stdout.splitlines()[-1] == "1 True ['fill', 'my_filter.py']", done.stdout + done.stderr
    (line,) = done.stderr.splitlines()
    assert line.startswith("error: cannot write ") and line.endswith(": No space left on device")


@needs_unwritable_folders
def test_a_read_only_folder_is_refused_up_front(tmp_path):
    folder = tmp_path / "ex"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        done = exercise_new(folder)
    finally:
        folder.chmod(0o755)
    assert done.returncode == 2 and "is not writable" in one_error_line(done)
