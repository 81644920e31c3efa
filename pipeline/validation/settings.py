"""The options of one validation: bands, bounds and how the held-out prediction is made."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from pipeline.validation.fit import TIC_LIMIT
from pipeline.validation.truth import TRUTH_K


@dataclass(frozen=True)
class ValidationSettings:
    """Options of :func:`pipeline.validation.validate` (SI unless named otherwise).

    tolerances: proof-of-match band per channel (SI), merged over the defaults (1.5 deg/s
        on rates, 0.1 g on specific forces, 1.5 deg on angles).
    allowed_bias: largest constant offset per channel (SI) removed before judging.
    tic_limit: TIC below which an output's fit counts as good.
    truth_k: |estimate - truth| / std allowed for the truth check.
    mag_bound_db, phase_bound_deg, min_coherence: frequency-response mismatch bounds; only
        frequencies where an input's auto-spectrum reaches input_power_fraction of its peak
        and the coherence reaches min_coherence are judged.
    inverse_bandwidth: loop bandwidth (rad/s) of the inverse simulation.
    integrator: for the proof-of-match and frequency-response simulations (None: the one
        used in the fit).
    proof_of_match: how the held-out prediction is made (``auto``, ``simulation``,
        ``air-data``; :data:`pipeline.validation.proof_of_match.POM_MODES`).
    calm_air: the held-out maneuvers are known to be flown in calm air (a simulated
        validation flight): ``auto`` then picks the simulation for every stable model.
    """

    tolerances: Mapping[str, float] | None = None
    allowed_bias: Mapping[str, float] | None = None
    tic_limit: float = TIC_LIMIT
    truth_k: float = TRUTH_K
    mag_bound_db: float = 3.0
    phase_bound_deg: float = 20.0
    min_coherence: float = 0.6
    input_power_fraction: float = 0.1
    inverse_bandwidth: float = 5.0
    integrator: str | None = None
    proof_of_match: str = "auto"
    calm_air: bool = False
