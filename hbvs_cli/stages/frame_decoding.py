"""Taught frames decoded ahead of use in a worker thread (OpenCV's decoder releases the GIL), with bounded memory,
and what fit keeps of each (:class:`FrameLog`). Colour only for the dot detector (a dot may differ from its wall in
hue alone): luminance decodes faster."""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, Callable, Iterator

import numpy as np

from ..io.fit_file import FitFile
from ..io.images import decode_image
from ..io.teach_file import TeachFrame
from ..perception.target_kinds import TARGET_KINDS
from ..sim.scene import knows_its_world
from ..thread_pool import StopSafePool


def decode_frame(frame: TeachFrame, name: str, colour: bool = False) -> tuple[bytes, np.ndarray]:
    """The compressed bytes and the image of a teach frame: gray, or BGR for a colour frame when ``colour``."""
    data = frame.stored_image(f"{name} frame {frame.index}").data
    return data, decode_image(data, name, colour=colour)


def decoded_frames(
    frames: Iterator[TeachFrame], name: str, depth: int = 4, colour: Callable[[], bool] = lambda: False
) -> Iterator[tuple[TeachFrame, bytes, np.ndarray]]:
    """Yield ``(frame, image_bytes, image)`` in order, up to ``depth`` decoded ahead, in colour when ``colour()`` says so."""
    with StopSafePool(max_workers=1, thread_name_prefix="hbvs-decode") as pool:
        pending: deque[_Queued] = deque()
        for frame in frames:
            keep_colour = colour()
            pending.append(_Queued(frame, keep_colour, pool.submit(decode_frame, frame, name, keep_colour)))
            if len(pending) > depth:
                yield _next_decoded(pending, name)
        while pending:
            yield _next_decoded(pending, name)


@dataclass
class _Queued:
    """A frame queued for decoding: whether its colour is kept, and its decoding."""

    frame: TeachFrame
    colour: bool
    decoding: Future[tuple[bytes, np.ndarray]]


def _next_decoded(pending: deque[_Queued], name: str) -> tuple[TeachFrame, bytes, np.ndarray]:
    """The oldest queued frame, decoded. While the thread is still on it, the frame after it, if not started, is
    decoded here: a consumer quicker than decoding (a board's or a marker's detection) would wait with a core to spare."""
    oldest = pending.popleft()
    if pending and not oldest.decoding.done():
        after = pending[0]
        if after.decoding.cancel():
            decoded: Future[tuple[bytes, np.ndarray]] = Future()
            try:
                decoded.set_result(decode_frame(after.frame, name, after.colour))
            except Exception as exc:  # raised when that frame's turn comes, not before this one
                decoded.set_exception(exc)
            after.decoding = decoded
    return (oldest.frame, *oldest.decoding.result())


class FrameLog:
    """Per-frame results of fit kept in memory: a few numbers per frame in a growing numpy buffer (Python objects per frame
    would cost kilobytes over a long recording), never images."""

    def __init__(self, n_points: int) -> None:
        self._rows = np.empty(1024, dtype=[("t", float), ("log_time", np.int64), ("pixels", float, (n_points, 2)),
                                           ("pose", float, 3), ("command", float, 2)])  # log times: exact integers
        self.count = 0

    def add(self, t: float, log_time_ns: int, pixels: np.ndarray, pose: Any, command: Any) -> None:
        if self.count == len(self._rows):
            self._rows = np.concatenate([self._rows, np.empty_like(self._rows)])
        self._rows[self.count] = (t, log_time_ns, pixels, np.nan if pose is None else pose,
                                  np.nan if command is None else command)
        self.count += 1

    def arrays(self) -> dict[str, np.ndarray]:
        """Each column of the frames so far: ``t``, ``log_time``, ``pixels`` (F, N, 2), ``pose`` (F, 3), ``command`` (F, 2)."""
        return {name: self._rows[name][: self.count].copy() for name in self._rows.dtype.names}


def fit_reference_image(fit: FitFile) -> np.ndarray | None:
    """The fit's reference image, decoded when the simulation builds its world from it."""
    if fit.reference_image is None or knows_its_world(fit.model):
        return None
    return decode_image(fit.reference_image, "the fit's reference image")


def fit_template_image(fit: FitFile) -> np.ndarray | None:
    """The fit's template image, decoded for a kind that uses one (texture; the others have none)."""
    if not fit.templates or not getattr(TARGET_KINDS.get(fit.model.detector.kind), "uses_template", False):
        return None
    return decode_image(fit.templates[-1], "the fit's template image")
