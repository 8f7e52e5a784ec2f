"""The exit code of each error hbvs raises on purpose (the table in :mod:`hbvs_cli.errors`):
a domain error's bad value is a bad option (2), bad or too little data a bad input (3)."""

from __future__ import annotations

from ..errors import HbvsError, InsufficientDataError, InvalidValueError, MalformedDataError

#: Exit codes of the domain errors that do not carry one.
DOMAIN_EXIT_CODES: dict[type[HbvsError], int] = {
    InvalidValueError: 2,
    MalformedDataError: 3,
    InsufficientDataError: 3,
}


def exit_code_of(error: HbvsError) -> int:
    """The exit code for ``error``: its domain kind's, else the one it carries."""
    return next((DOMAIN_EXIT_CODES[kind] for kind in type(error).__mro__ if kind in DOMAIN_EXIT_CODES), error.exit_code)
