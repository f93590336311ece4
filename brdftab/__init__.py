"""brdftab: tabulate, convert and validate BRDFs.

A BRDF is anything that evaluates ``f(wi, wo, wavelengths)`` vectorized, in sr⁻¹, with unit
directions pointing away from the surface (normal +z). Analytic models
(:mod:`brdftab.models`) and tables read from files (:class:`brdftab.table.Table`) both do.

Script API::

    import brdftab
    brdf = brdftab.from_spec("specs/ggx-gold.toml")        # the spec's model
    table = brdftab.open("ggx-gold.nc")                     # a table from any supported file
    ggx = brdftab.models.create("microfacet", alpha=0.3)    # a model by name
    f = ggx.eval(wi, wo)                                    # [..., n_channels] in 1/sr
    brdftab.save(ggx, "ggx.nc", grid=brdftab.grids.merl_grid())
    fit = brdftab.fit(table, "microfacet", free=["alpha"], params={"alpha": 0.5})   # a model fitted to a table
"""

from __future__ import annotations

import importlib

from ._version import __version__

__all__ = ["__version__", "BRDF", "BrdftabError", "Table", "fit", "from_spec", "geometry", "grids", "load_spec", "models",
           "open", "save", "tabulate"]

#: Names imported on first use (PEP 562): ``import brdftab`` stays light, so the command line
#: installs its signal handlers before numpy, xarray and netCDF4 load.
_LAZY = {"BRDF": ".brdf", "BrdftabError": ".errors", "Table": ".table", "tabulate": ".table", "fit": ".fitting"}


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    if name.startswith("__"):
        raise AttributeError(name)
    try:
        return importlib.import_module(f".{name}", __name__)
    except ModuleNotFoundError as exc:
        if exc.name != f"{__name__}.{name}":
            raise
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}") from None


def __dir__():
    return sorted(set(globals()) | set(__all__))


def load_spec(path):
    """Parse and validate a spec file (TOML); returns a :class:`brdftab.spec.Spec`."""
    from .spec import load_spec as _load

    return _load(path)


def from_spec(path):
    """The BRDF a spec file describes (its ``[model]``).

    >>> import pathlib, tempfile, brdftab
    >>> spec = pathlib.Path(tempfile.mkdtemp()) / "white.toml"
    >>> _ = spec.write_text('[model]\\nname = "lambert"\\nalbedo = 0.5\\n[grid]\\ntype = "merl"\\n'
    ...                     '[[output]]\\npath = "white.nc"\\n')
    >>> brdftab.from_spec(spec)
    lambert(albedo=0.5)
    """
    return load_spec(path).model


def open(path):  # noqa: A001 - mirrors xarray.open_dataset / io.open naming
    """Read a table from any supported file (format from magic bytes, then extension).

    >>> import pathlib, tempfile, brdftab
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "white.binary"
    >>> _ = brdftab.save(brdftab.models.create("lambert", albedo=0.5), path)   # MERL: its own grid
    >>> table = brdftab.open(path)
    >>> table.grid.describe(), table.channels
    ('merl theta_h[90] x theta_d[90] x phi_d[180]', ('R', 'G', 'B'))
    >>> round(float(table.eval([0, 0, 1], [0.6, 0, 0.8])[0]) * 3.141592653589793, 6)   # ρ = 0.5
    0.5
    """
    from . import formats

    return formats.read(path)


def save(brdf, path, grid=None, *, format=None, overwrite=False, **options):
    """Write ``brdf`` to ``path`` (format from ``format`` or the extension), atomically.

    A table is written as it is when ``grid`` is None or equals its own grid; otherwise the
    BRDF is tabulated (resampled) on ``grid`` first. An existing file is replaced only with
    ``overwrite=True``. ``grid`` may be a grid, a type name or a ``[grid]`` table (a dict,
    angles in degrees). Returns what was written (usually the table).

    >>> import pathlib, tempfile, brdftab
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> ggx = brdftab.models.create("microfacet", alpha=0.3)
    >>> table = brdftab.save(ggx, folder / "ggx.nc", grid={"type": "rusinkiewicz", "n_theta_h": 16,
    ...                                                      "n_theta_d": 16, "n_phi_d": 32})
    >>> table.values.shape
    (16, 16, 32, 1)
    >>> brdftab.save(ggx, folder / "ggx.nc", grid="merl")
    Traceback (most recent call last):
    ...
    brdftab.errors.BrdftabError: ...ggx.nc: already exists (use --overwrite to replace it)
    """
    from . import formats

    return formats.write(brdf, path, grid=grid, format=format, overwrite=overwrite, **options)
