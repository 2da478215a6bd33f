"""The README's Python session runs as written (in a scratch folder: it writes demo/ and
fit.json where it runs)."""

import contextlib
import io
import os
import pathlib
import re

README = pathlib.Path(__file__).resolve().parents[3] / "README.md"


def test_the_readme_session_runs(tmp_path):
    text = README.read_text()
    section = text[text.index("\n## Python\n"):]
    section = section[: section.index("\n## ", 1)]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert len(blocks) == 1, "the Python section has one session"
    here = os.getcwd()
    printed = io.StringIO()
    os.chdir(tmp_path)
    try:
        with contextlib.redirect_stdout(printed):
            exec(compile(blocks[0], "README.md", "exec"), {})
    finally:
        os.chdir(here)
    lines = printed.getvalue().splitlines()
    assert "converged" in lines[0]
    assert lines[1] == "(36, 3)"
    assert (tmp_path / "fit.json").exists()
