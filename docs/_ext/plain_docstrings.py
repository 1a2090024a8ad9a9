"""Read torch_grid's docstrings, written as plain text for help(), as reStructuredText without
changing their words.

Before napoleon parses the Google-style sections (Args:, Returns:), each docstring is rewritten:

- characters that reStructuredText reads as markup in prose (``*``, ``|``, a trailing ``_``,
  ``\\``) are escaped;
- a line that starts with one of the function's parameter names and a colon (``source: ...``),
  after a blank line or a field of an earlier parameter, starts a ``:param:`` field, continued by
  the lines below it up to the next blank line or field;
- a block indented under a paragraph (equations, aligned lists) becomes a literal block, so that
  its line breaks and alignment stay as written.
"""
from __future__ import annotations

import inspect
import re

SECTIONS = re.compile(r"^\s*(Args|Arguments|Parameters|Returns|Return|Raises|Yields|Examples?|Notes?):\s*$")
FIELD = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*): (.*)$")
TRAILING_UNDERSCORE = re.compile(r"(?<=\w)_(?=\W|$)")


def escape(text: str) -> str:
    """Prose with reStructuredText's inline markup characters escaped (backquoted code left as is)."""
    parts = text.split("`")
    for k in range(0, len(parts), 2):  # outside `...`
        part = parts[k].replace("\\", "\\\\").replace("*", "\\*").replace("|", "\\|")
        parts[k] = TRAILING_UNDERSCORE.sub(r"\\_", part)
    if len(parts) % 2 == 0:  # an unmatched backquote: escape it too
        return "\\`".join(["`".join(parts[:-1]), parts[-1]])
    return "`".join(parts)


def indentation(line: str) -> int:
    return len(line) - len(line.lstrip())


def parameters(obj) -> list[str]:
    try:
        return [name for name in inspect.signature(obj).parameters if name != "self"]
    except (TypeError, ValueError):
        return []


def rewrite(lines: list[str], names: list[str]) -> list[str]:
    base = min((indentation(line) for line in lines if line.strip()), default=0)
    out: list[str] = []
    section = field = literal = False
    last = -1  # the position in `names` of the last field's parameter
    for line in lines:
        blank = not line.strip()
        indent = indentation(line)
        if SECTIONS.match(line):
            section, field, literal = True, False, False
            if out and out[-1].strip():
                out.append("")
            out.append(line)
            continue
        if section:  # napoleon's; it ends at the next line as little indented as its header
            if blank or indent > base:
                out.append(escape(line))
                continue
            section = False
            out.append("")
        if blank:
            field = literal = False
            last = -1
            out.append(line)
            continue
        if literal or (indent > base and not field):
            if not literal:  # a block indented under a paragraph: a literal block
                if out and out[-1].strip():
                    out[-1] = out[-1] + (":" if out[-1].rstrip().endswith(":") else " ::")
                else:
                    out.append("::")
                out.append("")
                literal = True
            if indent <= base:  # the block has ended without a blank line
                literal = False
                out.append("")
            else:
                out.append(line)
                continue
        match = FIELD.match(line[base:]) if indent == base else None
        after = not out or not out[-1].strip() or field  # a field starts a paragraph or follows one
        if match and after and match.group(1) in names[last + 1:]:
            last = names.index(match.group(1))
            if out and out[-1].strip() and not field:
                out.append("")
            out.append(" " * base + f":param {match.group(1)}: " + escape(match.group(2)))
            field = True
            continue
        if field:
            if indent == base:  # the field's continuation lines are indented under its marker
                out.append(" " * (base + 3) + escape(line[base:]))
                continue
            field = False
        out.append(escape(line))
    return out


_ATTRIBUTES = ("property", "attribute", "data")
_kept: dict[str, list[str]] = {}


def process(app, what, name, obj, options, lines):
    lines[:] = rewrite(list(lines), parameters(obj) if what in ("function", "method", "class") else [])
    if what in _ATTRIBUTES:
        _kept[name] = list(lines)


def restore(app, what, name, obj, options, lines):
    """An attribute's docstring as rewritten above: napoleon would read "Number of frames: ..." as a
    type and a description."""
    if what in _ATTRIBUTES and name in _kept:
        lines[:] = _kept.pop(name)


def setup(app):
    app.connect("autodoc-process-docstring", process, priority=100)  # before napoleon (500)
    app.connect("autodoc-process-docstring", restore, priority=900)  # after it
    return {"parallel_read_safe": True, "parallel_write_safe": True}
