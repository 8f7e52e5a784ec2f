"""Where the documents and sample files that help and messages name are on this machine: inside the
package in a wheel (pyproject.toml), beside it in a checkout."""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent.parent


def shipped_path(relative: str) -> Path:
    """The installed file for a name such as ``docs/method.md``: the wheel's copy, else the checkout's,
    else the name under the package (so a message still says where it would be)."""
    return next((path for path in (_PACKAGE / relative, _PACKAGE.parent / relative) if path.is_file()), _PACKAGE / relative)


def shipped_root() -> Path:
    """The folder that holds the installed ``docs/`` and ``samples/`` (the wheel's package, or a checkout)."""
    return shipped_path("docs/method.md").parent.parent

