"""The exceptions hbvs raises on purpose, each with its exit code (README.md, "Exit codes").

Every error a user can cause is an :class:`HbvsError`: the CLI prints its message as one
line on stderr and exits with its code (a domain error's bad value is a bad option, 2; bad or
too little data a bad input, 3); anything else that escapes is a bug.
"""

from __future__ import annotations

from typing import Any


class HbvsError(Exception):
    """Base of every error hbvs raises on purpose; its message is meant for the user."""

    exit_code: int = 3


class UpstreamFailedError(HbvsError):
    """stdin is a pipe that closed without a byte: the command before this one in the
    pipeline failed (and said why), so this one exits without a word of its own."""

    exit_code = 9


class UsageError(HbvsError):
    """Options that cannot go together, or a value outside its range."""

    exit_code = 2


class InputError(HbvsError):
    """A file or stream that is missing, unreadable or not what it should be (exit 3, as :class:`HbvsError`)."""


class CalibrationError(InputError):
    """A camera calibration file that is missing, malformed or inconsistent."""


class RecordingError(InputError):
    """An MCAP file that is malformed, truncated beyond use, or of the wrong kind."""


class DomainError(HbvsError):
    """An error of the method itself, raised by the pure core (the numbers, not their source)."""


class InvalidValueError(DomainError):
    """A value outside its domain: a gain or a depth that is not positive, an unknown name."""

    exit_code = 2


class MalformedDataError(DomainError):
    """Data that are not what the method needs (times that do not increase, a missing channel)."""


class NotAnImageError(MalformedDataError, InputError):
    """An array that is not an image hbvs reads (empty, or of another pixel type or shape)."""


class InsufficientDataError(DomainError):
    """Too little usable data; ``facts`` holds the numbers behind the message for a stage to word."""

    def __init__(self, message: str, **facts: Any) -> None:
        super().__init__(message)
        self.facts = facts


class GeometryError(DomainError):
    """Input whose geometry admits no (unique) answer."""

    exit_code = 4


class NotEnoughPointsError(GeometryError):
    """Fewer target points than the method needs."""


class CollinearPointsError(GeometryError):
    """Reference points that are (nearly) collinear, so the homography is not unique."""


class PointAtCameraHeightError(GeometryError):
    """A target point whose normalised height m_z is (nearly) zero: (18) divides by it."""


class PointBehindCameraError(GeometryError):
    """A point with non-positive depth, or a depth ratio that is not positive."""


class NonFiniteInputError(GeometryError):
    """NaN or infinity where numbers were expected."""


class NoValidBranchError(GeometryError):
    """A homography none of whose decompositions puts the plane in front of the camera."""


class NotAtStartError(HbvsError):
    """A live run's robot does not see the target as it was seen at the taught start."""

    exit_code = 8


class TargetLostError(HbvsError):
    """The target stayed out of sight longer than the allowed timeout."""

    exit_code = 5


class CameraClockError(DomainError):
    """A live camera's time stamps ran ahead of this host's clock or stepped back (a clock jump,
    or two clocks on one topic): the taught trajectory must never run faster than real time."""

    exit_code = 10


class CommandConflictError(HbvsError):
    """Another node published on the robot's command topic while hbvs was driving."""

    exit_code = 11


class TruncatedInputError(InputError):
    """An input ended before its end record, and its result would replace an existing file."""


class OutputError(HbvsError):
    """An output that could not be written: a full disk, an I/O error, a closed stdout."""

    exit_code = 6


class LimitExceededError(HbvsError):
    """A size that would turn into memory or time beyond a limit (``hbvs --limit`` raises it)."""

    exit_code = 7


class PipeClosedError(HbvsError):
    """The reader of stdout closed the pipe (exit 141, as a shell reports SIGPIPE)."""

    exit_code = 141
