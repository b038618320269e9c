"""The paper's study on one worker, this checkout (each backend) against another one, in alternating
rounds: wall and CPU time of the whole command (start-up, the robot walks and the reads included),
and whether the rows agree.

    git worktree add --detach /tmp/old 1bcfd88 && (cd /tmp/old && uv sync)
    uv run python benchmarks/study_speedup.py /tmp/old --rounds 2

Each command runs in its checkout's own environment (`uv run --no-sync` there). The CSV's rows are
compared without the timing columns; the numpy backend writes the rows the other checkout writes
when their filters' arithmetic is the same, the compiled one agrees with them statistically (the
summary table), not row for row.
"""

from __future__ import annotations

import argparse
import csv
import os
import resource
import subprocess
import tempfile
import time
from pathlib import Path

STUDY = ["study", "--maze", "paper_5x5", "--sigma", "0.2,0.4,0.6,0.8", "--runs", "30", "--seed", "2024"]
STUDY += ["--workers", "1", "--no-viz"]
TIMING = {"ms_per_step", "run_seconds"}
# not a result: 1bcfd88 wrote the study's threshold (0.2) on every row; since the threshold became an option
# of every particle filter, the SIR and APF rows carry their own (1: they resample every step, as before)
SETTING_ONLY = {"threshold"}


def run_study(checkout: Path, backend: str | None) -> tuple[float, float, int, list[dict[str, str]]]:
    """(wall seconds, CPU seconds of the process and its children, their page faults, the CSV's rows
    without timing)."""
    folder = Path(tempfile.mkdtemp())
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # as a user runs it: imports read their cached bytecode
    if backend is not None:
        env["MAZELAB_BACKEND"] = backend
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    subprocess.run(
        ["uv", "run", "--no-sync", "python", "main.py", *STUDY, "--csv", str(folder / "s.csv")],
        cwd=checkout, env=env, check=True, capture_output=True,
    )  # fmt: skip
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    with open(folder / "s.csv", encoding="utf-8") as rows:
        kept = [{k: v for k, v in row.items() if k not in TIMING} for row in csv.DictReader(rows)]
    return wall, cpu, after.ru_minflt - before.ru_minflt, kept


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("other", type=Path, help="the other checkout (its own uv environment)")
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    here = Path(__file__).resolve().parents[1]
    subjects = [("other", args.other, None), ("numpy", here, "numpy"), ("compiled", here, "compiled")]
    for _, checkout, backend in subjects:  # warm-up: bytecode written, kernels cached
        run_study(checkout, backend)
    print(f"load average before: {os.getloadavg()}")
    times: dict[str, list[tuple[float, float]]] = {label: [] for label, _, _ in subjects}
    rows: dict[str, list[dict[str, str]]] = {}
    for r in range(args.rounds):
        order = subjects if r % 2 == 0 else subjects[::-1]
        for label, checkout, backend in order:
            wall, cpu, faults, rows[label] = run_study(checkout, backend)
            times[label].append((wall, cpu))
            figures = f"wall {wall:6.1f} s  CPU {cpu:6.1f} s  page faults {faults:7,}"
            print(f"round {r + 1} {label:<9} {figures}  load {os.getloadavg()[0]:.1f}")
    for label in ("numpy", "compiled"):
        cpu_other = sum(c for _, c in times["other"])
        cpu_here = sum(c for _, c in times[label])
        wall_other = sum(w for w, _ in times["other"])
        wall_here = sum(w for w, _ in times[label])
        common = [k for k in rows["other"][0] if k in rows[label][0] and k not in SETTING_ONLY]  # newer: more
        pairs = list(zip(rows["other"], rows[label], strict=True))
        same = sum(all(a[k] == b[k] for k in common) for a, b in pairs)
        differing = sorted({k for a, b in pairs for k in common if a[k] != b[k]})
        converged = sum(row["converged_at"] not in ("", "None") for row in rows[label])
        print(
            f"{label}: {cpu_other / cpu_here:.2f}x the other checkout's speed in CPU time, "
            f"{wall_other / wall_here:.2f}x in wall time; {same} of {len(rows[label])} rows equal on the "
            f"{len(common)} result columns both write (differing: {', '.join(differing) or 'none'}); "
            f"{converged} runs converged"
        )
    print(f"other: {sum(row['converged_at'] not in ('', 'None') for row in rows['other'])} runs converged")


if __name__ == "__main__":
    main()
