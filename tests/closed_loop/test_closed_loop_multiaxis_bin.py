"""Closed loop on multiaxis_multisine_turbulence from the ArduPilot log without vanes: the
flight of tests/closed_loop/test_closed_loop_multiaxis.py written as flight.bin, whose
alpha and beta are the autopilot's estimates, fitted by filter error with the angles rebuilt
from the flight path; the longitudinal axis (the lateral one's rebuilt beta:
tests/conditioning/test_flow_angles.py). Its own file: it flies and fits on its own (no
module fixture), so the test run can give it a worker of its own."""

import json

from test_closed_loop_multiaxis import LONG, SCENARIO


def test_estimate_from_the_bin_without_vanes(tmp_path):
    """The ArduPilot log of the same flight (flight.bin, ``fsid simulate``): its AOA/SSA are
    the autopilot's estimates, so alpha and beta are rebuilt from the 10 Hz flight path,
    and those carry no gust. The gust models then measure them as the rigid body's angles
    (alpha_k, beta_k; the problem notes say so), and filter error runs on the 50 Hz grid
    of the other outputs, the rebuilt angles at their own samples.
    ``fsid estimate flight.bin --method fem --validate-with validation.bin``, seed 31:
    before, both filter-error fits failed (singular information on the longitudinal axis,
    SVD failure on the lateral one); with the angles as alpha_k, beta_k on the 10 Hz grid
    every derivative within 12.4 std (lateral 10.4; longitudinal not converged); on the
    50 Hz grid longitudinal within 9.6 (CL0, Cm0 7.8, CD0 6.4; CLq 4.0), lateral 4.5
    (CYbeta), both converged (seeds 32-34, ad hoc: 8.6, 7.8, 14.5 and 3.6, 4.7, 2.9). The
    vanes' flight.mcap: within 3.4.

    CL0, Cm0 and CD0 were off by the flight's mean vertical gust, which the rebuilt alpha
    cannot see (ad hoc: -0.40 m/s over the flight, the air-relative alpha 0.45 deg above
    the inertial one). The reconstruction assumes no vertical wind; the uncertainty of
    that (and of the fitted horizontal wind) now reaches the estimates as a consider part
    (pipeline.uncertainty.consider.wind): the vertical gust's level from the airspeed
    residual above the pitot noise (2.07 m/s; truth 2.19), its time constant from the
    residual's correlation (6.8 s; L_w / V 8.0), averaged over the fitted maneuvers:
    0.76 m/s (longitudinal). With it CL0 is 1.05 total std off, Cm0 and CD0 under 1;
    longitudinal within 3.7 (CLq), lateral 4.3 (CYbeta; the horizontal wind's part is
    small there).

    The flight turns through 80 deg, enough for the wind fit to estimate the pitot's scale
    factor with the wind (pipeline.conditioning.flow_angles.airspeed_calibration): +2.99 +- 1.91 %
    (truth 0; the gusts colour the airspeed residual), not applied, and its std carried
    with the wind's: longitudinal within 1.85 std, lateral 3.04 (CYbeta)."""
    from pipeline.cli import main
    from pipeline.jobs.simulate import simulate
    from pipeline.problems import KINEMATIC_NOTE

    run, _ = simulate(SCENARIO, tmp_path / "sim", progress=False)
    out = tmp_path / "est"
    assert (
        main(
            [
                "estimate",
                str(run / "flight.bin"),
                "--method",
                "fem",
                "--model",
                "longitudinal",
                "--no-compat",
                "--no-figures",
                "--quiet",
                "--validate-with",
                str(run / "validation.bin"),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    rep = json.loads((out / "report.json").read_text())
    assert rep["meta"]["flow_angles"]["channels"] == ["alpha", "beta"]
    wu = rep["meta"]["flow_angles"]["wind_uncertainty"]
    assert wu["parts"] == ["wind north", "wind east", "vertical wind", "airspeed scale"]
    cal = rep["meta"]["flow_angles"]["airspeed_scale"]  # the pitot has no error here
    assert cal["status"] == "estimated" and not cal["applied"] and cal["carried"], cal
    assert abs(cal["estimate"]) < 3 * cal["std"] and set(wu["std_airspeed_scale"].values()) == {cal["std"]}
    assert set(wu["methods"].values()) == {"propagated"}
    assert 0.4 < wu["std_mps"]["fem"]["vertical wind"] < 1.2, wu["std_mps"]
    m = rep["methods"]["fem"]  # one axis: the key is the method
    assert KINEMATIC_NOTE.format(angle="alpha", state="alpha_k") in m["validation"]["problem"]["notes"]
    assert "rebuilt with" in m["consider_source"]
    # this seed's longitudinal fit ends near 3 total std, the last digits machine-dependent:
    # the lateral axis' limit of the same flight, 3.5
    worst = max(abs(m["parameters"][n]["error_in_std"]) for n in LONG)
    assert m["converged"] and worst < 3.5, worst
    ps = rep["methods"]["fem"]["parameters"]
    crb = rep["methods"]["fem"]["validation"]["uncertainty"]["per_parameter"]
    # the trim terms the mean vertical gust moves: within 3 total std, 6-10 CRB std off
    for n in ("CL0", "Cm0", "CD0"):
        assert abs(ps[n]["error_in_std"]) < 3.0 < abs(ps[n]["estimate"] - ps[n]["truth"]) / crb[n]["crb_std"], (
            n,
            ps[n],
        )
    assert (
        "grid 50 Hz; slower channels at their own samples only"
        in rep["methods"]["fem"]["validation"]["problem"]["notes"]
    )
