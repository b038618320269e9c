"""notebooks/lab_uk.ipynb reads as Ukrainian written for the lab, not as a translation: the native
speaker's corrections stay made, its prose and everything it prints and draws hold no English word and
no decimal point (the study's table and the figures' ticks too, with a decimal comma), and what a student
hands in carries no path of their machine.
Run in a fresh kernel as tests/test_notebook.py runs it (its kernel spec), in a folder of the test's own.
"""

from __future__ import annotations

import ast
import io
import json
import re
import tokenize

import nbformat
import pytest
from conftest import ROOT
from test_notebook import (  # noqa: F401
    check_the_executed_lab,
    code_cells,
    execute_lab,
    figure_texts,
    kernel_spec,
    read_notebook,
    stdout_of,
)

CYRILLIC = re.compile(r"[а-щьюяєіїґ]", re.IGNORECASE)
# the native speaker's corrections: the wording that was there, and what replaced it
CORRECTED = [
    ("з статті", "зі статті"),
    ("випадкові кроки", "випадкові числа"),
    ("прокидається", "Робот вмикається"),
    ("Робота шукають", "Для пошуку робота використовуємо три гранулярні фільтри"),
    ("за замовчуванням", "типово"),
    ("накреслити лабіринт", "задати карту лабіринту"),
    ("обрати шуми", "обрати параметри σ і Δ"),
    ("в межах `delta`", "не більше ніж на `delta / 2` в кожен бік"),
    ("по чотирьох кутах якого знаходяться станції", "у чотирьох кутах якого розташовані станції"),
    ("Система відліку на карті", "Система координат карти"),
    ("тестовий запуск", "пробний запуск"),
    ("усі кути, якими робот справді рухався", "усі напрямки, у яких робот справді рухався"),
    ("якщо файл хибний", "якщо файл неправильний"),
    ("там, де робот є насправді", "там, де насправді перебуває робот"),
    ("Англійська версія", "Англомовна версія"),
    ("значимістю", "значущістю"),
    ("показу компаса", "показань компаса"),
    ("коло радіуса", "коло радіусом"),
    ("у клоні репозиторію", "а не з файлом у теці проєкту"),
    ("в статті Arulampalam та ін.", "в оглядовій статті Арулампалама та співавторів"),
    ("Усі випадкові величини задає одне зерно", "Усі випадкові числа породжуються з одного зерна"),
    ("зважене за їхніми вагами", "середнє положень гранул, зважене їхніми вагами"),
    ("залежність від кроку похибки", "залежно від номера кроку"),
    ("натисніть «відтворити»", "натисніть кнопку відтворення"),
    ("падає нижче від штрихової лінії", "опускається нижче штрихової лінії"),
    ("розкидані по всьому лабіринту", "розсіяні по всьому лабіринту"),
    ("Файл сценарію — звичайний JSON", "Сценарій зберігається у звичайному форматі JSON"),
    ("й повертає збережені відстані", "й повідомляє збережені відстані"),
    ("Відрізняються лише випадкові числа, які генерує", "Різняться лише випадкові числа, які породжує"),
    ("з 95% довірчим інтервалом", "та її 95-відсотковий довірчий інтервал"),
    ("у файл `parameters_path`, типово — у файл", "у файл, заданий параметром `parameters_path`"),
]
# the last-20% error is named once, as the "кінцева похибка", and called so from then on
FINAL_ERROR_DEFINED = "на *кінцеву похибку* — середню похибку оцінки за останні 20% кроків"
# Latin words that Ukrainian text keeps: the filters' short names, the names of the tools and of the file
# format, and the English term the classes are named after; everything else in Latin is code, written
# `so` in the text (or a name with an underscore, such as a key of the scenario file). Single letters are
# the mathematics' x, y, k, r.
ALLOWED_LATIN = {"SIR", "APF", "RPF", "Rerun", "Jupyter", "JSON", "particle"}
LATIN_WORD = re.compile(r"[A-Za-z]{2,}")
DECIMAL_POINT = re.compile(r"\d\.\d")


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


