"""What each figure shows and what to read in it; the report's sections in pipeline order."""

from __future__ import annotations

__all__ = ["CAPTIONS", "SECTIONS"]

#: Figure name -> caption: what is drawn, then what to read in it.
CAPTIONS = {
    "baselines": (
        "Every model's held-out scores with their 95 % intervals, one panel per metric on its "
        "own axis. ▲ / ▼: better / worse than the chapter's FCM + ANFIS on the same tags or "
        "filter runs (the paired interval of the difference excludes 0); overlapping bars "
        "alone do not decide, the marks do."),
    "scene_top_view": (
        "The scene from above: walls at laser height, training and held-out tags, the route, "
        "and the true and MCL trajectories. Read where the MCL track leaves the true one: "
        "those reads carry a pose error into the training data."),
    "mcl_error": (
        "Monte Carlo Localization error over time on the training tour and the evaluation "
        "path. Peaks are where the biased map misleads the laser; the median is in the MCL "
        "table."),
    "ssm_surface": (
        "Chapter Fig. 4: the learned RSSI model fs(d, α), normalised, over distance and "
        "bearing. Expect a fall with d and a maximum near α = 0 (boresight); ripples are "
        "fuzzy rules, not physics."),
    "tdm_surface": (
        "Chapter Fig. 5: the learned detection model fT(d, α). The 0.5 contour is the model's "
        "read range per bearing."),
    "learned_vs_truth_rssi": (
        "Learned RSSI against the noise-free ray-traced truth per (d, α) cell, and their "
        "difference. Red and blue patches in the right panel are where the model is biased; "
        "blank cells hold no closed link."),
    "learned_vs_truth_detection": (
        "Learned detection probability against the true one per (d, α) cell, and their "
        "difference. Large differences at the edge of the read range matter most for "
        "localisation."),
    "rho_vs_truth": (
        "Chapter Fig. 6: true and learned ρ = fs·fT around sample antenna poses, seen from "
        "above. The learned lobe cannot see walls or cabinets; the true one can."),
    "fields": (
        "Ray-traced one-way gain over the field plane for sample antenna poses. Fading "
        "ripples and shadows behind objects are what a model of (d, α) alone averages out."),
    "fig7_error": (
        "Chapter Fig. 7: |f̄s − s| × 100 on normalised RSSI along the evaluation path "
        "(chapter Sec. 5). Its median and share below 20 % are in the held-out table."),
    "site_errors": (
        "Mean signed ρ error (model − truth) at every tag site, one elevation per wall "
        "facing. Red sites behind cabinets and boxes are where the model expects reads the "
        "physics does not give."),
    "downstream": (
        "Left: the share of held-out tags localised within an error, per model (further left "
        "is better). Right: the RFID-only robot filter per model, median of its runs with a "
        "band from the best to the worst run; dashed red: the kidnapping."),
}

#: The report's sections in pipeline order: (title, figure names).
SECTIONS = (
    ("Scene and tour", ("scene_top_view", "mcl_error")),
    ("Learned sensor model", ("ssm_surface", "tdm_surface")),
    ("Model against the ray-traced truth",
     ("learned_vs_truth_rssi", "learned_vs_truth_detection", "rho_vs_truth", "fields",
      "fig7_error", "site_errors")),
    ("Downstream localisation", ("downstream",)),
)
