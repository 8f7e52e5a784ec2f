"""Frame sources for ``hbvs teach``: video files, image folders, live cameras, ROS 2 bags.

Every source is an iterable of :class:`SourceFrame` (8-bit grayscale image plus a time
in seconds from the first frame) produced lazily, one frame at a time, so a long video
or bag never sits in memory. Each source also offers :meth:`FrameSource.describe` for
the recording's metadata and a ``camera`` attribute holding intrinsics found in the
source itself (only bags carry them, in a ``CameraInfo`` topic).

Conversion to 8 bits is the same everywhere: colour goes through ``cv2.cvtColor`` and
16-bit data keeps its high byte (a fixed scale, so the brightness of a scene does not
change from frame to frame as a per-frame stretch would).
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from ..core.camera import CameraIntrinsics
from ..errors import CalibrationError, HbvsError, InputError, RecordingError, UsageError
from .calibration import intrinsics_from_values
from .mcap_io import ChannelSummary, McapMessage, McapStream, read_summary
from .topics import CAMERA_CALIBRATION_SCHEMA, COMPRESSED_IMAGE_SCHEMA, ROS_CAMERA_INFO_SCHEMA, ROS_COMPRESSED_IMAGE_SCHEMA

__all__ = [
    "SourceFrame",
    "FrameSource",
    "VideoSource",
    "ImageFolderSource",
    "CameraSource",
    "BagSource",
    "IMAGE_EXTENSIONS",
    "to_gray8",
]

#: File extensions :class:`ImageFolderSource` picks up (compared case-insensitively).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")

_NS = 1_000_000_000


@dataclass(frozen=True)
class SourceFrame:
    """One frame from a source.

    Attributes
    ----------
    t : float
        Seconds from the first frame of the source.
    image : numpy.ndarray
        ``uint8`` grayscale image, shape ``(H, W)``.
    encoded : bytes or None
        The original compressed bytes when the source already had them (a JPEG/PNG file,
        a ``CompressedImage`` in a bag), so a recording can store them without
        re-encoding; None otherwise.
    format : str or None
        ``"jpeg"`` or ``"png"`` when ``encoded`` is set.
    """

    t: float
    image: np.ndarray
    encoded: bytes | None = None
    format: str | None = None


class FrameSource:
    """Base of the frame sources: iterate it for :class:`SourceFrame` objects.

    Attributes
    ----------
    kind : str
        Short name of the source type, as in :meth:`describe`.
    camera : CameraIntrinsics or None
        Intrinsics found in the source itself, None when it has none.
    """

    kind: str = "source"
    camera: CameraIntrinsics | None = None

    def __iter__(self) -> Iterator[SourceFrame]:  # pragma: no cover - abstract
        raise NotImplementedError

    def describe(self) -> dict[str, Any]:  # pragma: no cover - abstract
        """JSON-ready description for the recording's metadata."""
        raise NotImplementedError


# ----------------------------------------------------------------------------- helpers
def to_gray8(image: np.ndarray, what: str) -> np.ndarray:
    """A decoded frame as contiguous 8-bit gray (see :func:`hbvs_cli.perception.detector.as_gray`)."""
    from ..perception.detector import as_gray

    return as_gray(image, what)


def _sniff_format(data: bytes) -> str | None:
    """"jpeg" or "png" from the magic bytes (names and ROS format strings may lie)."""
    if data.startswith(b"\xff\xd8\xff"):
        return "jpeg"
    if data.startswith(b"\x89PNG\r\n\x1a\n"):
        return "png"
    return None


def _decode_image(data: bytes, what: str) -> np.ndarray:
    """Decode compressed image bytes to 8-bit gray, naming ``what`` on failure."""
    from .images import decode_image

    return decode_image(data, what)


def _cv_message(exc: BaseException) -> str:
    cause = exc.__cause__ if exc.__cause__ is not None else exc
    message = " ".join(str(cause).split())
    return message.split("error: ", 1)[1] if "error: " in message else message


def _natural_key(text: str) -> tuple[Any, ...]:
    """Sort key that orders embedded numbers by value: frame2 before frame10."""
    # re.split with a capturing group alternates text, number, text...: the types line up
    # position by position, so the part tuples of two names always compare; the name
    # itself breaks ties ("a01" vs "a1").
    parts = re.split(r"(\d+)", text)
    return tuple(int(p) if i % 2 else p.lower() for i, p in enumerate(parts)), text


def _check_rate(value: float | None, what: str) -> float | None:
    if value is None:
        return None
    try:
        rate = float(value)
    except (TypeError, ValueError):
        raise UsageError(f"{what} must be a number, got {value!r}") from None
    if not math.isfinite(rate) or rate <= 0:
        raise UsageError(f"{what} must be a positive number, got {value!r}")
    return rate


