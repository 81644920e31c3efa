"""How the filters fare on the lateral model with the roll gust, on data that model itself
generates: a Monte Carlo over noise draws on the inputs of one JSBSim flight of
multiaxis_multisine_turbulence (the lateral problem of pipeline.problems.multiaxis.multiaxis_problem
with the gust states: 7 states, the measured longitudinal variables as inputs).

Each draw simulates the lateral gust model (estimators.models.lateral, f_measured_gust /
g_measured_gust) at the true derivatives on the flight's own inputs (Euler-Maruyama, 10
sub-steps per 50 Hz sample), with white process noise on beta and r, the roll gust p_g and
white sensor noise at the flight's logged levels, and fits it with the pipeline's own
settings (pipeline.methods.fitting.fit_problem: FEM with F estimated, EKF and UKF with twice the Dryden
level, as on a simulated flight). Two gust variants:

* ``markov``: p_g the first-order Markov process the model assumes, with the time constant
  and rms of JSBSim's p_turb on that flight (a new realisation per draw);
* ``flight``: p_g = JSBSim's own p_turb of the flight (the same realisation in every draw;
  only the sensor and the other process noise change).

Per variant, method and derivative: empirical std over the draws / mean reported std
(1 = honest; with ``flight`` the gust is the same in every draw, so the scatter is only
the sensor noise's and this ratio and the bias say little), the bias in empirical std, and
the mean |error| / reported std (what the closed-loop tests hold below 3). A method name
ending in ``-trueQ`` (ekf-trueQ, ukf-trueQ) gives the filter the draws' own process noise
instead of the pipeline's, ``-trueQR`` their own measurement noise too (R; the pipeline's is
the grid's second differences). With ``flight`` the draws' process noise has no roll gust
(it is forced), so -trueQ/-trueQR filters get none and say nothing there.

Measured (2026-11-25, the scenario as it is now - turbulence in the aircraft's axes,
smoothed surface inputs - flight seed 31: p_turb rms 0.0566 rad/s, time constant 0.483 s;
draws 0-7, 2 jobs, 1 min; empirical / reported std, largest |bias| in empirical std,
worst mean |error| / std):
  markov fem         0.56-1.31, 1.70, 1.64 (Cnr)
  markov ekf         0.68-2.93, 1.88, 2.97 (Clp)
  markov ukf         0.42-1.23, 3.40, 1.46 (Clr)
  markov ekf-trueQ   0.63-2.07, 2.62, 4.76 (Clbeta)
  markov ukf-trueQ   0.52-3.16, 3.38, 4.01 (Clbeta)
  markov ekf-trueQR  0.82-2.59, 1.06, 3.09 (Clbeta)
  markov ukf-trueQR  0.59-4.61, 1.27, 3.49 (Clbeta)
  flight fem         mean |error|/std worst 1.84 (Clp); ekf 19.2 (Clp); ukf 2.32 (Clbeta)
Given both noise covariances exactly the filters' bias shrinks to about one empirical std
(the true process noise with the second-difference R is worse than the pipeline's
twice-the-level Q); their std stays too small (up to 2.6x, 4.6x: the covariance of the
parameter-in-the-state filter misses the gain's dependence on the parameters, Ljung).

Measured before (2026-11-25, with the scenario's turbulence in JSBSim's frame - it has since
put it in the aircraft's axes - and before the pipeline smoothed the surface inputs - the draws are
simulated and fitted on the same inputs, so that changes only their content; flight seed
31: p_turb rms 0.049 rad/s, time constant 0.418 s; draws 0-7; empirical/reported std, largest |bias| in empirical std, worst mean
|error|/std):
  markov fem        0.50-1.47, 0.76, 1.13 (CYda)
  markov ekf        0.43-1.25, 3.67, 2.38 (Clp)
  markov ukf        0.42-1.46, 4.00, 2.53 (Clp)
  markov ekf-trueQ  0.64-9.97, 6.36, 8.23 (Clbeta)
  markov ukf-trueQ  0.72-2.49, 2.99, 3.78 (Clp)
  flight fem        mean |error|/std worst 1.97 (Cldr)
  flight ekf        6.69 (Clbeta)
  flight ukf        4.83 (Clbeta)
Before the filters started the gust state at its stationary spread (at 1e-3 rad/s; the
draws' gust then started at 0): markov ekf 0.43-3.61, 3.26, 3.80 (Clp); ukf 0.59-2.76,
3.43, 3.50 (Clp); ekf-trueQ 0.63-4.20, 2.70, 4.10 (Clr); ukf-trueQ 0.63-3.40, 1.96, 3.71
(Clr); flight ekf 15.2, ukf 8.7 (Clp).
Filter error is honest and unbiased on this model, and stays within 2 std with the
flight's own roll gust. The parameter-in-the-state filters are not, on data their own
model made: Clp is biased by 3.7-4 of its empirical std, and with the flight's gust the
roll derivatives end 5-7 reported std off (on the JSBSim flight itself,
tests/closed_loop/test_closed_loop_multiaxis.py: UKF 6.5, EKF 18.7; 6.0, 6.2 once the pipeline
smoothed the surface inputs, benchmarks/input_noise_mc.py). Given the true process noise the
EKF is worse still (up to 10x too small a std; some draws wander off from the start of a
segment where the gust is uncertain and the linearisation poor). JSBSim's p_turb is the
first-order Markov process the model assumes (JSBSim's Tustin form with tau_p = L_p / V,
L_p = sqrt(L_w b) / 2.6: 0.44 s here; ad-hoc, its autocorrelation gives 0.41-0.43 s at
every lag from 0.1 to 0.6 s), so what fails there is the filters, not the gust model.

    python benchmarks/lateral_gust_filters_mc.py [--seeds 8] [--seed-base 0] [--jobs 2]
        [--flight-seed 31] [--methods fem,ekf,ukf,ekf-trueQ,ukf-trueQ,ekf-trueQR,ukf-trueQR]
        [--variants markov,flight]
"""

