"""A fitted material as a Mitsuba 3 BSDF: the ``mi.load_dict`` tree and its XML.

Each part of the model is one Mitsuba plugin, and their weighted sum a nest of ``blendbsdf``
(``docs/export.md``):

- a specular lobe j → ``roughconductor`` with ``distribution = "beckmann"``, ``alpha = m_j``
  (Mitsuba's Beckmann D = exp(−tan²θ/α²)/(π α² cos⁴θ) is ctfit's D̂/π with α = m), the Fresnel
  term as ``eta`` and ``k`` (F0 → the paper's effective index (1 + √F0)/(1 − √F0), k = 0; a real
  n → k = 0; a conductor's n, k), and ``specular_reflectance`` 4 for the paper's
  "cook-torrance-1982" normalisation (4× the normalised form), 1 otherwise;
- a Lambertian R_d → ``diffuse`` with ``reflectance`` ρ = π R_d (F0 for "F0/pi");
- a transmitted R_d (plastic) → Mitsuba's smooth ``plastic`` with ``specular_reflectance = 0``
  (its diffuse term alone, exactly ctfit's), ``int_ior = n``, ``ext_ior = 1``,
  ``nonlinear = false`` and ``diffuse_reflectance`` ρ = π R_d;
- the weights s w_j of the lobes and 1 − s of the diffuse part sum to 1: a ``blendbsdf`` of the
  first piece and a blend of the rest, weight = the rest's share.

Mitsuba evaluates G with Smith's rational G1 (ctfit's "smith-rational") and has no Gaussian D,
so :func:`mitsuba_target` is the ctfit material the export evaluates: exact for
``geometry="smith-rational"`` and the Beckmann distribution, the closest otherwise (same
parameters, Mitsuba's G and D).
"""

from __future__ import annotations

import dataclasses
from xml.sax.saxutils import quoteattr

import numpy as np

from .._model import Material, fresnel_diffuse_reflectance, normal_reflectance
from .error_grid import unit_directions
from .rgb_bands import F0_MAX

__all__ = ["mitsuba_bsdf", "mitsuba_target", "mitsuba_values", "mitsuba_xml", "roughplastic_bsdf"]

_PAD_NM = (300.0, 900.0)  # beyond Mitsuba's spectral range (360–830 nm): ctfit holds the end values


def mitsuba_target(material: Material) -> Material:
    """The ctfit material that the Mitsuba export of ``material`` evaluates.

    Smith's rational G and Beckmann's D; F0 at most 1 − 10⁻⁶; for an RGB material a reflectance
    of at most 1 (Mitsuba refuses more in RGB), i.e. R_d ≤ 1/π.

    Examples
    --------
    >>> import numpy as np, ctfit
    >>> from ctfit._export.mitsuba import mitsuba_target
    >>> mat = ctfit.Material(ctfit.Structure(), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.9])), channels=("G",))
    >>> mitsuba_target(mat).structure.geometry
    'smith-rational'
    """
    st = dataclasses.replace(material.structure, geometry="smith-rational", distribution="beckmann")
    p = material.params
    if p.f0 is not None:
        p = dataclasses.replace(p, f0=np.minimum(np.asarray(p.f0, float), F0_MAX))
    if p.rd is not None and material.is_rgb:
        p = dataclasses.replace(p, rd=np.minimum(np.asarray(p.rd, float), 1 / np.pi))
    return dataclasses.replace(material, structure=st, params=p)


def _value(material: Material, values):
    """A number, an ``rgb`` or a ``spectrum`` (λ:value pairs, padded to the visible range) for Mitsuba."""
    a = np.asarray(values, dtype=float)
    if a.ndim == 0 or np.ptp(a) == 0:
        return float(a.reshape(-1)[0])
    if material.is_rgb:
        if tuple(material.channels) != ("R", "G", "B"):
            raise ValueError(f"material {material.name!r}: Mitsuba takes R, G, B channels or wavelengths, not channels {list(material.channels)}")
        return {"type": "rgb", "value": [float(v) for v in a]}
    wl = [float(w) for w in material.wavelength_nm]
    pairs = [(w, float(v)) for w, v in zip(wl, a)]
    if wl[0] > _PAD_NM[0]:
        pairs.insert(0, (_PAD_NM[0], float(a[0])))
    if wl[-1] < _PAD_NM[1]:
        pairs.append((_PAD_NM[1], float(a[-1])))
    return {"type": "spectrum", "value": pairs}


def _index(material: Material):
    """(eta, k) of the Fresnel term as Mitsuba's complex index."""
    st, p = material.structure, material.params
    if st.fresnel == "f0":
        r = np.sqrt(np.asarray(p.f0, float))
        return (1 + r) / (1 - r), 0.0
    return np.asarray(p.n, float), (0.0 if st.fresnel == "n" else np.asarray(p.k, float))