def _same_size(size: tuple[int, int] | None, image: np.ndarray, what: str) -> tuple[int, int]:
    """The size of the first frame; later frames of another size are refused."""
    current = (int(image.shape[1]), int(image.shape[0]))
    if size is not None and current != size:
        raise InputError(
            f"{what}: image is {current[0]}x{current[1]} but earlier frames are {size[0]}x{size[1]}; "
            "all frames must have the same size"
        )
    return current


# ----------------------------------------------------------------------------- video
class VideoSource(FrameSource):
    """Frames of a video file (anything ``cv2.VideoCapture`` reads).

    Parameters
    ----------
    path : str or path-like
        The video. URLs (``rtsp://...``) and OpenCV image-sequence patterns
        (``img_%04d.png``) are passed to OpenCV unchecked.
    fps : float, optional
        Frame rate to assume instead of the one the container declares.

    Raises
    ------
    InputError
        If the file is missing, cannot be opened, or no frame can be decoded.
    UsageError
        If ``fps`` is not a positive number.

    Notes
    -----
    ``t`` is ``index / fps`` with the ``fps`` override, else with the container's frame
    rate, else (a container without a usable rate) from ``CAP_PROP_POS_MSEC``.
    """

    kind = "video"

    def __init__(self, path: str | os.PathLike[str], fps: float | None = None) -> None:
        self.path = str(path)
        self.fps_override = _check_rate(fps, "--fps")
        self.camera = None
        passthrough = "://" in self.path or "%" in self.path
        if not passthrough:
            file = Path(path)
            if not file.exists():
                raise InputError(f"{self.path}: no such file")
            if file.is_dir():
                raise InputError(
                    f"{self.path}: is a directory, expected a video file (use an image folder source for images)"
                )
        capture = self._open()
        try:
            self._container_fps = self._property(capture, cv2.CAP_PROP_FPS)
            count = self._property(capture, cv2.CAP_PROP_FRAME_COUNT)
            self.frame_count = int(count) if count is not None else None
            ok, frame = self._read(capture)
            if not ok:
                raise InputError(f"no frames could be decoded from {self.path}")
            self.width, self.height = int(frame.shape[1]), int(frame.shape[0])
        finally:
            capture.release()

    @property
    def fps(self) -> float | None:
        """The rate used for timestamps, None when they come from the container's clock."""
        if self.fps_override is not None:
            return self.fps_override
        if self._container_fps is not None and self._container_fps < 1000.0:
            # Containers without a real rate report 0, or their time base (e.g. 90000).
            return self._container_fps
        return None

    def _open(self) -> Any:
        try:
            capture = cv2.VideoCapture(self.path)
        except (cv2.error, SystemError) as exc:
            raise InputError(f"{self.path}: cannot open the video ({_cv_message(exc)})") from None
        if not capture.isOpened():
            capture.release()
            raise InputError(
                f"{self.path}: cannot open the video (not a video, or a codec this OpenCV build lacks)"
            )
        return capture

    def _read(self, capture: Any) -> tuple[bool, np.ndarray | None]:
        try:
            ok, frame = capture.read()
        except (cv2.error, SystemError) as exc:
            raise InputError(f"{self.path}: error while decoding the video ({_cv_message(exc)})") from None
        if not ok or frame is None or frame.size == 0:
            return False, None
        return True, frame

    @staticmethod
    def _property(capture: Any, prop: int) -> float | None:
        value = capture.get(prop)
        return float(value) if value is not None and math.isfinite(value) and value > 0 else None

    def __iter__(self) -> Iterator[SourceFrame]:
        capture = self._open()
        try:
            fps = self.fps
            first_msec: float | None = None
            index = 0
            while True:
                ok, frame = self._read(capture)
                if not ok:
                    break
                if fps is not None:
                    t = index / fps
                else:
                    msec = float(capture.get(cv2.CAP_PROP_POS_MSEC))
                    first_msec = msec if first_msec is None else first_msec
                    t = (msec - first_msec) / 1000.0
                yield SourceFrame(t=t, image=to_gray8(frame, f"{self.path} frame {index}"))
                index += 1
            if index == 0:
                raise InputError(f"no frames could be decoded from {self.path}")
        finally:
            capture.release()

    def describe(self) -> dict[str, Any]:
        """Kind, path, frame count (the container's estimate), fps and image size."""
        return {
            "kind": self.kind,
            "path": self.path,
            "frame_count": self.frame_count,
            "fps": self.fps,
            "width": self.width,
            "height": self.height,
            "timestamps": "fps override" if self.fps_override is not None
            else "frame rate" if self.fps is not None else "container clock",
        }