from __future__ import annotations

import sys
import tempfile
from functools import lru_cache, partial
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from _montecarlo import flown_problem, fly, range_line, scatter_table, seed_arguments  # noqa: E402

from pipeline.problems.lateral import LAT_FREE  # noqa: E402

SCENARIO = ROOT / "scenarios" / "multiaxis_multisine_turbulence.toml"
NAMES = LAT_FREE
#: white process noise (state unit per sqrt(s)) of the draws besides the roll gust: FEM's
#: estimates on the JSBSim flight (F_beta 0.020, F_r 0.005, F_p 0)
OTHER_F = {"beta": 0.020, "r": 0.005}
SUBSTEPS = 10


def fly_once(workdir: Path, seed: int) -> None:
    """Fly the scenario once into ``workdir``: flight.mcap, truth.json, JSBSim's roll
    gust (p_turb.npy: rows t, p_turb) and true surface positions (surfaces.npy: rows t,
    da, dr; rad)."""
    import sim
    from pipeline.outputs.writers import write_mcap, write_truth_json

    res = sim.fly(sim.load_scenario(SCENARIO), seed=seed, workdir=workdir / ".jsbsim")
    write_mcap(workdir / "flight.mcap", res)
    write_truth_json(workdir / "truth.json", res)
    np.save(workdir / "p_turb.npy", res.truth[["t", "p_turb"]].to_numpy().T)
    np.save(workdir / "surfaces.npy", res.truth[["t", "da", "dr"]].to_numpy().T)


@lru_cache(maxsize=1)
def flight(workdir: Path) -> dict:
    """The flown flight of ``workdir`` (once per process): the lateral problem (from the
    written MCAP), the truth document and JSBSim's roll gust (t, p_turb) with its time
    constant (s, from the lag autocorrelation) and rms (rad/s)."""
    pb, truth_doc = flown_problem(workdir, "lateral", rate_hz=50.0)
    t, pt = np.load(workdir / "p_turb.npy")
    lag = int(round(0.2 / np.median(np.diff(t))))
    rho = np.corrcoef(pt[:-lag], pt[lag:])[0, 1]
    return {
        "problem": pb,
        "truth": truth_doc,
        "t": t,
        "p_turb": pt,
        "tau": float(-0.2 / np.log(rho)),
        "rms": float(pt.std()),
    }


