"""File sizes of what hbvs records (issue 18), side by side with the layout used before.

``python -m bench.file_sizes`` (about 2 minutes on 2 cores) writes ``bench/FILE_SIZES.md``.
The same frames are stored in both layouts in one run:

* before: every frame a PNG, base64 inside a JSON ``foxglove.CompressedImage`` (a colour
  PNG kept as it came);
* now: one gray channel (colour only for sources with colour, which this does not measure),
  JPEG at quality 90 for frames hbvs compresses, PNG files and bag images kept (a colour PNG
  of gray content as gray PNG), bytes in a protobuf ``foxglove.CompressedImage``.

Figures: bytes per frame against the bytes of the image it holds (goal <= 1.1x), the
default 20 s teach against before (goal <= 0.25), and the fit's accuracy against the
truth from JPEG and from lossless PNG frames (goal: the tests' bounds, theta_d < 0.05 deg).
"""

from __future__ import annotations

import datetime
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "FILE_SIZES.md"


def _old_layout_copy(source: Path, target: Path, colour_pngs: list[Path] | None = None) -> None:
    """``source`` rewritten as hbvs wrote files before issue 18: PNG frames, base64 in JSON
    (written with the mcap library directly: hbvs no longer reads or writes that layout).

    With ``colour_pngs`` the frames are those files' bytes as they came (what ``--images``
    stored then); otherwise each frame is re-encoded as the gray PNG hbvs wrote then.
    """
    import base64
    import json

    from mcap.writer import CompressionType, Writer

    from hbvs_cli.io.images import decode_image, encode_image, read_compressed_image
    from hbvs_cli.io.mcap import McapStream

    stream = McapStream(source)
    with open(target, "wb") as handle:
        writer = Writer(handle, chunk_size=512 * 1024, compression=CompressionType.ZSTD)
        writer.start()
        channels: dict[str, int] = {}
        first, index = True, 0
        for message in stream:
            if first:
                for name, values in stream.metadata.items():
                    writer.add_metadata(name, values)
                first = False
            data = message.data
            if message.schema_name == "foxglove.CompressedImage":
                stored = read_compressed_image(message.data)
                if colour_pngs is not None:
                    png = colour_pngs[index].read_bytes()
                else:
                    png = stored.data if stored.format == "png" else encode_image(decode_image(stored.data), "png")
                sec, nsec = divmod(message.log_time, 10**9)
                data = json.dumps({"timestamp": {"sec": sec, "nsec": nsec}, "frame_id": "camera",
                                   "data": base64.b64encode(png).decode("ascii"), "format": "png"}, separators=(",", ":")).encode()
                index += 1
            if message.topic not in channels:
                schema = writer.register_schema(message.schema_name, message.schema_encoding, message.schema_data)
                encoding = "json" if message.schema_name == "foxglove.CompressedImage" else message.message_encoding
                channels[message.topic] = writer.register_channel(message.topic, encoding, schema)
            writer.add_message(channels[message.topic], message.log_time, data, message.log_time)
        writer.finish()


def _image_bytes(path: Path) -> tuple[int, int]:
    """(frames, bytes of the images they hold) of any hbvs file's /camera/image topic."""
    from hbvs_cli.io.images import read_compressed_image
    from hbvs_cli.io.mcap import McapStream

    count = total = 0
    for message in McapStream(path, topics={"/camera/image"}):
        count += 1
        total += len(read_compressed_image(message.data).data)
    return count, total


def _fit_theta_error(teach: Path, folder: Path) -> tuple[float, float]:
    """(theta_d RMS error in deg, x_hd2 RMS error) of the fit of a simulated teach."""
    from hbvs_cli.core.path import CommandProfile
    from hbvs_cli.io.fit_file import read_fit_file
    from hbvs_cli.sim.world import World
    from hbvs_cli.stages.console import Console
    from hbvs_cli.stages.fit import FitOptions, run_fit

    sys.path.insert(0, str(HERE.parent / "tests"))  # the ground truth is a test oracle
    from oracles import TaughtPathTrajectory

    fit = folder / (teach.stem + "-fit.mcap")
    run_fit(FitOptions(input=str(teach), output=str(fit)), Console(quiet=True))
    model = read_fit_file(fit).model
    path = model.taught_path
    interval = float(np.median(np.diff(path.t)))
    profile = CommandProfile(t=path.t - path.t[0], v=path.v, w=path.w, t_end=float(path.t[-1] - path.t[0] + interval))
    _, _, d_star = World.from_dict(model.world_description).reference_geometry(path.reference_pose)
    truth = TaughtPathTrajectory(profile, path.start_pose, path.reference_pose, d_star)
    t = path.t[(path.t >= model.trajectory.t_start) & (path.t <= model.trajectory.t_end)]
    fitted, exact = model.trajectory.evaluate(t), truth.evaluate(t - path.t[0])
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    return float(np.degrees(rms(fitted.theta_d - exact.theta_d))), rms(fitted.x_hd2 - exact.x_hd2)


