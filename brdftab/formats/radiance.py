"""Radiance / LBNL WINDOW XML BSDF files (``.xml``): Klems matrices and tensor trees, read and write.

Layout (``formats/radiance.md``; schema ``BSDF-v1.4.xsd``, namespace ``http://windows.lbl.gov``)::

    <WindowElement> ... <Optical><Layer>
      <Material> <Name/> ... </Material>
      <DataDefinition> <IncidentDataStructure>Columns | Rows | TensorTree3 | TensorTree4</IncidentDataStructure>
                       <AngleBasis> ... (Klems) </AngleBasis> </DataDefinition>
      <WavelengthData> <Wavelength unit="Integral">Visible | CIE-X | CIE-Z | CIE-u | CIE-v | Solar ...</Wavelength>
        <WavelengthDataBlock> <WavelengthDataDirection>Reflection Front | Reflection Back |
                                  Transmission Front | Transmission Back</WavelengthDataDirection>
          <ColumnAngleBasis/> <RowAngleBasis/>   (Klems)   or   <AngleBasis>LBNL/Shirley-Chiu</AngleBasis>
          <ScatteringData> values </ScatteringData>
        </WavelengthDataBlock> </WavelengthData>
    </Layer></Optical></WindowElement>

The values are BSDF values f_r [sr⁻¹] (no cosine factor), read as Radiance's library reads them:
as float32, negative values set to 0. A Klems matrix (``Columns``) is a stream with rows =
outgoing patches and columns = incident patches (``bsdf[o·n + i]``; ``Rows`` is the transpose),
on :class:`~brdftab.grids.KlemsGrid`; a tensor tree is expanded to the full-resolution
:class:`~brdftab.grids.TensorTreeGrid` of its deepest leaf. Both grids are stored by netCDF and
zarr, and a table on them evaluates as Radiance's library does (constant over patch pairs, or
over tree cells).

Sides: brdftab holds one BRDF with the normal along +z, wi and wo pointing away. A file's
reflection block of either side maps to it keeping x and y of both directions (Radiance's
vectors of a back-side block have z < 0; x and y are the same). Radiance's library serves a
file's "Reflection Front" on its −z side and "Reflection Back" on +z (front and back are reversed
from WINDOW's orientation, ``bsdf_m.c``). The reader reads "Reflection Front" (WINDOW's
convention for the side facing the incident light) by default, or "Reflection Back" when the file
has no front (``side`` chooses); transmission blocks are skipped with a warning, and the other
reflection block of a file that has both is kept in the variable ``radiance_other_side``. The writer
labels brdftab's BRDF "Reflection Front" (``side = "back"`` writes "Reflection Back"; a table read
from a file keeps its side) and writes a kept other block as the other side.

Colour: Klems files hold ``Visible`` (CIE Y) and optionally ``CIE-X`` and ``CIE-Z`` blocks; trees
hold ``Visible`` and optionally ``CIE-u`` and ``CIE-v`` (u′, v′ chromaticity) trees. A file with
only ``Visible`` reads as one grey channel (``mono``), one with colour as X, Y, Z. Other
wavelengths (``Solar``, ``NIR``) are skipped with a note, as Radiance does.

Writing: a Klems value is the average of f over the outgoing patch (``patch_samples``² points at
equal projected solid angles) at the incident patch's centre direction, so Σ_o f[o][i] Λ_o (the
hemispherical reflectance Radiance's ``checkBSDF`` reports) is brdftab's directional albedo at
that incidence. A tree is written at full resolution (a top node whose children are full leaves),
each value the average over its outgoing cell at the centre of its incident cell.
"""

from __future__ import annotations

import re
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from .. import __version__
from ..colorimetry import PARAMS as COLOUR_PARAMS
from ..errors import BrdftabWarning, FormatError, ParameterError
from ..grids.klems import BASIS_NAMES, KLEMS_BASES, KlemsGrid, klems_rings
from ..grids.tensor_tree import MAX_LEVEL, TensorTreeGrid
from ..params import Param
from . import FileFormat, register

__all__ = ["read_radiance", "write_radiance", "prepare_radiance", "parse_tree", "tree_text", "SIDES", "QUANTITY"]

NAMESPACE = "http://windows.lbl.gov"
SIDES = {"front": "Reflection Front", "back": "Reflection Back"}
#: Table variable holding a file's other reflection block (same dims as ``brdf``), written back as that side.
OTHER_SIDE = "radiance_other_side"
BASES = ("klems-full", "klems-half", "klems-quarter", "tensor-tree")
GREY = ("mono",)
XYZ = ("X", "Y", "Z")
QUANTITY = ("f_r [sr-1] (BSDF values without the cosine factor), read as Radiance's BSDF library reads them: "
            "float32, negative values set to 0")
