"""Image files from a folder or a glob pattern."""

from __future__ import annotations

import glob
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ...errors import InputError
from ..images import as_image8, decode_image, image_size, sniff_format
from .frame_source import FrameSource, SourceFrame, _natural_key, _same_size

#: File extensions :class:`ImageFolderSource` picks up (compared case-insensitively).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


class ImageFolderSource(FrameSource):
    """Image files at ``fps`` (frame ``i`` at ``t = i / fps``), in natural order, from a folder (not
    recursive), a glob (``**`` recurses) or one image."""

    kind = "images"

    def __init__(self, dir_or_glob: str | os.PathLike[str], fps: float) -> None:
        self.path = str(dir_or_glob)
        self.fps = fps  # an option checked finite and >= 0.1 Hz; teach gives images its default rate without one
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
            files = [Path(p) for p in glob.glob(spec, recursive=True) if wanted(Path(p))]
            if not files:
                raise InputError(f"{spec}: no image files ({extensions}) match this pattern")
            return sorted(files, key=lambda p: _natural_key(str(p)))
        if path.is_file():
            if path.suffix.lower() not in IMAGE_EXTENSIONS:
                raise InputError(f"{spec}: not an image file ({extensions}); expected a folder or a glob")
            return [path]
        raise InputError(f"{spec}: no such folder")

    @property
    def image_size(self) -> tuple[int, int] | None:
        """(width, height) of the first image, from its header."""
        try:
            with self.files[0].open("rb") as stream:
                return image_size(stream.read(1 << 16))
        except OSError:
            return None

    def __iter__(self) -> Iterator[SourceFrame]:
        size: tuple[int, int] | None = None
        for index, file in enumerate(self.files):
            try:
                data = file.read_bytes()
            except OSError as exc:
                raise InputError(f"{file}: cannot read the image ({exc.strerror or exc})") from None
            image = as_image8(decode_image(data, str(file), colour=True), str(file))
            size = _same_size(size, image, str(file))
            fmt = sniff_format(data)
            yield SourceFrame(t=index / self.fps, image=image, encoded=data if fmt else None, format=fmt)

    def describe(self) -> dict[str, Any]:
        """Kind, path, frame count, fps and the first and last file."""
        return {
            "kind": self.kind, "path": self.path, "frame_count": len(self.files), "fps": self.fps,
            "first": str(self.files[0]), "last": str(self.files[-1]),
        }