def simulate(
    pb, truth: dict, gust: str, fl: dict, rng: np.random.Generator, u_sim: list[np.ndarray] | None = None
) -> list:
    """New segments of ``pb`` with outputs simulated by its model at the true derivatives,
    driven by each segment's inputs or by ``u_sim`` (one (n, n_u) array per segment: the
    inputs the simulated aircraft saw, when those are not the ones the fit is given)."""
    from estimators.model import Namespace, Segment
    from pipeline.methods.noise import measurement_noise_std

    m = pb.model
    vals = {p.name: p.value for p in m.parameters}
    vals.update({k: v for k, v in truth["derivatives"].items() if k in vals})
    vals["tau_pg"] = fl["tau"]
    p, c = Namespace(vals), Namespace(m.constants)
    F = np.array(list(true_process_noise(pb, gust, fl).values()))
    ig = m.states.index("p_g")
    G = measurement_noise_std(pb)
    segs = []
    for i_seg, s in enumerate(pb.fit):
        us = s.u if u_sim is None else u_sim[i_seg]
        n, h = s.t.size, float(np.median(np.diff(s.t)))
        dt = h / SUBSTEPS
        x = np.zeros(len(m.states))
        for i, st in enumerate(m.states):
            if st in m.outputs and np.isfinite(s.z[0, m.outputs.index(st)]):
                x[i] = s.z[0, m.outputs.index(st)]
        x[m.states.index("beta_k")] = x[m.states.index("beta")]
        # the gust at the segment start: JSBSim's, or a draw from the stationary spread
        x[ig] = np.interp(s.t[0], fl["t"], fl["p_turb"]) if gust == "flight" else fl["rms"] * rng.standard_normal()
        X = np.empty((n, x.size))
        X[0] = x
        w = rng.standard_normal((n, SUBSTEPS, x.size)) * F * np.sqrt(dt)
        for k in range(1, n):
            for j in range(SUBSTEPS):
                a = (j + 0.5) / SUBSTEPS
                if gust == "flight":
                    x[ig] = np.interp(s.t[k - 1] + a * h, fl["t"], fl["p_turb"])
                u = (1 - a) * us[k - 1] + a * us[k]
                x = x + np.asarray(m.f(x, u, p, c), dtype=float) * dt + w[k, j]
            X[k] = x
        Y = np.array([np.asarray(m.g(X[k], us[k], p, c), dtype=float) for k in range(n)])
        Z = Y + G * rng.standard_normal(Y.shape)
        Z[np.isnan(s.z)] = np.nan
        segs.append(Segment(t=s.t, u=s.u, z=Z, x0=s.x0, constants=s.constants, name=s.name))
    return segs


def true_process_noise(pb, gust: str, fl: dict) -> dict[str, float]:
    """The process noise F (state -> state unit per sqrt(s)) the draws are simulated with
    (the roll gust's only with ``gust="markov"``)."""
    F = {s: OTHER_F.get(s, 0.0) for s in pb.model.states}
    F["p_g"] = fl["rms"] * np.sqrt(2.0 / fl["tau"]) if gust == "markov" else 0.0
    return F


def one_draw(seed: int, *, workdir: Path, methods: list[str], variants: list[str]) -> list[dict]:
    """Both gust variants of one draw, fitted by every method: rows of (variant, method,
    name, estimate, std, truth)."""
    import copy

    from pipeline.methods.fitting import fit_problem
    from pipeline.methods.noise import measurement_noise_std

    fl = flight(workdir)
    rows = []
    for gust in variants:
        pb = copy.copy(fl["problem"])
        pb.fit = simulate(fl["problem"], fl["truth"], gust, fl, np.random.default_rng(1000 + seed))
        for method in methods:
            if method.endswith("-trueQR"):  # ... and their own measurement noise
                res = fit_problem(
                    pb,
                    method[:-7],
                    process_noise=true_process_noise(pb, gust, fl),
                    measurement_noise=dict(zip(pb.model.outputs, measurement_noise_std(pb))),
                )
            elif method.endswith("-trueQ"):  # the filter given the draws' own process noise
                res = fit_problem(pb, method[:-6], process_noise=true_process_noise(pb, gust, fl))
            else:
                res = fit_problem(pb, method, turbulence=fl["truth"]["turbulence"])
            rows += [
                {
                    "variant": gust,
                    "method": method,
                    "name": n,
                    "estimate": float(res.params[n]),
                    "std": float(res.std[n]),
                    "truth": float(fl["truth"]["derivatives"][n]),
                }
                for n in NAMES
            ]
    return rows


def main() -> None:
    seeds, jobs, opt = seed_arguments(
        __doc__.splitlines()[0], 8, 0, {"flight-seed": "31", "methods": "fem,ekf,ukf", "variants": "markov,flight"}
    )
    with tempfile.TemporaryDirectory() as d:
        fly_once(Path(d), int(opt["flight-seed"]))
        fl = flight(Path(d))
        print(
            f"flight seed {opt['flight-seed']}: JSBSim p_turb rms {fl['rms']:.4f} rad/s, "
            f"time constant {fl['tau']:.3f} s"
        )
        df = fly(
            partial(one_draw, workdir=Path(d), methods=opt["methods"].split(","), variants=opt["variants"].split(",")),
            seeds,
            jobs,
        )
    df["err_std"] = (df["estimate"] - df["truth"]).abs() / df["std"]
    tab = scatter_table(df, ["variant", "method", "name"], {"reported": "std"})
    tab["mean_err_std"] = df.groupby(["variant", "method", "name"], sort=False)["err_std"].mean()
    for group, t in tab.groupby(level=[0, 1], sort=False):
        print(
            range_line(tab, group) + f"; mean |error|/std worst "
            f"{t['mean_err_std'].max():.2f} ({t['mean_err_std'].idxmax()[2]})"
        )


if __name__ == "__main__":
    main()
