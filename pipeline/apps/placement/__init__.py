"""Antenna placement as a study: candidate mounts, replicates, objectives with intervals,
a ranked answer and an optimiser that reuses the traces.

``rfidstudy placement PLACEMENT.toml --out DIR`` (:func:`run_placement`); the file's
format is :mod:`pipeline.apps.placement.spec`'s, the objectives
:mod:`pipeline.apps.placement.objectives`', the outputs :mod:`pipeline.apps.placement.summary`'s.
Within the package the imports flow one way: :mod:`.runner` -> :mod:`.optimise` /
:mod:`.summary` -> :mod:`.figures` / :mod:`.report` -> :mod:`.results` (run directories,
bands, the ranked table, :class:`PlacementResult`) -> :mod:`.objectives`; :mod:`.spec`
-> :mod:`.candidates`.
"""

from pipeline.apps.placement.candidates import (
    Candidate,
    candidates_of,
    check_candidate,
    mount_antennas,
)
from pipeline.apps.placement.objectives import (
    OBJECTIVES,
    CandidateData,
    Objective,
    load_candidate_data,
)
from pipeline.apps.placement.optimise import search
from pipeline.apps.placement.runner import PlacementResult, ProgressEvent, run_placement
from pipeline.apps.placement.spec import PlacementSpec, load_placement, placement_from_mapping

__all__ = [
    "OBJECTIVES",
    "Candidate",
    "CandidateData",
    "Objective",
    "PlacementResult",
    "PlacementSpec",
    "ProgressEvent",
    "candidates_of",
    "check_candidate",
    "load_candidate_data",
    "load_placement",
    "mount_antennas",
    "placement_from_mapping",
    "run_placement",
    "search",
]
