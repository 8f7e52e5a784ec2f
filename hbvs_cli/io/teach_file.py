"""The teach recording: what ``hbvs teach`` writes and ``hbvs fit`` / ``repeat --replay`` read (docs/files.md).
A frame's command and true pose are written just before its image, with its log time, so a streaming reader has them."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Iterator

from .. import __version__
from ..core.camera import CameraIntrinsics, camera_from_description
from ..errors import HbvsError, RecordingError
from .calibration import calibration_from_foxglove, calibration_to_foxglove, intrinsics_from_values, stated_sigma
from .foxglove_scene import SceneWriter
from .images import StoredImage, read_compressed_image, write_compressed_image
from .mcap import McapStream, McapWriter, read_metadata, time_message
from .messages import CAMERA_FRAME, planar_pose_from_message, pose_message, velocity_from_message, velocity_message
from .topics import CALIBRATION_METADATA, CALIBRATION_TOPIC, IMAGE_TOPIC, TOPICS, WORLD_METADATA
from .topics import TEACH_COMMAND_TOPIC as COMMAND_TOPIC
from .topics import TRUE_POSE_TOPIC as POSE_TOPIC

FILE_KIND = "teach"

#: The settings of a simulated teach that repeat reuses to render the same sensor.
RENDER_SETTINGS = ("noise", "blur", "exposure", "noise_grain")

#: What a malformed description can raise while it is parsed (outside HbvsError).
PARSE_ERRORS = (LookupError, TypeError, ValueError, AttributeError, ArithmeticError)


def world_description(data: Any, source: str) -> dict[str, Any]:
    """A recorded world description with what io uses of it checked (the camera as a calibration,
    a finite camera height); :class:`RecordingError` otherwise. The simulator checks the rest."""
    try:
        camera = camera_from_description(data["camera"])
    except HbvsError as exc:
        raise RecordingError(f"{source}: malformed world description: {exc}") from None
    except PARSE_ERRORS as exc:
        raise RecordingError(f"{source}: malformed world description ({exc})") from None
    try:
        intrinsics_from_values(camera.K, camera.width, camera.height, camera.distortion_model, camera.distortion, "camera")
    except HbvsError as exc:
        raise RecordingError(f"{source}: the world's {exc}") from None
    height = data.get("camera_height_m")
    if isinstance(height, bool) or not isinstance(height, (int, float)) or not math.isfinite(height):
        raise RecordingError(f"{source}: malformed world description (the camera height is not finite)")
    return data


def _stated_sigma(sigma: Any, source: str) -> tuple[float, ...]:
    """A recorded calibration's standard deviations (:data:`CALIBRATION_METADATA`), () when none."""
    try:
        return stated_sigma({"std_deviations_intrinsics": sigma}, f"{source}: {CALIBRATION_METADATA} metadata") if sigma is not None else ()
    except HbvsError as exc:
        raise RecordingError(str(exc)) from None


def render_settings_problem(settings: Any) -> str | None:
    """Why recorded sensor settings (:data:`RENDER_SETTINGS`) are unusable, or None when fine."""
    if not isinstance(settings, dict):
        return "the settings are not a mapping"
    for key in RENDER_SETTINGS:
        value = settings.get(key)  # None: not recorded
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value < math.inf):
            return f"the setting {key} = {str(value)[:40]!r} is not a finite non-negative number"
    if settings.get("exposure") == 0:
        return "the exposure setting is zero"
    return None


class TeachWriter:
    """Writes a teach recording; a simulated teach hands its world (recorded, and drawn on ``/scene``)."""

    def __init__(
        self, writer: McapWriter, source: str, settings: dict[str, Any], world: Any = None, frame_id: str | None = None,
    ) -> None:
        self.writer = writer
        #: The camera's frame of reference: a bag's own frame_id, else hbvs's camera frame.
        self.frame_id = frame_id or CAMERA_FRAME
        writer.metadata("hbvs", {"file_kind": FILE_KIND, "hbvs_version": __version__, "source": source, "settings": settings})
        if world is not None:
            writer.metadata(WORLD_METADATA, {"world": world.to_dict()})
        self.world = world
        self.scene = SceneWriter(writer)

    def calibration(self, camera: CameraIntrinsics, log_time_ns: int = 0) -> None:
        """The camera's calibration, and before it the standard deviations it states (if any)."""
        if camera.sigma:
            self.writer.metadata(CALIBRATION_METADATA, {"sigma": list(camera.sigma)})
        self.writer.write(
            CALIBRATION_TOPIC, TOPICS[FILE_KIND][CALIBRATION_TOPIC], log_time_ns,
            calibration_to_foxglove(camera, self.frame_id, log_time_ns),
        )

    def frame(
        self, log_time_ns: int, image_bytes: bytes, image_format: str, pose: tuple[float, float, float] | None = None,
        camera_height: float = 0.0, command: tuple[float, float] | None = None,
    ) -> None:
        """One frame: its command and true pose (when known), then the image."""
        if command is not None:
            message = velocity_message(time_message(log_time_ns), *command)
            self.writer.write(COMMAND_TOPIC, TOPICS[FILE_KIND][COMMAND_TOPIC], log_time_ns, message)
        if pose is not None:
            self.writer.write(POSE_TOPIC, TOPICS[FILE_KIND][POSE_TOPIC], log_time_ns, pose_message(log_time_ns, pose, camera_height))
            if not self.scene.started:
                self.scene.start(log_time_ns, camera_height, self.world)
            self.scene.pose(log_time_ns, pose)
        write_compressed_image(self.writer, IMAGE_TOPIC, log_time_ns, image_bytes, image_format, self.frame_id)


