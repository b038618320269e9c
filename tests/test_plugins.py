"""A student's filter as a plug-in (`file.py:Class`) on run, compare, study and accuracy; bad plug-ins
refused in one line (exit 2); a plug-in that raises shows the student's frames and the step (exit 1)."""

from __future__ import annotations

import csv
import textwrap

import pytest
from conftest import ROOT

from mazelab.cli.app import main
from mazelab.registry import filter_entry, load_plugin
from mazelab.simulation import simulate
from mazelab.stops import StudentCodeError

ANSWERS = ROOT / "tests" / "exercise_answers.py"
REFERENCE = f"{ANSWERS}:ReferenceFilter"
QUICK = ["--steps", "20", "--particles", "200", "--seed", "3"]


def test_filter_entry_takes_a_file_and_class():
    cls = filter_entry(REFERENCE).filter_class
    assert cls.__name__ == "ReferenceFilter" and cls.name == "ReferenceFilter"
    assert filter_entry(REFERENCE).filter_class is cls  # imported once per process
    assert filter_entry("ReferenceFilter").filter_class is cls  # results carry the name; it resolves once loaded
    assert filter_entry(cls).filter_class is cls


def test_two_files_with_one_class_name_do_not_clash(tmp_path):
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        source = f"from mazelab.filters import SIRParticleFilter\nclass F(SIRParticleFilter):\n    tag = {folder!r}\n"
        (tmp_path / folder / "f.py").write_text(source)
    a, b = load_plugin(f"{tmp_path / 'a' / 'f.py'}:F"), load_plugin(f"{tmp_path / 'b' / 'f.py'}:F")
    assert (a.tag, b.tag) == ("a", "b") and a.__module__ != b.__module__


def test_run_with_a_plugin(capsys):
    assert main(["run", "--filter", REFERENCE, *QUICK, "--quiet", "--no-viz"]) == 0
    assert "ReferenceFilter: last-step error" in capsys.readouterr().out


def test_compare_and_study_with_a_plugin(tmp_path, capsys):
    scenario = tmp_path / "s.json"
    assert main(["run", "--maze", "paper_5x5", *QUICK, "--quiet", "--no-viz", "--save-scenario", str(scenario)]) == 0
    assert main(["compare", str(scenario), "--filters", f"sir,{REFERENCE}", "--no-viz"]) == 0
    table = capsys.readouterr().out
    assert "SIRParticleFilter" in table and "ReferenceFilter" in table
    rows = tmp_path / "study.csv"
    args = ["study", "--maze", "paper_5x5", "--filters", f"sir,{REFERENCE}", "--runs", "2", "--steps", "15"]
    assert main([*args, "--particles", "200", "--workers", "2", "--seed", "1", "--csv", str(rows)]) == 0
    filters = [row["filter"] for row in csv.DictReader(rows.open())]
    assert filters == ["SIRParticleFilter", "ReferenceFilter"] * 2  # the workers loaded the file themselves


def test_accuracy_with_a_plugin(capsys):
    args = ["accuracy", "--maze", "paper_5x5", "--runs", "1", "--steps", "10", "--particles", "200", "--workers", "1"]
    assert main([*args, "--filters", f"sir,{REFERENCE}"]) == 0
    out = capsys.readouterr().out
    assert "ReferenceFilter" in out and "SIRParticleFilter" in out


