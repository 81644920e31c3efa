"""The ArduPilot Lua player of ``fsid design`` run in a Lua 5.4 interpreter (lupa) against
stand-ins for the autopilot's scripting bindings (servo outputs, RC switch, clock,
attitude, parameters, messages, log): the pulses it writes, read back through the ingest's
own servo calibration (pipeline.ingest.maps.servo.pwm_deflection), are the designed inputs
added to what the autopilot commands; it starts on the switch, stops at the end, on the
switch going low and beyond the attitude limits, and re-arms only after the switch is low."""

import math

import numpy as np
import pandas as pd
import pytest

lupa = pytest.importorskip("lupa.lua54")

from pipeline.ingest.maps import load_map  # noqa: E402
from pipeline.ingest.maps.servo import pwm_deflection  # noqa: E402
from pipeline.outputs.lua_player import SURFACES, player_script  # noqa: E402
from sim.maneuvers import orthogonal_multisines  # noqa: E402

TRAVEL = {"de": 20.0, "da": 18.0, "dr": 25.0}
#: the outputs (0-based channel) of each surface's servo function, their calibration
#: (the aileron reversed and asymmetric about its trim) and the autopilot's own command
OUTPUTS = {"de": 1, "da": 0, "dr": 3}
PARAMS = {
    "SERVO2_MIN": 1000,
    "SERVO2_MAX": 2000,
    "SERVO2_TRIM": 1500,
    "SERVO1_MIN": 1100,
    "SERVO1_MAX": 1950,
    "SERVO1_TRIM": 1480,
    "SERVO1_REVERSED": 1,
    "SERVO4_MIN": 1050,
    "SERVO4_MAX": 1900,
    "SERVO4_TRIM": 1500,
}
COMMANDED = {"de": 1530, "da": 1470, "dr": 1500}

HARNESS = """
local H = {now = 0, switch = 0, roll = 0, pitch = 0, armed = true, out = {}, texts = {}, logs = 0}
local function ms(v) return {tofloat = function(self) return v end} end
millis = function() return ms(H.now) end
local SW = {get_aux_switch_pos = function(self) return H.switch end}
rc = {find_channel_for_option = function(self, opt) if opt == 300 then return SW end return nil end}
param = {get = function(self, name) return H.params[name] end}
arming = {is_armed = function(self) return H.armed end}
ahrs = {get_roll = function(self) return H.roll end, get_pitch = function(self) return H.pitch end}
gcs = {send_text = function(self, sev, text) H.texts[#H.texts + 1] = text end}
logger = {write = function(self, ...) H.logs = H.logs + 1 end}
SRV_Channels = {
  find_channel = function(self, func) return H.chan[func] end,
  get_output_pwm = function(self, func) return H.cmd[func] end,
  set_output_pwm_chan_timeout = function(self, chan, pwm, timeout)
    H.out[#H.out + 1] = {H.now, chan, pwm, timeout}
  end,
}
return H
"""


class Autopilot:
    """The Lua runtime with the harness, the player loaded and run on its own schedule."""

    def __init__(self, script: str):
        self.lua = lupa.LuaRuntime(unpack_returned_tuples=True)
        self.H = self.lua.execute(HARNESS)
        self.H.params = self.lua.table_from(PARAMS)
        self.H.chan = self.lua.table_from({SURFACES[u][0]: c for u, c in OUTPUTS.items()})
        self.H.cmd = self.lua.table_from({SURFACES[u][0]: p for u, p in COMMANDED.items()})
        fn, self.period = self.lua.execute(script)
        self.fn = fn

    def run_until(self, t_ms: float) -> None:
        while self.H.now < t_ms:
            self.fn, self.period = self.fn()
            self.H.now += self.period

    def outputs(self) -> pd.DataFrame:
        rows = [tuple(self.H.out[i + 1][k + 1] for k in range(4)) for i in range(len(self.H.out))]
        return pd.DataFrame(rows, columns=["ms", "chan", "pwm", "timeout"])

    def texts(self) -> list[str]:
        return [self.H.texts[i + 1] for i in range(len(self.H.texts))]