@dataclass(frozen=True)
class TeachFrame:
    """One frame of a teach recording: ``t`` (s) since the first, the stored ``foxglove.CompressedImage``,
    the true ``pose`` (x, y, phi) and taught ``command`` (v, w) when known."""

    index: int
    log_time_ns: int
    t: float
    image_message: bytes
    pose: tuple[float, float, float] | None
    command: tuple[float, float] | None

    def stored_image(self, source: str = "") -> StoredImage:
        """The compressed image bytes and format of this frame."""
        return read_compressed_image(self.image_message, source)


@dataclass
class TeachReader:
    """Streams the frames of a teach recording (a file or ``-``) in constant memory; ``camera``,
    ``world_description`` and ``info`` are filled as their records arrive."""

    source: Any
    name: str = ""
    camera: CameraIntrinsics | None = None
    #: The simulated world's description (:func:`world_description`), None for real footage.
    world_description: dict[str, Any] | None = None
    info: dict[str, Any] = field(default_factory=dict)
    stream: McapStream | None = None

    def __post_init__(self) -> None:
        self.stream = McapStream(self.source, schemas=TOPICS[FILE_KIND], name=self.name)
        self.name = self.stream.name

    def _check_kind(self) -> None:
        if self.info or not (info := read_metadata(self.stream, "hbvs")):
            return
        kind = info.get("file_kind")
        if kind != FILE_KIND:
            what = f"a {kind!r} file" if isinstance(kind, str) else "a file whose hbvs metadata names no file kind"
            raise RecordingError(f"{self.name}: this is {what}; a teach recording (from hbvs teach) is expected")
        settings = info.get("settings")
        problem = None if settings is None else render_settings_problem(settings)
        if problem is not None:
            raise RecordingError(f"{self.name}: malformed hbvs metadata: {problem}")
        self.info = info
        world = read_metadata(self.stream, WORLD_METADATA).get("world")
        if world is not None:
            self.world_description = world_description(world, self.name)

    def frames(self) -> Iterator[TeachFrame]:
        """Yield frames in recording order."""
        first_time: int | None = None
        pending_pose: tuple[int, tuple[float, float, float]] | None = None
        pending_command: tuple[int, tuple[float, float]] | None = None
        index = 0
        for message in self.stream:
            self._check_kind()
            if message.topic == CALIBRATION_TOPIC:
                if self.camera is None:
                    camera = calibration_from_foxglove(message.foxglove(self.name), self.name)
                    self.camera = replace(camera, sigma=_stated_sigma(read_metadata(self.stream, CALIBRATION_METADATA).get("sigma"), self.name))
            elif message.topic == POSE_TOPIC:
                pending_pose = (message.log_time, planar_pose_from_message(message.foxglove(self.name), self.name))
            elif message.topic == COMMAND_TOPIC:
                pending_command = (message.log_time, velocity_from_message(message.json(self.name), self.name))
            elif message.topic == IMAGE_TOPIC:
                # Callers decode image_message themselves (in a worker thread, ahead of use).
                if message.message_encoding != "protobuf":
                    raise RecordingError(f"{self.name}: images on {IMAGE_TOPIC} are {message.message_encoding[:40]!r}, expected protobuf")
                if first_time is None:
                    first_time = message.log_time
                pose = pending_pose[1] if pending_pose and pending_pose[0] == message.log_time else None
                command = pending_command[1] if pending_command and pending_command[0] == message.log_time else None
                yield TeachFrame(
                    index=index, log_time_ns=message.log_time, t=(message.log_time - first_time) * 1e-9,
                    image_message=message.data, pose=pose, command=command,
                )
                index += 1
        self._check_kind()
        if not self.info and self.stream.complete and index == 0:
            raise RecordingError(f"{self.name}: no hbvs metadata and no images: not a teach recording")

    @property
    def truncated(self) -> bool:
        """True when the file ended before its footer (a crashed recorder)."""
        return bool(self.stream and self.stream.truncated)