# ----------------------------------------------------------------------------- images
class ImageFolderSource(FrameSource):
    """Image files from a folder or a glob pattern, in natural order, at a fixed rate.

    Parameters
    ----------
    dir_or_glob : str or path-like
        A folder (every ``.png .jpg .jpeg .bmp .tif .tiff`` file in it, not recursive),
        a glob pattern such as ``"run1/*.jpg"`` (``**`` recurses), or a single image.
    fps : float
        The frame rate: frame ``i`` has ``t = i / fps``.

    Raises
    ------
    InputError
        If the folder does not exist, or no image file is found. An image that cannot be
        read raises InputError naming it when iteration reaches it.
    UsageError
        If ``fps`` is not a positive number.
    """

    kind = "images"

    def __init__(self, dir_or_glob: str | os.PathLike[str], fps: float) -> None:
        self.path = str(dir_or_glob)
        rate = _check_rate(fps, "--fps")
        if rate is None:
            raise UsageError("an image folder needs a frame rate (--fps)")
        self.fps = rate
        self.camera = None
        self.files = self._find(self.path)

    @staticmethod
    def _find(spec: str) -> list[Path]:
        def wanted(p: Path) -> bool:
            return p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()

        path = Path(spec)
        extensions = " ".join(IMAGE_EXTENSIONS)
        if path.is_dir():
            try:
                files = [p for p in path.iterdir() if wanted(p)]
            except OSError as exc:
                raise InputError(f"{spec}: cannot list the folder ({exc.strerror or exc})") from None
            if not files:
                raise InputError(f"{spec}: no images ({extensions}) in this folder")
            return sorted(files, key=lambda p: _natural_key(p.name))
        if any(c in spec for c in "*?["):
            import glob

            files = [Path(p) for p in glob.glob(spec, recursive=True) if wanted(Path(p))]
            if not files:
                raise InputError(f"{spec}: no image files ({extensions}) match this pattern")
            return sorted(files, key=lambda p: _natural_key(str(p)))
        if path.is_file():
            if path.suffix.lower() not in IMAGE_EXTENSIONS:
                raise InputError(f"{spec}: not an image file ({extensions}); expected a folder or a glob")
            return [path]
        raise InputError(f"{spec}: no such folder")

    def __iter__(self) -> Iterator[SourceFrame]:
        size: tuple[int, int] | None = None
        for index, file in enumerate(self.files):
            try:
                data = file.read_bytes()
            except OSError as exc:
                raise InputError(f"{file}: cannot read the image ({exc.strerror or exc})") from None
            image = _decode_image(data, str(file))
            size = _same_size(size, image, str(file))
            fmt = _sniff_format(data)
            yield SourceFrame(t=index / self.fps, image=image, encoded=data if fmt else None, format=fmt)

    def describe(self) -> dict[str, Any]:
        """Kind, path, frame count, fps and the first and last file."""
        return {
            "kind": self.kind,
            "path": self.path,
            "frame_count": len(self.files),
            "fps": self.fps,
            "first": str(self.files[0]),
            "last": str(self.files[-1]),
        }


