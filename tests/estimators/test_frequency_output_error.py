"""Frequency-domain output error (estimators.FrequencyOutputError) on the package's linear
short-period model: truth known, biases dropped out of the band, several segments, the
complex-Gaussian weighting, refusals."""

import numpy as np
import pytest

from estimators import FrequencyOutputError, ModelDefinitionError, OutputError, Segment, simulate_outputs
from estimators.datasets import multistep
from estimators.models.short_period import short_period

C = {"m": 7472.0, "Iyy": 65000.0, "S": 30.0, "cbar": 2.14, "rho": 0.792, "V": 100.0}
TRUTH = {"CLalpha": 4.8, "CLde": 0.35, "Cmalpha": -0.9, "Cmq": -18.0, "Cmde": -1.4}
NOISE = np.array([np.radians(0.1), np.radians(0.2), np.radians(0.5), 0.2])  # alpha, q, qdot, az
W = 2 * np.pi * np.linspace(0.1, 1.5, 40)


def _segments(seed: int, n: int = 1, offsets: bool = False) -> list[Segment]:
    true = short_period(C, values=TRUTH)
    rng = np.random.default_rng(seed)
    t = np.arange(0, 20, 0.02)
    segs = []
    for k in range(n):
        de = np.radians(multistep(t, 1.0 + 0.5 * k, 0.6, amplitude=2.0 - 0.3 * k))
        seg = Segment(t=t, u=de[:, None], z=np.zeros((t.size, 4)), x0=np.zeros(2))
        z = simulate_outputs(true, seg, TRUTH).to_numpy() + NOISE * rng.standard_normal((t.size, 4))
        if offsets:  # trim values of each maneuver: they drop out with the detrended ends
            z = z + rng.normal(0, 0.02, 4)
        segs.append(Segment(t=t, u=de[:, None], z=z, x0=np.zeros(2), name=f"m{k}"))
    return segs


def test_estimates_within_their_bounds_and_close_to_time_domain_output_error():
    segs = _segments(0)
    res = FrequencyOutputError(short_period(C), W).fit(segs)
    assert res.method == "fdoe" and res.converged and res.settings["domain"] == "frequency"
    assert set(res.covariances) == {"crb", "sandwich"} and res.std_method == "crb"
    for n, v in TRUTH.items():
        assert abs(res.params[n] - v) < 3 * res.std[n], (n, res.params[n], v, res.std[n])
    oem = OutputError(short_period(C)).fit(segs)
    for n in TRUTH:  # the same data, another criterion: within their bounds of each other
        assert abs(res.params[n] - oem.params[n]) < 3 * np.hypot(res.std[n], oem.std[n])
    # S is the residual spectral covariance, R its real part; residuals per segment on f
    assert res.R.shape == (4, 4) and res.residuals[0].index.name == "f_hz" and len(res.residuals[0]) == W.size


def test_trim_offsets_drop_out_and_segments_add_up():
    one = FrequencyOutputError(short_period(C), W).fit(_segments(1, n=1, offsets=True))
    three = FrequencyOutputError(short_period(C), W).fit(_segments(1, n=3, offsets=True))
    for n, v in TRUTH.items():
        assert abs(three.params[n] - v) < 3 * three.std[n], (n, three.params[n], v)
    # information adds: the maneuvers' amplitudes 2, 1.7, 1.4 against the first's 2 give
    # sqrt(4 / (4 + 2.89 + 1.96)) = 0.67 of its std, with each fit's own S estimate about it
    ratio = three.std[list(TRUTH)] / one.std[list(TRUTH)]
    assert np.all((0.5 < ratio) & (ratio < 0.9)), ratio


def test_per_segment_biases_are_held_and_said():
    model = short_period(C, output_biases=["az"])
    res = FrequencyOutputError(model, W).fit(_segments(2, n=2, offsets=True))
    assert "bias_az[0]" in res.names and "bias_az" not in res.free_names
    assert "drop out of the band" in res.message and np.isnan(res.std["bias_az[1]"])


def test_refusals():
    segs = _segments(3)
    z = segs[0].z.copy()
    z[5, 1] = np.nan
    bad = Segment(t=segs[0].t, u=segs[0].u, z=z, x0=np.zeros(2))
    with pytest.raises(ModelDefinitionError, match="complete records"):
        FrequencyOutputError(short_period(C), W).fit([bad])
    with pytest.raises(ModelDefinitionError, match="x_ref needs 2"):
        FrequencyOutputError(short_period(C), W, x_ref=[0.0])
