"""notebooks/lab_uk.ipynb reads as Ukrainian written for the lab, not as a translation: the native
speaker's corrections stay made, every line the notebook prints itself is Ukrainian (the study's table
too, its numbers with a decimal comma), and what a student hands in carries no path of their machine.
Run in a fresh kernel as tests/test_notebook.py runs it (its kernel spec), in a folder of the test's own.
"""

from __future__ import annotations

import ast
import json
import re

import nbformat
import pytest
from conftest import ROOT
from test_notebook import check_the_executed_lab, code_cells, execute_lab, kernel_spec, read_notebook, stdout_of  # noqa: F401

CYRILLIC = re.compile(r"[а-щьюяєіїґ]", re.IGNORECASE)  # noqa: RUF001
# the native speaker's corrections: the wording that was there, and what replaced it
CORRECTED = [
    ("з статті", "зі статті"),
    ("випадкові кроки", "випадкові числа"),
    ("прокидається", "Робот вмикається"),
    ("Робота шукають", "Для пошуку робота використовуємо три гранулярні фільтри"),
    ("за замовчуванням", "типово"),
    ("накреслити лабіринт", "задати карту лабіринту"),
    ("обрати шуми", "обрати параметри σ і Δ"),  # noqa: RUF001
    ("в межах `delta`", "не більше ніж на `delta / 2` в кожен бік"),
    ("по чотирьох кутах якого знаходяться станції", "у чотирьох кутах якого розташовані станції"),  # noqa: RUF001
    ("Система відліку на карті", "Система координат карти"),
    ("тестовий запуск", "пробний запуск"),
    ("усі кути, якими робот справді рухався", "усі напрямки, у яких робот справді рухався"),  # noqa: RUF001
    ("якщо файл хибний", "якщо файл неправильний"),
    ("там, де робот є насправді", "там, де насправді перебуває робот"),
    ("Англійська версія", "Англомовна версія"),
    ("значимістю", "значущістю"),
    ("показу компаса", "показань компаса"),
    ("коло радіуса", "коло радіусом"),
]
# the last-20% error is named once, as the "кінцева похибка", and called so from then on
FINAL_ERROR_DEFINED = "на *кінцеву похибку* — середню похибку оцінки за останні 20% кроків"
# what the library prints in English into a cell's output (the notebook does not print it itself)
LIBRARY_LINES = ("scenario saved to ",)


def text_of(notebook: nbformat.NotebookNode) -> str:
    """The markdown and the code's strings and comments: everything a student reads."""
    return " ".join(" ".join(cell.source.split()) for cell in notebook.cells)  # lines joined, as read


def printed_strings(source: str) -> list[str]:
    """The words of each print() call of a cell: its string constants and f-strings' constant parts."""
    found = []
    for node in ast.walk(ast.parse("\n".join(line for line in source.splitlines() if not line.startswith("%")))):
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "print":
            words = [
                part.value
                for argument in ast.walk(node)
                for part in ([argument] if isinstance(argument, ast.Constant) else [])
                if isinstance(part.value, str)
            ]
            found.append(" ".join(words))
    return found


def test_the_native_speakers_corrections_are_made():
    text = text_of(read_notebook("uk"))
    for wrong, right in CORRECTED:
        assert wrong not in text, wrong
        assert right in text, right
    assert not re.search(r"\d x \d|\] x \[|\} x \{", text), "a product of sizes is written with the sign"
    assert "\N{MULTIPLICATION SIGN}" in text
    assert text.count(FINAL_ERROR_DEFINED) == 1 and "похибка останніх 20%" not in text


def test_every_line_the_notebook_prints_is_worded_in_ukrainian():
    """Each print() call that has words of its own has Ukrainian ones (keys of the file and names of
    the filters are code, not words)."""
    for cell in code_cells(read_notebook("uk")):
        for words in printed_strings(cell.source):
            latin_words = re.findall(r"\b[a-z]{4,}\b", re.sub(r"`[^`]*`|\b\w+_\w+\b|pip install.*", "", words))
            if latin_words:
                assert CYRILLIC.search(words), f"cell {cell.id} prints English words: {words!r}"


@pytest.mark.slow  # a kernel, then the whole lab, as in test_notebook.py (it still runs by default)
def test_the_executed_notebook_is_ukrainian_and_names_no_folder_of_this_machine(kernel_spec, tmp_path):  # noqa: F811
    workdir = tmp_path / "a student's folder"
    notebook = execute_lab("uk", kernel_spec, workdir)
    check_the_executed_lab(notebook, workdir, "uk")
    lab_cells = [cell for cell in code_cells(notebook) if cell.id != "test-probe"]  # the probe prints the python
    outputs = json.dumps([cell.outputs for cell in lab_cells], ensure_ascii=False)
    for folder in {str(workdir), str(workdir.resolve()), str(tmp_path), str(ROOT), "/home/", "/root/"}:
        assert folder not in outputs, f"an output names {folder}"
    cells = {cell.id: cell for cell in lab_cells}
    for cell in cells.values():
        for line in stdout_of(cell).splitlines():
            if line.startswith(LIBRARY_LINES):
                continue
            if re.search(r"\b(?:the|and|with|of|to|saved|filter|runs|error|interval)\b", line):
                assert CYRILLIC.search(line), f"cell {cell.id} printed English: {line!r}"
    assert "scenario saved to model_parameters.json\n" in stdout_of(cells["step-09-code"])
    table = stdout_of(cells["step-14-code"]).splitlines()
    assert CYRILLIC.search(table[0]) and "filter" not in table[0] and "runs" not in table[0]
    assert len(table) == 1 + 4 * 3  # the header, then four values of sigma for each of three filters
    for row in table[1:]:  # a decimal comma in the numbers, as Ukrainian text writes them; [low; high]
        assert re.match(r"\s*0,\d\s", row) and re.search(r" \d,\d{3} +\[\d,\d{3}; \d,\d{3}\]", row), row
        assert not re.search(r"\d\.\d", row), row