# ----------------------------------------------------------------------------- camera
class CameraSource(FrameSource):
    """A live camera, timestamped with ``clock`` from the first frame.

    The device is opened by the constructor (so a missing camera is reported before
    anything is recorded) and released when iteration ends, when the consumer stops
    iterating (``close()`` on the generator, e.g. on Ctrl-C), or by :meth:`close`.

    Parameters
    ----------
    index : int or str
        The device index (``0``) or a device path/URL for OpenCV.
    duration : float, optional
        Stop once a frame arrives ``duration`` seconds or more after the first one
        (that frame is not yielded). None: until the consumer stops.
    capture_factory : callable
        ``capture_factory(index)`` returns an object with ``isOpened()``, ``read()``,
        ``get(prop)`` and ``release()``, like ``cv2.VideoCapture``; injectable for tests.
    clock : callable
        Monotonic seconds; injectable for tests.
    max_failed_reads : int
        Consecutive failed reads tolerated (cameras drop the odd frame, some fail the
        first reads while starting) before giving up.

    Raises
    ------
    InputError
        If the device cannot be opened; during iteration, if it delivers no frame or
        stops delivering frames.
    UsageError
        If ``duration`` is not a positive number.
    """

    kind = "camera"

    def __init__(
        self,
        index: int | str,
        duration: float | None = None,
        capture_factory: Callable[[Any], Any] = cv2.VideoCapture,
        clock: Callable[[], float] = time.monotonic,
        max_failed_reads: int = 5,
    ) -> None:
        self.index = index
        self.duration = _check_rate(duration, "--duration")
        self.camera = None
        self._factory = capture_factory
        self._clock = clock
        self.max_failed_reads = int(max_failed_reads)
        self._capture: Any = self._open()
        self.fps = self._property(self._capture, cv2.CAP_PROP_FPS)
        width = self._property(self._capture, cv2.CAP_PROP_FRAME_WIDTH)
        height = self._property(self._capture, cv2.CAP_PROP_FRAME_HEIGHT)
        self.width = int(width) if width else None
        self.height = int(height) if height else None

    def _open(self) -> Any:
        try:
            capture = self._factory(self.index)
        except (cv2.error, SystemError, OSError) as exc:
            raise InputError(f"camera {self.index}: cannot open the device ({_cv_message(exc)})") from None
        if capture is None or not capture.isOpened():
            if capture is not None:
                capture.release()
            raise InputError(
                f"camera {self.index}: cannot open the device (is it connected and not in use by another program?)"
            )
        return capture

    @staticmethod
    def _property(capture: Any, prop: int) -> float | None:
        get = getattr(capture, "get", None)
        if get is None:
            return None
        try:
            value = float(get(prop))
        except (cv2.error, SystemError, TypeError, ValueError):
            return None
        return value if math.isfinite(value) and value > 0 else None

    def close(self) -> None:
        """Release the device if it is still held (it is after construction)."""
        if self._capture is not None:
            self._capture.release()
            self._capture = None

    def __enter__(self) -> CameraSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __iter__(self) -> Iterator[SourceFrame]:
        # Take over the capture opened by the constructor; a second iteration reopens.
        capture = self._capture if self._capture is not None else self._open()
        self._capture = None
        try:
            first: float | None = None
            count = 0
            failures = 0
            while True:
                try:
                    ok, frame = capture.read()
                except (cv2.error, SystemError) as exc:
                    raise InputError(f"camera {self.index}: read failed ({_cv_message(exc)})") from None
                now = float(self._clock())
                if not ok or frame is None or getattr(frame, "size", 0) == 0:
                    failures += 1
                    if failures > self.max_failed_reads:
                        if count == 0:
                            raise InputError(f"camera {self.index}: the device opened but delivered no frames")
                        raise InputError(f"camera {self.index}: stopped delivering frames after {count} frames")
                    continue
                failures = 0
                if first is None:
                    first = now
                t = now - first
                if self.duration is not None and t >= self.duration:
                    return
                yield SourceFrame(t=t, image=to_gray8(np.asarray(frame), f"camera {self.index}"))
                count += 1
        finally:
            capture.release()

    def describe(self) -> dict[str, Any]:
        """Kind, device, fps reported by the driver, requested duration, image size."""
        return {
            "kind": self.kind,
            "path": None,
            "device": self.index,
            "frame_count": None,
            "fps": self.fps,
            "duration": self.duration,
            "width": self.width,
            "height": self.height,
        }


# ----------------------------------------------------------------------------- ROS 2 bag
_COMPRESSED = ROS_COMPRESSED_IMAGE_SCHEMA
_RAW = "sensor_msgs/msg/Image"
_CAMERA_INFO = ROS_CAMERA_INFO_SCHEMA
_IMAGE_TYPES = (_COMPRESSED, _RAW)
#: Foxglove's image and calibration schemas (hbvs's own files, Foxglove recordings), read
#: in the protobuf and JSON encodings.
_FOXGLOVE_IMAGE = COMPRESSED_IMAGE_SCHEMA
_FOXGLOVE_CALIBRATION = CAMERA_CALIBRATION_SCHEMA
_FOXGLOVE_ENCODINGS = ("protobuf", "json")


def _is_image_topic(topic: _Topic) -> bool:
    if topic.type == _FOXGLOVE_IMAGE:
        return topic.encoding in _FOXGLOVE_ENCODINGS
    return topic.type in _IMAGE_TYPES and topic.encoding == "cdr"


def _is_calibration_topic(topic: _Topic) -> bool:
    if topic.type == _FOXGLOVE_CALIBRATION:
        return topic.encoding in _FOXGLOVE_ENCODINGS
    return topic.type == _CAMERA_INFO
_MCAP_MAGIC = b"\x89MCAP0\r\n"
#: Bytes per pixel of the raw encodings hbvs converts.
_RAW_ENCODINGS = {"mono8": 1, "mono16": 2, "rgb8": 3, "bgr8": 3}


def _ros2_type(name: str) -> str:
    """``pkg/Type`` (ROS 1 style, as some converters write) to ``pkg/msg/Type``."""
    parts = name.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else name


@dataclass
class _Topic:
    name: str
    type: str
    encoding: str
    count: int | None


#: Largest ROS 2 message definition parsed (CameraInfo with its dependencies is ~10 KB).
_MAX_SCHEMA_BYTES = 1 << 20
#: Largest CameraInfo message decoded: a real one is under 1 KB, and CDR arrays decode
#: element by element in Python, so a huge one would take seconds for nothing.
_MAX_CAMERA_INFO_BYTES = 1 << 16


