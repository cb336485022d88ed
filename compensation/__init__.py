"""The learning side of procam: compensation methods, training, metrics, benchmark and the CLI.

Every method registers itself in :data:`compensation.methods.METHODS` when its module is
imported; importing the baselines here makes the registry complete whichever module comes first.
"""
from compensation import methods, nayar, pix2pix, tps  # noqa: F401
