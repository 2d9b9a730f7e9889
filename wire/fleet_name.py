"""The one rule for fleet names: the plan's ``fleet``, ``ctl``/``watch``'s FLEET, ``--fleet``.

A fleet name is one chunk of every zenoh key of a mission (``swarmseek/<fleet>/mission/state``,
``.../mission/control``, ``.../vehicle/<sysid>/sensor``). It must name exactly one fleet: a
wildcard (``*``, ``**``, ``$*``) would address every fleet on the network (``ctl '**' land``),
a ``/`` would add key levels, and zenoh refuses an empty chunk, ``#``, ``?`` and a ``$`` not in
``$*``. Whitespace, control characters and a leading ``@`` (zenoh's verbatim chunks, which
wildcards never match) are refused too, and a name is at most :data:`FLEET_NAME_MAX_CHARS`
characters. The plan (:mod:`mission.core.plan`) and every command line that takes a fleet
name (``mission.cli``, for ``ctl``, ``watch``, ``sitl``, ``mock`` and ``sensor``) check it here.
"""
from __future__ import annotations

__all__ = ["FLEET_NAME_MAX_CHARS", "fleet_name_problem", "check_fleet_name"]

#: longest fleet name accepted (it is in every key and every reading's payload)
FLEET_NAME_MAX_CHARS = 64
#: characters a zenoh key chunk naming one fleet must not hold
_FORBIDDEN = "/*$?#"


def fleet_name_problem(name) -> str | None:
    """Why ``name`` is not a valid fleet name, or None when it is.

    Parameters
    ----------
    name : object
        The candidate (anything: a non-string is a problem too).

    Returns
    -------
    str or None
        A one-line reason naming the offending character, e.g. ``"must not contain '*' (a zenoh
        wildcard or key separator: ...)"``.
    """
    if not isinstance(name, str):
        return f"must be a string, got {type(name).__name__}"
    if not name:
        return "must not be empty"
    if len(name) > FLEET_NAME_MAX_CHARS:
        return f"must be at most {FLEET_NAME_MAX_CHARS} characters, got {len(name)}"
    bad = next((ch for ch in name if ch in _FORBIDDEN), None)
    if bad is not None:
        return (f"must not contain {bad!r}: a fleet name is one zenoh key chunk, without wildcards "
                f"('*', '**', '$*' would address every fleet) or the characters / * $ ? #")
    bad = next((ch for ch in name if ch.isspace() or not ch.isprintable()), None)
    if bad is not None:
        return f"must not contain whitespace or control characters, got {bad!r}"
    if name.startswith("@"):
        return "must not start with '@' (a zenoh verbatim chunk, which no subscriber's wildcard matches)"
    return None


def check_fleet_name(name) -> str:
    """``name`` if it is a valid fleet name.

    Raises
    ------
    ValueError
        ``fleet name <name!r> <why>`` (see :func:`fleet_name_problem`).
    """
    problem = fleet_name_problem(name)
    if problem:
        raise ValueError(f"fleet name {_shown(name)} {problem}")
    return name


def _shown(name) -> str:
    text = repr(name)
    return text if len(text) <= 40 else text[:37] + "..."
