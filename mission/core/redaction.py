"""Secrets never reach a log: how a field is marked secret and what is written instead.

A dataclass field holding a secret (a signing key, a password) is declared with
:func:`secret_field`; the serialiser of every log, summary and publication
(:func:`mission.telemetry.mission_log.to_jsonable`) writes :data:`REDACTED` in its place, and
writes byte strings only as their length (:func:`describe_bytes`) and redacts every mapping
entry named in :data:`SECRET_NAMES`, so a new secret field cannot leak by default. A class that wants to say more about its secret (e.g. a key's fingerprint)
gives itself a ``to_json()`` method, which the serialiser prefers.
"""
from __future__ import annotations

from dataclasses import Field, field

__all__ = ["REDACTED", "SECRET_METADATA_KEY", "SECRET_NAMES", "describe_bytes", "is_secret_field", "secret_field"]

#: what a log shows in place of a secret field
REDACTED = "<redacted>"
#: the dataclass field metadata key that marks a secret
SECRET_METADATA_KEY = "secret"
#: names of mapping entries (and MAVLink message fields) always redacted: SETUP_SIGNING's
#: ``secret_key``, a zenoh ``password``, a key file's ``passphrase``, a TLS ``private_key``
SECRET_NAMES = frozenset({"secret_key", "password", "passphrase", "private_key", "signing_key"})


def secret_field(**kwargs) -> Field:
    """A dataclass ``field`` holding a secret: out of ``repr`` and redacted in every log.

    Parameters
    ----------
    **kwargs
        Passed to :func:`dataclasses.field` (``default``, ``default_factory`` ...).
    """
    metadata = dict(kwargs.pop("metadata", None) or {})
    metadata[SECRET_METADATA_KEY] = True
    return field(repr=False, metadata=metadata, **kwargs)


def is_secret_field(f: Field) -> bool:
    """True if the dataclass field ``f`` was declared with :func:`secret_field`."""
    return bool(f.metadata.get(SECRET_METADATA_KEY, False))


def describe_bytes(data) -> str:
    """``<N bytes>``: how a log shows a byte string (never its content)."""
    return f"<{len(data)} bytes>"
