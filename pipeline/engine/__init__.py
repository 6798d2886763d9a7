"""The stage engine: cached, resumable stages in a run directory (application side).

=================  ==============================================================
module             what it holds
=================  ==============================================================
``stagedef``       :class:`~pipeline.engine.stagedef.Stage`: a stage's name, inputs,
                   outputs and fingerprint
``stageproc``      running one stage (in-process or in a child process)
``study``          :func:`~pipeline.engine.study.run_study`: a stage list into a run
                   directory, each stage cached by its fingerprint
``runstore``       the run directory's store: manifest, stage records, atomic writes,
                   the one-writer lock
``runlog``         the run's log file
``tracetasks``     a study's ray tracing as Dask tasks on a cluster
``preflight``      checks before a run directory is made (map source, memory limit)
=================  ==============================================================

The engine knows nothing of what a stage computes: the study's stages are in
:mod:`pipeline.stages`, the applications that run studies in :mod:`pipeline.apps`.
"""