#: Default tree levels (2^level cells per coordinate) for isotropic and anisotropic trees.
DEFAULT_LEVEL = {3: 5, 4: 4}
#: Default sub-samples per dimension of each outgoing patch (Klems) or cell (tree) the writer averages.
DEFAULT_SAMPLES = {"klems": 16, "tree": 4}
_SPLIT = re.compile(r"[\s,]+")


# --------------------------------------------------------------------------------------------
# Reading


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _child(node, name):
    for c in node:
        if _local(c.tag) == name:
            return c
    return None


def _children(node, name):
    return [c for c in node if _local(c.tag) == name]


def _text(node, name, default=""):
    c = _child(node, name) if node is not None else None
    return (c.text or "").strip() if c is not None else default


def _numbers(path, text: str, what: str) -> np.ndarray:
    parts = [p for p in _SPLIT.split(text.strip()) if p]
    try:
        return np.array(parts, dtype=float)
    except ValueError:
        bad = next(p for p in parts if not _is_number(p))
        raise FormatError(f"{path}: {what}: {bad[:30]!r} is not a number") from None


def _is_number(p):
    try:
        float(p)
        return True
    except ValueError:
        return False


def sniff(head: bytes, size: int) -> bool:
    """An XML document whose root is a WINDOW ``WindowElement`` (the BSDF schema)."""
    text = head.lstrip(b"\xef\xbb\xbf").lstrip()
    return text.startswith(b"<") and b"<WindowElement" in head


def parse_tree(path, text: str, rank: int):
    """``(values, level)`` of a tensor tree's ``ScatteringData``: the tree expanded to the full
    grid of its deepest leaf, ``values`` of shape ``(2^level,) * rank`` (C order over Radiance's
    coordinates; a branch's child ``n`` holds the upper half of coordinate ``k`` when bit ``k`` of
    ``n`` is set, a leaf lists its ``2^(rank·j)`` values with the last coordinate fastest)."""
    tokens = re.findall(r"[{}]|[^\s,{}]+", text)
    pos = 0

    def node(depth):
        nonlocal pos
        if pos >= len(tokens) or tokens[pos] != "{":
            raise FormatError(f"{path}: tensor tree: expected '{{' at token {pos + 1}")
        pos += 1
        if depth > MAX_LEVEL:
            raise FormatError(f"{path}: tensor tree deeper than {MAX_LEVEL} levels")
        if pos < len(tokens) and tokens[pos] == "{":
            kids = [node(depth + 1) for _ in range(1 << rank)]
            out = ("branch", kids)
        else:
            end = pos
            while end < len(tokens) and tokens[end] not in "{}":
                end += 1
            vals = tokens[pos:end]
            pos = end
            n = len(vals)
            j = 0
            while (1 << (rank * j)) < n:
                j += 1
            if n == 0 or (1 << (rank * j)) != n:
                raise FormatError(f"{path}: tensor tree leaf of {n} values; a leaf holds 2^({rank} k) values")
            try:
                arr = np.array(vals, dtype=float)
            except ValueError:
                raise FormatError(f"{path}: tensor tree: a value that is not a number in a leaf") from None
            out = ("leaf", arr, j)
        if pos >= len(tokens) or tokens[pos] != "}":
            raise FormatError(f"{path}: tensor tree: expected '}}' at token {pos + 1}")
        pos += 1
        return out

    root = node(0)
    if pos != len(tokens):
        raise FormatError(f"{path}: tensor tree: {len(tokens) - pos} tokens after the tree")

    def depth(t, d=0):
        return d + t[2] if t[0] == "leaf" else max(depth(k, d + 1) for k in t[1])

    level = max(depth(root), 1)
    if level > MAX_LEVEL:
        raise FormatError(f"{path}: tensor tree of {2 ** level} cells per coordinate; brdftab reads up to "
                          f"{2 ** MAX_LEVEL}")
    res = 1 << level
    out = np.empty((res,) * rank)

    def fill(t, origin, size):
        if t[0] == "leaf":
            arr, j = t[1], t[2]
            block = arr.reshape((1 << j,) * rank)
            rep = size >> j
            for ax in range(rank):
                block = np.repeat(block, rep, axis=ax)
            out[tuple(slice(o, o + size) for o in origin)] = block
            return
        half = size >> 1
        for n, kid in enumerate(t[1]):
            fill(kid, [o + half * ((n >> k) & 1) for k, o in enumerate(origin)], half)

    fill(root, [0] * rank, res)
    return out, level


