"""Setup files as TOML: reading one with clear errors, writing the fully resolved setup.

:func:`dump_setup` writes (with ``tomli-w``) the fully resolved TOML that reads back to an equal
:class:`~sim.setup.schema.Setup`; a dataset keeps it as ``setup.toml`` next to its captures.
"""
from __future__ import annotations

import tomllib
from pathlib import Path

import tomli_w

from sim.errors import SetupError
from sim.options import flat_items
from sim.setup.schema import SECTIONS, Setup
from sim.setup.validation import parse_setup

_HEADER = "# procam setup, fully resolved (metres, degrees, linear RGB)\n"


def read_toml(path: Path | str, what: str = "setup file") -> dict:
    """The mapping of a TOML file (``what`` it is, for messages). A UTF-8 byte-order mark, which
    some editors write and TOML does not allow, is skipped.

    Raises
    ------
    SetupError
        Naming the file, if it cannot be read or is not valid TOML.
    """
    try:
        with open(path, "rb") as f:
            return tomllib.loads(f.read().decode("utf-8-sig"))
    except OSError as exc:
        raise SetupError(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:  # TOML is UTF-8
        raise SetupError(f"{path}: not valid TOML ({exc})") from None


def load_setup(path: Path | str) -> Setup:
    """Read and validate a setup file.

    Parameters
    ----------
    path : Path or str
        A TOML setup file; a relative ``surface.texture`` path is relative to its folder.

    Returns
    -------
    Setup

    Raises
    ------
    SetupError
        If the file cannot be read, is not TOML, or a key or value is invalid.
    """
    path = Path(path)
    return parse_setup(read_toml(path), str(path), path.parent)


def dump_setup(setup: Setup) -> str:
    """The fully resolved setup as TOML: every value, sections and keys in schema order (a
    surface's own keys in the place of :attr:`~sim.setup.schema.SurfaceConfig.shape`).

    ``parse_setup(tomllib.loads(dump_setup(s))) == s``. An ambient light given by colour
    temperature is written as ``temperature`` and ``intensity``, with the resolved radiance in
    a comment at the top.

    Parameters
    ----------
    setup : Setup

    Returns
    -------
    str

    Examples
    --------
    >>> from sim.setup.schema import Setup
    >>> print(dump_setup(Setup("bare")).splitlines()[1])
    name = "bare"
    """
    header = _HEADER
    document: dict = {"name": setup.name}
    for section in SECTIONS:
        cfg = getattr(setup, section)
        if section == "ambient" and cfg.temperature is not None:
            header += f"# resolved linear RGB radiance = [{', '.join(map(repr, cfg.radiance))}]\n"
            document[section] = {"temperature": cfg.temperature, "intensity": cfg.intensity}
        else:
            document[section] = {k: v for k, v in flat_items(cfg).items() if v is not None}
    return header + tomli_w.dumps(document)
