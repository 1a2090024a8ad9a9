"""The README's example runs as written: its first ```python block, executed in a fresh namespace."""
from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def first_python_block(text: str) -> str:
    match = re.search(r"^```python\n(.*?)^```", text, flags=re.MULTILINE | re.DOTALL)
    assert match, "README.md has no ```python block"
    return match.group(1)


def test_readme_example_runs():
    code = first_python_block(README.read_text())
    assert "torch_grid.load(" in code
    exec(compile(code, f"{README}:example", "exec"), {"__name__": "readme_example"})
