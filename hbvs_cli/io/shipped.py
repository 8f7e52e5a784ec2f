"""Where the documents and sample files that help and messages name are on this machine: inside the
package in a wheel (pyproject.toml), beside it in a checkout."""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent.parent


def shipped_root() -> Path:
    """The folder that holds the installed ``docs/`` and ``samples/``: the wheel's package, else the checkout's root
    (whichever holds ``docs/method.md``), else the package (so a message still says where they would be)."""
    return next((root for root in (_PACKAGE, _PACKAGE.parent) if (root / "docs/method.md").is_file()), _PACKAGE)
