"""The documentation site as a student meets it, built as CI builds it (`mkdocs build --strict`): it
loads nothing from another host (a lab room offline still has its code highlighted), the code is
highlighted, an asterisk between two words stays a product, the home page leads to a quick start, and
the pages have subheadings, so that the side menu shows their sections."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT

# the pages whose side menu this suite guards: long enough to need sections
SECTIONED_PAGES = ("index", "quickstart", "paper", "viewer", "mazes", "scenarios", "limits", "kidnapped", "development")


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("site")
    subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "--site-dir", str(folder)],
        cwd=ROOT, check=True, capture_output=True,
    )  # fmt: skip
    return folder


def test_no_page_loads_a_script_or_a_stylesheet_from_another_host(site):
    for page in site.rglob("*.html"):
        html = page.read_text(encoding="utf-8")
        loaded = re.findall(r'<script[^>]*\ssrc="([^"]+)"|<link[^>]*\shref="([^"]+)"', html)
        remote = [url for pair in loaded for url in pair if re.match(r"(https?:)?//", url)]
        assert remote == [], f"{page.relative_to(site)} loads {remote}"


def test_code_is_highlighted_when_the_site_is_built(site):
    html = (site / "quickstart" / "index.html").read_text(encoding="utf-8")
    assert '<span class="c1"># makes .venv' in html  # a shell comment, coloured by the shipped stylesheet
    assert ".highlight .c1" in (site / "css" / "pygments.css").read_text()


def test_an_asterisk_between_words_is_a_product_not_emphasis(site):
    html = (site / "api" / "filters" / "index.html").read_text(encoding="utf-8")
    assert "r*N..(r+1)*N" in html and "<em>N..(r+1)</em>" not in html


def test_the_home_page_leads_to_the_quick_start(site):
    html = (site / "index.html").read_text(encoding="utf-8")
    assert 'href="quickstart/"' in html


@pytest.mark.parametrize("name", SECTIONED_PAGES)
def test_a_page_has_sections_for_the_side_menu(name):
    text = (ROOT / "docs" / f"{name}.md").read_text(encoding="utf-8")
    assert len(re.findall(r"^## \S", text, re.M)) >= 2, f"docs/{name}.md: no sections for the side menu"
