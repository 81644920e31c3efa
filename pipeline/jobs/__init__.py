"""The jobs behind the ``fsid`` commands: :mod:`.scenario` (``fsid run``: :mod:`.simulate`
then the estimate job), :mod:`.estimate` (``fsid estimate``), :mod:`.check` (``fsid
check``). Their stages: :mod:`.stages` (data preparation), :mod:`.estimation` (input
dynamics, fits, consider stage), :mod:`.identify` (the one fit loop), :mod:`.fit` (one fit
validated), :mod:`.consider_stage`, :mod:`.write`; their settings :mod:`.options` and
progress lines :mod:`.progress`.

Light on purpose: the command line imports :mod:`.options` without loading the jobs.
"""