@pytest.fixture(scope="module")
def design():
    U = orthogonal_multisines(["de", "da", "dr"], (0.2, 1.5), 10.0, 0.02, {"de": 0.05, "da": 0.06, "dr": 0.04})
    return U, player_script(U, TRAVEL, (0.2, 1.5))


def test_the_played_pulses_read_back_as_the_design(design):
    U, script = design
    ap = Autopilot(script)
    ap.run_until(500.0)
    assert ap.outputs().empty  # the switch is low: nothing played
    ap.H.switch = 2
    start = ap.H.now
    ap.run_until(start + 10_500.0)
    out = ap.outputs()
    assert any("sequence started" in x for x in ap.texts()) and any("sequence done" in x for x in ap.texts())
    rules = load_map("ardupilot_bin").rules
    # each pulse, calibrated as the ingest reads the log, minus the autopilot's own command
    for u, chan in OUTPUTS.items():
        mine = out[out["chan"] == chan]
        t = (mine["ms"].to_numpy() - start) / 1000.0
        assert t.min() == 0.0 and t.max() <= 10.0 and len(mine) == 1001  # every 10 ms over the sequence
        n = chan + 1
        rule = rules[u]

        def deflection(pwm, rule=rule, n=n, u=u):
            return rule.sign * pwm_deflection(rule, np.asarray(pwm, float), PARAMS, n, TRAVEL[u])[0]

        played = deflection(mine["pwm"].to_numpy()) - deflection(COMMANDED[u])
        designed = np.interp(t, U.index.to_numpy(), U[u].to_numpy())
        # integer pulses: half a microsecond of the smaller half-range is the resolution
        half = min(
            PARAMS[f"SERVO{n}_MAX"] - PARAMS[f"SERVO{n}_TRIM"], PARAMS[f"SERVO{n}_TRIM"] - PARAMS[f"SERVO{n}_MIN"]
        )
        resolution = 0.5 / half * math.radians(TRAVEL[u])
        # linear interpolation of the 50 Hz design between its samples differs from the
        # closed form by at most (2 pi f_max)^2 dt^2 / 8 of the amplitude
        interp = (2 * np.pi * 1.5) ** 2 * 0.02**2 / 8 * np.max(np.abs(U[u])) * len(U.attrs["frequencies"][u])
        assert np.max(np.abs(played - designed)) <= resolution + interp + 1e-12, u
        assert np.ptp(played) > 0.8 * np.ptp(U[u])  # it moves as much as designed
        assert (mine["timeout"] == 50).all()
    # the sequence ended: nothing more until the switch is lowered and raised again
    n_out = len(out)
    ap.run_until(ap.H.now + 1000.0)
    assert len(ap.outputs()) == n_out
    ap.H.switch = 0
    ap.run_until(ap.H.now + 100.0)
    ap.H.switch = 2
    ap.run_until(ap.H.now + 100.0)
    assert len(ap.outputs()) > n_out  # re-armed by the low switch


def test_it_stops_on_the_switch_and_the_attitude_limits(design):
    _, script = design
    ap = Autopilot(script)
    ap.H.switch = 2
    ap.run_until(2000.0)
    ap.H.switch = 0
    ap.run_until(2100.0)
    n = len(ap.outputs())
    ap.run_until(4000.0)
    assert len(ap.outputs()) == n and any("switch low" in x for x in ap.texts())
    ap.H.switch = 2
    ap.run_until(4500.0)
    ap.H.roll = math.radians(50.0)
    ap.run_until(4600.0)
    n = len(ap.outputs())
    ap.run_until(6000.0)
    assert len(ap.outputs()) == n and any("attitude beyond its limits" in x for x in ap.texts())


def test_it_does_not_start_disarmed_or_without_the_outputs(design):
    _, script = design
    ap = Autopilot(script)
    ap.H.armed = False
    ap.H.switch = 2
    ap.run_until(1000.0)
    assert ap.outputs().empty and any("not armed" in x for x in ap.texts())
    ap = Autopilot(script)
    ap.H.chan = ap.lua.table_from({SURFACES["de"][0]: 1})  # no aileron or rudder output
    ap.H.switch = 2
    ap.run_until(1000.0)
    assert any("no output with SERVOn_FUNCTION 4" in x for x in ap.texts())
    assert len(ap.outputs()) <= 1  # at most the elevator's first pulse before it stopped
