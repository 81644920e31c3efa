"""The estimation methods of the pipeline: which there are and what each needs is the
registry (:mod:`pipeline.registry`, light: the command line reads it); here how each fits a problem
(:mod:`.fitting`), the noise levels they start from (:mod:`.noise`), equation error on the
built-in models' regressions (:mod:`.equation_error`) and when a fit holds the
angle-of-attack-rate derivatives (:mod:`.alphadot`).

Layer: above pipeline.problems (and conditioning, ingest, estimators); below the jobs.
"""
