"""MAVLink connection strings as pymavlink and MAVProxy users write them (see :mod:`mission.link.endpoint`)."""
from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = ["ConnectionSpec", "parse_connection", "DEFAULT_SERIAL_BAUD"]

DEFAULT_SERIAL_BAUD = 57600
_KINDS = ("udpin", "udpout", "tcp", "tcpin", "serial")
_ALIASES = {"udp": "udpin"}
_HOST_RE = re.compile(r"^[A-Za-z0-9.\-]+$")


@dataclass(frozen=True)
class ConnectionSpec:
    """A parsed connection string.

    Attributes
    ----------
    uri : str
        The string as given (stripped).
    kind : str
        ``"udpin"``, ``"udpout"``, ``"tcp"``, ``"tcpin"`` or ``"serial"``.
    host : str or None
        Host for network kinds.
    port : int or None
        Port for network kinds (0 only for ``udpin``/``tcpin``: any free port).
    device : str or None
        Serial device path.
    baud : int or None
        Serial baud rate.
    """

    uri: str
    kind: str
    host: str | None = None
    port: int | None = None
    device: str | None = None
    baud: int | None = None

    @property
    def is_server(self) -> bool:
        """True when the ground station waits for vehicles to talk first (udpin, tcpin)."""
        return self.kind in ("udpin", "tcpin")


def _parse_baud(text: str, uri: str) -> int:
    try:
        baud = int(text)
    except ValueError:
        raise ValueError(f"bad connection {uri!r}: baud rate {text!r} is not an integer") from None
    if baud <= 0:
        raise ValueError(f"bad connection {uri!r}: baud rate must be positive, got {baud}")
    return baud


def parse_connection(uri: str) -> ConnectionSpec:
    """Parse a pymavlink/MAVProxy connection string.

    Parameters
    ----------
    uri : str
        ``udpin:HOST:PORT``, ``udp:HOST:PORT`` (same as udpin), ``udpout:HOST:PORT``,
        ``tcp:HOST:PORT``, ``tcpin:HOST:PORT``, ``serial:/dev/ttyX[:BAUD]`` or
        ``/dev/ttyX[,BAUD]`` (baud default 57600).

    Returns
    -------
    ConnectionSpec

    Raises
    ------
    ValueError
        With the string and what is wrong with it.
    """
    if not isinstance(uri, str):
        raise ValueError(f"bad connection {uri!r}: expected a string")
    text = uri.strip()
    if not text:
        raise ValueError("bad connection '': empty connection string")
    if text.startswith("/"):
        device, _, baud_text = text.partition(",")
        baud = _parse_baud(baud_text, text) if baud_text else DEFAULT_SERIAL_BAUD
        return ConnectionSpec(text, "serial", device=device, baud=baud)
    kind, sep, rest = text.partition(":")
    kind = _ALIASES.get(kind.lower(), kind.lower())
    if not sep or kind not in _KINDS:
        raise ValueError(
            f"bad connection {text!r}: unknown scheme {text.partition(':')[0]!r}; expected one of "
            f"udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT, "
            f"serial:DEVICE[:BAUD] or /dev/DEVICE[,BAUD]")
    if kind == "serial":
        device, _, baud_text = rest.partition(":")
        if not device:
            raise ValueError(f"bad connection {text!r}: serial needs a device, e.g. serial:/dev/ttyUSB0:57600")
        baud = _parse_baud(baud_text, text) if baud_text else DEFAULT_SERIAL_BAUD
        return ConnectionSpec(text, "serial", device=device, baud=baud)
    host, sep, port_text = rest.rpartition(":")
    if not sep or not host:
        raise ValueError(f"bad connection {text!r}: expected {kind}:HOST:PORT")
    if not _HOST_RE.match(host):
        raise ValueError(f"bad connection {text!r}: bad host {host!r}")
    try:
        port = int(port_text)
    except ValueError:
        raise ValueError(f"bad connection {text!r}: port {port_text!r} is not an integer") from None
    low = 0 if kind in ("udpin", "tcpin") else 1
    if not low <= port <= 65535:
        raise ValueError(f"bad connection {text!r}: port {port} out of range {low}..65535")
    return ConnectionSpec(text, kind, host=host, port=port)