@contextlib.contextmanager
def _bag_errors(name: str) -> Iterator[None]:
    """Turn what the MCAP reader or the CDR decoder raises on a damaged file into one
    InputError that says so."""
    try:
        yield
    except RecordingError as exc:
        detail = str(exc).removeprefix(f"{name}: ")
        raise InputError(f"{name}: cannot read the bag, the MCAP file is damaged or truncated ({detail})") from None
    except HbvsError:
        raise
    except Exception as exc:
        detail = " ".join(str(exc).split())
        kind = type(exc).__name__
        detail = kind if not detail or detail == kind else f"{kind}: {detail[:200]}"
        raise InputError(f"{name}: cannot read the bag, the MCAP file is damaged or truncated ({detail})") from exc


def _require_complete(stream: McapStream, name: str) -> None:
    """A bag file that ends early or turns unreadable is refused, as a damaged input
    (raised as a RecordingError, which :func:`_bag_errors` words for bags)."""
    if stream.truncated:
        raise RecordingError(f"{name}: {stream.stop_reason}")


class _Ros2Decoders:
    """CDR decoders from mcap-ros2-support, one per distinct schema, built on first use."""

    def __init__(self) -> None:
        from mcap_ros2.decoder import DecoderFactory

        self._factory = DecoderFactory()
        self._decoders: dict[tuple[str, str, str, bytes], Callable[[bytes], Any]] = {}

    def decode(self, message: McapMessage, what: str) -> Any:
        key = (message.message_encoding, message.schema_name, message.schema_encoding, message.schema_data)
        decoder = self._decoders.get(key)
        if decoder is None:
            from mcap.records import Schema

            if len(message.schema_data) > _MAX_SCHEMA_BYTES:
                raise InputError(f"{what}: its message definition is {len(message.schema_data)} bytes, more than hbvs parses")
            # The factory caches decoders by schema id: every distinct schema gets its own.
            schema = Schema(
                id=len(self._decoders) + 1, name=message.schema_name,
                encoding=message.schema_encoding, data=message.schema_data,
            )
            # The vendored ROS parser prints its own complaint about a bad definition on
            # stderr before raising; the exception says it already, in hbvs's one line.
            with contextlib.redirect_stderr(io.StringIO()):
                decoder = self._factory.decoder_for(message.message_encoding, schema)
            if decoder is None:
                raise InputError(
                    f"{what}: encoded as {message.message_encoding!r} with a {message.schema_encoding!r} schema; "
                    "hbvs decodes ROS 2 messages (cdr with ros2msg schemas)"
                )
            self._decoders[key] = decoder
        return decoder(message.data)