def _diffuse_leaf(material: Material) -> dict:
    st, p = material.structure, material.params
    if st.diffuse == "F0/pi":
        return {"type": "diffuse", "reflectance": _value(material, normal_reflectance(st, p))}
    rho = _value(material, np.pi * np.asarray(p.rd, float))
    if st.diffuse == "transmitted":
        return {"type": "plastic", "int_ior": float(np.asarray(p.n).reshape(-1)[0]), "ext_ior": 1.0,
                "diffuse_reflectance": rho, "specular_reflectance": 0.0, "nonlinear": False}
    return {"type": "diffuse", "reflectance": rho}


def _pieces(material: Material) -> list[tuple[float, dict]]:
    """(weight, leaf) of every part; the weights sum to 1."""
    st, p = material.structure, material.params
    s = float(p.s) if st.has_s else float(st.has_specular)
    pieces = []
    if st.has_specular:
        eta, k = _index(material)
        scale = 4.0 if st.normalization == "cook-torrance-1982" else 1.0
        for m, w in zip(np.asarray(p.m, float).reshape(-1), np.asarray(p.w, float).reshape(-1)):
            leaf = {"type": "roughconductor", "distribution": "beckmann", "alpha": float(m),
                    "eta": _value(material, eta), "k": _value(material, k)}
            if scale != 1.0:
                leaf["specular_reflectance"] = scale
            pieces.append((s * float(w), leaf))
    if st.has_diffuse:
        pieces.append((1 - s, _diffuse_leaf(material)))
    kept = [piece for piece in pieces if piece[0] > 0]
    return kept or pieces[:1]


def _blend(pieces):
    if len(pieces) == 1:
        return pieces[0][1]
    rest = sum(c for c, _ in pieces[1:])
    total = pieces[0][0] + rest
    return {"type": "blendbsdf", "weight": rest / total, "bsdf_0": pieces[0][1], "bsdf_1": _blend(pieces[1:])}


def mitsuba_bsdf(material: Material) -> dict:
    """The ``mi.load_dict`` tree of the material's Mitsuba 3 BSDF (of :func:`mitsuba_target`).

    Examples
    --------
    One lobe and a Lambertian part: a ``blendbsdf`` whose weight is the diffuse share 1 − s:

    >>> import numpy as np, ctfit
    >>> from ctfit._export.mitsuba import mitsuba_bsdf
    >>> mat = ctfit.Material(ctfit.Structure(geometry="smith-rational", diffuse="constant"),
    ...                      ctfit.Params(s=np.array(0.75), m=np.array([0.2]), w=np.ones(1), f0=np.array([0.9]), rd=np.array(0.1)),
    ...                      channels=("G",))
    >>> tree = mitsuba_bsdf(mat)
    >>> tree["type"], tree["weight"], tree["bsdf_0"]["type"], tree["bsdf_0"]["alpha"], tree["bsdf_1"]["type"]
    ('blendbsdf', 0.25, 'roughconductor', 0.2, 'diffuse')
    """
    return _blend(_pieces(mitsuba_target(material)))


def _xml_value(name: str, value) -> str:
    if isinstance(value, bool):
        return f'<boolean name="{name}" value="{str(value).lower()}"/>'
    if isinstance(value, (int, float)):
        return f'<float name="{name}" value="{float(value)!r}"/>'
    if isinstance(value, str):
        return f"<string name=\"{name}\" value={quoteattr(value)}/>"
    if value["type"] == "rgb":
        return f'<rgb name="{name}" value="{", ".join(repr(float(v)) for v in value["value"])}"/>'
    return f'<spectrum name="{name}" value="{", ".join(f"{w!r}:{v!r}" for w, v in value["value"])}"/>'


def _xml_lines(node: dict, depth: int, root: bool) -> list[str]:
    pad = "    " * depth
    head = f'{pad}<bsdf type="{node["type"]}"' + (' version="3.0.0"' if root else "") + ">"
    lines = [head]
    for key, value in node.items():
        if key == "type":
            continue
        if isinstance(value, dict) and value["type"] not in ("rgb", "spectrum"):
            lines += _xml_lines(value, depth + 1, False)
        else:
            lines.append(f"{pad}    {_xml_value(key, value)}")
    return lines + [f"{pad}</bsdf>"]


def mitsuba_xml(tree: dict, comments=()) -> str:
    """The XML of a :func:`mitsuba_bsdf` tree (``mi.load_string``), each comment on its own line.

    Examples
    --------
    >>> from ctfit._export.mitsuba import mitsuba_xml
    >>> print(mitsuba_xml({"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.25, 0.125]}}, ["ctfit export"]))
    <!-- ctfit export -->
    <bsdf type="diffuse" version="3.0.0">
        <rgb name="reflectance" value="0.5, 0.25, 0.125"/>
    </bsdf>
    <BLANKLINE>
    """
    notes = [f"<!-- {str(c).replace('--', '- -')} -->" for c in comments]
    return "\n".join(notes + _xml_lines(tree, 0, True)) + "\n"


