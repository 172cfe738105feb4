"""The readable table of a posterior: the ``uncertainty`` section of a fit JSON as plain text."""

from __future__ import annotations

from .._model import band_labels

__all__ = ["format_uncertainty_table", "number_text"]


def _fmt(s: dict | None) -> str:
    """A summary as "median (+p84 − median / −median − p16)"; "—" without a median."""
    if not s or s.get("median") is None:
        return "—"
    med, lo, hi = s["median"], s["p16"], s["p84"]
    return f"{med:.6g} (+{hi - med:.2g} / −{med - lo:.2g})"


def number_text(x: float | None, spec: str) -> str:
    """``x`` formatted with ``spec``; "n/a" where the JSON holds none (NaN is written as null), e.g.
    τ, ESS or R̂ of a chain too short to estimate them."""
    return "n/a" if x is None or x != x else format(x, spec)


def format_uncertainty_table(doc: dict, label: str = "") -> str:
    """A plain-text table of an ``uncertainty`` section (or a whole fit JSON document holding one).

    >>> import ctfit
    >>> m = {"median": 0.251, "p16": 0.247, "p84": 0.256}
    >>> doc = {"wavelength_nm": [450.0, 650.0], "uncertainty": {"lobes": [{"m": m, "weight": None}],
    ...        "F0": [{"median": 0.6, "p16": 0.59, "p84": 0.61}, {"median": 0.9, "p16": 0.89, "p84": 0.91}]}}
    >>> print(ctfit.format_uncertainty_table(doc, "gold"))  # doctest: +NORMALIZE_WHITESPACE
    posterior of gold
    ------------------------------------------------------------------------
      median (+p84 − median / −median − p16)
      lobe 0: m = 0.251 (+0.005 / −0.004)   weight = —
              band                                F0
            450 nm              0.6 (+0.01 / −0.01)
            650 nm              0.9 (+0.01 / −0.01)
    """
    u = doc.get("uncertainty", doc)
    lines = [f"posterior of {label}" if label else "posterior", "-" * 72, "  median (+p84 − median / −median − p16)"]
    if "s" in u:
        lines.append(f"  s = {_fmt(u['s'])}")
    for j, lobe in enumerate(u.get("lobes", [])):
        lines.append(f"  lobe {j}: m = {_fmt(lobe['m'])}   weight = {_fmt(lobe['weight'])}")
    band_keys = [k for k in ("F0", "n", "k", "Rd") if isinstance(u.get(k), list)]
    if band_keys:
        bands = u if ("wavelength_nm" in u or "channels" in u) else doc  # the bands sampled (the data's), else the material's
        if bands.get("wavelength_nm") or bands.get("channels"):  # their labels: "450 nm", a channel, "unknown band"
            labels = band_labels(bands.get("wavelength_nm"), bands.get("channels"), bool(bands.get("band_unknown")))
        else:  # band indices, without a wavelength
            labels = [f"band {i}" for i in range(len(u[band_keys[0]]))]
        lines.append("  " + f"{'band':>12}" + "".join(f"  {k:>32}" for k in band_keys))
        for i, lab in enumerate(labels):
            lines.append("  " + f"{lab:>12}" + "".join(f"  {_fmt(u[k][i]):>32}" for k in band_keys))
    if isinstance(u.get("Rd"), dict):
        lines.append(f"  Rd = {_fmt(u['Rd'])}")
    if "sigma_noise" in u:
        lines.append(f"  sigma_noise = {_fmt(u['sigma_noise'])}   ({u['likelihood']['loss']} residuals)")
    col = u.get("colour")
    if col:
        srgb = ", ".join(f"{c['median']:.3f}" for c in col["sRGB"])
        lab = ", ".join(_fmt(c) for c in col["Lab"])
        lines.append(f"  colour ({col['illuminant']}): sRGB median ({srgb}) {col['sRGB_hex_median']}   Lab {lab}")
    d = u.get("diagnostics", {})
    if d:
        lines.append("-" * 72)
        acc = d["acceptance_fraction"]
        lines.append(
            f"  walkers: {d['walkers']}   steps: {d['steps']}   burn: {d['burn']}   thin: {d['thin']}   draws: {d['draws']}   "
            f"acceptance: {acc['mean']:.2f}"
        )
        lines.append(
            f"  τ_max: {number_text(d['autocorr_time_max'], '.1f')} steps   ESS_min (ArviZ, bulk): {number_text(d['ess_min'], '.0f')}   "
            f"R̂_max: {number_text(d.get('r_hat_max'), '.3f')}   "
            f"chain ≥ 50 τ: {d['chain_long_enough']}   time: {d['time_s']:.1f} s"
        )
        per = [f"{k} {number_text(d['ess_bulk'][k], '.0f')}/{number_text(d['r_hat'][k], '.3f')}" for k in d.get("ess_bulk", {})]
        if per:
            lines.append("  ESS (bulk) / R̂ per quantity: " + ", ".join(per))
    priors = u.get("priors", {}).get("parameters", {})
    if priors:
        lines.append("  priors: " + "; ".join(e["density"] for e in priors.values()))
    problems = list(u.get("problems", []))
    if "usable" in u:
        lines.append("  posterior: " + ("usable" if u["usable"] else "NOT usable: the problems below say why"))
    for w in problems:
        lines.append(f"  problem: {w}")
    for w in u.get("warnings", []):
        if w not in problems:
            lines.append(f"  warning: {w}")
    return "\n".join(lines)
