"""Ingest: a log file into canonical flight data.

The format readers (:mod:`pipeline.ingest.readers`, ``read_log``) decode a log into raw
tables (:mod:`pipeline.ingest.rawlog`), a channel map (:mod:`pipeline.ingest.maps`) turns
them into canonical SI channels (:mod:`pipeline.ingest.flightdata`), and the aircraft's
constants and sensor positions come from its TOML, a truth.json or the log
(:mod:`pipeline.ingest.aircraft`, :mod:`pipeline.ingest.constants`). Imports no other
layer of the pipeline.
"""
