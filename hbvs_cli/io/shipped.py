"""Where the documents and sample files that help and messages name are on this machine.

The wheel ships ``docs/*.md`` and the small ``samples/`` files inside the package
(``hbvs_cli/docs``, ``hbvs_cli/samples``: see pyproject.toml); a source checkout or an
editable install has them beside the package.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent.parent


def shipped_path(relative: str) -> Path:
    """The installed file for a name such as ``docs/method.md`` or ``samples/gains.toml``.

    The wheel's copy when there is one, else the checkout's; the name under the package
    when neither exists (so a message still says where it would be).
    """
    for candidate in (_PACKAGE / relative, _PACKAGE.parent / relative):
        if candidate.is_file():
            return candidate
    return _PACKAGE / relative


def shipped_root() -> Path:
    """The folder that holds the installed ``docs/`` and ``samples/`` (the wheel's package
    folder, or a checkout's root)."""
    path = shipped_path("docs/method.md")
    return path.parent.parent


def shipped_name(relative: str) -> str:
    """How help texts name a shipped file: ``docs/method.md``, short enough for 80 columns;
    the root help says once where these names are (:func:`shipped_root`)."""
    return relative
