"""docs/cli.md from the commands' help (``make docs``): typer's generator escapes it for HTML, which a
Markdown viewer shows verbatim inside code spans (``<path>`` as ``&lt;path&gt;``) and in apostrophes."""

from __future__ import annotations

import html
import re
import sys
from pathlib import Path


def unescape_markdown(text: str) -> str:
    """Apostrophes and quotes everywhere; every entity inside a code span (rendered literally there).
    Outside code spans ``&lt;`` stays: a bare ``<a>`` would be read as an HTML tag and vanish."""
    text = text.replace("&#x27;", "'").replace("&quot;", '"')
    return re.sub(r"`[^`\n]*`", lambda m: html.unescape(m.group(0)), text)


if __name__ == "__main__":
    path = Path(sys.argv[1])
    path.write_text(unescape_markdown(path.read_text()))
