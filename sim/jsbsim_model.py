"""Generate a JSBSim aircraft (XML) from a truth set.

The XML goes into a caller-supplied root folder (a run folder or a cache folder), never into
the package. Layout written: ``ROOT/aircraft/<name>/<name>.xml`` plus ``ROOT/engine/``
holding a zero-power electric engine and a direct thruster: JSBSim's trim adjusts the
throttle through its engine list, so one (thrust-less) engine exists only to carry
``fcs/throttle-cmd-norm[0]``. The thrust itself is an external force of
``throttle * max_thrust`` along body x through the CG.

FCS (all angles in rad): per axis ``fcs/<s>-cmd-rad = trim + fcs/<s>-maneuver-rad
(+ fcs/de-sas-rad)``, then an actuator (optional first-order lag, clipped to the
surface limit) writes ``fcs/<s>-pos-rad`` for s in de, da, dr. Elevator trim is
``fcs/pitch-trim-cmd-norm * de_limit`` (set by JSBSim's trim). Throttle:
``fcs/throttle-pos = clip(fcs/throttle-cmd-norm[0] + fcs/throttle-maneuver, 0, 1)``.
Servo resolution (``FcsConfig.servo_step_rad``, ``throttle_step``; 0 = none): while
``fcs/servo-quantize`` is 1 every command is rounded to the nearest multiple of its step,
as an autopilot's whole-microsecond PWM does (the flight sets it after the trim, which
needs continuous controls); the unrounded sums are ``fcs/<s>-cmd-sum-rad`` and
``fcs/throttle-cmd-sum``.
Pitch SAS (optional): ``fcs/de-sas-rad = fcs/sas-on * (k_alpha*(alpha - fcs/sas-alpha-ref-rad)
+ k_q*q)`` with the truth alpha and body pitch rate.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape

from sim.aircraft import DERIVATIVES, Aircraft, regressor_key

# Exact SI -> English factors. Values are written to the XML in English units so that
# JSBSim's own (rounded) unit conversions never touch them.
M2FT = 1.0 / 0.3048
N2LBF = 1.0 / 4.4482216152605
KG2LB = 1.0 / 0.45359237
KG2SLUG = 1.0 / 14.593902937206364
KGM2_2_SLUGFT2 = KG2SLUG * M2FT**2

#: JSBSim property of each regressor
_REG_PROPS = {
    "0": [],
    "asym": [],
    "alpha": ["aero/alpha-rad"],
    "alpha2": ["aero/alpha-rad", "aero/alpha-rad"],
    "q": ["aero/ci2vel", "velocities/q-aero-rad_sec"],
    "alphadot": ["aero/ci2vel", "aero/alphadot-rad_sec"],
    "beta": ["aero/beta-rad"],
    "p": ["aero/bi2vel", "velocities/p-aero-rad_sec"],
    "r": ["aero/bi2vel", "velocities/r-aero-rad_sec"],
    "de": ["fcs/de-pos-rad"],
    "da": ["fcs/da-pos-rad"],
    "dr": ["fcs/dr-pos-rad"],
}
#: coefficient -> (JSBSim axis, frame). Forces in stability axes (x along the projection
#: of the airspeed on the symmetry plane, y = body y). JSBSim takes stability X as drag
#: (positive aft) and Z as lift (positive up) and flips them itself (FGAerodynamics::Run),
#: so every function is the plain positive term. Moments in body axes about the CG.
_AXIS = {
    "CL": ("Z", "STABILITY"),
    "CD": ("X", "STABILITY"),
    "CY": ("Y", "STABILITY"),
    "Cl": ("ROLL", "BODY"),
    "Cm": ("PITCH", "BODY"),
    "Cn": ("YAW", "BODY"),
}
#: order of the axis elements (JSBSim wants one force axis system)
_AXIS_ORDER = ("CD", "CY", "CL", "Cl", "Cm", "Cn")
_REF = {"CL": None, "CD": None, "CY": None, "Cl": "metrics/bw-ft", "Cm": "metrics/cbarw-ft", "Cn": "metrics/bw-ft"}


@dataclass(frozen=True)
class FcsConfig:
    """Control-system options taken from the scenario."""

    actuator_lag_s: float = 0.0  #: first-order actuator time constant, s (0 = none)
    sas_k_alpha: float = 0.0  #: pitch SAS gain on alpha error, rad/rad
    sas_k_q: float = 0.0  #: pitch SAS gain on pitch rate, rad/(rad/s)
    servo_step_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: de, da, dr command resolution, rad (0 = continuous)
    throttle_step: float = 0.0  #: throttle command resolution, fraction (0 = continuous)


def coefficient_properties(aircraft: Aircraft) -> dict[str, str]:
    """JSBSim property (``aero/coefficient/<name>``, force in lbf or moment in lbf ft) of each
    non-zero derivative."""
    return {n: f"aero/coefficient/{n}" for n in _active(aircraft)}


def _active(aircraft: Aircraft) -> list[str]:
    return [n for names in DERIVATIVES.values() for n in names if aircraft.derivatives[n] != 0.0]


def _aero_xml(aircraft: Aircraft) -> str:
    out = ["  <aerodynamics>"]
    for coef in _AXIS_ORDER:
        names = DERIVATIVES[coef]
        axis, frame = _AXIS[coef]
        out.append(f'    <axis name="{axis}" frame="{frame}">')
        for n in names:
            val = aircraft.derivatives[n]
            if val == 0.0:
                continue
            # aero/qbar-area: JSBSim's qbar * S, formed each step before the aero functions
            # run; one read in place of qbar and S (the same product, bit for bit)
            props = ["aero/qbar-area"]
            if _REF[coef]:
                props.append(_REF[coef])
            props += _REG_PROPS[regressor_key(n)]
            inner = "".join(f"<property>{p}</property>" for p in props)
            out.append(
                f'      <function name="aero/coefficient/{n}"><description>{n}</description>'
                f"<product>{inner}<value>{val!r}</value></product></function>"
            )
        out.append("    </axis>")
    out.append("  </aerodynamics>")
    return "\n".join(out)


def _actuator(axis: str, limit: float, lag: float) -> str:
    lag_xml = f"<lag>{1.0 / lag!r}</lag>" if lag > 0 else ""
    return (
        f'      <actuator name="fcs/{axis}-pos-rad"><input>fcs/{axis}-cmd-rad</input>{lag_xml}'
        f"<clipto><min>{-limit!r}</min><max>{limit!r}</max></clipto>"
        f"<output>fcs/{axis}-pos-rad</output></actuator>"
    )


def _command(out: str, total: str, terms: str, step: float, clip: str = "") -> str:
    """FCS component(s) writing property ``out``: the sum of ``terms``; with a ``step`` > 0
    rounded to a multiple of it while ``fcs/servo-quantize`` is 1 (x + on * (step *
    floor(x / step + 1/2) - x)). The rounding reads the sum x three times, so x is formed
    once, by a component of its own writing property ``total`` (listed just before): the
    same arithmetic on the same values as three inline sums, a third of the evaluations."""
    if step <= 0.0:
        return f'<fcs_function name="{out}"><function><sum>{terms}</sum></function>{clip}</fcs_function>'
    x = f"<property>{total}</property>"
    rounded = (
        f"<product><value>{step!r}</value><floor><sum><product><value>{1.0 / step!r}</value>{x}"
        f"</product><value>0.5</value></sum></floor></product>"
    )
    return (
        f'<fcs_function name="{total}"><function><sum>{terms}</sum></function></fcs_function>\n'
        f'      <fcs_function name="{out}"><function><sum>{x}<product><property>fcs/servo-quantize</property>'
        f"<difference>{rounded}{x}</difference></product></sum></function>{clip}</fcs_function>"
    )


def _fcs_xml(aircraft: Aircraft, fcs: FcsConfig) -> str:
    lim = aircraft.limits
    q_de, q_da, q_dr = fcs.servo_step_rad
    trim = {
        a: f"<product><property>fcs/{n}-trim-cmd-norm</property><value>{lim[a]!r}</value></product>"
        for a, n in (("de", "pitch"), ("da", "roll"), ("dr", "yaw"))
    }
    de_cmd = _command(
        "fcs/de-cmd-rad",
        "fcs/de-cmd-sum-rad",
        trim["de"] + "<property>fcs/elevator-cmd-norm</property>"
        "<property>fcs/de-maneuver-rad</property><property>fcs/de-sas-rad</property>",
        q_de,
    )
    da_cmd = _command(
        "fcs/da-cmd-rad", "fcs/da-cmd-sum-rad", trim["da"] + "<property>fcs/da-maneuver-rad</property>", q_da
    )
    dr_cmd = _command(
        "fcs/dr-cmd-rad", "fcs/dr-cmd-sum-rad", trim["dr"] + "<property>fcs/dr-maneuver-rad</property>", q_dr
    )
    throttle = _command(
        "fcs/throttle-pos",
        "fcs/throttle-cmd-sum",
        "<property>fcs/throttle-cmd-norm[0]</property><property>fcs/throttle-maneuver</property>",
        fcs.throttle_step,
        "<clipto><min>0</min><max>1</max></clipto>",
    )
    tmax_lbf = aircraft.max_thrust * N2LBF
    return f"""  <flight_control name="fsid">
    <property value="0">fcs/de-maneuver-rad</property>
    <property value="0">fcs/da-maneuver-rad</property>
    <property value="0">fcs/dr-maneuver-rad</property>
    <property value="0">fcs/throttle-maneuver</property>
    <property value="0">fcs/sas-on</property>
    <property value="0">fcs/sas-alpha-ref-rad</property>
    <property value="0">fcs/servo-quantize</property>
    <channel name="pitch">
      <fcs_function name="fcs/de-sas-rad"><function><product><property>fcs/sas-on</property><sum>
        <product><value>{fcs.sas_k_alpha!r}</value><difference><property>aero/alpha-rad</property><property>fcs/sas-alpha-ref-rad</property></difference></product>
        <product><value>{fcs.sas_k_q!r}</value><property>velocities/q-rad_sec</property></product>
      </sum></product></function></fcs_function>
      {de_cmd}
{_actuator('de', lim['de'], fcs.actuator_lag_s)}
    </channel>
    <channel name="roll">
      {da_cmd}
{_actuator('da', lim['da'], fcs.actuator_lag_s)}
    </channel>
    <channel name="yaw">
      {dr_cmd}
{_actuator('dr', lim['dr'], fcs.actuator_lag_s)}
    </channel>
    <channel name="thrust">
      {throttle}
      <pure_gain name="fcs/thrust-lbf"><input>fcs/throttle-pos</input><gain>{tmax_lbf!r}</gain>
        <output>external_reactions/thrust/magnitude</output></pure_gain>
    </channel>
  </flight_control>"""


def aircraft_xml(aircraft: Aircraft, fcs: FcsConfig) -> str:
    """The complete JSBSim aircraft definition as XML text.

    Ixz: the truth set holds the textbook product of inertia (int x z dm, body axes, the
    tensor's off-diagonal is -Ixz). JSBSim 1.3 builds its tensor with the opposite sign of
    the <ixz> element, so the element gets -Ixz (the flown rates then satisfy the Euler
    equations with the truth set's Ixz)."""
    ac = aircraft
    loc0 = '<x>0</x><y>0</y><z>0</z>'
    return f"""<?xml version="1.0"?>
<!-- Generated by fsid sim from {escape(str(ac.path))}. Do not edit: regenerate. -->
<fdm_config name="{escape(ac.name)}" version="2.0" release="BETA">
  <fileheader><author>fsid</author><description>{escape(ac.description)}</description></fileheader>
  <metrics>
    <wingarea unit="FT2">{ac.S * M2FT**2!r}</wingarea>
    <wingspan unit="FT">{ac.b * M2FT!r}</wingspan>
    <chord unit="FT">{ac.cbar * M2FT!r}</chord>
    <htailarea unit="M2">0</htailarea><htailarm unit="M">0</htailarm>
    <vtailarea unit="M2">0</vtailarea><vtailarm unit="M">0</vtailarm>
    <location name="AERORP" unit="M">{loc0}</location>
    <location name="EYEPOINT" unit="M">{loc0}</location>
    <location name="VRP" unit="M">{loc0}</location>
  </metrics>
  <mass_balance>
    <ixx unit="SLUG*FT2">{ac.Ixx * KGM2_2_SLUGFT2!r}</ixx>
    <iyy unit="SLUG*FT2">{ac.Iyy * KGM2_2_SLUGFT2!r}</iyy>
    <izz unit="SLUG*FT2">{ac.Izz * KGM2_2_SLUGFT2!r}</izz>
    <ixz unit="SLUG*FT2">{-ac.Ixz * KGM2_2_SLUGFT2!r}</ixz>
    <emptywt unit="LBS">{ac.mass * KG2LB!r}</emptywt>
    <location name="CG" unit="M">{loc0}</location>
  </mass_balance>
  <ground_reactions/>
  <external_reactions>
    <force name="thrust" frame="BODY">
      <location unit="M">{loc0}</location>
      <direction><x>1</x><y>0</y><z>0</z></direction>
    </force>
  </external_reactions>
  <propulsion>
    <engine file="fsid_zero_engine">
      <thruster file="fsid_direct">
        <location unit="M">{loc0}</location>
        <orient unit="DEG"><roll>0</roll><pitch>0</pitch><yaw>0</yaw></orient>
      </thruster>
    </engine>
  </propulsion>
{_fcs_xml(ac, fcs)}
{_aero_xml(ac)}
</fdm_config>
"""


_ENGINE = """<?xml version="1.0"?>
<!-- zero-power engine: exists only so JSBSim's trim has a throttle to adjust -->
<electric_engine name="fsid_zero_engine"><power unit="WATTS">0</power></electric_engine>
"""
_THRUSTER = """<?xml version="1.0"?>
<direct name="fsid_direct"></direct>
"""


def write_jsbsim_root(aircraft: Aircraft, fcs: FcsConfig, root: str | Path) -> str:
    """Write the aircraft, engine and thruster XML under ``root``; return the model name."""
    root = Path(root)
    name = aircraft.name
    (root / "aircraft" / name).mkdir(parents=True, exist_ok=True)
    (root / "engine").mkdir(parents=True, exist_ok=True)
    (root / "systems").mkdir(parents=True, exist_ok=True)
    (root / "aircraft" / name / f"{name}.xml").write_text(aircraft_xml(aircraft, fcs))
    (root / "engine" / "fsid_zero_engine.xml").write_text(_ENGINE)
    (root / "engine" / "fsid_direct.xml").write_text(_THRUSTER)
    return name
