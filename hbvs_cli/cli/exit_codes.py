"""The exit code of each error hbvs raises on purpose (the table in :mod:`hbvs_cli.errors`).

The I/O edge and the stages raise errors that say what the command line or a file did
wrong, and carry their exit code (``UsageError`` 2, ``InputError`` 3, ...). The pure core
raises domain errors (:class:`~hbvs_cli.errors.DomainError`) that know nothing of a command
line; this is where they become exit codes, the same a user saw when the core raised the
command line's errors: a bad value is a bad option (2), malformed or too little data a bad
input (3). Degenerate geometry keeps its own code (4).
"""

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
    for kind in type(error).__mro__:
        if kind in DOMAIN_EXIT_CODES:
            return DOMAIN_EXIT_CODES[kind]
    return error.exit_code