def _klems_basis(path, layer, block) -> str:
    names = {v.lower(): k for k, v in BASIS_NAMES.items()}
    col, row = _text(block, "ColumnAngleBasis"), _text(block, "RowAngleBasis")
    for what, name in (("ColumnAngleBasis", col), ("RowAngleBasis", row)):
        if name.lower() not in names:
            raise FormatError(f"{path}: {what} {name!r}: brdftab reads the bases "
                              f"{', '.join(BASIS_NAMES.values())}")
    if col.lower() != row.lower():
        raise FormatError(f"{path}: ColumnAngleBasis {col!r} and RowAngleBasis {row!r} differ; brdftab reads "
                          "matrices with one basis")
    basis = names[col.lower()]
    # a basis defined in the file under a standard name must be the standard one
    for ab in _children(_child(layer, "DataDefinition") or [], "AngleBasis"):
        if _text(ab, "AngleBasisName").lower() != col.lower():
            continue
        rings = []
        for blk in _children(ab, "AngleBasisBlock"):
            try:
                lower = float(_text(_child(blk, "ThetaBounds"), "LowerTheta"))
                n = int(_text(blk, "nPhis"))
            except (TypeError, ValueError):
                raise FormatError(f"{path}: AngleBasis {col!r}: a block without numeric LowerTheta / nPhis") from None
            rings.append((lower, n))
        if rings and [(float(a), int(b)) for a, b in KLEMS_BASES[basis]] != rings:
            raise FormatError(f"{path}: AngleBasis {col!r} in the file differs from the standard {col} basis")
    return basis


def _blocks(path, layer):
    """``{(wavelength, direction): block}`` of the layer's data blocks, and the skipped ones."""
    found, skipped = {}, []
    for wd in _children(layer, "WavelengthData"):
        wl = _text(wd, "Wavelength")
        for blk in _children(wd, "WavelengthDataBlock"):
            direction = " ".join(_text(blk, "WavelengthDataDirection").split())
            key = (wl.lower(), direction.lower())
            if key in found:
                raise FormatError(f"{path}: two {wl} {direction!r} blocks")
            found[key] = blk
            skipped.append((wl, direction))
    return found, skipped


