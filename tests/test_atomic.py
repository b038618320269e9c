"""mazelab.atomic's temporaries on a folder shared between hosts (NFS): each names its host, and a
write removes only the temporaries of this host's dead writers; a symlink loop at an output name is
refused as not a regular file. Real processes (one under another host name, in its own UTS
namespace where the machine allows one) and real links."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT

from mazelab.atomic import (
    TEMPORARY_PATTERN,
    NotRegularFileError,
    host_tag,
    output_target,
    remove_stale_temporaries,
    temporary_name,
    write_atomically,
)

UNSHARE = shutil.which("unshare")
SLOW_WRITER = """
import os, sys, time
from mazelab import atomic
atomic.write_all = lambda handle, data: (os.write(handle, data[:10]), print("writing", flush=True), time.sleep(60))
atomic.write_atomically(sys.argv[1], b"x" * 1000)
"""


def dead_pid() -> int:
    """The pid of a process that has ended and been reaped."""
    done = subprocess.Popen([sys.executable, "-c", "pass"])
    done.wait()
    return done.pid


def test_a_temporary_names_this_host():
    name = temporary_name(Path("/somewhere/s.csv"))
    match = TEMPORARY_PATTERN.match(name)
    assert match and match.group(1) == host_tag() and int(match.group(2)) == os.getpid()
    assert name.startswith(".s.csv.") and host_tag(socket.gethostname()) == host_tag()


def test_host_tags_keep_to_name_characters_and_tell_hosts_apart():
    assert host_tag("lab-pc-7") == "lab-pc-7"
    tags = {host_tag(h) for h in ("node1.cluster.example", "node1_cluster_example", "node1-cluster", "x" * 300)}
    assert len(tags) == 4
    assert all(len(t) <= 40 and TEMPORARY_PATTERN.match(f".s.csv.{t}.12-0123abcd.tmp") for t in tags)


def test_only_this_hosts_dead_writers_temporaries_are_removed(tmp_path):
    pid = dead_pid()
    mine = tmp_path / f".s.csv.{host_tag()}.{pid}-0123abcd.tmp"
    other_host = tmp_path / f".s.csv.{host_tag('other-host')}.{pid}-0123abcd.tmp"  # its writer may be alive there
    old_format = tmp_path / f".s.csv.{pid}-0123abcd.tmp"  # no host: cannot tell whose, kept
    alive_here = tmp_path / f".s.csv.{host_tag()}.{os.getpid()}-0123abcd.tmp"
    for path in (mine, other_host, old_format, alive_here):
        path.write_text("x")
    assert remove_stale_temporaries(tmp_path) == [mine]
    write_atomically(tmp_path / "t.csv", "new\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [other_host.name, old_format.name, alive_here.name, "t.csv"]
    )


@pytest.mark.skipif(UNSHARE is None or sys.platform != "linux", reason="needs unshare (util-linux) on Linux")
def test_a_killed_writer_of_another_host_keeps_its_temporary(tmp_path):
    """A writer under another host name (its own UTS namespace) is killed mid-write: its pid is not
    alive here, but it named its host, so the next write here leaves its temporary alone."""
    target = tmp_path / "s.json"
    script = f'hostname other-host && exec {sys.executable} -c "$0" {target}'
    writer = subprocess.Popen([UNSHARE, "--user", "--map-root-user", "--uts", "sh", "-c", script, SLOW_WRITER],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})  # fmt: skip
    try:
        line = writer.stdout.readline()
        if line != "writing\n":
            pytest.skip(f"no UTS namespace here: {writer.stderr.read().strip()}")
        (temporary,) = [p for p in tmp_path.iterdir() if p.name.startswith(".s.json.")]
        assert TEMPORARY_PATTERN.match(temporary.name).group(1) == "other-host"
        os.kill(writer.pid, signal.SIGKILL)  # exec'd: the writer itself
        writer.wait(timeout=10)
        write_atomically(tmp_path / "other.json", "{}")
        assert temporary.exists() and not target.exists()
    finally:
        writer.kill()
        writer.wait()


def test_a_symlink_loop_is_not_a_regular_file(tmp_path):
    loop = tmp_path / "loop.csv"
    loop.symlink_to(loop)
    for replace in (False, True):
        with pytest.raises(NotRegularFileError, match="it is a symlink loop, not a regular file"):
            output_target(loop, replace)
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    a.symlink_to(b)
    b.symlink_to(a)
    with pytest.raises(NotRegularFileError, match="loop"):
        write_atomically(a, "x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "b.csv", "loop.csv"]


def test_a_symlink_loop_as_a_commands_output_is_refused_before_the_run(tmp_path):
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    for option in ("--csv", "--plot", "--traces", "--record"):
        path = f"{loop}.png" if option == "--plot" else f"{loop}.csv" if option == "--traces" else str(loop)
        if path != str(loop):
            Path(path).symlink_to(path)
        done = subprocess.run([sys.executable, str(ROOT / "main.py"), "study", "--maze", "paper_5x5", "--runs", "2",
                               "--steps", "3", "--filters", "sir", option, path], capture_output=True, text=True,
                              timeout=120)  # fmt: skip
        assert done.returncode == 2, (option, done.stderr)
        (line,) = done.stderr.splitlines()
        assert "symlink loop" in line and "Study:" not in done.stdout, (option, done.stdout)
