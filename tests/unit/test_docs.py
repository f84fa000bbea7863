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
