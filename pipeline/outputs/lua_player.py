"""The designed inputs as an ArduPilot Lua script (``fsid design`` writes it as
``fsid_player.lua``): while an RC switch is high it adds the multisines to the surface
outputs that the autopilot commands, so the flight flies the design on top of the pilot's or
the stabiliser's commands.

The script evaluates each input's closed form u(t) = scale sum_k sin(2 pi f_k t + phase_k)
(:func:`sim.maneuvers.orthogonal_multisines`) at its own clock and converts deflection to
pulse width with the servo's SERVOn_MIN/MAX/TRIM/REVERSED and the aircraft file's travel,
the inverse of the calibration the ingest reads the log with
(:func:`pipeline.ingest.maps.servo.pwm_deflection`), so that the logged surfaces read back as
the design. Surface signs and ArduPilot servo functions are those of the ArduPilot map.

Limits (stated in the script's header): it needs a dedicated output per surface (no elevon or
V-tail mixing), an RC channel with RCx_OPTION = 300 (Scripting1), and the vehicle armed; it
stops (and sends why) when the switch goes low, when the bank or pitch angle leaves its
limits, at the end of the sequence, or when an output has no servo function; it clamps each
pulse to the servo's MIN/MAX. It runs once per switch-high; lower the switch to re-arm it.
"""

from __future__ import annotations

from collections.abc import Mapping
from string import Template

import numpy as np
import pandas as pd

from pipeline.ingest.maps import load_map

#: ArduPilot servo function and sign of each surface: the ArduPilot map's (ardupilot_bin.toml's
#: [channels.*] pwm.function and sign), so that the log reads the played pulses back as the design
SURFACES = {
    u: (int(r.pwm["function"]), float(r.sign))
    for u, r in load_map("ardupilot_bin").rules.items()
    if u in ("de", "da", "dr")
}
#: the script's period (ms) and each override's timeout (ms): an override the script stops
#: renewing ends within the timeout
PERIOD_MS = 10
OVERRIDE_TIMEOUT_MS = 50
#: RCx_OPTION of the switch that runs the sequence (Scripting1)
SWITCH_OPTION = 300
#: the sequence stops when |bank| or |pitch| exceeds these (deg)
ROLL_LIMIT_DEG = 45.0
PITCH_LIMIT_DEG = 30.0

