"""Compiled kernels kept on disk between runs (estimators.compile.kernels.load_kernels).

Each case runs a fit in a fresh Python process, as ``fsid`` does, with its own
FSID_CACHE_DIR: a two-state model written to a file, fitted by output error and by the
filter-error method (nonlinear form: the compiled filter loop). numba's own counters say
whether the compiled functions were loaded from the cache or compiled.
"""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from estimators import Model, OutputError, Parameter, Segment, simulate_outputs
from estimators.compile.kernels import kernel_for

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.slow

MODEL = '''
"""Two-state short-period model for the kernel-cache test."""
GAIN = {gain}


def f(x, u, p, c):
    alpha, q = x
    (de,) = u
    return (p.Za * alpha + q + p.Zde * de,
            GAIN * (p.Ma * alpha + p.Mq * q + p.Mde * de))


def g(x, u, p, c):
    alpha, q = x
    return alpha, q
'''

FIT = '''
import json, sys
import numpy as np
sys.path[:0] = [sys.argv[1], sys.argv[2]]
from estimators import FilterError, Model, OutputError, Parameter, Segment, simulate_outputs
from estimators.compile.kernels import kernel_for
from estimators.filters.kernels import output_kernel
import sp_model as mod
truth = dict(Za=-1.2, Zde=-0.15, Ma=-6.0, Mq=-2.5, Mde=-9.0)
m = Model(states=["alpha", "q"], inputs=["de"], outputs=["alpha", "q"],
          parameters=[Parameter(k, 0.8 * v) for k, v in truth.items()], constants={"V": 30.0},
          f=mod.f, g=mod.g, name="sp")
t = np.arange(0, 10, 0.02)
de = np.where((t > 1) & (t < 2), 0.05, 0.0) - np.where((t > 2) & (t < 3), 0.05, 0.0)
seg = Segment(t=t, u=de[:, None], z=np.zeros((t.size, 2)), x0=np.zeros(2))
seg.z = (simulate_outputs(m.with_values(truth), seg).to_numpy()
         + 1e-3 * np.random.default_rng(1).standard_normal((t.size, 2)))
out = {"oem": OutputError(m).fit(seg, estimate_x0=False).params.to_dict(),
       "q_peak": float(np.abs(seg.z[:, 1]).max())}
k = kernel_for(m)
found = [("rhs", k.module.rhs), ("rk4", k.module.integrate_rk4)]
if sys.argv[3] == "fem":
    fem = FilterError(m, form="nonlinear", process_noise={"q": 0.01}).fit(seg, estimate_x0=False)
    out["fem"] = fem.params.to_dict()
    found.append(("loop", output_kernel(m).nl_loop_rk4))
out["hits"] = {n: sum(d.stats.cache_hits.values()) for n, d in found}
out["misses"] = {n: sum(d.stats.cache_misses.values()) for n, d in found}
out["module"] = getattr(k.module, "__name__", None)
print(json.dumps(out))
'''


