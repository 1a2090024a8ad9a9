"""The docs' examples run as written: each page's ```python blocks, in order and in one namespace, as a
reader would run them (the README's example is tests/test_readme.py's). A block's asserts are its claims."""
from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parents[1] / "docs"
BLOCK = re.compile(r"^```python\n(.*?)^```", flags=re.MULTILINE | re.DOTALL)

# Blocks that need an optional package, skipped (with the reason shown) where it is not installed:
# (page, block index on the page) -> module.
OPTIONAL = {
    ("guides/trajectory_optimisation.md", 1): "mpc",  # mpc.pytorch: pip install --no-deps mpc==0.0.6
}
# Blocks that cannot run in the test suite (e.g. one that needs a GPU), each with its reason. None at present.
EXCLUDED: dict[tuple[str, int], str] = {}


def blocks(page: Path) -> list[str]:
    return BLOCK.findall(page.read_text())


PAGES = [p.relative_to(DOCS).as_posix() for p in sorted([*DOCS.glob("*.md"), *DOCS.glob("guides/*.md")]) if blocks(p)]


def test_the_lists_name_existing_blocks():
    assert "quickstart.md" in PAGES and any(p.startswith("guides/") for p in PAGES)
    for page, index in [*OPTIONAL, *EXCLUDED]:
        assert page in PAGES and index < len(blocks(DOCS / page)), (page, index)


@pytest.mark.parametrize("page", PAGES)
def test_page_blocks_run(page):
    namespace, skipped = {"__name__": "docs_example"}, []
    for index, code in enumerate(blocks(DOCS / page)):
        if (page, index) in EXCLUDED:
            continue
        module = OPTIONAL.get((page, index))
        if module is not None and importlib.util.find_spec(module) is None:
            skipped.append(f"block {index} needs {module}")
            continue
        exec(compile(code, f"{DOCS / page}:block {index}", "exec"), namespace)
    if skipped:
        pytest.skip(f"{page}: " + ", ".join(skipped) + " (not installed); the page's other blocks ran")
