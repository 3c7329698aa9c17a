"""The README's Python example runs as written, and its loss falls."""
from __future__ import annotations

import contextlib
import io
import re

from conftest import REPO


def test_readme_python_example_runs():
    text = (REPO / "README.md").read_text()
    block = re.search(r"## Python\n.*?```python\n(.*?)```", text, re.S)
    assert block, "README has no Python example"
    code = block.group(1)
    assert len(code.strip().splitlines()) <= 12, "the example should stay about ten lines"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, "README.md", "exec"), {})
    losses = [float(line.split()[1]) for line in out.getvalue().splitlines()]
    assert len(losses) == 5 and losses[-1] < 0.8 * losses[0], losses