class BagSource(FrameSource):
    """Images from a ROS 2 bag in MCAP storage, decoded with mcap-ros2-support.

    Parameters
    ----------
    path : str or path-like
        A bag folder (``metadata.yaml`` and its ``.mcap`` files, read in the order
        metadata.yaml lists them), its ``metadata.yaml``, or a single ``.mcap`` file.
    topic : str, optional
        The image topic (``sensor_msgs/msg/Image`` or ``sensor_msgs/msg/CompressedImage``).
        None picks the only image topic that has messages.

    Attributes
    ----------
    topic : str
        The image topic read.
    camera : CameraIntrinsics or None
        From the first message of the ``sensor_msgs/msg/CameraInfo`` topic that belongs
        to the image topic (the one in the same namespace, or the only one). None when
        there is none, or when it is unusable, with the reason in ``camera_problem``.
    camera_problem : str or None
        Why a CameraInfo topic present in the bag gave no intrinsics (all-zero K of an
        uncalibrated driver, invalid values, binning/ROI). Not an error: the user may
        give a calibration file instead.

    Raises
    ------
    InputError
        If the path is not an MCAP bag, the file is damaged, there is no image topic, or
        several and ``topic`` is None, or ``topic`` is not an image topic of the bag.
        During iteration: an image that cannot be decoded, an unsupported raw encoding,
        frames that change size, a topic without messages.

    Notes
    -----
    ``t`` comes from ``header.stamp`` relative to the first frame; a frame with a zero
    stamp (drivers that do not fill it) falls back to the message log time. Frames are
    yielded in the order the bag stores them (the order rosbag2 received them), so a
    driver whose stamps go backwards gives a ``t`` that does too.

    Files are read through :class:`~hbvs_cli.io.mcap_io.McapStream` (and
    :func:`~hbvs_cli.io.mcap_io.read_summary` for the topic list), with its caps on record,
    chunk and declaration sizes; message definitions above 1 MiB and CameraInfo messages
    above 64 KiB are not decoded. A bag file cut short is refused rather than read in part.
    """

    kind = "ros2_bag"

    def __init__(self, path: str | os.PathLike[str], topic: str | None = None) -> None:
        self.path = str(path)
        self.files = _bag_files(Path(path), self.path)
        self._decoders = _Ros2Decoders()
        topics = self._scan()
        self.topic, self._topic = self._choose(topics, topic)
        self.camera = None
        self.camera_problem: str | None = None
        self.camera_info_topic = self._camera_info_topic(topics)
        if self.camera_info_topic is not None:
            self.camera, self.camera_problem = self._read_camera_info(self.camera_info_topic)

    # -- discovery
    def _scan(self) -> dict[str, _Topic]:
        """Topics of every file, from the summary section (or one streaming pass without)."""
        topics: dict[str, _Topic] = {}

        def add(name: str, type_name: str, encoding: str, count: int | None) -> None:
            known = topics.get(name)
            if known is None:
                topics[name] = _Topic(name, type_name, encoding, count)
            elif known.count is not None and count is not None:
                known.count += count
            else:
                known.count = None

        for file in self.files:
            with _bag_errors(str(file)):
                listed = read_summary(file, str(file))
                if listed is None:
                    listed = self._stream_channels(file)
            for channel in listed:
                add(channel.topic, _ros2_type(channel.schema_name), channel.message_encoding, channel.message_count)
        return topics

    @staticmethod
    def _stream_channels(file: Path) -> list[ChannelSummary]:
        """Channels and message counts from one pass over a file without a summary (a
        recorder killed before writing it); messages are counted, not kept."""
        stream = McapStream(file, name=str(file))
        counts: dict[tuple[str, str, str, str], int] = {}
        for message in stream:
            key = (message.topic, message.schema_name, message.schema_encoding, message.message_encoding)
            counts[key] = counts.get(key, 0) + 1
        _require_complete(stream, str(file))
        return [ChannelSummary(*key, message_count=count) for key, count in counts.items()]

    def _choose(self, topics: dict[str, _Topic], topic: str | None) -> tuple[str, _Topic]:
        images = sorted((t for t in topics.values() if _is_image_topic(t)), key=lambda t: t.name)
        if topic is not None:
            chosen = topics.get(topic)
            if chosen is None:
                listed = ", ".join(t.name for t in images) or "none"
                raise InputError(f"{self.path}: no topic {topic!r} in the bag (image topics: {listed})")
            if chosen.type not in (*_IMAGE_TYPES, _FOXGLOVE_IMAGE):
                raise InputError(
                    f"{self.path}: topic {topic} carries {chosen.type or 'an unknown type'}, "
                    "not sensor_msgs/msg/Image, sensor_msgs/msg/CompressedImage or foxglove.CompressedImage"
                )
            if not _is_image_topic(chosen):
                expected = "protobuf or json" if chosen.type == _FOXGLOVE_IMAGE else "cdr"
                raise InputError(f"{self.path}: topic {topic} is encoded as {chosen.encoding!r}, expected {expected}")
            return topic, chosen
        # Recorders create channels for subscribed topics that never published: skip them.
        candidates = [t for t in images if t.count is None or t.count > 0] or images
        if not candidates:
            raise InputError(f"no image topic in {self.path}")
        if len(candidates) > 1:
            listed = ", ".join(f"{t.name} ({t.type.rsplit('/', 1)[-1]})" for t in candidates)
            raise InputError(f"{self.path}: several image topics: {listed}; choose one with --topic")
        return candidates[0].name, candidates[0]

    def _camera_info_topic(self, topics: dict[str, _Topic]) -> str | None:
        infos = sorted(t.name for t in topics.values() if _is_calibration_topic(t) and t.count != 0)
        if len(infos) <= 1:
            return infos[0] if infos else None

        # Several cameras: take the CameraInfo whose namespace is the longest prefix of
        # the image topic (/front/camera_info for /front/image_raw/compressed).
        def shared(info: str) -> int:
            namespace = info.rsplit("/", 1)[0] + "/"
            return len(namespace) if self.topic.startswith(namespace) else -1

        best = max(infos, key=shared)
        return best if shared(best) > 0 else None

    def _read_camera_info(self, topic: str) -> tuple[CameraIntrinsics | None, str | None]:
        """The first CameraInfo message, reading only up to it."""
        source = f"{self.path} {topic}"
        for file in self.files:
            stream = McapStream(file, topics={topic}, name=str(file))
            messages = iter(stream)
            with _bag_errors(str(file)):
                try:
                    first = next(messages, None)
                finally:
                    messages.close()
                if first is None:
                    _require_complete(stream, str(file))
                    continue
                if len(first.data) > _MAX_CAMERA_INFO_BYTES:
                    return None, f"{source}: a CameraInfo message of {len(first.data)} bytes is not one hbvs can use"
                if first.schema_name == _FOXGLOVE_CALIBRATION:
                    return _camera_from_foxglove(first, source)
                info = self._decoders.decode(first, source)
            try:
                return self._camera_from_info(info, source)
            except (AttributeError, TypeError, ValueError, OverflowError) as exc:
                return None, f"{source}: malformed CameraInfo ({exc})"
        return None, f"{source}: the topic has no messages"

    @staticmethod
    def _camera_from_info(info: Any, source: str) -> tuple[CameraIntrinsics | None, str | None]:
        k = [float(v) for v in info.k]
        if not any(k):
            return None, f"{source}: K is all zeros (the driver publishes an uncalibrated CameraInfo)"
        if int(getattr(info, "binning_x", 0)) > 1 or int(getattr(info, "binning_y", 0)) > 1:
            return None, f"{source}: binning is not supported; give a calibration for the binned images"
        roi = getattr(info, "roi", None)
        if roi is not None and int(getattr(roi, "width", 0)) > 0:
            return None, (
                f"{source}: a region of interest is not supported; give a calibration for the cropped images"
            )
        try:
            camera = intrinsics_from_values(k, info.width, info.height, info.distortion_model, list(info.d), source)
        except CalibrationError as exc:
            return None, str(exc)
        return camera, None

    # -- frames
    def __iter__(self) -> Iterator[SourceFrame]:
        first_ns: int | None = None
        use_stamp = True
        stamp_minus_log = 0
        size: tuple[int, int] | None = None
        index = 0
        for file in self.files:
            stream = McapStream(file, topics={self.topic}, name=str(file))
            with _bag_errors(str(file)):
                for message in stream:
                    what = f"{self.path} {self.topic} message {index}"
                    if self._topic.type == _FOXGLOVE_IMAGE:
                        image, encoded, fmt, stamp_ns = _foxglove_frame(message, what)
                    else:
                        decoded = self._decoders.decode(message, what)
                        image, encoded, fmt = self._convert(decoded, what)
                        stamp = getattr(decoded, "header", None)
                        stamp_ns = (int(stamp.stamp.sec) * _NS + int(stamp.stamp.nanosec)) if stamp is not None else 0
                    size = _same_size(size, image, what)
                    if first_ns is None:
                        use_stamp = stamp_ns != 0
                        stamp_minus_log = stamp_ns - message.log_time if use_stamp else 0
                        first_ns = stamp_ns if use_stamp else message.log_time
                    if use_stamp and stamp_ns != 0:
                        ns = stamp_ns
                    else:
                        # Same clock as the first frame: shift the log time onto the stamps.
                        ns = message.log_time + stamp_minus_log
                    yield SourceFrame(t=(ns - first_ns) / _NS, image=image, encoded=encoded, format=fmt)
                    index += 1
                _require_complete(stream, str(file))
        if index == 0:
            raise InputError(f"{self.path}: topic {self.topic} has no messages")

    def _convert(self, msg: Any, what: str) -> tuple[np.ndarray, bytes | None, str | None]:
        if self._topic.type == _COMPRESSED:
            data = msg.data if isinstance(msg.data, bytes) else bytes(msg.data)
            image = _decode_image(data, f"{what} (format {msg.format!r})")
            fmt = _sniff_format(data)
            return image, (data if fmt else None), fmt
        return _raw_to_gray8(msg, what), None, None

    def describe(self) -> dict[str, Any]:
        """Kind, path, topic, message type, frame count, CameraInfo topic and problem."""
        return {
            "kind": self.kind,
            "path": self.path,
            "files": [str(f) for f in self.files],
            "topic": self.topic,
            "message_type": self._topic.type,
            "frame_count": self._topic.count,
            "fps": None,
            "camera_info_topic": self.camera_info_topic,
            "camera_info_problem": self.camera_problem,
        }


