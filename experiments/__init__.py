"""experiments: the paper's experiments, above the science and the simulated world.

The paper reproduction (``swarmseek paper``), its figures, and the vectorised offline
source-seeking simulation (``swarmseek simulate``). Imports :mod:`formation`, :mod:`estimator`
and :mod:`sitl_mock.fields_config`; never :mod:`mission`.
"""
