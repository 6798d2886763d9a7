"""The applications that run studies (application side): nothing below imports them.

=================  ==============================================================
module             what it holds
=================  ==============================================================
``cli``            the ``rfidstudy`` command line (thin: parses, calls, prints)
``clicommon``      helpers the command line's modules share
``cliscenes``      the ``rfidstudy scenes`` / ``map`` commands
``studyrun``       :func:`~pipeline.apps.studyrun.run_full_study`: one study or its
                   replicates
``replicates``     a study repeated over independent seeds, pooled with intervals
``studypool``      several studies side by side in worker processes
``sweep``          a parameter sweep (local processes or a Dask cluster)
``targets``        what the command line's target names: study TOML, scene, ROS map
``profiles``       bundled config profiles (e.g. the map-scale profile)
``placement``      antenna-placement what-if studies on top of the study
=================  ==============================================================
"""
