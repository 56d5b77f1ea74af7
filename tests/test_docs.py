"""The README and the user guide say what the code does: their Python examples run
(warnings are errors here too), the command-line page covers every command and option,
and the README's links point at files that exist."""
from __future__ import annotations

import argparse
import re
import shutil
from pathlib import Path

import pytest

from preisach.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]


def _python_blocks(path: Path) -> str:
    text = path.read_text(encoding="utf-8")
    return "\n".join(re.findall(r"```python\n(.*?)```", text, flags=re.S))


@pytest.mark.parametrize("doc", ["README.md", "docs/guide/python.md"])
def test_python_examples_run(doc, tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    (tmp_path / "examples").mkdir()
    shutil.copy(ROOT / "examples" / "paper_ident.csv", tmp_path / "examples")
    monkeypatch.chdir(tmp_path)
    code = _python_blocks(ROOT / doc)
    assert code.strip()
    exec(compile(code, doc, "exec"), {"__name__": "__docs__"})
    assert (tmp_path / "model.json").exists()


def test_the_cli_page_covers_every_command_and_option():
    text = (ROOT / "docs" / "guide" / "cli.md").read_text(encoding="utf-8")
    subs = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for name, sub in subs.choices.items():
        assert f"## {name}\n" in text, name
        section = text.split(f"## {name}\n", 1)[1].split("\n## ", 1)[0]
        for action in sub._actions:
            for flag in action.option_strings:
                if flag.startswith("--") and flag != "--help":
                    assert flag in section, (name, flag)


def test_readme_links_exist_and_the_readme_stays_short():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 200
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text):
        if "://" not in target:
            assert (ROOT / target).exists(), target
