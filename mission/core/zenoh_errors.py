"""Plain-words messages for zenoh sessions that cannot be opened (no Rust source paths).

zenoh's errors end with the Rust source location (``... at /root/.cargo/.../orchestrator.rs:447.``)
and do not say which of the plan's endpoints is at fault; :func:`zenoh_open_message` names the
endpoints and the likely cause.
"""
from __future__ import annotations

import re

__all__ = ["clean_zenoh_error", "zenoh_open_message"]

_RUST_LOCATION = re.compile(r"\s+at\s+\S+\.rs:\d+\.?")


def clean_zenoh_error(exc) -> str:
    """The error's text without the Rust source locations."""
    return _RUST_LOCATION.sub("", str(exc)).strip().rstrip("!. ")


def zenoh_open_message(exc, zplan) -> str:
    """Why the zenoh session of ``zplan`` (:class:`mission.core.zenoh_security.ZenohPlan`) could
    not be opened, for the operator."""
    text = clean_zenoh_error(exc)
    connect, listen, mode = ", ".join(zplan.connect), ", ".join(zplan.listen), zplan.mode
    if "connect" in text.lower() and connect:
        return (f"cannot reach the zenoh endpoint(s) {connect} (mode {mode}): nothing answers there; is the "
                f"zenoh router or the sensors' listener running, and is the address right? (zenoh: {text})")
    if listen and ("bind" in text.lower() or "listen" in text.lower() or "address" in text.lower()):
        return (f"cannot listen on {listen}: the address is in use or not this machine's "
                f"(another swarmseek, a mock fleet?) (zenoh: {text})")
    return f"cannot open the zenoh session (mode {mode}; connect [{connect}], listen [{listen}]): {text}"