def measure(folder: Path) -> list[tuple[str, str, str, str]]:
    """Rows (case, before, now, goal) of the table."""
    import cv2

    from hbvs_cli.core.camera import DEFAULT_CAMERA
    from hbvs_cli.io.calibration import save_calibration_ros
    from hbvs_cli.io.teach_file import TeachReader
    from hbvs_cli.stages.console import Console
    from hbvs_cli.stages.repeat import RepeatOptions, run_repeat
    from hbvs_cli.stages.teach import TeachOptions, run_teach

    quiet = Console(quiet=True)
    rows = []
    # 1. The default 20 s simulated teach: JPEG 90 now, PNG in JSON before, and PNG now.
    teach, png_teach, old = folder / "teach.mcap", folder / "teach-png.mcap", folder / "teach-before.mcap"
    run_teach(TeachOptions(output=str(teach)), quiet)
    run_teach(TeachOptions(output=str(png_teach), image_format="png"), quiet)
    _old_layout_copy(png_teach, old)
    frames, jpeg_bytes = _image_bytes(teach)
    _, png_bytes = _image_bytes(png_teach)
    size, png_size, old_size = teach.stat().st_size, png_teach.stat().st_size, old.stat().st_size
    rows.append((
        f"default 20 s teach ({frames} frames): file size",
        f"{old_size / 1e6:.1f} MB (PNG, base64 JSON)",
        f"{size / 1e6:.1f} MB = {size / old_size:.3f} of before (JPEG 90); --format png {png_size / 1e6:.1f} MB",
        "<= 0.25 of before",
    ))
    rows.append((
        "default teach: file bytes per frame / image bytes per frame",
        f"{old_size / frames / 1e3:.1f} KB / {png_bytes / frames / 1e3:.1f} KB PNG = {old_size / png_bytes:.3f}x",
        f"{size / frames / 1e3:.1f} KB / {jpeg_bytes / frames / 1e3:.1f} KB JPEG = {size / jpeg_bytes:.3f}x; "
        f"--format png {png_size / png_bytes:.3f}x",
        "<= 1.1x",
    ))
    theta_jpeg, x2_jpeg = _fit_theta_error(teach, folder)
    theta_png, x2_png = _fit_theta_error(png_teach, folder)
    rows.append((
        "fit of the default teach: theta_d, x_hd2 RMS error against the truth",
        f"{theta_png:.4f} deg, {x2_png:.1e} (lossless PNG)",
        f"{theta_jpeg:.4f} deg, {x2_jpeg:.1e} (JPEG 90)",
        "tests' bounds: < 0.05 deg, < 1e-3",
    ))
    # 2. --images of colour PNGs (what a camera tool exports): 60 rendered frames.
    images = folder / "frames"
    images.mkdir()
    pngs = []
    for frame in TeachReader(png_teach).frames():
        if frame.index >= 60:
            break
        gray = cv2.imdecode(np.frombuffer(frame.stored_image().data, np.uint8), cv2.IMREAD_GRAYSCALE)
        pngs.append(images / f"frame{frame.index:03d}.png")
        cv2.imwrite(str(pngs[-1]), cv2.merge([gray, gray, gray]))
    calibration = folder / "camera.yaml"
    save_calibration_ros(DEFAULT_CAMERA, calibration)
    from_images, old_images = folder / "images.mcap", folder / "images-before.mcap"
    run_teach(TeachOptions(output=str(from_images), images=str(images), calibration=calibration), quiet)
    _old_layout_copy(from_images, old_images, pngs)
    count, stored = _image_bytes(from_images)
    colour = sum(p.stat().st_size for p in pngs)
    rows.append((
        f"teach --images, {count} colour PNGs: bytes per frame",
        f"{old_images.stat().st_size / count / 1e3:.1f} KB (colour PNG {colour / count / 1e3:.1f} KB, base64 JSON)",
        f"{from_images.stat().st_size / count / 1e3:.1f} KB = {from_images.stat().st_size / old_images.stat().st_size:.3f} "
        f"of before; {from_images.stat().st_size / stored:.3f}x its gray PNGs (lossless)",
        "<= 1.1x the image",
    ))
    # 3. repeat --record-images on the default fit, 4x the taught pace (150 steps).
    run, old_run = folder / "run.mcap", folder / "run-before.mcap"
    run_repeat(RepeatOptions(input=str(folder / "teach-fit.mcap"), output=str(run), sim=True, record_images=True, speed=4.0), quiet)
    _old_layout_copy(run, old_run)
    count, stored = _image_bytes(run)
    per_step = run.stat().st_size / count
    rows.append((
        f"repeat --record-images ({count} steps): file bytes per step / image bytes per step",
        f"{old_run.stat().st_size / count / 1e3:.1f} KB a step (PNG, base64 JSON; with the run's other messages)",
        f"{per_step / 1e3:.1f} KB / {stored / count / 1e3:.1f} KB JPEG = {per_step / (stored / count):.3f}x "
        f"(the state, pose and command messages included); {run.stat().st_size / old_run.stat().st_size:.3f} of before",
        "<= 1.1x",
    ))
    return rows


def main() -> int:
    import cv2

    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="hbvs-sizes-") as tmp:
        rows = measure(Path(tmp))
    elapsed = time.perf_counter() - start
    lines = [
        "# hbvs file sizes",
        "",
        f"Produced by `python -m bench.file_sizes` in {elapsed:.0f} s on {datetime.date.today()} "
        f"(Python {sys.version.split()[0]}, OpenCV {cv2.__version__}, {os.cpu_count()} cores). "
        "See the module's docstring for the two layouts.",
        "",
        "| case | before | now | goal |",
        "|---|---|---|---|",
        *[f"| {' | '.join(row)} |" for row in rows],
        "",
    ]
    RESULTS.write_text("\n".join(lines), encoding="utf-8")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
