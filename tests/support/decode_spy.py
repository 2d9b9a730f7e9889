"""A spy on a module's ``decode_single_frame`` (the fast MAVLink decoder, :mod:`wire.fast_decode`)."""
from __future__ import annotations


def spy_on_fast_decoder(monkeypatch, module) -> list[bool]:
    """Wrap ``module.decode_single_frame`` for the test (``monkeypatch`` restores it).

    Returns
    -------
    list of bool
        Filled as the test runs: for every call, whether the fast decoder returned a message.
    """
    hits: list[bool] = []
    real = module.decode_single_frame

    def spy(data):
        msg = real(data)
        hits.append(msg is not None)
        return msg

    monkeypatch.setattr(module, "decode_single_frame", spy)
    return hits