def roughplastic_bsdf(material: Material) -> dict:
    """A plastic as Mitsuba's own ``roughplastic`` (a ``blendbsdf`` of one per lobe, weights w_j):
    approximate — its diffuse term uses rough transmittance tables (``docs/export.md``).

    ``alpha = m_j``, ``int_ior = n``, ``ext_ior = 1``, ``nonlinear = false``,
    ``specular_reflectance = s`` (4 s for "cook-torrance-1982"), ``diffuse_reflectance`` ρ =
    π R_d (1 − s) for a transmitted diffuse part, and for a Lambertian one the ρ whose smooth
    transmitted albedo is π R_d (1 − s): ρ = π R_d (1 − s) n² (1 − F_dr(1/n))/(1 − F_dr(n))².

    Examples
    --------
    Half specular, R_d = 0.2 sr⁻¹ transmitted: ρ = π · 0.2 · 0.5:

    >>> import numpy as np, ctfit
    >>> from ctfit._export.mitsuba import roughplastic_bsdf
    >>> params = ctfit.Params(s=np.array(0.5), m=np.array([0.2]), w=np.ones(1), n=np.array(1.5), rd=np.array([0.2]))
    >>> tree = roughplastic_bsdf(ctfit.Material(ctfit.Structure(family="plastic", diffuse="transmitted"), params, channels=("G",)))
    >>> tree["type"], tree["specular_reflectance"], round(tree["diffuse_reflectance"], 4)
    ('roughplastic', 0.5, 0.3142)
    """
    st, p = material.structure, material.params
    if st.family != "plastic" or not st.has_specular:
        raise ValueError(f"material {material.name!r}: roughplastic needs a plastic with a specular part")
    n = float(np.asarray(p.n).reshape(-1)[0])
    s = float(p.s) if st.has_s else 1.0
    rho = np.zeros(1) if not st.has_diffuse else np.pi * (1 - s) * np.asarray(p.rd, float)
    if st.diffuse in ("spectrum", "constant"):
        rho = rho * n * n * (1 - float(fresnel_diffuse_reflectance(1 / n))) / (1 - float(fresnel_diffuse_reflectance(n))) ** 2
    if material.is_rgb:
        rho = np.minimum(rho, 1.0)
    scale = 4.0 if st.normalization == "cook-torrance-1982" else 1.0
    pieces = [(float(w), {"type": "roughplastic", "distribution": "beckmann", "alpha": float(m), "int_ior": n, "ext_ior": 1.0,
                          "nonlinear": False, "specular_reflectance": s * scale, "diffuse_reflectance": _value(material, rho)})
              for m, w in zip(np.asarray(p.m, float).reshape(-1), np.asarray(p.w, float).reshape(-1))]
    return _blend([piece for piece in pieces if piece[0] > 0] or pieces[:1])


def mitsuba_values(tree: dict, material: Material, theta_i, phi_i, theta_o, phi_o) -> np.ndarray:
    """Mitsuba 3's own BRDF of ``tree`` (its ``eval`` over cos θ_o) at directions in degrees, in the
    material's bands: ``scalar_rgb`` for RGB and one-band materials, ``scalar_spectral`` at the
    material's wavelengths otherwise. Needs the ``mitsuba`` package; the variant is restored.

    Examples
    --------
    >>> import numpy as np, ctfit
    >>> from ctfit._export.mitsuba import mitsuba_values
    >>> matte = ctfit.Material(ctfit.Structure(lobes=0, diffuse="constant"), ctfit.Params(rd=np.array(0.1)), channels=("G",))
    >>> mitsuba_values({"type": "diffuse", "reflectance": 0.5}, matte, [30.0], [0.0], [60.0], [90.0]).round(6).tolist()  # ρ/π
    [[0.159155]]
    """
    try:
        import mitsuba as mi
    except ImportError as e:
        raise ValueError("measuring the error of a Mitsuba plugin ctfit cannot evaluate itself needs Mitsuba 3 (pip install mitsuba)") from e
    spectral = not material.is_rgb and len(material.wavelength_nm) > 1
    previous = mi.variant()
    mi.set_variant("scalar_spectral" if spectral else "scalar_rgb")
    try:
        bsdf, ctx, frame = mi.load_dict(tree), mi.BSDFContext(), mi.Frame3f(mi.Vector3f(0, 0, 1))
        wl = np.asarray(material.wavelength_nm, float) if spectral else np.zeros(1)
        groups = [np.resize(wl[i:i + 4], 4) for i in range(0, wl.size, 4)]
        out = []
        for l, v in zip(unit_directions(theta_i, phi_i), unit_directions(theta_o, phi_o)):
            si = mi.SurfaceInteraction3f()
            si.sh_frame, si.wi = frame, mi.Vector3f(*l)
            values = []
            for g in groups:
                if spectral:
                    # a list of four floats: Mitsuba converts it to its spectrum type
                    si.wavelengths = [float(x) for x in g]  # type: ignore[assignment]
                values.append(np.asarray(bsdf.eval(ctx, si, mi.Vector3f(*v)), float) / v[2])
            out.append(np.concatenate(values)[:wl.size] if spectral else values[0][: 1 if len(material.band_labels) == 1 else 3])
        return np.array(out)
    finally:
        if previous:
            mi.set_variant(previous)

