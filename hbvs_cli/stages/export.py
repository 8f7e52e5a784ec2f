"""``hbvs export``: a teach, fit or run file as a ROS 2 bag (see :mod:`hbvs_cli.io.ros_export`)."""

from __future__ import annotations

from ..settings.commands import ExportOptions
from .console import Console


def run_export(options: ExportOptions, console: Console) -> dict[str, int]:
    """Write the bag; say on stderr what went into it. Returns the messages per bag topic."""
    from ..io.output_target import refuse_overwriting_inputs
    from ..io.ros_export import export_ros2_bag

    refuse_overwriting_inputs([("-o", options.output)], [("input", options.input)])
    summary = export_ros2_bag(options.input, options.output, allow_truncated=options.allow_truncated)
    topics = ", ".join(f"{topic} {count}" for topic, count in sorted(summary.counts.items()))
    if summary.truncated:
        console.warn(f"{options.input} ended before its end record: the bag holds what was there")
    console.info(f"export: {summary.kind} file -> ROS 2 bag {summary.output} ({topics})")
    return summary.counts
