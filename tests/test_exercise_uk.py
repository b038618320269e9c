"""The exercise in Ukrainian as a native reader meets it: the catalogue, my_filter.py and README.md of
`exercise new --lang uk`, notebooks/exercise_uk.ipynb, and what `exercise check --lang uk` prints for a
passing submission, one with four planted bugs and one that does not import. Their prose and output
hold no word in Latin letters but a short allowlist (SIR, APF, RPF, Rerun, code names and options)
and no number with a decimal point."""

from __future__ import annotations

import ast
import json
import re
import textwrap

import pytest
from conftest import ROOT
from exercise_answers import write_submission

from mazelab.cli.app import main
from mazelab.exercise.template import catalogue, exercise_texts

NAMES = {  # words in Latin letters a Ukrainian text may hold: names, and the code's own names
    "SIR", "APF", "RPF", "Rerun", "Arulampalam",
    "predict", "weigh", "resample", "estimate", "numpy", "rng", "self", "exit", "arange", "searchsorted",
    "cumsum", "size", "len", "positions", "weights", "points", "mazelab", "python", "uv", "CLONE", "SCENARIO",
    "LANGUAGE", "en", "uk", "log", "exp", "cos", "sin", "NaN", "nan", "inf", "False", "True", "MyFilter",
    "StudentFilter", "ClassName", "dataclasses", "namedtuple", "marshal", "Draw", "Calculate", "RESAMPLE",
    "noqa", "notebook",
}  # fmt: skip
# an option, a name with "_", "." or a digit, a letter of a formula (with its indices), an error, a signal
CODE_LIKE = re.compile(r"^(-{1,2}\w|.*[_.\d]|[A-Za-z][^A-Za-z]*$|[A-Z]\w*Error$|SIG[A-Z]+$)")


SEPARATORS = r"\s,;:!?()\[\]{}\"'=<>|*+/~@^" + "\u00ab\u00bb\u2014\u2013\u2192\u00b7\u00d7\u2264\u2265\u2212"


def foreign_words(text: str) -> list[str]:
    """The words of `text` in Latin letters that are neither code nor allowed (code spans skipped)."""
    text = re.sub(r"`[^`]*`", " ", text)
    words = re.findall(f"[^{SEPARATORS}]+", text)
    latin = [w.rstrip(".") for w in words if re.search(r"[A-Za-z]", w)]
    return sorted({w for w in latin if w not in NAMES and not CODE_LIKE.match(w)})


def decimal_points(text: str) -> list[str]:
    return re.findall(r"\S*\d\.\d\S*", text)


def assert_ukrainian(text: str, where: str) -> None:
    assert foreign_words(text) == [], (where, foreign_words(text))
    assert decimal_points(text) == [], (where, decimal_points(text))


def test_the_catalogue_is_ukrainian():
    for msgid, msgstr in catalogue("uk").entries.items():
        assert_ukrainian(re.sub(r"\{\w+\}", " ", msgstr), msgid)


def test_the_exercise_files_are_ukrainian():
    mine, readme = exercise_texts("uk")
    texts = [n.value for n in ast.walk(ast.parse(mine)) if isinstance(n, ast.Constant) and isinstance(n.value, str)]
    for text in [*texts, readme]:
        assert_ukrainian(text, text[:60])


def test_the_notebook_is_ukrainian():
    notebook = json.loads((ROOT / "notebooks" / "exercise_uk.ipynb").read_text())
    for cell in notebook["cells"]:
        source = "".join(cell["source"])
        if cell["cell_type"] == "markdown":
            assert_ukrainian(source, cell["id"])
        else:
            tree = ast.parse(source)
            texts = [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)]
            comments = re.findall(r"#\s*(?:noqa: \w+)?(.*)", source)
            for text in [t for t in texts if len(t) > 12] + comments:
                assert_ukrainian(text, cell["id"])


PLANTED = {  # four parts each with a bug whose hint is a sentence
    "predict": """
        def predict(self, positions, compass_angle, rng):
            step = ROBOT_SPEED * np.array([np.cos(compass_angle), np.sin(compass_angle)])
            return positions + step
    """,
    "weigh": """
        def weigh(self, positions, z):
            distance = self.world.distance_to_nearest_station(positions)
            return 0.5 * ((z - distance) / self.sigma) ** 2
    """,
    "resample": "def resample(self, weights, rng):\n    return np.arange(len(weights))\n",
    "estimate": "def estimate(self, positions, weights):\n    return positions.mean(axis=0)\n",
}


@pytest.mark.parametrize("submission", ["passing", "four bugs", "not importable"])
def test_check_in_ukrainian_prints_ukrainian(tmp_path, capsys, submission):
    path = tmp_path / "my_filter.py"
    if submission == "passing":
        write_submission(path)
    elif submission == "four bugs":
        write_submission(path, **{part: textwrap.dedent(code) for part, code in PLANTED.items()})
    else:
        path.write_text("raise RuntimeError('не готово')\n")
    code = main(["exercise", "check", str(path), "--lang", "uk", "--seed", "2024"])
    printed = capsys.readouterr()
    assert code == {"passing": 0, "four bugs": 1, "not importable": 2}[submission], printed
    assert_ukrainian(printed.out.replace(str(path), "").replace(str(tmp_path), ""), submission)
    assert_ukrainian(printed.err.replace(str(path), ""), submission)
    if submission == "four bugs":
        assert printed.out.count("НЕ ЗАРАХОВАНО") == 5 and "рівняння (3)" in printed.out  # noqa: RUF001
