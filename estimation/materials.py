"""The material table: density and friction by name, from ``materials.toml`` (each row has a source)."""

from __future__ import annotations

import difflib
import math
import sys
from dataclasses import dataclass
from functools import cache
from importlib import resources

from estimation.errors import MaterialError

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


@cache
def materials() -> dict[str, Material]:
    """All materials in the table, by name."""
    text = resources.files("estimation").joinpath("materials.toml").read_text()
    table = tomllib.loads(text)
    out = {}
    for name, row in table.items():
        out[name] = Material(
            name=name,
            density=float(row["density"]),
            friction=float(row["friction"]),
            source=str(row["source"]),
            solref=tuple(row["solref"]) if "solref" in row else None,
            solimp=tuple(row["solimp"]) if "solimp" in row else None,
        )
    return out


def material(name: str) -> Material:
    """Look a material up by name (case and '-'/' ' insensitive).

    Raises:
        MaterialError: unknown name; the message lists close matches.
    """
    table = materials()
    key = name.strip().lower().replace("-", "_").replace(" ", "_")
    if key in table:
        return table[key]
    close = difflib.get_close_matches(key, list(table), n=3, cutoff=0.5)
    hint = f"; did you mean {', '.join(close)}?" if close else f"; known: {', '.join(sorted(table))}"
    raise MaterialError(f"unknown material {name!r}{hint}")


#: Density used when neither a material nor a density is given: water, so mass (kg) = volume (litres).
DEFAULT_DENSITY = 1000.0


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
    """Return ``density`` (kg/m^3) if it is a positive finite number.

    Raises:
        MaterialError: zero, negative, NaN or infinite.
    """
    if not math.isfinite(density) or density <= 0:
        raise MaterialError(f"density must be a positive number of kg/m^3, got {density}")
    return float(density)
