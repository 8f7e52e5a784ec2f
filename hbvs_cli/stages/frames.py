"""Taught frames decoded ahead of use, in a worker thread, with bounded memory.

Decoding a PNG or JPEG is most of what reading a recording costs, and OpenCV's decoder
releases the GIL: decoding the next frames in a second thread while the current one is
detected keeps both cores busy. At most ``depth`` decoded frames wait at any time.
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Iterator

import numpy as np

from ..io.images import decode_image
from ..io.teach_file import TeachFrame


def decode_frame(frame: TeachFrame, name: str) -> tuple[bytes, np.ndarray]:
    """The compressed bytes and the gray image of a teach frame's image message."""
    data = frame.stored_image(f"{name} frame {frame.index}").data
    return data, decode_image(data, name)


def decoded_frames(frames: Iterator[TeachFrame], name: str, depth: int = 4) -> Iterator[tuple[TeachFrame, bytes, np.ndarray]]:
    """Yield ``(frame, image_bytes, image)`` in order, decoding up to ``depth`` frames ahead."""
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="hbvs-decode") as pool:
        pending: deque[tuple[TeachFrame, Future[tuple[bytes, np.ndarray]]]] = deque()
        for frame in frames:
            pending.append((frame, pool.submit(decode_frame, frame, name)))
            if len(pending) > depth:
                ready, future = pending.popleft()
                yield (ready, *future.result())
        while pending:
            ready, future = pending.popleft()
            yield (ready, *future.result())