def read_radiance(path, side: str | None = None):
    """Read the reflection data of a Radiance / WINDOW XML file (Klems matrix or tensor tree)
    into a :class:`~brdftab.table.Table`. ``side``: ``"front"`` ("Reflection Front", the
    default when the file has it) or ``"back"`` ("Reflection Back", the default otherwise)."""
    from ..channels import Layout
    from ..table import Table, make_table

    path = Path(path)
    if side is not None and side not in SIDES:
        raise ParameterError("side", f"expected 'front' or 'back', got {side!r}")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise FormatError(f"{path}: not a well-formed XML file ({exc})") from None
    except OSError as exc:
        raise FormatError(f"{path}: cannot read ({exc.strerror})") from None
    if _local(root.tag) != "WindowElement":
        raise FormatError(f"{path}: XML root <{_local(root.tag)}>, not a WINDOW <WindowElement> BSDF file")
    layers = _children(_child(root, "Optical") or [], "Layer")
    if not layers:
        raise FormatError(f"{path}: no <Optical><Layer> in the file")
    if len(layers) > 1:
        warnings.warn(f"{path}: {len(layers)} layers; brdftab reads the first, as Radiance does", BrdftabWarning,
                      stacklevel=3)
    layer = layers[0]
    structure = _text(_child(layer, "DataDefinition"), "IncidentDataStructure")
    kinds = {"columns": "Columns", "rows": "Rows", "tensortree3": "TensorTree3", "tensortree4": "TensorTree4"}
    if structure.lower() not in kinds:
        raise FormatError(f"{path}: IncidentDataStructure {structure!r}; brdftab reads Columns, Rows (Klems "
                          "matrices), TensorTree3 and TensorTree4")
    structure = kinds[structure.lower()]
    tree = structure.startswith("Tensor")
    found, listed = _blocks(path, layer)
    refl = {d for (wl, d) in found if wl == "visible" and d.startswith("reflection")}
    if side is None:
        side = "front" if "reflection front" in refl else "back"
    label = SIDES[side]
    if label.lower() not in refl:
        have = ", ".join(f"{wl} {d}" for wl, d in listed) or "none"
        raise FormatError(f"{path}: no Visible {label!r} block (the file has: {have}); brdftab reads reflection "
                          "(a BRDF)" + ("" if not refl else "; pass side = '" + ("back" if side == "front" else "front")
                                        + "'"))
    colour = ("cie-u", "cie-v") if tree else ("cie-x", "cie-z")
    has_colour = all((c, label.lower()) in found for c in colour)
    names = ("visible",) + (colour if has_colour else ())
    opposite = SIDES["back" if side == "front" else "front"]
    both = all((name, opposite.lower()) in found for name in names)
    labels = (label, opposite) if both else (label,)
    kept = {(name, lab.lower()) for name in names for lab in labels}
    notes = []
    other = sorted({f"{wl} {d}" for wl, d in listed if (wl.lower(), d.lower()) not in kept})
    if other:
        notes.append("skipped: " + ", ".join(other))
    trans = [f"{wl} {d}" for wl, d in listed if d.lower().startswith("transmission")]
    if trans:
        warnings.warn(f"{path}: transmission blocks skipped ({', '.join(trans)}): brdftab holds reflection (a BRDF) "
                      "only", BrdftabWarning, stacklevel=3)
    if tree:
        rank = int(structure[-1])
        per_side, level = [], 0
        for lab in labels:
            chans = []
            for name in names:
                blk = found[(name, lab.lower())]
                basis = _text(blk, "AngleBasis")
                if basis.lower() != "lbnl/shirley-chiu":
                    raise FormatError(f"{path}: tensor tree with AngleBasis {basis!r}; Radiance's trees use "
                                      "LBNL/Shirley-Chiu")
                data = _child(blk, "ScatteringData")
                vals, lv = parse_tree(path, (data.text or "") if data is not None else "", rank)
                chans.append((vals, lv))
                level = max(level, lv)
            per_side.append(chans)
        stacks = []
        for chans in per_side:
            arrays = []
            for vals, lv in chans:
                for ax in range(rank):
                    vals = np.repeat(vals, 1 << (level - lv), axis=ax)
                arrays.append(vals[: 1 << (level - 1)] if rank == 3 else vals)
            stacks.append(np.stack(arrays, axis=-1))
        grid = TensorTreeGrid(rank, level)
    else:
        basis = None
        stacks = []
        for lab in labels:
            mats = []
            for name in names:
                blk = found[(name, lab.lower())]
                b = _klems_basis(path, layer, blk)
                if basis is not None and b != basis:
                    raise FormatError(f"{path}: blocks on different Klems bases")
                basis = b
                n = int(sum(r[1] for r in KLEMS_BASES[basis]))
                data = _child(blk, "ScatteringData")
                vals = _numbers(path, (data.text or "") if data is not None else "", f"{name} {lab} ScatteringData")
                if vals.size != n * n:
                    raise FormatError(f"{path}: {name} {lab} ScatteringData holds {vals.size} values; a "
                                      f"{BASIS_NAMES[basis]} matrix holds {n} x {n} = {n * n}")
                m = vals.reshape(n, n)  # Columns: [outgoing, incident]; Rows: [incident, outgoing]
                mats.append(m.T if structure == "Columns" else m)
            stacks.append(np.stack(mats, axis=-1))
        grid = KlemsGrid(basis)
    for k, stack in enumerate(stacks):
        bad = ~np.isfinite(stack)
        if bad.any():
            raise FormatError(f"{path}: {labels[k]}: {int(bad.sum())} values that are not finite numbers")
        clamped = int((stack < 0).sum())
        if clamped:
            notes.append(f"{labels[k]}: {clamped} negative values set to 0 (as Radiance does)")
        stack = np.maximum(stack, 0.0).astype(np.float32).astype(np.float64)
        stacks[k] = _to_xyz(stack, tree) if has_colour else stack
    stack = stacks[0]
    material = _child(layer, "Material")
    provenance = {
        "title": f"Radiance XML BSDF {path.name}",
        "model": "unknown",
        "material": _text(material, "Name") or path.stem,
        "parameters": "{}",
        "isotropic": int(tree and structure == "TensorTree3"),
        "origin": "unknown",
        "source_file": path.name,
        "source_format": "radiance",
        "source_quantity": QUANTITY,
        "radiance_side": label,
        "radiance_structure": structure,
        "radiance_sides_note": ("brdftab's +z hemisphere holds the file's block with x and y of both directions kept; "
                                "Radiance's library serves 'Reflection Front' on its -z side"),
    }
    if has_colour:
        provenance["radiance_colour"] = ("X, Y, Z from the Visible (Y), CIE-u and CIE-v trees" if tree else
                                         "X, Y, Z from the CIE-X, Visible (Y) and CIE-Z matrices")
    else:
        provenance["radiance_colour"] = "mono = the Visible block (photopic, CIE Y)"
    manufacturer = _text(material, "Manufacturer")
    if manufacturer:
        provenance["radiance_manufacturer"] = manufacturer
    if notes:
        provenance["radiance_notes"] = "; ".join(notes)
    table = make_table(stack, grid, Layout(XYZ if has_colour else GREY), provenance=provenance)
    for key in ("created", "brdftab_version", "history", "source", "reciprocal", "spec_sha256"):
        table.ds.attrs.pop(key, None)
    if both:  # the file's other reflection block, kept beside the BRDF so that a copy writes it back
        var = table.ds["brdf"]
        table.ds[OTHER_SIDE] = var.copy(data=stacks[1])
        table.ds[OTHER_SIDE].attrs.update({"long_name": f"the file's {opposite} block, f_r as read",
                                           "radiance_side": opposite})
    return Table(table.ds)


