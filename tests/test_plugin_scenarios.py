"""Plug-ins are first-class and contained; scenarios never run code (mazelab.registry, mazelab.scenario).

- loading a scenario that names a file never imports it (compare, run --filter sir, load_scenario);
- a plug-in's saved run replays bit for bit with its options once the user names it, its file's hash
  checked; without --filter the replay says how, in one line;
- a plug-in imports a helper module beside it; the lab's own StudentFilter named as the class is refused;
- a plug-in that changes its maze changes no other filter's run;
- contract gaps and bad step values are one line naming the part and the step;
- a plug-in's sys.exit, KeyboardInterrupt, os.chdir or forgotten thread never becomes the program's exit;
- a plug-in that does not declare `batched` runs one run at a time in a study that batches the others.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from mazelab.cli.app import main
from mazelab.scenario import load_scenario

ROOT = Path(__file__).resolve().parent.parent
RUN = ["--maze", "paper_5x5", "--steps", "25", "--particles", "200", "--seed", "4", "--no-viz", "--quiet"]

ADAPTIVE = '''
"""SIR that resamples only when the ESS falls below ess_share * N (the contract's worked example)."""
from helper_beside import DEFAULT_SHARE
from mazelab.filters import ParticleFilter
from mazelab.declaration import Option, number_in


class AdaptiveSIR(ParticleFilter):
    """SIR that resamples only when the ESS falls below ess_share * N."""

    options = ParticleFilter.options.extend(
        Option("ess_share", DEFAULT_SHARE, "resample when ESS < ess_share * N", check=number_in("ess_share", 0, 1)),
    )

    def time_to_resample(self):
        return self.ess < self.settings["ess_share"] * self.count
'''


@pytest.fixture
def plugin(tmp_path) -> Path:
    """adaptive.py, with the helper module it imports beside it."""
    (tmp_path / "helper_beside.py").write_text("DEFAULT_SHARE = 0.5\n")
    path = tmp_path / "adaptive.py"
    path.write_text(ADAPTIVE)
    return path


def first_line(capsys) -> str:
    return capsys.readouterr().out.splitlines()[0]


def test_the_contracts_worked_example_runs_as_written(tmp_path, capsys):
    doc = (ROOT / "docs" / "architecture.md").read_text()
    example = doc[doc.index("### A new filter") :]
    code = example[example.index("```python\n") + len("```python\n") : example.index("```\n\nSaved as my_filter.py")]
    (tmp_path / "my_filter.py").write_text(code)
    assert main(["run", "--filter", f"{tmp_path}/my_filter.py:PeriodicSIR", "--option", "period=3", *RUN]) == 0
    assert first_line(capsys).startswith("PeriodicSIR: last-step error")


def test_a_plugins_saved_run_replays_bit_for_bit_with_its_options(tmp_path, capsys, plugin):
    saved = tmp_path / "s.json"
    spec = f"{plugin}:AdaptiveSIR"
    assert main(["run", "--filter", spec, "--option", "ess_share=0.3", *RUN, "--save-scenario", str(saved)]) == 0
    original = first_line(capsys)
    stored = load_scenario(saved)
    assert stored.filter_options["ess_share"] == 0.3 and stored.format_version == 4
    assert stored.filter_plugin.class_name == "AdaptiveSIR" and stored.filter_plugin.spec == spec
    assert main(["run", "--scenario", str(saved), "--filter", spec, "--no-viz", "--quiet"]) == 0
    replay = capsys.readouterr()
    assert replay.out.splitlines()[0] == original and replay.err == ""
    assert main(["run", "--scenario", str(saved), "--no-viz", "--quiet"]) == 2  # never imported by itself
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"--filter {spec}" in err and "a scenario never runs code" in err
    assert main(["run", "--scenario", str(saved), "--filter", "sir", "--no-viz", "--quiet"]) == 0  # another filter
    assert "filter AdaptiveSIR -> SIRParticleFilter" in capsys.readouterr().err
    assert main(["compare", str(saved), "--filters", f"sir,{spec}", "--no-viz"]) == 0
    assert "ess_share 0.3" in capsys.readouterr().err  # compare's plug-in takes its stored option, said
    plugin.write_text(ADAPTIVE + "\n# edited\n")  # the file changed since: said in one line, and run
    assert main(["run", "--scenario", str(saved), "--filter", spec, "--no-viz", "--quiet"]) == 0
    changed = capsys.readouterr()
    assert changed.err.count("\n") == 1 and "has changed since the scenario was saved" in changed.err


def _marker_plugin(tmp_path: Path) -> tuple[Path, Path]:
    marker = tmp_path / "IMPORTED"
    evil = tmp_path / "evil.py"
    evil.write_text(
        f"open({str(marker)!r}, 'w').write('ran')\n"
        "from mazelab.filters import SIRParticleFilter\n\nclass Evil(SIRParticleFilter):\n    pass\n"
    )
    return evil, marker


@pytest.mark.parametrize("how", ["as the filtering_algorithm", "as a plug-in reference"])
def test_loading_a_scenario_that_names_a_file_never_imports_it(tmp_path, capsys, how):
    evil, marker = _marker_plugin(tmp_path)
    saved = tmp_path / "s.json"
    assert main(["run", *RUN, "--save-scenario", str(saved)]) == 0
    data = json.loads(saved.read_text())
    if how == "as the filtering_algorithm":
        data["filtering_algorithm"] = f"{evil}:Evil"
    else:
        data |= {"filtering_algorithm": "Evil", "format_version": 4,
                 "filter_plugin": {"spec": f"{evil}:Evil", "sha256": "0" * 64, "class": "Evil"}}  # fmt: skip
    saved.write_text(json.dumps(data))
    load_scenario(saved)
    assert main(["compare", str(saved), "--filters", "sir", "--no-viz"]) == 0
    assert main(["run", "--scenario", str(saved), "--filter", "sir", "--no-viz", "--quiet"]) == 0
    assert main(["run", "--scenario", str(saved), "--no-viz", "--quiet"]) == 2
    assert not marker.exists()


def test_the_labs_own_student_filter_is_not_a_plugin(tmp_path, capsys):
    path = tmp_path / "mine.py"
    path.write_text("from mazelab.exercise import StudentFilter\n\nclass Mine(StudentFilter):\n    pass\n")
    assert main(["run", "--filter", f"{path}:StudentFilter", *RUN]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "StudentFilter is the lab's own class" in err and "it defines: Mine" in err


def test_a_plugin_that_changes_its_maze_changes_no_other_filters_run(tmp_path, capsys):
    saved = tmp_path / "s.json"
    assert main(["run", *RUN, "--save-scenario", str(saved)]) == 0
    vandal = tmp_path / "vandal.py"
    vandal.write_text(
        textwrap.dedent(
            """
            import numpy as np
            from mazelab.filters import SIRParticleFilter

            class Vandal(SIRParticleFilter):
                def step(self, compass_angle, z):
                    try:
                        self.world.grid[:] = 1  # refused: the maze is read-only
                    except ValueError:
                        pass
                    lookup = self.world._lookup  # forced past the read-only maze: its own copy only
                    self.world.__dict__["stations"] = self.world.stations + 0.5
                    lookup.__dict__["stations"] = lookup.stations + 0.5
                    lookup.__dict__["_tables"] = {}
                    super().step(compass_angle, z)
            """
        )
    )
    table_alone, table_with = tmp_path / "alone.csv", tmp_path / "with.csv"
    assert main(["compare", str(saved), "--filters", "sir,apf", "--no-viz", "--csv", str(table_alone)]) == 0
    assert main(["compare", str(saved), "--filters", f"{vandal}:Vandal,sir,apf", "--no-viz",
                 "--csv", str(table_with)]) == 0  # fmt: skip
    alone, with_vandal = (list(csv.DictReader(t.open())) for t in (table_alone, table_with))
    for name in ("SIRParticleFilter", "AuxiliaryParticleFilter"):
        assert [r[name] for r in alone] == [r[name] for r in with_vandal]


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("def __init__(self, *a, **k):\n        self.count = 3", "it has no attribute 'reinitialised_at'"),
        ("def __init__(self, *a, **k):\n        self.count, self.reinitialised_at = 3, 7",
         "reinitialised_at must be a list of step numbers"),
        ("def __init__(self, *a, **k):\n        self.count, self.reinitialised_at = 0, []",
         "count must be a whole number >= 1"),
        ("estimate = property(lambda self: np.array([np.nan, 1.0]))", "at step 1: Gap.estimate must be finite"),
        ("estimate = property(lambda self: np.zeros(3))", "at step 1: Gap.estimate must have shape (2,)"),
        ("ess = property(lambda self: 'many')", "at step 1: Gap.ess must be a number"),
    ],
)  # fmt: skip
def test_a_contract_gap_or_a_bad_value_is_one_line_naming_the_part_and_the_step(tmp_path, capsys, body, message):
    path = tmp_path / "gap.py"
    base = textwrap.dedent(
        """
        import numpy as np

        class Gap:
            name, options = "Gap", {}

            def __init__(self, world, sigma, delta, particles, rng=None):
                self.count, self.reinitialised_at = len(particles), []

            def step(self, compass_angle, z):
                pass

            estimate = property(lambda self: np.zeros(2))
            ess = property(lambda self: 1.0)
            is_confident = property(lambda self: False)

            def belief(self):
                return None

        class Gap(Gap):
            BODY
        """
    )
    path.write_text(base.replace("BODY", body))
    assert main(["run", "--filter", f"{path}:Gap", *RUN]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: Gap ") and err.count("\n") == 1 and message in err, err


PROGRAM = [sys.executable, str(ROOT / "main.py")]


def _run(tmp_path: Path, source: str, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    (tmp_path / "p.py").write_text(textwrap.dedent(source))
    env = {**os.environ, "RERUN": "off"}
    return subprocess.run([*PROGRAM, *args], cwd=tmp_path, capture_output=True, text=True, timeout=timeout, env=env)


EXITS_AT_IMPORT = "import sys\nsys.exit(0)\n"
STEP_SOURCE = """
import os, sys, threading, time
from mazelab.filters import SIRParticleFilter

class P(SIRParticleFilter):
    def step(self, compass_angle, z):
        super().step(compass_angle, z)
        if self.steps_done == 3:
            ACTION
"""


@pytest.mark.parametrize(
    ("source", "args", "code", "message"),
    [
        (EXITS_AT_IMPORT, ["run", "--filter", "p.py:P", *RUN], 2, "it called sys.exit(0) while being imported"),
        ("raise KeyboardInterrupt\n", ["run", "--filter", "p.py:P", *RUN], 2, "raised KeyboardInterrupt while"),
        (EXITS_AT_IMPORT, ["study", "--filters", "p.py:P", "--runs", "1", "--steps", "5", "--csv", "s.csv"], 2,
         "it called sys.exit(0) while being imported"),
        (STEP_SOURCE.replace("ACTION", "sys.exit(0)"), ["run", "--filter", "p.py:P", *RUN], 1,
         "P called sys.exit(0) at step 3 (a filter must not end the program)"),
        (STEP_SOURCE.replace("ACTION", "sys.exit(4)"), ["run", "--filter", "p.py:P", *RUN], 1, "sys.exit(4) at step 3"),
        (STEP_SOURCE.replace("ACTION", "raise KeyboardInterrupt"), ["run", "--filter", "p.py:P", *RUN], 1,
         "P raised KeyboardInterrupt at step 3"),
    ],
)  # fmt: skip
def test_a_plugins_own_exit_is_its_error_never_the_programs_exit(tmp_path, source, args, code, message):
    done = _run(tmp_path, source, *args)
    assert done.returncode == code and message in done.stderr, done.stderr
    assert not (tmp_path / "s.csv").exists()


def test_a_plugin_that_changes_the_working_folder_leaves_the_outputs_where_asked(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    source = STEP_SOURCE.replace("ACTION", f"os.chdir({str(elsewhere)!r})")
    done = _run(tmp_path, source, "run", "--filter", "p.py:P", *RUN, "--save-scenario", "s.json")
    assert done.returncode == 0 and (tmp_path / "s.json").is_file() and not (elsewhere / "s.json").exists()
    assert "changed the working folder" in done.stderr and "scenario saved to s.json" in done.stdout


def test_a_plugins_forgotten_thread_does_not_keep_the_program_alive(tmp_path):
    source = STEP_SOURCE.replace("ACTION", "threading.Thread(target=time.sleep, args=(3600,)).start()")
    done = _run(tmp_path, source, "run", "--filter", "p.py:P", *RUN, timeout=60)
    assert done.returncode == 0 and "P: last-step error" in done.stdout
    assert "thread(s) that the lab did not start are still running" in done.stderr


def test_a_plugin_that_does_not_declare_batched_runs_one_run_at_a_time(tmp_path, capsys, plugin):
    """AdaptiveSIR's step is a single run's: in a study whose SIR runs are batched it must still run
    run by run (every row there, none failed), and its rows equal those of a study of it alone."""
    spec = f"{plugin}:AdaptiveSIR"
    tables = tmp_path / "both.csv", tmp_path / "alone.csv"
    common = ["--maze", "paper_5x5", "--runs", "4", "--steps", "20", "--particles", "100", "--seed", "3", "--no-viz"]
    assert main(["study", "--filters", f"sir,{spec}", *common, "--workers", "1", "--csv", str(tables[0])]) == 0
    assert main(["study", "--filters", spec, *common, "--workers", "1", "--csv", str(tables[1])]) == 0
    both, alone = (list(csv.DictReader(t.open())) for t in tables)
    mine = [r["mean_error"] for r in both if r["filter"] == "AdaptiveSIR"]
    assert len(mine) == 4 and mine == [r["mean_error"] for r in alone]
    assert "failed" not in capsys.readouterr().err


INHERITING = '''
from mazelab.filters import SIRParticleFilter


class Inheriting(SIRParticleFilter):
    """SIR under another name: its options are SIR's, stored with its saved runs (threshold 1 among them)."""

    name = "Inheriting"
    options = {**SIRParticleFilter.options, "inflation": 1.0}
'''


def test_compare_of_a_plugins_scenario_gives_the_rpf_its_own_threshold(tmp_path, capsys):
    """A scenario saved by a plug-in stores its options (SIR's threshold 1 among them); they are the
    plug-in's, whose defaults are not known unless it is loaded: the RPF of a comparison keeps its own
    threshold (0.2) and scores as on the same walk saved by SIR, whether the plug-in is compared too or not."""
    (tmp_path / "inheriting.py").write_text(INHERITING)
    spec = f"{tmp_path / 'inheriting.py'}:Inheriting"
    saved, by_sir = tmp_path / "p.json", tmp_path / "s.json"
    assert main(["run", "--filter", spec, *RUN, "--save-scenario", str(saved)]) == 0
    assert main(["run", "--filter", "sir", *RUN, "--save-scenario", str(by_sir)]) == 0
    assert json.loads(saved.read_text())["filter_options"]["threshold"] == 1.0

    def rpf_errors(scenario: Path, *filters: str) -> list[str]:
        table = tmp_path / f"{scenario.stem}{len(filters)}.csv"
        assert main(["compare", str(scenario), "--filters", ",".join(filters), "--csv", str(table), "--no-viz"]) == 0
        rows = list(csv.DictReader(table.open()))
        return [row["RegularizedParticleFilter"] for row in rows]

    expected = rpf_errors(by_sir, "sir", "rpf")
    assert rpf_errors(saved, "sir", "rpf") == expected
    assert rpf_errors(saved, "sir", spec, "rpf") == expected
    assert "threshold" not in capsys.readouterr().err  # no stored threshold handed to another filter
