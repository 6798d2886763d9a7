"""The propagation oracle's read likelihood: the reader's own, given true one-way gains.

Given the true one-way gains (as ray traced) at the candidates, the reader's
``P(read) = P(closed) (1 - anticollision miss)`` (the miss
probability of the ``"fixed"`` reader's constant, or per attempt slot for the Gen2
reader, :meth:`OracleLikelihood.with_gains`),
``mu = reader_rssi_dbm(gain)``, ``sigma^2 = rssi_noise^2 + resolution^2 / 12``. The
simulated reader closes the link on the noise-free powers, i.e. when
``reader_rssi_dbm(gain) >= T`` with ``T = reader_rssi_dbm(budget.min_gain_db())`` (the
tag and reader thresholds in one, in the RSSI domain); the oracle softens this step to
``P(closed) = Phi((mu - T) / closure_sigma_db)``, ``closure_sigma_db`` defaulting to the
reader's RSSI noise: gains at candidate points a few centimetres from the tag differ
by fractions of a dB (fading), so a hard step would veto the neighbours of the truth
on a hair. With exact gains it is the best any sensor model can do with these reads.

It shares the robustness clips (``eps``, ``z_clip``) and the per-pair
:class:`~.likelihood.GaussianTerms` of :mod:`.likelihood`.
"""

from __future__ import annotations

import numpy as np
from scipy.special import log_ndtr

from pipeline.acquisition.singulation import p_singulated, reader_dwell_s
from pipeline.localisation.likelihood import EPS, Z_CLIP, GaussianTerms, _check_eps, _check_zclip

__all__ = ["OracleGains", "OracleLikelihood"]


class OracleLikelihood:
    """The reader's own read likelihood given true one-way gains (see module doc).

    Parameters
    ----------
    budget : propagation.LinkBudget
    miss_probability : float
        Anti-collision miss probability of a closed link, in [0, 1) (the default of
        :meth:`read_probability`, :meth:`terms` and :meth:`with_gains`).
    rssi_noise_db : float
        Reader RSSI noise std [dB] (>= 0).
    rssi_resolution_db : float
        RSSI quantisation step [dB] (>= 0); enters as variance ``step^2 / 12``.
    closure_sigma_db : float, optional
        Width of the soft link-closure step in the RSSI domain [dB]; default the RSSI
        sigma (noise and quantisation), at least 0.1 dB.
    eps, z_clip : float
        As :class:`~.likelihood.ModelLikelihood`.
    """

    def __init__(self, budget, *, miss_probability: float, rssi_noise_db: float,
                 rssi_resolution_db: float = 0.0, closure_sigma_db: float | None = None,
                 eps: float = EPS, z_clip: float = Z_CLIP) -> None:
        self.budget = budget
        if not 0.0 <= float(miss_probability) < 1.0:
            raise ValueError(f"miss_probability must be in [0, 1), got {miss_probability!r}")
        if not float(rssi_noise_db) >= 0 or not float(rssi_resolution_db) >= 0:
            raise ValueError("rssi_noise_db and rssi_resolution_db must be >= 0")
        self.miss_probability = float(miss_probability)
        self.sigma_db = float(np.sqrt(float(rssi_noise_db) ** 2
                                      + float(rssi_resolution_db) ** 2 / 12.0))
        if self.sigma_db <= 0:
            self.sigma_db = 0.1  # a noise-free reader: keep the density finite
        cs = max(self.sigma_db, 0.1) if closure_sigma_db is None else float(closure_sigma_db)
        if not cs > 0:
            raise ValueError(f"closure_sigma_db must be > 0, got {closure_sigma_db!r}")
        self.closure_sigma_db = cs
        self.eps = _check_eps(eps)
        self.z_clip = _check_zclip(z_clip)
        self.threshold_dbm = float(budget.reader_rssi_dbm(budget.min_gain_db()))

    @classmethod
    def from_reader(cls, reader, frequency_hz: float | None = None, *,
                    miss_probability: float | None = None, **kw) -> OracleLikelihood:
        """From a :class:`pipeline.acquisition.config.ReaderConfig` (budget, noise, losses);
        the link budget is ``reader.link_budget(frequency_hz)`` (or ``reader.budget`` of a
        reader object that holds one). ``miss_probability`` defaults to the reader's
        ``anticollision_miss_probability`` with the ``"fixed"`` inventory, and with
        ``"gen2"`` to a lone tag's ``1 - p_singulated(1)`` in a round-robin antenna dwell
        (:mod:`pipeline.acquisition.singulation`): the per-slot value of a read log
        belongs in :meth:`with_gains`."""
        if hasattr(reader, "link_budget"):
            budget = reader.link_budget(frequency_hz)
        else:
            budget = reader.budget
        if miss_probability is None:
            miss_probability = reader.anticollision_miss_probability
            if getattr(reader, "inventory", "fixed") == "gen2":
                miss_probability = 1.0 - float(p_singulated(1, reader.gen2, reader_dwell_s(reader)))
        return cls(budget, miss_probability=miss_probability,
                   rssi_noise_db=reader.rssi_noise_db,
                   rssi_resolution_db=reader.rssi_resolution_db, **kw)

    def read_probability(self, gain_db, miss_probability=None) -> np.ndarray:
        """Unclipped P(read) of one-way gains [dB] (-inf: 0).

        ``miss_probability`` (float or array broadcast to the gains' shape, in [0, 1))
        replaces the oracle's own constant when given.
        """
        q = self.miss_probability if miss_probability is None else miss_probability
        mu = np.asarray(self.budget.reader_rssi_dbm(gain_db), dtype=np.float64)
        with np.errstate(invalid="ignore"):
            lc = log_ndtr((mu - self.threshold_dbm) / self.closure_sigma_db)
        return np.exp(np.nan_to_num(lc, nan=-np.inf)) * (1.0 - q)

    def terms(self, gain_db, miss_probability=None) -> GaussianTerms:
        """Per-pair terms of one-way gains [dB] (any shape; -inf where not traced);
        ``miss_probability`` as in :meth:`read_probability`."""
        g = np.asarray(gain_db, dtype=np.float64)
        if np.any(np.isnan(g)):
            raise ValueError("oracle gains contain NaN (use -inf for untraced pairs)")
        p = np.clip(self.read_probability(g, miss_probability), self.eps, 1.0 - self.eps)
        mu = np.asarray(self.budget.reader_rssi_dbm(g), dtype=np.float64)
        return GaussianTerms(np.log(p), np.log1p(-p), mu, self.sigma_db, 0.0, self.z_clip)

    def log_likelihood(self, gain_db, read, rssi_dbm) -> np.ndarray:
        """Elementwise ``log p(read, rssi | gain)``."""
        return self.terms(gain_db).loglik(read, rssi_dbm)

    def sample(self, gain_db, rng: np.random.Generator):
        """Outcomes drawn exactly from this likelihood: ``(read, rssi_dbm)``."""
        g = np.asarray(gain_db, dtype=np.float64)
        read = rng.random(g.shape) < self.read_probability(g)
        mu = np.asarray(self.budget.reader_rssi_dbm(g), dtype=np.float64)
        z = rng.standard_normal(g.shape)
        return read, np.where(read, mu + self.sigma_db * z, np.nan)

    def with_gains(self, gain_db, miss_probability=None) -> OracleGains:
        """Bind a (slots x candidates) gain matrix for :func:`~pipeline.localisation.localise_tags`;
        ``miss_probability``: see :class:`OracleGains`."""
        return OracleGains(self, gain_db, miss_probability)