def _foxglove_frame(message: McapMessage, what: str) -> tuple[np.ndarray, bytes | None, str | None, int]:
    """Image, its bytes, their format and the stamp (ns) of a ``foxglove.CompressedImage``."""
    from .images import read_compressed_image

    stored = read_compressed_image(message.message_encoding, message.data, what)
    image = _decode_image(stored.data, f"{what} (format {stored.format!r})")
    fmt = _sniff_format(stored.data)
    return image, (stored.data if fmt else None), fmt, stored.stamp_ns


def _camera_from_foxglove(message: McapMessage, source: str) -> tuple[CameraIntrinsics | None, str | None]:
    """Intrinsics of a ``foxglove.CameraCalibration`` (JSON or protobuf), or why there are none."""
    from .calibration import calibration_from_foxglove
    from .mcap_io import decode_json

    if message.message_encoding == "json":
        fields = decode_json(message.data, source)
    else:
        from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
        from google.protobuf.message import DecodeError

        try:
            calibration = CameraCalibration.FromString(message.data)
        except (DecodeError, ValueError, RuntimeError):
            return None, f"{source}: malformed foxglove.CameraCalibration"
        fields = {
            "width": calibration.width, "height": calibration.height, "distortion_model": calibration.distortion_model,
            "D": list(calibration.D), "K": list(calibration.K), "R": list(calibration.R), "P": list(calibration.P),
        }
    if isinstance(fields, dict) and not any(fields.get("K") or []):
        return None, f"{source}: K is all zeros (an uncalibrated camera)"
    try:
        return calibration_from_foxglove(fields, source), None
    except CalibrationError as exc:
        return None, str(exc)


