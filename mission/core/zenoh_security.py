"""zenoh transport security from the plan: TLS, user/password authentication, access control.

The plan's ``[zenoh.tls]``, ``[zenoh.auth]`` and ``[zenoh.access_control]`` tables (see
``docs/zenoh.md``) are validated here (every problem reported with its dotted key, through the
plan's :class:`~mission.core.plan_checks.Checker`) and turned into zenoh 1.x configuration:

- ``transport/link/tls/*`` (certificate and key file paths, ``enable_mtls``);
- ``transport/auth/usrpwd`` (``user``, ``password`` read from a file, ``dictionary_file``);
- ``access_control``: default deny; sensor readings (``put`` on
  ``swarmseek/<fleet>/vehicle/*/sensor``) accepted only from subjects named by certificate common
  name or user name, and the coordinator's state (``swarmseek/<fleet>/mission/**``) sent only to
  the listed monitors.

Secrets never sit in the plan itself: the password is read from ``password_file``, which, like
the dictionary and the private keys, must not be world-readable.

This module holds the validation of the plan's ``[zenoh]`` tables (:func:`parse_zenoh` and the
parsers of its sub-tables). The settings and their zenoh configuration are in
:mod:`mission.core.zenoh_config`, the secret files in :mod:`wire.zenoh_secrets` (shared with the simulator).
"""
from __future__ import annotations

from pathlib import Path

from mission.core.plan_checks import Checker, show_value
from mission.core.zenoh_config import ZENOH_MODES, ZenohAclPlan, ZenohAuthPlan, ZenohPlan
from wire.zenoh_config import TLS_FILE_KEYS
from wire.zenoh_secrets import ZenohSecurityError, check_dictionary_file, private_file_problem, read_password_file

__all__ = ["parse_zenoh", "parse_tls", "parse_auth", "parse_access_control"]

_PRIVATE_TLS_KEYS = ("listen_private_key", "connect_private_key")
_NAME_CHARS_FORBIDDEN = ":\n\r"


def _resolve(value: str, base_dir: Path | None) -> Path:
    """``value`` as a path, relative ones taken from ``base_dir`` (the plan file's folder)."""
    fp = Path(value)
    if not fp.is_absolute() and base_dir is not None:
        fp = base_dir / fp
    return fp


def parse_tls(c: Checker, t: dict, prefix: str, base_dir: Path | None,
              listen: tuple[str, ...], connect: tuple[str, ...]) -> tuple[dict, bool]:
    """Validate ``[zenoh.tls]``: returns ``(file key -> path, enable_mtls)``; problems go to ``c``."""
    c.unknown(t, TLS_FILE_KEYS + ("enable_mtls",), prefix)
    tls: dict[str, str] = {}
    for key in TLS_FILE_KEYS:
        if key not in t:
            continue
        v = c.string(t, key, prefix)
        if v is None:
            continue
        fp = _resolve(v, base_dir)
        why = private_file_problem(fp) if key in _PRIVATE_TLS_KEYS else (
            None if fp.is_file() else f"file not found: {fp}")
        if why:
            c.bad(f"{prefix}.{key}", why)
            continue
        tls[key] = str(fp)
    mtls = t.get("enable_mtls", False)
    if not isinstance(mtls, bool):
        c.bad(f"{prefix}.enable_mtls", f"must be true or false, got {show_value(mtls)}")
        mtls = False
    for side in ("listen", "connect"):
        pair = (f"{side}_certificate", f"{side}_private_key")
        if (pair[0] in t) != (pair[1] in t):
            missing = pair[1] if pair[0] in t else pair[0]
            present = pair[0] if missing == pair[1] else pair[1]
            if _reported(c, f"{prefix}.{present}"):
                continue
            c.bad(f"{prefix}.{missing}", f"required with {prefix}.{present}")
    if any(ep.startswith("tls/") for ep in listen):
        for key in ("listen_certificate", "listen_private_key"):
            if key not in t and not _reported(c, f"{prefix}.{key}"):
                c.bad(f"{prefix}.{key}", "required: a listen endpoint uses tls/")
    if any(ep.startswith("tls/") for ep in connect) and "root_ca_certificate" not in t:
        c.bad(f"{prefix}.root_ca_certificate", "required: a connect endpoint uses tls/")
    if mtls:
        if "root_ca_certificate" not in t:
            c.bad(f"{prefix}.root_ca_certificate", "required with enable_mtls = true")
        if not any(k in t for k in ("listen_certificate", "connect_certificate")):
            c.bad(f"{prefix}.enable_mtls", "needs a listen_certificate or connect_certificate "
                  "(with its private key)")
    return tls, mtls


def _reported(c: Checker, key: str) -> bool:
    return any(k == key for k, _ in c.problems)


