"""Resolve driver factories named in the configuration.

``agf`` never imports ``drivers``: the configuration names the implementation of each protocol as a
``"module:attribute"`` string, and this module imports it on demand. A real truck's config names
real drivers, the default config names the simulated twins.
"""

from __future__ import annotations

import importlib
from typing import Any

from agf.errors import ConfigError


def load_object(spec: str, *, key: str = "plugin") -> Any:
    """Import ``"package.module:attribute"`` and return the attribute.

    Parameters
    ----------
    spec : str
        Dotted module path and attribute name separated by a colon.
    key : str
        The configuration key that held ``spec``, used in error messages.

    Raises
    ------
    ConfigError
        If ``spec`` is malformed, the module cannot be imported or lacks the attribute.
    """
    module_name, sep, attr = spec.partition(":")
    if not sep or not module_name or not attr:
        raise ConfigError(f"{key}: expected 'module:attribute', got {spec!r}")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(f"{key}: cannot import module {module_name!r} ({exc})") from exc
    try:
        return getattr(module, attr)
    except AttributeError as exc:
        raise ConfigError(f"{key}: module {module_name!r} has no attribute {attr!r}") from exc
