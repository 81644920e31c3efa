"""Conditioning: flight data made fit for estimation, each step with a JSON-ready account
of what it did.

Data-quality checks (:mod:`.checks`); the sensor-compatibility check and the sensor
errors it removes (:mod:`.compatibility`, :mod:`.sensor_correction`); angles of attack
and sideslip rebuilt from the flight path (:mod:`.flow_angles`, :mod:`.wind_uncertainty`);
the control inputs' delays and lags (:mod:`.input_dynamics`), their steps between slow
samples (:mod:`.input_sampling`) and their noise (:mod:`.input_smoothing`); air data
blended with the integrated IMU (:mod:`.airdata_kinematics`). Imports only
:mod:`pipeline.ingest` of the pipeline's layers.
"""