def _fit(tmp: Path, cache: Path, methods: str = "fem", **env) -> dict:
    e = {**os.environ, "FSID_CACHE_DIR": str(cache), **env}
    e.pop("FSID_JIT", None)
    r = subprocess.run(
        [sys.executable, str(tmp / "fit.py"), str(ROOT), str(tmp), methods],
        capture_output=True,
        text=True,
        env=e,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("jitcache")
    (tmp / "sp_model.py").write_text(MODEL.format(gain=1.0))
    (tmp / "fit.py").write_text(FIT)
    return tmp


@pytest.fixture(scope="module")
def first_and_second(work):
    cache = work / "cache"
    return cache, _fit(work, cache), _fit(work, cache)


def test_second_run_loads_what_the_first_compiled(first_and_second):
    cache, first, second = first_and_second
    assert first["hits"] == {"rhs": 0, "rk4": 0, "loop": 0}, first
    assert min(first["misses"].values()) >= 1, first
    assert second["misses"] == {"rhs": 0, "rk4": 0, "loop": 0}, second
    assert min(second["hits"].values()) >= 1, second
    # the same numbers, bit for bit, and the estimates where they belong
    assert first["oem"] == second["oem"] and first["fem"] == second["fem"]
    assert first["oem"]["Ma"] == pytest.approx(-6.0, rel=0.01)
    names = sorted(p.name for p in (cache / "kernels").glob("*.py"))
    assert [n.split("_")[1] for n in names] == ["filter", "rhs"], names
    assert second["module"] + ".py" in names


def test_an_edited_model_gets_new_kernels(work, first_and_second):
    cache, first, _ = first_and_second
    (work / "sp_model.py").write_text(MODEL.format(gain=1.1))
    try:
        edited = _fit(work, cache, "oem")
    finally:
        (work / "sp_model.py").write_text(MODEL.format(gain=1.0))
    assert edited["module"] != first["module"]
    assert edited["hits"]["rk4"] == 0 and edited["misses"]["rk4"] >= 1
    # the edited f is what runs: its 10 % stronger pitching moment moves the simulated
    # response (the data are simulated with it), and the fit still finds the truth
    assert abs(edited["q_peak"] / first["q_peak"] - 1.0) > 0.01, (edited, first)
    assert edited["oem"]["Ma"] == pytest.approx(-6.0, rel=0.01)


def test_cache_off_writes_nothing_and_gives_the_same_numbers(work, first_and_second):
    _, first, _ = first_and_second
    off = work / "off"
    r = _fit(work, off, "oem", FSID_JIT_CACHE="0")
    assert r["module"] is None and r["hits"]["rk4"] == 0
    assert not (off / "kernels").exists() or not any((off / "kernels").iterdir())
    assert r["oem"] == first["oem"]


#: one-state models typed in (built with exec: no source file): f2 doubles f1's input gain
TYPED = textwrap.dedent('''
    def f1(x, u, p, c):
        (v,) = x
        (w,) = u
        return (p.a * v + p.b * w,)

    def f2(x, u, p, c):
        (v,) = x
        (w,) = u
        return (p.a * v + 2.0 * p.b * w,)

    def g(x, u, p, c):
        (v,) = x
        return (v,)
''')


def _typed() -> dict:
    ns: dict = {}
    exec(TYPED, ns)
    return ns


def test_a_model_without_a_source_file_compiles_in_memory(tmp_path, monkeypatch):
    monkeypatch.setenv("FSID_CACHE_DIR", str(tmp_path))
    ns = _typed()
    m = Model(
        states=["v"],
        inputs=["w"],
        outputs=["v"],
        parameters=[Parameter("a", -1.0), Parameter("b", 1.0, free=False)],
        f=ns["f1"],
        g=ns["g"],
        name="typed",
    )
    t = np.arange(0, 5, 0.05)
    seg = Segment(t=t, u=np.sin(t)[:, None], z=np.zeros((t.size, 1)), x0=np.zeros(1))
    seg.z = simulate_outputs(m.with_values({"a": -2.0}), seg).to_numpy() + 1e-3 * np.random.default_rng(
        2
    ).standard_normal((t.size, 1))
    res = OutputError(m).fit(seg, estimate_x0=False)
    assert abs(res.params["a"] + 2.0) < 3 * res.std["a"]
    k = kernel_for(m)
    assert k.compiled and not hasattr(k.module, "__file__")
    assert not (tmp_path / "kernels").exists() or not any((tmp_path / "kernels").glob("*.py"))


def test_models_sharing_g_get_their_own_filter_loop(tmp_path, monkeypatch):
    """Two models with the same g and names but different f: the filter-error kernels
    (which call the model's rhs) are not shared - the second fit sees its own f (input
    gain 2: the estimated b halves)."""
    from estimators import FilterError
    from estimators.filters.kernels import output_kernel

    monkeypatch.setenv("FSID_CACHE_DIR", str(tmp_path))
    ns = _typed()
    t = np.arange(0, 20, 0.05)
    w = np.sign(np.sin(0.7 * t))[:, None]
    fits = []
    for f in (ns["f1"], ns["f2"]):
        m = Model(
            states=["v"],
            inputs=["w"],
            outputs=["v"],
            parameters=[Parameter("a", -1.0), Parameter("b", 0.5)],
            f=f,
            g=ns["g"],
            name="shared-g",
        )
        seg = Segment(t=t, u=w, z=np.zeros((t.size, 1)), x0=np.zeros(1))
        truth = Model(
            states=["v"],
            inputs=["w"],
            outputs=["v"],
            parameters=[Parameter("a", -2.0), Parameter("b", 1.0)],
            f=ns["f1"],
            g=ns["g"],
        )
        seg.z = simulate_outputs(truth, seg).to_numpy() + 1e-3 * np.random.default_rng(3).standard_normal((t.size, 1))
        fits.append((m, FilterError(m, form="nonlinear", process_noise={"v": 1e-3}).fit(seg, estimate_x0=False)))
    (m1, r1), (m2, r2) = fits
    assert output_kernel(m1) is not output_kernel(m2)
    assert r1.params["b"] == pytest.approx(1.0, rel=0.02)
    assert r2.params["b"] == pytest.approx(0.5, rel=0.02)


def _module_files(root: Path, name: str, mb: float, age_days: float, now: float) -> None:
    """A fake kernel module in a cache folder: its .py, numba's index and object file (``mb``
    megabytes), last used ``age_days`` ago (its ``.used`` stamp)."""
    (root / "__pycache__").mkdir(parents=True, exist_ok=True)
    files = [
        root / f"{name}.py",
        root / "__pycache__" / f"{name}.rhs-7.py311.nbi",
        root / "__pycache__" / f"{name}.rhs-7.py311.1.nbc",
        root / f"{name}.used",
    ]
    for p in files:
        p.write_bytes(b"x" * (int(mb * 1e6) if p.suffix == ".nbc" else 10))
        t = now - age_days * 86400.0
        os.utime(p, (t, t))


def test_prune_removes_unused_then_least_recently_used_modules(tmp_path):
    from estimators.compile import prune_kernels

    now = 2.0e9
    _module_files(tmp_path, "fsid_rhs_old", 0.1, 40.0, now)  # unused for 40 days
    _module_files(tmp_path, "fsid_filter_mid", 2.0, 10.0, now)  # 2 MB, used 10 days ago
    _module_files(tmp_path, "fsid_rhs_new", 2.0, 1.0, now)  # 2 MB, used yesterday
    _module_files(tmp_path, "fsid_rhs_live", 2.0, 50.0, now)  # old, but loaded by this process
    (tmp_path / "notes.txt").write_text("not ours")
    (tmp_path / "fsid.py").write_text("not a kernel")
    os.utime(tmp_path / "notes.txt", (0, 0))

    def names():
        return sorted({p.name.split(".")[0] for p in tmp_path.rglob("*") if p.is_file()})

    # within both limits nothing goes
    assert prune_kernels(tmp_path, max_age_days=60, max_mb=100, now=now) == []
    # 30 days: the old module goes with its numba files, the one in use stays
    assert prune_kernels(tmp_path, max_age_days=30, max_mb=100, keep=["fsid_rhs_live"], now=now) == ["fsid_rhs_old"]
    assert names() == ["fsid", "fsid_filter_mid", "fsid_rhs_live", "fsid_rhs_new", "notes"]
    # 5 MB for 6 MB of kernels: the least recently used goes first, then no more than needed
    assert prune_kernels(tmp_path, max_age_days=30, max_mb=5, keep=["fsid_rhs_live"], now=now) == ["fsid_filter_mid"]
    assert names() == ["fsid", "fsid_rhs_live", "fsid_rhs_new", "notes"]


def test_a_new_kernel_prunes_stale_ones_and_keeps_its_own(work, tmp_path):
    """A process writing a new module prunes the folder first (FSID_CACHE_DAYS=0: every
    module it did not load is stale); a load stamps ``.used`` and leaves the .py's time,
    which numba's index checks, as it was."""
    cache = tmp_path / "cache"
    first = _fit(work, cache, "oem")
    kernels = cache / "kernels"
    py = kernels / f"{first['module']}.py"
    mtime = py.stat().st_mtime
    assert (kernels / f"{first['module']}.used").is_file()
    again = _fit(work, cache, "oem", FSID_CACHE_DAYS="0")  # nothing new written: no pruning
    assert again["misses"]["rk4"] == 0 and py.stat().st_mtime == mtime
    (work / "sp_model.py").write_text(MODEL.format(gain=1.1))
    try:
        edited = _fit(work, cache, "oem", FSID_CACHE_DAYS="0")
    finally:
        (work / "sp_model.py").write_text(MODEL.format(gain=1.0))
    left = {p.name.split(".")[0] for p in kernels.rglob("*") if p.is_file()}
    assert left == {edited["module"]}, left
    assert edited["oem"]["Ma"] == pytest.approx(-6.0, rel=0.01)
