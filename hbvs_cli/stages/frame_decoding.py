"""Taught frames decoded ahead of use, in a worker thread, with bounded memory.

Decoding is most of a recording's reading cost and OpenCV's decoder releases the GIL, so a
second thread decodes ahead (at most ``depth`` frames) while the current one is detected.
Colour is decoded only for the dot detector (a dot may differ from its wall in hue alone);
the others use luminance, which a colour JPEG decodes faster.
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable, Iterator

import numpy as np

from ..io.fit_file import FitFile
from ..io.images import decode_image
from ..io.teach_file import TeachFrame
from ..sim.scene import knows_its_world


def decode_frame(frame: TeachFrame, name: str, colour: bool = False) -> tuple[bytes, np.ndarray]:
    """The compressed bytes and the image of a teach frame's image message: gray, or BGR
    for a colour frame when ``colour`` is asked (:func:`~hbvs_cli.io.images.decode_image`)."""
    data = frame.stored_image(f"{name} frame {frame.index}").data
    return data, decode_image(data, name, colour=colour)


def decoded_frames(
    frames: Iterator[TeachFrame], name: str, depth: int = 4, colour: Callable[[], bool] = lambda: False
) -> Iterator[tuple[TeachFrame, bytes, np.ndarray]]:
    """Yield ``(frame, image_bytes, image)`` in order, decoding up to ``depth`` frames ahead.

    ``colour()`` is asked as each frame is queued: whether to keep its colour (fit keeps it
    while it picks the target, then only for dots).
    """
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="hbvs-decode") as pool:
        pending: deque[tuple[TeachFrame, Future[tuple[bytes, np.ndarray]]]] = deque()
        for frame in frames:
            pending.append((frame, pool.submit(decode_frame, frame, name, colour())))
            if len(pending) > depth:
                ready, future = pending.popleft()
                yield (ready, *future.result())
        while pending:
            ready, future = pending.popleft()
            yield (ready, *future.result())


def fit_reference_image(fit: FitFile) -> np.ndarray | None:
    """The fit's reference image, decoded when the simulation builds its world from it."""
    if fit.reference_image is None or knows_its_world(fit.model):
        return None
    return decode_image(fit.reference_image, "the fit's reference image")


def fit_template_image(fit: FitFile) -> np.ndarray | None:
    """The fit's template image, decoded for a texture target (the others have none)."""
    if fit.template_image is None or fit.model.detector.get("kind") != "texture":
        return None
    return decode_image(fit.template_image, "the fit's template image")
