"""Where hbvs's DDS looks for the robot: ROS 2's own discovery settings (Jazzy and later:
``ROS_AUTOMATIC_DISCOVERY_RANGE``, ``ROS_STATIC_PEERS``, the deprecated ``ROS_LOCALHOST_ONLY``;
``CYCLONEDDS_URI`` wins over them) turned into the Eclipse Cyclone DDS configuration hbvs joins the
domain with, and the one line the live stages print about it. What each setting does, and why Fast
DDS's type information is ignored: docs/robot.md. Pure text: no DDS binding is needed to compute or test it.

Cyclone's ``AllowInvalidTryConstruct`` alone did not make Fast DDS 3's endpoints match; ignoring
their type information did (``tests/test_ros2_real.py``).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

from ..errors import UsageError

RANGES = ("OFF", "LOCALHOST", "SUBNET", "SYSTEM_DEFAULT")
#: eProsima's RTPS vendor id (Fast DDS), whose type information Cyclone is told to ignore.
FAST_DDS_VENDOR_ID = "1.15"
_COMPATIBILITY = f"<Compatibility><IgnoreTypeInformation>{FAST_DDS_VENDOR_ID}</IgnoreTypeInformation></Compatibility>"
#: Unicast discovery needs participant indices: as many as processes on one machine may join.
_MAX_PARTICIPANT_INDEX = 60


@dataclass(frozen=True)
class DdsSettings:
    """``config``: the Cyclone DDS configuration (XML fragments joined by commas, as ``CYCLONEDDS_URI``
    takes them); ``description``: one line for the start-up message, e.g. ``DDS: interface lo, discovery
    localhost (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST)``."""

    config: str
    description: str


def _domain(body: str) -> str:
    return f'<CycloneDDS xmlns="https://cdds.io/config"><Domain Id="any">{body}</Domain></CycloneDDS>'


def discovery_range(environ: Mapping[str, str]) -> tuple[str, str]:
    """The discovery range ROS 2 would use (one of :data:`RANGES`), and why: ``ROS_AUTOMATIC_DISCOVERY_RANGE=...``,
    ``ROS_LOCALHOST_ONLY=1`` or ``nothing set``."""
    text = environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip()
    if text:
        if text.upper() in RANGES:
            return text.upper(), f"ROS_AUTOMATIC_DISCOVERY_RANGE={text}"
        # rcl warns and falls back to this machine only: the safe reading of a typo.
        return "LOCALHOST", f"ROS_AUTOMATIC_DISCOVERY_RANGE={text!r} is not one of {', '.join(RANGES)}: localhost, as ROS 2"
    if environ.get("ROS_LOCALHOST_ONLY", "").strip() == "1":
        return "LOCALHOST", "ROS_LOCALHOST_ONLY=1"
    return "SUBNET", "nothing set: ROS 2's default"


def dds_settings(environ: Mapping[str, str] | None = None) -> DdsSettings:
    """The Cyclone DDS configuration for ROS 2's discovery variables in ``environ`` (``os.environ``
    when None); :class:`UsageError` for ``OFF`` (no other process could ever be found)."""
    environ = os.environ if environ is None else environ
    compatibility = _domain(_COMPATIBILITY)
    user = environ.get("CYCLONEDDS_URI", "").strip()
    if user:
        # Later fragments override earlier ones: the user's file has the last word.
        return DdsSettings(f"{compatibility},{user}", "DDS: the network of CYCLONEDDS_URI (ROS 2's discovery variables not used)")
    scope, reason = discovery_range(environ)
    # ROS_STATIC_PEERS: addresses separated by ";" (blanks ignored).
    peers = [peer.strip() for peer in environ.get("ROS_STATIC_PEERS", "").split(";") if peer.strip()]
    peer_text = f", static peers {', '.join(peers)}" if peers else ""
    if scope == "OFF":
        raise UsageError("ROS_AUTOMATIC_DISCOVERY_RANGE=OFF: ROS 2 then discovers nothing outside its own process, so hbvs "
                         "could never reach the robot; set LOCALHOST or SUBNET (or unset it)")
    if scope == "SYSTEM_DEFAULT":
        return DdsSettings(compatibility, f"DDS: Cyclone DDS's defaults (multicast on the interface it picks){peer_text} ({reason})")
    peer_list = [*(["127.0.0.1"] if scope == "LOCALHOST" else []), *peers]
    peer_xml = "".join(f"<Peer address={quoteattr(peer)}/>" for peer in peer_list)
    discovery = (f"<Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>{_MAX_PARTICIPANT_INDEX}"
                 f"</MaxAutoParticipantIndex><Peers>{peer_xml}</Peers></Discovery>") if peer_list else ""
    if scope == "LOCALHOST":
        # Static peers are on other machines: then every interface, still without multicast.
        interface = "" if peers else '<Interfaces><NetworkInterface name="lo"/></Interfaces>'
        general = f"<General>{interface}<AllowMulticast>false</AllowMulticast></General>"
        where = "the interface Cyclone DDS picks" if peers else "interface lo"
        return DdsSettings(_domain(general + discovery + _COMPATIBILITY),
                           f"DDS: {where}, discovery localhost{peer_text}, no multicast ({reason})")
    return DdsSettings(_domain(discovery + _COMPATIBILITY),
                       f"DDS: the interface Cyclone DDS picks, discovery subnet (multicast){peer_text} ({reason})")
