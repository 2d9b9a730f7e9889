"""A zenoh session configuration with explicit endpoints, as every session of the project opens.

:func:`zenoh_config` (peer mode, multicast scouting off, optional TLS and user/password
authentication) is used by the simulator's sensors, ``swarmseek mock`` / ``sensor`` and the
ground station's ``watch``; the plan's ``[zenoh]`` settings (``mission.core.zenoh_config``) write
the same keys and share :data:`TLS_FILE_KEYS`.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Mapping

if TYPE_CHECKING:  # pragma: no cover
    import zenoh

__all__ = ["TLS_FILE_KEYS", "ZENOH_PROTOCOLS", "zenoh_config"]

#: the ``transport/link/tls`` keys that name files
TLS_FILE_KEYS = ("root_ca_certificate", "listen_certificate", "listen_private_key",
                 "connect_certificate", "connect_private_key")
#: protocols of a zenoh endpoint ``PROTO/ADDRESS``
ZENOH_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream")


def _endpoints(value, what: str) -> list[str]:
    if value is None:
        return []
    items = [value] if isinstance(value, str) else list(value)
    for ep in items:
        proto, sep, rest = str(ep).partition("/")
        if not sep or proto not in ZENOH_PROTOCOLS or not rest:
            raise ValueError(
                f"bad zenoh {what} endpoint {ep!r}: expected PROTO/ADDRESS, e.g. tcp/127.0.0.1:7447")
    return [str(ep) for ep in items]


def zenoh_config(listen: str | Iterable[str] | None = None,
                 connect: str | Iterable[str] | None = None, *,
                 tls: Mapping[str, str] | None = None, enable_mtls: bool = False,
                 username: str | None = None, password: str | None = None,
                 dictionary_file: str | None = None) -> "zenoh.Config":
    """A peer-mode zenoh configuration with explicit endpoints and multicast scouting off.

    Parameters
    ----------
    listen, connect : str or iterable of str or None
        Endpoints such as ``tcp/127.0.0.1:7447`` or ``tls/127.0.0.1:7447``. At least one of
        the two must be given.
    tls : mapping, optional
        ``transport/link/tls`` file paths: ``root_ca_certificate``, ``listen_certificate``,
        ``listen_private_key``, ``connect_certificate``, ``connect_private_key``.
    enable_mtls : bool
        Mutual TLS (present and require certificates).
    username, password : str, optional
        zenoh user/password authentication (``transport/auth/usrpwd``); both or neither.
    dictionary_file : str, optional
        ``user:password`` lines of the peers this session accepts.

    Raises
    ------
    ValueError
        If no endpoint is given, an endpoint is malformed, a TLS key is unknown, a TLS file is
        missing, or only one of username/password is given.
    """
    import zenoh

    listen_eps = _endpoints(listen, "listen")
    connect_eps = _endpoints(connect, "connect")
    if not listen_eps and not connect_eps:
        raise ValueError("zenoh_config needs at least one listen or connect endpoint")
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("peer"))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps(listen_eps))
    conf.insert_json5("connect/endpoints", json.dumps(connect_eps))
    for key, path in (tls or {}).items():
        if key not in TLS_FILE_KEYS:
            raise ValueError(f"unknown zenoh TLS key {key!r} (allowed: {', '.join(TLS_FILE_KEYS)})")
        if not Path(path).is_file():
            raise ValueError(f"zenoh TLS {key}: file not found: {path}")
        conf.insert_json5(f"transport/link/tls/{key}", json.dumps(str(path)))
    if enable_mtls:
        conf.insert_json5("transport/link/tls/enable_mtls", "true")
    if (username is None) != (password is None):
        raise ValueError("zenoh authentication needs both username and password")
    usrpwd = {}
    if username is not None:
        usrpwd.update(user=str(username), password=str(password))
    if dictionary_file is not None:
        if not Path(dictionary_file).is_file():
            raise ValueError(f"zenoh dictionary_file not found: {dictionary_file}")
        usrpwd["dictionary_file"] = str(dictionary_file)
    if usrpwd:
        conf.insert_json5("transport/auth/usrpwd", json.dumps(usrpwd))
    return conf
