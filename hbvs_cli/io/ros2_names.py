"""ROS 2 topic names as ROS 2 validates them (rcl's topic-name rules, rmw's fully qualified form),
checked before anything joins DDS, so a typo is a usage error and not a topic nobody publishes."""

from __future__ import annotations

import re

from ..errors import UsageError

#: One token of a name: ASCII letters, digits and underscores, not starting with a digit.
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
#: rmw's limit on a fully qualified topic name: the DDS topic ``rt/...`` must fit 255 characters.
MAX_TOPIC_NAME_LENGTH = 255 - len("rt")


def full_topic_name(name: str, option: str = "topic") -> str:
    """The fully qualified ROS 2 topic name of ``name`` (a relative name is under ``/``, the
    namespace hbvs's node has), or :class:`UsageError` naming ``option`` and the broken rule.

    ROS 2's rules: tokens separated by single ``/``, each of ASCII letters, digits and ``_`` and not
    starting with a digit; no trailing ``/``. ``~`` (the node's private namespace) and ``{...}``
    substitutions need a node name and namespace, which hbvs's DDS participant does not have.
    """
    problem = _problem(name)
    if problem:
        raise UsageError(f"{option} {name!r} is not a ROS 2 topic name: {problem}")
    return name if name.startswith("/") else "/" + name


def _problem(name: str) -> str | None:
    if not name:
        return "it is empty"
    if name.startswith("~"):
        return "'~' (the node's private namespace) needs a node namespace; give the full name, e.g. /robot/cmd_vel"
    if "{" in name or "}" in name:
        return "substitutions ({node}, {ns}) need a node; give the full name"
    bad = dict.fromkeys(c for c in name if not (c == "/" or c == "_" or (c.isascii() and c.isalnum())))
    if bad:
        return f"{''.join(bad)!r} not allowed (ASCII letters, digits, '_' and '/' only)"
    if name == "/":
        return "it names no topic"
    if "//" in name:
        return "'//' (an empty token)"
    if name.endswith("/"):
        return "it ends with '/'"
    for token in name.strip("/").split("/"):
        if not _TOKEN.fullmatch(token):
            return f"the token {token!r} starts with a digit"
    if len(name.lstrip("/")) + 1 > MAX_TOPIC_NAME_LENGTH:
        return f"longer than {MAX_TOPIC_NAME_LENGTH} characters"
    return None


def check_topic_names(*named: tuple[str | None, str]) -> None:
    """:func:`full_topic_name` for each ``(name, option)`` given (None: not given): a usage error
    before any DDS participant is made or file written."""
    for name, option in named:
        if name is not None:
            full_topic_name(name, option)