_TEMPLATE = Template(
    """-- fsid designed-input player (written by fsid design; regenerate rather than edit)
-- Adds the designed multisines to the surface outputs while the RC switch with
-- RCx_OPTION = $switch (Scripting1) is high. Needs: a dedicated output per surface
-- (SERVOn_FUNCTION $functions; no elevon or V-tail mixing), the vehicle armed.
-- Stops when the switch goes low, |bank| > $roll_limit deg or |pitch| > $pitch_limit deg,
-- at the end ($duration s); every pulse clamped to SERVOn_MIN/MAX. Runs once per
-- switch-high: lower the switch to re-arm. Logged as FSID (T, and each input in rad).
-- Design: band $band Hz, $duration s; deflection per surface = scale * sum sin(2 pi f t + phase)

local DURATION = $duration
local PERIOD_MS = $period
local TIMEOUT_MS = $timeout
local SWITCH_OPTION = $switch
local ROLL_LIMIT = math.rad($roll_limit)
local PITCH_LIMIT = math.rad($pitch_limit)
local INPUTS = {
$inputs
}

local state = "idle"     -- idle -> playing -> done (until the switch goes low)
local start_ms = 0

local function say(severity, text)
  gcs:send_text(severity, "fsid: " .. text)
end

local function servo(input)
  local chan = SRV_Channels:find_channel(input.func)
  if not chan then return nil end
  local pre = string.format("SERVO%d_", chan + 1)
  return {
    chan = chan,
    min = param:get(pre .. "MIN") or 1100,
    max = param:get(pre .. "MAX") or 1900,
    trim = param:get(pre .. "TRIM") or 1500,
    rev = (param:get(pre .. "REVERSED") or 0) ~= 0,
  }
end

-- the servo's normalised command (-1..1) of a pulse, and its inverse: the ingest's calibration
local function norm_of(pwm, s)
  local n
  if pwm >= s.trim then n = (pwm - s.trim) / (s.max - s.trim) else n = (pwm - s.trim) / (s.trim - s.min) end
  if s.rev then n = -n end
  return n
end

local function pwm_of(n, s)
  if s.rev then n = -n end
  local p
  if n >= 0 then p = s.trim + n * (s.max - s.trim) else p = s.trim + n * (s.trim - s.min) end
  p = math.max(s.min, math.min(s.max, p))
  return math.floor(p + 0.5)
end

local function deflection(input, t)
  local u = 0.0
  for k = 1, #input.freqs do
    u = u + math.sin(2 * math.pi * input.freqs[k] * t + input.phases[k])
  end
  return input.scale * u
end

local function stop(why)
  state = "done"
  say(6, why)
end

local function play(now)
  local t = (now - start_ms) / 1000.0
  if t > DURATION then
    stop(string.format("sequence done (%.1f s)", DURATION))
    return
  end
  if math.abs(ahrs:get_roll()) > ROLL_LIMIT or math.abs(ahrs:get_pitch()) > PITCH_LIMIT then
    stop(string.format("stopped at %.2f s: attitude beyond its limits", t))
    return
  end
  local values = {}
  for _, input in ipairs(INPUTS) do
    local s = servo(input)
    local current = s and SRV_Channels:get_output_pwm(input.func)
    if not current then
      stop(input.name .. ": no output with SERVOn_FUNCTION " .. input.func)
      return
    end
    local d = deflection(input, t)
    values[#values + 1] = d
    local n = norm_of(current, s) + d / (input.sign * input.travel)
    SRV_Channels:set_output_pwm_chan_timeout(s.chan, pwm_of(n, s), TIMEOUT_MS)
  end
  logger:write("FSID", "T,$labels", "f$formats", t, table.unpack(values))
end

function update()
  local sw = rc:find_channel_for_option(SWITCH_OPTION)
  local high = sw ~= nil and sw:get_aux_switch_pos() == 2
  local now = millis():tofloat()
  if state == "idle" and high then
    if not arming:is_armed() then
      say(4, "not armed: sequence not started")
      state = "done"
    else
      state = "playing"
      start_ms = now
      say(6, "sequence started")
    end
  elseif state == "playing" and not high then
    stop(string.format("stopped at %.2f s: switch low", (now - start_ms) / 1000.0))
  elseif state == "done" and not high then
    state = "idle"
  end
  if state == "playing" then play(now) end
  return update, PERIOD_MS
end

if not rc:find_channel_for_option(SWITCH_OPTION) then
  say(4, "no RC channel with RCx_OPTION " .. SWITCH_OPTION .. ": the sequence cannot start")
end
return update, PERIOD_MS
"""
)


def _numbers(x: np.ndarray) -> str:
    return "{" + ", ".join(f"{float(v):.17g}" for v in x) + "}"


def player_script(U: pd.DataFrame, travel_deg: Mapping[str, float], band: tuple[float, float]) -> str:
    """The Lua text playing the designed inputs ``U`` (orthogonal_multisines' frame, its
    attrs frequencies, phases, scale; columns among de, da, dr) with the surfaces' travel
    (deg at full servo travel) and the design's band (Hz) for the header."""
    rows = []
    for name in U.columns:
        func, sign = SURFACES[name]
        rows.append(
            f'  {{ name = "{name}", func = {func}, sign = {sign:g}, travel = {np.radians(travel_deg[name]):.17g},\n'
            f"    scale = {float(U.attrs['scale'][name]):.17g},\n"
            f"    freqs = {_numbers(U.attrs['frequencies'][name])},\n"
            f"    phases = {_numbers(U.attrs['phases'][name])} }},"
        )
    duration = float(U.index[-1] - U.index[0])
    return _TEMPLATE.substitute(
        switch=SWITCH_OPTION,
        functions=", ".join(f"{SURFACES[n][0]} ({n})" for n in U.columns),
        roll_limit=f"{ROLL_LIMIT_DEG:g}",
        pitch_limit=f"{PITCH_LIMIT_DEG:g}",
        duration=f"{duration:.17g}",
        band=f"{band[0]:g}-{band[1]:g}",
        period=PERIOD_MS,
        timeout=OVERRIDE_TIMEOUT_MS,
        inputs="\n".join(rows),
        labels=",".join(n.capitalize() for n in U.columns),
        formats="f" * len(U.columns),
    )
