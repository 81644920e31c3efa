"""The method registry (pipeline.registry): one entry per method carries what it
is - its help, where its fit is (imported on first use), its colour - and a fit's key is a
FitKey, split in one place (pipeline.registry)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from pipeline.outputs.figures.style import method_color as figure_colour
from pipeline.outputs.recording_layout import method_color as recording_colour
from pipeline.registry import CATALOGUE, SPECS, FitKey, method_colour, result_key
from pipeline.validation.names import is_method, method_group


def test_every_method_names_a_fit_that_exists():
    fits = [m.fit_function() for m in CATALOGUE]
    assert all(callable(f) for f in fits)
    assert len({id(f) for f in fits}) == len(CATALOGUE)  # each method its own fit


def test_the_registry_loads_without_the_numerical_packages():
    code = "import sys, pipeline.registry; print(sorted({'numpy', 'scipy', 'numba'} & set(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out


@pytest.mark.parametrize(
    ("key", "axis", "method", "base"),
    [
        ("oem", "", "oem", "oem"),
        ("lateral-oem", "lateral", "oem", "oem"),
        ("longitudinal-fem", "longitudinal", "fem", "fem"),
        ("fem-nl", "", "fem-nl", "fem"),
        ("lateral-ukf-aug", "lateral", "ukf-aug", "ukf"),
        ("sixdof-ekf", "sixdof", "ekf", "ekf"),
        ("long-oem", "long", "oem", "oem"),  # a caller's own group
    ],
)
def test_a_key_read_back(key, axis, method, base):
    k = FitKey.parse(key)
    assert (k.axis, k.method, k.base) == (axis, method, base) and str(k) == key
    assert method_group(key) == axis and is_method(key, base) and not is_method(key, "soem")


def test_one_colour_per_method_everywhere():
    assert result_key("lateral", "fem", True) == "lateral-fem" and result_key("lateral", "fem", False) == "fem"
    for m in CATALOGUE:
        for key in (m.name, f"lateral-{m.name}"):
            rgb = method_colour(key, [key])
            assert recording_colour(key, [key]) == rgb
            assert figure_colour(key, [key]) == "#{:02x}{:02x}{:02x}".format(*rgb)
    own = [SPECS[n].colour for n in ("oem", "ls", "fem", "ekf", "ukf")]
    assert len(set(own)) == len(own)
