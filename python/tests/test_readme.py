"""The Python examples of python/README.md and README.md run as shown:
each ```python block on its own, from the repository's root (the paths
they name are relative to it), as a reader pastes it."""

import contextlib
import io
import os
import re

import pytest

from conftest import REPO

READMES = [REPO / "python" / "README.md", REPO / "README.md"]


def snippets():
    """(readme, first line, code) of every ```python block."""
    found = []
    for readme in READMES:
        text = readme.read_text(encoding="utf-8")
        for match in re.finditer(r"^```python\n(.*?)^```", text, re.S | re.M):
            line = text.count("\n", 0, match.start()) + 1
            found.append((readme, line, match.group(1)))
    return found


SNIPPETS = snippets()


def test_the_readmes_have_python_examples():
    # Two in python/README.md (the example and the incremental one), one
    # in README.md: a renamed fence would silently test nothing.
    assert [(r.name, r.parent.name) for r, _, _ in SNIPPETS].count(("README.md", "python")) >= 2
    assert len(SNIPPETS) >= 3


@pytest.mark.parametrize(
    "readme, line, code",
    SNIPPETS,
    ids=[f"{r.parent.name}/{r.name}:{line}" for r, line, _ in SNIPPETS],
)
def test_a_readme_example_runs_on_its_own(readme, line, code):
    here = os.getcwd()
    os.chdir(REPO)
    try:
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            exec(compile(code, f"{readme}:{line}", "exec"), {"__name__": "__readme__"})
    finally:
        os.chdir(here)
    assert out.getvalue(), "an example shows what it does"
