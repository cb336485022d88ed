"""The learning side of procam: compensation methods, their training, their evaluation, the CLI.

Sub-packages: :mod:`compensation.methods` (one module per method and the registry),
:mod:`compensation.training` (configuration, the training loop, run directories) and
:mod:`compensation.evaluation` (metrics, losses, closed loop, benchmark tables).
"""
