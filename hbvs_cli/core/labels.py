"""Enumerations whose members are the words hbvs's files record."""

from __future__ import annotations

from enum import Enum


class Label(str, Enum):
    """A ``str`` enumeration that prints, formats and serialises as its value: a status
    written to a file or a message reads ``"outlier"``, not ``"ObservationStatus.OUTLIER"``."""

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)
