"""The ``twin`` command line. Thin: parse, call library functions, print, map errors to exit 2."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Callable
from pathlib import Path

from estimation.errors import TwinError

log = logging.getLogger("twin")

EXIT_BAD_INPUT = 2


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the process exit code (0 ok, 2 bad input)."""
    parser = _parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    handler: Callable[[argparse.Namespace], int] = args.handler
    try:
        return handler(args)
    except TwinError as exc:
        print(f"twin {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="twin", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages to stderr")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("estimate", help="estimate volume, mass, centre of mass and inertia from a cloud")
    p.add_argument("cloud", type=Path, help="PLY, PCD, XYZ/TXT, NPY or NPZ point cloud")
    dens = p.add_mutually_exclusive_group()
    dens.add_argument("--density", type=float, help="kg/m^3")
    dens.add_argument("--material", help="a name from the material table (e.g. wood_oak)")
    p.add_argument("--units", default="m", choices=["m", "cm", "mm"], help="units of the file (default m)")
    p.add_argument("--method", default="auto", choices=["auto", "obb", "hull", "surface"])
    p.add_argument("--viewpoint", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="sensor position (file units) to orient estimated normals towards")
    p.add_argument("--mesh-out", type=Path, help="write the reconstructed mesh (.stl, .ply, .obj)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(handler=_cmd_estimate)

    p = sub.add_parser("materials", help="list the material table")
    p.set_defaults(handler=_cmd_materials)
    return parser


#: Density used when neither --density nor --material is given: water, so mass (kg) = volume (litres).
DEFAULT_DENSITY = 1000.0


def _cmd_estimate(args: argparse.Namespace) -> int:
    import numpy as np

    from estimation import estimate, load_cloud
    from estimation.materials import check_density, material
    from estimation.units import unit_scale

    scale = unit_scale(args.units)
    name = None
    if args.material is not None:
        mat = material(args.material)
        density, name = mat.density, mat.name
    else:
        density = check_density(args.density if args.density is not None else DEFAULT_DENSITY)
    t0 = time.perf_counter()
    cloud = load_cloud(args.cloud, scale=scale)
    read = time.perf_counter() - t0
    viewpoint = None if args.viewpoint is None else np.asarray(args.viewpoint) * scale
    result = estimate(cloud, density, method=args.method, material=name, viewpoint=viewpoint,
                      read_seconds=read)
    if args.mesh_out is not None:
        _write_mesh(result.vertices, result.faces, args.mesh_out)
    seconds = time.perf_counter() - t0
    record = estimate_to_json(result, seconds)
    if args.json:
        print(json.dumps(record))
    else:
        _print_estimate(record)
    return 0


def estimate_to_json(result, seconds: float) -> dict:  # type: ignore[no-untyped-def]
    """The stable JSON form of a :class:`~estimation.PhysicalEstimate` (the CLI contract)."""
    m = result.mass
    return {
        "volume_m3": m.volume,
        "mass_kg": m.mass,
        "density_kg_m3": m.density,
        "material": result.material,
        "center_of_mass_m": m.center_of_mass.tolist(),
        "inertia_kg_m2": m.inertia.tolist(),
        "principal_moments_kg_m2": m.principal_moments.tolist(),
        "principal_axes": m.principal_axes.tolist(),
        "obb": {
            "center_m": result.obb.center.tolist(),
            "extents_m": result.obb.extents.tolist(),
            "rotation": result.obb.rotation.tolist(),
        },
        "method": result.method,
        "points_in": result.points_in,
        "points_used": result.points_used,
        "watertight": result.watertight,
        "cell_m": result.cell,
        "seconds": seconds,
        "timings_s": {k: getattr(result.timings, k) for k in
                      ("read", "downsample", "normals", "reconstruct", "mass_properties")},
        "warnings": list(result.warnings),
    }


def _print_estimate(record: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"estimate ({record['method']})", show_header=False)
    com = ", ".join(f"{x:.4f}" for x in record["center_of_mass_m"])
    rows = [
        ("volume", f"{record['volume_m3']:.6g} m^3 ({record['volume_m3'] * 1e6:.2f} cm^3)"),
        ("density", f"{record['density_kg_m3']:g} kg/m^3" + (f" ({record['material']})" if record["material"] else "")),
        ("mass", f"{record['mass_kg']:.6g} kg"),
        ("centre of mass", f"[{com}] m"),
        ("principal moments", ", ".join(f"{x:.4g}" for x in record["principal_moments_kg_m2"]) + " kg m^2"),
        ("OBB extents", ", ".join(f"{x:.4f}" for x in record["obb"]["extents_m"]) + " m"),
        ("points", f"{record['points_in']} in, {record['points_used']} used"),
        ("watertight", str(record["watertight"])),
        ("time", f"{record['seconds']:.3f} s"),
    ]
    for key, value in rows:
        table.add_row(key, value)
    console = Console()
    console.print(table)
    for warning in record["warnings"]:
        console.print(f"[yellow]warning:[/yellow] {warning}")


def _write_mesh(vertices, faces, path: Path) -> None:  # type: ignore[no-untyped-def]
    import trimesh

    try:
        trimesh.Trimesh(vertices, faces, process=False).export(path)
    except (OSError, ValueError) as exc:
        raise TwinError(f"{path}: cannot write mesh ({exc})") from exc


def _cmd_materials(args: argparse.Namespace) -> int:
    from estimation.materials import materials

    for mat in materials().values():
        print(f"{mat.name:18s} {mat.density:8.0f} kg/m^3  friction {mat.friction:.2f}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