class OracleGains:
    """An :class:`OracleLikelihood` with its true gains, shape (S slots, C candidates) [dB].

    Column c must be candidate c of the candidate set, row s slot s of the
    :class:`~pipeline.localisation.Observations` (in their order); -inf where not traced.
    ``miss_probability`` (optional, in [0, 1)): the miss probability of a closed link per
    slot, shape (S,) (the Gen2 reader's,
    :func:`pipeline.acquisition.singulation.miss_probability_at_poses`), or per pair
    (S, C); default the oracle's constant.
    """

    def __init__(self, oracle: OracleLikelihood, gain_db, miss_probability=None) -> None:
        g = np.asarray(gain_db, dtype=np.float64)
        if g.ndim != 2:
            raise ValueError(f"oracle gains must be (slots, candidates), got shape {g.shape}")
        if np.any(np.isnan(g)):
            raise ValueError("oracle gains contain NaN (use -inf for untraced pairs)")
        self.oracle = oracle
        self.gain_db = g
        self.miss_probability = None
        if miss_probability is not None:
            q = np.asarray(miss_probability, dtype=np.float64)
            if q.ndim == 1 and q.shape[0] == g.shape[0]:
                q = q[:, None]  # one per slot
            if not np.all((q >= 0.0) & (q < 1.0)):
                raise ValueError("miss_probability must be in [0, 1)")
            try:
                self.miss_probability = np.broadcast_to(q, g.shape)
            except ValueError:
                raise ValueError(f"miss_probability has shape {np.shape(miss_probability)}, "
                                 f"expected (slots,) or {g.shape}") from None
        self.name = "oracle"

    def terms_for(self, cols) -> GaussianTerms:
        q = None if self.miss_probability is None else self.miss_probability[:, cols]
        return self.oracle.terms(self.gain_db[:, cols], q)
