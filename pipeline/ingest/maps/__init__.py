"""Channel maps: TOML files saying which log field becomes which canonical channel.

The format is documented in :mod:`pipeline.ingest.maps.rules`; the built-in maps are the
TOML files of this package (:mod:`pipeline.ingest.maps.loading`).
"""

from pipeline.ingest.maps.apply import apply_map, apply_rule
from pipeline.ingest.maps.loading import BUILTIN, builtin_names, load_map, plain_map_toml
from pipeline.ingest.maps.rules import TRANSFORMS, UNIT_FACTORS, ChannelMap, ChannelRule
from pipeline.ingest.maps.servo import DEFAULT_TRAVEL_DEG, TORQUE_AXES, servo_travel

__all__ = [
    "BUILTIN",
    "DEFAULT_TRAVEL_DEG",
    "TORQUE_AXES",
    "TRANSFORMS",
    "UNIT_FACTORS",
    "ChannelMap",
    "ChannelRule",
    "apply_map",
    "apply_rule",
    "builtin_names",
    "load_map",
    "plain_map_toml",
    "servo_travel",
]
