"""Taught frames decoded ahead of use, in a worker thread, with bounded memory.

Reading the MCAP and decoding its images are a recording's reading cost, and OpenCV's
decoder releases the GIL, so a second thread reads and decodes ahead (at most ``depth``
frames) while the current one is detected.
Colour is decoded only for the dot detector (a dot may differ from its wall in hue alone);
the others use luminance, which a colour JPEG decodes faster.
"""

from __future__ import annotations

import queue
import threading
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
    """Yield ``(frame, image_bytes, image)`` in order, read and decoded up to ``depth`` frames
    ahead in a worker thread (the caller's thread is left to detection).

    ``colour()`` is asked as each frame is read: whether to keep its colour (fit keeps it
    while it picks the target, then only for dots). An error of the reading or decoding is
    raised here, at the frame where it happened.
    """
    ready: queue.Queue[tuple[TeachFrame, bytes, np.ndarray] | BaseException | None] = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def hand_over(item: tuple[TeachFrame, bytes, np.ndarray] | BaseException | None) -> bool:
        while not stop.is_set():
            try:
                ready.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def read_ahead() -> None:
        try:
            for frame in frames:
                if not hand_over((frame, *decode_frame(frame, name, colour()))):
                    return
            hand_over(None)
        except BaseException as error:  # raised again in the caller's thread
            hand_over(error)

    worker = threading.Thread(target=read_ahead, name="hbvs-decode", daemon=True)
    worker.start()
    try:
        while (item := ready.get()) is not None:
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        worker.join(timeout=2.0)  # a worker blocked on a silent pipe must not hold the exit


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
