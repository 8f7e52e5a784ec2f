"""Frames decoded ahead (``stages.frame_decoding.decoded_frames``): the consumer's order, the
frames' own pixels and colour, and an undecodable frame's error at its own turn, also when
the consumer decodes frames itself while the decoding thread lags."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from hbvs_cli.errors import InputError
from hbvs_cli.stages import frame_decoding


class FakeFrame:
    """What ``decode_frame`` reads of a teach frame: its index and its stored image's bytes."""

    def __init__(self, index: int, data: bytes) -> None:
        self.index = index
        self._data = data

    def stored_image(self, source: str = "") -> SimpleNamespace:
        return SimpleNamespace(data=self._data)


def colour_png(index: int) -> tuple[bytes, np.ndarray]:
    """A 24x32 colour PNG whose pixels name its frame (seeded), and its pixels (BGR)."""
    rng = np.random.default_rng(index)
    image = rng.integers(0, 256, size=(24, 32, 3), dtype=np.uint8)
    ok, encoded = cv2.imencode(".png", image)
    assert ok
    return encoded.tobytes(), image


@pytest.fixture
def slow_decoding_thread(monkeypatch: pytest.MonkeyPatch) -> list[tuple[int, str]]:
    """The decoding thread takes 20 ms a frame (the consumer none); who decoded which frame."""
    decoded_by: list[tuple[int, str]] = []
    decode = frame_decoding.decode_frame

    def slow(frame, name, colour=False):
        thread = threading.current_thread().name
        if thread.startswith("hbvs-decode"):
            time.sleep(0.02)
        decoded_by.append((frame.index, thread))
        return decode(frame, name, colour)

    monkeypatch.setattr(frame_decoding, "decode_frame", slow)
    return decoded_by


def test_frames_come_in_order_with_their_own_pixels_whoever_decodes_them(slow_decoding_thread) -> None:
    pngs = [colour_png(k) for k in range(30)]
    frames = [FakeFrame(k, data) for k, (data, _) in enumerate(pngs)]
    # Colour kept for the first ten frames queued only (as fit does while it picks the target).
    asked = iter([True] * 10 + [False] * 20)
    out = list(frame_decoding.decoded_frames(iter(frames), "teach.mcap", colour=lambda: next(asked)))
    assert [frame.index for frame, _, _ in out] == list(range(30))
    for k, (frame, data, image) in enumerate(out):
        assert data == pngs[k][0]
        gray = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
        expected = pngs[k][1] if k < 10 else gray
        assert image.shape == expected.shape and np.array_equal(image, expected)
    by_consumer = {index for index, thread in slow_decoding_thread if not thread.startswith("hbvs-decode")}
    # The decoding thread lagging, the consumer decoded frames too; none was decoded twice.
    assert len(by_consumer) >= 5, by_consumer
    assert sorted(index for index, _ in slow_decoding_thread) == list(range(30))
    assert any(k < 10 for k in by_consumer) and any(k >= 10 for k in by_consumer)


def test_an_undecodable_frame_fails_at_its_own_turn_not_before(slow_decoding_thread) -> None:
    attempted_by = set()
    for bad in (5, 6, 7, 8):
        pngs = [colour_png(k)[0] for k in range(12)]
        pngs[bad] = pngs[bad][:40]  # cut short: not an image
        frames = [FakeFrame(k, data) for k, data in enumerate(pngs)]
        seen = []
        slow_decoding_thread.clear()
        with pytest.raises(InputError, match="cannot be decoded"):
            for frame, _, _ in frame_decoding.decoded_frames(iter(frames), "teach.mcap"):
                seen.append(frame.index)
        assert seen == list(range(bad))
        attempted_by |= {thread.startswith("hbvs-decode") for index, thread in slow_decoding_thread if index == bad}
    assert attempted_by == {True, False}  # the bad frame met by the decoding thread, and by the consumer
