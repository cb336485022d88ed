"""Setup files: the validated description of one simulated projector-camera setup.

A setup file (TOML, ``scenes/*.toml``) has a ``name`` and the sections ``surface``, ``projector``,
``camera``, ``ambient``, ``render`` and ``registration``; every key but ``name`` is optional. The package holds

- :mod:`~sim.setup.schema`: the frozen dataclasses (:class:`Setup` and its sections), each key
  declared once with its default, kind, range and unit (:mod:`sim.options`) and documented by
  its docstring; a surface's own keys are declared by its module in :mod:`sim.surfaces`;
- :mod:`~sim.setup.validation`: :func:`parse_setup`, a mapping checked into a :class:`Setup` by
  the one validator of :mod:`sim.options` plus the checks that span keys, with errors naming
  the file, the dotted key and what was expected;
- :mod:`~sim.setup.toml`: :func:`load_setup` (a file) and :func:`dump_setup` (the fully
  resolved TOML, which reads back to an equal :class:`Setup`);
- :mod:`~sim.setup.suites`: :func:`load_suite`, the shipped scenes (:func:`scene_path`),
  :func:`load_setups`, what a command line names, :func:`select_setups` (``--only``),
  :func:`suite_test_frames`, the test frames a suite asks for, and :func:`merge_setup`, partial
  overrides deep-merged onto a setup mapping.
"""
from sim.errors import SetupError
from sim.setup.schema import (NAME_PATTERN, TEMPERATURE_RANGE, AmbientConfig, CameraConfig,
                              ProjectorConfig, RegistrationConfig, RenderConfig, Setup, SurfaceConfig,
                              temperature_rgb)
from sim.setup.suites import (load_setups, load_suite, merge_setup, scene_path, select_setups,
                              suite_test_frames)
from sim.setup.toml import dump_setup, load_setup
from sim.setup.validation import parse_setup

__all__ = ["NAME_PATTERN", "TEMPERATURE_RANGE", "AmbientConfig", "CameraConfig",
           "ProjectorConfig", "RegistrationConfig", "RenderConfig", "Setup", "SetupError",
           "SurfaceConfig", "dump_setup", "load_setup", "load_setups", "load_suite", "merge_setup",
           "parse_setup", "scene_path", "select_setups", "suite_test_frames", "temperature_rgb"]