def _to_xyz(stack, tree):
    """``[..., (Y, X, Z)]`` or ``[..., (Y, u', v')]`` as X, Y, Z."""
    if not tree:
        return stack[..., [1, 0, 2]]
    Y, u, v = stack[..., 0], stack[..., 1], stack[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        X = np.where(v > 0, Y * 9.0 * u / (4.0 * v), 0.0)
        Z = np.where(v > 0, Y * (12.0 - 3.0 * u - 20.0 * v) / (4.0 * v), 0.0)
    return np.stack([X, Y, np.maximum(Z, 0.0)], axis=-1)


def _from_xyz(values):
    """``[..., X, Y, Z]`` as ``[..., (Y, u', v')]`` (the tree's Visible, CIE-u and CIE-v); a node
    without light takes the chromaticity of equal energy."""
    X, Y, Z = values[..., 0], values[..., 1], values[..., 2]
    d = X + 15.0 * Y + 3.0 * Z
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(d > 0, 4.0 * X / d, 4.0 / 19.0)
        v = np.where(d > 0, 9.0 * Y / d, 9.0 / 19.0)
    return np.stack([Y, u, v], axis=-1)


# --------------------------------------------------------------------------------------------
# Writing


def _basis_options(basis, tree_rank, tree_level, anisotropic):
    if basis not in BASES:
        raise ParameterError("basis", f"expected one of {', '.join(BASES)}, got {basis!r}")
    if basis != "tensor-tree":
        for name, v in (("tree_rank", tree_rank), ("tree_level", tree_level)):
            if v is not None:
                raise ParameterError(name, "applies to basis = 'tensor-tree' only")
        return KlemsGrid(basis.split("-", 1)[1])
    rank = tree_rank if tree_rank is not None else (4 if anisotropic else 3)
    if rank not in (3, 4):
        raise ParameterError("tree_rank", f"expected 3 or 4, got {rank!r}")
    level = tree_level if tree_level is not None else DEFAULT_LEVEL[rank]
    return TensorTreeGrid(rank, level)


def check_options(basis=None, tree_rank=None, tree_level=None, side=None, patch_samples=None,
                  illuminant="D65", observer="cie1931-2", wavelengths_nm=None):
    if basis is not None or tree_rank is not None or tree_level is not None:
        _basis_options(basis or ("tensor-tree" if tree_rank or tree_level else "klems-full"), tree_rank, tree_level,
                       False)
    if side is not None and side not in SIDES:
        raise ParameterError("side", f"expected 'front' or 'back', got {side!r}")
    if (illuminant, observer) != ("D65", "cie1931-2"):
        from ..colorimetry import from_options

        from_options(illuminant, observer)


def native_grid(requested, options: dict):
    """The grid ``basis`` names (a Klems basis, or a tensor tree of ``tree_rank``/``tree_level``);
    a requested grid of that kind is kept when the options do not say otherwise."""
    basis = options.get("basis")
    rank, level = options.get("tree_rank"), options.get("tree_level")
    if isinstance(requested, KlemsGrid) and basis in (None, f"klems-{requested.basis}"):
        return requested
    if isinstance(requested, TensorTreeGrid) and basis in (None, "tensor-tree") and rank in (None, requested.rank) \
            and level in (None, requested.level):
        return requested
    if basis is None and (rank is not None or level is not None):
        basis = "tensor-tree"
    return _basis_options(basis or "klems-full", rank, level, False)


def _colour_source(brdf, illuminant, observer, wavelengths_nm):
    """``brdf`` as grey (mono) or X, Y, Z (RGB and spectra through colour-science)."""
    from ..colorimetry import XYZView, from_options, to_colour

    if brdf.spectral:
        return to_colour(brdf, from_options(illuminant, observer, "XYZ"), wavelengths_nm)
    if brdf.channels == GREY or brdf.channels == XYZ:
        return brdf
    if brdf.channels == ("R", "G", "B"):
        return XYZView(brdf, luminance_only=False)
    raise FormatError(f"a Radiance XML file stores grey (Visible) or X, Y, Z data; '{brdf.name}' has channels "
                      f"{', '.join(brdf.channels)}")


def prepare_radiance(brdf, grid, basis=None, tree_rank=None, tree_level=None, side=None,
                     patch_samples=None, illuminant="D65", observer="cie1931-2", wavelengths_nm=None):
    """The grey or X, Y, Z table on a Klems or tensor-tree grid that :func:`write_radiance` writes.

    A table already on the target grid is copied; anything else is averaged over each outgoing
    patch (Klems) or cell (tree) at the centre of each incident one, ``patch_samples``² points
    at equal projected solid angles (default 16 for Klems, 4 for trees)."""
    from ..table import Table, make_table, warn_specular_dropped

    check_options(basis, tree_rank, tree_level, side, patch_samples, illuminant, observer, wavelengths_nm)
    if tree_rank is None and not brdf.isotropic and (basis == "tensor-tree" or (
            basis is None and isinstance(grid, TensorTreeGrid))):
        tree_rank = 4  # an anisotropic source needs the anisotropic tree
    target = native_grid(grid, {"basis": basis, "tree_rank": tree_rank, "tree_level": tree_level})
    if isinstance(target, TensorTreeGrid) and target.rank == 3 and not brdf.isotropic:
        raise FormatError(f"'{brdf.name}' is anisotropic and a TensorTree3 holds isotropic data; use tree_rank = 4 "
                          "or a Klems basis")
    warn_specular_dropped(brdf, "a Radiance XML file")
    source = _colour_source(brdf, illuminant, observer, wavelengths_nm)
    if isinstance(source, Table) and source.grid.equals(target):
        return source
    from ..grids.cells import cell_averages

    n = patch_samples or DEFAULT_SAMPLES["tree" if isinstance(target, TensorTreeGrid) else "klems"]
    values = cell_averages(source, target, n).reshape(target.shape + (-1,))
    what = "patch" if isinstance(target, KlemsGrid) else "cell"
    provenance = {"radiance_sampling": f"average of f over each outgoing {what} ({n} x {n} points of equal projected "
                                       f"solid angle) at the incident {what}'s centre",
                  "cell_samples": n}
    if isinstance(brdf, Table):
        provenance.update({k: v for k, v in brdf.ds.attrs.items() if k in ("spec_sha256", "spec_file", "comment")})
    out = make_table(values, target, source.layout, brdf=source, provenance=provenance)
    # what the cells hold: only an isotropic tree is isotropic by construction, and averaging over
    # outgoing cells at incident centres is not reciprocal (the table declares neither)
    out.ds.attrs["isotropic"] = int(isinstance(target, TensorTreeGrid) and target.rank == 3)
    out.ds.attrs.pop("reciprocal", None)
    result = Table(out.ds)
    result.origin = getattr(source, "origin", "analytic")
    return result


def _encoded(table, values=None):
    """``(block names, [..., C] array in file order)``: the values (default the table's) as the file
    holds them, float32, negatives 0."""
    v = np.asarray(table.values if values is None else values, float)
    v = np.nan_to_num(v, nan=0.0, posinf=0.0, neginf=0.0)
    tree = isinstance(table.grid, TensorTreeGrid)
    if table.channels == GREY:
        names, parts = ("Visible",), v
    elif tree:
        names, parts = ("Visible", "CIE-u", "CIE-v"), _from_xyz(v)
    else:
        names, parts = ("Visible", "CIE-X", "CIE-Z"), v[..., [1, 0, 2]]
    return names, np.maximum(parts, 0.0).astype(np.float32)


def stored_radiance(table, **options):
    """The table as a reader of the file gets it back: float32 values (and X, Z through u′, v′ for a tree)."""
    from ..table import Table

    if table.channels not in (GREY, XYZ):
        return table
    _, parts = _encoded(table)
    back = parts.astype(np.float64)
    if table.channels == XYZ:
        back = _to_xyz(back, isinstance(table.grid, TensorTreeGrid))
    if np.array_equal(back, np.asarray(table.values)):
        return table
    ds = table.ds.copy(deep=False)
    ds["brdf"] = ds["brdf"].copy(data=back)
    out = Table(ds)
    out.origin = table.origin
    out.stored_dtype = "float32"
    return out


def _numbers_text(values) -> str:
    """Values as text that reads back to the same float32 (9 significant digits)."""
    return " ".join(np.char.mod("%.9g", np.asarray(values, np.float64).ravel()).tolist())


def tree_text(values, rank: int) -> str:
    """The ``ScatteringData`` of a full-resolution tree: a top node whose ``2^rank`` children are
    full leaves (``values`` of shape ``(2^L,)*rank``, or the lower half of the first coordinate
    for ``rank`` 3, whose upper half Radiance never reads: those children are ``{ 0 }``)."""
    res = values.shape[-1]
    half = res // 2
    lines = ["{"]
    for n in range(1 << rank):
        bits = [(n >> k) & 1 for k in range(rank)]
        if rank == 3 and bits[0]:
            lines.append("\t{ 0 }")
            continue
        key = tuple(slice(b * half, (b + 1) * half) for b in bits)
        lines.append("\t{ " + _numbers_text(values[key]) + " }")
    lines.append("}")
    return "\n".join(lines)


def _xml_escape(text: str) -> str:
    return str(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def write_radiance(table, path, basis=None, tree_rank=None, tree_level=None, side=None,
                   patch_samples=None, illuminant="D65", observer="cie1931-2", wavelengths_nm=None):
    """Write ``table`` (on a Klems or tensor-tree grid, grey or X, Y, Z; see :func:`prepare_radiance`)."""
    grid = table.grid
    if not isinstance(grid, (KlemsGrid, TensorTreeGrid)):
        raise FormatError(f"a Radiance XML file needs a table on a Klems or tensor-tree grid, not on {grid.describe()}")
    if table.channels not in (GREY, XYZ):
        raise FormatError(f"a Radiance XML file stores grey or X, Y, Z channels, not {table.channels}")
    names, parts = _encoded(table)
    tree = isinstance(grid, TensorTreeGrid)
    if side is None:  # a table read from a file keeps its side; anything else is WINDOW's front
        side = "back" if table.ds.attrs.get("radiance_side") == SIDES["back"] else "front"
    label = SIDES[side]
    blocks = [(label, parts)]
    if OTHER_SIDE in table.ds.data_vars and table.ds[OTHER_SIDE].shape == table.ds["brdf"].shape:
        other = table.ds[OTHER_SIDE].transpose(*table.ds["brdf"].dims).values
        blocks.append((SIDES["back" if side == "front" else "front"], _encoded(table, other)[1]))
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           f"<!-- Written by brdftab {__version__} from {_xml_escape(table.name).replace('--', '- -')}: "
           f"BRDF f_r [1/sr] as {label} (formats/radiance.md) -->",
           f'<WindowElement xmlns="{NAMESPACE}" xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
           'xsi:schemaLocation="http://windows.lbl.gov/BSDF-v1.4.xsd">',
           "<WindowElementType>System</WindowElementType>", "<FileType>BSDF</FileType>", "<Optical>", "<Layer>",
           "\t<Material>", f"\t\t<Name>{_xml_escape(table.ds.attrs.get('material', table.name))}</Name>",
           "\t\t<Manufacturer>brdftab</Manufacturer>", "\t\t<DeviceType>Other</DeviceType>",
           "\t\t<Thickness unit=\"Millimeter\">0</Thickness>", "\t</Material>",
           "\t<DataDefinition>"]
    if tree:
        out.append(f"\t\t<IncidentDataStructure>TensorTree{grid.rank}</IncidentDataStructure>")
    else:
        lo, hi, counts, _ = klems_rings(grid.basis)
        out += ["\t\t<IncidentDataStructure>Columns</IncidentDataStructure>", "\t\t<AngleBasis>",
                f"\t\t\t<AngleBasisName>{grid.basis_name}</AngleBasisName>"]
        for a, b, c in zip(lo, hi, counts):
            centre = 0.0 if a == 0 else 0.5 * (a + b)
            out += ["\t\t\t<AngleBasisBlock>", f"\t\t\t\t<Theta>{centre:g}</Theta>", f"\t\t\t\t<nPhis>{c}</nPhis>",
                    "\t\t\t\t<ThetaBounds>", f"\t\t\t\t\t<LowerTheta>{a:g}</LowerTheta>",
                    f"\t\t\t\t\t<UpperTheta>{b:g}</UpperTheta>", "\t\t\t\t</ThetaBounds>", "\t\t\t</AngleBasisBlock>"]
        out.append("\t\t</AngleBasis>")
    out.append("\t</DataDefinition>")
    detectors = {"Visible": "ASTM E308 1931 Y.dsp", "CIE-X": "ASTM E308 1931 X.dsp", "CIE-Z": "ASTM E308 1931 Z.dsp",
                 "CIE-u": "ASTM E308 1931 Y.dsp", "CIE-v": "ASTM E308 1931 Y.dsp"}
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write("\n".join(out) + "\n")
        for c, name in enumerate(names):
            fh.write("\t<WavelengthData>\n\t\t<LayerNumber>System</LayerNumber>\n"
                     f"\t\t<Wavelength unit=\"Integral\">{name}</Wavelength>\n"
                     "\t\t<SourceSpectrum>CIE Illuminant D65 1nm.ssp</SourceSpectrum>\n"
                     f"\t\t<DetectorSpectrum>{detectors[name]}</DetectorSpectrum>\n")
            for lab, values in blocks:
                fh.write("\t\t<WavelengthDataBlock>\n"
                         f"\t\t\t<WavelengthDataDirection>{lab}</WavelengthDataDirection>\n")
                if tree:
                    fh.write("\t\t\t<AngleBasis>LBNL/Shirley-Chiu</AngleBasis>\n")
                else:
                    fh.write(f"\t\t\t<ColumnAngleBasis>{grid.basis_name}</ColumnAngleBasis>\n"
                             f"\t\t\t<RowAngleBasis>{grid.basis_name}</RowAngleBasis>\n")
                fh.write("\t\t\t<ScatteringDataType>BRDF</ScatteringDataType>\n\t\t\t<ScatteringData>\n")
                v = values[..., c]
                if tree:
                    fh.write(tree_text(v, grid.rank))
                else:
                    fh.write("\n".join(_numbers_text(row) for row in v.T))  # rows = outgoing, columns = incident
                fh.write("\n\t\t\t</ScatteringData>\n\t\t</WavelengthDataBlock>\n")
            fh.write("\t</WavelengthData>\n")
        fh.write("</Layer>\n</Optical>\n</WindowElement>\n")


register(FileFormat(
    name="radiance",
    extensions=(".xml",),
    description="Radiance / LBNL WINDOW XML BSDF: writes and reads f_r [sr-1, no cosine] as Klems matrices (full "
                "145 x 145, half, quarter: the average of f over each outgoing patch at each incident patch's "
                "centre) or tensor trees (TensorTree3 isotropic, TensorTree4 anisotropic), Visible (Y) or X, Y, Z; "
                "brdftab's BRDF is written as 'Reflection Front' (WINDOW's convention; Radiance's library serves it "
                "on its -z side), and the reader takes 'Reflection Front', else 'Reflection Back', skipping "
                "transmission blocks",
    read=read_radiance,
    write=write_radiance,
    sniff=sniff,
    native_grid=native_grid,
    prepare=prepare_radiance,
    check_options=check_options,
    stored=stored_radiance,
    colour=True,
    params=(
        Param("basis", "choice", "klems-full (145 x 145 patches, the default; a table on a Klems or tensor-tree "
              "grid keeps its own), klems-half, klems-quarter or tensor-tree.", default=None, choices=BASES),
        Param("tree_rank", "int", "Tensor tree: 3 (TensorTree3, isotropic) or 4 (TensorTree4, anisotropic); default "
              "3 for an isotropic source, 4 otherwise.", default=None, minimum=3, maximum=4),
        Param("tree_level", "int", "Tensor tree: 2^level cells per coordinate (default 5 for rank 3, 4 for rank 4).",
              default=None, minimum=1, maximum=MAX_LEVEL),
        Param("side", "choice", "Which block the BRDF is written as: front ('Reflection Front', WINDOW's convention, "
              "served by Radiance's library on its -z side; the default) or back ('Reflection Back', served on +z). "
              "A table read from an XML file keeps its side, and a file's other reflection block, kept beside it, "
              "is written as the other side.", default=None, choices=tuple(SIDES)),
        Param("patch_samples", "int", "Points per dimension averaged over each outgoing patch or cell (default 16 "
              "for Klems, 4 for trees).", default=None, minimum=1, maximum=64),
    ) + COLOUR_PARAMS,
    precision=1e-6,  # float32 samples; X and Z of a tree pass through float32 u', v'
))