def parse_auth(c: Checker, t: dict, prefix: str, base_dir: Path | None) -> ZenohAuthPlan | None:
    """Validate ``[zenoh.auth]`` (None when absent or invalid); problems go to ``c``."""
    if not t:
        return None
    c.unknown(t, ("username", "password_file", "dictionary_file"), prefix)
    if "password" in t:
        c.bad(f"{prefix}.password", "never put a password in the plan: use password_file")
    username = c.string(t, "username", prefix)
    if username is not None and any(ch in username for ch in _NAME_CHARS_FORBIDDEN):
        c.bad(f"{prefix}.username", f"must not contain ':' or line breaks, got {username!r}")
        username = None
    if ("username" in t) != ("password_file" in t):
        missing = "password_file" if "username" in t else "username"
        c.bad(f"{prefix}.{missing}", "username and password_file go together")
    files: dict[str, str | None] = {}
    for key in ("password_file", "dictionary_file"):
        files[key] = None
        v = c.string(t, key, prefix)
        if v is None:
            continue
        fp = _resolve(v, base_dir)
        try:
            if key == "password_file":
                read_password_file(fp)
            else:
                check_dictionary_file(fp)
        except ZenohSecurityError as exc:
            c.bad(f"{prefix}.{key}", str(exc))
            continue
        files[key] = str(fp)
    if not any(k in t for k in ("username", "password_file", "dictionary_file")):
        c.bad(prefix, "give username + password_file, dictionary_file, or both")
    if username is None and files["dictionary_file"] is None:
        return None
    if username is not None and files["password_file"] is None:
        return None
    return ZenohAuthPlan(username=username, password_file=files["password_file"],
                         dictionary_file=files["dictionary_file"])


def parse_access_control(c: Checker, t: dict, prefix: str, fleet: str | None, *,
                         enable_mtls: bool, auth: ZenohAuthPlan | None,
                         listen: tuple[str, ...] = ()) -> ZenohAclPlan | None:
    """Validate ``[zenoh.access_control]`` (None when absent or invalid); problems go to ``c``."""
    if not t:
        return None
    keys = ("sensor_cert_common_names", "sensor_usernames", "monitor_cert_common_names",
            "monitor_usernames", "commander_cert_common_names", "commander_usernames")
    c.unknown(t, ("default",) + keys, prefix)
    default = t.get("default", "deny")
    if default != "deny":
        c.bad(f"{prefix}.default", f"only \"deny\" is supported (an allow default could not keep "
              f"other peers from putting readings), got {show_value(default)}")
    names = {k: c.strings(t, k, prefix) for k in keys}
    if not names["sensor_cert_common_names"] and not names["sensor_usernames"]:
        c.bad(prefix, "give sensor_cert_common_names or sensor_usernames (else no reading is accepted)")
    for k in ("sensor_cert_common_names", "monitor_cert_common_names", "commander_cert_common_names"):
        if names[k] and not enable_mtls:
            c.bad(f"{prefix}.{k}", "certificate names need [zenoh.tls] enable_mtls = true")
    for k in ("sensor_usernames", "monitor_usernames", "commander_usernames"):
        if names[k] and (auth is None or auth.dictionary_file is None):
            c.bad(f"{prefix}.{k}", "user names need [zenoh.auth] dictionary_file (to authenticate them)")
        elif names[k] and not listen:
            c.bad(f"{prefix}.{k}", "user names identify only peers that connect to this session: "
                  "give [zenoh] listen endpoints (or use certificate names)")
    if fleet is None:
        return None
    return ZenohAclPlan(sensor_key_expr=f"swarmseek/{fleet}/vehicle/*/sensor",
                        state_key_expr=f"swarmseek/{fleet}/mission/**",
                        control_key_expr=f"swarmseek/{fleet}/mission/control", **names)


def parse_zenoh(c: Checker, doc: dict, base_dir: Path | None) -> ZenohPlan:
    """Validate the plan's ``[zenoh]`` table; problems go to ``c`` with their dotted keys."""
    t = c.table(doc, "zenoh")
    p = "zenoh"
    c.unknown(t, ("mode", "listen", "connect", "tls", "auth", "access_control",
                  "allow_unauthenticated_network"), p)
    allow_open = t.get("allow_unauthenticated_network", False)
    if not isinstance(allow_open, bool):
        c.bad(f"{p}.allow_unauthenticated_network", f"must be true or false, got {show_value(allow_open)}")
        allow_open = False
    mode = c.string(t, "mode", p, "peer", choices=ZENOH_MODES)
    listen = c.strings(t, "listen", p)
    connect = c.strings(t, "connect", p)
    if "listen" in t or "connect" in t:
        if not listen and not connect:
            c.bad(p, "give at least one listen or connect endpoint (multicast scouting is off)")
    for j, ep in enumerate(listen + connect):
        if "/" not in ep:
            c.bad(f"{p}.{'listen' if j < len(listen) else 'connect'}",
                  f"endpoint {ep!r} must look like tcp/HOST:PORT or tls/HOST:PORT")
    tls, mtls = parse_tls(c, c.table(t, "tls", p), f"{p}.tls", base_dir, listen, connect)
    auth = parse_auth(c, c.table(t, "auth", p), f"{p}.auth", base_dir)
    fleet = doc.get("fleet") if isinstance(doc.get("fleet"), str) else None
    acl = parse_access_control(c, c.table(t, "access_control", p), f"{p}.access_control", fleet,
                               enable_mtls=mtls, auth=auth, listen=listen)
    return ZenohPlan(mode=mode or "peer", listen=listen, connect=connect, tls=tls,
                     enable_mtls=mtls, auth=auth, access_control=acl,
                     allow_unauthenticated_network=allow_open)
