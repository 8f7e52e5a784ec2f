"""The I/O edge: MCAP files, calibration files, image sources, CSV paths and TOML configs.

Everything that touches bytes lives here; :mod:`hbvs_cli.core` and
:mod:`hbvs_cli.perception` never read or write files."""

from contextlib import AbstractContextManager


class ClosedOnExit(AbstractContextManager):
    """A resource that ``with`` closes (its ``close()``) when the block ends, however it ends."""

    def __exit__(self, *exc: object) -> None:
        self.close()  # type: ignore[attr-defined]  # each resource has its own
