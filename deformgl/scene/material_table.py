"""The scene file's ``[material]`` table of a simulated body: a solid (a preset and/or Young's
modulus, density and Poisson's ratio) or a sheet (cloth), checked key by key
(:mod:`deformgl.scene.schema` builds the rest of the scene)."""

from __future__ import annotations

from typing import Any

from deformgl.scene.checks import Check, _fail, _join, _num, _str, _table
from deformgl.sim.materials import MAX_POISSON, MIN_POISSON, MODELS, PRESETS, ElasticMaterial, SheetMaterial

__all__ = ["_BODY_MATERIAL", "_MATERIAL_KEYS"]


_PA = _num(lo=0.0, lo_open=True, sane=(1e-3, 1e13), unit="Pa")
_MATERIAL_KEYS: dict[str, tuple[Check, Any]] = {
    "preset": (_str(tuple(PRESETS)), None),
    "youngs_modulus": (_PA, None),
    "density": (_num(lo=0.0, lo_open=True, sane=(1e-3, 1e5), unit="kg/m^3"), None),
    "stretch_modulus": (_num(lo=0.0, lo_open=True, sane=(1e-6, 1e10), unit="N/m"), None),
    "areal_density": (_num(lo=0.0, lo_open=True, sane=(1e-6, 1e4), unit="kg/m^2"), None),
    "flexion_ratio": (_num(lo=0.0, hi=0.5), None),
    "bending_stiffness": (_num(lo=0.0, lo_open=True, sane=(1e-12, 1e6), unit="N*m"), None),
    "poissons_ratio": (_num(), None),  # the range and why: _build_body_material
    "mass_damping": (_num(lo=0.0, sane=(0.0, 1e6), unit="1/s"), 0.0),
    "stiffness_damping": (_num(lo=0.0, sane=(0.0, 1e3), unit="s"), 0.0),
    "model": (_str(MODELS), None),
}


def _build_body_material(file: str, key: str, d: dict[str, Any]) -> ElasticMaterial | SheetMaterial:
    """``[material]``: a solid (a preset and/or youngs_modulus + density) or a sheet
    (stretch_modulus + areal_density, for cloth; bending_stiffness in N*m or flexion_ratio)."""
    sheet = [k for k in ("stretch_modulus", "areal_density", "flexion_ratio", "bending_stiffness") if d[k] is not None]
    solid = [k for k in ("preset", "youngs_modulus", "density", "poissons_ratio", "model") if d[k] is not None]
    if sheet and solid:
        _fail(file, _join(key, sheet[0]), f"a sheet (cloth) key; not used with {solid[0]!r} (a solid)")
    if sheet:
        for k in ("stretch_modulus", "areal_density"):
            if d[k] is None:
                _fail(file, _join(key, k), "required for a sheet material (cloth)")
        if d["flexion_ratio"] and d["bending_stiffness"] is not None:
            _fail(file, _join(key, "bending_stiffness"), "not used with flexion_ratio: give one (bending_stiffness, "
                  "the plate's D in N*m, is the calibrated bending; flexion springs would add to it)")
        return SheetMaterial(d["stretch_modulus"], d["areal_density"], d["mass_damping"],
                             d["stiffness_damping"], d["flexion_ratio"] or 0.0,
                             bending_stiffness=d["bending_stiffness"] or 0.0)
    base = PRESETS[d["preset"]] if d["preset"] is not None else None
    if base is not None and all(d[k] is not None for k in ("youngs_modulus", "density", "poissons_ratio")):
        _fail(file, _join(key, "preset"), "not used when youngs_modulus, density and poissons_ratio are all given "
              "(a preset gives the values they leave out)")
    values = {}
    for k in ("youngs_modulus", "density"):
        value = d[k] if d[k] is not None else (getattr(base, k) if base is not None else None)
        if value is None:
            _fail(file, _join(key, k), "required (or set 'preset' to one of " + ", ".join(PRESETS) + ")")
        values[k] = value
    nu = d["poissons_ratio"] if d["poissons_ratio"] is not None else (base.poissons_ratio if base is not None else 0.25)
    if not MIN_POISSON <= nu <= MAX_POISSON:
        _fail(file, _join(key, "poissons_ratio"), f"must be in [{MIN_POISSON}, {MAX_POISSON}], got {nu:g}: below 1/4 "
              "the spring lattice would need lambda < mu, which central springs cannot give")
    same = base is not None and d["youngs_modulus"] is None and d["density"] is None and d["poissons_ratio"] is None
    return ElasticMaterial(values["youngs_modulus"], values["density"], d["mass_damping"], d["stiffness_damping"],
                           name=base.name if same and base is not None else "", source=base.source if base is not None else "",
                           poissons_ratio=nu, model=d["model"] or "lattice")


_BODY_MATERIAL = _table(_MATERIAL_KEYS, _build_body_material)
