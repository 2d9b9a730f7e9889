"""A minimal field plug-in (docs/fields.md, "Your own field"): a Gaussian puff that breathes.

Use it from this directory (or with it on PYTHONPATH)::

    cd examples/fields
    PYTHONPATH=$PWD swarmseek run --field-python my_field:make --json

``make`` is the factory: it gets the plan's ``[field]`` table (a dict; here ``source_enu_m``,
``width_m`` and ``period_s``, all optional) and returns the field.
"""
import numpy as np


class BreathingPuff:
    """``(1 + 0.05 sin(2 pi t / period)) exp(-|r - source|^2 / (2 width^2))``, ENU m, seconds."""

    time_dependent = True  # value() reads t_s

    def __init__(self, source_enu_m, width_m, period_s):
        self.source = np.asarray(source_enu_m, dtype=float)
        self.width_m = float(width_m)
        self.period_s = float(period_s)

    def value(self, points_enu_m, t_s):
        """points_enu_m: (M, 3) ENU m; t_s: the world's clock, s. Returns (M,), finite, >= 0."""
        d2 = np.sum((points_enu_m - self.source) ** 2, axis=-1)
        pulse = 1.0 + 0.05 * np.sin(2.0 * np.pi * t_s / self.period_s)
        return pulse * np.exp(-d2 / (2.0 * self.width_m ** 2))

    def source_enu(self):
        """Where the seekers should end: the puff's centre, ENU m."""
        return self.source


def make(table):
    """The factory: the plan's [field] table in, the field out."""
    return BreathingPuff(table.get("source_enu_m", (10.0, -5.0, 12.0)),
                         table.get("width_m", 15.0), table.get("period_s", 60.0))
