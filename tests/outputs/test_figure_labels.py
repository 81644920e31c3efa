"""The frequency-response figures' labels stay clear of the panels beside them (a newcomer
found the phase column's labels running into the magnitude panels): rendered, every y
label's box is checked against every other axes' box."""

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from estimators import frequency_response
from pipeline.outputs.figures.frequency import _draw as draw_validation
from pipeline.outputs.figures.style import grid_size
from pipeline.outputs.response import _draw as draw_response


def _overlaps(fig: Figure) -> list[str]:
    FigureCanvasAgg(fig).draw()
    r = fig.canvas.get_renderer()
    axes = fig.get_axes()
    out = []
    for a in axes:
        label = a.yaxis.label
        if not label.get_text():
            continue
        box = label.get_window_extent(r)
        for b in axes:
            if b is not a and box.overlaps(b.get_window_extent(r)):
                out.append(f"{label.get_text()!r} runs into another panel")
    return out


def test_validation_frequency_figure_labels_do_not_overlap():
    f = np.geomspace(0.1, 5, 40)
    H = (1.0 / (1j * 2 * np.pi * f + 1.0))[:, None, None] * np.ones((1, 2, 2))
    fr = {
        "f": f,
        "H_model": H,
        "H_analytic": H,
        "H_data": H * 1.05,
        "coherence": np.full(H.shape, 0.9),
        "used": np.ones(H.shape, dtype=bool),
        "inputs": ["da", "dr"],
        "outputs": ["p", "r"],
    }
    fig = Figure(figsize=grid_size(4, 1.15))
    draw_validation(fig, "lateral-oem", fr, [(0, 0), (1, 0), (0, 1), (1, 1)], 0.6)
    assert not _overlaps(fig)


def test_response_figure_labels_do_not_overlap():
    rng = np.random.default_rng(0)
    t = np.arange(6000) * 0.02
    u = rng.standard_normal((t.size, 2))
    y = np.column_stack([np.convolve(u[:, 0], np.ones(5) / 5, "same"), u[:, 1] + 0.1 * rng.standard_normal(t.size)])
    fr = frequency_response(t, u, y, inputs=["de", "dr"], outputs=["q", "r"])
    fig = Figure(figsize=grid_size(4, 1.15))
    draw_response(fig, fr, {})
    assert not _overlaps(fig)
