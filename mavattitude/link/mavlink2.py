"""pymavlink, imported once and pinned to MAVLink 2.

pymavlink chooses its wire protocol from the environment when ``mavutil`` is first imported
(``MAVLINK20`` set: the ``dialects.v20`` module, else ``v10``) and, on a MAVLink 1 connection, switches
*process-wide* when the first byte it reads is a MAVLink 2 magic (``mavfile.auto_mavlink_version``).
MAVLink 1 cannot carry ``repr_offset_q``, message ids above 255 or a signature, so we do not rely on
either mechanism alone:

1. ``MAVLINK20=1`` is put into the environment before ``mavutil`` is imported here, so a process in
   which this module is the first importer gets the v2 dialect globally;
2. every connection we open gets its own protocol object from the v2 module of the current dialect
   (:func:`force_mavlink2`), whatever another importer made the global default, and has the
   auto-switch disabled, so the wire protocol of our packets never depends on import order.
"""

from __future__ import annotations

import importlib
import os
from types import ModuleType
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil  # after the environment set-up above, on purpose

from mavattitude.errors import LinkError

mavlink2: ModuleType = importlib.import_module(f"pymavlink.dialects.v20.{mavutil.current_dialect}")


def force_mavlink2(conn: Any) -> None:
    """Give a fresh ``mavutil`` connection a MAVLink 2 protocol object (keeps the signing state it had)."""
    old = conn.mav
    mav = mavlink2.MAVLink(conn, srcSystem=old.srcSystem, srcComponent=old.srcComponent)
    mav.robust_parsing = True
    mav.signing = old.signing
    mav.seq = old.seq
    conn.mav = mav
    conn.WIRE_PROTOCOL_VERSION = mavlink2.WIRE_PROTOCOL_VERSION
    conn.first_byte = False  # no process-wide protocol switch triggered by what a peer sends


def message_id(name: str) -> int:
    """The MAVLink message id of a message name (``"RAW_IMU"`` -> 27)."""
    msg_id = getattr(mavlink2, f"MAVLINK_MSG_ID_{name.upper()}", None)
    if msg_id is None:
        raise LinkError(f"the MAVLink dialect {mavutil.current_dialect!r} has no message {name}")
    return int(msg_id)
