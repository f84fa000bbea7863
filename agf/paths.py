"""Where the repository's own files are, for paths that DESIGN.md makes repository-relative."""

from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CONFIG = REPO_ROOT / "configs" / "agf.yaml"


def repo_path(path: str | Path) -> Path:
    """Resolve ``path`` against the repository root unless it is absolute."""
    path = Path(path)
    return path if path.is_absolute() else REPO_ROOT / path
