"""How large a built folder's MuJoCo XML may be before ``twin run`` hands it to MuJoCo.

A folder ``twin build`` wrote may have been edited since, and MuJoCo expands ``<replicate>`` while it parses:
the guard reads the XML itself, cheaply, and refuses what would take minutes and gigabytes.
"""

from __future__ import annotations

from pathlib import Path

from estimation.errors import TwinError

#: XML a folder's model may hold, scene.xml and the files it includes together: 1000 objects
#: (scenes.scenefile.MAX_OBJECTS) of 64 hulls each write about 17 MB.
MAX_MODEL_XML_BYTES = 32 * 2**20
#: XML elements one object of a built folder is allowed: body, inertial, joint, visual geom and mesh, primitive geom
#: (6), and a geom and a mesh for each of up to 64 hulls (four times CoACD's default cap). Times MAX_OBJECTS, that
#: is 134,000 elements, which MuJoCo parses in about 8 s and 1.1 GB at worst (all of them replicated geoms); a
#: nested <replicate count="1000"> pair (10^6 geoms) held 1.6 GB and had not finished in 30 s.
MODEL_ELEMENTS_PER_OBJECT = 6 + 2 * 64


def check_model_size(path: Path) -> None:
    """Refuse a folder's model that MuJoCo would spend minutes and gigabytes parsing, before it starts.

    Counts the XML elements of ``path`` and of the files it includes or loads as ``<model>`` assets (read
    relative to its folder, as MuJoCo does), each multiplied by the counts of the ``<replicate>`` elements around
    it, and an ``<attach>`` as the elements of the model it attaches. Files that are missing or repeated are
    skipped: MuJoCo names them in its own error.

    Raises:
        TwinError: more than MAX_MODEL_XML_BYTES of XML, XML that is not well-formed, an included file that is
            not a regular file (a FIFO, /dev/zero), or more elements than MAX_OBJECTS x MODEL_ELEMENTS_PER_OBJECT.
    """
    import xml.etree.ElementTree as ET

    from scenes.scenefile import MAX_OBJECTS

    limit = MAX_OBJECTS * MODEL_ELEMENTS_PER_OBJECT
    seen: set[Path] = set()
    models: dict[str, int] = {}  # <model> asset name -> its elements
    folders: dict[str, str] = {}  # <compiler> meshdir, texturedir, assetdir
    left = MAX_MODEL_XML_BYTES

    def elements(file: Path) -> int:
        nonlocal left
        try:
            file = file.resolve()
            if file in seen or not file.exists():
                return 0
            if not file.is_file():  # MuJoCo would wait on a FIFO for ever
                raise TwinError(f"{path}: it includes {file}, which is not a regular file")
            seen.add(file)
            with file.open("rb") as f:
                text = f.read(left + 1)
        except (OSError, RuntimeError):  # RuntimeError: a loop of links (Python 3.11's resolve); MuJoCo says why
            return 0
        left -= len(text)
        if left < 0:
            raise TwinError(f"{path}: the model is over {MAX_MODEL_XML_BYTES // 2**20} MiB of XML "
                            f"(with what it includes); a built scene of {MAX_OBJECTS} objects is far less")
        try:
            root = ET.fromstring(text)
        except ET.ParseError as exc:
            raise TwinError(f"{file}: not well-formed XML ({exc})") from None
        total, stack = 1, [(root, 1)]
        while stack:  # not recursion: a deep nesting would reach Python's recursion limit
            parent, times = stack.pop()
            for child in parent:
                inner = times
                if child.tag == "replicate":
                    inner = min(times * _replicate_count(child.get("count")), limit + 1)
                elif child.tag in ("include", "model") and child.get("file"):
                    inner = min(times * max(elements(path.parent / child.get("file", "")), 1), limit + 1)
                    if child.tag == "model":
                        models[child.get("name", "")] = inner
                elif child.tag == "attach":
                    inner = min(times * max(models.get(child.get("model", ""), 0), 1), limit + 1)
                elif child.tag == "compiler":
                    folders.update({k: child.get(k, "") for k in ("meshdir", "texturedir", "assetdir") if child.get(k)})
                elif child.get("file"):  # a mesh, texture, height field or skin: MuJoCo reads a FIFO for ever too
                    _regular(path, child.get("file", ""), folders)
                _check_allocation(file, child)
                total = min(total + inner, limit + 1)
                stack.append((child, inner if child.tag == "replicate" else times))
        return total

    if elements(path) > limit:
        raise TwinError(f"{path}: the model expands to more than {limit:,} XML elements (<replicate> counts "
                        f"multiplied out); {MAX_OBJECTS} objects of {(MODEL_ELEMENTS_PER_OBJECT - 6) // 2} hulls "
                        "each are the most 'twin run' takes")


#: Largest count an element may ask MuJoCo to allocate for by itself (height field samples, flex vertices,
#: keyframes or user values times what each holds): a built scene has none of these; 4096 x 4096 samples is
#: a detailed terrain. An edited folder's <size nkey="100000000"/> compiled for minutes, a 30000 x 30000
#: height field took 7 GB, a 20000 x 20000 builtin texture 2.4 GB.
MAX_ELEMENT_ALLOCATION = 4096 * 4096

#: The attributes counted, per element: their values multiplied.
_ALLOCATING = {"hfield": (("nrow", "ncol"),), "flexcomp": (("count",),), "texture": (("width", "height"),),
               "size": (("nkey",), ("nuser_body",), ("nuser_jnt",), ("nuser_geom",), ("nuser_site",),
                        ("nuser_cam",), ("nuser_tendon",), ("nuser_actuator",), ("nuser_sensor",))}


def _check_allocation(file: Path, element) -> None:  # type: ignore[no-untyped-def]
    """Refuse an element whose counts (:data:`_ALLOCATING`) multiply past MAX_ELEMENT_ALLOCATION."""
    for names in _ALLOCATING.get(element.tag, ()):
        product = 1
        for name in names:
            for word in (element.get(name) or "").split():
                try:
                    product *= max(int(float(word)), 1)
                except (ValueError, OverflowError):
                    continue  # MuJoCo names what it cannot read
        if product > MAX_ELEMENT_ALLOCATION:
            raise TwinError(f"{file}: <{element.tag} {' '.join(names)}> asks for {product:,} entries, more than "
                            f"the {MAX_ELEMENT_ALLOCATION:,} 'twin run' takes")


def _replicate_count(text: str | None) -> int:
    """A <replicate>'s count; 1 for one MuJoCo will refuse anyway (missing or not a number)."""
    try:
        return max(int(text or "1"), 0)
    except ValueError:
        return 1


def _regular(model: Path, name: str, folders: dict[str, str]) -> None:
    """Refuse an asset file that exists but is not a regular file, wherever MuJoCo may look for it (beside the
    model, or in its compiler's asset folders)."""
    for folder in ("", *folders.values()):
        candidate = model.parent / folder / name
        try:
            if candidate.exists() and not candidate.is_file():
                raise TwinError(f"{model}: it reads {candidate}, which is not a regular file")
        except OSError:
            continue