@pytest.mark.parametrize(
    ("source", "spec_class", "message"),
    [
        (None, "F", "no such file"),
        ("import no_such_module_here\n", "F", "does not import: ModuleNotFoundError"),
        ("def f(:\n", "F", "does not import: SyntaxError"),
        ("class G:\n    pass\n", "F", "has no class 'F' (it defines: G)"),
        ("class F:\n    name = 'F'\n    options = {}\n    def belief(self): pass\n", "F", "has no method step()"),
        ("class F:\n    def step(self, a, z): pass\n    def belief(self): pass\n", "F", "class attribute 'name'"),
    ],
)
def test_bad_plugins_get_one_line(tmp_path, capsys, source, spec_class, message):
    path = tmp_path / "student.py"
    if source is not None:
        path.write_text(source)
    assert main(["run", "--filter", f"{path}:{spec_class}", *QUICK, "--quiet", "--no-viz"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and "student.py" in err
    assert "Traceback" not in err


SPELLED_DEFAULT = """\
from mazelab.filters import SIRParticleFilter


class Spelled(SIRParticleFilter):
    options = {{**SIRParticleFilter.options, "inflation": 1.0}}

    def __init__(self, world, sigma, delta, particles, rng=None, inflation={inflation}, **options):
        super().__init__(world, sigma, delta, particles, rng, inflation=inflation, **options)
"""


@pytest.mark.parametrize("spelled", ["2.0", "1", "None"])
def test_a_plugin_whose_constructor_spells_another_default_is_refused(tmp_path, capsys, spelled):
    """Its runs would use the constructor's default while its scenarios store the declared one."""
    path = tmp_path / "spelled.py"
    path.write_text(SPELLED_DEFAULT.format(inflation=spelled))
    assert main(["run", "--filter", f"{path}:Spelled", *QUICK, "--quiet", "--no-viz"]) == (0 if spelled == "1" else 2)
    err = capsys.readouterr().err
    if spelled != "1":  # 1 == 1.0: the declared default, spelled as a whole number
        assert err.count("\n") == 1 and "spelled.py" in err and "Traceback" not in err
        assert f"the constructor's default inflation={spelled} is not the declared default 1.0" in err


def test_a_plugin_in_filters_is_checked_before_any_run(tmp_path, capsys):
    assert main(["study", "--filters", f"sir,{tmp_path / 'none.py'}:F", "--runs", "1", "--steps", "5"]) == 2
    assert "none.py" in capsys.readouterr().err


RAISING = """\
import numpy as np
from exercise_answers import ReferenceFilter


class Raising(ReferenceFilter):
    def weigh(self, positions, z):
        if self.steps_done == 2:
            return np.log(positions[:, 5])
        return super().weigh(positions, z)
"""


def test_a_plugin_that_raises_shows_its_own_frame_and_the_step(tmp_path, capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "tests"))
    path = tmp_path / "raising.py"
    path.write_text(RAISING)
    assert main(["run", "--filter", f"{path}:Raising", *QUICK, "--quiet", "--no-viz"]) == 1
    err = capsys.readouterr().err
    assert "Raising raised IndexError at step 3" in err
    assert f"{path}, line 8, in weigh: return np.log(positions[:, 5])" in err
    assert "mazelab" not in err.replace("mazelab_plugin", "")  # none of the lab's frames
    assert "Traceback" not in err


def test_simulate_raises_a_student_code_error_with_the_original_as_cause(paper_world):
    from mazelab.robot import Robot

    source = textwrap.dedent(
        """
        import numpy as np
        from mazelab.exercise import StudentFilter

        class Broken(StudentFilter):
            def resample(self, weights, rng):
                return np.arange(len(weights))

            def predict(self, positions, compass_angle, rng):
                return positions[:3]
        """
    )
    namespace: dict = {}
    exec(compile(source, "broken_filter.py", "exec"), namespace)
    with pytest.raises(StudentCodeError, match="Broken raised PartError at step 1: predict returned shape") as info:
        robot = Robot(0.3, 0.5, (1.5, 0.5))
        simulate(robot, paper_world, 0.3, 0.5, 50, 5, filtering_algorithm=namespace["Broken"], seed=1)
    assert info.value.__cause__ is not None


def test_a_shipped_filter_error_is_not_blamed_on_a_student(paper_world):
    from mazelab.robot import Robot

    with pytest.raises(ValueError, match="does not take the option"):
        simulate(Robot(0.3, 0.5, (1.5, 0.5)), paper_world, 0.3, 0.5, 50, 5, filtering_algorithm="sir", bogus=1)
