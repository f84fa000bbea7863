"""Generated documentation stays in step with the code it is generated from."""

from __future__ import annotations

import importlib.util
from importlib.machinery import SourceFileLoader

from agf.paths import repo_path


def test_controller_diagram_in_docs_is_current():
    loader = SourceFileLoader("controller_diagram", str(repo_path("tools/controller_diagram")))
    tool = importlib.util.module_from_spec(importlib.util.spec_from_loader("controller_diagram", loader))
    loader.exec_module(tool)
    from agf.controller import controller_diagram

    expected = tool.TEXT.format(diagram=controller_diagram().rstrip())
    assert repo_path("docs/controller.md").read_text() == expected, "run tools/controller_diagram"


def test_every_refusal_in_the_vision_guide_is_one_the_code_raises():
    """docs/vision.md's refusal table quotes each message, with ``...`` or ``N`` for what the code fills in;
    every literal part of at least two words must still be in the code."""
    import re

    sources = "".join(path.read_text() for path in sorted(repo_path("agf/vision").glob("*.py")))
    sources = re.sub(r"\"\s*\n\s*f?\"", "", sources)  # join the implicitly concatenated message parts
    table = [line for line in repo_path("docs/vision.md").read_text().splitlines() if line.startswith("| `")]
    assert len(table) >= 10
    for line in table:
        quoted = line.split("`")[1]
        parts = [p.strip(" ,") for p in re.split(r"\.\.\.|\{[^}]*\}|\bN\b", quoted)]
        parts = [p for p in parts if len(p.split()) >= 2]
        assert parts, f"docs/vision.md quotes {quoted!r}, with no literal part of two words to look for"
        missing = [p for p in parts if p not in sources]
        assert not missing, f"docs/vision.md quotes {quoted!r}; agf/vision/ no longer says {missing}"
