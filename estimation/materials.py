"""The material table: density and friction by name, from ``materials.toml`` (each row has a source)."""

from __future__ import annotations

import difflib
import math
import numbers
import sys
from dataclasses import dataclass
from functools import cache
from importlib import resources

from estimation.errors import MaterialError, refused_number

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


@dataclass(frozen=True)
class Material:
    """A named material.

    Attributes:
        name: table key, e.g. 'wood_oak'.
        density: kg/m^3.
        friction: dry sliding friction coefficient (dimensionless).
        source: where the numbers come from.
        solref: optional MuJoCo contact solref (time constant s, damping ratio).
        solimp: optional MuJoCo contact solimp (5 numbers).
    """

    name: str
    density: float
    friction: float
    source: str
    solref: tuple[float, ...] | None = None
    solimp: tuple[float, ...] | None = None


#: The table in ``materials.toml`` that maps other names to table keys (not a material).
_ALIASES = "aliases"


@cache
def _table() -> dict:
    return tomllib.loads(resources.files("estimation").joinpath("materials.toml").read_text())


@cache
def materials() -> dict[str, Material]:
    """All materials in the table, by name (aliases not included: see :func:`aliases`)."""
    out = {}
    for name, row in _table().items():
        if name == _ALIASES:
            continue
        out[name] = Material(
            name=name,
            density=float(row["density"]),
            friction=float(row["friction"]),
            source=str(row["source"]),
            solref=tuple(row["solref"]) if "solref" in row else None,
            solimp=tuple(row["solimp"]) if "solimp" in row else None,
        )
    return out


@cache
def aliases() -> dict[str, str]:
    """Other names for table materials (``'pla'`` -> ``'pla_plastic'``, ``'aluminum'`` -> ``'aluminium'``).

    Raises:
        MaterialError: an alias in ``materials.toml`` names no material (a packaging mistake).
    """
    table = materials()
    out = {}
    for alias, target in _table().get(_ALIASES, {}).items():
        if target not in table:
            raise MaterialError(f"materials.toml: alias {alias!r} names no material ({target!r})")
        out[_normalise(alias)] = target
    return out


def _normalise(name: str) -> str:
    return name.strip().lower().replace("-", "_").replace(" ", "_")


def material(name: str) -> Material:
    """Look a material up by name or alias (case and '-'/' ' insensitive): ``material("PLA")`` is
    ``pla_plastic``.

    Raises:
        MaterialError: unknown name; the message lists close matches among names and aliases.
    """
    if not isinstance(name, str):  # material(123) was an AttributeError ('int' object has no attribute 'strip')
        raise MaterialError(f"a material is named by a string (see 'twin materials'), got {type(name).__name__}")
    table, other = materials(), aliases()
    key = _normalise(name)
    if key in table:
        return table[key]
    if key in other:
        return table[other[key]]
    close = difflib.get_close_matches(key, [*table, *other], n=3, cutoff=0.5)
    named = [f"{c} (= {other[c]})" if c in other else c for c in close]
    hint = f"; did you mean {', '.join(named)}?" if close else f"; known: {', '.join(sorted(table))}"
    raise MaterialError(f"unknown material {name!r}{hint}")


#: Density used when neither a material nor a density is given: water, so mass (kg) = volume (litres).
DEFAULT_DENSITY = 1000.0

#: The densities, kg/m^3, a message from the network may state (:mod:`sync.messages`): from below the
#: lightest aerogels (~1) to above the densest element (osmium, 22,590); every material in the table lies
#: well inside. Past them an estimate's mass is no object's (1e300 gave a 4.8e296 kg crate).
MIN_DENSITY, MAX_DENSITY = 0.1, 1e5


def resolve_density(material_name: str | None, density: float | None) -> tuple[float, Material | None]:
    """(density kg/m^3, the material or None) from a material name, an explicit density, or neither.

    Raises:
        MaterialError: unknown material, or a density that is not a positive finite number.
    """
    if material_name is not None:
        mat = material(material_name)
        return mat.density, mat
    return check_density(DEFAULT_DENSITY if density is None else density), None


def check_density(density: float) -> float:
    """Return ``density`` (kg/m^3) if it is a number from ``MIN_DENSITY`` to ``MAX_DENSITY``.

    Raises:
        MaterialError: not a real number, zero, negative, NaN, infinite or outside that range (the Python API
            took 1e306, and eigh failed on the inertia it made; 1e-300 gave an all-zero inertia).
    """
    if isinstance(density, bool) or not isinstance(density, numbers.Real):
        raise MaterialError(f"density must be a number of kg/m^3, got {str(density)[:40]!r}")
    if not math.isfinite(density) or density <= 0:
        raise MaterialError(f"density must be a positive number of kg/m^3, got {density}")
    if not MIN_DENSITY <= density <= MAX_DENSITY:
        raise MaterialError(f"density must be a positive number of kg/m^3 from {MIN_DENSITY:g} to {MAX_DENSITY:g} "
                            f"(aerogel to past osmium), got {refused_number(density, MIN_DENSITY, MAX_DENSITY)}")
    return float(density)