def english_in(text: str, code_names: set[str] = frozenset()) -> list[str]:
    """The Latin words of `text` outside ALLOWED_LATIN and `code_names`, after its code is taken out:
    `spans`, fenced blocks, $mathematics$, and names joined by an underscore, a dot or a slash (a key,
    a file: model_parameters.json)."""
    text = re.sub(r"```.*?```|`[^`]*`|\$[^$]*\$", " ", text, flags=re.S)
    words = LATIN_WORD.findall(re.sub(r"\b\w+(?:[_./]\w+)+\b", " ", text))
    return [word for word in words if word not in ALLOWED_LATIN | code_names]


def prose_of(notebook: nbformat.NotebookNode) -> str:
    """The Ukrainian a student reads besides the output: the markdown, and the code's comments and docstrings."""
    parts = []
    for cell in notebook.cells:
        if cell.cell_type == "markdown":
            parts.append(cell.source)
            continue
        code = "\n".join(line for line in cell.source.splitlines() if not line.startswith("%"))
        tokens = tokenize.generate_tokens(io.StringIO(code).readline)
        parts += [token.string for token in tokens if token.type == tokenize.COMMENT]
        functions = [node for node in ast.walk(ast.parse(code)) if isinstance(node, ast.FunctionDef)]
        parts += [ast.get_docstring(node) or "" for node in functions]
    return "\n".join(parts)


def test_the_prose_holds_no_english_word_and_no_decimal_point():
    prose = prose_of(read_notebook("uk"))
    assert english_in(prose) == []
    assert DECIMAL_POINT.findall(re.sub(r"`[^`]*`", " ", prose)) == []
    assert "0,2" in prose and "Арулампалама" in prose  # a decimal comma; the author's name in Cyrillic


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
    """What the notebook prints and draws holds no Latin word outside ALLOWED_LATIN and the scenario
    file's keys (no `True`, no class names in legends or tables) and no decimal point: numbers, points,
    tables and the figures' ticks are written with a decimal comma."""
    workdir = tmp_path / "a student's folder"
    notebook = execute_lab("uk", kernel_spec, workdir)
    check_the_executed_lab(notebook, workdir, "uk")
    lab_cells = [cell for cell in code_cells(notebook) if not cell.id.startswith("test-")]  # the probes' own
    outputs = json.dumps([cell.outputs for cell in lab_cells], ensure_ascii=False)
    for folder in {str(workdir), str(workdir.resolve()), str(tmp_path), str(ROOT), "/home/", "/root/"}:
        assert folder not in outputs, f"an output names {folder}"
    keys = set(json.loads((workdir / "model_parameters.json").read_text()))
    cells = {cell.id: cell for cell in lab_cells}
    for cell in cells.values():
        for line in stdout_of(cell).splitlines():
            assert english_in(line, keys) == [] and not DECIMAL_POINT.search(line), f"cell {cell.id}: {line!r}"
    assert "scenario saved to" not in stdout_of(cells["step-09-code"])
    for texts in figure_texts(notebook):
        assert {"SIR", "APF", "RPF"} <= set(texts), texts
        for text in texts:
            assert english_in(text) == [] and not DECIMAL_POINT.search(text), text
        assert any(re.fullmatch(r"0,\d+", text) for text in texts), texts  # ticks with a decimal comma
    table = stdout_of(cells["step-14-code"]).splitlines()
    assert CYRILLIC.search(table[0]) and "filter" not in table[0] and "runs" not in table[0]
    assert len(table) == 1 + 4 * 3  # the header, then four values of sigma for each of three filters
    for row in table[1:]:  # a decimal comma in the numbers, as Ukrainian text writes them; [low; high]
        assert re.match(r"\s*0,\d\s", row) and re.search(r" \d,\d{3} +\[\d,\d{3}; \d,\d{3}\]", row), row
        assert row.split()[1] in ("SIR", "APF", "RPF"), row