def _raw_to_gray8(msg: Any, what: str) -> np.ndarray:
    """A ``sensor_msgs/msg/Image`` (mono8, mono16, rgb8, bgr8) as 8-bit gray."""
    encoding = str(msg.encoding)
    bpp = _RAW_ENCODINGS.get(encoding.lower())
    if bpp is None:
        raise InputError(
            f"{what}: unsupported image encoding {encoding!r} (hbvs reads mono8, mono16, rgb8, bgr8)"
        )
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height <= 0 or width <= 0:
        raise InputError(f"{what}: empty image ({width}x{height})")
    if step < width * bpp:
        raise InputError(f"{what}: step {step} is shorter than a row of {width} {encoding} pixels")
    data = np.frombuffer(msg.data if isinstance(msg.data, bytes) else bytes(msg.data), dtype=np.uint8)
    if data.size < step * height:
        raise InputError(f"{what}: {data.size} bytes of data, expected {step * height} ({height} rows of {step})")
    # Rows may be padded to `step` bytes: drop the padding before reinterpreting.
    rows = np.ascontiguousarray(data[: step * height].reshape(height, step)[:, : width * bpp])
    kind = encoding.lower()
    if kind == "mono8":
        return rows.copy()
    if kind == "mono16":
        values = rows.view(">u2" if msg.is_bigendian else "<u2").reshape(height, width)
        return (values >> 8).astype(np.uint8)
    pixels = rows.reshape(height, width, 3)
    return cv2.cvtColor(pixels, cv2.COLOR_RGB2GRAY if kind == "rgb8" else cv2.COLOR_BGR2GRAY)


def _bag_files(path: Path, name: str) -> list[Path]:
    """The .mcap files of a bag folder (metadata.yaml order), or the one file given."""
    if path.name == "metadata.yaml" and path.is_file():
        path = path.parent
    if path.is_dir():
        try:
            found = [p for p in path.iterdir() if p.suffix == ".mcap" and p.is_file()]
            has_sqlite = any(p.suffix == ".db3" for p in path.iterdir())
        except OSError as exc:
            raise InputError(f"{name}: cannot list the folder ({exc.strerror or exc})") from None
        if not found:
            if has_sqlite:
                raise InputError(
                    f"{name}: this ROS 2 bag uses SQLite storage (.db3); hbvs reads MCAP bags "
                    "(convert it with `ros2 bag convert`)"
                )
            raise InputError(f"{name}: no .mcap file in this folder; expected a ROS 2 bag in MCAP storage")
        ordered = _metadata_order(path, found)
        return ordered if ordered is not None else sorted(found, key=lambda p: _natural_key(p.name))
    if not path.exists():
        raise InputError(f"{name}: no such file or directory")
    try:
        with path.open("rb") as stream:
            magic = stream.read(len(_MCAP_MAGIC))
    except OSError as exc:
        raise InputError(f"{name}: cannot read the file ({exc.strerror or exc})") from None
    if magic != _MCAP_MAGIC:
        raise InputError(f"{name}: not an MCAP file (expected a ROS 2 bag folder or its .mcap file)")
    return [path]


def _metadata_order(folder: Path, found: Sequence[Path]) -> list[Path] | None:
    """The files in metadata.yaml's ``relative_file_paths`` order, None if unusable.

    The metadata is only a hint for the order of split bags: anything odd about it
    (missing, huge, malformed, naming other files) falls back to natural order.
    """
    metadata = folder / "metadata.yaml"
    try:
        if not metadata.is_file() or metadata.stat().st_size > 1 << 20:
            return None
        document = yaml.safe_load(metadata.read_text(encoding="utf-8"))
        listed = document["rosbag2_bagfile_information"]["relative_file_paths"]
        ordered = [folder / Path(str(p)).name for p in listed]
    except (OSError, UnicodeDecodeError, yaml.YAMLError, RecursionError, KeyError, TypeError, ValueError):
        return None
    if sorted(ordered) != sorted(found):
        return None
    return ordered
