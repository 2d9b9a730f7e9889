"""The signing configuration of a mission: the plan's ``[security]`` table and the key it names.

Everything about signing that a plan needs (no MAVLink framing): :class:`SigningConfig`, the
signing timestamp origin and :func:`signing_config_from_table`. The frame-level signing and the
checks of received frames are in :mod:`mission.link.signing`.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from mission.core.redaction import secret_field
from wire.signing import SigningError, load_key_file, signing_timestamp

__all__ = ["DEFAULT_ALLOW_UNSIGNED", "SigningConfig", "signing_config_from_table"]

#: messages accepted unsigned by default: what radio modems inject (ArduPilot's accept list).
DEFAULT_ALLOW_UNSIGNED = frozenset({"RADIO_STATUS", "RADIO"})
_KEY_LEN = 32
_SECURITY_KEYS = ("signing_key_file", "signing_link_id", "allow_unsigned", "setup_signing")
#: [security] keys that are a policy, not a signing setting (no key file needed): read by the plan
_POLICY_KEYS = ("require_signing",)
_MSG_IDS: dict[str, int] = {cls.msgname: msg_id for msg_id, cls in mavlink.mavlink_map.items()}

# ---------------------------------------------------------------------------- configuration
@dataclass(frozen=True)
class SigningConfig:
    """What signing the ground station does (the key never appears in ``repr`` nor in a log).

    Parameters
    ----------
    key : bytes
        The 32-byte secret key (not all zeros).
    link_id : int
        Link id (0..255) written in our signatures; give each link of a mission its own
        through :meth:`new_state` if several links reach one vehicle.
    allow_unsigned : frozenset of str
        Names of messages accepted unsigned (still counted as ``unsigned_allowed``);
        ``"*"`` accepts every unsigned frame (a migration mode: nothing is protected).
    send_setup : bool
        Send SETUP_SIGNING to vehicles heard unsigned (provisioning over a trusted link).
    key_file : str or None
        Where the key came from (for messages).
    """

    key: bytes = secret_field()
    link_id: int = 0
    allow_unsigned: frozenset = DEFAULT_ALLOW_UNSIGNED
    send_setup: bool = True
    key_file: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.key, (bytes, bytearray)) or len(self.key) != _KEY_LEN:
            raise SigningError(f"a signing key is {_KEY_LEN} bytes")
        if not any(self.key):
            raise SigningError("the all-zero signing key means 'signing off'; use another key")
        object.__setattr__(self, "key", bytes(self.key))
        if isinstance(self.link_id, bool) or not isinstance(self.link_id, int) \
                or not 0 <= self.link_id <= 255:
            raise SigningError(f"link_id must be an integer 0..255, got {self.link_id!r}")
        names = frozenset(self.allow_unsigned)
        unknown = sorted(n for n in names if n != "*" and n not in _MSG_IDS)
        if unknown:
            raise SigningError(f"allow_unsigned: unknown MAVLink message name(s) {unknown}")
        object.__setattr__(self, "allow_unsigned", names)
        object.__setattr__(self, "_allowed_ids",
                           frozenset(_MSG_IDS[n] for n in names if n != "*"))

    @classmethod
    def from_key_file(cls, path, *, allow_world_readable: bool = False, **kwargs) -> "SigningConfig":
        """Read ``path`` with :func:`load_key_file`; ``kwargs`` are the other fields."""
        return cls(key=load_key_file(path, allow_world_readable=allow_world_readable),
                   key_file=str(path), **kwargs)

    @property
    def fingerprint(self) -> str:
        """First 8 hex digits of ``SHA-256(SHA-256(key))``: safe to log, tells keys apart."""
        return hashlib.sha256(hashlib.sha256(self.key).digest()).hexdigest()[:8]

    def __repr__(self) -> str:
        return (f"SigningConfig(fingerprint={self.fingerprint!r}, link_id={self.link_id}, "
                f"allow_unsigned={sorted(self.allow_unsigned)}, send_setup={self.send_setup}, "
                f"key_file={self.key_file!r})")

    def to_json(self) -> dict:
        """What a log, a summary or a publication says of signing: on, the key's fingerprint,
        where it came from and the settings; never the key."""
        return {"signing": True, "fingerprint": self.fingerprint, "key_file": self.key_file,
                "link_id": self.link_id, "allow_unsigned": sorted(self.allow_unsigned),
                "send_setup": self.send_setup}

    def allows_unsigned(self, msg_id: int) -> bool:
        """True if an unsigned message with this id is accepted."""
        return "*" in self.allow_unsigned or msg_id in self._allowed_ids

    def new_state(self, unix_s: float, link_id: int | None = None) -> mavlink.MAVLinkSigning:
        """A pymavlink signing state for one link, its timestamp at ``unix_s``.

        Share it between every encoder of the link (:func:`apply_signing`) and the link's
        :class:`SignatureVerifier`.
        """
        state = mavlink.MAVLinkSigning()
        state.secret_key = self.key
        state.link_id = self.link_id if link_id is None else int(link_id) & 0xFF
        state.timestamp = signing_timestamp(unix_s)
        state.sign_outgoing = True
        return state


# ---------------------------------------------------------------------------- plan section
def signing_config_from_table(table: Mapping, base_dir=None) -> SigningConfig | None:
    """Build the signing configuration from a plan's ``[security]`` table.

    Keys: ``signing_key_file`` (path, relative to ``base_dir``; no key file: no signing, None
    is returned), ``signing_link_id`` (0..255, default 0), ``allow_unsigned`` (message names,
    default ``["RADIO_STATUS", "RADIO"]``, ``["*"]`` for all), ``setup_signing`` (bool, default
    true: send SETUP_SIGNING to vehicles heard unsigned). ``require_signing`` (bool, default false)
    is checked here but is a policy of the plan (``Plan.require_signing``: a vehicle link that is
    not loopback must be signed, :mod:`mission.core.plan_security`); it needs no key file.

    Raises
    ------
    SigningError
        With ``problems`` listing every bad key as ``("security.<key>", why)``.
    """
    problems: list[tuple[str, str]] = []
    if not isinstance(table, Mapping):
        raise SigningError("[security] must be a table", [("security", "expected a table")])
    for key in table:
        if key not in _SECURITY_KEYS + _POLICY_KEYS:
            allowed = ", ".join(_SECURITY_KEYS + _POLICY_KEYS)
            problems.append((f"security.{key}", f"unknown key (allowed: {allowed})"))
    link_id = table.get("signing_link_id", 0)
    if isinstance(link_id, bool) or not isinstance(link_id, int) or not 0 <= link_id <= 255:
        problems.append(("security.signing_link_id", f"expected an integer 0..255, got {link_id!r}"))
        link_id = 0
    allow = table.get("allow_unsigned", sorted(DEFAULT_ALLOW_UNSIGNED))
    if not isinstance(allow, (list, tuple)) or not all(isinstance(a, str) for a in allow):
        problems.append(("security.allow_unsigned", f"expected a list of message names, got {allow!r}"))
        allow = DEFAULT_ALLOW_UNSIGNED
    else:
        unknown = [a for a in allow if a != "*" and a not in _MSG_IDS]
        if unknown:
            problems.append(("security.allow_unsigned", f"unknown MAVLink message name(s) {unknown}"))
            allow = DEFAULT_ALLOW_UNSIGNED
    require = table.get("require_signing", False)
    if not isinstance(require, bool):
        problems.append(("security.require_signing", f"expected true or false, got {require!r}"))
    setup = table.get("setup_signing", True)
    if not isinstance(setup, bool):
        problems.append(("security.setup_signing", f"expected true or false, got {setup!r}"))
        setup = True
    config = None
    path = table.get("signing_key_file")
    if path is not None:
        if not isinstance(path, str) or not path.strip():
            problems.append(("security.signing_key_file", f"expected a file path, got {path!r}"))
        else:
            fp = Path(path).expanduser()
            if not fp.is_absolute() and base_dir is not None:
                fp = Path(base_dir) / fp
            try:
                config = SigningConfig.from_key_file(fp, link_id=link_id, allow_unsigned=frozenset(allow),
                                                     send_setup=setup)
            except SigningError as exc:
                problems.append(("security.signing_key_file", str(exc)))
    elif any(k in table for k in _SECURITY_KEYS[1:]):
        problems.append(("security.signing_key_file", "required by the other signing settings"))
    if problems:
        raise SigningError("invalid [security] section:\n" +
                           "\n".join(f"  {k}: {why}" for k, why in problems), problems)
    return config
