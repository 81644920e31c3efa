"""Log writers: the simulator's tables written in the formats real flights arrive in.

* :func:`write_mcap` (path, sim_result): the product's own MCAP, JSON-schema topics.
* :func:`write_dataflash` (path, sim_result, ...): ArduPilot DataFlash ``.bin``.
* :func:`write_truth_json` (path, sim_result): the truth set, trim, sensor errors, seed.

All writes are atomic (temporary file + rename).
"""

from pipeline.outputs.writers.dataflash import write_dataflash
from pipeline.outputs.writers.mcap_json import TOPICS, write_mcap
from pipeline.outputs.writers.truth_json import truth_dict, write_truth_json

__all__ = ["TOPICS", "truth_dict", "write_dataflash", "write_mcap", "write_truth_json"]
