"""A live camera's time stamps checked against this host's monotonic clock.

A live loop plays the taught trajectory at the pace of the camera's stamps (the time a frame
was taken is the best measure of when the robot was where it saw itself); but a driver can
freeze, step back or jump a stamp, or two cameras share one topic. So the trajectory never runs
faster than real time and every command rests on a fresh frame.
"""

from __future__ import annotations

import math

from ..errors import CameraClockError

#: A stamp may run ahead of (or step back behind) this host's clock by this many frame periods
#: before it is a fault; delays in transport and processing only ever make a frame look older.
CLOCK_JUMP_PERIODS = 5.0
#: ... and by at least this much (s), for cameras faster than 20 Hz.
CLOCK_JUMP_MIN_S = 0.25


class CameraClock:
    """The stamps of one camera of frame period ``period_s`` (s), frame by frame: frames newer
    than the last one let through and no further ahead of this host's clock than the tolerance.

    The offset ``arrival - stamp`` of a frame is the clocks' difference plus the frame's delay,
    and a delay is never negative: so the smallest offset seen is the clocks' difference plus the
    shortest delay, and a frame whose offset is smaller than that by more than the tolerance
    carries a stamp that ran ahead of this host's clock.
    """

    def __init__(self, period_s: float) -> None:
        self.tolerance_s = max(CLOCK_JUMP_PERIODS * float(period_s), CLOCK_JUMP_MIN_S)
        #: The stamp of the last frame let through (s), None before the first.
        self.last_stamp: float | None = None
        #: Frames refused since the last one let through (stamps not newer, or not numbers).
        self.refused = 0
        self._offset: float | None = None

    def admit(self, stamp: float, arrival: float) -> bool:
        """Whether a frame stamped ``stamp`` (s, the camera's clock) that arrived at ``arrival``
        (s, ``time.monotonic()``) is to be used; False: its stamp is not newer than the last one
        let through (a frozen or repeating clock, a reordered frame) or not a time at all.
        CameraClockError when the stamp is ahead of this host's clock, or behind the last
        frame's, by more than :attr:`tolerance_s`."""
        if not (math.isfinite(stamp) and stamp > 0.0):
            self.refused += 1
            return False
        offset = arrival - stamp
        if self._offset is not None and offset < self._offset - self.tolerance_s:
            raise CameraClockError(
                f"a camera frame is stamped {self._offset - offset:.3g} s ahead of this host's clock (a clock jump, or a "
                "second camera on the topic): zero sent"
            )
        if self.last_stamp is not None and stamp <= self.last_stamp:
            if stamp < self.last_stamp - self.tolerance_s:
                raise CameraClockError(
                    f"the camera's stamps stepped back {self.last_stamp - stamp:.3g} s (a clock reset, or a second camera "
                    "on the topic): zero sent"
                )
            self.refused += 1
            return False
        self._offset = offset if self._offset is None else min(self._offset, offset)
        self.last_stamp = stamp
        self.refused = 0
        return True
