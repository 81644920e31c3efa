"""The noise-free truth of a flight: the JSBSim properties read each sample and their
conversion to the canonical SI channels (DESIGN.md section 3) plus the extras."""

from __future__ import annotations

import numpy as np
import pandas as pd

from sim.aircraft import DERIVATIVES, Aircraft

FT = 0.3048
LBF = 4.4482216152605
PSF = 47.880258980335840
SLUGFT3 = 515.3788183931961

#: truth column -> (JSBSim property, factor to SI)
PROPS: dict[str, tuple[str, float]] = {
    "p": ("velocities/p-rad_sec", 1.0),
    "q": ("velocities/q-rad_sec", 1.0),
    "r": ("velocities/r-rad_sec", 1.0),
    "pdot": ("accelerations/pdot-rad_sec2", 1.0),
    "qdot": ("accelerations/qdot-rad_sec2", 1.0),
    "rdot": ("accelerations/rdot-rad_sec2", 1.0),
    "phi": ("attitude/phi-rad", 1.0),
    "theta": ("attitude/theta-rad", 1.0),
    "psi": ("attitude/psi-rad", 1.0),
    "V": ("velocities/vt-fps", FT),
    "alpha": ("aero/alpha-rad", 1.0),
    "beta": ("aero/beta-rad", 1.0),
    "u": ("velocities/u-aero-fps", FT),
    "v": ("velocities/v-aero-fps", FT),
    "w": ("velocities/w-aero-fps", FT),
    "vn": ("velocities/v-north-fps", FT),
    "ve": ("velocities/v-east-fps", FT),
    "vd": ("velocities/v-down-fps", FT),
    "h": ("position/h-sl-ft", FT),
    "qbar": ("aero/qbar-psf", PSF),
    "rho": ("atmosphere/rho-slugs_ft3", SLUGFT3),
    "de": ("fcs/de-pos-rad", 1.0),
    "da": ("fcs/da-pos-rad", 1.0),
    "dr": ("fcs/dr-pos-rad", 1.0),
    "throttle": ("fcs/throttle-pos", 1.0),
    "thrust": ("fcs/thrust-lbf", LBF),
    "p_aero": ("velocities/p-aero-rad_sec", 1.0),
    "q_aero": ("velocities/q-aero-rad_sec", 1.0),
    "r_aero": ("velocities/r-aero-rad_sec", 1.0),
    "alphadot": ("aero/alphadot-rad_sec", 1.0),
    "p_turb": ("atmosphere/p-turb-rad_sec", 1.0),
    "q_turb": ("atmosphere/q-turb-rad_sec", 1.0),
    "r_turb": ("atmosphere/r-turb-rad_sec", 1.0),
    "gust_n": ("atmosphere/turb-north-fps", FT),
    "gust_e": ("atmosphere/turb-east-fps", FT),
    "gust_d": ("atmosphere/turb-down-fps", FT),
    "de_cmd": ("fcs/de-cmd-rad", 1.0),
    "da_cmd": ("fcs/da-cmd-rad", 1.0),
    "dr_cmd": ("fcs/dr-cmd-rad", 1.0),
    "de_sas": ("fcs/de-sas-rad", 1.0),
    "lat": ("position/lat-geod-deg", 1.0),
    "lon": ("position/long-gc-deg", 1.0),
}
#: raw JSBSim helpers needed to form coefficients and specific forces
AUX = [
    "simulation/sim-time-sec",
    "forces/fbx-total-lbs",
    "forces/fby-total-lbs",
    "forces/fbz-total-lbs",
    "inertia/mass-slugs",
    "aero/qbar-psf",
    "metrics/Sw-sqft",
    "metrics/bw-ft",
    "metrics/cbarw-ft",
]

#: truth columns, in order (DESIGN.md section 3 first, then the extras)
TRUTH_COLUMNS: tuple[str, ...] = (
    "t",
    "ax",
    "ay",
    "az",
    "p",
    "q",
    "r",
    "pdot",
    "qdot",
    "rdot",
    "phi",
    "theta",
    "psi",
    "V",
    "alpha",
    "beta",
    "u",
    "v",
    "w",
    "vn",
    "ve",
    "vd",
    "h",
    "qbar",
    "rho",
    "de",
    "da",
    "dr",
    "throttle",
    "thrust",
    "p_aero",
    "q_aero",
    "r_aero",
    "alphadot",
    "p_turb",
    "q_turb",
    "r_turb",
    "gust_n",
    "gust_e",
    "gust_d",
    "gust_u",
    "gust_v",
    "gust_w",
    "CL",
    "CD",
    "CY",
    "Cl",
    "Cm",
    "Cn",
    "de_cmd",
    "da_cmd",
    "dr_cmd",
    "de_sas",
    "lat",
    "lon",
)

