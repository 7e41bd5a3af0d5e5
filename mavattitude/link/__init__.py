"""The MAVLink edge: the only package that imports pymavlink.

:class:`MavlinkLink` is the connection the service talks to (MAVLink 2, signing, reconnection);
:func:`load_signing_key` reads a signing key file.
"""

from mavattitude.link.connection import LinkCounters, MavlinkLink, parse_connect
from mavattitude.link.mavlink2 import message_id
from mavattitude.link.signing import load_signing_key

__all__ = ["LinkCounters", "MavlinkLink", "load_signing_key", "message_id", "parse_connect"]