#: SI unit of every truth column
TRUTH_UNITS: dict[str, str] = {
    "t": "s",
    **{c: "m/s^2" for c in ("ax", "ay", "az")},
    **{c: "rad/s" for c in ("p", "q", "r", "p_aero", "q_aero", "r_aero", "alphadot", "p_turb", "q_turb", "r_turb")},
    **{c: "rad/s^2" for c in ("pdot", "qdot", "rdot")},
    **{
        c: "rad"
        for c in ("phi", "theta", "psi", "alpha", "beta", "de", "da", "dr", "de_cmd", "da_cmd", "dr_cmd", "de_sas")
    },
    **{
        c: "m/s"
        for c in ("V", "u", "v", "w", "vn", "ve", "vd", "gust_n", "gust_e", "gust_d", "gust_u", "gust_v", "gust_w")
    },
    "h": "m",
    "qbar": "Pa",
    "rho": "kg/m^3",
    "throttle": "-",
    "thrust": "N",
    **{c: "-" for c in ("CL", "CD", "CY", "Cl", "Cm", "Cn")},
    "lat": "deg",
    "lon": "deg",
}


def truth_table(
    data: np.ndarray, props: list[str], coef_names: list[str], ac: Aircraft
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(truth, aero_terms) from the properties ``props`` read each sample, data (N,
    len(props)): the TRUTH_COLUMNS in SI units (specific forces from the body forces and
    mass, turbulence turned into body axes, the coefficients summed from their terms
    ``coef_names``) and each derivative's force or moment term in N or N m."""
    col = {p: data[:, i] for i, p in enumerate(props)}
    d: dict[str, np.ndarray] = {"t": col["simulation/sim-time-sec"]}
    m = col["inertia/mass-slugs"]
    for ax, f in (("ax", "fbx"), ("ay", "fby"), ("az", "fbz")):
        d[ax] = col[f"forces/{f}-total-lbs"] / m * FT
    for name, (p, k) in PROPS.items():
        d[name] = col[p] * k
    # turbulence NED -> body axes (gust_u/v/w: air-mass velocity along body x/y/z)
    ph, th, ps = d["phi"], d["theta"], d["psi"]
    cph, sph, cth, sth, cps, sps = np.cos(ph), np.sin(ph), np.cos(th), np.sin(th), np.cos(ps), np.sin(ps)
    gn, ge, gd = d["gust_n"], d["gust_e"], d["gust_d"]
    d["gust_u"] = cth * cps * gn + cth * sps * ge - sth * gd
    d["gust_v"] = (sph * sth * cps - cph * sps) * gn + (sph * sth * sps + cph * cps) * ge + sph * cth * gd
    d["gust_w"] = (cph * sth * cps + sph * sps) * gn + (cph * sth * sps - sph * cps) * ge + cph * cth * gd
    qs = col["aero/qbar-psf"] * col["metrics/Sw-sqft"]
    ref = {
        "CL": qs,
        "CD": qs,
        "CY": qs,
        "Cl": qs * col["metrics/bw-ft"],
        "Cm": qs * col["metrics/cbarw-ft"],
        "Cn": qs * col["metrics/bw-ft"],
    }
    terms = {"t": d["t"]}
    for coef, names in DERIVATIVES.items():
        tot = np.zeros_like(d["t"])
        unit = LBF if coef in ("CL", "CD", "CY") else LBF * FT
        for n in names:
            if n in coef_names:
                term = col[f"aero/coefficient/{n}"]
                tot = tot + term
                terms[n] = term * unit
        with np.errstate(divide="ignore", invalid="ignore"):
            d[coef] = tot / ref[coef]
    truth = pd.DataFrame({c: d[c] for c in TRUTH_COLUMNS})
    return truth, pd.DataFrame(terms)
